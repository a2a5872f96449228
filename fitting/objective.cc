#include "fitting/objective.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "core/error.h"
#include "core/srgb.h"
#include "fitting/colour.h"

namespace flamerig {

void ObjectiveOptions::Validate() const {
  auto fail = [](const std::string& what) { throw InputError("objective options: " + what); };
  if (!(w_am >= 0 && w_am <= kMaxWeight)) fail("w_am must be in [0, 1e12]");
  if (!(w_sm >= 0 && w_sm <= kMaxWeight)) fail("w_sm must be in [0, 1e12]");
  if (!(smooth_delta_e >= 0) || !(smooth_neighbour >= 0)) fail("smoothing epsilons must be >= 0");
  if (!(along_y >= 0 && along_y <= kMaxDirectionFactor) ||
      !(across_y >= 0 && across_y <= kMaxDirectionFactor))
    fail("along_y and across_y must be in [0, 1000]");
  if (!(w_sm * std::max(along_y, across_y) <= kMaxWeight))
    fail("w_sm x along_y and w_sm x across_y must be <= 1e12");
  if (!(t_min_k > 0) || !(t_max_k > t_min_k) || !std::isfinite(t_max_k))
    fail("need 0 < t_min_k < t_max_k, finite");
  if (!(n_min_per_m3 >= 0) || !(n_max_per_m3 >= 0) ||
      (n_max_per_m3 > 0 && !(n_max_per_m3 > n_min_per_m3 && n_min_per_m3 > 0)))
    fail("density bounds: both 0 (plausible soot), or 0 < n_min_per_m3 < n_max_per_m3");
}

double EnergyTerms::exact_energy() const {
  double sum = 0;
  for (const TermValue& t : terms) sum += t.weight * t.exact;
  return sum;
}

Eigen::Vector3d CameraLab(const Eigen::Vector3d& linear_rgb, double exposure,
                          Eigen::Matrix3d* d_lab_d_linear) {
  static const Eigen::Vector3d white = colour::D65White();
  const Eigen::Matrix3d& to_xyz = colour::XyzFromLinearSrgb();
  Eigen::Vector3d c;
  Eigen::Vector3d dc;  // dc/dI per channel: s inside (0, 1), 0 where clamped
  for (int ch = 0; ch < 3; ++ch) {
    const double v = exposure * linear_rgb[ch];
    c[ch] = v > 1 ? 1 : (v > 0 ? v : 0);
    dc[ch] = (v > 0 && v < 1) ? exposure : 0;
  }
  const Eigen::Vector3d xyz = to_xyz * c;
  constexpr double d = 6.0 / 29.0;
  Eigen::Vector3d f, df;
  for (int i = 0; i < 3; ++i) {
    const double t = xyz[i] / white[i];
    if (t > d * d * d) {
      f[i] = std::cbrt(t);
      df[i] = 1.0 / (3.0 * f[i] * f[i]) / white[i];
    } else {
      f[i] = t / (3 * d * d) + 4.0 / 29.0;
      df[i] = 1.0 / (3 * d * d) / white[i];
    }
  }
  if (d_lab_d_linear) {
    Eigen::Matrix3d d_lab_d_f;
    d_lab_d_f << 0, 116, 0, 500, -500, 0, 0, 200, -200;
    *d_lab_d_linear = d_lab_d_f * df.asDiagonal() * to_xyz * dc.asDiagonal();
  }
  return Eigen::Vector3d(116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2]));
}

namespace {

double Charbonnier(double x, double eps) {
  return eps > 0 ? std::sqrt(x * x + eps * eps) - eps : std::abs(x);
}
// d/dx of Charbonnier (the sign for eps = 0, 0 at 0).
double CharbonnierDerivative(double x, double eps) {
  if (eps > 0) return x / std::sqrt(x * x + eps * eps);
  return x > 0 ? 1.0 : (x < 0 ? -1.0 : 0.0);
}

// ---- The terms of the energy

// E_am: CIE76 Delta E between what the camera records of each rendered pixel and the recorded
// pixel, over every pixel of every view; the gradient through the renderer's adjoint.
// CameraLab of a pixel, taken from `black` when the radiance is exactly zero: most pixels of a
// fire's views are black, and Lab (with its cube roots) and its Jacobian at zero are the same
// for all of them at one exposure. The same values as CameraLab, computed once.
struct BlackPixel {
  explicit BlackPixel(double s) : lab(CameraLab(Eigen::Vector3d::Zero(), s, &jacobian)) {}
  Eigen::Matrix3d jacobian;
  Eigen::Vector3d lab;
};
inline Eigen::Vector3d LabOf(const Eigen::Vector3d& linear, double s, const BlackPixel& black,
                             Eigen::Matrix3d* jacobian) {
  if ((linear.array() == 0.0).all()) {  // exactly black (isZero() would take 1e-12 for 0)
    if (jacobian) *jacobian = black.jacobian;
    return black.lab;
  }
  return CameraLab(linear, s, jacobian);
}

class DataTerm : public EnergyTerm {
 public:
  DataTerm(const FitObjective& objective, double weight, double eps)
      : objective_(objective), weight_(weight), eps_(eps) {}
  std::string name() const override { return "data"; }
  double weight() const override { return weight_; }

