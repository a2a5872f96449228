#include "pipeline/truth.h"

#include <algorithm>
#include <cmath>

#include "core/error.h"
#include "tomography/reconstruct.h"

namespace flamerig {

TruthError CompareWithTruth(const FireVolume& truth, const FireVolume& fitted) {
  TruthError out;
  if (truth.temperature_k.empty() || truth.density_per_m3.empty() || fitted.temperature_k.empty() ||
      fitted.density_per_m3.empty()) {
    out.why_not = "a volume lacks temperature or density";
    return out;
  }
  const GridGeometry& tg = truth.geometry;
  const GridGeometry& fg = fitted.geometry;
  out.same_grid = tg.SameVoxels(fg);
  const std::vector<float>& e = truth.emission_rgb;
  double peak = 0;
  for (std::size_t v = 0; !e.empty() && v < tg.num_voxels(); ++v)
    peak = std::max(peak, double(e[3 * v + 1]));
  double se = 0, bias = 0;
  for (int k = 0; k < tg.dims.z(); ++k)
    for (int j = 0; j < tg.dims.y(); ++j)
      for (int i = 0; i < tg.dims.x(); ++i) {
        const std::size_t v = tg.Flat(i, j, k);
        if (truth.temperature_k[v] < 1300 || !(truth.density_per_m3[v] > 0)) continue;
        if (!e.empty() && e[3 * v + 1] < 0.01 * peak) continue;
        ++out.visible;
        std::size_t f = v;
        if (!out.same_grid) {
          const Eigen::Vector3d at = fg.IndexFromRig(tg.VoxelCenter(i, j, k)).array().round();
          if ((at.array() < 0).any() || (at.array() >= fg.dims.cast<double>().array()).any())
            continue;
          f = fg.Flat(int(at.x()), int(at.y()), int(at.z()));
        }
        if (!(fitted.density_per_m3[f] > 0)) continue;
        const double d = double(fitted.temperature_k[f]) - truth.temperature_k[v];
        se += d * d;
        bias += d;
        ++out.counted;
      }
  out.compared = true;
  if (out.counted) {
    out.rms_k = std::sqrt(se / out.counted);
    out.mean_k = bias / out.counted;
  }
  return out;
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
