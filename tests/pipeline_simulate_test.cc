// `flamerig simulate`'s dataset: complete, deterministic, the fire visible and well exposed.
#include <gtest/gtest.h>

#include <unistd.h>
#include <filesystem>
#include <fstream>

#include <yaml-cpp/yaml.h>

#include "core/error.h"
#include "core/image.h"
#include "core/srgb.h"
#include "pipeline/simulate.h"
#include "tomography/vdb_io.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

TEST(Simulate, WritesACompleteDeterministicDataset) {
  fs::path dir = fs::temp_directory_path() / ("flamerig_sim_test_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  SimulateConfig config;
  config.frames = 2;
  config.grid_resolution = 24;
  config.ring.width = 160;
  config.ring.height = 120;
  config.shared_per_pair = 2;
  config.closeups_per_camera = 1;
  config.board.square_m = 0.008;
  config.board.marker_m = 0.006;
  SimulateSummary s = Simulate(config, (dir / "a").string());
  Simulate(config, (dir / "b").string());
  EXPECT_EQ(s.frames, 2);
  EXPECT_GT(s.calibration_views, 0);
  EXPECT_GE(s.exposure, 0.01);
  EXPECT_LE(s.exposure, 1000);
  Rig rig = Rig::Load((dir / "a" / "rig.yaml").string());
  ASSERT_EQ(rig.cameras.size(), 2u);
  FireVolume truth = ReadVdb((dir / "a" / "truth" / "frame_000001.vdb").string());
  EXPECT_EQ(truth.geometry.dims.y(), 24);
  EXPECT_FALSE(truth.emission_rgb.empty());
  EXPECT_NEAR(truth.metadata_numbers.at("exposure"), s.exposure, 1e-12);
  for (const auto& cam : rig.cameras) {
    for (const char* frame : {"frame_000000", "frame_000001"}) {
      ImageU8 a = ReadImageU8((dir / "a" / "frames" / frame / (cam.name + ".png")).string());
      ImageU8 b = ReadImageU8((dir / "b" / "frames" / frame / (cam.name + ".png")).string());
      EXPECT_EQ(a.width, 160);
      EXPECT_EQ(a.channels, 3);
      EXPECT_EQ(a.pixels, b.pixels);  // deterministic
      int brightest = 0;
      for (auto p : a.pixels) brightest = std::max<int>(brightest, p);
      EXPECT_GT(brightest, 200);  // the fire is visible and well exposed
    }
  }
  EXPECT_TRUE(fs::exists(dir / "a" / "calibration" / "board.yaml"));
  EXPECT_TRUE(fs::exists(dir / "a" / "preview.png"));
  EXPECT_TRUE(fs::exists(dir / "a" / "dataset.yaml"));

  // Simulated again with fewer frames: no frame of the longer take stays behind, and a file of
  // the user's own stays.
  std::ofstream(dir / "a" / "notes.txt") << "mine\n";
  SimulateConfig shorter = config;
  shorter.frames = 1;
  shorter.calibration = false;
  Simulate(shorter, (dir / "a").string());
  EXPECT_TRUE(fs::exists(dir / "a" / "frames" / "frame_000000"));
  EXPECT_FALSE(fs::exists(dir / "a" / "frames" / "frame_000001"));
  EXPECT_FALSE(fs::exists(dir / "a" / "truth" / "frame_000001.vdb"));
  EXPECT_FALSE(fs::exists(dir / "a" / "calibration"));
  EXPECT_TRUE(fs::exists(dir / "a" / "notes.txt"));
  // A folder holding frames that simulate did not write (an exported recording) is refused and
  // left as it was.
  fs::create_directories(dir / "recorded" / "frames" / "frame_000000");
  std::ofstream(dir / "recorded" / "dataset.yaml") << "dataset:\n  rig: rig.yaml\n";
  try {
    Simulate(shorter, (dir / "recorded").string());
    ADD_FAILURE() << "simulated over an exported recording";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("no dataset.yaml written by flamerig simulate"),
              std::string::npos)
        << e.what();
  }
  EXPECT_TRUE(fs::exists(dir / "recorded" / "frames" / "frame_000000"));
  EXPECT_FALSE(fs::exists(dir / "recorded" / "rig.yaml"));
  fs::remove_all(dir);
}

