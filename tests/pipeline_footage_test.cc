// Real footage reaching the tomography: the input transfer function of plain images, the
// tomography's config file, and frames through a real video codec (ffmpeg).
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include "calibration/synthetic_rig.h"
#include "core/error.h"
#include "core/srgb.h"
#include "pipeline/frame_source.h"
#include "pipeline/subprocess.h"
#include "pipeline/tomography_config.h"
#include "pipeline/video_codec.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

fs::path TempDir(const std::string& name) {
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_footage_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

// A child's peak memory is its own: a small child of a parent holding 300 MB reports a few MB (wait4's
// ru_maxrss said 300+, the parent's peak at the spawn), and a child that holds 200 MB reports at
// least that.
TEST(RunProgram, ReportsTheChildsOwnPeakNotTheParents) {
  std::vector<char> held(300u << 20);
  for (std::size_t i = 0; i < held.size(); i += 4096) held[i] = static_cast<char>(i);
  const ProgramResult small = RunProgram({"sh", "-c", "sleep 0.3"});
  ASSERT_TRUE(small.ok()) << small.error;
  EXPECT_GT(small.peak_resident_bytes, 0u);
  EXPECT_LT(small.peak_resident_bytes, 50u << 20);
  const ProgramResult big = RunProgram(
      {"python3", "-c", "import time; x = bytearray(200 * 1024 * 1024); time.sleep(0.3)"});
  ASSERT_TRUE(big.ok()) << big.error;
  EXPECT_GE(big.peak_resident_bytes, 200u << 20);
  EXPECT_LT(big.peak_resident_bytes, 290u << 20);
  EXPECT_EQ(held[4096], static_cast<char>(4096));
}

TEST(InputTransfer, SpecsParseOrNameTheForms) {
  TransferFunction t;
  double gamma = 0;
  ParseTransferSpec("linear", &t, &gamma);
  EXPECT_EQ(t, TransferFunction::kLinear);
  ParseTransferSpec("srgb", &t, &gamma);
  EXPECT_EQ(t, TransferFunction::kSrgb);
  ParseTransferSpec("gamma=2.4", &t, &gamma);
  EXPECT_EQ(t, TransferFunction::kGamma);
  EXPECT_DOUBLE_EQ(gamma, 2.4);
  for (const char* bad : {"log", "gamma=", "gamma=abc", "gamma=2.2x", "gamma=0", "gamma=11", ""}) {
    try {
      ParseTransferSpec(bad, &t, &gamma);
      ADD_FAILURE() << bad;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("linear, srgb or gamma=G"), std::string::npos)
          << e.what();
    }
  }
}

// Code 128 of an 8-bit frame is 128/255 of full scale when linear, the sRGB curve's value when
// sRGB, (128/255)^G with a gamma: the camera's signal through every rig camera.
TEST(InputTransfer, DecodesEightBitFramesAsTold) {
  const Box3 box{Eigen::Vector3d(-0.01, 0, -0.01), Eigen::Vector3d(0.01, 0.02, 0.01)};
  synthetic::RingOptions ring;
  ring.cameras = 2;
  const Rig rig = synthetic::MakeRingRig(box, ring);
  const ImageU8 frame(4, 4, 3, 128);
  const double code = 128.0 / 255;
  const std::vector<std::pair<std::string, double>> cases = {
      {"", SrgbDecode(code)},  // the rig's default
      {"srgb", SrgbDecode(code)},
      {"linear", code},
      {"gamma=2.4", std::pow(code, 2.4)}};
  for (const auto& [spec, want] : cases) {
    const Rig r = WithInputTransfer(rig, spec);
    for (const RigCamera& camera : r.cameras) {
      ImageU8 picture;
      LinearFrame linear;
      ImageF signal;
      DecodeCameraImage(frame, ImageU16(), 8, 2.0, camera.radiometry, &picture, &linear, &signal);
      EXPECT_NEAR(signal.at(1, 1, 0), want, 1e-6) << spec;
      EXPECT_NEAR(linear.radiance.at(1, 1, 2), want / 2.0, 1e-6) << spec;
    }
  }
  EXPECT_THROW(WithInputTransfer(rig, "loglinear"), InputError);
}

