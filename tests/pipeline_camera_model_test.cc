// The radiometric camera model through the pipeline: frames decoded through each rig camera's model
// (a mono frame from a colour camera refused with the reason, a deep camera's codes checked
// against its bit depth), what a simulated camera records decoding back to its signal, and the
// end-to-end measurement the model exists for: a camera that is not the sRGB observer, fitted with
// its own spectral response, gives the temperatures an sRGB camera gives, where assuming sRGB
// leaves a bias (scored against the simulator's truth, finer than the fit's grid).
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>

#include "core/error.h"
#include "fitting/absorption.h"
#include "fitting/camera_response.h"
#include "fitting/physics.h"
#include "pipeline/fit_job.h"
#include "pipeline/frame_source.h"
#include "pipeline/reconstruct_job.h"
#include "pipeline/simulate.h"
#include "tomography/vdb_io.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

CameraRadiometry Linear12() {
  CameraRadiometry r;
  r.transfer = TransferFunction::kLinear;
  r.bit_depth = 12;
  r.black_level = 64;
  return r;
}

// A mono machine-vision sensor (one broad band), 12-bit linear, for filters to go in front of.
CameraRadiometry MonoSensor() {
  CameraRadiometry r = Linear12();
  r.spectral.kind = SpectralSensitivity::Kind::kBands;
  r.spectral.bands = {{600, 250}};
  return r;
}

CameraRadiometry BandCamera() {
  CameraRadiometry r = Linear12();
  r.spectral.kind = SpectralSensitivity::Kind::kBands;
  r.spectral.bands = {{640, 60}, {540, 80}, {450, 60}};
  return r;
}

TEST(CameraModel, AMonoFrameFromAColourCameraIsRefusedWithTheReason) {
  ImageU8 mono(8, 6, 1, 100), rgb8;
  ImageU16 none;
  LinearFrame linear;
  ImageF signal;
  try {
    DecodeCameraImage(mono, none, 8, 1.0, CameraRadiometry(), &rgb8, &linear, &signal);
    FAIL() << "a mono frame was decoded as colour";
  } catch (const InputError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("one-channel (mono) frame"), std::string::npos) << what;
    EXPECT_NE(what.find("spectral sensitivity"), std::string::npos) << what;
  }
  // With the sensor's sensitivity given it decodes, one channel in three.
  CameraRadiometry m;
  m.spectral.kind = SpectralSensitivity::Kind::kBands;
  m.spectral.bands = {{650, 10}};
  DecodeCameraImage(mono, none, 8, 1.0, m, &rgb8, &linear, &signal);
  EXPECT_EQ(signal.channels, 3);
  EXPECT_EQ(signal.at(3, 2, 0), signal.at(3, 2, 2));
  // And a colour frame from a mono camera is an error too.
  ImageU8 colour(8, 6, 3, 100);
  EXPECT_THROW(DecodeCameraImage(colour, none, 8, 1.0, m, &rgb8, &linear, &signal), InputError);
}

TEST(CameraModel, DeepLinearFramesDecodeWithBlackLevelAndBitDepth) {
  ImageU8 none, rgb8;
  ImageU16 frame(4, 1, 3, 64);
  frame.pixels[3] = 2079;  // pixel 1: (2079 - 64) / (4095 - 64) = 0.5
  frame.pixels[6] = 4095;  // pixel 2: saturated
  frame.pixels[9] = 10;    // pixel 3: below black
  LinearFrame linear;
  ImageF signal;
  DecodeCameraImage(none, frame, 16, 2.0, Linear12(), &rgb8, &linear, &signal);
  EXPECT_NEAR(signal.at(1, 0, 0), (2079.0 - 64) / (4095 - 64), 1e-7);
  EXPECT_NEAR(linear.radiance.at(1, 0, 0), 0.5 * (2079.0 - 64) / (4095 - 64), 1e-7);
  EXPECT_EQ(signal.at(2, 0, 0), 1.0f);
  EXPECT_EQ(linear.saturated[2], 1);
  EXPECT_EQ(linear.saturated[1], 0);
  EXPECT_EQ(signal.at(3, 0, 0), 0.0f);
  // The same frame read as the default camera (16-bit linear over 65535) is 16 times darker:
  // that is what the bit depth is for.
  DecodeCameraImage(none, frame, 16, 2.0, CameraRadiometry(), &rgb8, &linear, &signal);
  EXPECT_NEAR(signal.at(1, 0, 0), 2079.0 / 65535, 1e-7);
  // A code beyond 12 bits names the bit depth.
  frame.pixels[0] = 5000;
  try {
    DecodeCameraImage(none, frame, 16, 2.0, Linear12(), &rgb8, &linear, &signal);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("12-bit camera"), std::string::npos) << e.what();
  }
}