  TermValue Evaluate(const FitParameters& x, const FitGradient& gradient,
                     EnergyTerms* stats) const override {
    if ((gradient.d_t || gradient.d_n) && !objective_.any_mosaic())
      return EvaluateFused(x, gradient, stats);
    const bool want_gradient = gradient.wanted();
    const BlackPixel zero(x.s), zero_signal(1.0);
    const FitObjective::Renders renders = objective_.Render(x.t, x.n);
    TermValue value{name(), weight_, 0, 0};
    double ds_total = 0;
    std::vector<double> grad_t, grad_n;
    const auto& views = objective_.views();
    for (std::size_t v = 0; v < views.size(); ++v) {
      // A Bayer view is compared as its signal after the mosaic and the demosaicing (exposure
      // applied there, so Lab takes it at 1); its gradient goes back through the mosaic's adjoint.
      const BayerRecord* mosaic = objective_.mosaic(v);
      ImageF codes;  // the mosaic's interpolated codes, for its adjoint
      const ImageF recorded =
          mosaic ? mosaic->Forward(renders.linear[v], x.s, want_gradient ? &codes : nullptr)
                 : ImageF();
      const ImageF& img = mosaic ? recorded : renders.linear[v];
      const double s = mosaic ? 1.0 : x.s;
      const BlackPixel& black = mosaic ? zero_signal : zero;
      const auto& target = objective_.target_lab()[v];
      ImageF d_img;
      if (want_gradient) d_img = ImageF(img.width, img.height, 3, 0.0f);
      struct Sums {
        double exact = 0, smooth = 0, ds = 0;
      };
      const Sums sums = tbb::parallel_reduce(
          tbb::blocked_range<std::size_t>(0, target.size(), 4096), Sums{},
          [&](const tbb::blocked_range<std::size_t>& r, Sums acc) {
            for (std::size_t p = r.begin(); p < r.end(); ++p) {
              const Eigen::Vector3d linear(img.pixels[3 * p], img.pixels[3 * p + 1],
                                           img.pixels[3 * p + 2]);
              Eigen::Matrix3d jac;
              const Eigen::Vector3d lab = LabOf(linear, s, black, want_gradient ? &jac : nullptr);
              const Eigen::Vector3d diff = lab - target[p].cast<double>();
              const double de = diff.norm();
              acc.exact += de;
              acc.smooth += Charbonnier(de, eps_);
              if (want_gradient && de > 0) {
                // d/dLab of the (smoothed) distance, then through the camera to the radiance.
                const Eigen::Vector3d g_lab = diff * (CharbonnierDerivative(de, eps_) / de);
                const Eigen::Vector3d g_lin = jac.transpose() * g_lab * weight_;
                for (int ch = 0; ch < 3; ++ch)
                  d_img.pixels[3 * p + ch] = static_cast<float>(g_lin[ch]);
                // c = s I, so dE/ds = sum over channels of dE/dc * I = (dE/dI * I) / s.
                acc.ds += g_lin.dot(linear) / s;
              }
            }
            return acc;
          },
          [](Sums a, const Sums& b) {
            a.exact += b.exact;
            a.smooth += b.smooth;
            a.ds += b.ds;
            return a;
          });
      value.exact += sums.exact;
      value.smooth += sums.smooth;
      if (mosaic && want_gradient)
        d_img = mosaic->Adjoint(renders.linear[v], x.s, d_img, gradient.d_s ? &ds_total : nullptr,
                                &codes);
      else
        ds_total += sums.ds;
      if (stats) {
        stats->view_mean_delta_e.push_back(target.empty() ? 0.0 : sums.exact / target.size());
        stats->pixels += static_cast<std::int64_t>(target.size());
      }
      if (gradient.d_t || gradient.d_n)
        objective_.renderer(v).RenderGradient(*views[v].rays, d_img, &grad_t, &grad_n);
    }
    const auto& active = objective_.active();
    for (std::size_t a = 0; a < active.size(); ++a) {
      if (gradient.d_t && !grad_t.empty()) (*gradient.d_t)[a] += grad_t[active[a]];
      if (gradient.d_n && !grad_n.empty()) (*gradient.d_n)[a] += grad_n[active[a]];
    }
    if (gradient.d_s) *gradient.d_s += ds_total;
    if (stats) stats->data_exact += value.exact;
    return value;
  }

