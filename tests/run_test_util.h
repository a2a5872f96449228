// Helpers shared by the `flamerig run` tests: a small simulated dataset and volume comparison.
#ifndef FLAMERIG_TESTS_RUN_TEST_UTIL_H_
#define FLAMERIG_TESTS_RUN_TEST_UTIL_H_

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <string>

#include "tomography/vdb_io.h"
#include "pipeline/run.h"
#include "pipeline/simulate.h"

namespace flamerig {
namespace testing_run {

namespace fs = std::filesystem;

inline fs::path TempDir(const std::string& tag) {
  const fs::path dir = fs::temp_directory_path() /
                       ("flamerig_run_test_" + std::to_string(::getpid()) + "_" + tag + "_" +
                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

// A small candle filmed by three cameras 120 degrees apart: 24^3 voxels, 120x90 images.
inline fs::path SimulateDataset(const fs::path& dir, int frames, int cameras = 3) {
  SimulateConfig c;
  c.frames = frames;
  c.grid_resolution = 24;
  c.ring.cameras = cameras;
  c.ring.width = 120;
  c.ring.height = 90;
  c.ring.fill = 0.8;
  c.calibration = false;
  Simulate(c, dir.string());
  return dir;
}

inline RunOptions SmallRun(const fs::path& dataset, const fs::path& out) {
  RunOptions o;
  o.source.images_dir = (dataset / "frames").string();
  o.rig_path = (dataset / "rig.yaml").string();
  o.out_dir = out.string();
  o.reconstruct.resolution = 24;
  o.truth_dir = (dataset / "truth").string();
  return o;
}

inline RunSummary RunAll(const RunOptions& o) {
  const FrameSource source(o.source, Rig::Load(o.rig_path));
  std::size_t begin, end;
  RunRange(o, source, &begin, &end);
  return RunFrames(o, o.rig_path, begin, end);
}

inline void ExpectSameVolume(const fs::path& a, const fs::path& b) {
  const FireVolume va = ReadVdb(a.string()), vb = ReadVdb(b.string());
  EXPECT_TRUE(va.temperature_k == vb.temperature_k) << a << " vs " << b;
  EXPECT_TRUE(va.density_per_m3 == vb.density_per_m3) << a << " vs " << b;
  EXPECT_EQ(va.metadata_numbers.at("exposure"), vb.metadata_numbers.at("exposure"));
}

}  // namespace testing_run
}  // namespace flamerig

#endif  // FLAMERIG_TESTS_RUN_TEST_UTIL_H_
