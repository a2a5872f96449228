#include "fitting/fit.h"

#include <ceres/gradient_problem.h>
#include <ceres/gradient_problem_solver.h>
#include <ceres/iteration_callback.h>
#include <tbb/enumerable_thread_specific.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <limits>
#include <map>
#include <memory>
#include <random>
#include <sstream>
#include <stdexcept>
#include <tuple>
#include <unordered_map>

#include "core/error.h"
#include "core/format.h"
#include "core/log.h"
#include "fitting/colour.h"
#include "fitting/levenberg_marquardt.h"
#include "fitting/physics.h"
#include "tomography/reconstruct.h"

namespace flamerig {

namespace {

using Clock = std::chrono::steady_clock;
double Seconds(Clock::time_point since) {
  return std::chrono::duration<double>(Clock::now() - since).count();
}

double Sigmoid(double u) {
  if (u >= 0) return 1.0 / (1.0 + std::exp(-u));
  const double e = std::exp(u);
  return e / (1.0 + e);
}
// Inverse of Sigmoid for p in (0, 1), clamped away from the ends.
double Logit(double p) {
  p = std::clamp(p, 1e-2, 1.0 - 1e-2);
  return std::log(p / (1.0 - p));
}

double Luminance(const float* rgb) { return 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]; }

}  // namespace

void FitOptions::Validate() const {
  objective.Validate();
  render.Validate();
  if (estimate_uncertainty) uncertainty.Validate();
  auto fail = [](const std::string& what) { throw InputError("fit options: " + what); };
  if (!(activity_threshold >= 0 && activity_threshold < 1))
    fail("activity_threshold must be in [0, 1)");
  if (!(exposure_min > 0) || !(exposure_max > exposure_min) || !std::isfinite(exposure_max))
    fail("need 0 < exposure_min < exposure_max, finite");
  if (init_colour_radius_voxels < 0 || init_colour_radius_voxels > 8)
    fail("init_colour_radius_voxels must be in [0, 8]");
  if (init_band_radius_voxels < -1 || init_band_radius_voxels > 8)
    fail("init_band_radius_voxels must be -1 (automatic) or in [0, 8]");
  if (coarsest_resolution < 4) fail("coarsest_resolution must be >= 4");
  if (iterations_per_level < 0 || iterations_finest < 0) fail("iterations must be >= 0");
  if (stall_window < 0) fail("stall_window must be >= 0");
  if (!(stall_decrease >= 0) || !(stall_decrease < 1)) fail("stall_decrease must be in [0, 1)");
  if (!(axisymmetric_stall_decrease >= 0) || !(axisymmetric_stall_decrease < 1))
    fail("axisymmetric_stall_decrease must be in [0, 1)");
  if (!(axisymmetric_lm_stall_decrease >= 0) || !(axisymmetric_lm_stall_decrease < 1))
    fail("axisymmetric_lm_stall_decrease must be in [0, 1)");
  if (axisymmetric_solver != TiedSolver::kLbfgs &&
      axisymmetric_solver != TiedSolver::kLevenbergMarquardt)
    fail("axisymmetric_solver must be L-BFGS or Levenberg-Marquardt");
  if (!(smooth_delta_e >= 0) || !(smooth_neighbour >= 0)) fail("smoothing must be >= 0");
  if (!(time_limit_s >= 0)) fail("time_limit_s must be >= 0");
  try {
    TiedObjective().Validate();
  } catch (const InputError& e) {
    fail(std::string(
             "the tied fit's axisymmetric_w_sm (axisymmetric_lm_w_sm), axisymmetric_along_y and "
             "axisymmetric_across_y (its w_sm, along_y and across_y): ") +
         e.what());
  }
  if (neighbour_weight_resolution < 0) fail("neighbour_weight_resolution must be >= 0");
  if (!(known_exposure >= 0) || !std::isfinite(known_exposure) ||
      (known_exposure > 0 && !(known_exposure >= exposure_min && known_exposure <= exposure_max)))
    fail("known_exposure must be 0 (unknown) or in [exposure_min, exposure_max]");
}

ObjectiveOptions FitOptions::TiedObjective() const {
  ObjectiveOptions tied = objective;
  tied.w_sm = axisymmetric_solver == TiedSolver::kLevenbergMarquardt ? axisymmetric_lm_w_sm
                                                                     : axisymmetric_w_sm;
  tied.along_y = axisymmetric_along_y;
  tied.across_y = axisymmetric_across_y;
  return tied;
}

std::string FitOptions::Key() const {
  std::ostringstream k;
  k.precision(17);
  const ObjectiveOptions& o = objective;
  k << "w_am " << o.w_am << ", w_sm " << o.w_sm << ", smooth_delta_e " << o.smooth_delta_e
    << ", smooth_neighbour " << o.smooth_neighbour << ", t " << o.t_min_k << " .. " << o.t_max_k
    << " K, n " << o.n_min_per_m3 << " .. " << o.n_max_per_m3 << " /m^3, density_pairwise "
    << o.density_pairwise << ", model_mosaic " << o.model_mosaic << ", along_y " << o.along_y
    << ", across_y " << o.across_y;
  const RenderOptions& r = render;
  k << "; render: step " << r.step_voxels << ", min_transmittance " << r.min_transmittance
    << ", skip_empty_space " << r.skip_empty_space << ", brick " << r.brick_size_voxels << ", path "
    << ToString(r.path) << ", spectral " << r.spectral_first_nm << " .. " << r.spectral_last_nm
    << " / " << r.spectral_step_nm << " nm, double " << r.double_precision << ", wide "
    << r.wide_kernels << ", response '"
    << (r.response ? r.response->name() : std::string("the views'")) << "'";
  k << "; fit: neighbour_weight_resolution " << neighbour_weight_resolution << ", activity "
    << activity_threshold << ", exposure " << exposure_min << " .. " << exposure_max << ", known "
    << known_exposure << ", colour start " << init_colour_radius_voxels << " / "
    << init_colour_cap_brightness << ", band start " << init_band_radius_voxels
    << ", coarse_to_fine " << coarse_to_fine << " from " << coarsest_resolution << ", iterations "
    << iterations_per_level << " / " << iterations_finest << ", stall " << stall_window << " / "
    << stall_decrease << ", smooth " << smooth_delta_e << " / " << smooth_neighbour
    << ", time_limit " << time_limit_s << " s, density_pairwise " << density_pairwise
    << ", warm density from emission " << warm_start_density_from_emission << ", axisymmetric "
    << axisymmetric << " (w_sm " << axisymmetric_w_sm << " x " << axisymmetric_along_y
    << " along y, x " << axisymmetric_across_y << " across, interpolate "
    << axisymmetric_interpolate << ", stall " << axisymmetric_stall_decrease << ", solver "
    << ToString(axisymmetric_solver) << ", its stall " << axisymmetric_lm_stall_decrease
    << " and w_sm " << axisymmetric_lm_w_sm << "), vary " << vary.temperature << vary.density
    << ", uncertainty " << estimate_uncertainty << " (" << uncertainty.determined_fraction
    << ", dense up to " << uncertainty.max_dense_nodes << " nodes)";
  return k.str();
}

const char* ToString(FitOptions::TiedSolver solver) {
  return solver == FitOptions::TiedSolver::kLevenbergMarquardt ? "levenberg-marquardt" : "l-bfgs";
}

const char* ToString(FitTermination termination) {
  switch (termination) {
    case FitTermination::kConverged:
      return "converged";
    case FitTermination::kIterationLimit:
      return "iteration limit";
    case FitTermination::kTimeLimit:
      return "time limit";
    case FitTermination::kCancelled:
      return "cancelled";
    case FitTermination::kFailed:
      return "failed";
  }
  return "?";
}

std::string FitResult::BriefReport() const {
  std::ostringstream s;
  s.precision(4);
  s << method << ": " << ToString(termination) << " after " << iterations << " iterations ("
    << message << "), " << active_voxels << " active voxels, " << evaluations << " evaluations, "
    << seconds << " s; energy " << initial_energy << " -> " << final_terms.exact_energy()
    << " (data " << final_terms.data_exact << ", pairwise " << final_terms.smooth_exact
    << "), mean Delta E " << final_terms.mean_delta_e << " (per view:";
  for (double d : final_terms.view_mean_delta_e) s << " " << d;
  s << "), exposure " << exposure;
  if (density_scale != 1) s << ", density scale " << density_scale;
  if (rings > 0) s << ", axisymmetric: " << rings << " rings";
  if (voxels_at_temperature_bound + voxels_at_density_bound > 0)
    s << "; at the upper bound (held by it, not by the images): " << voxels_at_temperature_bound
      << " voxel(s) in temperature, " << voxels_at_density_bound << " in density";
  return s.str();
}

ThinEmissionTable::ThinEmissionTable(const AbsorptionModel& absorption, double t_min_k,
                                     double t_max_k,
                                     std::shared_ptr<const ChannelResponse> response)
    : t_min_(t_min_k), t_max_(t_max_k) {
  if (!(t_min_k > 0) || !(t_max_k > t_min_k))
    throw InputError("ThinEmissionTable: need 0 < t_min < t_max");
  if (!response) response = ChannelResponse::SrgbObserver();
  // The observer (with any gains, at any exposure: ChannelResponse::Exposed) by its basis.
  xyz_chromaticity_ = response->basis_is_xyz();
  mono_ = response->channels() == 1;
  const int first = xyz_chromaticity_ ? colour::CieObserver::kFirstNm : ChannelResponse::kFirstNm;
  const int last = xyz_chromaticity_ ? colour::CieObserver::kLastNm : ChannelResponse::kLastNm;
  std::vector<double> sigma(last - first + 1);
  for (int i = first; i <= last; ++i) sigma[i - first] = absorption.CrossSectionM2(i);
  const int n = static_cast<int>(std::ceil(t_max_k - t_min_k)) + 1;
  const auto& cie = colour::CieObserver::Cie1931TwoDegree();
  for (int k = 0; k < n; ++k) {
    const double t = std::min(t_max_k, t_min_k + k);
    if (xyz_chromaticity_) {
      int i = 0;
      const Eigen::Vector3d xyz = cie.Integrate(
          [&](double nm) { return sigma[i++] * physics::PlanckRadiancePerNm(nm, t); });
      rgb_.push_back(colour::LinearSrgbFromXyz() * xyz);
      xy_.push_back(colour::Chromaticity(xyz));
    } else {
      const Eigen::Vector3d c = response->Integrate([&](double nm) {
        const int i = static_cast<int>(nm) - first;
        return i >= 0 && i < int(sigma.size()) ? sigma[i] * physics::PlanckRadiancePerNm(nm, t)
                                               : 0.0;
      });
      const Eigen::Vector3d unit = c.cwiseQuotient(response->gain());  // the tomography's units
      rgb_.push_back(unit);
      xy_.push_back(colour::Chromaticity(unit));
    }
  }
}

Eigen::Vector3d ThinEmissionTable::RgbPerDensity(double t_k) const {
  const double u = std::clamp(t_k - t_min_, 0.0, double(rgb_.size() - 1));
  const std::size_t i = std::min(static_cast<std::size_t>(u), rgb_.size() - 2);
  const double f = u - i;
  return (1 - f) * rgb_[i] + f * rgb_[i + 1];
}

double ThinEmissionTable::TemperatureOf(const Eigen::Vector3d& rgb) const {
  if (mono_) return 0.5 * (t_min_ + t_max_);  // one channel has no colour to read
  const Eigen::Vector3d xyz =
      xyz_chromaticity_ ? Eigen::Vector3d(colour::XyzFromLinearSrgb() * rgb) : rgb;
  if (!(xyz.sum() > 0)) return t_min_;
  const Eigen::Vector2d xy = colour::Chromaticity(xyz);
  auto dist = [&](std::size_t k) { return (xy_[k] - xy).squaredNorm(); };
  std::size_t best = 0;
  for (std::size_t k = 0; k < xy_.size(); k += 10)
    if (dist(k) < dist(best)) best = k;
  const std::size_t lo = best >= 10 ? best - 10 : 0, hi = std::min(xy_.size() - 1, best + 10);
  for (std::size_t k = lo; k <= hi; ++k)
    if (dist(k) < dist(best)) best = k;
  return std::min(t_max_, t_min_ + best);
}

