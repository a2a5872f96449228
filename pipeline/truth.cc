#include "pipeline/truth.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <utility>

#include "core/error.h"
#include "tomography/reconstruct.h"

namespace flamerig {

namespace {

// Whether the truth's voxels are the fit's, in one frame: then they pair index by index.
bool SameVoxelsInOneFrame(const FireVolume& truth, const FireVolume& fitted,
                          const Rigid3& fit_from_truth) {
  const Rigid3& m = fit_from_truth;
  return truth.geometry.SameVoxels(fitted.geometry) && m.rotation.w() == 1 &&
         m.rotation.vec().isZero(0) && m.translation.isZero(0);
}

// The rings of an axisymmetric fit's profile (FitResult::ring_profile on `grid`), found as the fit
// ties its voxels (fit.cc, MakeRingTie): a point of layer j lies in the ring of that layer whose
// radius is its distance to the layer's axis (in the xz plane) in voxels, rounded.
class RingLookup {
 public:
  RingLookup(const std::vector<RingProfilePoint>& profile, const GridGeometry& grid)
      : voxel_m_(grid.voxel_size_m.x()), axis_of_layer_(grid.dims.y(), nullptr) {
    for (std::size_t p = 0; p < profile.size(); ++p) {
      ring_.emplace(std::make_pair(profile[p].layer, profile[p].radius_voxels), p);
      if (profile[p].layer >= 0 && profile[p].layer < grid.dims.y())
        axis_of_layer_[profile[p].layer] = &profile[p];
    }
  }
  // The profile's index of the ring of layer `layer` holding `centre` (rig frame), or -1 when the
  // layer has no axis or no ring at that radius.
  long Find(int layer, const Eigen::Vector3d& centre) const {
    if (layer < 0 || layer >= static_cast<int>(axis_of_layer_.size())) return -1;
    const RingProfilePoint* axis = axis_of_layer_[layer];
    if (!axis) return -1;
    const int radius = static_cast<int>(std::lround(
        std::hypot(centre.x() - axis->axis_x_m, centre.z() - axis->axis_z_m) / voxel_m_));
    const auto it = ring_.find(std::make_pair(layer, radius));
    return it == ring_.end() ? -1 : static_cast<long>(it->second);
  }

