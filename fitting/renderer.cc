#include "fitting/renderer.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <sstream>
#include <stdexcept>
#include <type_traits>

#include "core/cpu.h"
#include "core/error.h"
#include "fitting/colour.h"
#include "tomography/ray_march.h"

// The spectral kernels pass GCC vector types between inline functions of this file, which the
// AVX2 build's flatten inlines into its kernels. GCC's note is that such a value is passed
// differently with and without AVX: a call the compiler makes between the two builds still agrees
// with itself (it knows both ends), it is only slower; nothing outside this file sees these types.
#pragma GCC diagnostic ignored "-Wpsabi"

namespace flamerig {

const char* ToString(SpectralPath path) {
  switch (path) {
    case SpectralPath::kAuto:
      return "auto";
    case SpectralPath::kFast:
      return "fast";
    case SpectralPath::kSpectral:
      return "spectral";
  }
  return "?";
}

void RenderOptions::Validate() const {
  auto fail = [](const std::string& field, double value, const std::string& rule) {
    std::ostringstream s;
    s << "RenderOptions." << field << " = " << value << ": " << rule;
    throw InputError(s.str());
  };
  // Below 0.01 (100 samples per voxel) a render would take hours, not be more exact.
  if (!(step_voxels >= 0.01) || !(step_voxels <= 4))
    fail("step_voxels", step_voxels, "must be in [0.01, 4]");
  if (!(min_transmittance >= 0) || !(min_transmittance < 1)) {
    fail("min_transmittance", min_transmittance, "must be in [0, 1)");
  }
  if (brick_size_voxels < 2 || brick_size_voxels > 64) {
    fail("brick_size_voxels", brick_size_voxels, "must be in [2, 64]");
  }
  SpectralBins(spectral_first_nm, spectral_last_nm, spectral_step_nm);  // throws on bad bins
}

std::string RenderSummary::BriefReport() const {
  std::ostringstream s;
  s.precision(3);
  s << ToString(path_used) << " path (" << path_reason << "), " << rays << " rays, " << rays_hit_box
    << " hit the box, " << steps_evaluated << " samples, " << steps_skipped_empty
    << " steps skipped in empty bricks (" << occupied_brick_fraction * 100
    << "% of bricks occupied), " << rays_terminated_early << " rays terminated early, "
    << (wide_kernels ? "AVX2 + FMA kernels, " : "baseline kernels, ") << time_ms << " ms";
  return s.str();
}

FireRenderer::FireRenderer(const AbsorptionModel& absorption, const RenderOptions& options)
    : absorption_(absorption), options_(options) {
  options_.Validate();
  response_ = options_.response ? options_.response : ChannelResponse::SrgbObserver();
  if (options_.path == SpectralPath::kFast && !absorption_.is_grey()) {
    throw InputError("RenderOptions.path = fast needs grey absorption; the model is " +
                     absorption_.name());
  }
  if (options_.path == SpectralPath::kSpectral) {
    path_ = SpectralPath::kSpectral;
    path_reason_ = "requested";
  } else if (absorption_.is_grey()) {
    path_ = SpectralPath::kFast;
    path_reason_ = options_.path == SpectralPath::kFast ? "requested" : "grey absorption";
  } else {
    path_ = SpectralPath::kSpectral;
    path_reason_ = "wavelength-dependent absorption (" + absorption_.name() + ")";
  }
  if (path_ == SpectralPath::kSpectral) {
    double first = options_.spectral_first_nm, last = options_.spectral_last_nm;
    const double step = options_.spectral_step_nm;
    if (!response_->basis_is_xyz()) {
      // Bins centred on where the camera responds, covering it.
      const double lo = response_->support_first_nm(), hi = response_->support_last_nm();
      const double bins = std::max(1.0, std::ceil((hi - lo) / step - 1e-9));
      first = 0.5 * (lo + hi) - 0.5 * (bins - 1) * step;
      last = first + (bins - 1) * step;
    }
    bins_ = std::make_unique<SpectralBins>(first, last, step, response_.get());
    for (double nm : bins_->centers_nm())
      bin_cross_section_m2_.push_back(absorption_.CrossSectionM2(nm));
  }
}

void FireRenderer::SetVolume(const GridGeometry& geometry, const std::vector<float>& temperature_k,
                             const std::vector<float>& density_per_m3) {
  FireVolume check;
  check.geometry = geometry;
  check.temperature_k = temperature_k;
  check.density_per_m3 = density_per_m3;
  if (temperature_k.size() != geometry.num_voxels() ||
      density_per_m3.size() != geometry.num_voxels()) {
    throw InputError("SetVolume: temperature and density need " +
                     std::to_string(geometry.num_voxels()) + " values each, got " +
                     std::to_string(temperature_k.size()) + " and " +
                     std::to_string(density_per_m3.size()));
  }
  check.Validate();
  geometry_ = geometry;
  const std::size_t nvox = geometry.num_voxels();
  temperature_ = temperature_k;
  density_ = density_per_m3;
  // Voxels with density > 0 (the medium) get a slot: their index in the gradient buffers.
  slot_.assign(nvox, -1);
  active_voxels_.clear();
  for (std::size_t v = 0; v < nvox; ++v) {
    if (!(density_per_m3[v] > 0)) continue;
    slot_[v] = static_cast<std::int32_t>(active_voxels_.size());
    active_voxels_.push_back(static_cast<std::uint32_t>(v));
  }
  if (path_ == SpectralPath::kFast) {
    // Per voxel: kappa and XYZ(T), interleaved so that a trilinear sample reads 8 x 16 bytes.
    const double sigma = absorption_.CrossSectionM2(550.0);
    const ChannelResponse& table = *response_;
    fast_.assign(4 * nvox, 0.0f);
    for (std::uint32_t v : active_voxels_) {
      double xyz[3];
      table.Lookup(double(temperature_k[v]), xyz);
      const std::size_t i = 4 * static_cast<std::size_t>(v);  // 2^30 voxels overflow 32 bits
      fast_[i] = static_cast<float>(sigma * density_per_m3[v]);
      for (int c = 0; c < 3; ++c) fast_[i + 1 + c] = static_cast<float>(xyz[c]);
    }
  } else {
    // The spectra: SpectralBins' kelvin rows over the volume's temperatures, and each voxel's
    // record (spectral_voxels_ in renderer.h): 16 bytes a voxel instead of a row of its own, and
    // the rows it shares with voxels of nearly the same temperature stay in cache.
    const int nbins = bins_->count();
    const int nbp = padded_bins_ = (nbins + kLanes - 1) / kLanes * kLanes;
    int lo = SpectralBins::kMaxTableK, hi = 0;
    // Temperatures beyond SpectralBins' table: two rows for each distinct value, B(T) and the
    // exact dB/dT per kelvin (a uniform stress volume at 1e5 K needs one pair, not one a voxel).
    std::map<float, std::uint32_t> hot;
    for (std::uint32_t v : active_voxels_) {
      const float t = temperature_k[v];
      if (t >= float(SpectralBins::kMaxTableK)) {
        hot.emplace(t, 0);
        continue;
      }
      const int k = t > 0 ? static_cast<int>(t) : 0;
      lo = std::min(lo, k);
      hi = std::max(hi, k);
    }
    const std::size_t kelvin_rows = hi >= lo ? static_cast<std::size_t>(hi - lo + 2) : 0;
    constexpr std::size_t kZeroRows = 2;
    const std::size_t rows = kZeroRows + kelvin_rows + 2 * hot.size();
    if (rows * nbp >= (std::size_t(1) << 32)) {
      throw InputError("SetVolume: " + std::to_string(hot.size()) +
                       " distinct temperatures above " + std::to_string(SpectralBins::kMaxTableK) +
                       " K make the spectral table too large for the renderer");
    }
    spectral_table_.assign(rows * nbp, 0.0f);
    for (std::size_t r = 0; r < kelvin_rows; ++r)
      std::copy_n(bins_->PlanckRow(lo + static_cast<int>(r)), nbins,
                  &spectral_table_[(kZeroRows + r) * nbp]);
    hot_rows_offset_ = (kZeroRows + kelvin_rows) * nbp;
    std::size_t next = kZeroRows + kelvin_rows;
    std::vector<double> b(nbins), d(nbins);
    for (auto& [t, offset] : hot) {
      bins_->PlanckAllWithDerivative(double(t), b.data(), d.data());
      for (int i = 0; i < nbins; ++i) {
        spectral_table_[next * nbp + i] = static_cast<float>(b[i]);
        spectral_table_[(next + 1) * nbp + i] = static_cast<float>(d[i]);
      }
      offset = static_cast<std::uint32_t>(next * nbp);
      next += 2;
    }
    spectral_voxels_.assign(nvox, SpectralVoxel());
    density_unit_ = 0;
    for (const std::uint32_t v : active_voxels_)
      density_unit_ = std::max(density_unit_, density_per_m3[v]);
    if (!(density_unit_ > 0)) density_unit_ = 1;
    for (std::size_t a = 0; a < active_voxels_.size(); ++a) {
      const std::uint32_t v = active_voxels_[a];
      const float t = temperature_k[v];
      SpectralVoxel& record = spectral_voxels_[v];
      record.density = density_per_m3[v] / density_unit_;
      record.slot = static_cast<std::int32_t>(a);
      if (t >= float(SpectralBins::kMaxTableK)) {
        record.offset = hot.at(t);  // fraction 0: the source is the first row, B(T)
      } else if (t > 0) {
        const int k = static_cast<int>(t);
        record.offset = static_cast<std::uint32_t>((kZeroRows + k - lo) * nbp);
        record.fraction = t - float(k);
      }  // T = 0: the zero rows
    }
  }

  // Bricks: occupied when any voxel within one voxel of the brick has density > 0, so that a
  // trilinear sample anywhere inside an unoccupied brick is exactly zero.
  const int b = options_.brick_size_voxels;
  const Eigen::Vector3i& d = geometry_.dims;
  brick_dims_ = Eigen::Vector3i((d.x() + b - 1) / b, (d.y() + b - 1) / b, (d.z() + b - 1) / b);
  brick_occupied_.assign(static_cast<std::size_t>(brick_dims_.prod()), 0);
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i) {
        if (!(density_per_m3[geometry_.Flat(i, j, k)] > 0)) continue;
        for (int dk = -1; dk <= 1; ++dk)
          for (int dj = -1; dj <= 1; ++dj)
            for (int di = -1; di <= 1; ++di) {
              int ii = std::clamp(i + di, 0, d.x() - 1), jj = std::clamp(j + dj, 0, d.y() - 1),
                  kk = std::clamp(k + dk, 0, d.z() - 1);
              brick_occupied_[(ii / b) +
                              brick_dims_.x() * ((jj / b) + brick_dims_.y() * (kk / b))] = 1;
            }
      }
  std::size_t occupied = std::count(brick_occupied_.begin(), brick_occupied_.end(), 1);
  occupied_brick_fraction_ =
      brick_occupied_.empty() ? 0.0 : double(occupied) / brick_occupied_.size();
  has_volume_ = true;
}

