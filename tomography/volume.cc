#include "tomography/volume.h"

#include <cmath>
#include <stdexcept>

#include "core/error.h"

namespace flamerig {

GridGeometry GridGeometry::FromBox(const Box3& box, int resolution) {
  if (!box.IsValid()) throw InputError("grid box: max must exceed min on every axis");
  if (resolution < 1) {
    throw InputError("grid resolution " + std::to_string(resolution) + " must be >= 1");
  }
  Eigen::Vector3d size = box.size();
  double voxel = size.maxCoeff() / resolution;
  GridGeometry g;
  for (int a = 0; a < 3; ++a)
    g.dims[a] = std::max(1, static_cast<int>(std::lround(size[a] / voxel)));
  g.voxel_size_m = Eigen::Vector3d::Constant(voxel);
  Eigen::Vector3d extent = g.dims.cast<double>() * voxel;
  g.origin_in_rig = box.center() - 0.5 * extent;
  return g;
}

GridGeometry GridGeometry::FromBoxAndDims(const Box3& box, const Eigen::Vector3i& dims) {
  if (!box.IsValid()) throw InputError("grid box: max must exceed min on every axis");
  if ((dims.array() < 1).any()) throw InputError("grid dims must all be >= 1");
  GridGeometry g;
  g.dims = dims;
  g.origin_in_rig = box.min_in_rig;
  g.voxel_size_m = box.size().cwiseQuotient(dims.cast<double>());
  return g;
}

void GridGeometry::Validate() const {
  if ((dims.array() < 1).any()) throw InputError("grid dims must all be >= 1");
  // A fire is millimetres to kilometres across: sizes and places far outside that are a damaged
  // file, and would overflow the ray marcher's arithmetic.
  if (!origin_in_rig.allFinite() || (origin_in_rig.array().abs() > kMaxExtentM).any())
    throw InputError("grid origin_in_rig must be finite and within 1e6 m of the rig's origin");
  if (!voxel_size_m.allFinite() || (voxel_size_m.array() < kMinVoxelSizeM).any() ||
      (voxel_size_m.cwiseProduct(dims.cast<double>()).array() > kMaxExtentM).any()) {
    throw InputError(
        "grid voxel_size_m must be finite and at least 1e-9 m, and the grid at most "
        "1e6 m across");
  }
}

namespace {

void CheckField(const GridGeometry& g, const std::vector<float>& values, int channels,
                const char* name, bool allow_negative) {
  if (values.empty()) return;
  if (values.size() != g.num_voxels() * channels) {
    throw InputError(std::string("field '") + name + "' has " + std::to_string(values.size()) +
                     " values, expected " + std::to_string(g.num_voxels() * channels));
  }
  for (std::size_t n = 0; n < values.size(); ++n) {
    float v = values[n];
    if (!std::isfinite(v) || (v < 0 && !allow_negative)) {
      const Eigen::Vector3i at = g.Unflat(n / channels);
      throw InputError(
          std::string("field '") + name + "' at voxel (" + std::to_string(at.x()) + ", " +
          std::to_string(at.y()) + ", " + std::to_string(at.z()) + ") is " + std::to_string(v) +
          (allow_negative ? "; values must be finite" : "; values must be finite and >= 0"));
    }
  }
}

}  // namespace

void FireVolume::Validate() const {
  geometry.Validate();
  CheckField(geometry, temperature_k, 1, "temperature", false);
  CheckField(geometry, density_per_m3, 1, "density", false);
  // Linear sRGB emission of out-of-gamut (deep red) fire colours has negative components.
  CheckField(geometry, emission_rgb, 3, "emission", true);
  CheckField(geometry, temperature_sigma_k, 1, "temperature_sigma", false);
  CheckField(geometry, density_sigma, 1, "density_sigma", false);
  CheckField(geometry, determined, 1, "determined", false);
  CheckField(geometry, soot_volume_fraction, 1, "soot_volume_fraction", false);
}

}  // namespace flamerig