 private:
  // The same with the voxels' gradient, each view rendered and marched back in one pass
  // (FireRenderer::RenderAndGradient): every pixel's distance and its derivatives are worked out
  // as the renderer finishes the pixel, into per-pixel arrays summed afterwards in pixel order.
  TermValue EvaluateFused(const FitParameters& x, const FitGradient& gradient,
                          EnergyTerms* stats) const {
    const double s = x.s;
    const BlackPixel zero(s);
    objective_.UploadVolume(x.t, x.n);
    TermValue value{name(), weight_, 0, 0};
    double ds_total = 0;
    std::vector<double> grad_t, grad_n;
    const auto& views = objective_.views();
    for (std::size_t v = 0; v < views.size(); ++v) {
      const auto& target = objective_.target_lab()[v];
      const int width = views[v].rays->width();
      std::vector<double> exact(target.size(), 0.0), smooth(target.size(), 0.0),
          ds(target.size(), 0.0);
      auto pixel_gradient = [&](int px, int py, const Eigen::Vector3d& linear) {
        const std::size_t p = static_cast<std::size_t>(py) * width + px;
        Eigen::Matrix3d jac;
        const Eigen::Vector3d lab = LabOf(linear, s, zero, &jac);
        const Eigen::Vector3d diff = lab - target[p].cast<double>();
        const double de = diff.norm();
        exact[p] = de;
        smooth[p] = Charbonnier(de, eps_);
        if (!(de > 0)) return Eigen::Vector3d::Zero().eval();
        // d/dLab of the (smoothed) distance, then through the camera to the radiance.
        const Eigen::Vector3d g_lab = diff * (CharbonnierDerivative(de, eps_) / de);
        const Eigen::Vector3d g_lin = jac.transpose() * g_lab * weight_;
        // The radiance as stored (float), as the unfused path reads it back from the image.
        Eigen::Vector3f g_float = g_lin.cast<float>();
        // c = s I, so dE/ds = sum over channels of dE/dc * I = (dE/dI * I) / s.
        ds[p] = g_lin.dot(linear) / s;
        return g_float.cast<double>().eval();
      };
      ImageF image;
      objective_.renderer(v).RenderAndGradient(*views[v].rays, pixel_gradient, &image, &grad_t,
                                               &grad_n);
      double view_exact = 0;
      for (std::size_t p = 0; p < target.size(); ++p) {
        view_exact += exact[p];
        value.smooth += smooth[p];
        ds_total += ds[p];
      }
      value.exact += view_exact;
      if (stats) {
        stats->view_mean_delta_e.push_back(target.empty() ? 0.0 : view_exact / target.size());
        stats->pixels += static_cast<std::int64_t>(target.size());
      }
    }
    const auto& active = objective_.active();
    for (std::size_t a = 0; a < active.size(); ++a) {
      if (gradient.d_t && !grad_t.empty()) (*gradient.d_t)[a] += grad_t[active[a]];
      if (gradient.d_n && !grad_n.empty()) (*gradient.d_n)[a] += grad_n[active[a]];
    }
    if (gradient.d_s) *gradient.d_s += ds_total;
    if (stats) stats->data_exact += value.exact;
    return value;
  }

  const FitObjective& objective_;
  double weight_, eps_;
};

// E_sm on one parameter: for every active voxel the sum over its active 18-neighbours of
// |v_j - v_i| in normalised units, each unordered pair counted from both ends (the paper's sum),
// each pair x its direction's factor (ObjectiveOptions::along_y, across_y).
class PairwiseTerm : public EnergyTerm {
 public:
  enum class Parameter { kTemperature, kDensity };
  PairwiseTerm(const FitObjective& objective, Parameter parameter, double weight, double eps)
      : objective_(objective), parameter_(parameter), weight_(weight), eps_(eps) {
    const ObjectiveOptions& o = objective.options();
    t_scale_ = 1.0 / (o.t_max_k - o.t_min_k);
    ln_range_ = std::log(objective.n_max()) - std::log(objective.n_min());
    if (o.along_y != 1 || o.across_y != 1) {
      factor_.reserve(objective.neighbour_pairs().size());
      for (const auto& [a, b] : objective.neighbour_pairs()) factor_.push_back(Factor(a, b));
      for (std::uint32_t a = 0; a < objective.num_active(); ++a)
        for (const std::uint32_t* e = objective.neighbours_begin(a);
             e != objective.neighbours_end(a); ++e)
          local_factor_.push_back(Factor(a, *e));
    }
  }
  std::string name() const override {
    return parameter_ == Parameter::kTemperature ? "pairwise temperature" : "pairwise density";
  }
  double weight() const override { return weight_; }
  bool local() const override { return true; }