std::vector<std::uint32_t> ActiveVoxels(const GridGeometry& grid, const FireVolume& tomography,
                                        double threshold, std::vector<float>* emission_on_grid) {
  if (tomography.emission_rgb.size() != tomography.geometry.num_voxels() * 3)
    throw InputError("fit: the tomography volume has no emission (3 values per voxel)");
  std::vector<float> e = tomography.geometry.SameVoxels(grid)
                             ? tomography.emission_rgb
                             : ResampleEmission(tomography.geometry, tomography.emission_rgb, grid);
  double peak = 0;
  for (std::size_t v = 0; v < grid.num_voxels(); ++v) {
    const double y = Luminance(&e[3 * v]);
    if (!std::isfinite(y))
      throw InputError("fit: the tomography emission is not finite at voxel " + std::to_string(v));
    peak = std::max(peak, y);
  }
  std::vector<std::uint32_t> active;
  if (peak > 0) {
    for (std::size_t v = 0; v < grid.num_voxels(); ++v)
      if (Luminance(&e[3 * v]) > threshold * peak) active.push_back(static_cast<std::uint32_t>(v));
  }
  if (emission_on_grid) *emission_on_grid = std::move(e);
  return active;
}

namespace {

// The fit's state on one grid.
struct State {
  GridGeometry grid;
  std::vector<std::uint32_t> active;
  std::vector<double> t, n;
  double s = 1;
};

// The bands of a two-colour start on one level's grid (BandTomography).
class BandStart {
 public:
  BandStart(const std::vector<BandTomography>& bands, const GridGeometry& grid,
            const AbsorptionModel& absorption, const FitOptions& options)
      : t_min_(options.objective.t_min_k), dims_(grid.dims) {
    const double t_min_k = options.objective.t_min_k, t_max_k = options.objective.t_max_k;
    // A cold start tries several radii (FastFit); this one serves warm starts.
    radius_ = options.init_band_radius_voxels >= 0 ? options.init_band_radius_voxels : 3;
    for (std::size_t b = 0; b < bands.size(); ++b) {
      const BandTomography& band = bands[b];
      const std::string where = "fit: band " + std::to_string(b);
      if (!band.response || band.response->channels() != 1)
        throw InputError(where + ": a two-colour start needs each band's mono camera response");
      const FireVolume& v = band.tomography;
      if (v.emission_rgb.size() != v.geometry.num_voxels() * 3)
        throw InputError(where + " (" + band.response->name() +
                         "): its tomography has no emission");
      const std::vector<float> rgb = v.geometry.SameVoxels(grid)
                                         ? v.emission_rgb
                                         : ResampleEmission(v.geometry, v.emission_rgb, grid);
      std::vector<float> grey(rgb.size() / 3);
      for (std::size_t i = 0; i < grey.size(); ++i) grey[i] = rgb[3 * i];
      integral_.push_back(IntegralVolume(grey, grid.dims));
      emission_.push_back(std::move(grey));
      const ThinEmissionTable table(absorption, t_min_k, t_max_k, band.response);
      std::vector<double> k, log_k;
      for (double t = t_min_k; t <= t_max_k; t += 1) {
        k.push_back(std::max(table.RgbPerDensity(t)[0], 1e-300));
        log_k.push_back(std::log(k.back()));
      }
      k_.push_back(std::move(k));
      log_k_.push_back(std::move(log_k));
    }
  }
  std::size_t bands() const { return emission_.size(); }
  int radius() const { return radius_; }  // of the neighbourhood whose emission gives T
  void set_radius(int r) { radius_ = r; }
  // Band b's emission at a voxel (channel 0: the bands are grey).
  double Emission(std::size_t b, std::size_t voxel) const { return emission_[b][voxel]; }
  // Each band's emission summed over the cube of radius() around voxel (i, j, k), clipped to the
  // grid: eight look-ups in the band's summed-volume table, whatever the radius.
  void BoxSums(int i, int j, int k, std::vector<double>* sums) const {
    const int r = radius_;
    const int x0 = std::max(0, i - r), x1 = std::min(dims_.x(), i + r + 1);
    const int y0 = std::max(0, j - r), y1 = std::min(dims_.y(), j + r + 1);
    const int z0 = std::max(0, k - r), z1 = std::min(dims_.z(), k + r + 1);
    sums->resize(integral_.size());
    for (std::size_t b = 0; b < integral_.size(); ++b) {
      const auto at = [&](int x, int y, int z) {
        return integral_[b]
                        [(static_cast<std::size_t>(z) * (dims_.y() + 1) + y) * (dims_.x() + 1) + x];
      };
      (*sums)[b] = at(x1, y1, z1) - at(x0, y1, z1) - at(x1, y0, z1) - at(x1, y1, z0) +
                   at(x0, y0, z1) + at(x0, y1, z0) + at(x1, y0, z0) - at(x0, y0, z0);
    }
  }

  // The temperature whose band ratios match `e` (per band) best: least squares over the bands with
  // positive emission of log e_b - log K_b(T) - mean over b; NaN when fewer than two have any.
  double Temperature(const std::vector<double>& e) const {
    std::vector<std::size_t> used;
    std::vector<double> log_e;
    // A band without light sums to zero up to the summed-volume table's rounding: below 1e-9 of
    // the brightest band it counts as none (its log would pin T to an end of the range).
    double largest = 0;
    for (double x : e)
      if (std::isfinite(x)) largest = std::max(largest, x);
    for (std::size_t b = 0; b < e.size(); ++b)
      if (e[b] > 1e-9 * largest && std::isfinite(e[b])) {
        used.push_back(b);
        log_e.push_back(std::log(e[b]));
      }
    if (used.size() < 2) return std::numeric_limits<double>::quiet_NaN();
    const std::size_t n = k_.front().size();
    auto cost = [&](std::size_t i) {
      double mean = 0;
      for (std::size_t u = 0; u < used.size(); ++u) mean += log_e[u] - log_k_[used[u]][i];
      mean /= double(used.size());
      double c = 0;
      for (std::size_t u = 0; u < used.size(); ++u) {
        const double r = log_e[u] - log_k_[used[u]][i] - mean;
        c += r * r;
      }
      return c;
    };
    // Every 10 K, then each kelvin around the best (the ratio is smooth in T).
    std::size_t best = 0;
    double best_cost = cost(0);
    for (std::size_t i = 10; i < n; i += 10)
      if (const double c = cost(i); c < best_cost) best = i, best_cost = c;
    const std::size_t lo = best >= 10 ? best - 10 : 0, hi = std::min(n - 1, best + 10);
    for (std::size_t i = lo; i <= hi; ++i)
      if (const double c = cost(i); c < best_cost) best = i, best_cost = c;
    return t_min_ + double(best);
  }
  // Density times exposure at a voxel at temperature t (in the tomography's units, as the colour
  // start's brightness): the bands' emission over their emission per density.
  double Brightness(std::size_t voxel, double t) const {
    const std::size_t i = std::min(k_.front().size() - 1,
                                   static_cast<std::size_t>(std::max(0.0, std::round(t - t_min_))));
    double e = 0, k = 0;
    for (std::size_t b = 0; b < bands(); ++b) {
      e += std::max(0.0, Emission(b, voxel));
      k += k_[b][i];
    }
    return k > 0 ? e / k : 0.0;
  }

 private:
  // S(x, y, z) = the sum of e over voxels [0, x) x [0, y) x [0, z), (nx+1)(ny+1)(nz+1).
  static std::vector<double> IntegralVolume(const std::vector<float>& e, const Eigen::Vector3i& d) {
    const std::size_t sx = d.x() + 1, sy = d.y() + 1;
    std::vector<double> s(sx * sy * (d.z() + 1), 0.0);
    for (int z = 1; z <= d.z(); ++z)
      for (int y = 1; y <= d.y(); ++y)
        for (int x = 1; x <= d.x(); ++x) {
          const std::size_t v =
              (static_cast<std::size_t>(z - 1) * d.y() + (y - 1)) * d.x() + (x - 1);
          const auto at = [&](int a, int b, int c) { return s[(c * sy + b) * sx + a]; };
          s[(z * sy + y) * sx + x] = e[v] + at(x - 1, y, z) + at(x, y - 1, z) + at(x, y, z - 1) -
                                     at(x - 1, y - 1, z) - at(x - 1, y, z - 1) -
                                     at(x, y - 1, z - 1) + at(x - 1, y - 1, z - 1);
        }
    return s;
  }

