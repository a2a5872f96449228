// Voxel grids and their .vdb files, checked with OpenVDB itself and its vdb_print tool.
#include <gtest/gtest.h>
#include <openvdb/openvdb.h>

#include <array>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <random>

#include "core/error.h"
#include "core/memory.h"
#include "tomography/vdb_io.h"
#include "tomography/volume.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

fs::path TempDir() {
  fs::path dir =
      fs::temp_directory_path() / ("flamerig_volume_test_" + std::to_string(::getpid()) + "_" +
                                   ::testing::UnitTest::GetInstance()->current_test_info()->name());
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

FireVolume RandomVolume() {
  FireVolume v;
  v.geometry = GridGeometry::FromBox(
      Box3{Eigen::Vector3d(-0.03, 0.01, -0.02), Eigen::Vector3d(0.03, 0.11, 0.02)}, 20);
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> u(0, 1);
  const std::size_t n = v.geometry.num_voxels();
  v.temperature_k.resize(n);
  v.density_per_m3.resize(n);
  v.emission_rgb.resize(3 * n);
  for (std::size_t i = 0; i < n; ++i) {
    bool fire = u(rng) < 0.3;
    v.temperature_k[i] = fire ? 300 + 2000 * u(rng) : 0.0f;
    v.density_per_m3[i] = fire ? 1e14f * u(rng) : 0.0f;
    for (int c = 0; c < 3; ++c) v.emission_rgb[3 * i + c] = fire ? u(rng) - 0.1f : 0.0f;
  }
  v.soot_volume_fraction.resize(n);
  for (std::size_t i = 0; i < n; ++i) v.soot_volume_fraction[i] = v.density_per_m3[i] * 3.35e-23f;
  v.metadata_numbers["exposure"] = 12.5;
  v.metadata_numbers["density_scale"] = 3e17;
  v.metadata_text["absorption_model"] = "soot";
  return v;
}

TEST(GridGeometry, FromBoxMakesCubicVoxelsCentredOnTheBox) {
  Box3 box{Eigen::Vector3d(-0.02, 0, -0.02), Eigen::Vector3d(0.02, 0.08, 0.02)};
  GridGeometry g = GridGeometry::FromBox(box, 64);
  EXPECT_EQ(g.dims, Eigen::Vector3i(32, 64, 32));
  EXPECT_NEAR(g.voxel_size_m.x(), 0.08 / 64, 1e-15);
  EXPECT_TRUE(g.box().min_in_rig.isApprox(box.min_in_rig, 1e-12));
  EXPECT_TRUE(g.box().max_in_rig.isApprox(box.max_in_rig, 1e-12));
  EXPECT_TRUE(g.IndexFromRig(g.VoxelCenter(3, 4, 5)).isApprox(Eigen::Vector3d(3, 4, 5), 1e-12));
  EXPECT_EQ(g.Flat(1, 0, 0), 1u);
  EXPECT_EQ(g.Flat(0, 1, 0), 32u);
  EXPECT_EQ(g.Flat(0, 0, 1), 32u * 64u);
  EXPECT_THROW(GridGeometry::FromBox(box, 0), InputError);
  EXPECT_THROW(GridGeometry::FromBox(Box3{box.max_in_rig, box.min_in_rig}, 8), InputError);
  EXPECT_EQ(GridGeometry::FromBox(box, 1).num_voxels(), 1u);
}

// Unflat inverts Flat (x fastest, then y, then z) on a grid whose three sides differ.
TEST(GridGeometry, UnflatInvertsFlat) {
  GridGeometry g;
  g.dims = Eigen::Vector3i(3, 4, 5);
  std::size_t expected = 0;
  for (int k = 0; k < 5; ++k)
    for (int j = 0; j < 4; ++j)
      for (int i = 0; i < 3; ++i, ++expected) {
        ASSERT_EQ(g.Flat(i, j, k), expected);
        EXPECT_EQ(g.Unflat(expected), Eigen::Vector3i(i, j, k)) << expected;
      }
}

TEST(Vdb, RoundTripIsExact) {
  fs::path dir = TempDir();
  FireVolume v = RandomVolume();
  const std::string path = (dir / "fire.vdb").string();
  WriteVdb(path, v);
  for (const auto& e : fs::directory_iterator(dir))  // no temporary file left beside it
    EXPECT_EQ(e.path().filename(), "fire.vdb");
  FireVolume back = ReadVdb(path);
  EXPECT_EQ(back.geometry.dims, v.geometry.dims);
  EXPECT_TRUE(back.geometry.origin_in_rig.isApprox(v.geometry.origin_in_rig, 1e-12));
  EXPECT_TRUE(back.geometry.voxel_size_m.isApprox(v.geometry.voxel_size_m, 1e-12));
  EXPECT_EQ(back.temperature_k, v.temperature_k);
  EXPECT_EQ(back.density_per_m3, v.density_per_m3);
  EXPECT_EQ(back.emission_rgb, v.emission_rgb);
  EXPECT_EQ(back.soot_volume_fraction, v.soot_volume_fraction);
  EXPECT_EQ(back.metadata_numbers.at("exposure"), 12.5);
  EXPECT_EQ(back.metadata_numbers.at("density_scale"), 3e17);
  EXPECT_EQ(back.metadata_text.at("absorption_model"), "soot");
  fs::remove_all(dir);
}

// OpenVDB's own reader sees the grids, units and the voxel-centre transform.
TEST(Vdb, OpenVdbSeesTheRigFrame) {
  fs::path dir = TempDir();
  FireVolume v = RandomVolume();
  const std::string path = (dir / "fire.vdb").string();
  WriteVdb(path, v);
  openvdb::initialize();
  openvdb::io::File file(path);
  file.open();
  auto grid = openvdb::gridPtrCast<openvdb::FloatGrid>(file.readGrid("temperature"));
  ASSERT_TRUE(grid);
  EXPECT_EQ(grid->metaValue<std::string>("units"), "K");
  openvdb::Vec3d world = grid->indexToWorld(openvdb::Coord(3, 7, 2));
  Eigen::Vector3d expected = v.geometry.VoxelCenter(3, 7, 2);
  EXPECT_NEAR(world.x(), expected.x(), 1e-12);
  EXPECT_NEAR(world.y(), expected.y(), 1e-12);
  EXPECT_NEAR(world.z(), expected.z(), 1e-12);
  EXPECT_EQ(grid->tree().getValue(openvdb::Coord(3, 7, 2)),
            v.temperature_k[v.geometry.Flat(3, 7, 2)]);
  EXPECT_TRUE(file.readGrid("density"));
  EXPECT_TRUE(file.readGrid("emission"));
  file.close();
  fs::remove_all(dir);
}

std::string RunCommand(const std::string& command, int* status) {
  std::array<char, 4096> buffer;
  std::string out;
  FILE* pipe = popen(command.c_str(), "r");
  if (!pipe) return "";
  while (fgets(buffer.data(), buffer.size(), pipe)) out += buffer.data();
  *status = pclose(pipe);
  return out;
}

TEST(Vdb, ReadableByVdbPrint) {
  fs::path dir = TempDir();
  const std::string path = (dir / "fire.vdb").string();
  WriteVdb(path, RandomVolume());
  int status = -1;
  std::string out = RunCommand("vdb_print -l " + path + " 2>&1", &status);
  EXPECT_EQ(status, 0) << out;
  EXPECT_NE(out.find("temperature"), std::string::npos) << out;
  EXPECT_NE(out.find("density"), std::string::npos) << out;
  EXPECT_NE(out.find("emission"), std::string::npos) << out;
  fs::remove_all(dir);
}

// A file written by another program: no flamerig metadata, active voxels at an offset.
TEST(Vdb, ReadsForeignFilesByTheirActiveBoundingBox) {
  fs::path dir = TempDir();
  openvdb::initialize();
  auto grid = openvdb::FloatGrid::create(0.0f);
  grid->setName("density");
  grid->setTransform(openvdb::math::Transform::createLinearTransform(0.01));
  grid->tree().setValue(openvdb::Coord(10, 20, 30), 5.0f);
  grid->tree().setValue(openvdb::Coord(12, 21, 30), 7.0f);
  const std::string path = (dir / "foreign.vdb").string();
  openvdb::io::File(path).write({grid});
  FireVolume v = ReadVdb(path);
  EXPECT_EQ(v.geometry.dims, Eigen::Vector3i(3, 2, 1));
  EXPECT_TRUE(v.geometry.VoxelCenter(0, 0, 0).isApprox(Eigen::Vector3d(0.10, 0.20, 0.30), 1e-12));
  EXPECT_EQ(v.density_per_m3[v.geometry.Flat(0, 0, 0)], 5.0f);
  EXPECT_EQ(v.density_per_m3[v.geometry.Flat(2, 1, 0)], 7.0f);
  EXPECT_TRUE(v.temperature_k.empty());
  fs::remove_all(dir);
}

// Tiles, as Houdini writes a region of one value: a root tile spans 4096^3 voxels, and only the
// lattice that flamerig_dims declares is read (it was walked whole: over a minute for this file).
TEST(Vdb, ReadsTilesWithinTheDeclaredLattice) {
  fs::path dir = TempDir();
  openvdb::initialize();
  auto grid = openvdb::FloatGrid::create(0.0f);
  grid->setName("temperature");
  grid->setTransform(openvdb::math::Transform::createLinearTransform(0.01));
  grid->insertMeta("flamerig_dims", openvdb::Vec3IMetadata(openvdb::Vec3i(6, 5, 4)));
  grid->tree().root().addTile(openvdb::Coord(-4096, 0, 0), 1500.0f, /*active=*/true);
  grid->tree().addTile(/*level=*/1, openvdb::Coord(0, 0, 0), 1800.0f, /*active=*/true);
  grid->tree().setValue(openvdb::Coord(200, 3, 2), 2000.0f);
  const std::string path = (dir / "tiles.vdb").string();
  openvdb::io::File(path).write({grid});
  FireVolume v = ReadVdb(path);
  ASSERT_EQ(v.geometry.dims, Eigen::Vector3i(6, 5, 4));
  for (float t : v.temperature_k) EXPECT_EQ(t, 1800.0f);
  fs::remove_all(dir);
}

// A file of a few hundred bytes may declare a lattice of two billion voxels, whose dense fields
// no machine holds: refused with the sizes before any is allocated (by the budget given, or by
// this machine's memory), not killed by the kernel part-way.
TEST(Vdb, ALatticeLargerThanMemoryIsRefusedBeforeItIsAllocated) {
  fs::path dir = TempDir();
  openvdb::initialize();
  auto make = [&](const std::string& name, openvdb::Vec3i dims) {
    openvdb::GridPtrVec grids;
    for (const char* field : {"temperature", "density", "temperature_sigma", "density_sigma",
                              "determined", "soot_volume_fraction"}) {
      auto grid = openvdb::FloatGrid::create(0.0f);
      grid->setName(field);
      grid->insertMeta("flamerig_dims", openvdb::Vec3IMetadata(dims));
      grid->tree().setValue(openvdb::Coord(1, 2, 3), 1500.0f);
      grids.push_back(grid);
    }
    const std::string path = (dir / name).string();
    openvdb::io::File(path).write(grids);
    return path;
  };
  // 1000^3 voxels, six fields: 24 GB.
  const std::string big = make("big.vdb", openvdb::Vec3i(1000, 1000, 1000));
  try {
    ReadVdb(big, /*max_bytes=*/std::size_t(1) << 30);
    FAIL() << "no error";
  } catch (const DataError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("big.vdb: its lattice of 1000 x 1000 x 1000 voxels needs 24.0 GB for "
                        "its 6 field values a voxel, more than the 1.1 GB allowed"),
              std::string::npos)
        << what;
  }
  // Within the budget, the same kind of file reads.
  const FireVolume small = ReadVdb(make("small.vdb", openvdb::Vec3i(8, 8, 8)), 6 * 512 * 4);
  EXPECT_EQ(small.temperature_k[small.geometry.Flat(1, 2, 3)], 1500.0f);
  // 1290 x 1290 x 1290, six fields: 51.5 GB, more than this machine has (else skipped).
  const std::string huge = make("huge.vdb", openvdb::Vec3i(1290, 1290, 1290));
  if (PhysicalMemoryBytes() == 0 || PhysicalMemoryBytes() > 51'000'000'000u) {
    fs::remove_all(dir);
    GTEST_SKIP() << "this machine has over 51 GB of memory";
  }
  try {
    ReadVdb(huge);
    FAIL() << "no error";
  } catch (const DataError& e) {
    EXPECT_NE(std::string(e.what()).find("of this machine's memory"), std::string::npos)
        << e.what();
  }
  fs::remove_all(dir);
}