  TermValue Evaluate(const FitParameters& x, const FitGradient& gradient,
                     EnergyTerms* stats) const override {
    TermValue value{name(), weight_, 0, 0};
    const double n_min = objective_.n_min();
    std::vector<double>* d = parameter_ == Parameter::kTemperature ? gradient.d_t : gradient.d_n;
    const auto& pairs = objective_.neighbour_pairs();
    for (std::size_t p = 0; p < pairs.size(); ++p) {
      const auto [a, b] = pairs[p];
      // Each unordered pair counts twice (the paper's sum over voxels of their neighbours).
      const double twice = factor_.empty() ? 2.0 : 2.0 * factor_[p];
      if (parameter_ == Parameter::kTemperature) {
        const double dt = (x.t[b] - x.t[a]) * t_scale_;
        value.exact += twice * std::abs(dt);
        value.smooth += twice * Charbonnier(dt, eps_);
        if (d) {
          const double g = twice * weight_ * CharbonnierDerivative(dt, eps_) * t_scale_;
          (*d)[b] += g;
          (*d)[a] -= g;
        }
      } else {
        // Below the search range's lowest density (down to 0, where ln n has no value) a density
        // counts as that lowest one: the term and its gradient stay finite, and flat there.
        const double na = std::max(x.n[a], n_min), nb = std::max(x.n[b], n_min);
        const double dn = (std::log(nb) - std::log(na)) / ln_range_;
        value.exact += twice * std::abs(dn);
        value.smooth += twice * Charbonnier(dn, eps_);
        if (d) {
          const double g = twice * weight_ * CharbonnierDerivative(dn, eps_) / ln_range_;
          if (x.n[b] > n_min) (*d)[b] += g / nb;
          if (x.n[a] > n_min) (*d)[a] -= g / na;
        }
      }
    }
    if (stats) stats->smooth_exact += value.exact;
    return value;
  }

  void AddPairCurvature(const FitParameters& x, std::vector<PairCurvature>* out) const override {
    const double n_min = objective_.n_min();
    const auto& pairs = objective_.neighbour_pairs();
    // rho'(d) / d of the Charbonnier (1 / |d| for the exact term, floored as the data term's).
    const double eps = std::max(eps_, 1e-3);
    for (std::size_t p = 0; p < pairs.size(); ++p) {
      const auto [a, b] = pairs[p];
      const double twice = factor_.empty() ? 2.0 : 2.0 * factor_[p];
      if (parameter_ == Parameter::kTemperature) {
        const double dt = (x.t[b] - x.t[a]) * t_scale_;
        (*out)[p].tt += twice * weight_ * t_scale_ * t_scale_ / std::sqrt(dt * dt + eps * eps);
      } else {
        if (!(x.n[a] > n_min) || !(x.n[b] > n_min)) continue;  // the term is flat there
        const double dn = (std::log(x.n[b]) - std::log(x.n[a])) / ln_range_;
        (*out)[p].nn += twice * weight_ / (ln_range_ * ln_range_) / std::sqrt(dn * dn + eps * eps);
      }
    }
  }

  double Local(const FitParameters& x, std::uint32_t a) const override {
    double sum = 0;
    const double va = Normalised(x, a);
    const std::uint32_t* first = objective_.neighbours_begin(0);
    for (const std::uint32_t* e = objective_.neighbours_begin(a); e != objective_.neighbours_end(a);
         ++e)
      sum += (local_factor_.empty() ? 1.0 : local_factor_[e - first]) *
             std::abs(Normalised(x, *e) - va);
    return sum;
  }

 private:
  // The direction factor of the pair of active voxels a and b (ObjectiveOptions::along_y).
  double Factor(std::uint32_t a, std::uint32_t b) const {
    const GridGeometry& g = objective_.grid();
    const Eigen::Vector3i d = g.Unflat(objective_.active()[b]) - g.Unflat(objective_.active()[a]);
    const ObjectiveOptions& o = objective_.options();
    return d.x() == 0 && d.z() == 0 ? o.along_y : o.across_y;
  }
  double Normalised(const FitParameters& x, std::uint32_t a) const {
    return parameter_ == Parameter::kTemperature ? objective_.NormaliseT(x.t[a])
                                                 : objective_.NormaliseN(x.n[a]);
  }
  const FitObjective& objective_;
  Parameter parameter_;
  double weight_, eps_, t_scale_ = 0, ln_range_ = 0;
  std::vector<double> factor_;  // per neighbour pair; empty: 1 for every pair
  // Per entry of the objective's neighbour lists (neighbours_begin(0) on), for Local; empty: 1.
  std::vector<double> local_factor_;
};

}  // namespace