  double t_min_;
  int radius_ = 1;
  Eigen::Vector3i dims_;
  std::vector<std::vector<double>> integral_;   // per band
  std::vector<std::vector<float>> emission_;    // per band, per voxel of the grid (channel 0)
  std::vector<std::vector<double>> k_, log_k_;  // per band, K_b and its log per kelvin from t_min
};

// Where any band has light: the bands' emission, each over its own peak, summed on the first
// band's grid (grey); empty without bands.
FireVolume BandActivity(const std::vector<BandTomography>& bands) {
  FireVolume out;
  if (bands.empty()) return out;
  out.geometry = bands.front().tomography.geometry;
  out.metadata_numbers = bands.front().tomography.metadata_numbers;
  out.emission_rgb.assign(3 * out.geometry.num_voxels(), 0.0f);
  for (std::size_t b = 0; b < bands.size(); ++b) {
    const FireVolume& v = bands[b].tomography;
    if (v.emission_rgb.size() != v.geometry.num_voxels() * 3)
      throw InputError("fit: band " + std::to_string(b) + ": its tomography has no emission");
    const std::vector<float> e = v.geometry.SameVoxels(out.geometry)
                                     ? v.emission_rgb
                                     : ResampleEmission(v.geometry, v.emission_rgb, out.geometry);
    float peak = 0;
    for (std::size_t i = 0; i < e.size(); i += 3) peak = std::max(peak, e[i]);
    if (!(peak > 0)) continue;
    for (std::size_t i = 0; i < e.size(); i += 3) {
      const float x = std::max(0.0f, e[i]) / peak;
      for (int c = 0; c < 3; ++c) out.emission_rgb[i + c] += x;
    }
  }
  return out;
}

// Per-voxel start from the emission (step 1 of the fast fit); from the bands' ratios when `bands`
// is given (a voxel with light in fewer than two bands takes the temperature its colour gives,
// for a mono rig the middle of the range, and its density from the bands at that temperature).
void InitialiseFromEmission(const std::vector<float>& emission, const ThinEmissionTable& table,
                            double exposure_tomography, double n_min, double n_max,
                            const FitOptions& options, State* st,
                            const BandStart* bands = nullptr) {
  const std::size_t m = st->active.size();
  st->t.assign(m, table.t_min());
  st->n.assign(m, n_min);
  std::vector<double> brightness(m, 0.0);
  const Eigen::Vector3i& dims = st->grid.dims;
  const int radius = options.init_colour_radius_voxels;
  std::vector<double> band_sum;
  for (std::size_t a = 0; a < m; ++a) {
    const std::size_t f = st->active[a];
    const float* e = &emission[3 * f];
    const Eigen::Vector3i v = st->grid.Unflat(f);
    const int i = v.x(), j = v.y(), k = v.z();
    if (bands) {
      bands->BoxSums(i, j, k, &band_sum);
      const double t = bands->Temperature(band_sum);
      if (std::isfinite(t)) {
        st->t[a] = t;
        brightness[a] = bands->Brightness(f, t);
        continue;
      }
    }
    // The colour of the neighbourhood (emission summed over a cube of voxels, so a brightness-
    // weighted chromaticity): a single voxel's colour from a few views is noisy, and the density
    // that brightness implies depends steeply on the temperature (Y grows 3650x from 1300 to
    // 2300 K), so noise in one would become speckle in the other. Neighbours brighter than the
    // voxel count at its brightness (FitOptions::init_colour_cap_brightness), and the cooler of
    // that colour's temperature and the plain sum's is taken.
    Eigen::Vector3d rgb = Eigen::Vector3d::Zero(), plain = Eigen::Vector3d::Zero();
    const double own = std::max(0.0, double(e[0]) + e[1] + e[2]);
    bool capped = false;
    for (int dk = -radius; dk <= radius; ++dk)
      for (int dj = -radius; dj <= radius; ++dj)
        for (int di = -radius; di <= radius; ++di) {
          const int ii = i + di, jj = j + dj, kk = k + dk;
          if (ii < 0 || jj < 0 || kk < 0 || ii >= dims.x() || jj >= dims.y() || kk >= dims.z())
            continue;
          const float* q = &emission[3 * st->grid.Flat(ii, jj, kk)];
          const double sum = double(q[0]) + q[1] + q[2];
          const Eigen::Vector3d value(q[0], q[1], q[2]);
          plain += value;
          if (options.init_colour_cap_brightness && own > 0 && sum > own) {
            rgb += (own / sum) * value;
            capped = true;
          } else {
            rgb += value;
          }
        }
    // Where no neighbour was capped the two pools are one: a single colour look-up.
    st->t[a] = table.TemperatureOf(rgb);
    if (capped) st->t[a] = std::min(st->t[a], table.TemperatureOf(plain));
    if (bands) {  // `emission` is then the bands' activity, without units: the bands' own
      brightness[a] = bands->Brightness(f, st->t[a]);
      continue;
    }
    const double per_density =
        table.RgbPerDensity(st->t[a]).dot(Eigen::Vector3d(0.2126, 0.7152, 0.0722));
    brightness[a] = per_density > 0 ? std::max(0.0, Luminance(e)) / per_density : 0.0;
  }
  // Image = s_tomo * integral(e) = s * integral(n * rgb(T)): n = brightness * s_tomo / s. A known
  // exposure is s; otherwise pick s so that the brighter voxels sit a decade inside the density
  // bounds.
  std::vector<double> sorted = brightness;
  std::sort(sorted.begin(), sorted.end());
  double s = options.known_exposure > 0 ? options.known_exposure : exposure_tomography;
  if (options.known_exposure <= 0 && !sorted.empty() && sorted.back() > 0) {
    const double reference = sorted[static_cast<std::size_t>(0.95 * (sorted.size() - 1))];
    const double n_ref = reference * exposure_tomography / s;
    if (n_ref > n_max / 10) s *= n_ref / (n_max / 10);
    if (n_ref > 0 && n_ref < n_min * 1e3) s *= n_ref / (n_min * 1e3);
    s = std::clamp(s, options.exposure_min, options.exposure_max);
  }
  st->s = s;
  for (std::size_t a = 0; a < m; ++a)
    st->n[a] = std::clamp(brightness[a] * exposure_tomography / s, n_min, n_max);
}

// Resamples a state onto a finer (or any) grid for the next level; voxels the source did not
// cover start from the emission.
void Resample(const State& from, const std::vector<float>& emission, const ThinEmissionTable& table,
              double exposure_tomography, double n_min, double n_max, const FitOptions& options,
              State* to, bool density_from_emission = false, const BandStart* bands = nullptr) {
  // Pack (T, ln n, 1) per voxel so that the emission resampler carries them, then normalise by
  // the coverage channel.
  std::vector<float> packed(from.grid.num_voxels() * 3, 0.0f);
  for (std::size_t a = 0; a < from.active.size(); ++a) {
    float* p = &packed[3 * from.active[a]];
    p[0] = static_cast<float>(from.t[a]);
    p[1] = static_cast<float>(std::log(from.n[a]));
    p[2] = 1.0f;
  }
  // On the same grid (a warm start from the previous frame) the values carry over exactly.
  std::vector<float> up = from.grid.SameVoxels(to->grid)
                              ? std::move(packed)
                              : ResampleEmission(from.grid, packed, to->grid);
  State fresh;
  fresh.grid = to->grid;
  fresh.active = to->active;
  InitialiseFromEmission(emission, table, exposure_tomography, n_min, n_max, options, &fresh,
                         bands);
  to->t = fresh.t;
  to->n = fresh.n;
  // The density of an emission-initialised voxel is in units of its own exposure: rescale to the
  // coarse level's exposure.
  const double rescale = fresh.s / from.s;
  to->s = from.s;
  for (std::size_t a = 0; a < to->active.size(); ++a) {
    const float* p = &up[3 * to->active[a]];
    if (p[2] > 0.5f) {
      // A temperature carried from the ends of the search range holds no information (the fit
      // pinned it there, where the sigmoid's gradient vanishes): the emission's colour restarts it.
      const double carried = p[0] / p[2];
      const double margin = 0.01 * (table.t_max() - table.t_min());
      if (carried > table.t_min() + margin && carried < table.t_max() - margin) to->t[a] = carried;
      if (density_from_emission) {
        // This frame's brightness at the carried temperature, in units of the carried exposure.
        const double per_density =
            table.RgbPerDensity(to->t[a]).dot(Eigen::Vector3d(0.2126, 0.7152, 0.0722));
        const double b = bands ? bands->Brightness(to->active[a], to->t[a])
                         : per_density > 0
                             ? std::max(0.0, Luminance(&emission[3 * to->active[a]])) / per_density
                             : 0.0;
        to->n[a] = std::clamp(b * exposure_tomography / from.s, n_min, n_max);
      } else {
        to->n[a] = std::clamp(std::exp(double(p[1]) / p[2]), n_min, n_max);
      }
    } else {
      to->n[a] = std::clamp(to->n[a] * rescale, n_min, n_max);
    }
  }
}

// The rings of FitOptions::axisymmetric: per layer of the grid (y), active voxels grouped by their
// distance to the layer's emission centroid, rounded to whole voxels. Members are active indices.
// The fit's parameters are tied to nodes (NodeTie), one per layer and whole radius: each voxel
// takes its ring's node (weight 1), or with FitOptions::axisymmetric_interpolate the two nodes at
// the whole radii either side of its own radius rho, floor(rho) and floor(rho) + 1, weights 1 - f
// and f (f = rho - floor(rho)): a field linear in the radius between the nodes.
struct RingTie {
  std::vector<std::vector<std::size_t>> rings;
  std::vector<std::pair<int, int>> places;  // per ring: (layer, radius in whole voxels)
  std::vector<Eigen::Vector2d> axis;        // per layer: the axis at (i, k), in voxel indices
  NodeTie nodes;
  bool interpolated = false;             // FitOptions::axisymmetric_interpolate
  std::vector<std::size_t> layer_nodes;  // per layer: its first node; one past the last at the end

  // The orthogonal projection onto the tied fields (those the nodes give): the least-squares
  // nodes q of `values` (W^T W q = W^T values, W the voxels' weights; per layer a tridiagonal
  // system, as each voxel weighs two neighbouring nodes), then W q. A projected gradient gives
  // every direction within the tied fields its exact derivative. Rings alone (weights 1): each
  // ring's mean.
  void Project(double* values) const { Expand(NodesOf(values), values); }
  // W q: each voxel's value from the nodes' (`values` has one per voxel).
  void Expand(const std::vector<double>& q, double* values) const {
    for (std::size_t a = 0; a < nodes.node.size(); ++a)
      values[a] = nodes.weight[a][0] * q[nodes.node[a][0]] +
                  (nodes.weight[a][1] == 0 ? 0.0 : nodes.weight[a][1] * q[nodes.node[a][1]]);
  }
  // W^T g: the nodes' share of per-voxel values (a gradient), added into `q`.
  void Contract(const double* values, double* q) const {
    for (std::size_t a = 0; a < nodes.node.size(); ++a) {
      q[nodes.node[a][0]] += nodes.weight[a][0] * values[a];
      if (nodes.weight[a][1] != 0) q[nodes.node[a][1]] += nodes.weight[a][1] * values[a];
    }
  }
  // The least-squares nodes of per-voxel `values`: W^T W q = W^T values.
  std::vector<double> NodesOf(const double* values) const {
    const std::size_t m = nodes.node.size();
    std::vector<double> b(nodes.nodes, 0.0), d(nodes.nodes, 0.0), e(nodes.nodes, 0.0);
    for (std::size_t a = 0; a < m; ++a) {
      const auto& [r0, r1] = nodes.node[a];
      const auto& [w0, w1] = nodes.weight[a];
      b[r0] += w0 * values[a];
      d[r0] += w0 * w0;
      if (w1 == 0) continue;  // (a ring's value that is not finite stays in its own ring)
      b[r1] += w1 * values[a];
      d[r1] += w1 * w1;
      if (r1 == r0 + 1) e[r0] += w0 * w1;  // e[r]: the (r, r + 1) entry
    }
    // Thomas's algorithm per layer; a node no voxel weighs solves to 0 (its row is empty). Nodes
    // that share no voxel (e = 0: always for rings) are not coupled, so that a value that is not
    // finite stays in its own nodes (0 x NaN would carry it along the layer); the same figures
    // for finite values.
    std::vector<double> c(nodes.nodes, 0.0);
    for (std::size_t layer = 0; layer + 1 < layer_nodes.size(); ++layer) {
      const std::size_t lo = layer_nodes[layer], hi = layer_nodes[layer + 1];
      for (std::size_t r = lo; r < hi; ++r) {
        double diag = d[r], rhs = b[r];
        if (r > lo && e[r - 1] != 0) {
          diag -= e[r - 1] * c[r - 1];
          rhs -= e[r - 1] * b[r - 1];
        }
        if (!(diag > 1e-12)) {
          c[r] = 0;
          b[r] = 0;
          continue;
        }
        c[r] = r + 1 < hi ? e[r] / diag : 0.0;
        b[r] = rhs / diag;
      }
      for (std::size_t r = hi; r-- > lo + 1;)
        if (c[r - 1] != 0) b[r - 1] -= c[r - 1] * b[r];
    }
    return b;
  }
  // The start tied to the rings: each ring's mean temperature and mean log density (then, in the
  // fit's parameters, projected onto the tied fields: Project).
  void Tie(State* st) const {
    for (const auto& ring : rings) {
      double t = 0, ln_n = 0;
      for (std::size_t a : ring) {
        t += st->t[a];
        ln_n += std::log(st->n[a]);
      }
      t /= double(ring.size());
      const double n = std::exp(ln_n / double(ring.size()));
      for (std::size_t a : ring) {
        st->t[a] = t;
        st->n[a] = n;
      }
    }
  }
};

RingTie MakeRingTie(const GridGeometry& grid, const std::vector<std::uint32_t>& active,
                    const std::vector<float>& emission, bool interpolate) {
  // Per layer: the luminance-weighted centroid of its active voxels, or their plain mean where
  // the layer has no light.
  std::vector<Eigen::Vector3d> weighted(grid.dims.y(), Eigen::Vector3d::Zero()),
      plain(grid.dims.y(), Eigen::Vector3d::Zero());  // (sum w x, sum w z, sum w)
  for (std::uint32_t f : active) {
    const Eigen::Vector3i v = grid.Unflat(f);
    const double w = std::max(0.0, Luminance(&emission[3 * std::size_t(f)]));
    weighted[v.y()] += Eigen::Vector3d(w * v.x(), w * v.z(), w);
    plain[v.y()] += Eigen::Vector3d(v.x(), v.z(), 1.0);
  }
  std::map<std::pair<int, int>, std::size_t> index;  // (layer, ring) -> ring number
  RingTie tie;
  tie.axis.assign(grid.dims.y(), Eigen::Vector2d::Zero());
  for (int j = 0; j < grid.dims.y(); ++j) {
    const Eigen::Vector3d& c = weighted[j].z() > 0 ? weighted[j] : plain[j];
    if (c.z() > 0) tie.axis[j] = Eigen::Vector2d(c.x() / c.z(), c.y() / c.z());
  }
  std::vector<double> rho(active.size());
  std::vector<int> last(grid.dims.y(), -1);  // per layer: its last node's radius
  for (std::size_t a = 0; a < active.size(); ++a) {
    const Eigen::Vector3i v = grid.Unflat(active[a]);
    const int j = v.y();
    rho[a] = std::hypot(v.x() - tie.axis[j].x(), v.z() - tie.axis[j].y());
    const int radius = static_cast<int>(std::lround(rho[a]));
    last[j] = std::max(last[j], static_cast<int>(std::floor(rho[a])) + 1);
    const auto [it, added] = index.emplace(std::make_pair(j, radius), tie.rings.size());
    if (added) {
      tie.rings.emplace_back();
      tie.places.emplace_back(j, radius);
    }
    tie.rings[it->second].push_back(a);
  }
  // Nodes: per layer, whole radii 0 .. last (interpolated) or one per ring.
  tie.layer_nodes.assign(grid.dims.y() + 1, 0);
  for (int j = 0; j < grid.dims.y(); ++j) tie.layer_nodes[j + 1] = tie.layer_nodes[j] + last[j] + 1;
  tie.nodes.nodes = tie.layer_nodes.back();
  tie.interpolated = interpolate;
  tie.nodes.node.resize(active.size());
  tie.nodes.weight.resize(active.size());
  for (std::size_t a = 0; a < active.size(); ++a) {
    const int j = grid.Unflat(active[a]).y();
    const std::size_t first = tie.layer_nodes[j];
    const int r0 =
        interpolate ? static_cast<int>(std::floor(rho[a])) : static_cast<int>(std::lround(rho[a]));
    const double f = interpolate ? rho[a] - r0 : 0.0;
    tie.nodes.node[a] = {std::uint32_t(first + r0),
                         std::uint32_t(first + std::min(r0 + 1, last[j]))};
    tie.nodes.weight[a] = {1.0 - f, f};
  }
  return tie;
}

// The tied fit's radial profile (FitResult::ring_profile), by layer and then radius.
std::vector<RingProfilePoint> MakeRingProfile(const GridGeometry& grid, const RingTie& tie,
                                              const std::vector<double>& t,
                                              const std::vector<double>& n,
                                              const VoxelUncertainty& uncertainty,
                                              double particle_volume_m3) {
  std::vector<RingProfilePoint> profile;
  for (std::size_t r = 0; r < tie.rings.size(); ++r) {
    const auto [j, radius] = tie.places[r];
    RingProfilePoint p;
    const std::size_t front = tie.rings[r].front();
    // Rings alone: every member holds the ring's values. Interpolated: the ring's voxels' means.
    double t_sum = 0, ln_n_sum = 0, var_t = 0, var_ln_n = 0;
    for (std::size_t a : tie.rings[r]) {
      t_sum += t[a];
      ln_n_sum += std::log(n[a]);
      if (!uncertainty.temperature_sigma_k.empty()) {
        var_t += double(uncertainty.temperature_sigma_k[a]) * uncertainty.temperature_sigma_k[a];
        var_ln_n += double(uncertainty.log_density_sigma[a]) * uncertainty.log_density_sigma[a];
      }
    }
    const double members = double(tie.rings[r].size());
    p.layer = j;
    const Eigen::Vector3d axis =
        grid.RigFromIndex(Eigen::Vector3d(tie.axis[j].x(), j, tie.axis[j].y()));
    p.height_m = axis.y();
    p.axis_x_m = axis.x();
    p.axis_y_m = axis.y();
    p.axis_z_m = axis.z();
    p.radius_voxels = radius;
    p.radius_m = radius * grid.voxel_size_m.x();
    p.voxels = tie.rings[r].size();
    p.temperature_k = tie.interpolated ? t_sum / members : t[front];
    p.density_per_m3 = tie.interpolated ? std::exp(ln_n_sum / members) : n[front];
    p.soot_volume_fraction = p.density_per_m3 * particle_volume_m3;
    if (!uncertainty.temperature_sigma_k.empty()) {
      p.temperature_sigma_k =
          tie.interpolated ? std::sqrt(var_t / members) : uncertainty.temperature_sigma_k[front];
      p.log_density_sigma =
          tie.interpolated ? std::sqrt(var_ln_n / members) : uncertainty.log_density_sigma[front];
    }
    profile.push_back(p);
  }
  std::sort(profile.begin(), profile.end(), [](const auto& x, const auto& y) {
    return std::tie(x.layer, x.radius_voxels) < std::tie(y.layer, y.radius_voxels);
  });
  return profile;
}

}  // namespace