TEST(TomographyConfig, TheShippedFileHoldsTheDefaults) {
  ReconstructOptions o;
  std::string transfer;
  LoadTomographyConfig(std::string(FLAMERIG_SOURCE_DIR) + "/config/tomography.yaml", &o, &transfer);
  const ReconstructOptions d;
  EXPECT_EQ(transfer, "srgb");
  EXPECT_EQ(o.resolution, d.resolution);
  EXPECT_EQ(o.bin, d.bin);
  EXPECT_EQ(o.solve.solver, d.solve.solver);
  EXPECT_EQ(o.solve.max_iterations, d.solve.max_iterations);
  EXPECT_DOUBLE_EQ(o.solve.relaxation, d.solve.relaxation);
  EXPECT_DOUBLE_EQ(o.solve.stagnation_tolerance, d.solve.stagnation_tolerance);
  EXPECT_EQ(o.solve.holdout_patience, d.solve.holdout_patience);
  EXPECT_EQ(o.solve.prior, d.solve.prior);
  EXPECT_DOUBLE_EQ(o.solve.prior_weight, d.solve.prior_weight);
  EXPECT_DOUBLE_EQ(o.solve.prior_edge, d.solve.prior_edge);
  EXPECT_EQ(o.coarse_to_fine, d.coarse_to_fine);
  EXPECT_EQ(o.coarse_iterations, d.coarse_iterations);
  EXPECT_DOUBLE_EQ(o.warm_stagnation_tolerance, d.warm_stagnation_tolerance);
  EXPECT_EQ(o.two_view_fine_iterations, d.two_view_fine_iterations);
  EXPECT_EQ(o.envelope_margin_voxels, d.envelope_margin_voxels);
  EXPECT_DOUBLE_EQ(o.hull.threshold_sigmas, d.hull.threshold_sigmas);
  EXPECT_DOUBLE_EQ(o.hull.noise_sigma, d.hull.noise_sigma);
  EXPECT_EQ(o.hull.dilation_px, d.hull.dilation_px);
  EXPECT_EQ(o.hull.min_views, d.hull.min_views);
  EXPECT_EQ(o.hull.min_speck_px, d.hull.min_speck_px);
}

TEST(TomographyConfig, ReadsKeysAndNamesTheFileAndKeyOfAnError) {
  const fs::path dir = TempDir("config");
  auto write = [&](const std::string& text) {
    const fs::path p = dir / "t.yaml";
    std::ofstream(p) << text;
    return p.string();
  };
  ReconstructOptions o;
  std::string transfer;
  LoadTomographyConfig(write("tomography:\n  resolution: 48\n  input_transfer: gamma=2.2\n"
                             "  cache: m\n  mask: {min_speck_px: 7, threshold_sigmas: 3}\n"
                             "  prior: tv\n  prior_weight: 0.5\n  bin: 3\n"
                             "  two_view_fine_iterations: -1\n"),
                       &o, &transfer);
  EXPECT_EQ(o.resolution, 48);
  EXPECT_EQ(transfer, "gamma=2.2");
  EXPECT_EQ(o.hull.min_speck_px, 7);
  EXPECT_DOUBLE_EQ(o.hull.threshold_sigmas, 3);
  EXPECT_EQ(o.solve.prior, "tv");
  EXPECT_EQ(o.bin, 3);
  EXPECT_DOUBLE_EQ(o.solve.prior_weight, 0.5);
  EXPECT_EQ(o.two_view_fine_iterations, -1);
  EXPECT_EQ(fs::path(o.cache_dir), dir / "m");  // relative to the file
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"tomography:\n  resolutoin: 48\n", "unknown key 'resolutoin'"},
      {"tomography:\n  mask: {dilation: 2}\n", "unknown key 'dilation'"},
      {"tomography:\n  resolution: 0\n", "'resolution' must be in [1, 1024]"},
      {"tomography:\n  mask: {min_views: 0}\n", "'min_views'"},
      {"tomography:\n  input_transfer: log\n", "'input_transfer'"},
      {"tomography:\n  solver: lsqr\n", "solver 'lsqr' is unknown"},
      {"tomography:\n  prior: laplace\n", "prior 'laplace' is unknown"},
      {"tomography:\n  solver: sart\n  prior: tv\n", "needs solver osem"},
      {"tomography:\n  prior_weight: -0.5\n", "'prior_weight'"},
      {"tomography:\n  bin: 0\n", "'bin'"},
      {"tomography:\n  two_view_fine_iterations: 0\n", "'two_view_fine_iterations'"},
      // A count given as a fraction: an error, not truncated to 2.
      {"tomography:\n  two_view_fine_iterations: 2.7\n",
       "'two_view_fine_iterations' must be a whole number"},
      {"tomography:\n  mask: {dilation_px: 1.5}\n", "'dilation_px' must be a whole number"},
      {"resolution: 48\n", "a 'tomography:' map"},
      {"tomography: [1, 2]\n", "a 'tomography:' map"}};
  for (const auto& [text, message] : bad) {
    const std::string path = write(text);
    try {
      ReconstructOptions x;
      std::string t;
      LoadTomographyConfig(path, &x, &t);
      ADD_FAILURE() << text;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(message), std::string::npos) << e.what();
    }
  }
  fs::remove_all(dir);
}