FitObjective::FitObjective(const GridGeometry& grid, std::vector<std::uint32_t> active,
                           std::vector<FitView> views, const AbsorptionModel& absorption,
                           const RenderOptions& render, const ObjectiveOptions& options)
    : grid_(grid), active_(std::move(active)), views_(std::move(views)), options_(options) {
  options_.Validate();
  grid_.Validate();
  if (views_.empty()) throw InputError("fit: no views to match");
  const std::size_t nvox = grid_.num_voxels();
  active_index_.assign(nvox, -1);
  std::vector<std::int32_t>& index = active_index_;
  for (std::size_t a = 0; a < active_.size(); ++a) {
    if (active_[a] >= nvox)
      throw InputError("fit: active voxel " + std::to_string(active_[a]) + " outside the grid");
    if (index[active_[a]] >= 0)
      throw InputError("fit: active voxel " + std::to_string(active_[a]) + " repeated");
    index[active_[a]] = static_cast<std::int32_t>(a);
  }
  for (const FitView& v : views_) {
    if (!v.rays) throw InputError("fit: view '" + v.name + "' has no camera rays");
    if (v.image.width != v.rays->width() || v.image.height != v.rays->height() ||
        v.image.channels != 3) {
      throw InputError("fit: view '" + v.name + "': image is " + std::to_string(v.image.width) +
                       "x" + std::to_string(v.image.height) + "x" +
                       std::to_string(v.image.channels) + ", the camera is " +
                       std::to_string(v.rays->width()) + "x" + std::to_string(v.rays->height()) +
                       "x3");
    }
    if (!v.signal.empty() && (v.signal.width != v.image.width ||
                              v.signal.height != v.image.height || v.signal.channels != 3)) {
      throw InputError("fit: view '" + v.name + "': signal is " + std::to_string(v.signal.width) +
                       "x" + std::to_string(v.signal.height) + "x" +
                       std::to_string(v.signal.channels) + ", the image " +
                       std::to_string(v.image.width) + "x" + std::to_string(v.image.height) + "x3");
    }
  }
  if (options_.n_max_per_m3 > 0) {
    n_min_ = options_.n_min_per_m3;
    n_max_ = options_.n_max_per_m3;
  } else {
    const DensityBounds b = DensityBounds::Plausible(absorption);
    n_min_ = b.min_per_m3;
    n_max_ = b.max_per_m3;
  }
  // 18-neighbourhood: offsets with one or two non-zero components.
  neighbour_start_.assign(active_.size() + 1, 0);
  std::vector<std::vector<std::uint32_t>> lists(active_.size());
  const Eigen::Vector3i& dims = grid_.dims;
  for (std::size_t a = 0; a < active_.size(); ++a) {
    const std::size_t f = active_[a];
    const Eigen::Vector3i v = grid_.Unflat(f);
    const int i = v.x(), j = v.y(), k = v.z();
    for (int dk = -1; dk <= 1; ++dk)
      for (int dj = -1; dj <= 1; ++dj)
        for (int di = -1; di <= 1; ++di) {
          const int nonzero = (di != 0) + (dj != 0) + (dk != 0);
          if (nonzero == 0 || nonzero == 3) continue;
          const int ii = i + di, jj = j + dj, kk = k + dk;
          if (ii < 0 || jj < 0 || kk < 0 || ii >= dims.x() || jj >= dims.y() || kk >= dims.z())
            continue;
          const std::int32_t b = index[grid_.Flat(ii, jj, kk)];
          if (b < 0) continue;
          lists[a].push_back(static_cast<std::uint32_t>(b));
          if (static_cast<std::size_t>(b) > a)
            pairs_.emplace_back(static_cast<std::uint32_t>(a), static_cast<std::uint32_t>(b));
        }
  }
  for (std::size_t a = 0; a < active_.size(); ++a) {
    neighbour_start_[a + 1] = neighbour_start_[a] + static_cast<std::uint32_t>(lists[a].size());
    neighbour_list_.insert(neighbour_list_.end(), lists[a].begin(), lists[a].end());
  }
  // Targets in Lab.
  for (const FitView& v : views_) {
    std::vector<Eigen::Vector3f> lab(v.image.num_pixels());
    for (std::size_t p = 0; p < lab.size(); ++p) {
      if (v.signal.empty()) {
        lab[p] = colour::SrgbU8ToLab(v.image.pixels[3 * p], v.image.pixels[3 * p + 1],
                                     v.image.pixels[3 * p + 2])
                     .cast<float>();
      } else {
        // The signal is what clamp(s I, 0, 1) predicts: its Lab, as CameraLab takes it.
        const Eigen::Vector3d signal(v.signal.pixels[3 * p], v.signal.pixels[3 * p + 1],
                                     v.signal.pixels[3 * p + 2]);
        if (!signal.allFinite())
          throw InputError("fit: view '" + v.name + "': signal pixel (" +
                           std::to_string(p % v.signal.width) + ", " +
                           std::to_string(p / v.signal.width) + ") is not finite");
        lab[p] = CameraLab(signal, 1.0).cast<float>();
      }
    }
    target_lab_.push_back(std::move(lab));
  }
  // One renderer per distinct camera response.
  std::vector<const ChannelResponse*> responses;
  for (const FitView& v : views_) {
    const ChannelResponse* r = v.response ? v.response.get() : render.response.get();
    const auto found = std::find(responses.begin(), responses.end(), r);
    view_renderer_.push_back(static_cast<std::size_t>(found - responses.begin()));
    if (found != responses.end()) continue;
    responses.push_back(r);
    RenderOptions options = render;
    if (v.response) options.response = v.response;
    renderers_.push_back(std::make_unique<FireRenderer>(absorption, options));
  }
  // The energy's terms: add a term here.
  terms_.push_back(std::make_unique<DataTerm>(*this, options_.w_am, options_.smooth_delta_e));
  terms_.push_back(std::make_unique<PairwiseTerm>(*this, PairwiseTerm::Parameter::kTemperature,
                                                  options_.w_sm, options_.smooth_neighbour));
  if (options_.density_pairwise)
    terms_.push_back(std::make_unique<PairwiseTerm>(*this, PairwiseTerm::Parameter::kDensity,
                                                    options_.w_sm, options_.smooth_neighbour));
}

