// export-volume: a volume written as .vdb, read back and exported as CSV, NumPy and HDF5 loads in
// NumPy and h5py (the readers a researcher uses) to the same values as the volume written, at
// voxel centres computed here in closed form from the grid.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>

#include "core/error.h"
#include "pipeline/volume_export.h"
#include "tomography/vdb_io.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

fs::path TempDir() {
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_volume_export_" + std::to_string(::getpid()) + "_" +
                                   ::testing::UnitTest::GetInstance()->current_test_info()->name());
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

std::string RunCommand(const std::string& command) {
  std::array<char, 4096> buffer;
  std::string out;
  std::unique_ptr<FILE, int (*)(FILE*)> pipe(popen(command.c_str(), "r"), pclose);
  if (!pipe) return "";
  while (fgets(buffer.data(), buffer.size(), pipe.get())) out += buffer.data();
  const int status = pclose(pipe.release());
  EXPECT_EQ(status, 0) << command << "\n" << out;
  return out;
}

// A fit's volume on a grid with different sizes, voxel sizes and an off-centre origin, so that a
// swapped axis or a misplaced half voxel shows; a third of the voxels have no medium.
FireVolume FittedVolume() {
  FireVolume v;
  v.geometry.dims = Eigen::Vector3i(5, 4, 3);
  v.geometry.origin_in_rig = Eigen::Vector3d(-0.031, 0.0125, 0.207);
  v.geometry.voxel_size_m = Eigen::Vector3d(0.002, 0.0025, 0.003);
  const std::size_t n = v.geometry.num_voxels();
  for (std::size_t f = 0; f < n; ++f) {
    const bool medium = f % 3 != 0;
    v.temperature_k.push_back(medium ? 1234.5678f + 13.1f * f : 0.f);
    v.density_per_m3.push_back(medium ? 1.234567e14f * (1 + f) : 0.f);
    v.temperature_sigma_k.push_back(medium ? 50.125f + f : 0.f);
    v.density_sigma.push_back(medium ? 0.01f * f : 0.f);
    v.determined.push_back(medium && f % 2 ? 1.f : 0.f);
    v.soot_volume_fraction.push_back(v.density_per_m3.back() * 3.351e-23f);
  }
  v.metadata_numbers["exposure"] = 1.5;
  v.metadata_text["absorption_model"] = "soot";
  return v;
}

// The closed form of a voxel centre (tomography/volume.h): origin + (index + 1/2) * size.
double Centre(const FireVolume& v, int axis, int index) {
  return v.geometry.origin_in_rig[axis] + (index + 0.5) * v.geometry.voxel_size_m[axis];
}

// A table as read back: column name -> values, in row order.
using Table = std::map<std::string, std::vector<double>>;

// Checks every row of `table` against `v`: the voxel named by i, j, k has the coordinates and the
// field values, exactly for the float fields (the .vdb's floats), and the rows are the expected
// voxels in flat order.
void ExpectMatches(const FireVolume& v, const Table& table, bool dense, const std::string& what) {
  const GridGeometry& g = v.geometry;
  std::vector<std::size_t> expected;
  for (std::size_t f = 0; f < g.num_voxels(); ++f)
    if (dense || v.density_per_m3[f] > 0) expected.push_back(f);
  for (const char* c :
       {"i", "j", "k", "x_m", "y_m", "z_m", "temperature_k", "density_per_m3",
        "temperature_sigma_k", "density_sigma", "determined", "soot_volume_fraction"}) {
    ASSERT_TRUE(table.count(c)) << what << " lacks column " << c;
    ASSERT_EQ(table.at(c).size(), expected.size()) << what << " column " << c;
  }
  EXPECT_EQ(table.size(), 12u) << what;
  for (std::size_t r = 0; r < expected.size(); ++r) {
    const int i = int(table.at("i")[r]), j = int(table.at("j")[r]), k = int(table.at("k")[r]);
    const std::size_t f = std::size_t(i) + 5 * (std::size_t(j) + 4 * std::size_t(k));
    ASSERT_EQ(f, expected[r]) << what << " row " << r;
    EXPECT_NEAR(table.at("x_m")[r], Centre(v, 0, i), 1e-15) << what;
    EXPECT_NEAR(table.at("y_m")[r], Centre(v, 1, j), 1e-15) << what;
    EXPECT_NEAR(table.at("z_m")[r], Centre(v, 2, k), 1e-15) << what;
    EXPECT_EQ(float(table.at("temperature_k")[r]), v.temperature_k[f]) << what;
    EXPECT_EQ(float(table.at("density_per_m3")[r]), v.density_per_m3[f]) << what;
    EXPECT_EQ(float(table.at("temperature_sigma_k")[r]), v.temperature_sigma_k[f]) << what;
    EXPECT_EQ(float(table.at("density_sigma")[r]), v.density_sigma[f]) << what;
    EXPECT_EQ(float(table.at("determined")[r]), v.determined[f]) << what;
    EXPECT_EQ(float(table.at("soot_volume_fraction")[r]), v.soot_volume_fraction[f]) << what;
  }
}

