// A small fire for the fuzz targets' seeds and the files they refer to: `dims` voxels of 5 mm at
// room temperature without soot, except one hot sooty voxel (1800 K, 1e16 particles per m^3).
#ifndef FLAMERIG_TESTS_FUZZ_SMALL_FIRE_H_
#define FLAMERIG_TESTS_FUZZ_SMALL_FIRE_H_

#include "tomography/vdb_io.h"

namespace flamerig_fuzz {

inline flamerig::FireVolume SmallFire(const Eigen::Vector3i& dims, int hot_voxel) {
  flamerig::FireVolume v;
  v.geometry.dims = dims;
  v.geometry.origin_in_rig = Eigen::Vector3d(-0.01, 0, -0.01);
  v.geometry.voxel_size_m = Eigen::Vector3d::Constant(0.005);
  v.temperature_k.assign(v.geometry.num_voxels(), 300.0f);
  v.density_per_m3.assign(v.geometry.num_voxels(), 0.0f);
  v.temperature_k[hot_voxel] = 1800;
  v.density_per_m3[hot_voxel] = 1e16f;
  return v;
}

}  // namespace flamerig_fuzz

#endif  // FLAMERIG_TESTS_FUZZ_SMALL_FIRE_H_