void MeasureRingHeights(const Eigen::Vector3d& up_in_rig, std::vector<RingProfilePoint>* profile) {
  if (!up_in_rig.allFinite() || up_in_rig.norm() == 0)
    throw InputError(fmt::format("ring heights: the rig's up ({}, {}, {}) is not a direction",
                                 up_in_rig.x(), up_in_rig.y(), up_in_rig.z()));
  const Eigen::Vector3d up = up_in_rig.normalized();
  for (RingProfilePoint& p : *profile)
    p.height_m = up.dot(Eigen::Vector3d(p.axis_x_m, p.axis_y_m, p.axis_z_m));
}

namespace {

// The energy in the unbounded parameters u = (u_T per voxel, u_n per voxel, u_s).
class SigmoidProblem : public ceres::FirstOrderFunction {
 public:
  // `start`: the values of the parameters that are held (FitOptions::vary, known_exposure), used
  // as they are rather than through the sigmoid (whose logit is clamped 1% inside the bounds).
  // `tie`: FitOptions::axisymmetric's rings (the start must be tied already), or null.
  SigmoidProblem(const FitObjective& objective, const FitOptions& options, const State& start,
                 int* evaluations, std::deque<std::pair<double, EnergyTerms>>* seen,
                 const RingTie* tie = nullptr)
      : objective_(objective),
        options_(options),
        evaluations_(evaluations),
        seen_(seen),
        tie_(tie) {
    if (!options.vary.temperature) held_t_ = start.t;
    if (!options.vary.density) held_n_ = start.n;
    held_s_ = options.known_exposure > 0 ? options.known_exposure : 0.0;
    m_ = objective.num_active();
    t_lo_ = options.objective.t_min_k;
    t_span_ = options.objective.t_max_k - options.objective.t_min_k;
    ln_n_lo_ = std::log(objective.n_min());
    ln_n_span_ = std::log(objective.n_max()) - ln_n_lo_;
    ln_s_lo_ = std::log(options.exposure_min);
    ln_s_span_ = std::log(options.exposure_max) - ln_s_lo_;
  }
  int NumParameters() const override { return static_cast<int>(2 * m_ + 1); }

  void Decode(const double* u, State* st) const {
    st->t.resize(m_);
    st->n.resize(m_);
    for (std::size_t a = 0; a < m_; ++a) {
      st->t[a] = held_t_.empty() ? t_lo_ + t_span_ * Sigmoid(u[a]) : held_t_[a];
      st->n[a] =
          held_n_.empty() ? std::exp(ln_n_lo_ + ln_n_span_ * Sigmoid(u[m_ + a])) : held_n_[a];
    }
    st->s = held_s_ > 0 ? held_s_ : std::exp(ln_s_lo_ + ln_s_span_ * Sigmoid(u[2 * m_]));
  }
  void Encode(const State& st, double* u) const {
    for (std::size_t a = 0; a < m_; ++a) {
      u[a] = Logit((st.t[a] - t_lo_) / t_span_);
      u[m_ + a] = Logit((std::log(st.n[a]) - ln_n_lo_) / ln_n_span_);
    }
    u[2 * m_] = Logit((std::log(st.s) - ln_s_lo_) / ln_s_span_);
  }

  // d T / d u_T, d ln n / d u_n per voxel and d ln s / d u_s at u: the sigmoids' slopes, 0 for a
  // parameter that is held.
  void Slopes(const double* u, std::vector<double>* t_slope, std::vector<double>* n_slope,
              double* s_slope) const {
    t_slope->resize(m_);
    n_slope->resize(m_);
    for (std::size_t a = 0; a < m_; ++a) {
      const double pt = Sigmoid(u[a]), pn = Sigmoid(u[m_ + a]);
      (*t_slope)[a] = held_t_.empty() ? t_span_ * pt * (1 - pt) : 0.0;
      (*n_slope)[a] = held_n_.empty() ? ln_n_span_ * pn * (1 - pn) : 0.0;
    }
    const double ps = Sigmoid(u[2 * m_]);
    *s_slope = held_s_ > 0 ? 0.0 : ln_s_span_ * ps * (1 - ps);
  }
  bool exposure_fitted() const { return !(held_s_ > 0); }

  bool Evaluate(const double* u, double* cost, double* gradient) const override {
    State st;
    Decode(u, &st);
    std::vector<double> d_t, d_n;
    double d_s = 0;
    EnergyTerms terms;
    try {
      terms = objective_.Evaluate(st.t, st.n, st.s, gradient ? &d_t : nullptr,
                                  gradient ? &d_n : nullptr, gradient ? &d_s : nullptr);
    } catch (const InputError&) {
      return false;  // a non-finite trial point: Ceres backs off
    }
    ++*evaluations_;
    *cost = terms.energy;
    // Ceres reports an iteration by its cost only; the callback finds the terms by it. Kept in
    // evaluation order (the accepted iterate is one of the latest), bounded.
    seen_->emplace_back(terms.energy, terms);
    if (seen_->size() > 64) seen_->pop_front();
    if (gradient) {
      // A parameter that is held has no gradient: L-BFGS's steps then never move it (its
      // components of every step and gradient difference are 0).
      for (std::size_t a = 0; a < m_; ++a) {
        const double pt = Sigmoid(u[a]);
        gradient[a] = options_.vary.temperature ? d_t[a] * t_span_ * pt * (1 - pt) : 0.0;
        const double pn = Sigmoid(u[m_ + a]);
        gradient[m_ + a] =
            options_.vary.density ? d_n[a] * st.n[a] * ln_n_span_ * pn * (1 - pn) : 0.0;
      }
      if (tie_) {
        tie_->Project(gradient);
        tie_->Project(gradient + m_);
      }
      const double ps = Sigmoid(u[2 * m_]);
      gradient[2 * m_] =
          options_.known_exposure > 0 ? 0.0 : d_s * st.s * ln_s_span_ * ps * (1 - ps);
    }
    return std::isfinite(*cost);
  }

 private:
  const FitObjective& objective_;
  const FitOptions& options_;
  int* evaluations_;
  std::deque<std::pair<double, EnergyTerms>>* seen_;
  const RingTie* tie_;
  std::size_t m_ = 0;
  double t_lo_, t_span_, ln_n_lo_, ln_n_span_, ln_s_lo_, ln_s_span_;
  std::vector<double> held_t_, held_n_;  // empty: fitted
  double held_s_ = 0;                    // 0: fitted
};

}  // namespace

bool EnergyStalled(const std::vector<double>& costs, int window, double decrease) {
  const int k = static_cast<int>(costs.size()) - 1;
  if (window <= 0 || k < window) return false;
  const double start = costs.front(), before = costs[k - window], now = costs[k];
  if (!std::isfinite(start) || !std::isfinite(before) || !std::isfinite(now)) return false;
  // A level that has not gone down at all has nothing to measure against: it has stalled.
  return !(start > now) || before - now < decrease * (start - now);
}

namespace {

class TraceCallback : public ceres::IterationCallback {
 public:
  TraceCallback(Clock::time_point start, int level, const std::string& stage,
                std::deque<std::pair<double, EnergyTerms>>* seen, std::vector<FitTracePoint>* trace,
                const ProgressCallback& progress, double time_limit_s, int max_iterations,
                bool announce, int stall_window = 0, double stall_decrease = 0,
                std::string stall_name = "stall_decrease")
      : stall_window_(stall_window),
        stall_decrease_(stall_decrease),
        stall_name_(std::move(stall_name)),
        start_(start),
        level_(level),
        stage_(stage),
        seen_(seen),
        trace_(trace),
        progress_(progress),
        time_limit_s_(time_limit_s),
        max_iterations_(max_iterations),
        announce_(announce) {}
  // Why the callback stopped the solver, if it did (Ceres reports USER_SUCCESS for both).
  bool cancelled() const { return cancelled_; }
  bool out_of_time() const { return out_of_time_; }
  // The energy stalled (FitOptions::stall_window, stall_decrease): the words for FitResult.
  bool stalled() const { return !stalled_.empty(); }
  const std::string& stalled_message() const { return stalled_; }
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& summary) override {
    costs_.push_back(summary.cost);
    Log().debug("fit: {} iteration {}: energy {:.9g}, |gradient| {:.3g}, step {:.3g}, {:.3f} s",
                stage_, summary.iteration, summary.cost, summary.gradient_max_norm,
                summary.step_norm, Seconds(start_));
    auto it = std::find_if(seen_->rbegin(), seen_->rend(),
                           [&](const auto& e) { return e.first == summary.cost; });
    if (it != seen_->rend()) {
      FitTracePoint p;
      p.seconds = Seconds(start_);
      p.energy = it->second.exact_energy();
      p.mean_delta_e = it->second.mean_delta_e;
      p.level = level_;
      p.stage = stage_;
      trace_->push_back(p);
    }
    Progress f;
    f.stage = "fit";
    // A line at each level's start, when there are several (coarse to fine).
    if (summary.iteration == 0 && announce_) f.message = "fit: " + stage_;
    f.unit = "iterations";
    f.done = summary.iteration;
    f.total = max_iterations_;
    f.values = {{"seconds", Seconds(start_)}};
    if (!trace_->empty() && it != seen_->rend()) {
      f.values.push_back({"energy", trace_->back().energy});
      f.values.push_back({"mean_delta_e", trace_->back().mean_delta_e});
    }
    // SOLVER_TERMINATE_SUCCESSFULLY keeps the current parameters (SOLVER_ABORT would discard
    // them); the flags say why.
    if (ReportProgress(progress_, f)) {
      cancelled_ = true;
      return ceres::SOLVER_TERMINATE_SUCCESSFULLY;
    }
    if (time_limit_s_ > 0 && Seconds(start_) > time_limit_s_) {
      out_of_time_ = true;
      return ceres::SOLVER_TERMINATE_SUCCESSFULLY;
    }
    // The minimised (smooth) energy over the last stall_window iterations.
    if (EnergyStalled(costs_, stall_window_, stall_decrease_)) {
      const double before = costs_[costs_.size() - 1 - stall_window_], now = costs_.back();
      std::ostringstream m;
      if (costs_.front() > now)
        m << "the energy fell over the last " << stall_window_ << " iterations by "
          << 100 * (before - now) / (costs_.front() - now) << "% of its fall since the start "
          << "(" << stall_name_ << " " << 100 * stall_decrease_ << "%)";
      else
        m << "the energy has not fallen in " << costs_.size() - 1 << " iterations";
      stalled_ = m.str();
      return ceres::SOLVER_TERMINATE_SUCCESSFULLY;
    }
    return ceres::SOLVER_CONTINUE;
  }