 private:
  double voxel_m_;
  std::vector<const RingProfilePoint*> axis_of_layer_;
  std::map<std::pair<int, int>, std::size_t> ring_;  // (layer, radius) -> profile index
};

// Calls visit(centre, v, relative) for each truth voxel v the images can show (>= 1300 K with
// soot, and at least 1% of the peak emission when the truth has an emission grid): its centre in
// the rig frame and its emission over the truth's peak (1 without an emission grid).
template <typename Visit>
void ForEachVisibleVoxel(const FireVolume& truth, Visit&& visit) {
  const GridGeometry& tg = truth.geometry;
  const std::vector<float>& e = truth.emission_rgb;
  double peak = 0;
  for (std::size_t v = 0; !e.empty() && v < tg.num_voxels(); ++v)
    peak = std::max(peak, double(e[3 * v + 1]));
  for (int k = 0; k < tg.dims.z(); ++k)
    for (int j = 0; j < tg.dims.y(); ++j)
      for (int i = 0; i < tg.dims.x(); ++i) {
        const std::size_t v = tg.Flat(i, j, k);
        if (truth.temperature_k[v] < 1300 || !(truth.density_per_m3[v] > 0)) continue;
        if (!e.empty() && e[3 * v + 1] < 0.01 * peak) continue;
        visit(tg.VoxelCenter(i, j, k), v, e.empty() ? 1.0 : e[3 * v + 1] / peak);
      }
}

// Calls visit(v, f, relative) for each visible truth voxel v (ForEachVisibleVoxel) paired with
// the fitted voxel f that holds its centre (v itself on the same grid) where the fit has medium.
// Counts the visible voxels, and sums their truth density into *density (when not null).
template <typename Visit>
void ForEachScoredVoxel(const FireVolume& truth, const FireVolume& fitted,
                        const Rigid3& fit_from_truth, std::size_t* visible, double* density,
                        Visit&& visit) {
  const GridGeometry& fg = fitted.geometry;
  const bool same_grid = SameVoxelsInOneFrame(truth, fitted, fit_from_truth);
  ForEachVisibleVoxel(truth, [&](const Eigen::Vector3d& centre, std::size_t v, double relative) {
    ++*visible;
    if (density) *density += truth.density_per_m3[v];
    std::size_t f = v;
    if (!same_grid && !fg.VoxelHolding(fit_from_truth * centre, &f)) return;
    if (!(fitted.density_per_m3[f] > 0)) return;
    visit(v, f, relative);
  });
}

}  // namespace

TruthError CompareWithTruth(const FireVolume& truth, const FireVolume& fitted,
                            const Rigid3& fit_from_truth) {
  TruthError out;
  if (truth.temperature_k.empty() || truth.density_per_m3.empty() || fitted.temperature_k.empty() ||
      fitted.density_per_m3.empty()) {
    out.why_not = "a volume lacks temperature or density";
    return out;
  }
  const GridGeometry& fg = fitted.geometry;
  out.same_grid = SameVoxelsInOneFrame(truth, fitted, fit_from_truth);
  const std::vector<float>& e = truth.emission_rgb;
  // Sums over the counted voxels, plain and emission-weighted.
  double n = 0, sd = 0, sdd = 0, sf = 0, st = 0, sff = 0, stt = 0, sft = 0;
  double w = 0, wd = 0, wdd = 0, wt = 0, wtt = 0;
  const bool have_sigma = fitted.temperature_sigma_k.size() == fg.num_voxels();
  const bool have_determined = have_sigma && fitted.determined.size() == fg.num_voxels();
  double within1 = 0, within2 = 0, determined = 0, determined_dd = 0, undetermined_dd = 0;
  std::vector<double> sigmas;
  const double truth_voxel_m3 = truth.geometry.voxel_size_m.prod();
  double visible_density = 0;
  ForEachScoredVoxel(truth, fitted, fit_from_truth, &out.visible, &visible_density,
                     [&](std::size_t v, std::size_t f, double) {
                       const double x = fitted.temperature_k[f], t = truth.temperature_k[v];
                       out.fit_visible_soot += fitted.density_per_m3[f] * truth_voxel_m3;
                       n += 1;
                       sd += x - t;
                       sdd += (x - t) * (x - t);
                       sf += x;
                       st += t;
                       sff += x * x;
                       stt += t * t;
                       sft += x * t;
                       const double weight = e.empty() ? 1.0 : std::max(0.0, double(e[3 * v + 1]));
                       w += weight;
                       wd += weight * (x - t);
                       wdd += weight * (x - t) * (x - t);
                       wt += weight * t;
                       wtt += weight * t * t;
                       ++out.counted;
                       if (have_sigma) {
                         const double sigma = fitted.temperature_sigma_k[f];
                         sigmas.push_back(sigma);
                         if (std::abs(x - t) <= sigma) within1 += 1;
                         if (std::abs(x - t) <= 2 * sigma) within2 += 1;
                         if (have_determined && fitted.determined[f] > 0.5) {
                           determined += 1;
                           determined_dd += (x - t) * (x - t);
                         } else {
                           undetermined_dd += (x - t) * (x - t);
                         }
                       }
                     });
  out.truth_visible_soot = visible_density * truth_voxel_m3;
  out.compared = true;
  out.truth_soot = TotalSoot(truth);
  out.fit_soot = TotalSoot(fitted);
  if (out.counted) {
    const double mf = sf / n, mt = st / n;
    out.mean_k = sd / n;
    out.rms_k = std::sqrt(sdd / n);
    const double vf = std::max(0.0, sff / n - mf * mf), vt = std::max(0.0, stt / n - mt * mt);
    out.fit_spread_k = std::sqrt(vf);
    out.truth_spread_k = std::sqrt(vt);
    out.correlation =
        vf > 0 && vt > 0 ? std::clamp((sft / n - mf * mt) / std::sqrt(vf * vt), -1.0, 1.0) : 0.0;
  }
  if (have_sigma && out.counted) {
    out.have_sigma = true;
    out.within_1_sigma = within1 / n;
    out.within_2_sigma = within2 / n;
    out.determined_share = determined / n;
    out.have_determined = have_determined;
    if (have_determined && determined > 0)
      out.determined_rms_k = std::sqrt(determined_dd / determined);
    if (have_determined && n > determined)
      out.undetermined_rms_k = std::sqrt(undetermined_dd / (n - determined));
    std::nth_element(sigmas.begin(), sigmas.begin() + sigmas.size() / 2, sigmas.end());
    out.median_sigma_k = sigmas[sigmas.size() / 2];
  }
  if (w > 0) {
    out.weighted_mean_k = wd / w;
    out.weighted_rms_k = std::sqrt(wdd / w);
    const double mt = wt / w;
    out.weighted_truth_spread_k = std::sqrt(std::max(0.0, wtt / w - mt * mt));
  }
  return out;
}

std::vector<EmissionBandError> TemperatureErrorByEmission(const FireVolume& truth,
                                                          const FireVolume& fitted,
                                                          const std::vector<double>& edges,
                                                          const Rigid3& fit_from_truth) {
  if (truth.temperature_k.empty() || truth.density_per_m3.empty() || fitted.temperature_k.empty() ||
      fitted.density_per_m3.empty())
    throw InputError("temperature error by emission: a volume lacks temperature or density");
  if (truth.emission_rgb.size() != 3 * truth.geometry.num_voxels())
    throw InputError("temperature error by emission: the truth has no emission grid");
  if (edges.size() < 2 || !std::is_sorted(edges.begin(), edges.end()) ||
      std::adjacent_find(edges.begin(), edges.end()) != edges.end())
    throw InputError("temperature error by emission: the bands' edges must rise");
  std::vector<EmissionBandError> bands(edges.size() - 1);
  std::vector<double> sum(bands.size(), 0.0), sum_sq(bands.size(), 0.0);
  std::size_t visible = 0;
  ForEachScoredVoxel(
      truth, fitted, fit_from_truth, &visible, nullptr,
      [&](std::size_t v, std::size_t f, double relative) {
        if (relative < edges.front() || relative > edges.back()) return;
        // The band [edges[b], edges[b + 1]) holding `relative`; the last one holds its top edge.
        const std::size_t b = std::min<std::size_t>(
            bands.size() - 1,
            std::upper_bound(edges.begin(), edges.end(), relative) - edges.begin() - 1);
        const double d = double(fitted.temperature_k[f]) - truth.temperature_k[v];
        ++bands[b].counted;
        sum[b] += d;
        sum_sq[b] += d * d;
      });
  double total = 0;
  for (double x : sum_sq) total += x;
  for (std::size_t b = 0; b < bands.size(); ++b) {
    bands[b].lo = edges[b];
    bands[b].hi = edges[b + 1];
    if (bands[b].counted) {
      bands[b].rms_k = std::sqrt(sum_sq[b] / bands[b].counted);
      bands[b].mean_k = sum[b] / bands[b].counted;
    }
    bands[b].share = total > 0 ? sum_sq[b] / total : 0.0;
  }
  return bands;
}

FireVolume SampleOnGrid(const FireVolume& volume, const GridGeometry& grid,
                        const Rigid3& grid_from_volume) {
  const Rigid3 volume_from_grid = grid_from_volume.Inverse();
  FireVolume out;
  out.geometry = grid;
  const bool have_t = volume.temperature_k.size() == volume.geometry.num_voxels();
  const bool have_n = volume.density_per_m3.size() == volume.geometry.num_voxels();
  const bool have_fv = volume.soot_volume_fraction.size() == volume.geometry.num_voxels();
  float ambient = 0;
  if (have_t && !volume.temperature_k.empty())
    ambient = *std::min_element(volume.temperature_k.begin(), volume.temperature_k.end());
  if (have_t) out.temperature_k.assign(grid.num_voxels(), ambient);
  if (have_n) out.density_per_m3.assign(grid.num_voxels(), 0.0f);
  if (have_fv) out.soot_volume_fraction.assign(grid.num_voxels(), 0.0f);
  out.metadata_numbers = volume.metadata_numbers;
  out.metadata_text = volume.metadata_text;
  for (int k = 0; k < grid.dims.z(); ++k)
    for (int j = 0; j < grid.dims.y(); ++j)
      for (int i = 0; i < grid.dims.x(); ++i) {
        std::size_t from = 0;
        if (!volume.geometry.VoxelHolding(volume_from_grid * grid.VoxelCenter(i, j, k), &from))
          continue;
        const std::size_t to = grid.Flat(i, j, k);
        if (have_t) out.temperature_k[to] = volume.temperature_k[from];
        if (have_n) out.density_per_m3[to] = volume.density_per_m3[from];
        if (have_fv) out.soot_volume_fraction[to] = volume.soot_volume_fraction[from];
      }
  return out;
}

RigRegistration RegisterTruth(const std::string& truth_rig_path, const Rig& fit_rig) {
  if (truth_rig_path.empty()) return {};
  try {
    return RegisterRigs(Rig::Load(truth_rig_path), fit_rig);
  } catch (const InputError& e) {
    throw InputError("truth rig " + truth_rig_path + ": " + e.what());
  }
}

double TotalSoot(const FireVolume& volume) {
  double sum = 0;
  for (float n : volume.density_per_m3)
    if (n > 0) sum += n;
  return sum * volume.geometry.voxel_size_m.prod();
}

std::vector<RingTruth> TruthOnRings(const FireVolume& truth, const GridGeometry& fit_grid,
                                    const std::vector<RingProfilePoint>& profile,
                                    const Rigid3& fit_from_truth) {
  if (!truth.HasTemperatureAndDensity())
    throw InputError("truth on rings: the truth needs temperature and density grids");
  const RingLookup ring(profile, fit_grid);
  std::vector<double> sum(profile.size(), 0.0);
  std::vector<RingTruth> out(profile.size());
  ForEachVisibleVoxel(truth, [&](const Eigen::Vector3d& truth_centre, std::size_t v, double) {
    const Eigen::Vector3d centre = fit_from_truth * truth_centre;
    std::size_t f = 0;
    if (!fit_grid.VoxelHolding(centre, &f)) return;
    const long r = ring.Find(fit_grid.Unflat(f).y(), centre);
    if (r < 0) return;
    sum[r] += truth.temperature_k[v];
    ++out[r].voxels;
  });
  for (std::size_t p = 0; p < out.size(); ++p)
    out[p].temperature_k =
        out[p].voxels ? sum[p] / double(out[p].voxels) : std::numeric_limits<double>::quiet_NaN();
  return out;
}

FireVolume LightEquivalentTruth(const FireVolume& truth, const GridGeometry& fit_grid,
                                const AbsorptionModel& absorption, const Rigid3& fit_from_truth,
                                const std::vector<RingProfilePoint>* rings,
                                const std::vector<float>* fitted_density) {
  if (!truth.HasTemperatureAndDensity() ||
      truth.emission_rgb.size() != 3 * truth.geometry.num_voxels())
    throw InputError("light-equivalent truth: the truth needs emission, temperature and density");
  const std::size_t n = fit_grid.num_voxels();
  // Per fitted voxel: the summed emission and density of the truth voxels it holds, their count.
  std::vector<Eigen::Vector3d> light(n, Eigen::Vector3d::Zero());
  std::vector<double> soot(n, 0.0), count(n, 0.0);
  const GridGeometry& tg = truth.geometry;
  for (int k = 0; k < tg.dims.z(); ++k)
    for (int j = 0; j < tg.dims.y(); ++j)
      for (int i = 0; i < tg.dims.x(); ++i) {
        std::size_t f = 0;
        if (!fit_grid.VoxelHolding(fit_from_truth * tg.VoxelCenter(i, j, k), &f)) continue;
        const std::size_t v = tg.Flat(i, j, k);
        light[f] += Eigen::Vector3d(truth.emission_rgb[3 * v], truth.emission_rgb[3 * v + 1],
                                    truth.emission_rgb[3 * v + 2]);
        soot[f] += truth.density_per_m3[v];
        count[f] += 1;
      }
  // Each fitted voxel's light: its own, or pooled over its ring's voxels (ring_of, -1: none).
  std::vector<Eigen::Vector3d> pooled_light = light;
  std::vector<double> pooled_count = count;
  std::vector<long> ring_of(n, -1);
  const bool medium_given = fitted_density && fitted_density->size() == n;
  if (rings && !rings->empty()) {
    const RingLookup ring(*rings, fit_grid);
    std::vector<Eigen::Vector3d> ring_light(rings->size(), Eigen::Vector3d::Zero());
    std::vector<double> ring_count(rings->size(), 0.0);
    for (std::size_t f = 0; f < n; ++f) {
      // A ring's voxels: the fit's with medium (its rings hold its active voxels), else those
      // holding truth soot; either only where the truth says something (it holds a voxel).
      if (!(count[f] > 0) || !(medium_given ? (*fitted_density)[f] > 0 : soot[f] > 0)) continue;
      const Eigen::Vector3i v = fit_grid.Unflat(f);
      ring_of[f] = ring.Find(v.y(), fit_grid.VoxelCenter(v.x(), v.y(), v.z()));
      if (ring_of[f] < 0) continue;
      ring_light[ring_of[f]] += light[f];
      ring_count[ring_of[f]] += count[f];
    }
    for (std::size_t f = 0; f < n; ++f) {
      if (ring_of[f] < 0) continue;
      pooled_light[f] = ring_light[ring_of[f]];
      pooled_count[f] = ring_count[ring_of[f]];
    }
  }
  const FitOptions defaults;
  const ThinEmissionTable table(absorption, defaults.objective.t_min_k, defaults.objective.t_max_k);
  FireVolume out;
  out.geometry = fit_grid;
  out.temperature_k.assign(n, static_cast<float>(table.t_min()));
  out.density_per_m3.assign(n, 0.0f);
  for (std::size_t f = 0; f < n; ++f) {
    // A ring's voxel shows the ring's light (its share of it), soot or not; another, its own.
    if (ring_of[f] < 0 && (!(soot[f] > 0) || !(count[f] > 0))) continue;
    const Eigen::Vector3d rgb = pooled_light[f] / pooled_count[f];  // per truth voxel
    const double t = table.TemperatureOf(rgb);
    const double per = table.RgbPerDensity(t).sum();
    out.temperature_k[f] = static_cast<float>(t);
    out.density_per_m3[f] = static_cast<float>(per > 0 && rgb.sum() > 0 && std::isfinite(rgb.sum())
                                                   ? rgb.sum() / per
                                                   : soot[f] / count[f]);
  }
  return out;
}

TruthError CompareLimitWithTruth(const FireVolume& truth, const FireVolume& fitted,
                                 const AbsorptionModel& absorption,
                                 const std::vector<RingProfilePoint>& rings,
                                 const Rigid3& fit_from_truth) {
  if (!truth.HasTemperatureAndDensity() ||
      truth.emission_rgb.size() != 3 * truth.geometry.num_voxels()) {
    TruthError none;
    none.why_not = "the truth has no emission, temperature or density grid";
    return none;
  }
  return CompareWithTruth(truth,
                          LightEquivalentTruth(truth, fitted.geometry, absorption, fit_from_truth,
                                               &rings, &fitted.density_per_m3),
                          fit_from_truth);
}

double EmissionError(const FireVolume& reconstruction, const FireVolume& truth,
                     const std::string& truth_name) {
  if (truth.emission_rgb.empty()) throw DataError(truth_name + ": has no 'emission' grid");
  const std::vector<float> t =
      truth.geometry.SameVoxels(reconstruction.geometry)
          ? truth.emission_rgb
          : ResampleEmission(truth.geometry, truth.emission_rgb, reconstruction.geometry);
  double num = 0, den = 0;
  for (std::size_t i = 0; i < t.size(); ++i) {
    const double d = double(reconstruction.emission_rgb[i]) - t[i];
    num += d * d;
    den += double(t[i]) * t[i];
  }
  return den > 0 ? std::sqrt(num / den) : 0.0;
}

}  // namespace flamerig
