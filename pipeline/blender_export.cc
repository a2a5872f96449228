#include "pipeline/blender_export.h"

#include <openvdb/openvdb.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <mutex>
#include <stdexcept>

#include "core/atomic_file.h"
#include "core/error.h"
#include "fitting/fit.h"

namespace flamerig {

namespace {

// Index (i, j, k) -> voxel centre in Blender's Z-up world: rig (x, y, z) -> (x, -z, y).
// Blender's Z up from the rig's up: R0 takes a y-up rig to Blender, (x, -z, y); a rig with another
// up is first turned so that its up is y by the smallest rotation (about x, by half a turn, for
// the first camera's frame, whose up is -y: (x, z, -y) in all).
Eigen::Matrix3d BlenderFromRig(const Eigen::Vector3d& up_in_rig) {
  Eigen::Matrix3d r0;
  r0 << 1, 0, 0, 0, 0, -1, 0, 1, 0;
  const Eigen::Vector3d u = up_in_rig.normalized();
  Eigen::Matrix3d q;
  if (u.y() < -1 + 1e-9)
    q = Eigen::Vector3d(1, -1, -1).asDiagonal();
  else
    q = Eigen::Quaterniond::FromTwoVectors(u, Eigen::Vector3d::UnitY()).toRotationMatrix();
  return r0 * q;
}

openvdb::math::Transform::Ptr BlenderTransform(const GridGeometry& g, const Eigen::Vector3d& up) {
  // rig = t + diag(s) ijk; blender = R rig. OpenVDB applies row vectors (world = index * M), so
  // row a of M's 3x3 part is where index axis a goes: R's column a, times the voxel's size.
  const Eigen::Matrix3d r = BlenderFromRig(up);
  const Eigen::Vector3d s = g.voxel_size_m;
  const Eigen::Vector3d t = r * (g.origin_in_rig + 0.5 * s);
  openvdb::math::Mat4d m = openvdb::math::Mat4d::identity();
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) m(a, b) = r(b, a) * s[a];
  m.setTranslation(openvdb::Vec3d(t.x(), t.y(), t.z()));
  return openvdb::math::Transform::createLinearTransform(m);
}

template <typename GridT, typename Get>
typename GridT::Ptr MakeGrid(const GridGeometry& g, const Eigen::Vector3d& up_in_rig,
                             const std::string& name, const std::string& units, Get get) {
  auto grid = GridT::create();
  grid->setName(name);
  grid->setTransform(BlenderTransform(g, up_in_rig));
  grid->insertMeta("units", openvdb::StringMetadata(units));
  auto acc = grid->getAccessor();
  for (int k = 0; k < g.dims.z(); ++k)
    for (int j = 0; j < g.dims.y(); ++j)
      for (int i = 0; i < g.dims.x(); ++i) {
        const std::size_t v = g.Flat(i, j, k);
        typename GridT::ValueType value;
        if (get(v, &value)) acc.setValue(openvdb::Coord(i, j, k), value);
      }
  return grid;
}

}  // namespace

BlenderGrids MakeBlenderGrids(const FireVolume& fitted, const AbsorptionModel& absorption) {
  const GridGeometry& g = fitted.geometry;
  const std::size_t n = g.num_voxels();
  if (!fitted.HasTemperatureAndDensity())
    throw InputError("Blender export: the volume needs temperature and density grids");
  BlenderGrids out;
  out.density_per_m.assign(n, 0.0f);
  out.temperature_k.assign(n, 0.0f);
  out.emission_rgb_per_m.assign(3 * n, 0.0f);
  out.flame.assign(n, 0.0f);
  double t_lo = 1e300, t_hi = -1e300;
  for (std::size_t v = 0; v < n; ++v) {
    if (!(fitted.density_per_m3[v] > 0)) continue;
    t_lo = std::min(t_lo, double(fitted.temperature_k[v]));
    t_hi = std::max(t_hi, double(fitted.temperature_k[v]));
  }
  if (t_lo > t_hi) return out;  // no medium: an empty (but valid) volume
  const double sigma_550 = absorption.CrossSectionM2(550.0);
  const ThinEmissionTable table(absorption, std::max(1.0, std::floor(t_lo)),
                                std::max(2.0, std::ceil(t_hi) + 1));
  for (std::size_t v = 0; v < n; ++v) {
    const double density = fitted.density_per_m3[v];
    if (!(density > 0)) continue;
    const double t = fitted.temperature_k[v];
    out.density_per_m[v] = static_cast<float>(sigma_550 * density);
    out.temperature_k[v] = static_cast<float>(t);
    const Eigen::Vector3d e = density * table.RgbPerDensity(t);
    for (int c = 0; c < 3; ++c) out.emission_rgb_per_m[3 * v + c] = static_cast<float>(e[c]);
    out.flame[v] = static_cast<float>(0.2126 * e[0] + 0.7152 * e[1] + 0.0722 * e[2]);
  }
  return out;
}

void WriteBlenderVdb(const std::string& path, const FireVolume& fitted,
                     const AbsorptionModel& absorption, const Eigen::Vector3d& up_in_rig) {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
  const BlenderGrids b = MakeBlenderGrids(fitted, absorption);
  const GridGeometry& g = fitted.geometry;
  auto scalar = [&](const std::vector<float>& values) {
    return [&values](std::size_t v, float* out) {
      *out = values[v];
      return values[v] != 0.0f;
    };
  };
  openvdb::GridPtrVec grids;
  grids.push_back(MakeGrid<openvdb::FloatGrid>(
      g, up_in_rig, "density", "1/m (absorption at 550 nm)", scalar(b.density_per_m)));
  grids.push_back(MakeGrid<openvdb::FloatGrid>(g, up_in_rig, "temperature",
                                               "K (0 outside the soot)", scalar(b.temperature_k)));
  grids.push_back(MakeGrid<openvdb::Vec3SGrid>(
      g, up_in_rig, "emission", "linear sRGB radiance per metre (W m^-2 sr^-1 nm^-1 m^-1)",
      [&](std::size_t v, openvdb::Vec3s* out) {
        const float* e = &b.emission_rgb_per_m[3 * v];
        *out = openvdb::Vec3s(e[0], e[1], e[2]);
        return e[0] != 0.0f || e[1] != 0.0f || e[2] != 0.0f;
      }));
  grids.push_back(MakeGrid<openvdb::FloatGrid>(g, up_in_rig, "flame",
                                               "luminance of emission per metre", scalar(b.flame)));
  openvdb::MetaMap meta;
  meta.insertMeta("creator", openvdb::StringMetadata("flamerig (Blender export, Z up)"));
  for (const char* key : {"exposure", "mean_delta_e", "frame", "source_frame_id", "no_fire"}) {
    auto it = fitted.metadata_numbers.find(key);
    if (it != fitted.metadata_numbers.end())
      meta.insertMeta(key, openvdb::DoubleMetadata(it->second));
  }
  meta.insertMeta("absorption_model", openvdb::StringMetadata(absorption.name()));
  AtomicFile out(path);
  try {
    openvdb::io::File file(out.temp_path());
    file.write(grids, meta);
    file.close();
  } catch (const openvdb::Exception& e) {
    throw IoError(path + ": cannot write VDB: " + e.what());
  }
  out.Commit();
}

}  // namespace flamerig