 private:
  int stall_window_;
  double stall_decrease_;
  std::string stall_name_;  // the FitOptions field it came from, for the message
  Clock::time_point start_;
  int level_;
  std::string stage_;
  std::deque<std::pair<double, EnergyTerms>>* seen_;
  std::vector<FitTracePoint>* trace_;
  const ProgressCallback& progress_;
  double time_limit_s_;
  int max_iterations_;
  bool announce_;
  bool cancelled_ = false, out_of_time_ = false;
  std::vector<double> costs_;  // per iteration, from iteration 0
  std::string stalled_;
};

// FitOptions::TiedSolver::kLevenbergMarquardt: the tied fit's energy over its nodes' parameters q
// (per node the logit of T's place in its range, then per node ln n's likewise, as the voxels' u;
// then the exposure's when it is fitted). Each voxel's u is W q (RingTie::Expand: a ring's node,
// or two nodes interpolated); the energy and its exact gradient are the voxels' (an untied
// SigmoidProblem) through W^T; the model's curvature is W^T J^T J W from the data term's rays
// (FitObjective::DataGaussNewton) plus the pairwise terms' (PairwiseGaussNewton), through the
// sigmoids' slopes. The curvature is kept per pair of grid layers, as dense blocks over their
// nodes: a ray crosses few layers, and the pairwise terms couple neighbouring ones.
class TiedLmProblem : public LevenbergMarquardtProblem {
 public:
  TiedLmProblem(const FitObjective& objective, const SigmoidProblem& voxels, const RingTie& tie)
      : objective_(objective), voxels_(voxels), tie_(tie) {
    m_ = objective.num_active();
    nodes_ = tie.nodes.nodes;
    layer_of_.assign(nodes_, 0);
    for (std::size_t l = 0; l + 1 < tie.layer_nodes.size(); ++l)
      for (std::size_t k = tie.layer_nodes[l]; k < tie.layer_nodes[l + 1]; ++k)
        layer_of_[k] = static_cast<std::uint32_t>(l);
    layers_ = tie.layer_nodes.size() - 1;
  }
  int NumParameters() const override {
    return static_cast<int>(2 * nodes_ + (voxels_.exposure_fitted() ? 1 : 0));
  }
  // The voxels' parameters (2 m + 1) from the nodes', and back (the least-squares nodes).
  void Expand(const double* q, double* u) const {
    tie_.Expand(std::vector<double>(q, q + nodes_), u);
    tie_.Expand(std::vector<double>(q + nodes_, q + 2 * nodes_), u + m_);
    if (voxels_.exposure_fitted()) u[2 * m_] = q[2 * nodes_];
  }
  std::vector<double> Reduce(const std::vector<double>& u) const {
    std::vector<double> q(NumParameters());
    const std::vector<double> t = tie_.NodesOf(u.data()), n = tie_.NodesOf(u.data() + m_);
    std::copy(t.begin(), t.end(), q.begin());
    std::copy(n.begin(), n.end(), q.begin() + nodes_);
    if (voxels_.exposure_fitted()) q[2 * nodes_] = u[2 * m_];
    return q;
  }
  std::vector<double> VoxelParameters(const double* q) const {
    std::vector<double> u(2 * m_ + 1, 0.0);
    Expand(q, u.data());
    return u;
  }

  bool Evaluate(const double* q, double* cost, double* gradient) override {
    std::vector<double> u = VoxelParameters(q), g(2 * m_ + 1, 0.0);
    if (!voxels_.Evaluate(u.data(), cost, gradient ? g.data() : nullptr)) return false;
    if (gradient) {
      std::fill_n(gradient, NumParameters(), 0.0);
      tie_.Contract(g.data(), gradient);
      tie_.Contract(g.data() + m_, gradient + nodes_);
      if (voxels_.exposure_fitted()) gradient[2 * nodes_] = g[2 * m_];
    }
    return true;
  }

  void Curvature(const double* q, Eigen::SparseMatrix<double>* h) override {
    const std::vector<double> u = VoxelParameters(q);
    State st;
    voxels_.Decode(u.data(), &st);
    std::vector<double> t_slope, n_slope;
    double s_slope = 0;
    voxels_.Slopes(u.data(), &t_slope, &n_slope, &s_slope);
    const bool fit_s = voxels_.exposure_fitted();
    const NodeTie& tie = tie_.nodes;
    // Per thread: the blocks of J^T J by pair of layers (key l1 x layers + l2, l1 <= l2), each
    // (2 n_l1) x (2 n_l2) over the layers' nodes, (T, n) interleaved; the exposure's row.
    struct Sums {
      std::unordered_map<std::uint64_t, Eigen::MatrixXd> blocks;
      Eigen::VectorXd s_row;
      double s_s = 0;
      std::vector<std::int32_t> local;  // per node: its place in the ray's lists, or -1
      std::vector<std::uint32_t> nodes;
      std::vector<Eigen::Matrix<double, 3, 2>> columns;
      std::vector<std::size_t> order;
    };
    tbb::enumerable_thread_specific<Sums> sums;
    const std::vector<std::size_t>& first = tie_.layer_nodes;
    objective_.DataGaussNewton(st.t, st.n, st.s, [&](const FitObjective::PixelRows& rows) {
      Sums& acc = sums.local();
      if (acc.local.empty()) {
        acc.local.assign(nodes_, -1);
        acc.s_row = Eigen::VectorXd::Zero(2 * nodes_);
      }
      acc.nodes.clear();
      acc.columns.clear();
      for (std::size_t i = 0; i < rows.active.size(); ++i) {
        const std::uint32_t a = rows.active[i];
        Eigen::Matrix<double, 3, 2> d = rows.d[i];
        d.col(0) *= t_slope[a];
        d.col(1) *= n_slope[a];
        for (int k = 0; k < 2; ++k) {
          const double w = tie.weight[a][k];
          if (w == 0) continue;
          const std::uint32_t node = tie.node[a][k];
          std::int32_t& l = acc.local[node];
          if (l < 0) {
            l = static_cast<std::int32_t>(acc.nodes.size());
            acc.nodes.push_back(node);
            acc.columns.emplace_back(Eigen::Matrix<double, 3, 2>::Zero());
          }
          acc.columns[l] += w * d;
        }
      }
      // By node (so by layer), then block by block.
      const std::size_t k = acc.nodes.size();
      acc.order.resize(k);
      for (std::size_t i = 0; i < k; ++i) acc.order[i] = i;
      std::sort(acc.order.begin(), acc.order.end(),
                [&](std::size_t x, std::size_t y) { return acc.nodes[x] < acc.nodes[y]; });
      const Eigen::Vector3d js = rows.d_log_s * s_slope;
      for (std::size_t r1 = 0; r1 < k;) {
        const std::uint32_t l1 = layer_of_[acc.nodes[acc.order[r1]]];
        std::size_t e1 = r1;
        while (e1 < k && layer_of_[acc.nodes[acc.order[e1]]] == l1) ++e1;
        for (std::size_t r2 = r1; r2 < k;) {
          const std::uint32_t l2 = layer_of_[acc.nodes[acc.order[r2]]];
          std::size_t e2 = r2;
          while (e2 < k && layer_of_[acc.nodes[acc.order[e2]]] == l2) ++e2;
          Eigen::MatrixXd& block = acc.blocks[std::uint64_t(l1) * layers_ + l2];
          if (block.size() == 0)
            block = Eigen::MatrixXd::Zero(2 * (first[l1 + 1] - first[l1]),
                                          2 * (first[l2 + 1] - first[l2]));
          for (std::size_t i = r1; i < e1; ++i) {
            const std::size_t li = acc.order[i];
            const std::size_t row = 2 * (acc.nodes[li] - first[l1]);
            for (std::size_t j = r2; j < e2; ++j) {
              const std::size_t lj = acc.order[j];
              const std::size_t col = 2 * (acc.nodes[lj] - first[l2]);
              block.block<2, 2>(row, col) += acc.columns[li].transpose() * acc.columns[lj];
            }
          }
          r2 = e2;
        }
        r1 = e1;
      }
      if (fit_s) {
        for (std::size_t i = 0; i < k; ++i) {
          const std::uint32_t node = acc.nodes[i];
          acc.s_row[2 * node] += acc.columns[i].col(0).dot(js);
          acc.s_row[2 * node + 1] += acc.columns[i].col(1).dot(js);
        }
        acc.s_s += js.squaredNorm();
      }
      for (std::uint32_t node : acc.nodes) acc.local[node] = -1;
    });
    // Into the lower triangle; parameter of node k's T: k, of its n: nodes + k; exposure 2 nodes.
    const int np = NumParameters();
    std::vector<Eigen::Triplet<double>> entries;
    auto index = [&](std::size_t node, int c) { return int(c == 0 ? node : nodes_ + node); };
    for (int i = 0; i < np; ++i) entries.emplace_back(i, i, 0.0);  // the diagonal, always there
    for (const Sums& acc : sums) {
      for (const auto& [key, block] : acc.blocks) {
        const std::size_t l1 = key / layers_, l2 = key % layers_;
        for (Eigen::Index r = 0; r < block.rows(); ++r)
          for (Eigen::Index c = 0; c < block.cols(); ++c) {
            const double v = block(r, c);
            if (v == 0) continue;
            const int gi = index(first[l1] + r / 2, int(r % 2)),
                      gj = index(first[l2] + c / 2, int(c % 2));
            // A block of one layer holds both triangles; one of another pair, one of them.
            if (l1 == l2 && gi < gj) continue;
            entries.emplace_back(std::max(gi, gj), std::min(gi, gj), v);
          }
      }
      if (fit_s && acc.s_row.size()) {
        for (std::size_t node = 0; node < nodes_; ++node)
          for (int c = 0; c < 2; ++c)
            if (acc.s_row[2 * node + c] != 0)
              entries.emplace_back(np - 1, index(node, c), acc.s_row[2 * node + c]);
        entries.emplace_back(np - 1, np - 1, acc.s_s);
      }
    }
    // The pairwise terms: h (d_b - d_a)^2 / 2 in each pair's difference.
    const std::vector<PairCurvature> pairs = objective_.PairwiseGaussNewton(st.t, st.n);
    const auto& neighbours = objective_.neighbour_pairs();
    std::vector<std::pair<int, double>> row;
    for (std::size_t p = 0; p < pairs.size(); ++p) {
      const auto [a, b] = neighbours[p];
      for (int c = 0; c < 2; ++c) {
        const double hp = c == 0 ? pairs[p].tt : pairs[p].nn;
        if (!(hp > 0)) continue;
        const std::vector<double>& slope = c == 0 ? t_slope : n_slope;
        row.clear();
        auto add = [&](std::uint32_t voxel, double sign) {
          for (int k = 0; k < 2; ++k) {
            const double w = tie.weight[voxel][k];
            if (w == 0) continue;
            const int g = index(tie.node[voxel][k], c);
            const double v = sign * w * slope[voxel];
            auto it =
                std::find_if(row.begin(), row.end(), [&](const auto& e) { return e.first == g; });
            if (it == row.end())
              row.emplace_back(g, v);
            else
              it->second += v;
          }
        };
        add(b, 1.0);
        add(a, -1.0);
        for (const auto& [gi, vi] : row)
          for (const auto& [gj, vj] : row)
            if (gi >= gj && vi * vj != 0) entries.emplace_back(gi, gj, hp * vi * vj);
      }
    }
    h->resize(np, np);
    h->setFromTriplets(entries.begin(), entries.end());
  }