TEST(CameraModel, WhatASimulatedCameraRecordsDecodesBackToItsSignal) {
  ImageF linear(64, 1, 3);
  for (int x = 0; x < 64; ++x)
    for (int c = 0; c < 3; ++c) linear.at(x, 0, c) = float(x) / 50 * (1 + 0.1 * c);
  const double exposure = 0.8;
  for (const CameraRadiometry& r : {Linear12(), CameraRadiometry()}) {
    ImageU8 u8, rgb8;
    ImageU16 u16;
    const int bits = RecordCameraImage(linear, exposure, r, 0, 1, &u8, &u16);
    EXPECT_EQ(bits, r.bit_depth == 12 ? 16 : 8);
    LinearFrame frame;
    ImageF signal;
    DecodeCameraImage(u8, u16, bits, exposure, r, &rgb8, &frame, &signal);
    // Quantisation: half a code of the camera's depth, through the transfer's steepest slope.
    const double tolerance = r.bit_depth == 12 ? 0.5 / 4031 + 1e-6 : 0.5 / 255 * 2.4 + 1e-6;
    for (int x = 0; x < 64; ++x)
      for (int c = 0; c < 3; ++c) {
        const double expected = std::min(1.0, exposure * linear.at(x, 0, c));
        EXPECT_NEAR(signal.at(x, 0, c), expected, tolerance) << x << " " << c;
      }
  }
}

// The temperature bias (fit - truth, K, on the truth's visible voxels) of a fit of a simulated
// 2-view candle filmed by cameras of `film`, fitted assuming `assume`.
double Bias(const fs::path& dir, const CameraRadiometry& film, const CameraRadiometry& assume,
            double* rms_k, double* fire_delta_e = nullptr) {
  SimulateConfig config;
  config.grid_resolution = 48;
  config.ring.width = 160;
  config.ring.height = 120;
  config.calibration = false;
  config.radiometry = film;
  const SimulateSummary s = Simulate(config, (dir / "data").string());
  Rig rig = Rig::Load((dir / "data" / "rig.yaml").string());
  for (RigCamera& c : rig.cameras) c.radiometry = assume;
  rig.Save((dir / "assumed" / "rig.yaml").string());
  FitJob job;
  job.rig_path = (dir / "assumed" / "rig.yaml").string();
  job.images_dir = (dir / "data" / "frames" / "frame_000000").string();
  job.out_path = (dir / "fit.vdb").string();
  job.resolution = 32;
  job.exposure = s.exposure;
  job.absorption = "soot";
  job.truth_path = (dir / "data" / "truth" / "frame_000000.vdb").string();
  const FitJobResult r = RunFitJob(job);
  EXPECT_TRUE(r.have_truth);
  *rms_k = r.truth.rms_k;
  if (fire_delta_e && !r.scores.empty()) *fire_delta_e = r.scores.front().fire_delta_e;
  return r.truth.mean_k;
}

