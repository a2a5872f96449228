// Voxel grids: a regular lattice of voxels over a box of the rig frame, and the fire fields on it.
//
// Geometry. A grid has dims (nx, ny, nz) voxels of size voxel_size_m (per axis, metres) starting at
// origin_in_rig, the min corner of its box. Voxel (i, j, k) covers
// [origin + (i, j, k) * size, origin + (i+1, j+1, k+1) * size) and its centre is at
// origin + (i + 0.5, j + 0.5, k + 0.5) * size. "Index coordinates" are continuous coordinates in
// which voxel centres sit at integers: index = (point_in_rig - origin) / size - 0.5.
//
// Flattening (the one place this is defined): a field's values are stored x fastest, then y, then
// z: flat = i + nx * (j + ny * k). Multi-channel fields interleave channels per voxel (flat * 3 +
// c).
//
// Fields (FireVolume): temperature in kelvin, soot number density in particles per m^3, an RGB
// emission (linear, in the renderer's units) and free metadata (exposure, density scale, units...).
// Any field may be absent (empty vector).
#ifndef FLAMERIG_TOMOGRAPHY_VOLUME_H_
#define FLAMERIG_TOMOGRAPHY_VOLUME_H_

#include <Eigen/Core>
#include <cstddef>
#include <map>
#include <string>
#include <vector>

#include "calibration/rig.h"

namespace flamerig {

struct GridGeometry {
  Eigen::Vector3i dims = Eigen::Vector3i::Zero();           // nx, ny, nz
  Eigen::Vector3d origin_in_rig = Eigen::Vector3d::Zero();  // min corner of the box, metres
  Eigen::Vector3d voxel_size_m = Eigen::Vector3d::Ones();   // per axis, metres

  // Cubic voxels covering `box`: `resolution` voxels along its longest axis, and as many as fit
  // (rounded, at least 1) along the others; the grid is centred on the box. Throws
  // InputError for an invalid box or resolution < 1.
  static GridGeometry FromBox(const Box3& box, int resolution);
  // Exactly `dims` voxels spanning `box` (voxels may be non-cubic).
  static GridGeometry FromBoxAndDims(const Box3& box, const Eigen::Vector3i& dims);

  std::size_t num_voxels() const {
    return static_cast<std::size_t>(dims.x()) * dims.y() * dims.z();
  }
  std::size_t Flat(int i, int j, int k) const {
    return static_cast<std::size_t>(i) +
           static_cast<std::size_t>(dims.x()) * (j + static_cast<std::size_t>(dims.y()) * k);
  }
  // The inverse of Flat: (i, j, k) of a flat index below num_voxels().
  Eigen::Vector3i Unflat(std::size_t flat) const {
    const std::size_t nx = static_cast<std::size_t>(dims.x()),
                      ny = static_cast<std::size_t>(dims.y());
    return Eigen::Vector3i(static_cast<int>(flat % nx), static_cast<int>((flat / nx) % ny),
                           static_cast<int>(flat / (nx * ny)));
  }
  Eigen::Vector3d VoxelCenter(int i, int j, int k) const {
    return RigFromIndex(Eigen::Vector3d(i, j, k));
  }
  // The point at fractional voxel indices (whole ones: the voxel's centre); IndexFromRig's inverse.
  Eigen::Vector3d RigFromIndex(const Eigen::Vector3d& index) const {
    return origin_in_rig + (index.array() + 0.5).matrix().cwiseProduct(voxel_size_m);
  }
  Eigen::Vector3d IndexFromRig(const Eigen::Vector3d& point_in_rig) const {
    return ((point_in_rig - origin_in_rig).cwiseQuotient(voxel_size_m).array() - 0.5).matrix();
  }
  // The voxel that holds `point_in_rig` (its flat index), false when the point is outside.
  bool VoxelHolding(const Eigen::Vector3d& point_in_rig, std::size_t* flat) const {
    const Eigen::Vector3d at = IndexFromRig(point_in_rig).array().round();
    if ((at.array() < 0).any() || (at.array() >= dims.cast<double>().array()).any()) return false;
    *flat = Flat(int(at.x()), int(at.y()), int(at.z()));
    return true;
  }
  Box3 box() const {
    return Box3{origin_in_rig, origin_in_rig + dims.cast<double>().cwiseProduct(voxel_size_m)};
  }
  // Throws InputError naming the bad member: dims >= 1, the origin finite and within
  // kMaxExtentM of the rig's, voxels at least kMinVoxelSizeM and the grid at most kMaxExtentM
  // across (a fire is millimetres to kilometres across; far outside is a damaged file).
  static constexpr double kMinVoxelSizeM = 1e-9, kMaxExtentM = 1e6;
  void Validate() const;
  bool operator==(const GridGeometry& o) const {
    return dims == o.dims && origin_in_rig == o.origin_in_rig && voxel_size_m == o.voxel_size_m;
  }
  // The same voxels up to rounding (a grid read back from a file): equal dims, origin and voxel
  // size within 1e-6 of a voxel.
  bool SameVoxels(const GridGeometry& o) const {
    const double tol = 1e-6 * voxel_size_m.minCoeff();
    return dims == o.dims && (origin_in_rig - o.origin_in_rig).cwiseAbs().maxCoeff() <= tol &&
           (voxel_size_m - o.voxel_size_m).cwiseAbs().maxCoeff() <= tol;
  }
};

struct FireVolume {
  GridGeometry geometry;
  std::vector<float> temperature_k;   // num_voxels values, or empty
  std::vector<float> density_per_m3;  // num_voxels values, or empty
  std::vector<float> emission_rgb;    // 3 * num_voxels values (interleaved RGB), or empty
  // A fit's per-voxel confidence (fitting/uncertainty.h), each num_voxels values or empty; 0 where
  // the fit has no medium: the standard deviation of the temperature (K) and of the natural log of
  // the density (a relative error: 0.1 is about 10%), and 1 where the images determine the voxel's
  // temperature, 0 where the prior does.
  std::vector<float> temperature_sigma_k;
  std::vector<float> density_sigma;
  std::vector<float> determined;
  // The soot's volume fraction (m^3 of soot per m^3; a candle peaks near 1e-6), num_voxels values
  // or empty: the density times one particle's volume, written beside the density when the
  // absorption model is soot (fitting/absorption.h, StampAbsorption). In the Rayleigh limit the
  // images determine it whatever particle size is assumed, where the number density scales as
  // 1 / radius^3.
  std::vector<float> soot_volume_fraction;
  std::map<std::string, double> metadata_numbers;    // e.g. "exposure", "density_scale"
  std::map<std::string, std::string> metadata_text;  // e.g. "absorption_model"

  // Checks sizes and that every value is finite, and temperature and density non-negative (emission
  // may be negative: linear sRGB of deep-red fire colours is out of gamut); throws
  // InputError naming the field and the first bad voxel (its i, j, k).
  void Validate() const;
  // Both temperature and density hold a value per voxel (a fit's or a truth's volume; a
  // tomography's has emission only).
  bool HasTemperatureAndDensity() const {
    return temperature_k.size() == geometry.num_voxels() &&
           density_per_m3.size() == geometry.num_voxels();
  }
};

}  // namespace flamerig

#endif  // FLAMERIG_TOMOGRAPHY_VOLUME_H_