// render.pixel_samples: each pixel the mean of N x N rays inside it (the renderer's test holds the
// rays to the pixel's covered share). The images keep the fire's light (an integral over the image
// that point samples and area samples both approximate), change where the fire's edges cross
// pixels, and the dataset says how they were made.
TEST(Simulate, PixelSamplesKeepTheLightAndSoftenTheEdges) {
  fs::path dir = fs::temp_directory_path() / ("flamerig_sim_pixels_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  SimulateConfig config;
  config.grid_resolution = 24;
  config.ring.width = 80;
  config.ring.height = 60;
  config.calibration = false;
  config.noise_dn = 0;
  config.auto_exposure = false;
  config.exposure = 0.5;
  Simulate(config, (dir / "point").string());
  config.pixel_samples = 4;
  Simulate(config, (dir / "area").string());
  const YAML::Node dataset = YAML::LoadFile((dir / "area" / "dataset.yaml").string());
  EXPECT_EQ(dataset["dataset"]["pixel_samples"].as<int>(), 4);
  for (const char* cam : {"cam0", "cam1"}) {
    const std::string name = std::string("frames/frame_000000/") + cam + ".png";
    const ImageU8 point = ReadImageU8((dir / "point" / name).string());
    const ImageU8 area = ReadImageU8((dir / "area" / name).string());
    double light_point = 0, light_area = 0;
    int differ = 0;
    for (std::size_t i = 0; i < point.pixels.size(); ++i) {
      light_point += SrgbDecode(point.pixels[i] / 255.0);
      light_area += SrgbDecode(area.pixels[i] / 255.0);
      differ += point.pixels[i] != area.pixels[i];
    }
    ASSERT_GT(light_point, 0) << cam;
    EXPECT_NEAR(light_area / light_point, 1.0, 0.03) << cam;
    EXPECT_GT(differ, 20) << cam;
  }
  SimulateConfig bad;
  bad.pixel_samples = 0;
  EXPECT_THROW(bad.Validate(), InputError);
  fs::remove_all(dir);
}

// Filters the rig's reader would refuse (100 nm), or where the sensor sees nothing (5000 nm), are
// refused before anything is written, naming the camera and its filter: the dataset was once
// half-written, its rig unreadable, and a second run into the same folder refused.
TEST(Simulate, CameraFiltersARigCannotHoldAreRefusedBeforeAnythingIsWritten) {
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_simulate_filters_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  SimulateConfig c;
  c.frames = 1;
  c.grid_resolution = 16;
  c.ring.cameras = 2;
  c.ring.width = 40;
  c.ring.height = 30;
  c.calibration = false;
  c.radiometry.transfer = TransferFunction::kLinear;
  c.radiometry.bit_depth = 12;
  c.radiometry.spectral.kind = SpectralSensitivity::Kind::kBands;
  c.radiometry.spectral.bands = {{700, 400}};
  for (const auto& [filter, says] :
       {std::pair{SpectralBand{100, 40},
                  "camera 1 (camera_filters[1]): radiometry.filter: "
                  "'centre_nm' must be in [200, 2000], got 100"},
        std::pair{SpectralBand{1900, 40}, "camera 1 (camera_filters[1]): camera response"}}) {
    c.camera_filters = {SpectralBand{650, 40}, filter};
    try {
      Simulate(c, dir.string());
      ADD_FAILURE() << "no error for " << filter.centre_nm;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(says), std::string::npos) << e.what();
    }
    EXPECT_FALSE(fs::exists(dir / "rig.yaml")) << filter.centre_nm;
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace flamerig