// Two-colour pyrometry's rig (issue 19, item 6): simulate puts each mono camera behind its own
// band-pass filter (camera_filters), writes each camera's model with its filter into the rig, and
// films through it: of a fire near 2000 K a camera behind a 550 nm filter records less than one
// behind 650 nm (the oracle: the ratio of the two bands' soot emission through the sensor, which
// the frames' sums must follow to within the flame's own temperatures).
// A wrong count of filters is refused naming the key.
TEST(CameraModel, SimulatePutsEachMonoCameraBehindItsOwnFilter) {
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_filters_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  const CameraRadiometry mono = MonoSensor();
  SimulateConfig config;
  config.grid_resolution = 32;
  config.ring.width = 80;
  config.ring.height = 60;
  config.calibration = false;
  config.radiometry = mono;
  config.camera_filters = {SpectralBand{650, 40}, SpectralBand{550, 40}};
  Simulate(config, (dir / "data").string());
  const Rig rig = Rig::Load((dir / "data" / "rig.yaml").string());
  ASSERT_EQ(rig.cameras.size(), 2u);
  EXPECT_EQ(rig.cameras[0].radiometry.spectral.filter.centre_nm, 650);
  EXPECT_EQ(rig.cameras[1].radiometry.spectral.filter.centre_nm, 550);
  double sums[2] = {0, 0};
  for (int c = 0; c < 2; ++c) {
    ImageU8 u8;
    ImageU16 u16;
    const std::string path =
        (dir / "data" / "frames" / "frame_000000" / ("cam" + std::to_string(c) + ".png")).string();
    ASSERT_EQ(ReadImage(path, &u8, &u16), 16);
    for (std::uint16_t v : u16.pixels) sums[c] += std::max(0, int(v) - 64);  // above black
  }
  // The ratio of the two bands' soot emission (absorption cross-section times Planck, Kirchhoff)
  // through the sensor at 1500 and 2000 K brackets the frames' ratio: the flame's visible voxels
  // lie between.
  const AbsorptionModel soot = AbsorptionModel::DefaultSoot();
  auto band = [&](double centre, double t) {
    const SpectralBand filter{centre, 40}, sensor{600, 250};
    double sum = 0;
    for (int nm = 380; nm <= 780; ++nm)
      sum += filter.At(nm) * sensor.At(nm) * soot.CrossSectionM2(nm) *
             physics::PlanckRadiancePerNm(nm, t);
    return sum;
  };
  const double ratio = sums[1] / sums[0];
  std::printf("green / red frame sum %.4f; soot emission at 1500 K %.4f, at 2000 K %.4f\n", ratio,
              band(550, 1500) / band(650, 1500), band(550, 2000) / band(650, 2000));
  EXPECT_GT(ratio, band(550, 1500) / band(650, 1500));
  EXPECT_LT(ratio, band(550, 2000) / band(650, 2000));
  // `reconstruct` of these cameras: its emission is in their own channels, said in the volume, and
  // not scored against the truth's linear sRGB emission (a relative L2 of 1.2 that meant nothing).
  ReconstructJob job;
  job.rig_path = (dir / "data" / "rig.yaml").string();
  job.images_dir = (dir / "data" / "frames" / "frame_000000").string();
  job.out_path = (dir / "emission.vdb").string();
  job.reconstruct.resolution = 16;
  job.truth_path = (dir / "data" / "truth" / "frame_000000.vdb").string();
  const ReconstructJobResult reconstructed = RunReconstructJob(job);
  EXPECT_LT(reconstructed.truth_error, 0);
  ASSERT_FALSE(reconstructed.notes.empty());
  EXPECT_NE(reconstructed.notes.back().find("not compared with the truth"), std::string::npos)
      << reconstructed.notes.back();
  EXPECT_NE(reconstructed.exposure_source.find("dataset.yaml"), std::string::npos);
  const std::string units = ReadVdb(job.out_path).metadata_text.at("emission_units");
  EXPECT_NE(units.find("own unit-gain channels"), std::string::npos) << units;
  EXPECT_NE(units.find("650/40 nm filter"), std::string::npos) << units;
  config.camera_filters.pop_back();
  try {
    config.Validate();
    ADD_FAILURE() << "one filter for two cameras was taken";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("camera_filters"), std::string::npos) << e.what();
  }
  fs::remove_all(dir);
}