FitObjective::~FitObjective() = default;

double FitObjective::NormaliseT(double t) const {
  return (t - options_.t_min_k) / (options_.t_max_k - options_.t_min_k);
}

double FitObjective::NormaliseN(double n) const {
  return (std::log(std::max(n, n_min_)) - std::log(n_min_)) / (std::log(n_max_) - std::log(n_min_));
}

bool FitObjective::any_mosaic() const {
  for (std::size_t v = 0; v < views_.size(); ++v)
    if (mosaic(v)) return true;
  return false;
}

double FitObjective::WeightedData(double data_exact) const {
  return terms_.front()->weight() * data_exact;  // the data term is first (constructor)
}

double FitObjective::EnergyWithData(double data_exact, const FitParameters& x) const {
  double sum = WeightedData(data_exact);
  for (std::size_t k = 1; k < terms_.size(); ++k)
    sum += terms_[k]->weight() * terms_[k]->Evaluate(x, FitGradient{}, nullptr).exact;
  return sum;
}

double FitObjective::LocalEnergy(const FitParameters& x, std::uint32_t a) const {
  double sum = 0;
  for (const auto& term : terms_)
    if (term->local()) sum += term->weight() * term->Local(x, a);
  return sum;
}

FitObjective::Renders FitObjective::Render(const std::vector<double>& t,
                                           const std::vector<double>& n) const {
  UploadVolume(t, n);
  Renders r;
  r.linear.resize(views_.size());
  for (std::size_t v = 0; v < views_.size(); ++v) renderer(v).Render(*views_[v].rays, &r.linear[v]);
  return r;
}

void FitObjective::UploadVolume(const std::vector<double>& t, const std::vector<double>& n) const {
  if (t.size() != active_.size() || n.size() != active_.size())
    throw InputError("fit: temperature and density need one value per active voxel");
  std::vector<float> tt(grid_.num_voxels(), 0.0f), nn(grid_.num_voxels(), 0.0f);
  for (std::size_t a = 0; a < active_.size(); ++a) {
    if (!std::isfinite(t[a]) || !std::isfinite(n[a]))
      throw InputError("fit: non-finite temperature or density at active voxel " +
                       std::to_string(a));
    tt[active_[a]] = static_cast<float>(std::max(0.0, t[a]));
    nn[active_[a]] = static_cast<float>(std::max(0.0, n[a]));
  }
  for (auto& renderer : renderers_) renderer->SetVolume(grid_, tt, nn);
}