TEST(Vdb, BadFilesAndVolumesGiveClearErrors) {
  fs::path dir = TempDir();
  auto expect_error = [](auto fn, const std::string& fragment) {
    try {
      fn();
      FAIL() << "no error";
    } catch (const std::exception& e) {
      EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
    }
  };
  expect_error([&] { ReadVdb((dir / "missing.vdb").string()); }, "missing.vdb");
  std::ofstream((dir / "garbage.vdb").string()) << "this is not a vdb file";
  expect_error([&] { ReadVdb((dir / "garbage.vdb").string()); }, "garbage.vdb");
  // Truncated copy of a real file.
  WriteVdb((dir / "good.vdb").string(), RandomVolume());
  auto size = fs::file_size(dir / "good.vdb");
  fs::copy_file(dir / "good.vdb", dir / "cut.vdb");
  fs::resize_file(dir / "cut.vdb", size / 2);
  expect_error([&] { ReadVdb((dir / "cut.vdb").string()); }, "cut.vdb");
  // Cut anywhere, a short error that says so: OpenVDB does not check its reads, and a file cut
  // at 500 bytes gave a grid type of 2 GB of spaces (15 GB of memory, a 2 GB message).
  for (const std::uintmax_t at :
       {std::uintmax_t(16), std::uintmax_t(500), std::uintmax_t(1000), size / 4, size - 1}) {
    fs::copy_file(dir / "good.vdb", dir / "cut_at.vdb", fs::copy_options::overwrite_existing);
    fs::resize_file(dir / "cut_at.vdb", at);
    try {
      ReadVdb((dir / "cut_at.vdb").string());
      ADD_FAILURE() << "no error cut at " << at;
    } catch (const DataError& e) {
      const std::string what = e.what();
      EXPECT_LT(what.size(), 400u) << at;
      EXPECT_NE(what.find("cut_at.vdb: not a readable VDB file"), std::string::npos) << what;
    }
  }
  // A damaged transform (the map's scale patched in the file) names the file: a zero scale is
  // OpenVDB's singular-matrix error, a scale of 1e300 puts the grid beyond any rig.
  for (const double scale : {0.0, 1e300, std::nan("")}) {
    std::string bytes;
    {
      std::ifstream in(dir / "good.vdb", std::ios::binary);
      bytes.assign(std::istreambuf_iterator<char>(in), {});
    }
    const std::string map = "UniformScaleTranslateMap";
    int patched = 0;
    for (auto at = bytes.find(map); at != std::string::npos; at = bytes.find(map, at + 1)) {
      for (int c = 0; c < 3; ++c)  // translation (3 doubles), then the scale (3 doubles)
        std::memcpy(&bytes[at + map.size() + 24 + 8 * std::size_t(c)], &scale, sizeof scale);
      ++patched;
    }
    ASSERT_GT(patched, 0);
    std::ofstream(dir / "map.vdb", std::ios::binary) << bytes;
    expect_error([&] { ReadVdb((dir / "map.vdb").string()); }, "map.vdb: ");
  }
  // A file with no known grid.
  openvdb::initialize();
  auto other = openvdb::FloatGrid::create(0.0f);
  other->setName("velocity_magnitude");
  other->tree().setValue(openvdb::Coord(0, 0, 0), 1.0f);
  openvdb::io::File((dir / "other.vdb").string()).write({other});
  expect_error([&] { ReadVdb((dir / "other.vdb").string()); }, "no grid named");
  // NaN in a volume is refused before anything is written.
  FireVolume v = RandomVolume();
  v.density_per_m3[v.geometry.Flat(2, 3, 4)] = std::nanf("");
  expect_error([&] { WriteVdb((dir / "nan.vdb").string(), v); }, "(2, 3, 4)");
  EXPECT_FALSE(fs::exists(dir / "nan.vdb"));
  FireVolume empty;
  empty.geometry = v.geometry;
  expect_error([&] { WriteVdb((dir / "empty.vdb").string(), empty); }, "no field");
  fs::remove_all(dir);
}