TEST(CameraModel, ANonSrgbCameraFittedWithItsResponseLosesTheBiasThatAssumingSrgbLeaves) {
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_camera_model_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  CameraRadiometry srgb_by_frame = Linear12();  // decodes right, assumes the sRGB observer
  double rms_reference = 0, rms_right = 0, rms_wrong = 0, de_reference = 0, de_right = 0;
  const double reference =
      Bias(dir / "srgb", Linear12(), Linear12(), &rms_reference, &de_reference);
  const double right = Bias(dir / "right", BandCamera(), BandCamera(), &rms_right, &de_right);
  const double wrong = Bias(dir / "wrong", BandCamera(), srgb_by_frame, &rms_wrong);
  std::printf(
      "temperature bias / RMS: sRGB camera %.1f / %.1f K; band camera with its response "
      "%.1f / %.1f K; assuming sRGB %.1f / %.1f K\n",
      reference, rms_reference, right, rms_right, wrong, rms_wrong);
  // The report scores a camera in its own channels against its own signal, as the fit does.
  std::printf("fire-pixel Delta E of the first view: sRGB camera %.2f, band camera %.2f\n",
              de_reference, de_right);
  EXPECT_GT(de_right, 0);
  EXPECT_LT(de_right, 2 * de_reference + 0.5);
  EXPECT_LT(std::abs(right - reference), 15.0);
  EXPECT_GT(std::abs(wrong - reference), 3 * std::abs(right - reference) + 30.0);
  fs::remove_all(dir);
}

TEST(CameraModel, AMonoCameraWithItsSensitivityGivenIsFittedWithFiniteResults) {
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_camera_mono_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  CameraRadiometry mono = Linear12();
  mono.spectral.kind = SpectralSensitivity::Kind::kBands;
  mono.spectral.bands = {{600, 200}};
  mono.spectral.filter = SpectralBand{650, 40};
  double rms = 0;
  const double bias = Bias(dir, mono, mono, &rms);
  std::printf("mono 650/40 nm camera, 2 views: bias %.1f K, RMS %.1f K\n", bias, rms);
  EXPECT_TRUE(std::isfinite(bias) && std::isfinite(rms));
  // Written as one channel per pixel.
  ImageU8 u8;
  ImageU16 u16;
  ASSERT_EQ(ReadImage((dir / "data" / "frames" / "frame_000000" / "cam0.png").string(), &u8, &u16),
            16);
  EXPECT_EQ(u16.channels, 1);
  fs::remove_all(dir);
}

