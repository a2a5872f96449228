#include "pipeline/volume_export.h"

#include <hdf5.h>

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <nlohmann/json.hpp>
#include <sstream>

#include "core/atomic_file.h"
#include "core/error.h"
#include "core/npy.h"

namespace flamerig {

namespace fs = std::filesystem;

namespace {

// One column of the table: its name, units, NumPy type code, and its value at a flat voxel index
// (integers and doubles are both carried as double here: every value fits exactly).
struct Column {
  std::string name, units;
  enum Type { kInt32, kFloat32, kFloat64 } type;
  std::function<double(std::size_t)> value;
};

std::vector<Column> ColumnsOf(const FireVolume& v) {
  const GridGeometry& g = v.geometry;
  const std::size_t nx = static_cast<std::size_t>(g.dims.x());
  const std::size_t ny = static_cast<std::size_t>(g.dims.y());
  auto ijk = [nx, ny](std::size_t flat) {
    return Eigen::Vector3i(int(flat % nx), int((flat / nx) % ny), int(flat / (nx * ny)));
  };
  std::vector<Column> c;
  for (int axis = 0; axis < 3; ++axis)
    c.push_back({std::string(1, "ijk"[axis]), "voxel index", Column::kInt32,
                 [ijk, axis](std::size_t f) { return double(ijk(f)[axis]); }});
  for (int axis = 0; axis < 3; ++axis)
    c.push_back({std::string(1, "xyz"[axis]) + "_m", "metres, voxel centre in the rig frame",
                 Column::kFloat64, [ijk, axis, &g](std::size_t f) {
                   const Eigen::Vector3i at = ijk(f);
                   return g.VoxelCenter(at.x(), at.y(), at.z())[axis];
                 }});
  auto field = [&](const std::vector<float>& values, const char* name, const char* units) {
    if (values.size() == g.num_voxels())
      c.push_back(
          {name, units, Column::kFloat32, [&values](std::size_t f) { return double(values[f]); }});
  };
  field(v.temperature_k, "temperature_k", "kelvin");
  field(v.density_per_m3, "density_per_m3", "soot particles per cubic metre");
  field(v.temperature_sigma_k, "temperature_sigma_k", "kelvin, one standard deviation");
  field(v.density_sigma, "density_sigma", "standard deviation of ln(density)");
  field(v.determined, "determined",
        "1 where the images determine the voxel, 0 where the prior does");
  field(v.soot_volume_fraction, "soot_volume_fraction", "cubic metres of soot per cubic metre");
  if (v.emission_rgb.size() == 3 * g.num_voxels())
    for (int ch = 0; ch < 3; ++ch)
      c.push_back({std::string("emission_") + "rgb"[ch], "linear emission, renderer's units",
                   Column::kFloat32,
                   [&v, ch](std::size_t f) { return double(v.emission_rgb[3 * f + ch]); }});
  return c;
}

// The voxels written: every one (dense), or those with medium.
std::vector<std::size_t> RowsOf(const FireVolume& v, bool dense) {
  const std::size_t n = v.geometry.num_voxels();
  std::vector<std::size_t> rows;
  const bool have_density = v.density_per_m3.size() == n;
  for (std::size_t f = 0; f < n; ++f) {
    bool keep = dense;
    if (!keep && have_density) keep = v.density_per_m3[f] > 0;
    if (!keep && !have_density) {
      keep = v.temperature_k.size() == n && v.temperature_k[f] != 0;
      for (int ch = 0; ch < 3 && !keep && v.emission_rgb.size() == 3 * n; ++ch)
        keep = v.emission_rgb[3 * f + ch] != 0;
    }
    if (keep) rows.push_back(f);
  }
  return rows;
}

nlohmann::json MetadataOf(const FireVolume& v, const std::vector<Column>& columns,
                          const VolumeExportOptions& options, std::size_t rows) {
  const GridGeometry& g = v.geometry;
  nlohmann::json j;
  j["source"] = options.source;
  j["rows"] = rows;
  j["row_selection"] = options.dense ? "every voxel of the grid, flat order (x fastest): a column "
                                       "reshapes to (nz, ny, nx)"
                                     : "the voxels with medium, flat order (x fastest)";
  j["grid"] = {{"dims", {g.dims.x(), g.dims.y(), g.dims.z()}},
               {"origin_m", {g.origin_in_rig.x(), g.origin_in_rig.y(), g.origin_in_rig.z()}},
               {"voxel_size_m", {g.voxel_size_m.x(), g.voxel_size_m.y(), g.voxel_size_m.z()}},
               {"note",
                "origin_m is the min corner of the box; voxel (i, j, k) is centred at "
                "origin_m + (i + 0.5, j + 0.5, k + 0.5) * voxel_size_m"}};
  for (const auto& c : columns) j["columns"].push_back({{"name", c.name}, {"units", c.units}});
  for (const auto& [key, value] : v.metadata_numbers) j["metadata"][key] = value;
  for (const auto& [key, value] : v.metadata_text) j["metadata"][key] = value;
  return j;
}

void WriteCsv(const std::string& path, const std::vector<Column>& columns,
              const std::vector<std::size_t>& rows) {
  std::string out;
  for (std::size_t c = 0; c < columns.size(); ++c) out += (c ? "," : "") + columns[c].name;
  out += "\n";
  char buf[40];
  for (std::size_t r : rows) {
    for (std::size_t c = 0; c < columns.size(); ++c) {
      const double x = columns[c].value(r);
      // 9 significant digits read back to the same float, 17 to the same double.
      const int n = columns[c].type == Column::kInt32
                        ? std::snprintf(buf, sizeof buf, "%.0f", x)
                        : std::snprintf(buf, sizeof buf, "%.*g",
                                        columns[c].type == Column::kFloat32 ? 9 : 17, x);
      if (c) out += ',';
      out.append(buf, static_cast<std::size_t>(n));
    }
    out += '\n';
  }
  WriteFileAtomically(path, out);
}

template <typename T>
void Append(std::string* out, T value) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));  // little-endian machines only (checked below)
  out->append(bytes, sizeof(T));
}