FitObjective::Curvature FitObjective::DataCurvature(const std::vector<double>& t,
                                                    const std::vector<double>& n, double s) const {
  const Renders renders = Render(t, n);
  Curvature out;
  const std::size_t na = active_.size();
  out.tt.assign(na, 0.0);
  out.tn.assign(na, 0.0);
  out.nn.assign(na, 0.0);
  std::vector<double> tt, tn, nn;
  for (std::size_t v = 0; v < views_.size(); ++v) {
    // Per pixel: d(Lab)/d(linear) at the fit (zero where clamped, or where the render is black),
    // and the residuals over fire pixels.
    const ImageF& img = renders.linear[v];
    const auto& target = target_lab_[v];
    // The residuals are the data term's (a Bayer view's through its mosaic); the Jacobians each
    // pixel's own, as if it had measured its three channels (see the header).
    const BayerRecord* bayer = mosaic(v);
    const ImageF recorded = bayer ? bayer->Forward(img, s) : ImageF();
    std::vector<Eigen::Matrix3f> jacobians(target.size(), Eigen::Matrix3f::Zero());
    std::vector<Eigen::Vector3d> residual(target.size(), Eigen::Vector3d::Zero());
    std::vector<char> fire(target.size(), 0);
    for (std::size_t p = 0; p < target.size(); ++p) {
      const Eigen::Vector3d linear(img.pixels[3 * p], img.pixels[3 * p + 1], img.pixels[3 * p + 2]);
      Eigen::Matrix3d jac;
      Eigen::Vector3d lab = CameraLab(linear, s, &jac);
      if (bayer)
        lab = CameraLab(Eigen::Vector3d(recorded.pixels[3 * p], recorded.pixels[3 * p + 1],
                                        recorded.pixels[3 * p + 2]),
                        1.0);
      if (!(linear.array() == 0.0).all()) jacobians[p] = jac.cast<float>();
      if (lab[0] > 1 || target[p][0] > 1) {
        residual[p] = lab - target[p].cast<double>();
        fire[p] = 1;
        out.residual_sq += residual[p].squaredNorm();
        out.residuals += 3;
      }
    }
    // Fire pixels side by side: each with the one to its right and the one below; in a Bayer
    // view three pixels apart, beyond the demosaicing's reach (its taps are the 8 neighbours),
    // since neighbours interpolated from the same sites share their noise.
    auto pair = [&](std::size_t p, std::size_t q) {
      if (!fire[q]) return;
      out.difference_sq += 0.5 * (residual[p] - residual[q]).squaredNorm();
      out.differences += 3;
    };
    // (A Bayer view's border pixels are copies of their inner neighbours': left out.)
    const std::size_t w = std::size_t(img.width);
    const int lag = bayer ? 3 : 1, edge = bayer ? 1 : 0;
    const int x_end = img.width - edge, y_end = img.height - edge;
    for (int y = edge; y < y_end; ++y)
      for (int x = edge; x < x_end; ++x) {
        const std::size_t p = std::size_t(y) * w + std::size_t(x);
        if (!fire[p]) continue;
        if (x + lag < x_end) pair(p, p + lag);
        if (y + lag < y_end) pair(p, p + lag * w);
      }
    renderer(v).RenderCurvature(*views_[v].rays, jacobians, &tt, &tn, &nn);
  }
  if (tt.empty()) return out;  // no view
  for (std::size_t a = 0; a < na; ++a) {
    const double dn_dlog = std::max(0.0, n[a]);  // d/d ln n = n d/dn
    out.tt[a] = tt[active_[a]];
    out.tn[a] = tn[active_[a]] * dn_dlog;
    out.nn[a] = nn[active_[a]] * dn_dlog * dn_dlog;
  }
  return out;
}