// Reads a damaged file found by fuzzing (tests/fuzz/regressions/vdb/NAME) and expects an error
// naming it and saying `why` (a phrase of tomography/openvdb_blosc_guard.cc's: proof that its
// checks, not OpenVDB's, caught it).
void ExpectFuzzFindingIsAnError(const std::string& name, const std::string& why) {
  const std::string path = std::string(FLAMERIG_SOURCE_DIR) + "/tests/fuzz/regressions/vdb/" + name;
  try {
    ReadVdb(path);
    FAIL() << "no error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(name), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(why), std::string::npos) << e.what();
  }
}

// A damaged delayed-load table made OpenVDB abort on an assertion while it skipped a leaf
// (ReadVdb now reads files whole); read whole by io::File, OpenVDB 10.0 allocated the 94 TB its
// chunk size says, where tomography/openvdb_blosc_guard.cc found the file ends first. Read as a
// stream that throws at its end (since 2026-12-01), the stream stops it before.
TEST(Vdb, ADamagedFileFoundByFuzzingIsAnErrorNotAnAbort) {
  ExpectFuzzFindingIsAnError("delayed_load_mask_assert.vdb", "it ends before its grids do");
}

// An uncompressed chunk larger than its values: OpenVDB 10.0 wrote it past the buffer before
// comparing sizes (a heap overflow under ASan; in a plain build it may pass unnoticed before
// OpenVDB's own error); tomography/openvdb_blosc_guard.cc compares first.
TEST(Vdb, AHeapOverflowFoundByFuzzingIsAnError) {
  ExpectFuzzFindingIsAnError("blosc_uncompressed_overflow.vdb", "the file states");
}

// A root tile whose active flag is the byte 64, not a bool (found by fuzzing in CI: undefined
// behaviour in OpenVDB's reader, tests/fuzz/ubsan_ignorelist.txt): with no flamerig_dims its
// bounding box is the tile's 4096^3 voxels, which no fire lattice is.
TEST(Vdb, ARootTileFoundByFuzzingIsAnError) {
  ExpectFuzzFindingIsAnError("root_tile_bool_64.vdb", "unusable dimensions");
}

}  // namespace
}  // namespace flamerig