// Frames through libx264 come back the same size, close to the original where it is smooth, and
// with the codec's marks on an exactly black background: lit pixels near the edges of the fire.
TEST(VideoCodec, Libx264KeepsTheFrameAndLeavesItsMarks) {
  const int w = 97, h = 71;  // odd: padded for 4:2:0 and cropped back
  ImageU8 frame(w, h, 3, 0);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const double r = std::hypot(x - 48.0, y - 35.0);
      if (r < 18)
        for (int c = 0; c < 3; ++c)
          frame.at(x, y, c) = static_cast<std::uint8_t>(std::lround((240 - 60 * c) * (1 - r / 36)));
    }
  VideoCodecOptions codec;
  codec.crf = 30;
  const std::vector<ImageU8> out = ThroughVideoCodec({frame, frame}, codec);
  ASSERT_EQ(out.size(), 2u);
  ASSERT_EQ(out[0].width, w);
  ASSERT_EQ(out[0].height, h);
  ASSERT_EQ(out[0].channels, 3);
  double inside = 0;
  int n = 0, lit_background = 0;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const double r = std::hypot(x - 48.0, y - 35.0);
      if (r < 12) {
        for (int c = 0; c < 3; ++c) inside += std::abs(out[0].at(x, y, c) - frame.at(x, y, c));
        n += 3;
      }
      if (r > 18 && (out[0].at(x, y, 0) || out[0].at(x, y, 1) || out[0].at(x, y, 2)))
        ++lit_background;
    }
  EXPECT_LT(inside / n, 8.0);    // mean absolute error in codes, inside the disc (5.3 measured)
  EXPECT_GT(inside / n, 0.0);    // lossy
  EXPECT_GT(lit_background, 0);  // ringing and chroma bleeding past the edge
  // A lossless encode gives the frame back to within the colour conversion's rounding.
  codec.crf = 0;
  codec.pixel_format = "yuv444p";
  const ImageU8 lossless = ThroughVideoCodec({frame}, codec)[0];
  int worst = 0;
  for (std::size_t i = 0; i < frame.pixels.size(); ++i)
    worst = std::max(worst, std::abs(lossless.pixels[i] - frame.pixels[i]));
  EXPECT_LE(worst, 3);
  // Bad input is an error naming it.
  EXPECT_THROW(ThroughVideoCodec({frame, ImageU8(10, 10, 3)}, codec), InputError);
  codec.codec = "x264; rm -rf";
  EXPECT_THROW(ThroughVideoCodec({frame}, codec), InputError);
}

}  // namespace
}  // namespace flamerig