void FitObjective::DataGaussNewton(const std::vector<double>& t, const std::vector<double>& n,
                                   double s, const PixelRowsVisitor& visit) const {
  if (!(s > 0) || !std::isfinite(s))
    throw InputError("fit: exposure " + std::to_string(s) + " must be finite and > 0");
  const Renders renders = Render(t, n);
  const double w_am = options_.w_am;
  const double eps = std::max(options_.smooth_delta_e, 1e-3);
  for (std::size_t v = 0; v < views_.size(); ++v) {
    const ImageF& img = renders.linear[v];
    const auto& target = target_lab_[v];
    const BayerRecord* bayer = mosaic(v);
    const ImageF recorded = bayer ? bayer->Forward(img, s) : ImageF();
    // Per pixel: sqrt(w_p) dLab/dI (what the renderer's pass multiplies its rays by), and
    // sqrt(w_p) r_p and sqrt(w_p) dr_p/d ln s for the visitor.
    std::vector<Eigen::Matrix3f> jacobians(target.size(), Eigen::Matrix3f::Zero());
    std::vector<Eigen::Vector3d> residual(target.size()), d_log_s(target.size());
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, target.size(), 4096),
        [&](const tbb::blocked_range<std::size_t>& range) {
          for (std::size_t p = range.begin(); p < range.end(); ++p) {
            const Eigen::Vector3d linear(img.pixels[3 * p], img.pixels[3 * p + 1],
                                         img.pixels[3 * p + 2]);
            Eigen::Matrix3d jac;
            Eigen::Vector3d lab = CameraLab(linear, s, &jac);
            if (bayer)
              lab = CameraLab(Eigen::Vector3d(recorded.pixels[3 * p], recorded.pixels[3 * p + 1],
                                              recorded.pixels[3 * p + 2]),
                              1.0);
            const Eigen::Vector3d r = lab - target[p].cast<double>();
            const double root = std::sqrt(w_am / std::sqrt(r.squaredNorm() + eps * eps));
            residual[p] = root * r;
            // d Lab(s I) / d ln s = (dLab/dI / s) (s I) = dLab/dI I.
            d_log_s[p] = root * (jac * linear);
            if (!(linear.array() == 0.0).all()) jacobians[p] = (root * jac).cast<float>();
          }
        });
    tbb::enumerable_thread_specific<PixelRows> rows;
    renderer(v).RenderJacobian(*views_[v].rays, jacobians,
                               [&](const FireRenderer::RayJacobian& ray) {
                                 PixelRows& out = rows.local();
                                 out.view = v;
                                 out.pixel = ray.pixel;
                                 out.residual = residual[ray.pixel];
                                 out.d_log_s = d_log_s[ray.pixel];
                                 out.active.clear();
                                 out.d.clear();
                                 for (std::size_t i = 0; i < ray.voxels.size(); ++i) {
                                   const std::int32_t a = active_index_[ray.voxels[i]];
                                   if (a < 0) continue;  // (every voxel with medium is active)
                                   out.active.push_back(static_cast<std::uint32_t>(a));
                                   Eigen::Matrix<double, 3, 2> d = ray.d[i];
                                   d.col(1) *= std::max(0.0, n[a]);  // d/d ln n = n d/dn
                                   out.d.push_back(d);
                                 }
                                 if (!out.active.empty()) visit(out);
                               });
  }
}

std::vector<PairCurvature> FitObjective::PairwiseGaussNewton(const std::vector<double>& t,
                                                             const std::vector<double>& n) const {
  if (t.size() != active_.size() || n.size() != active_.size())
    throw InputError("fit: temperature and density need one value per active voxel");
  std::vector<PairCurvature> out(pairs_.size());
  const FitParameters x{t, n, 1.0};
  for (const auto& term : terms_) term->AddPairCurvature(x, &out);
  return out;
}

double FitObjective::DataTermAt(const Renders& renders, double s) const {
  double sum = 0;
  for (std::size_t v = 0; v < views_.size(); ++v) {
    const BayerRecord* bayer = mosaic(v);
    const ImageF recorded = bayer ? bayer->Forward(renders.linear[v], s) : ImageF();
    const ImageF& img = bayer ? recorded : renders.linear[v];
    const double exposure = bayer ? 1.0 : s;
    const auto& target = target_lab_[v];
    sum += tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, target.size(), 4096), 0.0,
        [&](const tbb::blocked_range<std::size_t>& r, double acc) {
          for (std::size_t p = r.begin(); p < r.end(); ++p) {
            const Eigen::Vector3d lab = CameraLab(
                Eigen::Vector3d(img.pixels[3 * p], img.pixels[3 * p + 1], img.pixels[3 * p + 2]),
                exposure);
            acc += colour::DeltaE76(lab, target[p].cast<double>());
          }
          return acc;
        },
        std::plus<double>());
  }
  return sum;
}

EnergyTerms FitObjective::Evaluate(const std::vector<double>& t, const std::vector<double>& n,
                                   double s, std::vector<double>* d_t, std::vector<double>* d_n,
                                   double* d_s) const {
  if (!(s > 0) || !std::isfinite(s))
    throw InputError("fit: exposure " + std::to_string(s) + " must be finite and > 0");
  if (d_t) d_t->assign(active_.size(), 0.0);
  if (d_n) d_n->assign(active_.size(), 0.0);
  if (d_s) *d_s = 0.0;
  const FitParameters x{t, n, s};
  const FitGradient gradient{d_t, d_n, d_s};
  EnergyTerms result;
  for (const auto& term : terms_) {
    result.terms.push_back(term->Evaluate(x, gradient, &result));
    result.energy += term->weight() * result.terms.back().smooth;
  }
  result.mean_delta_e = result.pixels ? result.data_exact / result.pixels : 0.0;
  return result;
}

}  // namespace flamerig
