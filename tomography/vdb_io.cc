#include "tomography/vdb_io.h"

#include <openvdb/io/Stream.h>
#include <openvdb/openvdb.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <ios>
#include <mutex>
#include <stdexcept>
#include <string>

#include "core/atomic_file.h"
#include "core/error.h"
#include "core/memory.h"

namespace flamerig {
namespace {

void InitializeOpenVdb() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

openvdb::math::Transform::Ptr MakeTransform(const GridGeometry& g) {
  openvdb::math::Mat4d m = openvdb::math::Mat4d::identity();
  for (int a = 0; a < 3; ++a) m(a, a) = g.voxel_size_m[a];
  Eigen::Vector3d t = g.origin_in_rig + 0.5 * g.voxel_size_m;
  m.setTranslation(openvdb::Vec3d(t.x(), t.y(), t.z()));
  return openvdb::math::Transform::createLinearTransform(m);
}

template <typename GridT>
void StampGeometry(GridT& grid, const GridGeometry& g, const std::string& units) {
  grid.setTransform(MakeTransform(g));
  grid.insertMeta("flamerig_dims",
                  openvdb::Vec3IMetadata(openvdb::Vec3i(g.dims.x(), g.dims.y(), g.dims.z())));
  grid.insertMeta("units", openvdb::StringMetadata(units));
}

openvdb::FloatGrid::Ptr MakeFloatGrid(const GridGeometry& g, const std::vector<float>& values,
                                      const std::string& name, const std::string& units) {
  auto grid = openvdb::FloatGrid::create(0.0f);
  grid->setName(name);
  StampGeometry(*grid, g, units);
  auto acc = grid->getAccessor();
  for (int k = 0; k < g.dims.z(); ++k)
    for (int j = 0; j < g.dims.y(); ++j)
      for (int i = 0; i < g.dims.x(); ++i) {
        float v = values[g.Flat(i, j, k)];
        if (v != 0.0f) acc.setValue(openvdb::Coord(i, j, k), v);
      }
  return grid;
}

// Recovers the geometry from a grid's transform and metadata; throws on an unsupported transform.
GridGeometry GeometryOf(const openvdb::GridBase& grid, const std::string& path) {
  const openvdb::math::Transform& xf = grid.transform();
  if (!xf.isLinear())
    throw DataError(path + ": grid '" + grid.getName() + "' has a non-linear transform");
  openvdb::math::Mat4d m = xf.baseMap()->getAffineMap()->getMat4();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      if (r != c && std::abs(m(r, c)) > 1e-12 * std::abs(m(r, r))) {
        throw DataError(path + ": grid '" + grid.getName() +
                        "' is rotated or sheared; only axis-aligned grids are supported");
      }
  GridGeometry g;
  for (int a = 0; a < 3; ++a) g.voxel_size_m[a] = m(a, a);
  if ((g.voxel_size_m.array() <= 0).any()) {
    throw DataError(path + ": grid '" + grid.getName() + "' has a non-positive voxel size");
  }
  openvdb::Vec3d t = m.getTranslation();
  Eigen::Vector3d center0(t.x(), t.y(), t.z());
  openvdb::Coord lo(0, 0, 0);
  auto dims_meta = grid.getMetadata<openvdb::Vec3IMetadata>("flamerig_dims");
  if (dims_meta) {
    openvdb::Vec3i d = dims_meta->value();
    g.dims = Eigen::Vector3i(d.x(), d.y(), d.z());
  } else {
    openvdb::CoordBBox bbox = grid.evalActiveVoxelBoundingBox();
    if (bbox.empty())
      throw DataError(path + ": grid '" + grid.getName() + "' has no active voxels");
    lo = bbox.min();
    openvdb::Coord ext = bbox.dim();
    g.dims = Eigen::Vector3i(ext.x(), ext.y(), ext.z());
  }
  if ((g.dims.array() < 1).any() || g.num_voxels() > (std::size_t(1) << 31)) {
    throw DataError(path + ": grid '" + grid.getName() + "' has unusable dimensions");
  }
  Eigen::Vector3d lo_d(lo.x(), lo.y(), lo.z());
  g.origin_in_rig = center0 + lo_d.cwiseProduct(g.voxel_size_m) - 0.5 * g.voxel_size_m;
  return g;
}

// The float grids, as stored: name, the FireVolume field, the unit written beside it.
struct ScalarGrid {
  const char* name;
  std::vector<float> FireVolume::*field;
  const char* unit;
};
constexpr ScalarGrid kScalarGrids[] = {
    {"temperature", &FireVolume::temperature_k, "K"},
    {"density", &FireVolume::density_per_m3, "m^-3"},
    {"temperature_sigma", &FireVolume::temperature_sigma_k, "K"},
    {"density_sigma", &FireVolume::density_sigma, "sigma of ln density"},
    {"determined", &FireVolume::determined, "1 = by the images"},
    {"soot_volume_fraction", &FireVolume::soot_volume_fraction, "m^3 of soot per m^3"}};

// The field a float grid called `name` is read into, or nullptr for a grid flamerig does not read.
std::vector<float>* ScalarField(FireVolume& volume, const std::string& name) {
  for (const ScalarGrid& s : kScalarGrids)
    if (name == s.name) return &(volume.*s.field);
  return nullptr;
}

// Refuses a lattice whose dense fields (floats_per_voxel floats a voxel) need more than max_bytes
// (0: the machine's physical memory), before any is allocated.
void CheckFieldsFit(const GridGeometry& g, std::size_t floats_per_voxel, std::size_t max_bytes,
                    const std::string& path) {
  const bool machine = max_bytes == 0;
  if (machine) max_bytes = PhysicalMemoryBytes();
  if (max_bytes == 0) return;
  const double need = double(g.num_voxels()) * double(floats_per_voxel) * sizeof(float);
  if (need <= double(max_bytes)) return;
  char text[256];
  std::snprintf(text, sizeof text,
                ": its lattice of %d x %d x %d voxels needs %.1f GB for its %zu field values a "
                "voxel, more than the %.1f GB %s (a damaged flamerig_dims, or a volume too large "
                "to read here)",
                g.dims.x(), g.dims.y(), g.dims.z(), need / 1e9, floats_per_voxel, max_bytes / 1e9,
                machine ? "of this machine's memory" : "allowed");
  throw DataError(path + text);
}

openvdb::Coord OffsetOf(const openvdb::GridBase& grid) {
  if (grid.getMetadata<openvdb::Vec3IMetadata>("flamerig_dims")) return openvdb::Coord(0, 0, 0);
  return grid.evalActiveVoxelBoundingBox().min();
}

}  // namespace

void WriteVdb(const std::string& path, const FireVolume& volume) {
  volume.Validate();
  if (volume.temperature_k.empty() && volume.density_per_m3.empty() &&
      volume.emission_rgb.empty()) {
    throw InputError(path + ": the volume has no field to write");
  }
  InitializeOpenVdb();
  const GridGeometry& g = volume.geometry;
  openvdb::GridPtrVec grids;
  for (const ScalarGrid& s : kScalarGrids)
    if (!(volume.*s.field).empty())
      grids.push_back(MakeFloatGrid(g, volume.*s.field, s.name, s.unit));
  if (!volume.emission_rgb.empty()) {
    auto grid = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.0f));
    grid->setName("emission");
    StampGeometry(*grid, g, "linear RGB radiance (renderer units)");
    auto acc = grid->getAccessor();
    for (int k = 0; k < g.dims.z(); ++k)
      for (int j = 0; j < g.dims.y(); ++j)
        for (int i = 0; i < g.dims.x(); ++i) {
          const float* e = &volume.emission_rgb[3 * g.Flat(i, j, k)];
          if (e[0] != 0.0f || e[1] != 0.0f || e[2] != 0.0f) {
            acc.setValue(openvdb::Coord(i, j, k), openvdb::Vec3s(e[0], e[1], e[2]));
          }
        }
    grids.push_back(grid);
  }
  openvdb::MetaMap meta;
  meta.insertMeta("creator", openvdb::StringMetadata("flamerig"));
  for (const auto& [key, value] : volume.metadata_numbers)
    meta.insertMeta(key, openvdb::DoubleMetadata(value));
  for (const auto& [key, value] : volume.metadata_text)
    meta.insertMeta(key, openvdb::StringMetadata(value));

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