 private:
  const FitObjective& objective_;
  const SigmoidProblem& voxels_;
  const RingTie& tie_;
  std::size_t m_ = 0, nodes_ = 0, layers_ = 0;
  std::vector<std::uint32_t> layer_of_;  // per node
};

// FitResult::voxels_at_temperature_bound and voxels_at_density_bound of `st`, fitted in
// [t_min, t_max] and [n_min, n_max] (n_min > 0). 1% of the range is also where Logit clamps a
// start beyond the bound: a voxel left there unmoved is counted, whatever the rounding of its
// round trip through the sigmoid (hence the 1e-6 of the range below the 1%).
void CountAtUpperBounds(const State& st, double t_min, double t_max, double n_min, double n_max,
                        FitResult* r) {
  const double near = 0.01 + 1e-6;
  const double t_near = t_max - near * (t_max - t_min);
  const double ln_n_near = std::log(n_max) - near * (std::log(n_max) - std::log(n_min));
  r->voxels_at_temperature_bound = r->voxels_at_density_bound = 0;
  for (std::size_t a = 0; a < st.active.size(); ++a) {
    r->voxels_at_temperature_bound += st.t[a] >= t_near;
    r->voxels_at_density_bound += st.n[a] > 0 && std::log(st.n[a]) >= ln_n_near;
  }
}

// Voxels outside the medium get the ambient (lowest) temperature: they hold no soot, so they
// neither emit nor absorb, and a renderer that reads temperature alone sees them as cold.
FireVolume ToVolume(const State& st, const FitResult& r, double ambient_k) {
  FireVolume v;
  v.geometry = st.grid;
  v.temperature_k.assign(st.grid.num_voxels(), static_cast<float>(ambient_k));
  v.density_per_m3.assign(st.grid.num_voxels(), 0.0f);
  for (std::size_t a = 0; a < st.active.size(); ++a) {
    v.temperature_k[st.active[a]] = static_cast<float>(st.t[a]);
    v.density_per_m3[st.active[a]] = static_cast<float>(st.n[a]);
  }
  v.metadata_numbers["exposure"] = r.exposure;
  v.metadata_numbers["density_scale"] = r.density_scale;
  v.metadata_numbers["mean_delta_e"] = r.final_terms.mean_delta_e;
  v.metadata_numbers["energy"] = r.final_terms.exact_energy();
  v.metadata_numbers["active_voxels"] = static_cast<double>(st.active.size());
  v.metadata_numbers["voxels_at_temperature_bound"] =
      static_cast<double>(r.voxels_at_temperature_bound);
  v.metadata_numbers["voxels_at_density_bound"] = static_cast<double>(r.voxels_at_density_bound);
  v.metadata_text["method"] = r.method;
  v.metadata_text["termination"] = ToString(r.termination);
  v.metadata_text["termination_message"] = r.message;
  v.metadata_numbers["iterations"] = r.iterations;
  v.metadata_numbers["initial_energy"] = r.initial_energy;
  if (r.rings > 0) v.metadata_numbers["axisymmetric_rings"] = static_cast<double>(r.rings);
  // The prior the temperatures were fitted under: a researcher quoting them needs its weight.
  for (const TermValue& term : r.final_terms.terms)
    if (term.name == "pairwise temperature") v.metadata_numbers["w_sm"] = term.weight;
  return v;
}

std::vector<GridGeometry> Levels(const GridGeometry& grid, const FitOptions& options) {
  std::vector<GridGeometry> levels{grid};
  if (!options.coarse_to_fine) return levels;
  const Box3 box = grid.box();
  int r = grid.dims.maxCoeff();
  while (r / 2 >= options.coarsest_resolution) {
    r /= 2;
    levels.insert(levels.begin(), GridGeometry::FromBox(box, r));
  }
  return levels;
}

double TomographyExposure(const FireVolume& tomography) {
  auto it = tomography.metadata_numbers.find("exposure");
  return it != tomography.metadata_numbers.end() && it->second > 0 ? it->second : 1.0;
}

}  // namespace