// Python prints each column as "name v v v ..." with 17 significant digits.
Table ReadPythonDump(const std::string& text) {
  Table table;
  std::istringstream lines(text);
  std::string line;
  while (std::getline(lines, line)) {
    std::istringstream words(line);
    std::string name;
    words >> name;
    double x;
    auto& column = table[name];
    while (words >> x) column.push_back(x);
  }
  return table;
}

Table ReadCsv(const std::string& path) {
  std::ifstream in(path);
  std::string header, line;
  std::getline(in, header);
  std::vector<std::string> names;
  std::stringstream h(header);
  for (std::string name; std::getline(h, name, ',');) names.push_back(name);
  Table table;
  while (std::getline(in, line)) {
    std::stringstream row(line);
    std::string cell;
    for (std::size_t c = 0; std::getline(row, cell, ','); ++c)
      table[names.at(c)].push_back(std::stod(cell));
  }
  return table;
}

TEST(VolumeExport, CsvNumPyAndHdf5RoundTripAgainstTheVdb) {
  const fs::path dir = TempDir();
  const FireVolume truth = FittedVolume();
  WriteVdb((dir / "fit.vdb").string(), truth);
  const FireVolume read = ReadVdb((dir / "fit.vdb").string());
  for (bool dense : {false, true}) {
    const std::string tag = dense ? "dense" : "sparse";
    VolumeExportOptions options;
    options.dense = dense;
    options.source = "fit.vdb";
    for (const char* ext : {".csv", ".npy", ".h5"}) {
      const VolumeExportSummary s =
          ExportVolumeTable(read, (dir / ("t_" + tag + ext)).string(), options);
      EXPECT_EQ(s.rows, dense ? 60u : 40u) << ext;
      EXPECT_EQ(s.columns.size(), 12u) << ext;
      EXPECT_EQ(s.files.size(), std::string(ext) == ".h5" ? 1u : 2u) << ext;
    }
    ExpectMatches(truth, ReadCsv((dir / ("t_" + tag + ".csv")).string()), dense, tag + " csv");
    std::ofstream((dir / "read.py").string())
        << "import sys, json, numpy as np, h5py\n"
        << "a = np.load(sys.argv[1])\n"
        << "for n in a.dtype.names: print(n, ' '.join('%.17g' % x for x in a[n]))\n"
        << "m = json.load(open(sys.argv[1] + '.json'))\n"
        << "assert m['grid']['dims'] == [5, 4, 3], m['grid']\n"
        << "assert m['metadata']['absorption_model'] == 'soot'\n"
        << "assert [c['name'] for c in m['columns']] == list(a.dtype.names)\n"
        << "f = h5py.File(sys.argv[2], 'r')\n"
        << "assert list(f.attrs['grid_dims']) == [5, 4, 3]\n"
        << "assert abs(f.attrs['grid_origin_m'][2] - 0.207) < 1e-15\n"
        << "assert f['metadata'].attrs['absorption_model'] == 'soot'\n"
        << "assert f['metadata'].attrs['exposure'] == 1.5\n"
        << "assert f['temperature_k'].attrs['units'] == 'kelvin'\n"
        << "assert f['temperature_k'].dtype == np.float32 and f['i'].dtype == np.int32\n"
        << "for n in f.keys():\n"
        << "  if n != 'metadata': print('h5_' + n, ' '.join('%.17g' % x for x in f[n][:]))\n";
    const Table both = ReadPythonDump(RunCommand("/usr/bin/python3 " + (dir / "read.py").string() +
                                                 " " + (dir / ("t_" + tag + ".npy")).string() +
                                                 " " + (dir / ("t_" + tag + ".h5")).string()));
    Table npy, h5;
    for (const auto& [name, values] : both)
      (name.rfind("h5_", 0) == 0 ? h5[name.substr(3)] : npy[name]) = values;
    ExpectMatches(truth, npy, dense, tag + " npy");
    ExpectMatches(truth, h5, dense, tag + " h5");
  }
  fs::remove_all(dir);
}

TEST(VolumeExport, RefusesAnUnknownFormatAndAVolumeWithoutFields) {
  const fs::path dir = TempDir();
  try {
    ExportVolumeTable(FittedVolume(), (dir / "t.txt").string());
    FAIL() << "a .txt table was written";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("t.txt"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(".npy"), std::string::npos) << e.what();
  }
  FireVolume empty;
  empty.geometry = FittedVolume().geometry;
  VolumeExportOptions options;
  options.source = "empty.vdb";
  try {
    ExportVolumeTable(empty, (dir / "t.csv").string(), options);
    FAIL() << "a table without fields was written";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("empty.vdb"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(dir / "t.csv"));
  // A NaN in the volume is refused, naming the field and the voxel.
  FireVolume bad = FittedVolume();
  bad.temperature_k[7] = std::nanf("");
  EXPECT_THROW(ExportVolumeTable(bad, (dir / "t.csv").string()), InputError);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace flamerig