void WriteNpy(const std::string& path, const std::vector<Column>& columns,
              const std::vector<std::size_t>& rows) {
  static_assert(sizeof(float) == 4 && sizeof(double) == 8);
  const std::uint16_t probe = 1;
  if (*reinterpret_cast<const unsigned char*>(&probe) != 1)
    throw IoError(path + ": NumPy export is written little-endian; this machine is not");
  std::string descr = "[";
  for (std::size_t c = 0; c < columns.size(); ++c)
    descr += (c ? ", ('" : "('") + columns[c].name + "', '" +
             (columns[c].type == Column::kInt32     ? "<i4"
              : columns[c].type == Column::kFloat32 ? "<f4"
                                                    : "<f8") +
             "')";
  std::string out = NpyHeader(descr + "]", {rows.size()});
  for (std::size_t r : rows)
    for (const auto& c : columns) {
      const double x = c.value(r);
      if (c.type == Column::kInt32)
        Append(&out, static_cast<std::int32_t>(x));
      else if (c.type == Column::kFloat32)
        Append(&out, static_cast<float>(x));
      else
        Append(&out, x);
    }
  WriteFileAtomically(path, out);
}

// HDF5 handles closed on scope exit.
class Handle {
 public:
  Handle(hid_t id, herr_t (*close)(hid_t), const std::string& what) : id_(id), close_(close) {
    if (id < 0) throw IoError(what);
  }
  ~Handle() { close_(id_); }
  Handle(const Handle&) = delete;
  Handle& operator=(const Handle&) = delete;
  hid_t id() const { return id_; }

 private:
  hid_t id_;
  herr_t (*close_)(hid_t);
};

void Check(herr_t status, const std::string& what) {
  if (status < 0) throw IoError(what);
}

void TextAttribute(hid_t on, const std::string& name, const std::string& text,
                   const std::string& path) {
  // Variable-length UTF-8, which h5py reads as str (fixed-length strings come back as bytes).
  Handle type(H5Tcopy(H5T_C_S1), H5Tclose, path + ": HDF5 string type");
  Check(H5Tset_size(type.id(), H5T_VARIABLE), path + ": HDF5 string");
  Check(H5Tset_cset(type.id(), H5T_CSET_UTF8), path + ": HDF5 string");
  Handle space(H5Screate(H5S_SCALAR), H5Sclose, path + ": HDF5 space");
  Handle a(H5Acreate2(on, name.c_str(), type.id(), space.id(), H5P_DEFAULT, H5P_DEFAULT), H5Aclose,
           path + ": cannot create attribute " + name);
  const char* chars = text.c_str();
  Check(H5Awrite(a.id(), type.id(), &chars), path + ": cannot write attribute " + name);
}

// Doubles, or 64-bit integers when `whole`.
void NumberAttribute(hid_t on, const std::string& name, const std::vector<double>& values,
                     const std::string& path, bool whole = false) {
  const hsize_t n = values.size();
  Handle space(n == 1 ? H5Screate(H5S_SCALAR) : H5Screate_simple(1, &n, nullptr), H5Sclose,
               path + ": HDF5 space");
  Handle a(H5Acreate2(on, name.c_str(), whole ? H5T_STD_I64LE : H5T_IEEE_F64LE, space.id(),
                      H5P_DEFAULT, H5P_DEFAULT),
           H5Aclose, path + ": cannot create attribute " + name);
  Check(H5Awrite(a.id(), H5T_NATIVE_DOUBLE, values.data()),
        path + ": cannot write attribute " + name);
}