FitResult FastFit(const GridGeometry& grid, const FireVolume& tomography,
                  const std::vector<FitView>& views, const AbsorptionModel& absorption,
                  const FitOptions& options_in, const FitResult* warm_start,
                  const ProgressCallback& progress, const std::vector<BandTomography>& bands) {
  const auto start = Clock::now();
  if (bands.size() == 1)
    throw InputError("fit: a two-colour start needs two bands or more, got one");
  FitOptions options = options_in;
  options.Validate();
  if (OneBand(views))
    Log().warn(
        "fit: every fitted camera sees one band ({}): the images hold each voxel's emission in it, "
        "not its temperature, which comes from the start and the prior (no voxel is marked "
        "determined); cameras behind two filters or more (two-colour pyrometry) measure it",
        views.front().response->name());
  options.objective.smooth_delta_e = options.smooth_delta_e;
  options.objective.smooth_neighbour = options.smooth_neighbour;
  options.objective.density_pairwise = options.density_pairwise;
  if (options.axisymmetric) options.objective = options.TiedObjective();
  // The neighbour weight on a grid: as given at neighbour_weight_resolution voxels (FitOptions).
  auto ObjectiveAt = [&options](const GridGeometry& g) {
    ObjectiveOptions o = options.objective;
    if (options.neighbour_weight_resolution > 0) {
      const double ratio = double(options.neighbour_weight_resolution) / g.dims.maxCoeff();
      o.w_sm *= ratio * ratio;
      // Said in the weight the user gave, not in the scaled one ObjectiveOptions::Validate sees;
      // times the stronger direction's factor, as that check takes it (a tied fit's along the
      // axis is 40).
      const double factor = std::max({1.0, o.along_y, o.across_y});
      if (o.w_sm * factor > ObjectiveOptions::kMaxWeight)
        throw InputError(
            "fit: the neighbour weight " + FormatNumber(options.objective.w_sm) + ", scaled by (" +
            std::to_string(options.neighbour_weight_resolution) + " / " +
            std::to_string(g.dims.maxCoeff()) + ")^2 on this grid" +
            (factor > 1 ? " and by its direction factor " + FormatNumber(factor) : std::string()) +
            ", is " + FormatNumber(o.w_sm * factor) + ", above the limit " +
            FormatNumber(ObjectiveOptions::kMaxWeight) + ": give a smaller --w-sm or a finer grid");
    }
    return o;
  };
  const ThinEmissionTable table(
      absorption, options.objective.t_min_k, options.objective.t_max_k,
      !views.empty() && views.front().response ? views.front().response : options.render.response);
  // The bands' emission is in the units of their own exposure (a tomography from a file may have
  // another).
  const double s_tomo = TomographyExposure(bands.empty() ? tomography : bands.front().tomography);
  // A two-colour start's pooling radius, once chosen on a cold start's first level, in the voxels
  // of a grid `chosen_extent` voxels long: the later levels pool over the same distance.
  int chosen_radius = -1, chosen_extent = 0;
  auto make_band_start = [&](const GridGeometry& g) {
    std::unique_ptr<BandStart> b;
    if (bands.empty()) return b;
    b = std::make_unique<BandStart>(bands, g, absorption, options);
    if (chosen_radius >= 0)
      b->set_radius(std::clamp(
          static_cast<int>(std::lround(double(chosen_radius) * g.dims.maxCoeff() / chosen_extent)),
          0, 8));
    return b;
  };
  FitResult result;
  result.method =
      (options.axisymmetric &&
               options.axisymmetric_solver == FitOptions::TiedSolver::kLevenbergMarquardt
           ? std::string("fast fit (Levenberg-Marquardt on the rings' nodes, adjoint gradient")
           : std::string("fast fit (L-BFGS, adjoint gradient")) +
      std::string(options.coarse_to_fine ? ", coarse to fine)" : ")");
  const std::vector<GridGeometry> levels =
      warm_start ? std::vector<GridGeometry>{grid} : Levels(grid, options);
  State previous;
  bool have_previous = false;
  if (warm_start) {
    previous.grid = warm_start->volume.geometry;
    // Under a known exposure that is not the warm start's, its densities give the same images
    // (image = s * integral(n * rgb(T))) scaled by the ratio of the two.
    const double density_scale = options.known_exposure > 0 && warm_start->exposure > 0
                                     ? warm_start->exposure / options.known_exposure
                                     : 1.0;
    for (std::size_t v = 0; v < previous.grid.num_voxels(); ++v) {
      if (warm_start->volume.density_per_m3[v] > 0) {
        previous.active.push_back(static_cast<std::uint32_t>(v));
        previous.t.push_back(warm_start->volume.temperature_k[v]);
        previous.n.push_back(density_scale * warm_start->volume.density_per_m3[v]);
      }
    }
    previous.s = options.known_exposure > 0 ? options.known_exposure : warm_start->exposure;
    have_previous = !previous.active.empty();
  }
  // With bands, the active voxels are where any band has light: a tomography of all the cameras
  // together mixes bands whose brightness differs several times over (eight cameras in two bands:
  // its residual stayed at 59% of the data).
  const FireVolume band_activity = BandActivity(bands);
  const FireVolume& activity = bands.empty() ? tomography : band_activity;
  std::deque<std::pair<double, EnergyTerms>> seen;
  State st;
  double n_min = 0, n_max = 0;  // the density bounds of the returned level
  for (std::size_t level = 0; level < levels.size(); ++level) {
    st = State();
    st.grid = levels[level];
    std::vector<float> emission;
    st.active = ActiveVoxels(st.grid, activity, options.activity_threshold, &emission);
    if (st.active.empty()) {
      throw NoActiveVoxelsError(
          "fit: no active voxels (the tomography volume is black or below the activity "
          "threshold)");
    }
    FitObjective objective(st.grid, st.active, views, absorption, options.render,
                           ObjectiveAt(st.grid));
    n_min = objective.n_min();
    n_max = objective.n_max();
    std::unique_ptr<BandStart> band_start = make_band_start(st.grid);
    if (have_previous) {
      // From another frame (level 0 of a warm start): the temperatures carry over, the densities
      // follow this frame's brightness (options.warm_start_density_from_emission).
      Resample(previous, emission, table, s_tomo, objective.n_min(), objective.n_max(), options,
               &st, warm_start && level == 0 && options.warm_start_density_from_emission,
               band_start.get());
      if (band_start) result.band_radius_voxels = band_start->radius();
    } else if (band_start && options.init_band_radius_voxels < 0) {
      // The bands' ratio voxel by voxel is as noisy as the two tomographies it divides, and how
      // far to pool it depends on the scene and the views: of the starts from several radii, the
      // one whose images match the views best (its data term). Measured on eight mono cameras in
      // two bands (licks, fit 64): radius 1/2/3/5/7 start with Delta E 1.14/0.87/0.63/0.53/0.53
      // and temperature RMS 276/227/201/156/144 K (8, the largest tried, was then chosen).
      double best = std::numeric_limits<double>::infinity();
      State chosen;
      for (int r : {1, 2, 3, 5, 8}) {
        band_start->set_radius(r);
        State trial = st;
        InitialiseFromEmission(emission, table, s_tomo, objective.n_min(), objective.n_max(),
                               options, &trial, band_start.get());
        const double data = objective.Evaluate(trial.t, trial.n, trial.s).data_exact;
        if (chosen.t.empty() || data < best) {
          best = data;
          chosen = std::move(trial);
          result.band_radius_voxels = r;
        }
      }
      st = std::move(chosen);
      band_start->set_radius(result.band_radius_voxels);
      chosen_radius = result.band_radius_voxels;
      chosen_extent = st.grid.dims.maxCoeff();
    } else {
      InitialiseFromEmission(emission, table, s_tomo, objective.n_min(), objective.n_max(), options,
                             &st, band_start.get());
      if (band_start) result.band_radius_voxels = band_start->radius();
    }
    // An axisymmetric fit ties the start, whichever way it was had, into this level's rings.
    std::unique_ptr<RingTie> tie;
    if (options.axisymmetric) {
      tie = std::make_unique<RingTie>(
          MakeRingTie(st.grid, st.active, emission, options.axisymmetric_interpolate));
      tie->Tie(&st);
      result.rings = tie->rings.size();
    }
    const std::string stage =
        "level " + std::to_string(level + 1) + "/" + std::to_string(levels.size()) + " (" +
        std::to_string(st.grid.dims.x()) + "x" + std::to_string(st.grid.dims.y()) + "x" +
        std::to_string(st.grid.dims.z()) + ", " + std::to_string(st.active.size()) +
        " active voxels)";
    auto* problem_function =
        new SigmoidProblem(objective, options, st, &result.evaluations, &seen, tie.get());
    std::vector<double> u(2 * st.active.size() + 1);
    problem_function->Encode(st, u.data());
    if (tie && tie->interpolated) {  // ring means, as the fit's parameters, onto the tied fields
      tie->Project(u.data());
      tie->Project(u.data() + st.active.size());
    }
    ceres::GradientProblem problem(problem_function);
    ceres::GradientProblemSolver::Options solver;
    solver.line_search_direction_type = ceres::LBFGS;
    solver.max_num_iterations =
        level + 1 == levels.size() ? options.iterations_finest : options.iterations_per_level;
    solver.function_tolerance = 1e-7;
    solver.gradient_tolerance = 1e-12;
    solver.logging_type = ceres::SILENT;
    const bool lm =
        tie && options.axisymmetric_solver == FitOptions::TiedSolver::kLevenbergMarquardt;
    // The Levenberg-Marquardt solver has its own stop rule (LevenbergMarquardtOptions), not the
    // callback's.
    TraceCallback callback(start, static_cast<int>(level), stage, &seen, &result.trace, progress,
                           options.time_limit_s, solver.max_num_iterations, levels.size() > 1,
                           lm ? 0 : options.stall_window, options.StallDecrease(),
                           options.axisymmetric ? "axisymmetric_stall_decrease" : "stall_decrease");
    solver.callbacks.push_back(&callback);
    ceres::GradientProblemSolver::Summary summary;
    const std::size_t trace_start = result.trace.size();
    if (lm && solver.max_num_iterations > 0) {
      // On the nodes themselves: the energy of the voxels untied, through the tie (TiedLmProblem).
      SigmoidProblem voxels(objective, options, st, &result.evaluations, &seen);
      TiedLmProblem lm_problem(objective, voxels, *tie);
      std::vector<double> q = lm_problem.Reduce(u);
      LevenbergMarquardtOptions lm_options;
      lm_options.max_iterations = solver.max_num_iterations;
      lm_options.stall_decrease = options.axisymmetric_lm_stall_decrease;
      const LevenbergMarquardtSummary lm_summary = SolveLevenbergMarquardt(
          lm_problem, q.data(), lm_options, [&](const LevenbergMarquardtIteration& it) {
            ceres::IterationSummary summary_for_trace;
            summary_for_trace.iteration = it.iteration;
            summary_for_trace.cost = it.cost;
            return callback(summary_for_trace) == ceres::SOLVER_CONTINUE;
          });
      u = lm_problem.VoxelParameters(q.data());
      if (level == 0 && result.trace.size() > trace_start)
        result.initial_energy = result.trace[trace_start].energy;
      result.iterations += lm_summary.iterations;
      result.message = fmt::format(
          "{} ({} of {} steps taken, {} curvatures in {:.2f} s, factorised in {:.2f} s)",
          lm_summary.message, lm_summary.steps_taken, lm_summary.iterations, lm_summary.curvatures,
          lm_summary.seconds_in_curvature, lm_summary.seconds_in_factorisation);
      Log().debug("fit: {}: Levenberg-Marquardt: {}", stage, result.message);
      if (callback.cancelled()) {
        result.termination = FitTermination::kCancelled;
        result.message = "the progress callback asked to stop";
      } else if (callback.out_of_time()) {
        result.termination = FitTermination::kTimeLimit;
        result.message = "time limit of " + std::to_string(options.time_limit_s) + " s reached";
      } else {
        switch (lm_summary.termination) {
          case LevenbergMarquardtTermination::kConverged:
            result.termination = FitTermination::kConverged;
            break;
          case LevenbergMarquardtTermination::kIterationLimit:
            result.termination = FitTermination::kIterationLimit;
            break;
          case LevenbergMarquardtTermination::kTimeLimit:
            result.termination = FitTermination::kTimeLimit;
            break;
          case LevenbergMarquardtTermination::kCancelled:
            result.termination = FitTermination::kCancelled;
            break;
          case LevenbergMarquardtTermination::kFailed:
            result.termination = FitTermination::kFailed;
            break;
        }
      }
    } else if (solver.max_num_iterations > 0) {
      ceres::Solve(solver, problem, u.data(), &summary);
      // Ceres reports iteration 0 at the starting point: the trace's first point of the level.
      if (level == 0 && result.trace.size() > trace_start)
        result.initial_energy = result.trace[trace_start].energy;
      result.iterations += std::max(0, static_cast<int>(summary.iterations.size()) - 1);
      result.message = summary.message;
      if (callback.cancelled()) {
        result.termination = FitTermination::kCancelled;
        result.message = "the progress callback asked to stop";
      } else if (callback.out_of_time()) {
        result.termination = FitTermination::kTimeLimit;
        result.message = "time limit of " + std::to_string(options.time_limit_s) + " s reached";
      } else if (callback.stalled()) {
        result.termination = FitTermination::kConverged;
        result.message = callback.stalled_message();
      } else if (summary.termination_type == ceres::CONVERGENCE) {
        result.termination = FitTermination::kConverged;
      } else if (summary.termination_type == ceres::NO_CONVERGENCE) {
        result.termination = FitTermination::kIterationLimit;
      } else {
        result.termination = FitTermination::kFailed;
      }
    } else {
      result.termination = FitTermination::kIterationLimit;
      result.message = "no iterations asked for";
    }
    problem_function->Decode(u.data(), &st);
    previous = st;
    have_previous = true;
    result.active_voxels = st.active.size();
    if (level + 1 == levels.size()) {
      // Its data_exact and smooth_exact are the exact (non-smoothed) terms.
      result.final_terms = objective.Evaluate(st.t, st.n, st.s);
      if (options.estimate_uncertainty && result.termination != FitTermination::kCancelled &&
          !st.active.empty())
        result.uncertainty =
            tie ? EstimateUncertainty(objective, st.t, st.n, st.s, options.uncertainty, tie->nodes)
                : EstimateUncertainty(objective, st.t, st.n, st.s, options.uncertainty);
      if (tie)
        result.ring_profile =
            MakeRingProfile(st.grid, *tie, st.t, st.n, result.uncertainty,
                            absorption.is_grey() ? 0.0 : absorption.ParticleVolumeM3());
    }
    // Out of time or cancelled with finer levels to go: they are skipped, and that is why the fit
    // stopped. At the last level the solver's own reason stands.
    const bool skip_rest = level + 1 < levels.size() &&
                           (result.termination == FitTermination::kCancelled ||
                            (options.time_limit_s > 0 && Seconds(start) > options.time_limit_s));
    if (skip_rest) {
      if (result.termination != FitTermination::kCancelled) {
        result.termination = FitTermination::kTimeLimit;
        result.message = "time limit of " + std::to_string(options.time_limit_s) + " s reached";
      }
      // Out of time (or cancelled): carry the current level's state to the finest grid without
      // more iterations.
      if (level + 1 < levels.size()) {
        State fine;
        fine.grid = grid;
        std::vector<float> e;
        fine.active = ActiveVoxels(grid, activity, options.activity_threshold, &e);
        FitObjective fine_objective(grid, fine.active, views, absorption, options.render,
                                    ObjectiveAt(grid));
        std::unique_ptr<BandStart> fine_bands = make_band_start(grid);
        Resample(st, e, table, s_tomo, fine_objective.n_min(), fine_objective.n_max(), options,
                 &fine, false, fine_bands.get());
        st = fine;
        n_min = fine_objective.n_min();
        n_max = fine_objective.n_max();
        result.active_voxels = st.active.size();
        result.rings = 0;  // the returned volume is the finest grid's, untied
        result.final_terms = fine_objective.Evaluate(st.t, st.n, st.s);
      }
      break;
    }
  }
  if (result.trace.empty()) result.initial_energy = result.final_terms.exact_energy();
  if (result.band_radius_voxels >= 0)
    result.method += ", two-colour start from " + std::to_string(bands.size()) + " bands, radius " +
                     std::to_string(result.band_radius_voxels);
  result.exposure = st.s;
  result.seconds = Seconds(start);
  CountAtUpperBounds(st, options.objective.t_min_k, options.objective.t_max_k, n_min, n_max,
                     &result);
  result.volume = ToVolume(st, result, options.objective.t_min_k);
  // w_sm (ToVolume) is the weight applied on this grid; this says how it was scaled from the
  // given one (FitOptions::neighbour_weight_resolution).
  if (options.neighbour_weight_resolution > 0)
    result.volume.metadata_numbers["neighbour_weight_resolution"] =
        options.neighbour_weight_resolution;
  // And how it weighed the pairs by direction (ObjectiveOptions::along_y): w_sm x w_sm_along_y on
  // the pairs along y, w_sm x w_sm_across_y on the others (an axisymmetric fit's 40 and 0).
  result.volume.metadata_numbers["w_sm_along_y"] = options.objective.along_y;
  result.volume.metadata_numbers["w_sm_across_y"] = options.objective.across_y;
  // A tied fit: whether its field is linear in the radius between nodes (1) or one value a ring.
  if (options.axisymmetric)
    result.volume.metadata_numbers["axisymmetric_interpolate"] = options.axisymmetric_interpolate;
  StampAbsorption(absorption, &result.volume);
  if (!result.uncertainty.temperature_sigma_k.empty())
    StoreUncertainty(grid, st.active, result.uncertainty, &result.volume);
  return result;
}

FitResult NoFireResult(const GridGeometry& grid, const AbsorptionModel& absorption,
                       const FitOptions& options, double exposure) {
  if (!(exposure > 0) || !std::isfinite(exposure))
    throw InputError("fit: no fire: the exposure " + std::to_string(exposure) +
                     " is not a positive number");
  FitResult result;
  result.method = "no fire";
  result.termination = FitTermination::kConverged;
  result.message = "the images show no fire: nothing to fit";
  result.exposure = exposure;
  State st;
  st.grid = grid;
  st.s = exposure;
  result.volume = ToVolume(st, result, options.objective.t_min_k);
  result.volume.metadata_numbers["no_fire"] = 1;
  StampAbsorption(absorption, &result.volume);
  return result;
}

}  // namespace flamerig

