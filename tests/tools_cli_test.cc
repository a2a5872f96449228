// The flamerig binary end to end: help, errors, simulate, and render reproducing simulate's images.
#include <gtest/gtest.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include "acquisition/image.h"

namespace {

namespace fs = std::filesystem;

struct Result {
  int status;
  std::string output;
};

Result Flamerig(const std::string& args) {
  std::string command = std::string(FLAMERIG_BINARY) + " " + args + " 2>&1";
  std::array<char, 4096> buffer;
  Result r{-1, ""};
  FILE* pipe = popen(command.c_str(), "r");
  if (!pipe) return r;
  while (fgets(buffer.data(), buffer.size(), pipe)) r.output += buffer.data();
  int status = pclose(pipe);
  r.status = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

fs::path TempDir() {
  fs::path dir =
      fs::temp_directory_path() / ("flamerig_cli_test_" + std::to_string(::getpid()) + "_" +
                                   ::testing::UnitTest::GetInstance()->current_test_info()->name());
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

TEST(Cli, HelpAndUnknownCommands) {
  Result help = Flamerig("help");
  EXPECT_EQ(help.status, 0);
  EXPECT_NE(help.output.find("simulate"), std::string::npos);
  EXPECT_EQ(Flamerig("").status, 2);
  Result unknown = Flamerig("frobnicate");
  EXPECT_EQ(unknown.status, 2);
  EXPECT_NE(unknown.output.find("unknown command"), std::string::npos);
  Result missing = Flamerig("simulate --out /tmp/x");
  EXPECT_EQ(missing.status, 1);
  EXPECT_NE(missing.output.find("--config"), std::string::npos);
}

TEST(Cli, MalformedConfigNamesFileAndField) {
  fs::path dir = TempDir();
  std::ofstream((dir / "bad.yaml").string()) << "simulate:\n  frames: -3\n";
  Result r = Flamerig("simulate --config " + (dir / "bad.yaml").string() + " --out " +
                      (dir / "out").string());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.output.find("bad.yaml"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("frames"), std::string::npos) << r.output;
  std::ofstream((dir / "bad2.yaml").string()) << "simulate:\n  rig: {width: many}\n";
  r = Flamerig("simulate --config " + (dir / "bad2.yaml").string() + " --out " +
               (dir / "out").string());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.output.find("simulate.rig.width"), std::string::npos) << r.output;
  fs::remove_all(dir);
}

// Rendering the ground truth with `flamerig render` reproduces the images `flamerig simulate` wrote
// (noise off): the dataset is self-consistent and the render command uses the same physics.
TEST(Cli, RenderReproducesSimulatedImages) {
  fs::path dir = TempDir();
  std::ofstream((dir / "sim.yaml").string())
      << "simulate:\n  frames: 1\n  noise_dn: 0\n  grid_resolution: 24\n  rig: {width: 120, "
         "height: 90}\n"
      << "  calibration: {enabled: false}\n";
  Result sim = Flamerig("simulate --config " + (dir / "sim.yaml").string() + " --out " +
                        (dir / "data").string());
  ASSERT_EQ(sim.status, 0) << sim.output;
  Result render = Flamerig("render --rig " + (dir / "data" / "rig.yaml").string() + " --volume " +
                           (dir / "data" / "truth" / "frame_000000.vdb").string() + " --out " +
                           (dir / "render").string());
  ASSERT_EQ(render.status, 0) << render.output;
  for (const char* cam : {"cam0", "cam1"}) {
    flamerig::ImageU8 a = flamerig::ReadImageU8(
        (dir / "data" / "frames" / "frame_000000" / (std::string(cam) + ".png")).string());
    flamerig::ImageU8 b =
        flamerig::ReadImageU8((dir / "render" / (std::string(cam) + ".png")).string());
    EXPECT_EQ(a.pixels, b.pixels) << cam;
  }
  fs::remove_all(dir);
}

}  // namespace
