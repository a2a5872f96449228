#include "fitting/uncertainty.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "core/error.h"
#include "fitting/camera_response.h"

namespace flamerig {
namespace {

// Neighbouring fire-pixel pairs (3 residual differences each) below which the differences do not
// give the noise level: 30 pairs.
constexpr std::int64_t kMinDifferences = 90;

}  // namespace

bool OneBand(const std::vector<FitView>& views) {
  if (views.empty()) return false;
  for (const FitView& v : views)
    if (!v.response || v.response->channels() != 1 ||
        v.response->name() != views.front().response->name())
      return false;
  return true;
}

void UncertaintyOptions::Validate() const {
  if (!(determined_fraction > 0 && determined_fraction <= 1))
    throw InputError("uncertainty: determined_fraction must be in (0, 1]");
}

VoxelUncertainty EstimateUncertainty(const FitObjective& objective, const std::vector<double>& t,
                                     const std::vector<double>& n, double s,
                                     const UncertaintyOptions& options,
                                     const std::vector<std::vector<std::size_t>>* groups) {
  options.Validate();
  const auto start = std::chrono::steady_clock::now();
  FitObjective::Curvature c = objective.DataCurvature(t, n, s);
  const std::size_t na = objective.num_active();
  // Tied voxels share one (T, ln n): each group's block is the sum of its members'.
  std::size_t unknowns = na;
  if (groups) {
    std::size_t covered = 0;
    for (const auto& g : *groups) {
      double tt = 0, tn = 0, nn = 0;
      for (std::size_t a : g) {
        if (a >= na) throw InputError("uncertainty: a group names voxel " + std::to_string(a));
        tt += c.tt[a];
        tn += c.tn[a];
        nn += c.nn[a];
      }
      for (std::size_t a : g) {
        c.tt[a] = tt;
        c.tn[a] = tn;
        c.nn[a] = nn;
      }
      covered += g.size();
    }
    if (covered != na) throw InputError("uncertainty: the groups do not cover the active voxels");
    unknowns = groups->size();
  }
  VoxelUncertainty u;
  // The residuals' level per residual (degrees of freedom: less two per unknown voxel or group, at
  // least half the residuals), and the noise from their differences between neighbouring pixels,
  // scaled by the same ratio of residuals to degrees of freedom (a fit absorbs some of the noise
  // into its unknowns, and it is missing from both alike). Too few neighbouring pairs to say: the
  // level.
  const double dof =
      std::max(0.5 * double(c.residuals), double(c.residuals) - 2.0 * double(unknowns));
  u.residual_lab = dof > 0 ? std::sqrt(c.residual_sq / dof) : 0.0;
  u.sigma_lab = c.differences >= kMinDifferences && dof > 0
                    ? std::sqrt(c.difference_sq / double(c.differences) * double(c.residuals) / dof)
                    : u.residual_lab;
  const ObjectiveOptions& o = objective.options();
  u.prior_sigma_k = (o.t_max_k - o.t_min_k) / std::sqrt(12.0);
  const double prior_ln =
      std::max(1e-6, std::log(objective.n_max() / objective.n_min())) / std::sqrt(12.0);
  // A noise level of zero (a perfect fit of noise-free data) would make every voxel exact: keep
  // a floor of a hundredth of a Delta E.
  const double noise2 = std::max(u.sigma_lab * u.sigma_lab, 1e-4);
  u.one_band = OneBand(objective.views());
  u.temperature_sigma_k.resize(na);
  u.log_density_sigma.resize(na);
  u.determined.resize(na);
  for (std::size_t a = 0; a < na; ++a) {
    const double htt = c.tt[a] / noise2 + 1.0 / (u.prior_sigma_k * u.prior_sigma_k);
    const double hnn = c.nn[a] / noise2 + 1.0 / (prior_ln * prior_ln);
    const double htn = c.tn[a] / noise2;
    // An exact block has tn^2 <= tt nn and the prior's terms make the sum positive definite; a
    // voxel whose temperature and density columns are all but parallel (its brightness could
    // come from either) loses that to rounding only: keep the determinant at a relative 1e-12
    // there. (Until the blocks were exact the cross term was clamped at 0.99 of its bound,
    // which narrowed exactly these voxels' sigma.)
    const double det = std::max(htt * hnn - htn * htn, 1e-12 * htt * hnn);
    const double var_t = hnn / det, var_n = htt / det;
    const double sigma_t = std::isfinite(var_t) && !u.one_band ? std::sqrt(var_t) : u.prior_sigma_k;
    const double sigma_n = std::isfinite(var_n) && !u.one_band ? std::sqrt(var_n) : prior_ln;
    u.temperature_sigma_k[a] = float(std::min(sigma_t, u.prior_sigma_k));
    u.log_density_sigma[a] = float(std::min(sigma_n, prior_ln));
    const bool determined = sigma_t < options.determined_fraction * u.prior_sigma_k;
    u.determined[a] = determined ? 1.0f : 0.0f;
    u.determined_count += determined;
  }
  u.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return u;
}

void StoreUncertainty(const GridGeometry& grid, const std::vector<std::uint32_t>& active,
                      const VoxelUncertainty& u, FireVolume* volume) {
  const std::size_t nv = grid.num_voxels();
  volume->temperature_sigma_k.assign(nv, 0.0f);
  volume->density_sigma.assign(nv, 0.0f);
  volume->determined.assign(nv, 0.0f);
  for (std::size_t a = 0; a < active.size() && a < u.temperature_sigma_k.size(); ++a) {
    volume->temperature_sigma_k[active[a]] = u.temperature_sigma_k[a];
    volume->density_sigma[active[a]] = u.log_density_sigma[a];
    volume->determined[active[a]] = u.determined[a];
  }
  volume->metadata_numbers["sigma_lab"] = u.sigma_lab;
  volume->metadata_numbers["residual_lab"] = u.residual_lab;
  if (u.one_band) volume->metadata_numbers["one_band"] = 1;
  volume->metadata_numbers["determined_voxels"] = double(u.determined_count);
}

}  // namespace flamerig