namespace {

// exp(x) for float in plain arithmetic (Cephes-style range reduction and polynomial, relative error
// about 2e-7), so that the spectral loop over wavelength bins vectorises; libm's expf does not.
inline float VectorExp(float x) {
  x = x < -87.0f ? -87.0f : x;
  x = x > 88.0f ? 88.0f : x;
  // Round to nearest with the 1.5 * 2^23 trick (vectorises on plain SSE2, unlike nearbyint).
  const float k = (x * 1.44269504088896341f + 12582912.0f) - 12582912.0f;
  const float r = x - k * 0.693359375f + k * 2.12194440e-4f;
  float p = 1.9875691500e-4f;
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  p = p * r * r + r + 1.0f;
  const std::int32_t bits = (static_cast<std::int32_t>(k) + 127) << 23;
  return p * std::bit_cast<float>(bits);
}
inline double VectorExp(double x) { return std::exp(x); }

// 1 - exp(-tau) for tau >= 0 without cancellation at small tau (series below 1e-2). kThin: the
// caller knows tau < 1e-2 (the series alone, the same value without the exponential).
template <bool kThin = false, typename Real>
inline Real OneMinusExpNeg(Real tau) {
  const Real series =
      tau * (Real(1) - tau * (Real(0.5) - tau * (Real(1) / 6 - tau * (Real(1) / 24))));
  if constexpr (kThin) return series;
  const Real direct = Real(1) - VectorExp(-tau);  // both computed: a select, not a branch
  return tau < Real(1e-2) ? series : direct;
}

// phi(tau) = (1 - exp(-tau)) / tau and tau * phi'(tau) = exp(-tau) - phi(tau), for tau >= 0,
// without cancellation or 0/0 at small tau (series below 1e-2 and 0.1).
template <typename Real>
inline void PhiAndTauDPhi(Real tau, Real* phi, Real* tau_dphi) {
  const Real phi_series = Real(1) - tau * (Real(0.5) - tau * (Real(1) / 6 - tau * (Real(1) / 24)));
  *phi = tau < Real(1e-2) ? phi_series : OneMinusExpNeg(tau) / tau;
  const Real series =
      tau *
      (Real(-0.5) +
       tau * (Real(1) / 3 + tau * (Real(-1) / 8 + tau * (Real(1) / 30 - tau * (Real(1) / 144)))));
  const Real direct = VectorExp(-tau) - *phi;
  *tau_dphi = tau < Real(0.1) ? series : direct;
}

// The three terms of a step of optical depth tau >= 0 that the adjoint needs, from one
// exponential: 1 - exp(-tau), phi(tau) and tau * phi'(tau) (as OneMinusExpNeg and PhiAndTauDPhi).
// kThin: the caller knows tau < 1e-2, where all three are their series (the same values, without
// the exponential).
template <bool kThin = false, typename Real>
inline void StepTerms(Real tau, Real* absorbed, Real* phi, Real* tau_dphi) {
  if constexpr (kThin) {
    *absorbed = tau * (Real(1) - tau * (Real(0.5) - tau * (Real(1) / 6 - tau * (Real(1) / 24))));
    *phi = Real(1) - tau * (Real(0.5) - tau * (Real(1) / 6 - tau * (Real(1) / 24)));
    *tau_dphi =
        tau *
        (Real(-0.5) +
         tau * (Real(1) / 3 + tau * (Real(-1) / 8 + tau * (Real(1) / 30 - tau * (Real(1) / 144)))));
    return;
  }
  const Real e = VectorExp(-tau);
  const Real absorbed_series =
      tau * (Real(1) - tau * (Real(0.5) - tau * (Real(1) / 6 - tau * (Real(1) / 24))));
  *absorbed = tau < Real(1e-2) ? absorbed_series : Real(1) - e;
  const Real phi_series = Real(1) - tau * (Real(0.5) - tau * (Real(1) / 6 - tau * (Real(1) / 24)));
  *phi = tau < Real(1e-2) ? phi_series : *absorbed / tau;
  const Real series =
      tau *
      (Real(-0.5) +
       tau * (Real(1) / 3 + tau * (Real(-1) / 8 + tau * (Real(1) / 30 - tau * (Real(1) / 144)))));
  *tau_dphi = tau < Real(0.1) ? series : e - *phi;
}

}  // namespace

struct FireRenderer::MarchCounters {
  std::int64_t hit = 0, early = 0, evaluated = 0, skipped = 0, after = 0;
};