namespace flamerig {

namespace {

// Voxel order of the paper: flattened along y (fastest), then z, then x.
std::vector<std::uint32_t> YzxOrder(const GridGeometry& grid,
                                    const std::vector<std::uint32_t>& active) {
  std::vector<std::uint32_t> order(active.size());
  for (std::uint32_t a = 0; a < active.size(); ++a) order[a] = a;
  const std::size_t nx = grid.dims.x(), ny = grid.dims.y();
  auto key = [&](std::uint32_t a) {
    const std::size_t f = active[a];
    const std::size_t i = f % nx, j = (f / nx) % ny, k = f / (nx * ny);
    return std::tuple(i, k, j);  // x slowest, then z, then y fastest
  };
  std::sort(order.begin(), order.end(),
            [&](std::uint32_t a, std::uint32_t b) { return key(a) < key(b); });
  return order;
}

}  // namespace

FitResult PaperFit(const GridGeometry& grid, const FireVolume& tomography,
                   const std::vector<FitView>& views, const AbsorptionModel& absorption,
                   const FitOptions& options_in, const PaperFitOptions& paper,
                   const ProgressCallback& progress) {
  const auto start = Clock::now();
  FitOptions options = options_in;
  options.objective.w_sm = paper.w_sm;
  options.Validate();
  options.objective.smooth_delta_e = options.objective.smooth_neighbour = 0;  // exact energy
  if (paper.iterations < 1 || paper.samples_per_cluster < 1 || paper.exposure_sweep < 2 ||
      paper.exposure_samples < 0 || !(paper.initial_sigma_t_k > 0) ||
      !(paper.initial_sigma_log_n > 0) || !(paper.time_limit_s >= 0)) {
    throw InputError(
        "paper fit options: iterations, samples_per_cluster >= 1, exposure_sweep >= 2, "
        "exposure_samples >= 0, deviations > 0, time_limit_s >= 0");
  }
  const bool per_voxel_density = paper.algorithm == PaperAlgorithm::kPerVoxelDensity;
  // Algorithm 1's energy has the pairwise term on the densities too.
  options.objective.density_pairwise = per_voxel_density;
  FitResult result;
  result.method = per_voxel_density ? "paper Algorithm 1 (per-voxel temperature and density)"
                                    : "paper Algorithm 2 (per-voxel temperature, density scale)";
  std::vector<float> emission;
  const std::vector<std::uint32_t> active =
      ActiveVoxels(grid, tomography, options.activity_threshold, &emission);
  if (active.empty()) {
    throw NoActiveVoxelsError(
        "fit: no active voxels (the tomography volume is black or below the activity threshold)");
  }
  const FitObjective objective(grid, active, views, absorption, options.render, options.objective);
  const std::size_t m = active.size();
  const double t_lo = options.objective.t_min_k, t_hi = options.objective.t_max_k;
  const double ln_n_lo = std::log(objective.n_min()), ln_n_hi = std::log(objective.n_max());
  const double ln_s_lo = std::log(options.exposure_min), ln_s_hi = std::log(options.exposure_max);
  std::mt19937_64 rng(paper.seed);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  std::normal_distribution<double> normal(0.0, 1.0);

  // Algorithm 2's density: the tomography's red channel, normalised to a peak of 1.
  std::vector<double> red(m, 0.0);
  double red_peak = 0;
  for (std::size_t a = 0; a < m; ++a)
    red_peak = std::max(red_peak, double(emission[3 * active[a]]));
  for (std::size_t a = 0; a < m; ++a)
    red[a] = red_peak > 0 ? std::max(0.0, double(emission[3 * active[a]])) / red_peak : 0.0;

  // Uniform random start.
  std::vector<double> t(m), ln_n(m);
  for (std::size_t a = 0; a < m; ++a) {
    t[a] = t_lo + (t_hi - t_lo) * uniform(rng);
    ln_n[a] = ln_n_lo + (ln_n_hi - ln_n_lo) * uniform(rng);
  }
  double ln_scale = 0.5 * (ln_n_lo + ln_n_hi);
  // Densities in force. Algorithm 2 keeps a floor of n_min where the red channel is zero, so that
  // every active voxel stays in the medium.
  auto densities = [&](double ln_scale_value) {
    std::vector<double> n(m);
    for (std::size_t a = 0; a < m; ++a) {
      n[a] = per_voxel_density ? std::exp(ln_n[a])
                               : std::max(objective.n_min(), red[a] * std::exp(ln_scale_value));
    }
    return n;
  };
  bool cancelled = false;
  auto out_of_time = [&]() {
    return cancelled || (paper.time_limit_s > 0 && Seconds(start) > paper.time_limit_s);
  };

  // Initial exposure (and density scale) by a log-spaced sweep; one render per density scale,
  // every exposure scored on it.
  double ln_s = 0.5 * (ln_s_lo + ln_s_hi);
  double data = std::numeric_limits<double>::infinity();
  const int sweep = paper.exposure_sweep;
  for (int k = 0; k < (per_voxel_density ? 1 : sweep); ++k) {
    const double ln_scale_k =
        per_voxel_density ? ln_scale : ln_n_lo + (ln_n_hi - ln_n_lo) * k / (sweep - 1);
    const FitObjective::Renders renders = objective.Render(t, densities(ln_scale_k));
    ++result.evaluations;
    for (int e = 0; e < sweep; ++e) {
      const double ln_s_e = ln_s_lo + (ln_s_hi - ln_s_lo) * e / (sweep - 1);
      const double d = objective.DataTermAt(renders, std::exp(ln_s_e));
      if (d < data) {
        data = d;
        ln_s = ln_s_e;
        ln_scale = ln_scale_k;
      }
    }
  }

  // Clusters: ranges of the yzx-ordered active voxels.
  const std::vector<std::uint32_t> order = YzxOrder(grid, active);
  std::vector<std::pair<std::size_t, std::size_t>> clusters{{0, m / 2}, {m / 2, m}};
  // Each cluster starts from the mean of its voxels.
  auto assign_means = [&]() {
    for (const auto& [lo, hi] : clusters) {
      if (hi <= lo) continue;
      double mt = 0, mn = 0;
      for (std::size_t i = lo; i < hi; ++i) {
        mt += t[order[i]];
        mn += ln_n[order[i]];
      }
      mt /= double(hi - lo);
      mn /= double(hi - lo);
      for (std::size_t i = lo; i < hi; ++i) {
        t[order[i]] = mt;
        ln_n[order[i]] = mn;
      }
    }
  };
  assign_means();
  {
    const FitObjective::Renders renders = objective.Render(t, densities(ln_scale));
    ++result.evaluations;
    data = objective.DataTermAt(renders, std::exp(ln_s));
  }
  double last_trace = -1;
  std::string last_stage;
  auto trace = [&](int iteration, const std::string& stage, bool force) {
    const double now = Seconds(start);
    if (!force && now - last_trace < 0.25) return;
    last_trace = now;
    FitTracePoint p;
    p.seconds = now;
    const std::vector<double> n_now = densities(ln_scale);
    p.energy = objective.EnergyWithData(data, FitParameters{t, n_now, std::exp(ln_s)});
    p.mean_delta_e = data / double(std::max<std::int64_t>(1, [&] {
                       std::int64_t px = 0;
                       for (const FitView& v : views) px += v.image.num_pixels();
                       return px;
                     }()));
    p.level = iteration;
    p.stage = stage;
    result.trace.push_back(p);
    Progress f;
    f.stage = "fit";
    if (stage != last_stage) f.message = "fit: " + stage;  // a line at each sweep's start
    last_stage = stage;
    f.unit = "iterations";
    f.done = iteration;
    f.total = paper.iterations;
    f.values = {{"seconds", now}, {"energy", p.energy}, {"mean_delta_e", p.mean_delta_e}};
    if (ReportProgress(progress, f)) cancelled = true;
  };
  trace(0, "start", true);
  result.initial_energy = result.trace.back().energy;
  int sweeps = 0;

  // The densities in force, kept up to date for the local terms (Algorithm 1's pairwise density).
  std::vector<double> n_now = densities(ln_scale);
  bool vary_density = false;  // Algorithm 1 alternates; Algorithm 2 only varies temperature
  for (int it = 1; it <= paper.iterations && !out_of_time(); ++it) {
    const std::string stage = "iteration " + std::to_string(it) + " (" +
                              std::to_string(clusters.size()) + " clusters, " +
                              (vary_density ? "density" : "temperature") + ")";
    const double sigma_t = paper.initial_sigma_t_k / it;
    const double sigma_n = paper.initial_sigma_log_n / it;
    for (const auto& cluster : clusters) {
      // Plain names, not a structured binding: the lambdas below capture them (clang 14, which
      // builds the fuzz targets, cannot capture structured bindings).
      const auto lo = cluster.first, hi = cluster.second;
      if (hi <= lo || out_of_time()) continue;
      // The pairwise terms that a move of this cluster changes: those of its voxels with their
      // neighbours, counted from both ends (pairs inside the cluster stay equal, so they add a
      // constant).
      auto local_pairwise = [&]() {
        const FitParameters x{t, n_now, std::exp(ln_s)};
        double sum = 0;
        for (std::size_t i = lo; i < hi; ++i) sum += 2 * objective.LocalEnergy(x, order[i]);
        return sum;
      };
      auto set_cluster = [&](double v) {
        for (std::size_t i = lo; i < hi; ++i) {
          const std::uint32_t a = order[i];
          if (vary_density) {
            ln_n[a] = v;
            n_now[a] = std::exp(v);
          } else {
            t[a] = v;
          }
        }
      };
      const double current_value = vary_density ? ln_n[order[lo]] : t[order[lo]];
      double best_value = current_value;
      double current_score = objective.WeightedData(data) + local_pairwise();
      for (int j = 0; j < paper.samples_per_cluster; ++j) {
        double v = vary_density ? std::clamp(best_value + sigma_n * normal(rng), ln_n_lo, ln_n_hi)
                                : std::clamp(best_value + sigma_t * normal(rng), t_lo, t_hi);
        set_cluster(v);
        const FitObjective::Renders renders = objective.Render(t, densities(ln_scale));
        ++result.evaluations;
        const double d = objective.DataTermAt(renders, std::exp(ln_s));
        const double score = objective.WeightedData(d) + local_pairwise();
        if (score < current_score) {
          current_score = score;
          best_value = v;
          data = d;
        }
        set_cluster(best_value);
        trace(it, stage, false);
        if (out_of_time()) break;
      }
    }
    // Density factor (Algorithm 2) and exposure, on the data term alone.
    if (!per_voxel_density && !out_of_time()) {
      for (int j = 0; j < paper.exposure_samples; ++j) {
        const double ln_scale_new = std::clamp(ln_scale + normal(rng) / it, ln_n_lo, ln_n_hi);
        const FitObjective::Renders renders = objective.Render(t, densities(ln_scale_new));
        ++result.evaluations;
        const double d = objective.DataTermAt(renders, std::exp(ln_s));
        if (d < data) {
          data = d;
          ln_scale = ln_scale_new;
          n_now = densities(ln_scale);
        }
      }
    }
    if (!out_of_time()) {
      const FitObjective::Renders renders = objective.Render(t, densities(ln_scale));
      ++result.evaluations;
      for (int j = 0; j < paper.exposure_samples; ++j) {
        const double ln_s_new = std::clamp(ln_s + normal(rng) / it, ln_s_lo, ln_s_hi);
        const double d = objective.DataTermAt(renders, std::exp(ln_s_new));
        if (d < data) {
          data = d;
          ln_s = ln_s_new;
        }
      }
    }
    trace(it, stage, true);
    // Double the clusters; each child starts from its parent's value (the mean of its voxels).
    std::vector<std::pair<std::size_t, std::size_t>> finer;
    for (const auto& [lo, hi] : clusters) {
      const std::size_t mid = lo + (hi - lo) / 2;
      if (mid > lo) finer.emplace_back(lo, mid);
      if (hi > mid) finer.emplace_back(mid, hi);
    }
    clusters = std::move(finer);
    if (per_voxel_density) vary_density = !vary_density;
    if (!out_of_time()) sweeps = it;
  }
  result.iterations = sweeps;
  if (cancelled) {
    result.termination = FitTermination::kCancelled;
    result.message = "the progress callback asked to stop";
  } else if (sweeps < paper.iterations) {
    result.termination = FitTermination::kTimeLimit;
    result.message = "time limit of " + std::to_string(paper.time_limit_s) + " s reached";
  } else {
    result.termination = FitTermination::kIterationLimit;
    result.message = "all " + std::to_string(paper.iterations) + " sweeps done";
  }

  State st;
  st.grid = grid;
  st.active = active;
  st.t = t;
  st.n = densities(ln_scale);
  st.s = std::exp(ln_s);
  result.exposure = st.s;
  result.density_scale = per_voxel_density ? 1.0 : std::exp(ln_scale);
  result.final_terms = objective.Evaluate(st.t, st.n, st.s);
  result.active_voxels = m;
  result.seconds = Seconds(start);
  CountAtUpperBounds(st, options.objective.t_min_k, options.objective.t_max_k, objective.n_min(),
                     objective.n_max(), &result);
  result.volume = ToVolume(st, result, options.objective.t_min_k);
  StampAbsorption(absorption, &result.volume);
  return result;
}

}  // namespace flamerig
