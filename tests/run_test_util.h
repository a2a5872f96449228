// Helpers shared by the `flamerig run` tests: a small simulated dataset and volume comparison.
#ifndef FLAMERIG_TESTS_RUN_TEST_UTIL_H_
#define FLAMERIG_TESTS_RUN_TEST_UTIL_H_

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "core/image.h"
#include "pipeline/run.h"
#include "pipeline/simulate.h"
#include "tomography/vdb_io.h"

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

// A small candle filmed by `cameras` cameras on a ring (three: 120 degrees apart): 24^3 voxels,
// 120x90 images, no board views.
inline SimulateConfig SmallCandle(int frames, int cameras = 3) {
  SimulateConfig c;
  c.frames = frames;
  c.grid_resolution = 24;
  c.ring.cameras = cameras;
  c.ring.width = 120;
  c.ring.height = 90;
  c.ring.fill = 0.8;
  c.calibration = false;
  return c;
}

inline fs::path SimulateDataset(const fs::path& dir, int frames, int cameras = 3) {
  Simulate(SmallCandle(frames, cameras), dir.string());
  return dir;
}

// One frame of the small candle from raw 12-bit colour cameras (linear, black level 64): its
// frames are 16-bit PNGs of their codes, and its rig says so.
inline fs::path SimulateRawTwelveBit(const fs::path& dir, int cameras = 3) {
  SimulateConfig c = SmallCandle(1, cameras);
  c.radiometry.transfer = TransferFunction::kLinear;
  c.radiometry.bit_depth = 12;
  c.radiometry.black_level = 64;
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

// Writes 8-bit RGB images as an uncompressed StreamPix 6 sequence (BGR, image format 200) with
// timestamps 33 ms apart, laid out as the published format says (acquisition/streampix.h).
inline void WriteStreamPix(const fs::path& path, const std::vector<ImageU8>& frames) {
  auto put = [](std::vector<char>* b, std::size_t at, auto v) {
    std::memcpy(b->data() + at, &v, sizeof v);
  };
  const std::uint32_t w = frames.at(0).width, h = frames.at(0).height, image = w * h * 3;
  const std::uint32_t true_size = image + 8 + 8;
  std::vector<char> header(8192, 0);
  put(&header, 0, std::uint32_t(0xFEED));
  put(&header, 28, std::int32_t(5));
  put(&header, 32, std::int32_t(1024));
  put(&header, 548, w);
  put(&header, 552, h);
  put(&header, 556, std::uint32_t(24));
  put(&header, 560, std::uint32_t(24));
  put(&header, 564, image);
  put(&header, 568, std::uint32_t(200));
  put(&header, 572, static_cast<std::uint32_t>(frames.size()));
  put(&header, 580, true_size);
  put(&header, 584, 30.0);
  std::ofstream out(path, std::ios::binary);
  out.write(header.data(), static_cast<std::streamsize>(header.size()));
  for (std::size_t f = 0; f < frames.size(); ++f) {
    std::vector<char> bytes(true_size, 0);
    for (std::uint32_t p = 0; p < w * h; ++p)
      for (int c = 0; c < 3; ++c)
        bytes[3 * p + c] = static_cast<char>(frames[f].pixels[3 * p + 2 - c]);
    put(&bytes, image, std::int32_t(1'700'000'000));
    put(&bytes, image + 4, static_cast<std::uint16_t>(33 * f));
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  }
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