RenderSummary FireRenderer::Summarise(std::chrono::steady_clock::time_point start,
                                      std::int64_t rays, int bins,
                                      const MarchCounters& totals) const {
  RenderSummary summary;
  summary.path_used = path_;
  summary.path_reason = path_reason_;
  summary.spectral_bins = bins;
  summary.rays = rays;
  summary.rays_hit_box = totals.hit;
  summary.rays_terminated_early = totals.early;
  summary.steps_evaluated = totals.evaluated;
  summary.steps_skipped_empty = totals.skipped;
  summary.steps_after_termination = totals.after;
  summary.occupied_brick_fraction = occupied_brick_fraction_;
  summary.time_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

template <typename Real, typename Visit>
void FireRenderer::MarchRay(const RayMarch& march, MarchCounters* c, Visit&& visit) const {
  const GridGeometry& g = geometry_;
  const std::size_t nx = g.dims.x(), nxy = nx * g.dims.y();
  const std::int64_t n_steps = march.n_steps;
  const Eigen::Vector3d& o = march.origin_index;
  const Eigen::Vector3d& d = march.direction_index;
  // Both paths' voxel records are 16 bytes (fast_, spectral_voxels_). The corner loads' latency
  // bounds the fast path (perf: the first corner's load stalled it most), so the four cache lines
  // of the cell four steps ahead are prefetched while this step is evaluated (a prefetch never
  // faults; the cell is clamped to the grid).
  static_assert(sizeof(SpectralVoxel) == 4 * sizeof(float));
  const char* records = path_ == SpectralPath::kFast
                            ? reinterpret_cast<const char*>(fast_.data())
                            : reinterpret_cast<const char*>(spectral_voxels_.data());
  // The cell's lower corner is clamped as TrilinearStencil clamps it, and its upper rows exist
  // only where the grid has them, so no address lies outside the records.
  const int low_max[3] = {std::max(g.dims.x() - 2, 0), std::max(g.dims.y() - 2, 0),
                          std::max(g.dims.z() - 2, 0)};
  const std::size_t up_j = g.dims.y() > 1 ? nx : 0, up_k = g.dims.z() > 1 ? nxy : 0;
  auto prefetch = [&](const Eigen::Vector3d& p) {
    const int i = std::clamp(static_cast<int>(p.x()), 0, low_max[0]);
    const int j = std::clamp(static_cast<int>(p.y()), 0, low_max[1]);
    const int kk = std::clamp(static_cast<int>(p.z()), 0, low_max[2]);
    const char* base = records + 16 * (i + nx * j + nxy * kk);
    __builtin_prefetch(base);
    __builtin_prefetch(base + 16 * up_j);
    __builtin_prefetch(base + 16 * up_k);
    __builtin_prefetch(base + 16 * (up_j + up_k));
  };
  // Evaluates steps [k, end); false when the visitor stopped the ray.
  auto evaluate = [&](std::int64_t k, std::int64_t end) {
    for (; k < end; ++k) {
      double step_length;
      Eigen::Vector3d p;
      march.Step(k, &step_length, &p);
      prefetch(p + (4 * march.step_m) * d);
      const TrilinearStencil<Real> s(g.dims, Real(p.x()), Real(p.y()), Real(p.z()));
      std::size_t corner[8];
      Real weight[8];
      s.Corners(nx, nxy, corner, weight);
      ++c->evaluated;
      if (!visit(Real(step_length), corner, weight)) {
        ++c->early;
        c->after += n_steps - k - 1;
        return false;
      }
    }
    return true;
  };
  if (!options_.skip_empty_space) {
    evaluate(0, n_steps);
    return;
  }
  // The bricks along the ray, in order, by a 3D DDA (Amanatides and Woo): from the brick of the
  // first step's midpoint, each next brick is the neighbour across the face the ray leaves by,
  // found by comparing the distances to the three next faces, which each grow by a constant. A
  // brick's steps are those whose midpoints lie before its exit face: every step but the last is
  // full, its midpoint at t_enter + (k + 1/2) step_m; the last, shortened to end at t_exit, has its
  // own midpoint, up to half a step earlier (more than the dilation covers when steps exceed a
  // voxel), so it is placed by that. Rounding may move a step across a face by a hair; the bricks'
  // one-voxel dilation (SetVolume) covers that, so skipping stays exact. Past the grid's last brick
  // along an axis (the ray leaving the box by that face, or rounding), samples are clamped to the
  // border layer, which the last brick holds: that axis stops moving and the others go on.
  const int brick = options_.brick_size_voxels;
  int b[3], b_step[3];
  double t_face[3], t_delta[3];
  {
    double length;
    Eigen::Vector3d p;
    march.Step(0, &length, &p);
    for (int a = 0; a < 3; ++a) {
      b[a] = std::clamp(static_cast<int>(std::floor((p[a] + 0.5) / brick)), 0, brick_dims_[a] - 1);
      if (d[a] > 0) {
        b_step[a] = 1;
        t_face[a] = ((b[a] + 1) * brick - 0.5 - o[a]) / d[a];
        t_delta[a] = brick / d[a];
      } else if (d[a] < 0) {
        b_step[a] = -1;
        t_face[a] = (b[a] * brick - 0.5 - o[a]) / d[a];
        t_delta[a] = -brick / d[a];
      } else {
        b_step[a] = 0;
        t_face[a] = std::numeric_limits<double>::infinity();
        t_delta[a] = 0;
      }
    }
  }
  const std::size_t bx = brick_dims_.x(), bxy = bx * brick_dims_.y();
  std::size_t flat = b[0] + bx * b[1] + bxy * b[2];
  const std::ptrdiff_t flat_step[3] = {b_step[0], b_step[1] * std::ptrdiff_t(bx),
                                       b_step[2] * std::ptrdiff_t(bxy)};
  double last_midpoint;  // the last step's, along the ray
  {
    double length;
    Eigen::Vector3d p;
    march.Step(n_steps - 1, &length, &p);
    last_midpoint = march.t_exit - 0.5 * length;
  }
  std::int64_t k = 0;
  while (k < n_steps) {
    const int a =
        t_face[0] < t_face[1] ? (t_face[0] < t_face[2] ? 0 : 2) : (t_face[1] < t_face[2] ? 1 : 2);
    // The first step whose midpoint lies at or beyond the exit face.
    std::int64_t end = std::max(k, march.FirstStepAfter(t_face[a]));
    if (end == n_steps - 1 && last_midpoint < t_face[a]) end = n_steps;
    if (end > k) {
      if (brick_occupied_[flat]) {
        if (!evaluate(k, end)) return;
      } else {
        c->skipped += end - k;
      }
      k = end;
    }
    if (k >= n_steps) return;
    const int nb = b[a] + b_step[a];
    if (nb < 0 || nb >= brick_dims_[a]) {
      t_face[a] = std::numeric_limits<double>::infinity();  // clamped: this axis stays
      continue;
    }
    b[a] = nb;
    flat += flat_step[a];
    t_face[a] += t_delta[a];
  }
}

// Source per bin at a sample: emission / kappa = sum w n B_b(T) / sum w n, an average of the
// corners' Planck spectra weighted by w * n, each spectrum interpolated in the kelvin table
// (SetVolume). GatherCorners reads the eight corners' records and returns the sample's density
// n_sample = sum w n; when it is > 0, it gives each corner's row and, with u = w n / unit (unit =
// density_unit_: the records' densities are at most 1, so the sums stay below eight times the
// table's largest value whatever the densities), the weights of that row, u0 = u (1 - fraction),
// and of the next, u1 = u fraction (all eight: a corner without medium has u = 0 and the zero
// rows), from which SourceGroups below forms S_b n_sample / unit 24 bins at a time, in registers:
// two multiply-adds a corner, u0 row + u1 next_row, the table's linear interpolation as a sum of
// two non-negative terms. The steps (AdvanceLanes) fold the factor unit / n_sample into the
// step's sigma_b ds, with no division where the step is thin.
template <typename Real>
inline Real FireRenderer::GatherCorners(const std::size_t* corner, const Real* weight,
                                        std::int32_t* slot, const float** rows, Real* u0,
                                        Real* u1) const {
  Real n_scaled = 0;
  for (int n = 0; n < 8; ++n) {
    const SpectralVoxel& v = spectral_voxels_[corner[n]];
    slot[n] = v.slot;
    rows[n] = &spectral_table_[v.offset];
    const Real u = weight[n] * Real(v.density);  // w n / unit
    u1[n] = u * Real(v.fraction);
    u0[n] = u - u1[n];
    n_scaled += u;
  }
  return n_scaled * Real(density_unit_);
}

template <typename Real>
inline bool FireRenderer::FastSample(const std::size_t* corner, const Real* weight, Real* kappa,
                                     Real* source) const {
  // u = w kappa_corner; the source is sum u XYZ / sum u, an average that never overflows. One
  // division a sample, not one a corner, unless sum u is so small that its reciprocal overflows.
  Real u[8];
  const float* v[8];
  *kappa = 0;
  for (int n = 0; n < 8; ++n) {
    v[n] = &fast_[4 * corner[n]];
    u[n] = weight[n] * Real(v[n][0]);
    *kappa += u[n];
  }
  if (!(*kappa > Real(0))) return false;
  const Real inverse = Real(1) / *kappa;
  if (inverse <= std::numeric_limits<Real>::max()) {
    for (int n = 0; n < 8; ++n) u[n] *= inverse;
  } else {
    for (int n = 0; n < 8; ++n) u[n] /= *kappa;
  }
  if constexpr (std::is_same_v<Real, float>) {
    // The records as 4-float vectors: one multiply-add a corner (lane 0, kappa, unused).
    typedef float Float4 __attribute__((vector_size(16)));
    Float4 acc = {0, 0, 0, 0};
    for (int n = 0; n < 8; ++n) {
      Float4 record;
      std::memcpy(&record, v[n], sizeof record);
      acc += u[n] * record;
    }
    source[0] = acc[1];
    source[1] = acc[2];
    source[2] = acc[3];
  } else {
    Real s0 = 0, s1 = 0, s2 = 0;
    for (int n = 0; n < 8; ++n) {
      s0 += u[n] * Real(v[n][1]);
      s1 += u[n] * Real(v[n][2]);
      s2 += u[n] * Real(v[n][3]);
    }
    source[0] = s0;
    source[1] = s1;
    source[2] = s2;
  }
  return true;
}

namespace {

// Eight bins at a time, as GCC vector types (lanes.h's role, kept here: the spectral kernels are
// their only user). Explicit vectors rather than loops left to the auto-vectoriser, which kept or
// dropped these loops depending on how they were inlined. The AVX2 build (RenderRowsWide) puts
// one in a register; the baseline build uses two SSE registers.
template <typename Real>
struct LaneType;
template <>
struct LaneType<float> {
  typedef float type __attribute__((vector_size(32)));
  typedef std::int32_t mask __attribute__((vector_size(32)));
};
template <>
struct LaneType<double> {
  typedef double type __attribute__((vector_size(64)));
  typedef std::int64_t mask __attribute__((vector_size(64)));
};
template <typename Real>
using Lanes = typename LaneType<Real>::type;
constexpr int kVectorLanes = 8;

template <typename Real>
inline Lanes<Real> LoadLanes(const Real* p) {
  Lanes<Real> v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
template <typename Real>
inline Lanes<Real> LoadFloatLanes(const float* p) {
  if constexpr (std::is_same_v<Real, float>) {
    return LoadLanes(p);
  } else {
    return __builtin_convertvector(LoadLanes(p), Lanes<Real>);
  }
}
template <typename Real>
inline void StoreLanes(Real* p, const Lanes<Real>& v) {
  std::memcpy(p, &v, sizeof v);
}
template <typename Real>
inline Lanes<Real> Broadcast(Real x) {
  return Lanes<Real>{} + x;
}
template <typename Real>
inline Real SumOf(const Lanes<Real>& v) {
  Real m = v[0];
  for (int l = 1; l < kVectorLanes; ++l) m += v[l];
  return m;
}

// exp(x) lane by lane: VectorExp's polynomial for float (the same operations in the same order,
// so the same values), std::exp for double.
inline Lanes<float> ExpLanes(Lanes<float> x) {
  typedef LaneType<float>::mask Int;
  x = x < -87.0f ? Broadcast(-87.0f) : x;
  x = x > 88.0f ? Broadcast(88.0f) : x;
  const Lanes<float> k = (x * 1.44269504088896341f + 12582912.0f) - 12582912.0f;
  const Lanes<float> r = x - k * 0.693359375f + k * 2.12194440e-4f;
  Lanes<float> p = Broadcast(1.9875691500e-4f);
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  p = p * r * r + r + 1.0f;
  const Int bits = (__builtin_convertvector(k, Int) + 127) << 23;
  Lanes<float> scale;
  std::memcpy(&scale, &bits, sizeof scale);
  return p * scale;
}
inline Lanes<double> ExpLanes(Lanes<double> x) {
  for (int l = 0; l < kVectorLanes; ++l) x[l] = std::exp(x[l]);
  return x;
}

// OneMinusExpNeg and StepTerms lane by lane (the same series and thresholds).
template <bool kThin, typename Real>
inline Lanes<Real> OneMinusExpNegLanes(const Lanes<Real>& tau) {
  const Lanes<Real> series =
      tau * (Real(1) - tau * (Real(0.5) - tau * (Real(1) / 6 - tau * (Real(1) / 24))));
  if constexpr (kThin) {
    return series;
  } else {
    const Lanes<Real> direct = Real(1) - ExpLanes(-tau);
    return tau < Real(1e-2) ? series : direct;
  }
}
template <bool kThin, typename Real>
inline void StepTermsLanes(const Lanes<Real>& tau, Lanes<Real>* absorbed, Lanes<Real>* phi,
                           Lanes<Real>* tau_dphi) {
  const Lanes<Real> absorbed_series =
      tau * (Real(1) - tau * (Real(0.5) - tau * (Real(1) / 6 - tau * (Real(1) / 24))));
  const Lanes<Real> phi_series =
      Real(1) - tau * (Real(0.5) - tau * (Real(1) / 6 - tau * (Real(1) / 24)));
  const Lanes<Real> dphi_series =
      tau *
      (Real(-0.5) +
       tau * (Real(1) / 3 + tau * (Real(-1) / 8 + tau * (Real(1) / 30 - tau * (Real(1) / 144)))));
  if constexpr (kThin) {
    *absorbed = absorbed_series;
    *phi = phi_series;
    *tau_dphi = dphi_series;
  } else {
    const Lanes<Real> e = ExpLanes(-tau);
    const auto thin = tau < Real(1e-2);
    *absorbed = thin ? absorbed_series : Real(1) - e;
    *phi = thin ? phi_series : *absorbed / tau;
    *tau_dphi = tau < Real(0.1) ? dphi_series : e - *phi;
  }
}

// The sample's source S_b = sum over corners of u B_b(T) for the bins [b0, b0 + 8 G), from the
// corners' kelvin-table rows (GatherCorners), into source[0, G): the corners outside, the G
// groups of eight bins inside, so that each corner's two weights are broadcast once and stay in
// registers with the G sums (with the groups outside, a 24-bin ray kept 16 broadcast weights,
// more than the 16 vector registers hold with everything else, and reloaded them from the stack
// for every group). Each bin's sum runs over the corners in the same order either way, so the
// values are the same: this and the clearest bin's early stop (BinCrossSections) made the 128^3
// soot view with the fit's 21 bins 2.5% faster (paired runs on an AMD EPYC, 2026-11-28) and left
// its image unchanged to the bit.
template <int G, typename Real>
inline void SourceGroups(const float* const* rows, const Real* u0, const Real* u1, int b0,
                         int row_length, Lanes<Real>* source) {
  Lanes<Real> acc[G];
  for (int g = 0; g < G; ++g) acc[g] = Lanes<Real>{};
  for (int i = 0; i < 8; ++i) {
    const float* row = rows[i] + b0;
    for (int g = 0; g < G; ++g) {
      acc[g] += u0[i] * LoadFloatLanes<Real>(row + kVectorLanes * g);
      acc[g] += u1[i] * LoadFloatLanes<Real>(row + kVectorLanes * g + row_length);
    }
  }
  for (int g = 0; g < G; ++g) source[g] = acc[g];
}

// Calls step(b0, source of the bins [b0, b0 + 8)) for every group of eight bins of the nbp padded
// ones, in order, the sources formed three groups (24 bins, the fit's 21) at a time.
template <typename Real, typename Step>
inline void ForEachSourceGroup(int nbp, const float* const* rows, const Real* u0, const Real* u1,
                               Step&& step) {
  constexpr int kGroups = 3;
  Lanes<Real> source[kGroups];
  int b0 = 0;
  for (; b0 + kGroups * kVectorLanes <= nbp; b0 += kGroups * kVectorLanes) {
    SourceGroups<kGroups, Real>(rows, u0, u1, b0, nbp, source);
    for (int g = 0; g < kGroups; ++g) step(b0 + kVectorLanes * g, source[g]);
  }
  const int rest = (nbp - b0) / kVectorLanes;
  if (rest == 2) {
    SourceGroups<2, Real>(rows, u0, u1, b0, nbp, source);
  } else if (rest == 1) {
    SourceGroups<1, Real>(rows, u0, u1, b0, nbp, source);
  }
  for (int g = 0; g < rest; ++g) step(b0 + kVectorLanes * g, source[g]);
}

// A spectral ray's cross-sections per padded bin (the padding's zero) into sigma, and their
// largest into *sigma_max (a step is thin when it is). Returns the clearest bin: the one with the
// smallest cross-section among the first nbins (the first of equal ones). Every step multiplies
// each bin's transmittance by exp(-sigma_b n ds) (or its series), with the same n ds in every bin,
// so this bin's transmittance is the largest of all at every step: the steps below return it for
// the ray's early stop instead of reducing their lanes to a maximum. The padding's transmittance
// is zero.
template <typename Real>
inline int BinCrossSections(const std::vector<double>& cross_sections, int nbins, int nbp,
                            Real* sigma, Real* sigma_max) {
  *sigma_max = 0;
  int clearest = 0;
  for (int b = 0; b < nbp; ++b) {
    sigma[b] = b < nbins ? Real(cross_sections[b]) : Real(0);
    *sigma_max = std::max(*sigma_max, sigma[b]);
    if (b < nbins && sigma[b] < sigma[clearest]) clearest = b;
  }
  return clearest;
}

// One group of eight bins' step from the source GatherCorners' weights give (S_b n / unit, unit
// = density_unit_): the radiance it adds, Tr_b (1 - exp(-tau_b)) S_b with tau_b = sigma_b n ds, and
// the transmittance after it. The render and the adjoints' second passes all step through here, so
// that the latter retrace the former's radiance and transmittance to the bit (what is left behind
// a sample, the total less the radiance so far, is then exactly zero at the ray's end). kThin:
// tau_b < 1e-2 in every bin, where 1 - exp(-tau) = tau phi(tau) with phi its series 1 - tau / 2 +
// tau^2 / 6 - tau^3 / 24, and the step adds Tr_b phi (sigma_b ds unit) (S_b n / unit): no
// exponential and no division (a division a sample took 3% of the soot view's time). Otherwise
// 1 - exp(-tau) itself times S_b, `per_source` = unit / n. `factor` is phi where kThin, else
// 1 - exp(-tau): StepFactorLanes, or StepTermsLanes' phi and absorbed, the same values.
template <bool kThin, typename Real>
inline void AdvanceLanes(const Lanes<Real>& sig, const Lanes<Real>& tau, const Lanes<Real>& tr,
                         const Lanes<Real>& source, const Lanes<Real>& factor, Real ds_unit,
                         Real per_source, Lanes<Real>* added, Lanes<Real>* tr_after) {
  if constexpr (kThin) {
    const Lanes<Real> tr_phi = tr * factor;
    *added = tr_phi * (sig * ds_unit) * source;
    *tr_after = tr - tr_phi * tau;
  } else {
    const Lanes<Real> w = tr * factor;
    *added = w * (source * per_source);
    *tr_after = tr - w;
  }
}

// AdvanceLanes' factor for a step that needs nothing else: phi's series where kThin (as
// StepTermsLanes writes it), else 1 - exp(-tau).
template <bool kThin, typename Real>
inline Lanes<Real> StepFactorLanes(const Lanes<Real>& tau) {
  if constexpr (kThin) {
    return Real(1) - tau * (Real(0.5) - tau * (Real(1) / 6 - tau * (Real(1) / 24)));
  } else {
    return OneMinusExpNegLanes<false, Real>(tau);
  }
}

// One step of a spectral ray, every bin: L_b += Tr_b (1 - exp(-sigma_b n ds)) S_b, Tr_b likewise
// reduced (AdvanceLanes); returns the largest transmittance, the `clearest` bin's
// (BinCrossSections).
template <bool kThin, typename Real>
inline Real SpectralStep(int nbp, int clearest, const float* const* rows, const Real* u0,
                         const Real* u1, const Real* sigma, Real n_sample, Real unit, Real ds,
                         Real* radiance, Real* transmittance) {
  const Real n_ds = n_sample * ds, ds_unit = ds * unit;
  const Real per_source = kThin ? Real(0) : unit / n_sample;
  ForEachSourceGroup<Real>(nbp, rows, u0, u1, [&](int b0, const Lanes<Real>& source) {
    const Lanes<Real> sig = LoadLanes(sigma + b0);
    const Lanes<Real> tau = sig * n_ds;
    Lanes<Real> added, tr;
    AdvanceLanes<kThin, Real>(sig, tau, LoadLanes(transmittance + b0), source,
                              StepFactorLanes<kThin, Real>(tau), ds_unit, per_source, &added, &tr);
    StoreLanes(radiance + b0, LoadLanes(radiance + b0) + added);
    StoreLanes(transmittance + b0, tr);
  });
  return transmittance[clearest];
}

// The step the adjoint's second pass and the curvature's share: every bin's transmittance and
// cumulative radiance advanced as the render advanced them (AdvanceLanes), and for each group of
// bins `use(b0, sig, tr, phi, n_term)`, with Tr the transmittance before the step and n_term =
// Tr tau phi' S_b - behind_b (behind_b: the radiance the ray gathers after this step), from which
// dE_b = sigma_b Tr ds phi and dn = sigma_b ds n_term per unit adjoint. The weights are
// GatherCorners', as for SpectralStep. Returns the clearest bin's transmittance after the step.
template <bool kThin, typename Real, typename Use>
inline Real SpectralAdjointTerms(int nbp, int clearest, const float* const* rows, const Real* u0,
                                 const Real* u1, const Real* sigma, const Real* total,
                                 Real n_sample, Real unit, Real ds, Real* cumulative,
                                 Real* transmittance, Use&& use) {
  const Real n_ds = n_sample * ds, ds_unit = ds * unit, per_source = unit / n_sample;
  ForEachSourceGroup<Real>(nbp, rows, u0, u1, [&](int b0, const Lanes<Real>& source) {
    const Lanes<Real> sig = LoadLanes(sigma + b0);
    const Lanes<Real> tau = sig * n_ds;
    Lanes<Real> absorbed, phi, tau_dphi;
    StepTermsLanes<kThin, Real>(tau, &absorbed, &phi, &tau_dphi);
    const Lanes<Real> tr = LoadLanes(transmittance + b0);
    Lanes<Real> added, tr_after;
    AdvanceLanes<kThin, Real>(sig, tau, tr, source, kThin ? phi : absorbed, ds_unit, per_source,
                              &added, &tr_after);
    const Lanes<Real> cum = LoadLanes(cumulative + b0) + added;
    StoreLanes(cumulative + b0, cum);
    const Lanes<Real> behind = LoadLanes(total + b0) - cum;
    use(b0, sig, tr, phi, tr * tau_dphi * (source * per_source) - behind);
    StoreLanes(transmittance + b0, tr_after);
  });
  return transmittance[clearest];
}

// The adjoint's step on a spectral ray (GradientRows, pass 2): d_emission[b] = sigma_b dLoss/dE_b,
// and the absorption's part of dLoss/dn summed over bins into *d_n; returns the clearest bin's
// transmittance (SpectralAdjointTerms).
template <bool kThin, typename Real>
inline Real SpectralAdjointStep(int nbp, int clearest, const float* const* rows, const Real* u0,
                                const Real* u1, const Real* sigma, const Real* adjoint,
                                const Real* total, Real n_sample, Real unit, Real ds,
                                Real* cumulative, Real* transmittance, Real* d_emission,
                                Real* d_n) {
  Lanes<Real> dn{};
  const Real tr_clearest = SpectralAdjointTerms<kThin, Real>(
      nbp, clearest, rows, u0, u1, sigma, total, n_sample, unit, ds, cumulative, transmittance,
      [&](int b0, const Lanes<Real>& sig, const Lanes<Real>& tr, const Lanes<Real>& phi,
          const Lanes<Real>& n_term) {
        const Lanes<Real> sig_adj = sig * LoadLanes(adjoint + b0);
        StoreLanes(d_emission + b0, sig_adj * tr * ds * phi);
        dn += sig_adj * ds * n_term;
      });
  *d_n = SumOf<Real>(dn);
  return tr_clearest;
}

// The adjoint's step without its adjoint (RenderCurvature): what SpectralAdjointStep multiplies by
// the adjoint, per bin: e_factor[b] = sigma_b Tr ds phi (d_emission = adjoint * e_factor) and
// n_factor[b] = sigma_b ds n_term (d_n = sum_b adjoint_b n_factor[b]); returns the clearest bin's
// transmittance.
template <bool kThin, typename Real>
inline Real SpectralFactorStep(int nbp, int clearest, const float* const* rows, const Real* u0,
                               const Real* u1, const Real* sigma, const Real* total, Real n_sample,
                               Real unit, Real ds, Real* cumulative, Real* transmittance,
                               Real* e_factor, Real* n_factor) {
  return SpectralAdjointTerms<kThin, Real>(
      nbp, clearest, rows, u0, u1, sigma, total, n_sample, unit, ds, cumulative, transmittance,
      [&](int b0, const Lanes<Real>& sig, const Lanes<Real>& tr, const Lanes<Real>& phi,
          const Lanes<Real>& n_term) {
        StoreLanes(e_factor + b0, sig * tr * ds * phi);
        StoreLanes(n_factor + b0, sig * ds * n_term);
      });
}

// de[b] += weight * d_emission[b] over the padded bins.
template <typename Real>
inline void AddScaledLanes(int nbp, Real weight, const Real* d_emission, Real* de) {
  for (int b0 = 0; b0 < nbp; b0 += kVectorLanes)
    StoreLanes(de + b0, LoadLanes(de + b0) + weight * LoadLanes(d_emission + b0));
}

}  // namespace

// What every row of one render shares (RenderImpl -> RenderRows).
struct FireRenderer::RenderJob {
  const CameraRays* rays = nullptr;
  ImageF* linear_rgb = nullptr;
  const std::vector<float>* max_distance_m = nullptr;
  ImageF* transmittance_rgb = nullptr;
  Eigen::Vector3d weight_sum = Eigen::Vector3d::Zero();  // spectral: the bins' weights per channel
  double step_m = 0;
  double min_transmittance = 0;
  bool spectral = false;
  int nbins = 3;
  Eigen::Matrix3d to_rgb = Eigen::Matrix3d::Identity();
};

template <typename Real>
RenderSummary FireRenderer::RenderImpl(const CameraRays& camera_rays, ImageF* linear_rgb,
                                       const std::vector<float>* max_distance_m,
                                       ImageF* transmittance_rgb) const {
  const auto start = std::chrono::steady_clock::now();
  const int width = camera_rays.width(), height = camera_rays.height();
  *linear_rgb = ImageF(width, height, 3, 0.0f);
  if (transmittance_rgb) *transmittance_rgb = ImageF(width, height, 3, 1.0f);
  RenderJob job;
  job.rays = &camera_rays;
  job.linear_rgb = linear_rgb;
  job.max_distance_m = max_distance_m;
  job.transmittance_rgb = transmittance_rgb;
  job.spectral = path_ == SpectralPath::kSpectral;
  job.nbins = job.spectral ? bins_->count() : 3;
  // Per channel, the colour matching weights of the bins (spectral transmittance to RGB).
  if (job.spectral)
    for (int b = 0; b < bins_->count(); ++b) job.weight_sum += bins_->weight(b);
  job.step_m = options_.step_voxels * geometry_.voxel_size_m.minCoeff();
  job.min_transmittance = options_.min_transmittance;
  job.to_rgb = response_->output_from_basis();
  const bool wide = std::is_same_v<Real, float> && options_.wide_kernels && UseWideKernels();

  std::atomic<std::int64_t> hit{0}, early{0}, evaluated{0}, skipped{0}, after{0};
  tbb::parallel_for(tbb::blocked_range<int>(0, height), [&](const tbb::blocked_range<int>& rows) {
    MarchCounters c;
    if constexpr (std::is_same_v<Real, float>) {
      if (wide)
        RenderRowsWide(job, rows.begin(), rows.end(), &c);
      else
        RenderRows<float>(job, rows.begin(), rows.end(), &c);
    } else {
      RenderRows<Real>(job, rows.begin(), rows.end(), &c);
    }
    hit += c.hit;
    early += c.early;
    evaluated += c.evaluated;
    skipped += c.skipped;
    after += c.after;
  });

  RenderSummary summary = Summarise(start, static_cast<std::int64_t>(width) * height, job.nbins,
                                    MarchCounters{hit, early, evaluated, skipped, after});
  summary.wide_kernels = wide;
  return summary;
}

// The AVX2 + FMA build of the float kernel: everything RenderRows calls is inlined into it
// (flatten), so the whole ray march is compiled for the wider instructions.
__attribute__((target("avx2,fma"), flatten)) void FireRenderer::RenderRowsWide(
    const RenderJob& job, int y0, int y1, MarchCounters* c) const {
  RenderRows<float>(job, y0, y1, c);
}

template <typename Real>
void FireRenderer::RenderRows(const RenderJob& job, int y0, int y1, MarchCounters* counters) const {
  const CameraRays& camera_rays = *job.rays;
  ImageF* linear_rgb = job.linear_rgb;
  const std::vector<float>* max_distance_m = job.max_distance_m;
  ImageF* transmittance_rgb = job.transmittance_rgb;
  const GridGeometry& g = geometry_;
  const int width = camera_rays.width();
  const double step_m = job.step_m;
  const Real min_tr = Real(job.min_transmittance);
  const bool spectral = job.spectral;
  const int nbins = job.nbins;
  const Eigen::Matrix3d& to_rgb = job.to_rgb;
  const Eigen::Vector3d& weight_sum = job.weight_sum;
  MarchCounters& c = *counters;
  {
    // Spectral arrays run over the bins padded to a multiple of kLanes: the padding has no
    // absorption, no emission and zero transmittance, so it changes nothing, and every loop over
    // bins is whole vectors (lane-wise sums instead of reductions GCC will not
    // vectorise without reassociating).
    const int nbp = spectral ? padded_bins_ : 3;
    alignas(64) Real radiance[SpectralBins::kMaxBins];
    alignas(64) Real transmittance[SpectralBins::kMaxBins];
    alignas(64) Real sigma[SpectralBins::kMaxBins];
    Real sigma_max = 0;  // the largest cross-section, and the clearest bin (BinCrossSections)
    int clearest = 0;
    if (spectral) clearest = BinCrossSections(bin_cross_section_m2_, nbins, nbp, sigma, &sigma_max);
    for (int y = y0; y < y1; ++y) {
      for (int x = 0; x < width; ++x) {
        RayMarch march;
        if (!RayMarch::Make(g, camera_rays.at(x, y), step_m, &march)) continue;
        if (max_distance_m) {
          // An opaque surface inside or in front of the box ends the march there.
          const double stop = (*max_distance_m)[static_cast<std::size_t>(y) * width + x];
          if (!(stop > march.t_enter)) continue;
          if (stop < march.t_exit) {
            march.t_exit = stop;
            march.n_steps = std::max<std::int64_t>(
                1, static_cast<std::int64_t>(
                       std::ceil((march.t_exit - march.t_enter) / step_m - 1e-9)));
          }
        }
        ++c.hit;
        for (int b = 0; b < nbp; ++b) {
          radiance[b] = Real(0);
          transmittance[b] = b < nbins ? Real(1) : Real(0);
        }
        if (!spectral) {
          MarchRay<Real>(march, &c, [&](Real ds, const std::size_t* corner, const Real* weight) {
            // Interpolate the voxels' absorption kappa and emission kappa * XYZ(T).
            Real kappa, source[3];
            if (!FastSample(corner, weight, &kappa, source)) return true;
            // Constant source over the step: L += Tr * source * (1 - exp(-tau)).
            // A thin step (a candle's, mostly) needs no exponential.
            const Real tau = kappa * ds;
            const Real absorbed =
                tau < Real(1e-2) ? OneMinusExpNeg<true>(tau) : OneMinusExpNeg(tau);
            const Real w = transmittance[0] * absorbed;
            for (int ch = 0; ch < 3; ++ch) radiance[ch] += w * source[ch];
            transmittance[0] -= w;
            return !(transmittance[0] < min_tr);
          });
        } else {
          MarchRay<Real>(march, &c, [&](Real ds, const std::size_t* corner, const Real* weight) {
            std::int32_t slots[8];
            const float* rows[8];
            Real u0[8], u1[8];
            const Real n_sample = GatherCorners(corner, weight, slots, rows, u0, u1);
            if (!(n_sample > Real(0))) return true;
            // A step thin in every bin (a candle's, mostly) needs no exponential.
            const Real unit = Real(density_unit_);
            const Real max_tr =
                sigma_max * n_sample * ds < Real(1e-2)
                    ? SpectralStep<true, Real>(nbp, clearest, rows, u0, u1, sigma, n_sample, unit,
                                               ds, radiance, transmittance)
                    : SpectralStep<false, Real>(nbp, clearest, rows, u0, u1, sigma, n_sample, unit,
                                                ds, radiance, transmittance);
            return !(max_tr < min_tr);
          });
        }
        Eigen::Vector3d xyz;
        if (!spectral) {
          xyz = Eigen::Vector3d(radiance[0], radiance[1], radiance[2]);
        } else {
          xyz.setZero();
          for (int b = 0; b < nbins; ++b) xyz += double(radiance[b]) * bins_->weight(b);
        }
        const Eigen::Vector3d rgb = to_rgb * xyz;
        for (int ch = 0; ch < 3; ++ch) linear_rgb->at(x, y, ch) = static_cast<float>(rgb[ch]);
        if (transmittance_rgb) {
          Eigen::Vector3d tr = Eigen::Vector3d::Constant(double(transmittance[0]));
          if (spectral) {
            tr.setZero();
            for (int b = 0; b < nbins; ++b) tr += double(transmittance[b]) * bins_->weight(b);
            tr = tr.cwiseQuotient(weight_sum);
          }
          for (int ch = 0; ch < 3; ++ch)
            transmittance_rgb->at(x, y, ch) = static_cast<float>(std::clamp(tr[ch], 0.0, 1.0));
        }
      }
    }
  }
}

// What every row of one gradient pass shares (GradientImpl -> GradientRows), and each thread's
// private accumulators.
struct FireRenderer::GradientJob {
  const CameraRays* rays = nullptr;
  const ImageF* d_loss_d_rgb = nullptr;
  // RenderAndGradient: the pixels' gradients come from here, and the radiance goes there.
  const PixelGradient* pixel_gradient = nullptr;
  ImageF* linear_rgb = nullptr;
  Eigen::Matrix3d to_rgb = Eigen::Matrix3d::Identity();
  double step_m = 0;
  double min_transmittance = 0;
  bool spectral = false;
  int nbins = 3;
  Eigen::Matrix3d to_rgb_t =
      Eigen::Matrix3d::Identity();  // rgb = M xyz: dLoss/dxyz = M^T dLoss/drgb
  double grey_sigma = 0;
};
template <typename Real>
struct FireRenderer::GradientBuffers {
  std::vector<double> dt, dn;  // per slot
  // Spectral path: dLoss/d(emission) per slot and (padded) bin, sigma_b included; turned into dT
  // and dn once per voxel at the end (cheaper than a dot product per corner and step).
  std::vector<Real> de;
};

template <typename Real>
RenderSummary FireRenderer::GradientImpl(const CameraRays& camera_rays, const ImageF* d_loss_d_rgb,
                                         const PixelGradient* pixel_gradient, ImageF* linear_rgb,
                                         std::vector<double>* d_temperature,
                                         std::vector<double>* d_density) const {
  const auto start = std::chrono::steady_clock::now();
  const int width = camera_rays.width(), height = camera_rays.height();
  GradientJob job;
  job.rays = &camera_rays;
  job.d_loss_d_rgb = d_loss_d_rgb;
  job.pixel_gradient = pixel_gradient;
  job.linear_rgb = linear_rgb;
  if (linear_rgb) *linear_rgb = ImageF(width, height, 3, 0.0f);
  job.to_rgb = response_->output_from_basis();
  job.step_m = options_.step_voxels * geometry_.voxel_size_m.minCoeff();
  job.min_transmittance = options_.min_transmittance;
  job.spectral = path_ == SpectralPath::kSpectral;
  job.nbins = job.spectral ? bins_->count() : 3;
  job.to_rgb_t = response_->output_from_basis().transpose();
  job.grey_sigma = job.spectral ? 0.0 : absorption_.CrossSectionM2(550.0);
  const bool spectral = job.spectral;
  const int nbins = job.nbins;
  const std::size_t nactive = active_voxels_.size();
  const bool wide = std::is_same_v<Real, float> && options_.wide_kernels && UseWideKernels();

  using Buffers = GradientBuffers<Real>;
  tbb::enumerable_thread_specific<Buffers> buffers;
  std::atomic<std::int64_t> hit{0}, early{0}, evaluated{0}, skipped{0}, after{0};

  tbb::parallel_for(tbb::blocked_range<int>(0, height), [&](const tbb::blocked_range<int>& rows) {
    Buffers& buf = buffers.local();
    if (buf.dt.empty()) {
      buf.dt.assign(nactive, 0.0);
      buf.dn.assign(nactive, 0.0);
      if (spectral) buf.de.assign(nactive * padded_bins_, Real(0));
    }
    MarchCounters c;
    if constexpr (std::is_same_v<Real, float>) {
      if (wide)
        GradientRowsWide(job, rows.begin(), rows.end(), &buf, &c);
      else
        GradientRows<float>(job, rows.begin(), rows.end(), &buf, &c);
    } else {
      GradientRows<Real>(job, rows.begin(), rows.end(), &buf, &c);
    }
    hit += c.hit;
    early += c.early;
    evaluated += c.evaluated;
    skipped += c.skipped;
    after += c.after;
  });

  for (Buffers& buf : buffers) {
    if (buf.dt.empty()) continue;
    if (spectral) {
      // E_b of a voxel is sigma_b n B_b(T): dLoss/dn += sum_b de_b B_b(T), dLoss/dT += n sum_b
      // de_b B_b'(T), with B and B' (per kelvin) from the voxel's rows of the kelvin table.
      const int nbp = padded_bins_;
      tbb::parallel_for(tbb::blocked_range<std::size_t>(0, nactive, 256),
                        [&](const tbb::blocked_range<std::size_t>& r) {
                          for (std::size_t a = r.begin(); a < r.end(); ++a) {
                            const SpectralVoxel& row = spectral_voxels_[active_voxels_[a]];
                            const float* r0 = &spectral_table_[row.offset];
                            const float* r1 = r0 + nbp;
                            // Beyond the kelvin table the second row is dB/dT itself.
                            const bool hot_row = row.offset >= hot_rows_offset_;
                            const Real* de = &buf.de[a * nbp];
                            double dot_b = 0, dot_d = 0;
                            for (int b = 0; b < nbp; ++b) {
                              const double slope =
                                  hot_row ? double(r1[b]) : double(r1[b]) - double(r0[b]);
                              dot_b += double(de[b]) * (double(r0[b]) + row.fraction * slope);
                              dot_d += double(de[b]) * slope;
                            }
                            buf.dn[a] += dot_b;
                            buf.dt[a] += dot_d * density_[active_voxels_[a]];
                          }
                        });
    }
    for (std::size_t a = 0; a < nactive; ++a) {
      (*d_temperature)[active_voxels_[a]] += buf.dt[a];
      (*d_density)[active_voxels_[a]] += buf.dn[a];
    }
  }

  RenderSummary summary = Summarise(start, static_cast<std::int64_t>(width) * height, nbins,
                                    MarchCounters{hit, early, evaluated, skipped, after});
  summary.wide_kernels = wide;
  return summary;
}

// The AVX2 + FMA build of the float adjoint (see RenderRowsWide).
__attribute__((target("avx2,fma"), flatten)) void FireRenderer::GradientRowsWide(
    const GradientJob& job, int y0, int y1, GradientBuffers<float>* buffers,
    MarchCounters* c) const {
  GradientRows<float>(job, y0, y1, buffers, c);
}

template <typename Real>
inline void FireRenderer::MarchRadiance(const RayMarch& march, bool spectral, int nbp,
                                        const Real* sigma, Real sigma_max, int clearest,
                                        Real min_tr, Real* total, Real* transmittance) const {
  MarchCounters ignored;
  if (!spectral) {
    MarchRay<Real>(march, &ignored, [&](Real ds, const std::size_t* corner, const Real* weight) {
      Real kappa, source[3];
      if (!FastSample(corner, weight, &kappa, source)) return true;
      const Real w = transmittance[0] * OneMinusExpNeg(kappa * ds);
      for (int ch = 0; ch < 3; ++ch) total[ch] += w * source[ch];
      transmittance[0] -= w;
      return !(transmittance[0] < min_tr);
    });
    return;
  }
  std::int32_t slots[8];
  const float* rows[8];
  Real u0[8], u1[8];
  MarchRay<Real>(march, &ignored, [&](Real ds, const std::size_t* corner, const Real* weight) {
    const Real n_sample = GatherCorners(corner, weight, slots, rows, u0, u1);
    if (!(n_sample > Real(0))) return true;
    const Real unit = Real(density_unit_);
    const Real max_tr = sigma_max * n_sample * ds < Real(1e-2)
                            ? SpectralStep<true, Real>(nbp, clearest, rows, u0, u1, sigma, n_sample,
                                                       unit, ds, total, transmittance)
                            : SpectralStep<false, Real>(nbp, clearest, rows, u0, u1, sigma,
                                                        n_sample, unit, ds, total, transmittance);
    return !(max_tr < min_tr);
  });
}

template <typename Real>
void FireRenderer::GradientRows(const GradientJob& job, int y0, int y1,
                                GradientBuffers<Real>* buffers, MarchCounters* counters) const {
  const CameraRays& camera_rays = *job.rays;
  const bool fused = job.pixel_gradient != nullptr;
  const GridGeometry& g = geometry_;
  const int width = camera_rays.width();
  const double step_m = job.step_m;
  const Real min_tr = Real(job.min_transmittance);
  const bool spectral = job.spectral;
  const int nbins = job.nbins;
  const Eigen::Matrix3d& to_rgb_t = job.to_rgb_t;
  const double grey_sigma = job.grey_sigma;
  const ChannelResponse& table = *response_;
  GradientBuffers<Real>& buf = *buffers;
  MarchCounters& c = *counters;
  {
    // Spectral arrays are padded as in RenderRows.
    const int nbp = spectral ? padded_bins_ : 3;
    alignas(64) Real total[SpectralBins::kMaxBins], transmittance[SpectralBins::kMaxBins];
    alignas(64) Real cumulative[SpectralBins::kMaxBins], adjoint[SpectralBins::kMaxBins];
    alignas(64) Real sigma[SpectralBins::kMaxBins];
    alignas(64) Real d_emission[SpectralBins::kMaxBins];
    Real sigma_max = 0;  // the largest cross-section, and the clearest bin (BinCrossSections)
    int clearest = 0;
    if (spectral) clearest = BinCrossSections(bin_cross_section_m2_, nbins, nbp, sigma, &sigma_max);
    for (int y = y0; y < y1; ++y) {
      for (int x = 0; x < width; ++x) {
        Eigen::Vector3d g_rgb = Eigen::Vector3d::Zero();
        if (!fused) {
          const ImageF& d_loss_d_rgb = *job.d_loss_d_rgb;
          g_rgb = Eigen::Vector3d(d_loss_d_rgb.at(x, y, 0), d_loss_d_rgb.at(x, y, 1),
                                  d_loss_d_rgb.at(x, y, 2));
          if (g_rgb.isZero()) continue;
        }
        RayMarch march;
        if (!RayMarch::Make(g, camera_rays.at(x, y), step_m, &march)) {
          if (fused) (*job.pixel_gradient)(x, y, Eigen::Vector3d::Zero());
          continue;
        }
        ++c.hit;
        for (int b = 0; b < nbp; ++b) {
          total[b] = cumulative[b] = Real(0);
          transmittance[b] = b < nbins ? Real(1) : Real(0);
        }
        // Pass 2's adjoint per channel or bin, from dLoss/dRGB; false: nothing to march back.
        auto set_adjoint = [&](const Eigen::Vector3d& d_rgb) {
          if (d_rgb.isZero()) return false;
          const Eigen::Vector3d g_xyz = to_rgb_t * d_rgb;
          for (int b = 0; b < nbp; ++b) {
            adjoint[b] = b >= nbins ? Real(0)
                         : spectral ? Real(g_xyz.dot(bins_->weight(b)))
                                    : Real(g_xyz[b]);
          }
          return true;
        };
        // Fused (RenderAndGradient): after pass 1 the pixel is rendered as Render() renders it,
        // and its gradient asked for.
        auto render_pixel = [&]() {
          if (!fused) return true;
          Eigen::Vector3d xyz = Eigen::Vector3d::Zero();
          if (!spectral) {
            xyz = Eigen::Vector3d(total[0], total[1], total[2]);
          } else {
            for (int b = 0; b < nbins; ++b) xyz += double(total[b]) * bins_->weight(b);
          }
          const Eigen::Vector3d rgb = job.to_rgb * xyz;
          for (int ch = 0; ch < 3; ++ch) job.linear_rgb->at(x, y, ch) = static_cast<float>(rgb[ch]);
          // The image holds float radiance: the gradient is of that value, as after Render().
          const Eigen::Vector3d stored(job.linear_rgb->at(x, y, 0), job.linear_rgb->at(x, y, 1),
                                       job.linear_rgb->at(x, y, 2));
          return set_adjoint((*job.pixel_gradient)(x, y, stored));
        };
        if (!fused) set_adjoint(g_rgb);
        if (!spectral) {
          // Pass 1: the ray's radiance.
          MarchRadiance(march, false, nbp, sigma, sigma_max, clearest, min_tr, total,
                        transmittance);
          if (!render_pixel()) continue;
          transmittance[0] = Real(1);
          // Pass 2: the adjoint.
          MarchRay<Real>(march, &c, [&](Real ds, const std::size_t* corner, const Real* weight) {
            Real kappa, source[3];
            if (!FastSample(corner, weight, &kappa, source)) return true;
            Real absorbed, phi, tau_dphi;
            StepTerms(kappa * ds, &absorbed, &phi, &tau_dphi);
            const Real tr = transmittance[0];
            const Real w = tr * absorbed;
            Real d_kappa = 0;
            for (int ch = 0; ch < 3; ++ch) {
              cumulative[ch] += w * source[ch];
              const Real behind = total[ch] - cumulative[ch];
              d_emission[ch] = adjoint[ch] * tr * ds * phi;
              d_kappa += adjoint[ch] * ds * (tr * tau_dphi * source[ch] - behind);
            }
            for (int n = 0; n < 8; ++n) {
              const std::int32_t slot = slot_[corner[n]];
              if (slot < 0 || weight[n] == Real(0)) continue;
              Real xyz[3], d_xyz[3];
              table.LookupWithDerivative(Real(temperature_[corner[n]]), xyz, d_xyz);
              Real dk = d_kappa, dt = 0;
              for (int ch = 0; ch < 3; ++ch) {
                dk += d_emission[ch] * xyz[ch];
                dt += d_emission[ch] * d_xyz[ch];
              }
              buf.dn[slot] += double(weight[n] * dk) * grey_sigma;
              buf.dt[slot] += double(weight[n] * dt * Real(fast_[4 * corner[n]]));
            }
            transmittance[0] -= w;
            return !(transmittance[0] < min_tr);
          });
        } else {
          std::int32_t slots[8];
          const float* rows[8];
          Real u0[8], u1[8];
          auto sample = [&](const std::size_t* corner, const Real* weight, Real* n_sample) {
            *n_sample = GatherCorners(corner, weight, slots, rows, u0, u1);
            return *n_sample > Real(0);
          };
          // Pass 1: the ray's radiance per bin.
          MarchRadiance(march, true, nbp, sigma, sigma_max, clearest, min_tr, total, transmittance);
          if (!render_pixel()) continue;
          for (int b = 0; b < nbp; ++b) transmittance[b] = b < nbins ? Real(1) : Real(0);
          // Pass 2: the adjoint. The emission's part is accumulated per slot and bin (buf.de) and
          // contracted with each voxel's spectrum once, at the end.
          MarchRay<Real>(march, &c, [&](Real ds, const std::size_t* corner, const Real* weight) {
            Real n_sample;
            if (!sample(corner, weight, &n_sample)) return true;
            // d_emission[b] holds sigma_b dLoss/dE_b; d_n the kappa part, summed over bins.
            Real d_n;
            const Real max_tr =
                sigma_max * n_sample * ds < Real(1e-2)
                    ? SpectralAdjointStep<true, Real>(nbp, clearest, rows, u0, u1, sigma, adjoint,
                                                      total, n_sample, Real(density_unit_), ds,
                                                      cumulative, transmittance, d_emission, &d_n)
                    : SpectralAdjointStep<false, Real>(nbp, clearest, rows, u0, u1, sigma, adjoint,
                                                       total, n_sample, Real(density_unit_), ds,
                                                       cumulative, transmittance, d_emission, &d_n);
            for (int n = 0; n < 8; ++n) {
              const std::int32_t slot = slots[n];
              if (slot < 0 || weight[n] == Real(0)) continue;
              buf.dn[slot] += double(weight[n] * d_n);
              Real* de = &buf.de[static_cast<std::size_t>(slot) * nbp];
              AddScaledLanes(nbp, weight[n], d_emission, de);
            }
            return !(max_tr < min_tr);
          });
        }
      }
    }
  }
}

// Each thread's accumulators for RenderCurvature: the 2x2 blocks per slot, and for the ray being
// marched, per voxel it crosses, the per-bin sums of the adjoint's factors (emission part e,
// absorption part n); `local` maps a slot to its place in the ray's lists (-1: not crossed yet).
template <typename Real>
struct FireRenderer::CurvatureBuffers {
  std::vector<double> tt, tn, nn;     // per slot
  std::vector<std::int32_t> local;    // per slot
  std::vector<std::int32_t> touched;  // the ray's slots, in the order first crossed
  std::vector<Real> e, n;             // per touched slot, padded bins
  RayJacobian ray;                    // RenderJacobian: the ray's, handed to its visitor
};

template <typename Real>
RenderSummary FireRenderer::CurvatureImpl(const CameraRays& camera_rays,
                                          const std::vector<Eigen::Matrix3f>& pixel_jacobians,
                                          std::vector<double>* tt, std::vector<double>* tn,
                                          std::vector<double>* nn,
                                          const RayJacobianVisitor* visit) const {
  const auto start = std::chrono::steady_clock::now();
  const int width = camera_rays.width(), height = camera_rays.height();
  GradientJob job;
  job.rays = &camera_rays;
  job.to_rgb = response_->output_from_basis();
  job.step_m = options_.step_voxels * geometry_.voxel_size_m.minCoeff();
  job.min_transmittance = options_.min_transmittance;
  job.spectral = path_ == SpectralPath::kSpectral;
  job.nbins = job.spectral ? bins_->count() : 3;
  job.to_rgb_t = response_->output_from_basis().transpose();
  job.grey_sigma = job.spectral ? 0.0 : absorption_.CrossSectionM2(550.0);
  const std::size_t nactive = active_voxels_.size();
  const bool wide = std::is_same_v<Real, float> && options_.wide_kernels && UseWideKernels();

  tbb::enumerable_thread_specific<CurvatureBuffers<Real>> buffers;
  std::atomic<std::int64_t> hit{0}, early{0}, evaluated{0}, skipped{0}, after{0};
  tbb::parallel_for(tbb::blocked_range<int>(0, height), [&](const tbb::blocked_range<int>& rows) {
    CurvatureBuffers<Real>& buf = buffers.local();
    if (buf.local.empty()) {
      if (!visit) {
        buf.tt.assign(nactive, 0.0);
        buf.tn.assign(nactive, 0.0);
        buf.nn.assign(nactive, 0.0);
      }
      buf.local.assign(nactive, -1);
    }
    MarchCounters c;
    if constexpr (std::is_same_v<Real, float>) {
      if (wide)
        CurvatureRowsWide(job, pixel_jacobians, rows.begin(), rows.end(), visit, &buf, &c);
      else
        CurvatureRows<float>(job, pixel_jacobians, rows.begin(), rows.end(), visit, &buf, &c);
    } else {
      CurvatureRows<Real>(job, pixel_jacobians, rows.begin(), rows.end(), visit, &buf, &c);
    }
    hit += c.hit;
    early += c.early;
    evaluated += c.evaluated;
    skipped += c.skipped;
    after += c.after;
  });
  for (const CurvatureBuffers<Real>& buf : buffers) {
    if (buf.local.empty() || visit) continue;
    for (std::size_t a = 0; a < nactive; ++a) {
      const std::uint32_t v = active_voxels_[a];
      (*tt)[v] += buf.tt[a];
      (*tn)[v] += buf.tn[a];
      (*nn)[v] += buf.nn[a];
    }
  }
  RenderSummary summary = Summarise(start, static_cast<std::int64_t>(width) * height, job.nbins,
                                    MarchCounters{hit, early, evaluated, skipped, after});
  summary.wide_kernels = wide;
  return summary;
}

// The AVX2 + FMA build of the float curvature (see RenderRowsWide).
__attribute__((target("avx2,fma"), flatten)) void FireRenderer::CurvatureRowsWide(
    const GradientJob& job, const std::vector<Eigen::Matrix3f>& jacobians, int y0, int y1,
    const RayJacobianVisitor* visit, CurvatureBuffers<float>* buffers, MarchCounters* c) const {
  CurvatureRows<float>(job, jacobians, y0, y1, visit, buffers, c);
}

template <typename Real>
void FireRenderer::CurvatureRows(const GradientJob& job,
                                 const std::vector<Eigen::Matrix3f>& jacobians, int y0, int y1,
                                 const RayJacobianVisitor* visit, CurvatureBuffers<Real>* buffers,
                                 MarchCounters* counters) const {
  const CameraRays& camera_rays = *job.rays;
  const int width = camera_rays.width();
  const Real min_tr = Real(job.min_transmittance);
  const bool spectral = job.spectral;
  const int nbins = job.nbins;
  const int nbp = spectral ? padded_bins_ : 3;
  const ChannelResponse& table = *response_;
  CurvatureBuffers<Real>& buf = *buffers;
  MarchCounters& c = *counters;
  alignas(64) Real total[SpectralBins::kMaxBins], transmittance[SpectralBins::kMaxBins];
  alignas(64) Real cumulative[SpectralBins::kMaxBins], sigma[SpectralBins::kMaxBins];
  alignas(64) Real e_factor[SpectralBins::kMaxBins], n_factor[SpectralBins::kMaxBins];
  double adjoint[3][SpectralBins::kMaxBins];  // per residual and bin (or XYZ channel)
  Real sigma_max = 0;  // the largest cross-section, and the clearest bin (BinCrossSections)
  int clearest = 0;
  if (spectral) clearest = BinCrossSections(bin_cross_section_m2_, nbins, nbp, sigma, &sigma_max);
  // The ray's list entry of a slot, made (zeroed) when the ray first crosses it.
  auto local_of = [&](std::int32_t slot) {
    std::int32_t& l = buf.local[slot];
    if (l < 0) {
      l = static_cast<std::int32_t>(buf.touched.size());
      buf.touched.push_back(slot);
      const std::size_t need = buf.touched.size() * nbp;
      if (buf.e.size() < need) {
        buf.e.resize(2 * need);
        buf.n.resize(2 * need);
      }
      std::fill_n(&buf.e[static_cast<std::size_t>(l) * nbp], nbp, Real(0));
      std::fill_n(&buf.n[static_cast<std::size_t>(l) * nbp], nbp, Real(0));
    }
    return static_cast<std::size_t>(l) * nbp;
  };
  for (int y = y0; y < y1; ++y) {
    for (int x = 0; x < width; ++x) {
      const Eigen::Matrix3f& jac = jacobians[static_cast<std::size_t>(y) * width + x];
      if ((jac.array() == 0.0f).all()) continue;  // exactly zero: Eigen's isZero() is fuzzy
      RayMarch march;
      if (!RayMarch::Make(geometry_, camera_rays.at(x, y), job.step_m, &march)) continue;
      ++c.hit;
      for (int k = 0; k < 3; ++k) {
        const Eigen::Vector3d g_xyz = job.to_rgb_t * jac.row(k).transpose().cast<double>();
        for (int b = 0; b < nbp; ++b)
          adjoint[k][b] = b >= nbins ? 0.0 : spectral ? g_xyz.dot(bins_->weight(b)) : g_xyz[b];
      }
      for (int b = 0; b < nbp; ++b) {
        total[b] = cumulative[b] = Real(0);
        transmittance[b] = b < nbins ? Real(1) : Real(0);
      }
      if (spectral) {
        std::int32_t slots[8];
        const float* rows[8];
        Real u0[8], u1[8];
        // Pass 1: the ray's radiance per bin (as GradientRows).
        MarchRadiance(march, true, nbp, sigma, sigma_max, clearest, min_tr, total, transmittance);
        for (int b = 0; b < nbp; ++b) transmittance[b] = b < nbins ? Real(1) : Real(0);
        // Pass 2: the adjoint's factors, summed per voxel crossed.
        MarchRay<Real>(march, &c, [&](Real ds, const std::size_t* corner, const Real* w) {
          const Real n_sample = GatherCorners(corner, w, slots, rows, u0, u1);
          if (!(n_sample > Real(0))) return true;
          const Real max_tr =
              sigma_max * n_sample * ds < Real(1e-2)
                  ? SpectralFactorStep<true, Real>(nbp, clearest, rows, u0, u1, sigma, total,
                                                   n_sample, Real(density_unit_), ds, cumulative,
                                                   transmittance, e_factor, n_factor)
                  : SpectralFactorStep<false, Real>(nbp, clearest, rows, u0, u1, sigma, total,
                                                    n_sample, Real(density_unit_), ds, cumulative,
                                                    transmittance, e_factor, n_factor);
          for (int k = 0; k < 8; ++k) {
            if (slots[k] < 0 || w[k] == Real(0)) continue;
            const std::size_t l = local_of(slots[k]);
            AddScaledLanes(nbp, w[k], e_factor, &buf.e[l]);
            AddScaledLanes(nbp, w[k], n_factor, &buf.n[l]);
          }
          return !(max_tr < min_tr);
        });
      } else {
        MarchRadiance(march, false, nbp, sigma, sigma_max, clearest, min_tr, total, transmittance);
        transmittance[0] = Real(1);
        MarchRay<Real>(march, &c, [&](Real ds, const std::size_t* corner, const Real* w) {
          Real kappa, source[3];
          if (!FastSample(corner, w, &kappa, source)) return true;
          Real absorbed, phi, tau_dphi;
          StepTerms(kappa * ds, &absorbed, &phi, &tau_dphi);
          const Real tr = transmittance[0];
          const Real e = tr * ds * phi;
          Real nf[3];
          for (int ch = 0; ch < 3; ++ch) {
            cumulative[ch] += tr * absorbed * source[ch];
            nf[ch] = ds * (tr * tau_dphi * source[ch] - (total[ch] - cumulative[ch]));
          }
          for (int k = 0; k < 8; ++k) {
            const std::int32_t slot = slot_[corner[k]];
            if (slot < 0 || w[k] == Real(0)) continue;
            const std::size_t l = local_of(slot);
            for (int ch = 0; ch < 3; ++ch) {
              buf.e[l + ch] += w[k] * e;
              buf.n[l + ch] += w[k] * nf[ch];
            }
          }
          transmittance[0] -= tr * absorbed;
          return !(transmittance[0] < min_tr);
        });
      }
      // The ray's Jacobian per voxel crossed, three residuals by (T, n), into the blocks.
      for (std::size_t i = 0; i < buf.touched.size(); ++i) {
        const std::int32_t slot = buf.touched[i];
        const std::uint32_t voxel = active_voxels_[slot];
        const Real* e = &buf.e[i * nbp];
        const Real* n = &buf.n[i * nbp];
        double d_n[3] = {0, 0, 0}, d_t[3] = {0, 0, 0};
        if (spectral) {
          const SpectralVoxel& row = spectral_voxels_[voxel];
          const float* r0 = &spectral_table_[row.offset];
          const float* r1 = r0 + nbp;
          const bool hot_row = row.offset >= hot_rows_offset_;
          const double density = density_[voxel];
          for (int b = 0; b < nbins; ++b) {
            const double slope = hot_row ? double(r1[b]) : double(r1[b]) - double(r0[b]);
            const double part_n = double(e[b]) * (double(r0[b]) + row.fraction * slope) + n[b];
            const double part_t = double(e[b]) * slope * density;
            for (int k = 0; k < 3; ++k) {
              d_n[k] += adjoint[k][b] * part_n;
              d_t[k] += adjoint[k][b] * part_t;
            }
          }
        } else {
          Real xyz[3], d_xyz[3];
          table.LookupWithDerivative(Real(temperature_[voxel]), xyz, d_xyz);
          const double kappa = fast_[4 * static_cast<std::size_t>(voxel)];
          for (int ch = 0; ch < 3; ++ch) {
            const double part_n = job.grey_sigma * (double(n[ch]) + double(e[ch]) * xyz[ch]);
            const double part_t = kappa * double(e[ch]) * d_xyz[ch];
            for (int k = 0; k < 3; ++k) {
              d_n[k] += adjoint[k][ch] * part_n;
              d_t[k] += adjoint[k][ch] * part_t;
            }
          }
        }
        if (visit) {
          buf.ray.voxels.push_back(voxel);
          Eigen::Matrix<double, 3, 2>& d = buf.ray.d.emplace_back();
          for (int k = 0; k < 3; ++k) {
            d(k, 0) = d_t[k];
            d(k, 1) = d_n[k];
          }
        } else {
          for (int k = 0; k < 3; ++k) {
            buf.tt[slot] += d_t[k] * d_t[k];
            buf.tn[slot] += d_t[k] * d_n[k];
            buf.nn[slot] += d_n[k] * d_n[k];
          }
        }
        buf.local[slot] = -1;
      }
      buf.touched.clear();
      if (visit && !buf.ray.voxels.empty()) {
        buf.ray.pixel = static_cast<std::size_t>(y) * width + x;
        (*visit)(buf.ray);
      }
      buf.ray.voxels.clear();
      buf.ray.d.clear();
    }
  }
}

RenderSummary FireRenderer::RenderCurvature(const CameraRays& rays,
                                            const std::vector<Eigen::Matrix3f>& pixel_jacobians,
                                            std::vector<double>* tt, std::vector<double>* tn,
                                            std::vector<double>* nn) const {
  if (!has_volume_) throw std::logic_error("FireRenderer::RenderCurvature called before SetVolume");
  const std::size_t pixels = static_cast<std::size_t>(rays.width()) * rays.height();
  if (pixel_jacobians.size() != pixels) {
    throw InputError("RenderCurvature: " + std::to_string(pixel_jacobians.size()) +
                     " pixel Jacobians for a camera of " + std::to_string(pixels) + " pixels");
  }
  PrepareGradientArrays(tt, tn);
  PrepareGradientArrays(nn, tn);
  if (options_.double_precision)
    return CurvatureImpl<double>(rays, pixel_jacobians, tt, tn, nn, nullptr);
  return CurvatureImpl<float>(rays, pixel_jacobians, tt, tn, nn, nullptr);
}

RenderSummary FireRenderer::RenderJacobian(const CameraRays& rays,
                                           const std::vector<Eigen::Matrix3f>& pixel_jacobians,
                                           const RayJacobianVisitor& visit) const {
  if (!has_volume_) throw std::logic_error("FireRenderer::RenderJacobian called before SetVolume");
  const std::size_t pixels = static_cast<std::size_t>(rays.width()) * rays.height();
  if (pixel_jacobians.size() != pixels) {
    throw InputError("RenderJacobian: " + std::to_string(pixel_jacobians.size()) +
                     " pixel Jacobians for a camera of " + std::to_string(pixels) + " pixels");
  }
  if (!visit) throw InputError("RenderJacobian: no visitor");
  if (options_.double_precision)
    return CurvatureImpl<double>(rays, pixel_jacobians, nullptr, nullptr, nullptr, &visit);
  return CurvatureImpl<float>(rays, pixel_jacobians, nullptr, nullptr, nullptr, &visit);
}

void FireRenderer::PrepareGradientArrays(std::vector<double>* d_temperature,
                                         std::vector<double>* d_density) const {
  const std::size_t nvox = geometry_.num_voxels();
  for (std::vector<double>* v : {d_temperature, d_density}) {
    if (v->empty()) v->assign(nvox, 0.0);
    if (v->size() != nvox) {
      throw InputError("renderer: gradient and curvature arrays need " + std::to_string(nvox) +
                       " values, got " + std::to_string(v->size()));
    }
  }
}

RenderSummary FireRenderer::RenderGradient(const CameraRays& rays, const ImageF& d_loss_d_rgb,
                                           std::vector<double>* d_temperature,
                                           std::vector<double>* d_density) const {
  if (!has_volume_) throw std::logic_error("FireRenderer::RenderGradient called before SetVolume");
  if (d_loss_d_rgb.width != rays.width() || d_loss_d_rgb.height != rays.height() ||
      d_loss_d_rgb.channels != 3) {
    throw InputError("RenderGradient: d_loss_d_rgb is " + std::to_string(d_loss_d_rgb.width) + "x" +
                     std::to_string(d_loss_d_rgb.height) + "x" +
                     std::to_string(d_loss_d_rgb.channels) + ", the camera is " +
                     std::to_string(rays.width()) + "x" + std::to_string(rays.height()) + "x3");
  }
  PrepareGradientArrays(d_temperature, d_density);
  if (options_.double_precision)
    return GradientImpl<double>(rays, &d_loss_d_rgb, nullptr, nullptr, d_temperature, d_density);
  return GradientImpl<float>(rays, &d_loss_d_rgb, nullptr, nullptr, d_temperature, d_density);
}

RenderSummary FireRenderer::RenderAndGradient(const CameraRays& rays,
                                              const PixelGradient& pixel_gradient,
                                              ImageF* linear_rgb,
                                              std::vector<double>* d_temperature,
                                              std::vector<double>* d_density) const {
  if (!has_volume_)
    throw std::logic_error("FireRenderer::RenderAndGradient called before SetVolume");
  if (!pixel_gradient) throw InputError("RenderAndGradient: no pixel gradient function");
  if (!linear_rgb) throw InputError("RenderAndGradient: no image to render into");
  PrepareGradientArrays(d_temperature, d_density);
  if (options_.double_precision)
    return GradientImpl<double>(rays, nullptr, &pixel_gradient, linear_rgb, d_temperature,
                                d_density);
  return GradientImpl<float>(rays, nullptr, &pixel_gradient, linear_rgb, d_temperature, d_density);
}

RenderSummary FireRenderer::RenderPixelArea(const CameraModel& camera, int n,
                                            ImageF* linear_rgb) const {
  if (n < 1 || n > 8)
    throw InputError("RenderPixelArea: n x n rays a pixel with n = " + std::to_string(n) +
                     ": n must be in [1, 8]");
  if (n == 1) return Render(CameraRays(camera), linear_rgb);
  *linear_rgb = ImageF(camera.width(), camera.height(), 3, 0.0f);
  RenderSummary summary;
  for (int sy = 0; sy < n; ++sy)
    for (int sx = 0; sx < n; ++sx) {
      const Eigen::Vector2d offset((sx + 0.5) / n - 0.5, (sy + 0.5) / n - 0.5);
      ImageF sample;
      summary = Render(CameraRays(camera, offset), &sample);
      for (std::size_t i = 0; i < sample.pixels.size(); ++i)
        linear_rgb->pixels[i] += sample.pixels[i] / float(n * n);
    }
  return summary;
}

RenderSummary FireRenderer::Render(const CameraRays& rays, ImageF* linear_rgb) const {
  if (!has_volume_) throw std::logic_error("FireRenderer::Render called before SetVolume");
  if (options_.double_precision) return RenderImpl<double>(rays, linear_rgb);
  return RenderImpl<float>(rays, linear_rgb);
}

RenderSummary FireRenderer::Render(const CameraRays& rays, const std::vector<float>& max_distance_m,
                                   ImageF* linear_rgb, ImageF* transmittance_rgb) const {
  if (!has_volume_) throw std::logic_error("FireRenderer::Render called before SetVolume");
  if (max_distance_m.size() != static_cast<std::size_t>(rays.width()) * rays.height())
    throw InputError("FireRenderer::Render: need one max distance per pixel");
  if (options_.double_precision)
    return RenderImpl<double>(rays, linear_rgb, &max_distance_m, transmittance_rgb);
  return RenderImpl<float>(rays, linear_rgb, &max_distance_m, transmittance_rgb);
}

ImageU8 ApplyCameraResponse(const ImageF& linear_rgb, double exposure) {
  if (!(exposure > 0) || !std::isfinite(exposure)) {
    throw InputError("exposure = " + std::to_string(exposure) + " must be finite and > 0");
  }
  if (linear_rgb.channels != 3) throw InputError("ApplyCameraResponse needs a 3-channel image");
  ImageU8 out(linear_rgb.width, linear_rgb.height, 3);
  for (std::size_t i = 0; i < linear_rgb.pixels.size(); ++i) {
    out.pixels[i] = colour::QuantizeU8(colour::SrgbEncode(exposure * double(linear_rgb.pixels[i])));
  }
  return out;
}

}  // namespace flamerig