namespace {

// An exception's text as a message can hold it: OpenVDB puts names read from a damaged file into
// its messages (a grid type of 22,000 spaces). Runs of spaces and bytes outside printable ASCII
// become one space; at most 200 characters are kept.
std::string Printable(const std::string& text) {
  std::string out;
  for (char c : text) {
    const bool printable = c > ' ' && c < 127;
    if (printable)
      out += c;
    else if (!out.empty() && out.back() != ' ')
      out += ' ';
    if (out.size() >= 200) return out + "...";
  }
  return out;
}

}  // namespace

FireVolume ReadVdb(const std::string& path, std::size_t max_bytes) {
  InitializeOpenVdb();
  if (!std::filesystem::exists(path)) throw InputError(path + ": no such file");
  FireVolume volume;
  openvdb::GridPtrVecPtr grids;
  openvdb::MetaMap::Ptr meta;
  // Read first as a stream that throws at its end: OpenVDB does not check its reads, so a cut
  // file went on with whatever its variables held (cut at 500 bytes: a grid type of 2 GB of
  // spaces, 15 GB of memory and a 2 GB error message). A file the stream reader refuses for any
  // other reason is read again by io::File, which seeks to each grid where the stream reads on
  // (a damaged file found by fuzzing fails in the stream's metadata, and in io::File's blosc
  // chunk, where tomography/openvdb_blosc_guard.cc catches it). Every voxel is read now (no
  // delayed loading): the grids are used whole at once, and a damaged file's delayed-load table
  // made OpenVDB abort on an assertion when it skipped a leaf (tests/fuzz/regressions/vdb).
  try {
    try {
      std::ifstream in(path, std::ios::binary);
      if (!in) throw IoError(path + ": cannot open");
      in.exceptions(std::ios::failbit | std::ios::badbit);
      openvdb::io::Stream stream(in, /*delayLoad=*/false);
      grids = stream.getGrids();
      meta = stream.getMetadata();
    } catch (const std::ios_base::failure&) {
      std::error_code ec;
      throw DataError(path + ": not a readable VDB file: it ends before its grids do (" +
                      std::to_string(std::filesystem::file_size(path, ec)) +
                      " bytes: cut short, or damaged)");
    } catch (const openvdb::Exception&) {
      openvdb::io::File file(path);
      file.open(/*delayLoad=*/false);
      grids = file.getGrids();
      meta = file.getMetadata();
      file.close();
    }
  } catch (const Error&) {
    throw;
  } catch (const openvdb::Exception& e) {
    throw DataError(path + ": not a readable VDB file: " + Printable(e.what()));
  } catch (const std::bad_alloc&) {
    // OpenVDB trusts the sizes a file states (found by fuzzing: a damaged name length asked for
    // gigabytes); when the allocation fails, say which file.
    throw DataError(path + ": not a readable VDB file: it states sizes it cannot have");
  } catch (const std::exception& e) {
    throw DataError(path + ": not a readable VDB file: " + Printable(e.what()));
  }
  // Floats per voxel of the dense fields to be read: one per known scalar grid, three for emission.
  std::size_t floats_per_voxel = 0;
  for (const auto& base : *grids) {
    const std::string& name = base->getName();
    if (name == "emission")
      floats_per_voxel += 3;
    else if (ScalarField(volume, name))
      floats_per_voxel += 1;
  }
  bool have_geometry = false;
  auto adopt_geometry = [&](const openvdb::GridBase& grid) {
    GridGeometry g = GeometryOf(grid, path);
    if (!have_geometry) {
      CheckFieldsFit(g, floats_per_voxel, max_bytes, path);
      volume.geometry = g;
      have_geometry = true;
    } else if (!(g.dims == volume.geometry.dims) ||
               !g.origin_in_rig.isApprox(volume.geometry.origin_in_rig, 1e-9) ||
               !g.voxel_size_m.isApprox(volume.geometry.voxel_size_m, 1e-12)) {
      throw DataError(path + ": grid '" + grid.getName() +
                      "' does not share the lattice of the other grids");
    }
  };
  // Calls store(flat index, value) for every active voxel of `grid` inside the lattice adopted
  // (voxels outside it are ignored). A tile's box is clipped to the lattice first: a root tile
  // spans 4096^3 voxels, and a file with one and a small flamerig_dims took minutes here.
  auto for_each_voxel = [&](const auto& grid, const auto& store) {
    const GridGeometry& g = volume.geometry;
    const openvdb::Coord off = OffsetOf(grid);
    const openvdb::CoordBBox lattice(
        off, off + openvdb::Coord(g.dims.x() - 1, g.dims.y() - 1, g.dims.z() - 1));
    for (auto it = grid.cbeginValueOn(); it; ++it) {
      openvdb::CoordBBox box;
      it.getBoundingBox(box);
      box.intersect(lattice);
      if (box.empty()) continue;
      for (auto c = box.begin(); c; ++c) {
        const openvdb::Coord ijk = *c - off;
        if (ijk.x() < 0 || ijk.y() < 0 || ijk.z() < 0 || ijk.x() >= g.dims.x() ||
            ijk.y() >= g.dims.y() || ijk.z() >= g.dims.z())
          continue;
        store(g.Flat(ijk.x(), ijk.y(), ijk.z()), *it);
      }
    }
  };
  // OpenVDB checks a grid's transform only when it is used (a zero scale throws its own
  // ArithmeticError from getAffineMap): its messages get the file's name.
  try {
    for (const auto& base : *grids) {
      const std::string name = base->getName();
      std::vector<float>* field = ScalarField(volume, name);
      if (field) {
        auto grid = openvdb::gridConstPtrCast<openvdb::FloatGrid>(base);
        if (!grid) throw DataError(path + ": grid '" + name + "' is not a float grid");
        adopt_geometry(*grid);
        field->assign(volume.geometry.num_voxels(), 0.0f);
        for_each_voxel(*grid, [&](std::size_t f, float v) { (*field)[f] = v; });
      } else if (name == "emission") {
        auto grid = openvdb::gridConstPtrCast<openvdb::Vec3SGrid>(base);
        if (!grid) throw DataError(path + ": grid 'emission' is not a Vec3s grid");
        adopt_geometry(*grid);
        volume.emission_rgb.assign(3 * volume.geometry.num_voxels(), 0.0f);
        for_each_voxel(*grid, [&](std::size_t f, const openvdb::Vec3s& v) {
          for (int ch = 0; ch < 3; ++ch) volume.emission_rgb[3 * f + ch] = v[ch];
        });
      }
    }
  } catch (const openvdb::Exception& e) {
    throw DataError(path + ": not a readable VDB file: " + Printable(e.what()));
  }
  if (!have_geometry) {
    throw DataError(path + ": no grid named temperature, density or emission");
  }
  if (meta) {
    for (auto it = meta->beginMeta(); it != meta->endMeta(); ++it) {
      if (auto d = std::dynamic_pointer_cast<openvdb::DoubleMetadata>(it->second)) {
        volume.metadata_numbers[it->first] = d->value();
      } else if (auto s = std::dynamic_pointer_cast<openvdb::StringMetadata>(it->second)) {
        if (it->first != "creator") volume.metadata_text[it->first] = s->value();
      }
    }
  }
  try {
    volume.Validate();
  } catch (const InputError& e) {
    throw DataError(path + ": " + e.what());
  }
  return volume;
}

}  // namespace flamerig