void WriteHdf5(const std::string& path, const std::vector<Column>& columns,
               const std::vector<std::size_t>& rows, const nlohmann::json& meta) {
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);  // errors are thrown with the path, not printed
  AtomicFile file(path);
  {
    Handle h(H5Fcreate(file.temp_path().c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT), H5Fclose,
             "cannot create " + path);
    const hsize_t n = rows.size();
    Handle space(H5Screate_simple(1, &n, nullptr), H5Sclose, path + ": HDF5 space");
    std::vector<double> values(rows.size());
    for (const auto& c : columns) {
      for (std::size_t r = 0; r < rows.size(); ++r) values[r] = c.value(rows[r]);
      const hid_t stored = c.type == Column::kInt32     ? H5T_STD_I32LE
                           : c.type == Column::kFloat32 ? H5T_IEEE_F32LE
                                                        : H5T_IEEE_F64LE;
      Handle d(H5Dcreate2(h.id(), c.name.c_str(), stored, space.id(), H5P_DEFAULT, H5P_DEFAULT,
                          H5P_DEFAULT),
               H5Dclose, path + ": cannot create dataset " + c.name);
      // HDF5 converts the doubles to the stored type (exact: each value came from that type).
      if (n)
        Check(H5Dwrite(d.id(), H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, values.data()),
              path + ": cannot write dataset " + c.name);
      TextAttribute(d.id(), "units", c.units, path);
    }
    const auto& grid = meta["grid"];
    for (const char* key : {"dims", "origin_m", "voxel_size_m"})
      NumberAttribute(h.id(), std::string("grid_") + key, grid[key].get<std::vector<double>>(),
                      path, key == std::string("dims"));
    TextAttribute(h.id(), "grid_note", grid["note"].get<std::string>(), path);
    TextAttribute(h.id(), "source", meta["source"].get<std::string>(), path);
    TextAttribute(h.id(), "row_selection", meta["row_selection"].get<std::string>(), path);
    // The volume's own metadata in a group of its own, so that no key of another program's
    // .vdb can collide with the attributes above.
    Handle group(H5Gcreate2(h.id(), "metadata", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Gclose,
                 path + ": cannot create the group metadata");
    if (meta.contains("metadata"))
      for (const auto& [key, value] : meta["metadata"].items()) {
        if (value.is_number())
          NumberAttribute(group.id(), key, {value.get<double>()}, path);
        else
          TextAttribute(group.id(), key, value.get<std::string>(), path);
      }
    Check(H5Fflush(h.id(), H5F_SCOPE_GLOBAL), "cannot flush " + path);
  }
  file.Commit();
}

}  // namespace

VolumeTableFormat VolumeTableFormatOf(const std::string& path) {
  const std::string ext = fs::path(path).extension().string();
  if (ext == ".csv") return VolumeTableFormat::kCsv;
  if (ext == ".npy") return VolumeTableFormat::kNpy;
  if (ext == ".h5" || ext == ".hdf5") return VolumeTableFormat::kHdf5;
  throw InputError(path + ": unknown table format '" + ext + "' (use .csv, .npy, .h5 or .hdf5)");
}

VolumeExportSummary ExportVolumeTable(const FireVolume& volume, const std::string& path,
                                      const VolumeExportOptions& options) {
  const VolumeTableFormat format = VolumeTableFormatOf(path);
  volume.Validate();
  const std::vector<Column> columns = ColumnsOf(volume);
  if (columns.size() == 6)
    throw InputError(
        "export-volume: " + (options.source.empty() ? std::string("the volume") : options.source) +
        " has no temperature, density or emission grid");
  const std::vector<std::size_t> rows = RowsOf(volume, options.dense);
  const fs::path parent = fs::path(path).parent_path();
  std::error_code ec;
  if (!parent.empty()) fs::create_directories(parent, ec);
  if (ec) throw IoError("cannot create the folder " + parent.string() + ": " + ec.message());
  const nlohmann::json meta = MetadataOf(volume, columns, options, rows.size());
  VolumeExportSummary summary;
  summary.rows = rows.size();
  for (const auto& c : columns) summary.columns.push_back(c.name);
  summary.files.push_back(path);
  if (format == VolumeTableFormat::kHdf5) {
    WriteHdf5(path, columns, rows, meta);
    return summary;
  }
  if (format == VolumeTableFormat::kCsv)
    WriteCsv(path, columns, rows);
  else
    WriteNpy(path, columns, rows);
  WriteFileAtomically(path + ".json", meta.dump(2) + "\n");
  summary.files.push_back(path + ".json");
  return summary;
}

}  // namespace flamerig