// Two-colour pyrometry end to end (issue 19, item 6): four mono cameras in two pairs, each pair a
// few degrees apart (front and side), one of each pair behind a 650/40 nm filter and the other
// behind 550/40 nm. The fit starts each voxel's temperature from the ratio of the two bands' own
// tomographies (pipeline/band_tomography.h) and measures the temperature, scored against the
// simulator's truth (finer than the fit's grid); the same four cameras behind one filter cannot
// (no ratio: the temperature is left to the prior). Before the two-colour start this rig gave a
// bias of -342 K (RMS 490 K) like one band.
TEST(CameraModel, TwoColourPyrometryMeasuresTheTemperatureOneBandCannot) {
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_two_colour_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  auto fit = [&](const std::string& name, const std::vector<SpectralBand>& filters) {
    SimulateConfig config;
    config.grid_resolution = 48;
    config.ring.cameras = 4;
    config.ring.azimuths_deg = {0, 6, 90, 96};
    config.ring.width = 160;
    config.ring.height = 120;
    config.calibration = false;
    config.radiometry = MonoSensor();
    config.camera_filters = filters;
    const SimulateSummary s = Simulate(config, (dir / name / "data").string());
    FitJob job;
    job.rig_path = (dir / name / "data" / "rig.yaml").string();
    job.images_dir = (dir / name / "data" / "frames" / "frame_000000").string();
    job.out_path = (dir / name / "fit.vdb").string();
    job.resolution = 32;
    job.exposure = s.exposure;
    job.absorption = "soot";
    job.truth_path = (dir / name / "data" / "truth" / "frame_000000.vdb").string();
    const FitJobResult r = RunFitJob(job);
    EXPECT_TRUE(r.have_truth);
    return r;
  };
  const SpectralBand red{650, 40}, green{550, 40};
  const FitJobResult two = fit("two", {red, green, red, green});
  const FitJobResult one = fit("one", {red, red, red, red});
  std::printf(
      "two bands: bias %.1f K, RMS %.1f K (the truth's spread %.1f K), soot %.2f of the truth; "
      "one band: bias %.1f K, RMS %.1f K\n",
      two.truth.mean_k, two.truth.rms_k, two.truth.truth_spread_k,
      two.truth.fit_soot / two.truth.truth_soot, one.truth.mean_k, one.truth.rms_k);
  // Each band was reconstructed from its own two cameras.
  EXPECT_NE(two.tomography.find("band bands 600/250 nm behind a 650/40 nm filter from 2 view"),
            std::string::npos)
      << two.tomography;
  EXPECT_EQ(one.tomography.find("band "), std::string::npos) << one.tomography;
  EXPECT_LT(std::abs(two.truth.mean_k), 100.0);
  EXPECT_LT(two.truth.rms_k, 1.25 * two.truth.truth_spread_k);
  EXPECT_GT(std::abs(one.truth.mean_k), 200.0);
  EXPECT_GT(one.truth.rms_k, 2 * two.truth.rms_k);
  // The sigma says so: one band determines no voxel and gives each the search range's deviation
  // (the curvature alone called 60% of them determined, at errors of 400 K); two bands determine
  // some. The oracle: the uniform prior over [t_min, t_max], (t_max - t_min) / sqrt(12).
  const ObjectiveOptions& range = FitOptions().objective;
  const double prior = (range.t_max_k - range.t_min_k) / std::sqrt(12.0);
  EXPECT_TRUE(one.result.uncertainty.one_band);
  EXPECT_EQ(one.result.uncertainty.determined_count, 0u);
  ASSERT_FALSE(one.result.uncertainty.temperature_sigma_k.empty());
  for (float sigma : one.result.uncertainty.temperature_sigma_k)
    ASSERT_NEAR(sigma, prior, 1e-3 * prior);
  EXPECT_EQ(one.result.volume.metadata_numbers.at("one_band"), 1);
  EXPECT_EQ(one.result.volume.metadata_numbers.at("determined_voxels"), 0);
  EXPECT_FALSE(two.result.uncertainty.one_band);
  EXPECT_GT(two.result.uncertainty.determined_count, 0u);
  EXPECT_EQ(two.result.volume.metadata_numbers.count("one_band"), 0u);
  // The report says it too, beside the scores against the truth that `fit --truth` prints.
  auto report = [&](const std::string& name) {
    std::ifstream in(dir / name / "fit_report" / "report.md");
    return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  };
  EXPECT_NE(report("one").find("| voxels the images determine | 0 of "), std::string::npos)
      << report("one");
  EXPECT_NE(report("one").find("(one band: the temperature is the prior's)"), std::string::npos);
  EXPECT_NE(report("two").find(fmt::format("| temperature RMS, mean (fit - truth) | {:.1f} K, "
                                           "{:+.1f} K |",
                                           two.truth.rms_k, two.truth.mean_k)),
            std::string::npos)
      << report("two");
  // And its limit, as `fit --truth` prints it: the truth of 48 on the fit's grid of 32, each fitted
  // voxel showing its truth's light, holds less soot than the truth (a voxel's light shows its
  // hot part's colour) and errs less than the fit (measured: 0.87 of the visible soot, RMS 68 K
  // against the fit's 144 K).
  ASSERT_TRUE(two.limit.compared);
  std::printf("its limit: RMS %.1f K, bias %+.1f K, visible soot %.3f of the truth's\n",
              two.limit.rms_k, two.limit.mean_k,
              two.limit.fit_visible_soot / two.limit.truth_visible_soot);
  EXPECT_LT(two.limit.rms_k, two.truth.rms_k);
  EXPECT_LT(two.limit.fit_visible_soot, two.limit.truth_visible_soot);
  EXPECT_GT(two.limit.fit_visible_soot, 0.7 * two.limit.truth_visible_soot);
  EXPECT_NE(
      report("two").find(fmt::format("| its limit, the truth's light given exactly to each "
                                     "fitted voxel: temperature RMS, mean; soot in the "
                                     "truth's visible voxels, of the truth's there | {:.1f} "
                                     "K, {:+.1f} K; {:.3f} |",
                                     two.limit.rms_k, two.limit.mean_k,
                                     two.limit.fit_visible_soot / two.limit.truth_visible_soot)),
      std::string::npos)
      << report("two");
  fs::remove_all(dir);
}

}  // namespace
}  // namespace flamerig
