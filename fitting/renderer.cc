#include "fitting/renderer.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "core/error.h"
#include "fitting/colour.h"
#include "tomography/ray_march.h"

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
    << "% of bricks occupied), " << rays_terminated_early << " rays terminated early, " << time_ms
    << " ms";
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
    bins_ = std::make_unique<SpectralBins>(options_.spectral_first_nm, options_.spectral_last_nm,
                                           options_.spectral_step_nm, response_.get());
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
  // Voxels with density > 0 (the medium) get a slot: their index in the gradient buffers and, on
  // the spectral path, in spectra_.
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
    // Per voxel with soot: B_b(T) for every bin (kappa_b = sigma_b * n is formed per sample).
    const int nbins = bins_->count();
    spectra_.assign(active_voxels_.size() * nbins, 0.0f);
    std::vector<double> planck(nbins);
    for (std::size_t a = 0; a < active_voxels_.size(); ++a) {
      bins_->PlanckAll(double(temperature_k[active_voxels_[a]]), planck.data());
      for (int b = 0; b < nbins; ++b) spectra_[a * nbins + b] = static_cast<float>(planck[b]);
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

// 1 - exp(-tau) for tau >= 0 without cancellation at small tau (series below 1e-2).
template <typename Real>
inline Real OneMinusExpNeg(Real tau) {
  const Real series =
      tau * (Real(1) - tau * (Real(0.5) - tau * (Real(1) / 6 - tau * (Real(1) / 24))));
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
  const int brick = options_.brick_size_voxels;
  const bool skip = options_.skip_empty_space;
  const Eigen::Vector3d& o = march.origin_index;
  const Eigen::Vector3d& d = march.direction_index;
  const std::int64_t n_steps = march.n_steps;
  std::int64_t k = 0;
  while (k < n_steps) {
    double step_length;
    Eigen::Vector3d p;
    march.Step(k, &step_length, &p);
    if (skip) {
      const int bi =
          std::clamp(static_cast<int>(std::floor((p.x() + 0.5) / brick)), 0, brick_dims_.x() - 1);
      const int bj =
          std::clamp(static_cast<int>(std::floor((p.y() + 0.5) / brick)), 0, brick_dims_.y() - 1);
      const int bk =
          std::clamp(static_cast<int>(std::floor((p.z() + 0.5) / brick)), 0, brick_dims_.z() - 1);
      if (!brick_occupied_[bi + brick_dims_.x() *
                                    (bj + static_cast<std::size_t>(brick_dims_.y()) * bk)]) {
        // Jump to the first step whose midpoint lies beyond this brick.
        double t_leave = std::numeric_limits<double>::infinity();
        const int bidx[3] = {bi, bj, bk};
        for (int a = 0; a < 3; ++a) {
          if (d[a] > 0)
            t_leave = std::min(t_leave, ((bidx[a] + 1) * brick - 0.5 - o[a]) / d[a]);
          else if (d[a] < 0)
            t_leave = std::min(t_leave, (bidx[a] * brick - 0.5 - o[a]) / d[a]);
        }
        const std::int64_t next = std::max(k + 1, march.FirstStepAfter(t_leave));
        c->skipped += next - k;
        k = next;
        continue;
      }
    }
    const TrilinearStencil<Real> s(g.dims, Real(p.x()), Real(p.y()), Real(p.z()));
    std::size_t corner[8];
    Real weight[8];
    s.Corners(nx, nxy, corner, weight);
    ++c->evaluated;
    if (!visit(Real(step_length), corner, weight)) {
      ++c->early;
      c->after += n_steps - k - 1;
      return;
    }
    ++k;
  }
}

template <typename Real>
RenderSummary FireRenderer::RenderImpl(const CameraRays& camera_rays, ImageF* linear_rgb,
                                       const std::vector<float>* max_distance_m,
                                       ImageF* transmittance_rgb) const {
  const auto start = std::chrono::steady_clock::now();
  const int width = camera_rays.width(), height = camera_rays.height();
  *linear_rgb = ImageF(width, height, 3, 0.0f);
  if (transmittance_rgb) *transmittance_rgb = ImageF(width, height, 3, 1.0f);
  // Per channel, the colour matching weights of the bins (spectral transmittance to RGB).
  Eigen::Vector3d weight_sum = Eigen::Vector3d::Zero();
  if (path_ == SpectralPath::kSpectral)
    for (int b = 0; b < bins_->count(); ++b) weight_sum += bins_->weight(b);

  const GridGeometry& g = geometry_;
  const double step_m = options_.step_voxels * g.voxel_size_m.minCoeff();
  const Real min_tr = Real(options_.min_transmittance);
  const bool spectral = path_ == SpectralPath::kSpectral;
  const int nbins = spectral ? bins_->count() : 3;
  const Eigen::Matrix3d& to_rgb = response_->output_from_basis();

  std::atomic<std::int64_t> hit{0}, early{0}, evaluated{0}, skipped{0}, after{0};

  tbb::parallel_for(tbb::blocked_range<int>(0, height), [&](const tbb::blocked_range<int>& rows) {
    MarchCounters c;
    Real radiance[SpectralBins::kMaxBins];
    Real transmittance[SpectralBins::kMaxBins];
    Real sigma[SpectralBins::kMaxBins];
    Real planck[SpectralBins::kMaxBins];
    if (spectral) {
      for (int b = 0; b < nbins; ++b) sigma[b] = Real(bin_cross_section_m2_[b]);
    }
    for (int y = rows.begin(); y < rows.end(); ++y) {
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
        for (int b = 0; b < nbins; ++b) {
          radiance[b] = Real(0);
          transmittance[b] = Real(1);
        }
        if (!spectral) {
          MarchRay<Real>(march, &c, [&](Real ds, const std::size_t* corner, const Real* weight) {
            // Interpolate the voxels' absorption kappa and emission kappa * XYZ(T). The source
            // emission / kappa is formed as an average of XYZ(T) weighted by w * kappa, which never
            // overflows whatever the density.
            Real kappa = 0;
            for (int n = 0; n < 8; ++n) kappa += weight[n] * Real(fast_[4 * corner[n]]);
            if (!(kappa > Real(0))) return true;
            Real source[3] = {0, 0, 0};
            for (int n = 0; n < 8; ++n) {
              const float* v = &fast_[4 * corner[n]];
              const Real u = weight[n] * Real(v[0]) / kappa;
              for (int ch = 0; ch < 3; ++ch) source[ch] += u * Real(v[ch + 1]);
            }
            // Constant source over the step: L += Tr * source * (1 - exp(-tau)).
            const Real absorbed = OneMinusExpNeg(kappa * ds);
            const Real w = transmittance[0] * absorbed;
            for (int ch = 0; ch < 3; ++ch) radiance[ch] += w * source[ch];
            transmittance[0] -= w;
            return !(transmittance[0] < min_tr);
          });
        } else {
          MarchRay<Real>(march, &c, [&](Real ds, const std::size_t* corner, const Real* weight) {
            Real n_sample = 0;
            for (int n = 0; n < 8; ++n) n_sample += weight[n] * Real(density_[corner[n]]);
            if (!(n_sample > Real(0))) return true;
            // Source per bin: emission / kappa = sum w n B_b(T) / sum w n, an average of the
            // corners' Planck spectra weighted by w * n (no overflow whatever the density).
            for (int b = 0; b < nbins; ++b) planck[b] = Real(0);
            for (int n = 0; n < 8; ++n) {
              const std::int32_t slot = slot_[corner[n]];
              if (slot < 0 || weight[n] == Real(0)) continue;
              const float* row = &spectra_[static_cast<std::size_t>(slot) * nbins];
              const Real u = weight[n] * Real(density_[corner[n]]) / n_sample;
              for (int b = 0; b < nbins; ++b) planck[b] += u * Real(row[b]);  // vectorised
            }
            for (int b = 0; b < nbins; ++b) {  // vectorised
              const Real absorbed = OneMinusExpNeg(sigma[b] * n_sample * ds);
              const Real w = transmittance[b] * absorbed;
              radiance[b] += w * planck[b];
              transmittance[b] -= w;
            }
            Real max_tr = Real(0);
            for (int b = 0; b < nbins; ++b) max_tr = std::max(max_tr, transmittance[b]);
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
    hit += c.hit;
    early += c.early;
    evaluated += c.evaluated;
    skipped += c.skipped;
    after += c.after;
  });

  return Summarise(start, static_cast<std::int64_t>(width) * height, nbins,
                   MarchCounters{hit, early, evaluated, skipped, after});
}

template <typename Real>
RenderSummary FireRenderer::GradientImpl(const CameraRays& camera_rays, const ImageF& d_loss_d_rgb,
                                         std::vector<double>* d_temperature,
                                         std::vector<double>* d_density) const {
  const auto start = std::chrono::steady_clock::now();
  const int width = camera_rays.width(), height = camera_rays.height();
  const GridGeometry& g = geometry_;
  const double step_m = options_.step_voxels * g.voxel_size_m.minCoeff();
  const Real min_tr = Real(options_.min_transmittance);
  const bool spectral = path_ == SpectralPath::kSpectral;
  const int nbins = spectral ? bins_->count() : 3;
  // rgb = M xyz, so dLoss/dxyz = M^T dLoss/drgb.
  const Eigen::Matrix3d to_rgb_t = response_->output_from_basis().transpose();
  const double grey_sigma = spectral ? 0.0 : absorption_.CrossSectionM2(550.0);
  const ChannelResponse& table = *response_;
  const std::size_t nactive = active_voxels_.size();

  struct Buffers {
    std::vector<double> dt, dn;
    // Spectral path: dLoss/d(emission) per slot and bin, sigma_b included; turned into dT and dn
    // once per voxel at the end (cheaper than a dot product per corner and step).
    std::vector<Real> de;
  };
  tbb::enumerable_thread_specific<Buffers> buffers;
  std::atomic<std::int64_t> hit{0}, early{0}, evaluated{0}, skipped{0}, after{0};

  tbb::parallel_for(tbb::blocked_range<int>(0, height), [&](const tbb::blocked_range<int>& rows) {
    Buffers& buf = buffers.local();
    if (buf.dt.empty()) {
      buf.dt.assign(nactive, 0.0);
      buf.dn.assign(nactive, 0.0);
      if (spectral) buf.de.assign(nactive * nbins, Real(0));
    }
    MarchCounters c;
    Real total[SpectralBins::kMaxBins], transmittance[SpectralBins::kMaxBins];
    Real cumulative[SpectralBins::kMaxBins], adjoint[SpectralBins::kMaxBins];
    Real sigma[SpectralBins::kMaxBins], planck[SpectralBins::kMaxBins];
    Real d_emission[SpectralBins::kMaxBins];
    if (spectral) {
      for (int b = 0; b < nbins; ++b) sigma[b] = Real(bin_cross_section_m2_[b]);
    }
    for (int y = rows.begin(); y < rows.end(); ++y) {
      for (int x = 0; x < width; ++x) {
        const Eigen::Vector3d g_rgb(d_loss_d_rgb.at(x, y, 0), d_loss_d_rgb.at(x, y, 1),
                                    d_loss_d_rgb.at(x, y, 2));
        if (g_rgb.isZero()) continue;
        RayMarch march;
        if (!RayMarch::Make(g, camera_rays.at(x, y), step_m, &march)) continue;
        ++c.hit;
        const Eigen::Vector3d g_xyz = to_rgb_t * g_rgb;
        for (int b = 0; b < nbins; ++b) {
          adjoint[b] = spectral ? Real(g_xyz.dot(bins_->weight(b))) : Real(g_xyz[b]);
          total[b] = cumulative[b] = Real(0);
          transmittance[b] = Real(1);
        }
        MarchCounters ignored;
        if (!spectral) {
          // The per-step source S and absorption of the fast path (see RenderImpl).
          auto sample = [&](const std::size_t* corner, const Real* weight, Real* kappa,
                            Real* source) {
            *kappa = 0;
            for (int n = 0; n < 8; ++n) *kappa += weight[n] * Real(fast_[4 * corner[n]]);
            if (!(*kappa > Real(0))) return false;
            source[0] = source[1] = source[2] = Real(0);
            for (int n = 0; n < 8; ++n) {
              const float* v = &fast_[4 * corner[n]];
              const Real u = weight[n] * Real(v[0]) / *kappa;
              for (int ch = 0; ch < 3; ++ch) source[ch] += u * Real(v[ch + 1]);
            }
            return true;
          };
          // Pass 1: the ray's radiance.
          MarchRay<Real>(march, &ignored,
                         [&](Real ds, const std::size_t* corner, const Real* weight) {
                           Real kappa, source[3];
                           if (!sample(corner, weight, &kappa, source)) return true;
                           const Real w = transmittance[0] * OneMinusExpNeg(kappa * ds);
                           for (int ch = 0; ch < 3; ++ch) total[ch] += w * source[ch];
                           transmittance[0] -= w;
                           return !(transmittance[0] < min_tr);
                         });
          transmittance[0] = Real(1);
          // Pass 2: the adjoint.
          MarchRay<Real>(march, &c, [&](Real ds, const std::size_t* corner, const Real* weight) {
            Real kappa, source[3];
            if (!sample(corner, weight, &kappa, source)) return true;
            const Real tau = kappa * ds;
            Real phi, tau_dphi;
            PhiAndTauDPhi(tau, &phi, &tau_dphi);
            const Real tr = transmittance[0];
            const Real w = tr * OneMinusExpNeg(tau);
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
          auto sample = [&](const std::size_t* corner, const Real* weight, Real* n_sample) {
            *n_sample = 0;
            for (int n = 0; n < 8; ++n) *n_sample += weight[n] * Real(density_[corner[n]]);
            if (!(*n_sample > Real(0))) return false;
            for (int b = 0; b < nbins; ++b) planck[b] = Real(0);
            for (int n = 0; n < 8; ++n) {
              const std::int32_t slot = slot_[corner[n]];
              if (slot < 0 || weight[n] == Real(0)) continue;
              const float* row = &spectra_[static_cast<std::size_t>(slot) * nbins];
              const Real u = weight[n] * Real(density_[corner[n]]) / *n_sample;
              for (int b = 0; b < nbins; ++b) planck[b] += u * Real(row[b]);
            }
            return true;
          };
          auto keep_going = [&]() {
            Real max_tr = Real(0);
            for (int b = 0; b < nbins; ++b) max_tr = std::max(max_tr, transmittance[b]);
            return !(max_tr < min_tr);
          };
          MarchRay<Real>(
              march, &ignored, [&](Real ds, const std::size_t* corner, const Real* weight) {
                Real n_sample;
                if (!sample(corner, weight, &n_sample)) return true;
                for (int b = 0; b < nbins; ++b) {
                  const Real w = transmittance[b] * OneMinusExpNeg(sigma[b] * n_sample * ds);
                  total[b] += w * planck[b];
                  transmittance[b] -= w;
                }
                return keep_going();
              });
          for (int b = 0; b < nbins; ++b) transmittance[b] = Real(1);
          MarchRay<Real>(march, &c, [&](Real ds, const std::size_t* corner, const Real* weight) {
            Real n_sample;
            if (!sample(corner, weight, &n_sample)) return true;
            // d_emission[b] holds sigma_b dLoss/dE_b; d_n the kappa part, summed over bins.
            Real d_n = 0;
            for (int b = 0; b < nbins; ++b) {
              const Real tau = sigma[b] * n_sample * ds;
              Real phi, tau_dphi;
              PhiAndTauDPhi(tau, &phi, &tau_dphi);
              const Real tr = transmittance[b];
              const Real w = tr * OneMinusExpNeg(tau);
              cumulative[b] += w * planck[b];
              const Real behind = total[b] - cumulative[b];
              d_emission[b] = sigma[b] * adjoint[b] * tr * ds * phi;
              d_n += sigma[b] * adjoint[b] * ds * (tr * tau_dphi * planck[b] - behind);
              transmittance[b] -= w;
            }
            for (int n = 0; n < 8; ++n) {
              const std::int32_t slot = slot_[corner[n]];
              if (slot < 0 || weight[n] == Real(0)) continue;
              buf.dn[slot] += double(weight[n] * d_n);
              Real* de = &buf.de[static_cast<std::size_t>(slot) * nbins];
              for (int b = 0; b < nbins; ++b) de[b] += weight[n] * d_emission[b];  // vectorised
            }
            return keep_going();
          });
        }
      }
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
      // de_b B_b'(T).
      tbb::parallel_for(tbb::blocked_range<std::size_t>(0, nactive, 256),
                        [&](const tbb::blocked_range<std::size_t>& r) {
                          std::vector<Real> row_b(nbins), row_d(nbins);
                          for (std::size_t a = r.begin(); a < r.end(); ++a) {
                            const std::uint32_t v = active_voxels_[a];
                            bins_->PlanckAllWithDerivative(Real(temperature_[v]), row_b.data(),
                                                           row_d.data());
                            const Real* de = &buf.de[a * nbins];
                            double dot_b = 0, dot_d = 0;
                            for (int b = 0; b < nbins; ++b) {
                              dot_b += double(de[b]) * row_b[b];
                              dot_d += double(de[b]) * row_d[b];
                            }
                            buf.dn[a] += dot_b;
                            buf.dt[a] += dot_d * density_[v];
                          }
                        });
    }
    for (std::size_t a = 0; a < nactive; ++a) {
      (*d_temperature)[active_voxels_[a]] += buf.dt[a];
      (*d_density)[active_voxels_[a]] += buf.dn[a];
    }
  }

  return Summarise(start, static_cast<std::int64_t>(width) * height, nbins,
                   MarchCounters{hit, early, evaluated, skipped, after});
}

RenderSummary FireRenderer::RenderGradient(const CameraRays& rays, const ImageF& d_loss_d_rgb,
                                           std::vector<double>* d_temperature,
                                           std::vector<double>* d_density) const {
  if (!has_volume_) throw std::logic_error("FireRenderer::RenderGradient called before SetVolume");
  if (d_loss_d_rgb.width != rays.width() || d_loss_d_rgb.height != rays.height() ||
      d_loss_d_rgb.channels != 3) {
    throw InputError(
        "RenderGradient: d_loss_d_rgb is " + std::to_string(d_loss_d_rgb.width) + "x" +
        std::to_string(d_loss_d_rgb.height) + "x" + std::to_string(d_loss_d_rgb.channels) +
        ", the camera is " + std::to_string(rays.width()) + "x" + std::to_string(rays.height()) +
        "x3");
  }
  const std::size_t nvox = geometry_.num_voxels();
  for (std::vector<double>* v : {d_temperature, d_density}) {
    if (v->empty()) v->assign(nvox, 0.0);
    if (v->size() != nvox) {
      throw InputError("RenderGradient: gradient arrays need " + std::to_string(nvox) +
                                  " values, got " + std::to_string(v->size()));
    }
  }
  if (options_.double_precision)
    return GradientImpl<double>(rays, d_loss_d_rgb, d_temperature, d_density);
  return GradientImpl<float>(rays, d_loss_d_rgb, d_temperature, d_density);
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
    throw InputError("exposure = " + std::to_string(exposure) +
                                " must be finite and > 0");
  }
  if (linear_rgb.channels != 3)
    throw InputError("ApplyCameraResponse needs a 3-channel image");
  ImageU8 out(linear_rgb.width, linear_rgb.height, 3);
  for (std::size_t i = 0; i < linear_rgb.pixels.size(); ++i) {
    out.pixels[i] = colour::QuantizeU8(colour::SrgbEncode(exposure * double(linear_rgb.pixels[i])));
  }
  return out;
}

}  // namespace flamerig
