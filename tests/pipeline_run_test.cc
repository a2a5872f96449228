// `flamerig run`: whole recordings through tomography and the fit. Oracles: the simulator's ground
// truth (temperature, images), the recording's own content (which camera missed which set), an
// uninterrupted run for a killed-and-resumed one, closed forms for the Blender grids.
#include <gtest/gtest.h>
#include <openvdb/openvdb.h>
#include <signal.h>
#include <sys/wait.h>
#include <tbb/global_control.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <numeric>
#include <random>
#include <sstream>
#include <thread>

#include "acquisition/capture.h"
#include "acquisition/clock.h"
#include "acquisition/recording.h"
#include "core/atomic_file.h"
#include "core/error.h"
#include "core/read_file.h"
#include "core/srgb.h"
#include "fitting/physics.h"
#include "pipeline/blender_export.h"
#include "pipeline/distributed.h"
#include "pipeline/export.h"
#include "pipeline/fit_job.h"
#include "pipeline/fit_report.h"
#include "pipeline/frame_stages.h"
#include "pipeline/reconstruct_job.h"
#include "pipeline/run.h"
#include "pipeline/run_report.h"
#include "pipeline/simulate.h"
#include "pipeline/truth.h"
#include "tests/run_test_util.h"
#include "tomography/vdb_io.h"

namespace flamerig {
namespace {

// One column of a run's frames.csv by frame, read by Python's csv module (an independent reader).
std::map<std::size_t, std::string> FramesCsvColumn(const std::filesystem::path& csv,
                                                   const std::string& column) {
  const std::string command = "/usr/bin/python3 -c \"import csv,sys; [print(r['frame'], r['" +
                              column + "']) for r in csv.DictReader(open(sys.argv[1]))]\" " +
                              csv.string();
  std::map<std::size_t, std::string> values;
  std::unique_ptr<FILE, int (*)(FILE*)> pipe(popen(command.c_str(), "r"), pclose);
  if (!pipe) return values;
  char line[256];
  while (fgets(line, sizeof line, pipe.get())) {
    std::istringstream words(line);
    std::size_t frame = 0;
    std::string value;
    if (words >> frame >> value) values[frame] = value;
  }
  return values;
}

namespace fs = std::filesystem;

using namespace testing_run;

// A uniform field on `dims` voxels over the 4 mm cube at the origin.
FireVolume Cube(int n, float temperature_k) {
  FireVolume v;
  v.geometry.dims = Eigen::Vector3i::Constant(n);
  v.geometry.origin_in_rig = Eigen::Vector3d::Zero();
  v.geometry.voxel_size_m = Eigen::Vector3d::Constant(0.004 / n);
  v.temperature_k.assign(v.geometry.num_voxels(), temperature_k);
  v.density_per_m3.assign(v.geometry.num_voxels(), 1e16f);
  return v;
}

// A truth three times finer than the fit, shown on the fit's grid: each fit voxel takes the truth
// voxel holding its centre, the middle one of its 3x3x3 (index arithmetic is the oracle).
TEST(TruthOnTheFitsGrid, EachFitVoxelTakesTheTruthVoxelHoldingItsCentre) {
  FireVolume fine = Cube(12, 0);
  for (int k = 0; k < 12; ++k)
    for (int j = 0; j < 12; ++j)
      for (int i = 0; i < 12; ++i)
        fine.temperature_k[fine.geometry.Flat(i, j, k)] = float(1000 + 100 * i + 10 * j + k);
  fine.soot_volume_fraction.resize(fine.temperature_k.size());
  for (std::size_t v = 0; v < fine.temperature_k.size(); ++v)
    fine.soot_volume_fraction[v] = 1e-9f * fine.temperature_k[v];
  fine.metadata_text["absorption_model"] = "soot";
  const FireVolume coarse = Cube(4, 0);
  const FireVolume sampled = SampleOnGrid(fine, coarse.geometry);
  ASSERT_EQ(sampled.temperature_k.size(), 64u);
  ASSERT_EQ(sampled.soot_volume_fraction.size(), 64u);
  for (int k = 0; k < 4; ++k)
    for (int j = 0; j < 4; ++j)
      for (int i = 0; i < 4; ++i) {
        const float t = float(1000 + 100 * (3 * i + 1) + 10 * (3 * j + 1) + (3 * k + 1));
        EXPECT_EQ(sampled.temperature_k[coarse.geometry.Flat(i, j, k)], t);
        EXPECT_EQ(sampled.soot_volume_fraction[coarse.geometry.Flat(i, j, k)], 1e-9f * t);
      }
  EXPECT_EQ(sampled.metadata_text.at("absorption_model"), "soot");
  // A grid reaching beyond the truth's box: no medium there.
  FireVolume wide = Cube(4, 0);
  wide.geometry.voxel_size_m *= 2;
  const FireVolume outside = SampleOnGrid(fine, wide.geometry);
  EXPECT_GT(outside.density_per_m3[wide.geometry.Flat(0, 0, 0)], 0);
  EXPECT_EQ(outside.density_per_m3[wide.geometry.Flat(3, 3, 3)], 0);
}

// The run report's slices: a row each for the fit, the truth (finer than the fit, resampled), the
// error and the sigma; the truth row shows the truth's colours, not the fit's.
TEST(RunReport, SlicesShowFitTruthErrorAndSigmaWhenTheTruthIsFiner) {
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_report_slices_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / "out");
  fs::create_directories(dir / "truth");
  FireVolume fit = Cube(8, 1200);
  fit.temperature_sigma_k.assign(fit.geometry.num_voxels(), 150.0f);
  WriteVdb((dir / "out" / "frame_000000.vdb").string(), fit);
  WriteVdb((dir / "truth" / "frame_000000.vdb").string(), Cube(24, 2000));
  FrameSummary f;
  f.frame = 0;
  f.status = "computed";
  f.truth_frame = 0;
  RunReportInfo info;
  info.truth_dir = (dir / "truth").string();
  WriteRunReport((dir / "out").string(), {f}, info);
  const ImageU8 slices = ReadImageU8((dir / "out" / "report" / "slices_000000.png").string(), 3);
  // Four rows of (24 px title + 24 px panel label + 8 voxels x 40 px + 16 px gap).
  const int row = 24 + 24 + 8 * 40 + 16;
  ASSERT_EQ(slices.height, 4 * row);
  auto pixel = [&](int r) {
    const int x = 160, y = r * row + 48 + 160;  // the middle of the front panel
    return std::array<int, 3>{slices.at(x, y, 0), slices.at(x, y, 1), slices.at(x, y, 2)};
  };
  const auto fit_colour = pixel(0), truth_colour = pixel(1), error_colour = pixel(2);
  EXPECT_NE(truth_colour, fit_colour);                        // 2000 K against 1200 K
  EXPECT_NE(truth_colour, (std::array<int, 3>{40, 40, 40}));  // medium, not "none"
  // fit - truth = -800 K: saturated blue.
  EXPECT_EQ(error_colour, (std::array<int, 3>{0, 0, 255}));
  // Without the truth and the sigma: the fit's row alone.
  fit.temperature_sigma_k.clear();
  WriteVdb((dir / "out" / "frame_000000.vdb").string(), fit);
  WriteRunReport((dir / "out").string(), {f}, RunReportInfo());
  EXPECT_EQ(ReadImageU8((dir / "out" / "report" / "slices_000000.png").string(), 3).height, row);
  fs::remove_all(dir);
}

// The slices put the rig's up at the top: +y, or -y for a rig in its first camera's frame (whose
// y points down; such a fire was drawn on its head until 2026-12-02). And the temperature scale
// spans the truth as well as the fit: a truth hotter than the fit was drawn in the top colour
// whatever its temperature.
TEST(RunReport, SlicesPutTheRigsUpAtTheTopAndScaleToTheTruthToo) {
  FireVolume fit = Cube(8, 1000);
  for (int k = 0; k < 8; ++k)
    for (int j = 0; j < 8; ++j)
      for (int i = 0; i < 8; ++i) fit.temperature_k[fit.geometry.Flat(i, j, k)] = 1000 + 100 * j;
  const int top = 48 + 20, bottom = 48 + 7 * 40 + 20;  // the first and last voxel rows' middles
  auto colour = [](const ImageU8& picture, int y) {
    return std::array<int, 3>{picture.at(160, y, 0), picture.at(160, y, 1), picture.at(160, y, 2)};
  };
  const ImageU8 y_up = SlicesPicture(fit);
  const ImageU8 minus_y_up = SlicesPicture(fit, nullptr, Rigid3(), -Eigen::Vector3d::UnitY());
  ASSERT_EQ(y_up.height, minus_y_up.height);
  EXPECT_NE(colour(y_up, top), colour(y_up, bottom));
  EXPECT_EQ(colour(y_up, top), colour(minus_y_up, bottom));  // the hot layer, j = 7
  EXPECT_EQ(colour(y_up, bottom), colour(minus_y_up, top));  // the cool one, j = 0
  // A truth at 1800 K below and 2000 K above, beside a fit of at most 1700 K: two colours in the
  // truth's row, where a scale of the fit's alone drew both in its top colour.
  FireVolume truth = Cube(8, 1800);
  for (int k = 0; k < 8; ++k)
    for (int j = 4; j < 8; ++j)
      for (int i = 0; i < 8; ++i) truth.temperature_k[truth.geometry.Flat(i, j, k)] = 2000;
  const int row = 24 + 24 + 8 * 40 + 16;
  const ImageU8 with_truth = SlicesPicture(fit, &truth);
  EXPECT_NE(colour(with_truth, row + top), colour(with_truth, row + bottom));
}

// A resumed run's times and rates cover the same frames: the one line counts this call's frames'
// stage times against this call's seconds, and the report (every frame in OUT) its frames' own
// times. Both divided every frame's work by this call's time until 2026-12-02 (a resume that
// computed nothing reported 361 frames a minute).
TEST(RunReport, AResumedRunsRateCoversTheFramesItTimes) {
  FrameSummary earlier, now;
  earlier.frame = 0;
  now.frame = 1;
  earlier.status = now.status = "computed";
  earlier.fit_ms = 4000;
  earlier.reconstruct_ms = 1000;
  earlier.total_ms = 6000;
  now.fit_ms = 1500;
  now.reconstruct_ms = 500;
  now.total_ms = 3000;
  RunSummary run;
  run.begin = 0;
  run.end = 2;
  run.resumed = 1;
  run.computed = 1;
  run.seconds = 3.0;
  run.frames = {earlier, now};
  const std::string line = run.BriefReport();
  EXPECT_NE(line.find("20.0 computed frames/min; tomography 0.5 s, fit 1.5 s"), std::string::npos)
      << line;
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_report_rate_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  RunReportInfo info;
  info.wall_seconds = 0.5;  // a call that resumed both frames and computed nothing
  WriteRunReport(dir.string(), {earlier, now}, info);
  std::ifstream in(dir / "report" / "index.html");
  const std::string html((std::istreambuf_iterator<char>(in)), {});
  EXPECT_NE(html.find("The 2 computed frames took 9.0 s, read to write: 13.3 computed frames per "
                      "minute"),
            std::string::npos);
  EXPECT_NE(html.find("This call of run took 0.5 s."), std::string::npos);
  EXPECT_EQ(html.find("240.0"), std::string::npos);  // 2 frames in this call's 0.5 s
  fs::remove_all(dir);
}

// The state files and the report's JSON keep every field: doubles to the last bit, NaN and
// infinities (as YAML's .nan and .inf), empty lists, strings that look like numbers or booleans,
// and text that is not UTF-8 (replaced in JSON, not thrown on).
TEST(FrameSummary, YamlAndJsonKeepEveryField) {
  FrameSummary f;
  f.frame = 123456789;
  f.status = "true";
  f.cameras_used = 3;
  f.read_ms = 0.1;
  f.reconstruct_ms = 1.0 / 3.0;
  f.fit_ms = 2e-300;
  f.total_ms = 1e300;
  f.matrix_source = "1e5";
  f.hull_fraction = 0.125;
  f.active_voxels = 4000000000ull;
  f.exposure = 1.5442877277419982;
  f.exposure_from = "held from frame 0";
  f.energy = std::nan("");
  f.initial_energy = std::numeric_limits<double>::infinity();
  f.fit_message = "a \"quoted\" message: with colons, and\nlines";
  f.voxels_at_temperature_bound = 7;
  f.voxels_at_density_bound = 1;
  f.delta_e = {{"1e5", true, 0.5, 1.25}, {"null", false, -0.0, 3}};
  f.truth_rms_k = -1;
  f.truth_spread_k = 141.75;
  f.truth_within_1_sigma = 0.68;
  f.truth_determined_share = 0.625;
  f.truth_determined_rms_k = 123.5;
  f.truth_undetermined_rms_k = 250.25;
  f.truth_weighted_rms_k = 54.125;
  f.truth_weighted_bias_k = -12.5;
  f.truth_visible_soot = 1.5e11;
  f.visible_soot = 1.25e11;
  f.limit_rms_k = 55.5;
  f.limit_bias_k = -2.25;
  f.limit_visible_soot = 1.375e11;
  f.limit_soot = 1.4375e11;
  const FrameSummary back = FrameSummary::FromYaml(f.ToYaml(), "test");
  EXPECT_EQ(back.frame, f.frame);
  EXPECT_EQ(back.status, "true");
  EXPECT_TRUE(back.notes.empty());
  EXPECT_EQ(back.reconstruct_ms, f.reconstruct_ms);
  EXPECT_EQ(back.fit_ms, f.fit_ms);
  EXPECT_EQ(back.total_ms, f.total_ms);
  EXPECT_EQ(back.matrix_source, "1e5");
  EXPECT_EQ(back.active_voxels, f.active_voxels);
  EXPECT_EQ(back.exposure, f.exposure);
  EXPECT_TRUE(std::isnan(back.energy));
  EXPECT_EQ(back.initial_energy, std::numeric_limits<double>::infinity());
  EXPECT_EQ(back.fit_message, f.fit_message);
  EXPECT_EQ(back.voxels_at_temperature_bound, 7u);
  EXPECT_EQ(back.voxels_at_density_bound, 1u);
  ASSERT_EQ(back.delta_e.size(), 2u);
  EXPECT_EQ(back.delta_e[0].camera, "1e5");
  EXPECT_TRUE(back.delta_e[0].held_out);
  EXPECT_EQ(back.delta_e[0].fire, 1.25);
  EXPECT_EQ(back.delta_e[1].camera, "null");
  EXPECT_EQ(back.truth_spread_k, 141.75);
  EXPECT_EQ(back.truth_within_1_sigma, 0.68);
  EXPECT_EQ(back.truth_within_2_sigma, -1);
  EXPECT_EQ(back.truth_determined_share, 0.625);
  EXPECT_EQ(back.truth_determined_rms_k, 123.5);
  EXPECT_EQ(back.truth_undetermined_rms_k, 250.25);
  EXPECT_EQ(back.truth_weighted_rms_k, 54.125);
  EXPECT_EQ(back.truth_weighted_bias_k, -12.5);
  EXPECT_EQ(back.truth_visible_soot, 1.5e11);
  EXPECT_EQ(back.visible_soot, 1.25e11);
  EXPECT_EQ(back.limit_rms_k, 55.5);
  EXPECT_EQ(back.limit_bias_k, -2.25);
  EXPECT_EQ(back.limit_visible_soot, 1.375e11);
  EXPECT_EQ(back.limit_soot, 1.4375e11);
  {
    // A summary written before the weighted bias was reads it as NaN (0 is a bias), and its line
    // leaves it out.
    std::string older = f.ToYaml();
    const std::size_t at = older.find("truth_weighted_bias_k:");
    ASSERT_NE(at, std::string::npos);
    older.erase(at, older.find('\n', at) + 1 - at);
    FrameSummary old = FrameSummary::FromYaml(older, "test");
    EXPECT_TRUE(std::isnan(old.truth_weighted_bias_k));
    EXPECT_EQ(old.truth_weighted_rms_k, 54.125);
    old.status = "computed";
    old.truth_rms_k = 80;
    EXPECT_NE(old.Line().find("emission-weighted RMS 54.1 K"), std::string::npos) << old.Line();
    EXPECT_EQ(old.Line().find("(bias"), std::string::npos) << old.Line();
    old.truth_weighted_bias_k = -12.5;
    EXPECT_NE(old.Line().find("emission-weighted RMS 54.1 K (bias -12.5 K)"), std::string::npos)
        << old.Line();
  }
  {
    // A summary written before the fit's limit was scored reads it as none (-1).
    std::string older = f.ToYaml();
    const std::size_t at = older.find("limit_rms_k:");
    ASSERT_NE(at, std::string::npos);
    older.erase(at, older.find('\n', at) + 1 - at);
    EXPECT_EQ(FrameSummary::FromYaml(older, "test").limit_rms_k, -1);
  }
  // Not UTF-8: the JSON replaces it and stays JSON (Python's json module reads it).
  f.notes = {std::string("image \xff\xfe.png unreadable")};
  const std::string json = f.ToJson();
  EXPECT_NE(json.find("unreadable"), std::string::npos);
  const fs::path file =
      fs::temp_directory_path() / ("flamerig_summary_" + std::to_string(::getpid()) + ".json");
  std::ofstream(file.string()) << json;
  EXPECT_EQ(std::system(("/usr/bin/python3 -c \"import json,sys; j=json.load(open(sys.argv[1])); "
                         "assert j['energy'] is None and j['frame'] == 123456789\" " +
                         file.string())
                            .c_str()),
            0);
  fs::remove(file);
  EXPECT_EQ(FrameSummary::FromYaml(f.ToYaml(), "test").notes.size(), 1u);
}

TEST(TruthError, SameGridVoxelByVoxelOtherGridsByTheVoxelHoldingEachCentre) {
  const FireVolume truth = Cube(4, 1500);  // 64 visible voxels of 1 mm
  // The same grid, 20 K too hot: 20 K RMS and bias over every voxel.
  TruthError same = CompareWithTruth(truth, Cube(4, 1520));
  EXPECT_TRUE(same.compared && same.same_grid);
  EXPECT_EQ(same.visible, 64u);
  EXPECT_EQ(same.counted, 64u);
  EXPECT_NEAR(same.rms_k, 20, 1e-9);
  EXPECT_NEAR(same.mean_k, 20, 1e-9);
  // A fit on 2 mm voxels whose voxel c (flat index 0..7) is 1500 + 10 c: each holds 8 truth
  // voxels, so the RMS is sqrt(mean of (10 c)^2) = sqrt(1750) and the bias 35 K.
  FireVolume coarse = Cube(2, 0);
  for (int c = 0; c < 8; ++c) coarse.temperature_k[c] = 1500.0f + 10.0f * c;
  const TruthError other = CompareWithTruth(truth, coarse);
  EXPECT_TRUE(other.compared);
  EXPECT_FALSE(other.same_grid);
  EXPECT_EQ(other.counted, 64u);
  EXPECT_NEAR(other.rms_k, std::sqrt(1750.0), 1e-4);
  EXPECT_NEAR(other.mean_k, 35, 1e-4);
  EXPECT_FALSE(other.have_sigma);
  EXPECT_EQ(other.determined_rms_k, -1);
  // With sigma grids: the fit determines coarse voxels 0..5 (errors 0..50 K, 48 truth voxels)
  // and not 6 and 7 (60 and 70 K, 16 truth voxels). Closed forms: RMS over the determined
  // sqrt(mean of (10 c)^2 for c < 6) = sqrt(5500 / 6), over the rest sqrt((3600 + 4900) / 2).
  coarse.temperature_sigma_k.assign(8, 25.0f);
  coarse.determined.assign(8, 1.0f);
  coarse.determined[6] = coarse.determined[7] = 0.0f;
  const TruthError split = CompareWithTruth(truth, coarse);
  ASSERT_TRUE(split.have_sigma && split.have_determined);
  EXPECT_NEAR(split.determined_share, 0.75, 1e-12);
  EXPECT_NEAR(split.determined_rms_k, std::sqrt(5500.0 / 6), 1e-4);
  EXPECT_NEAR(split.undetermined_rms_k, std::sqrt(8500.0 / 2), 1e-4);
  EXPECT_NEAR(split.within_1_sigma, 3.0 / 8, 1e-12);  // errors 0, 10, 20 K of 25
  // Every voxel determined: no RMS for the rest.
  coarse.determined.assign(8, 1.0f);
  const TruthError all = CompareWithTruth(truth, coarse);
  EXPECT_NEAR(all.determined_rms_k, all.rms_k, 1e-9);
  EXPECT_EQ(all.undetermined_rms_k, -1);
  // A sigma grid without a determined one (a volume from elsewhere): no split, not "none
  // determined".
  coarse.determined.clear();
  const TruthError unsplit = CompareWithTruth(truth, coarse);
  EXPECT_TRUE(unsplit.have_sigma);
  EXPECT_FALSE(unsplit.have_determined);
  EXPECT_EQ(unsplit.determined_rms_k, -1);
  EXPECT_EQ(unsplit.undetermined_rms_k, -1);
  // A fitted box that holds only the lower half (y < 2 mm): the rest is visible, not counted.
  FireVolume half = Cube(2, 1510);
  half.geometry.dims.y() = 1;
  half.temperature_k.resize(4);
  half.density_per_m3.resize(4);
  const TruthError part = CompareWithTruth(truth, half);
  EXPECT_EQ(part.visible, 64u);
  EXPECT_EQ(part.counted, 32u);
  EXPECT_NEAR(part.rms_k, 10, 1e-4);
  // Soot: each cube holds 1e16 particles per m^3 in 64 mm^3 (6.4e8 particles), all visible. The
  // half box holds the lower half of the truth's visible voxels at its own density (here the
  // truth's), so it shows half of the visible soot, while its own total is half of the truth's.
  EXPECT_NEAR(same.truth_visible_soot, 6.4e8, 1e-6 * 6.4e8);
  EXPECT_NEAR(same.fit_visible_soot, 6.4e8, 1e-6 * 6.4e8);
  EXPECT_NEAR(part.fit_visible_soot, 3.2e8, 1e-6 * 3.2e8);
  EXPECT_NEAR(part.fit_soot, 3.2e8, 1e-6 * 3.2e8);
  // A truth voxel too cool for an image (1000 K) and one too faint for it (under 1% of the peak
  // emission) count in the truth's total, not in its visible soot; and the fit's voxels that
  // hold only them are not its visible soot either. Coarse voxel 0 (2 mm, the truth's 0, 1, 4,
  // 5, 16, 17, 20, 21) at 3 times the truth's density: the truth's visible voxels it holds
  // (all but the cool voxel 0 and the faint voxel 1) count 3 times.
  FireVolume cooler = Cube(4, 1500);
  cooler.temperature_k[0] = 1000;
  cooler.emission_rgb.assign(3 * 64, 1.0f);
  cooler.emission_rgb[3 * 1 + 1] = 0.005f;
  FireVolume dense = Cube(2, 1500);
  dense.density_per_m3[0] = 3e16f;
  const TruthError visible = CompareWithTruth(cooler, dense);
  EXPECT_NEAR(visible.truth_soot, 6.4e8, 1e-6 * 6.4e8);
  EXPECT_NEAR(visible.truth_visible_soot, 6.2e8, 1e-6 * 6.2e8);
  EXPECT_EQ(visible.counted, 62u);
  EXPECT_NEAR(visible.fit_visible_soot, (6 * 3 + 56) * 1e7, 1e-6 * 7.4e8);
  EXPECT_NEAR(visible.fit_soot, (3 + 7) * 8e7, 1e-6 * 8e8);
}

// A fit in another rig frame than its truth's (a calibrated rig's): the fit holds the truth's
// temperatures exactly, on a grid turned 90 degrees about the vertical through the cube's middle
// and then shifted by one voxel (1 mm) along x. Moved by that motion, every truth voxel finds its
// own value (index arithmetic is the oracle); scored in one frame, the error is the gauge's.
TEST(TruthError, ATruthInAnotherFrameIsMovedIntoTheFitsBeforeItIsScored) {
  FireVolume truth = Cube(4, 0);
  const GridGeometry& g = truth.geometry;
  for (int k = 0; k < 4; ++k)
    for (int j = 0; j < 4; ++j)
      for (int i = 0; i < 4; ++i) truth.temperature_k[g.Flat(i, j, k)] = 1500 + 10 * i + 3 * k + j;
  // fit_from_truth: p -> R (p - c) + c + (1 mm, 0, 0), R turning x towards -z (z' - 2 = -(x - 2),
  // x' - 2 = z - 2 in mm): the truth voxel (i, j, k) lands in fit voxel (k, j, 3 - i) of a grid
  // whose origin is at x = 1 mm.
  const Eigen::Vector3d c(0.002, 0.002, 0.002), shift(0.001, 0, 0);
  const Eigen::Quaterniond turn(Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitY()));
  const Rigid3 fit_from_truth(turn, c - (turn * c) + shift);
  FireVolume fit = Cube(4, 0);
  fit.geometry.origin_in_rig = shift;
  for (int k = 0; k < 4; ++k)
    for (int j = 0; j < 4; ++j)
      for (int i = 0; i < 4; ++i)
        fit.temperature_k[fit.geometry.Flat(k, j, 3 - i)] = truth.temperature_k[g.Flat(i, j, k)];
  const TruthError moved = CompareWithTruth(truth, fit, fit_from_truth);
  EXPECT_FALSE(moved.same_grid);
  EXPECT_EQ(moved.counted, 64u);
  EXPECT_NEAR(moved.rms_k, 0, 1e-9);
  EXPECT_NEAR(moved.correlation, 1, 1e-9);
  // The truth shown on the fit's grid, moved the same way, is the fit.
  const FireVolume shown = SampleOnGrid(truth, fit.geometry, fit_from_truth);
  EXPECT_EQ(shown.temperature_k, fit.temperature_k);
  // Without the motion: a quarter of the truth falls outside the fitted box, the rest is paired
  // with the wrong voxels.
  const TruthError unmoved = CompareWithTruth(truth, fit);
  EXPECT_EQ(unmoved.counted, 48u);
  EXPECT_GT(unmoved.rms_k, 10);
  // The identity changes nothing: on the same grid, voxel by voxel.
  const TruthError same = CompareWithTruth(truth, truth, Rigid3());
  EXPECT_TRUE(same.same_grid);
  EXPECT_EQ(same.rms_k, 0);
}

// The truth on an axisymmetric fit's rings. Fit voxels of 0.5 mm, a truth of 0.25 mm, the axis
// through the box's middle. The truth is 1400 + 10 jt K (jt its layer) within 0.75 mm of the axis
// and 1800 + 10 jt beyond, so that, in closed form, the rings of radius 0 and 1 (out to 0.75 mm)
// average 1400 + 10 (2 j + 0.5) over the two truth layers of fit layer j, the others 1800 + ...;
// the top truth layer is too cool to be seen (1000 K), so the top fit layer's rings hold its
// lower one alone. Rings no visible truth voxel reaches are NaN with no voxels, and a layer
// without rings counts none.
TEST(TruthOnRings, EachRingAveragesTheVisibleTruthVoxelsAtItsHeightAndRadius) {
  FireVolume truth = Cube(16, 0);
  const GridGeometry& tg = truth.geometry;
  for (int k = 0; k < 16; ++k)
    for (int j = 0; j < 16; ++j)
      for (int i = 0; i < 16; ++i) {
        const Eigen::Vector3d c = tg.VoxelCenter(i, j, k);
        const double rho = std::hypot(c.x() - 0.002, c.z() - 0.002);
        truth.temperature_k[tg.Flat(i, j, k)] =
            j == 15 ? 1000.0f : static_cast<float>((rho < 0.00075 ? 1400 : 1800) + 10 * j);
      }
  const GridGeometry fit = Cube(8, 0).geometry;
  std::vector<RingProfilePoint> profile;
  for (int j = 0; j < 8; ++j)
    for (int r = 0; r <= 7; ++r) {
      RingProfilePoint p;
      p.layer = j;
      p.radius_voxels = r;
      p.axis_x_m = p.axis_z_m = 0.002;
      profile.push_back(p);
    }
  // Layer 3 without a profile (its truth voxels are not counted), a point of a layer outside the
  // grid (it gets none).
  profile.erase(std::remove_if(profile.begin(), profile.end(),
                               [](const RingProfilePoint& p) { return p.layer == 3; }),
                profile.end());
  profile.push_back(profile.back());
  profile.back().layer = 99;
  const std::vector<RingTruth> rings = TruthOnRings(truth, fit, profile);
  ASSERT_EQ(rings.size(), profile.size());
  std::size_t counted = 0;
  for (std::size_t p = 0; p < profile.size(); ++p) {
    const int j = profile[p].layer, r = profile[p].radius_voxels;
    SCOPED_TRACE("layer " + std::to_string(j) + ", ring " + std::to_string(r));
    counted += rings[p].voxels;
    if (r >= 6 || j == 99) {  // the farthest truth voxel is 2.65 mm (5.3 fit voxels) out
      EXPECT_EQ(rings[p].voxels, 0u);
      EXPECT_TRUE(std::isnan(rings[p].temperature_k));
      continue;
    }
    ASSERT_GT(rings[p].voxels, 0u);
    const double base = r <= 1 ? 1400 : 1800;
    const double expected = j == 7 ? base + 10 * 14 : base + 10 * (2 * j + 0.5);
    EXPECT_NEAR(rings[p].temperature_k, expected, 1e-9);
  }
  EXPECT_EQ(counted, 16u * 16 * 13);  // every visible truth voxel but layer 3's, once
  FireVolume bare = Cube(4, 1500);
  bare.density_per_m3.clear();
  EXPECT_THROW(TruthOnRings(bare, fit, profile), InputError);
}

// The truth as a fit's grid or rings could show it (truth.h's LightEquivalentTruth). A truth 2x
// finer than the fit, its emission the thin limit's (density x ThinEmissionTable's, as simulate
// writes it): a fitted voxel whose truth is one temperature shows that temperature and density;
// one whose truth is half at 1500 K and half at 1900 K shows nearly the hot half's colour, and
// the soot that gives its light is short of the truth's (Wien at 600 nm: a particle at 1900 K
// gives 29 times the light of one at 1500 K, so the light's temperature is about 1890 K and its
// soot about 0.6 of the truth's). Pooled over a ring, the ring's voxels share one temperature.
TEST(LightEquivalentTruth, AFittedVoxelOrRingShowsItsTruthsLightAtOneTemperature) {
  FireVolume truth = Cube(8, 1900);
  const GridGeometry fit = Cube(4, 0).geometry;  // 1 mm voxels, each holding 2x2x2 of the truth's
  const GridGeometry& tg = truth.geometry;
  const AbsorptionModel soot = AbsorptionModel::FromName("soot");
  const FitOptions defaults;
  const ThinEmissionTable table(soot, defaults.objective.t_min_k, defaults.objective.t_max_k);
  auto fit_voxel = [](int i, int j, int k) { return Eigen::Vector3i(i / 2, j / 2, k / 2); };
  truth.emission_rgb.resize(3 * tg.num_voxels());
  for (int k = 0; k < 8; ++k)
    for (int j = 0; j < 8; ++j)
      for (int i = 0; i < 8; ++i) {
        const std::size_t v = tg.Flat(i, j, k);
        const Eigen::Vector3i f = fit_voxel(i, j, k);
        if (f.x() == 1 && f.z() == 1) truth.temperature_k[v] = 1500;  // one of each layer's ring 1
        if (f == Eigen::Vector3i(3, 3, 3) && i % 2 == 0) truth.temperature_k[v] = 1500;  // half
        truth.density_per_m3[v] = 1e16f * float(1 + f.y());
        const Eigen::Vector3d e =
            truth.density_per_m3[v] * table.RgbPerDensity(truth.temperature_k[v]);
        for (int c = 0; c < 3; ++c) truth.emission_rgb[3 * v + c] = static_cast<float>(e[c]);
      }
  auto truth_soot_in = [&](const std::function<bool(const Eigen::Vector3i&)>& in) {
    double n = 0;
    for (int k = 0; k < 8; ++k)
      for (int j = 0; j < 8; ++j)
        for (int i = 0; i < 8; ++i)
          if (in(fit_voxel(i, j, k))) n += truth.density_per_m3[tg.Flat(i, j, k)];
    return n / 8;  // a fitted voxel's mean density
  };
  // Voxel by voxel.
  const FireVolume voxels = LightEquivalentTruth(truth, fit, soot);
  ASSERT_TRUE(voxels.geometry.SameVoxels(fit));
  for (int k = 0; k < 4; ++k)
    for (int j = 0; j < 4; ++j)
      for (int i = 0; i < 4; ++i) {
        SCOPED_TRACE(std::to_string(i) + " " + std::to_string(j) + " " + std::to_string(k));
        const std::size_t f = fit.Flat(i, j, k);
        const Eigen::Vector3i at(i, j, k);
        if (at == Eigen::Vector3i(3, 3, 3)) {
          EXPECT_GT(voxels.temperature_k[f], 1850);
          EXPECT_LT(voxels.temperature_k[f], 1900);
          const double ratio =
              voxels.density_per_m3[f] / truth_soot_in([&](const auto& g) { return g == at; });
          EXPECT_GT(ratio, 0.5);
          EXPECT_LT(ratio, 0.65);
          continue;
        }
        EXPECT_NEAR(voxels.temperature_k[f], i == 1 && k == 1 ? 1500 : 1900, 1.0);
        EXPECT_NEAR(voxels.density_per_m3[f], 1e16 * (1 + j), 0.01 * 1e16 * (1 + j));
      }
  // By rings about the grid's centre line (x = z = 2 mm): ring 1 holds the four middle voxels of
  // a layer (0.71 mm out), ring 2 the twelve others. Layer 3 has no ring: its voxels stay apart.
  std::vector<RingProfilePoint> profile;
  for (int j = 0; j < 3; ++j)
    for (int r : {1, 2}) {
      RingProfilePoint p;
      p.layer = j;
      p.radius_voxels = r;
      p.axis_x_m = p.axis_z_m = 0.002;
      profile.push_back(p);
    }
  const FireVolume rings = LightEquivalentTruth(truth, fit, soot, Rigid3(), &profile);
  for (int j = 0; j < 4; ++j) {
    SCOPED_TRACE("layer " + std::to_string(j));
    const float ring1 = rings.temperature_k[fit.Flat(1, j, 1)];
    if (j == 3) {
      EXPECT_EQ(ring1, voxels.temperature_k[fit.Flat(1, j, 1)]);
      EXPECT_EQ(rings.temperature_k[fit.Flat(3, j, 3)], voxels.temperature_k[fit.Flat(3, j, 3)]);
      continue;
    }
    // Three of the four at 1900 K: the light's temperature about 1895 K.
    EXPECT_GT(ring1, 1850);
    EXPECT_LT(ring1, 1900);
    double fitted = 0;
    for (auto [i, k] : {std::pair{1, 1}, {1, 2}, {2, 1}, {2, 2}}) {
      EXPECT_EQ(rings.temperature_k[fit.Flat(i, j, k)], ring1);
      EXPECT_EQ(rings.density_per_m3[fit.Flat(i, j, k)], rings.density_per_m3[fit.Flat(1, j, 1)]);
      fitted += rings.density_per_m3[fit.Flat(i, j, k)];
    }
    const double held = truth_soot_in([&](const Eigen::Vector3i& g) {
      return g.y() == j && (g.x() == 1 || g.x() == 2) && (g.z() == 1 || g.z() == 2);
    });
    // Wien: (1/28 + 3 x 1.03) / 4 = 0.78 of the ring's soot.
    EXPECT_LT(fitted, 0.9 * held);
    EXPECT_GT(fitted, 0.7 * held);
    EXPECT_NEAR(rings.temperature_k[fit.Flat(0, j, 0)], 1900, 1.0);  // ring 2: all at 1900 K
  }
  // A truth in another frame, one fit voxel along x from the fit's: each fitted voxel shows the
  // light of the truth voxels moved into it, the cool column one voxel further along.
  const Rigid3 along_x(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.001, 0, 0));
  const FireVolume moved = LightEquivalentTruth(truth, fit, soot, along_x);
  for (int j = 0; j < 3; ++j) {
    EXPECT_NEAR(moved.temperature_k[fit.Flat(2, j, 1)], 1500, 1.0) << j;
    EXPECT_NEAR(moved.temperature_k[fit.Flat(1, j, 1)], 1900, 1.0) << j;
    EXPECT_EQ(moved.density_per_m3[fit.Flat(0, j, 1)], 0.0f) << j;  // nothing moved into it
  }
  FireVolume dark = truth;
  dark.emission_rgb.clear();
  EXPECT_THROW(LightEquivalentTruth(dark, fit, soot), InputError);
}

// A radial profile written as CSV reads back to the printed digits; a malformed file names its
// line and column.
TEST(RingProfileCsv, ReadsBackWhatItWroteAndNamesWhatIsMalformed) {
  const fs::path dir = TempDir("profile_csv");
  std::vector<RingProfilePoint> profile(3);
  for (int r = 0; r < 3; ++r) {
    RingProfilePoint& p = profile[r];
    p.layer = 7;
    p.height_m = 0.0123456789;
    p.axis_x_m = -0.001;
    p.axis_y_m = -0.0123456789;
    p.axis_z_m = 0.002;
    p.radius_voxels = r;
    p.radius_m = 0.00109375 * r;
    p.voxels = 1 + 6 * r;
    p.temperature_k = 1650.5 + 10 * r;
    p.temperature_sigma_k = 120.25;
    p.density_per_m3 = 3.5e15;
    p.log_density_sigma = 0.75;
    p.soot_volume_fraction = 1.25e-7 * (r + 1);
  }
  std::vector<RingTruth> truth(3);
  truth[1] = {1700, 12};
  const fs::path csv = dir / "profile.csv";
  WriteRingProfileCsv(csv.string(), profile, &truth);
  const std::vector<RingProfilePoint> back = ReadRingProfileCsv(csv.string());
  ASSERT_EQ(back.size(), profile.size());
  for (std::size_t r = 0; r < back.size(); ++r) {
    EXPECT_EQ(back[r].layer, profile[r].layer);
    EXPECT_EQ(back[r].radius_voxels, profile[r].radius_voxels);
    EXPECT_EQ(back[r].voxels, profile[r].voxels);
    EXPECT_NEAR(back[r].height_m, profile[r].height_m, 1e-12);
    EXPECT_NEAR(back[r].axis_x_m, profile[r].axis_x_m, 1e-12);
    EXPECT_NEAR(back[r].axis_y_m, profile[r].axis_y_m, 1e-12);
    EXPECT_NEAR(back[r].radius_m, profile[r].radius_m, 1e-12);
    EXPECT_NEAR(back[r].temperature_k, profile[r].temperature_k, 1e-3);
    EXPECT_NEAR(back[r].temperature_sigma_k, profile[r].temperature_sigma_k, 1e-3);
    EXPECT_NEAR(back[r].density_per_m3, profile[r].density_per_m3, 1e10);
    EXPECT_NEAR(back[r].log_density_sigma, profile[r].log_density_sigma, 1e-6);
    EXPECT_NEAR(back[r].soot_volume_fraction, profile[r].soot_volume_fraction, 1e-12);
  }
  std::ifstream in(csv);
  std::string header, first, second;
  std::getline(in, header);
  std::getline(in, first);
  std::getline(in, second);
  EXPECT_NE(header.find(",truth_temperature_k,truth_voxels"), std::string::npos) << header;
  EXPECT_EQ(first.substr(first.size() - 3), ",,0") << first;  // no truth voxel in ring 0
  EXPECT_EQ(second.substr(second.size() - 8), ",1700,12") << second;
  auto malformed = [&](const std::string& text, const std::string& says) {
    const fs::path bad = dir / "bad.csv";
    std::ofstream(bad) << text;
    try {
      ReadRingProfileCsv(bad.string());
      ADD_FAILURE() << "no error for " << text;
    } catch (const DataError& e) {
      EXPECT_NE(std::string(e.what()).find(says), std::string::npos) << e.what();
    }
  };
  malformed(header + "\n" + first + "\nnot,a,row\n", "line 3: 3 values for 15 columns");
  // A profile written before the volume fraction was (2026-11-29) reads with a fraction of 0,
  // and one from before axis_y_m (2026-12-02), whose height_m was the rig y, with that as both.
  {
    const fs::path old = dir / "old.csv";
    std::ofstream(old) << "layer,height_m,axis_x_m,axis_z_m,radius_voxels,radius_m,voxels,"
                          "temperature_k,temperature_sigma_k,density_per_m3,log_density_sigma\n"
                          "7,0.01,0,0,1,0.001,7,1700,100,3e15,0.5\n";
    const std::vector<RingProfilePoint> read = ReadRingProfileCsv(old.string());
    ASSERT_EQ(read.size(), 1u);
    EXPECT_EQ(read[0].temperature_k, 1700);
    EXPECT_EQ(read[0].soot_volume_fraction, 0);
    EXPECT_EQ(read[0].axis_y_m, 0.01);
    EXPECT_EQ(read[0].height_m, 0.01);
  }
  std::string nan_row = second;
  nan_row.replace(nan_row.find("1660.5"), 6, "nan");
  malformed(header + "\n" + nan_row + "\n", "line 2: temperature_k 'nan' is not a finite number");
  malformed("layer,height_m\n", "line 1: no 'axis_x_m' column");
  EXPECT_THROW(ReadRingProfileCsv((dir / "none.csv").string()), IoError);
  fs::remove_all(dir);
}

// The same voxels as CompareWithTruth, split by the truth's emission over its peak: bands whose
// errors are set by hand (the oracle), one voxel the fit left empty, and voxels too faint or too
// cool to be visible.
TEST(TruthError, ByEmissionSplitsTheScoredVoxelsByTheTruthsBrightness) {
  FireVolume truth = Cube(4, 1500);
  FireVolume fitted = Cube(4, 1500);
  truth.emission_rgb.assign(3 * 64, 0.0f);
  for (int v = 0; v < 64; ++v) {
    // 0..15 at the peak, 16..31 at 0.2, 32..47 at 0.05, 48..55 at 0.02, 56..59 at 0.005 (not
    // visible), 60..63 at 0.2 but 1200 K (not visible).
    const float e = v < 16   ? 1.0f
                    : v < 32 ? 0.2f
                    : v < 48 ? 0.05f
                    : v < 56 ? 0.02f
                    : v < 60 ? 0.005f
                             : 0.2f;
    truth.emission_rgb[3 * v + 1] = e;
    if (v >= 60) truth.temperature_k[v] = 1200;
    const float error = v < 16   ? 10.0f
                        : v < 32 ? -20.0f
                        : v < 48 ? 40.0f
                                 : (v % 2 ? 30.0f : -30.0f);
    fitted.temperature_k[v] = truth.temperature_k[v] + error;
  }
  fitted.density_per_m3[5] = 0;  // no medium in the fit: not counted
  const std::vector<EmissionBandError> bands = TemperatureErrorByEmission(truth, fitted);
  ASSERT_EQ(bands.size(), 4u);
  const std::size_t counted[] = {8, 16, 16, 15};
  const double rms[] = {30, 40, 20, 10}, mean[] = {0, 40, -20, 10};
  const double squares[] = {8 * 900.0, 16 * 1600.0, 16 * 400.0, 15 * 100.0};
  const double total = squares[0] + squares[1] + squares[2] + squares[3];
  const double edges[] = {0.01, 0.03, 0.1, 0.3, 1.0};
  for (int b = 0; b < 4; ++b) {
    SCOPED_TRACE(b);
    EXPECT_EQ(bands[b].lo, edges[b]);
    EXPECT_EQ(bands[b].hi, edges[b + 1]);
    EXPECT_EQ(bands[b].counted, counted[b]);
    EXPECT_NEAR(bands[b].rms_k, rms[b], 1e-3);
    EXPECT_NEAR(bands[b].mean_k, mean[b], 1e-3);
    EXPECT_NEAR(bands[b].share, squares[b] / total, 1e-6);
  }
  // The bands hold exactly the voxels CompareWithTruth scores, and its RMS.
  const TruthError all = CompareWithTruth(truth, fitted);
  EXPECT_EQ(all.counted, 55u);
  EXPECT_NEAR(all.rms_k, std::sqrt(total / 55), 1e-3);
  // Weighted by the truth's emission, band by band (the faintest band's errors cancel): 15
  // voxels at 1, 16 at 0.2, 16 at 0.05 and 8 at 0.02.
  const double weight = 15 + 16 * 0.2 + 16 * 0.05 + 8 * 0.02;
  EXPECT_NEAR(all.weighted_mean_k, (15 * 10.0 - 3.2 * 20 + 0.8 * 40) / weight, 1e-3);
  EXPECT_NEAR(all.weighted_rms_k,
              std::sqrt((15 * 100.0 + 3.2 * 400 + 0.8 * 1600 + 0.16 * 900) / weight), 1e-3);
  // Bands of one's own; a voxel outside them is left out.
  const std::vector<EmissionBandError> upper = TemperatureErrorByEmission(truth, fitted, {0.1, 1});
  ASSERT_EQ(upper.size(), 1u);
  EXPECT_EQ(upper[0].counted, 31u);
  EXPECT_NEAR(upper[0].mean_k, (15 * 10.0 - 16 * 20.0) / 31, 1e-3);
  EXPECT_DOUBLE_EQ(upper[0].share, 1.0);
  // Errors name what is wrong.
  EXPECT_THROW(TemperatureErrorByEmission(truth, fitted, {0.1, 0.1, 1}), InputError);
  EXPECT_THROW(TemperatureErrorByEmission(truth, fitted, {0.5}), InputError);
  FireVolume dark = truth;
  dark.emission_rgb.clear();
  EXPECT_THROW(TemperatureErrorByEmission(dark, fitted), InputError);
}

TEST(RunFrames, SplitsContiguouslyAcrossRanks) {
  for (int size = 1; size <= 5; ++size) {
    std::size_t expect = 3;
    for (int r = 0; r < size; ++r) {
      std::size_t b, e;
      RankFrames(3, 20, r, size, &b, &e);
      EXPECT_EQ(b, expect);
      EXPECT_LE(e - b, 17u / size + 1);
      EXPECT_GE(e - b, 17u / size);
      expect = e;
    }
    EXPECT_EQ(expect, 20u);
  }
  std::size_t b, e;
  EXPECT_THROW(RankFrames(0, 4, 2, 2, &b, &e), InputError);
}

TEST(RunFrames, ChangeDetectionSeesALocalChangeAndIgnoresNoise) {
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0, 1.0);
  ImageU8 a(160, 120, 3, 0);
  for (int y = 40; y < 100; ++y)
    for (int x = 70; x < 90; ++x)
      for (int c = 0; c < 3; ++c) a.at(x, y, c) = static_cast<std::uint8_t>(120 + 40 * c);
  auto noisy = [&](const ImageU8& in) {
    ImageU8 out = in;
    for (auto& p : out.pixels)
      p = static_cast<std::uint8_t>(std::clamp(p + noise(rng), 0.0, 255.0));
    return out;
  };
  const ImageU8 a1 = noisy(a), a2 = noisy(a);
  const ChangeOptions options;
  const ImageChange same = CompareImages(a1, a2, options);
  EXPECT_NEAR(same.noise_dn, std::sqrt(2.0), 0.6);  // two frames' noise of 1 DN each
  EXPECT_LE(same.changed_fraction, options.max_changed_fraction);
  // A lick of flame 4x3 pixels large, 30 levels brighter: a change.
  ImageU8 b = a;
  for (int y = 30; y < 33; ++y)
    for (int x = 75; x < 79; ++x) b.at(x, y, 0) = 30;
  const ImageChange changed = CompareImages(a1, noisy(b), options);
  EXPECT_GT(changed.changed_fraction, options.max_changed_fraction);
  EXPECT_THROW(CompareImages(a, ImageU8(10, 10, 3), options), InputError);
}

TEST(RunFrames, ReconstructorStateResumesBitExactly) {
  const tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
  const fs::path dir = TempDir("state");
  SimulateDataset(dir / "sim", 2);
  const Rig rig = Rig::Load((dir / "sim" / "rig.yaml").string());
  FrameSourceSpec spec;
  spec.images_dir = (dir / "sim" / "frames").string();
  const FrameSource source(spec, rig);
  ReconstructOptions ro;
  ro.resolution = 24;
  ro.cache_dir = (dir / "cache").string();
  const auto f0 = source.Read(0, 1.0), f1 = source.Read(1, 1.0);
  Reconstructor first(rig, ro);
  const FireVolume v0 = first.Reconstruct(f0.linear, nullptr);
  const std::string state = (dir / "after0.state").string();
  first.SaveState(state);
  ReconstructSummary s1;
  const FireVolume v1 = first.Reconstruct(f1.linear, &s1, &v0);
  Reconstructor second(rig, ro);
  second.LoadState(state);
  ReconstructSummary s2;
  const FireVolume w1 = second.Reconstruct(f1.linear, &s2, &v0);
  EXPECT_EQ(s1.matrix_source, "reused (envelope)");
  EXPECT_EQ(s2.matrix_source, "reused (envelope)");  // the loaded envelope, not a fresh one
  EXPECT_TRUE(v1.emission_rgb == w1.emission_rgb);

  // Damaged, or saved for another grid: errors that name the file.
  {
    std::fstream f(state, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(40);
    f.put('\x5a');
  }
  try {
    second.LoadState(state);
    ADD_FAILURE() << "a corrupt state loaded";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(state), std::string::npos) << e.what();
  }
  first.SaveState(state);
  ReconstructOptions other = ro;
  other.resolution = 20;
  Reconstructor third(rig, other);
  try {
    third.LoadState(state);
    ADD_FAILURE() << "a state for another grid loaded";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("another rig, grid or options"), std::string::npos);
  }
  fs::remove_all(dir);
}

// The main promise: every frame reconstructed and fitted, images reproduced and the temperature
// close to the simulator's truth where it can be seen.
TEST(RunFrames, FitsEveryFrameAgainstTheTruth) {
  const fs::path dir = TempDir("e2e");
  SimulateDataset(dir / "sim", 4);
  const RunOptions o = SmallRun(dir / "sim", dir / "out");
  std::size_t calls = 0;
  const FrameSource source(o.source, Rig::Load(o.rig_path));
  const RunSummary run =
      RunFrames(o, o.rig_path, 0, 4, Observe([&](const Progress& p) {
                  if (p.stage != "frames") return;  // the solves', the fits'
                  ++calls;
                  EXPECT_EQ(p.done, static_cast<std::int64_t>(calls));
                  EXPECT_EQ(p.total, 4);
                  EXPECT_NE(p.message.find(FrameName(calls - 1)), std::string::npos);
                }));
  ASSERT_EQ(run.frames.size(), 4u);
  EXPECT_EQ(run.computed, 4u);
  EXPECT_EQ(calls, 4u);
  for (const auto& f : run.frames) {
    SCOPED_TRACE(f.Line());
    EXPECT_EQ(f.status, "computed");
    EXPECT_EQ(f.cameras_used, 3);
    ASSERT_EQ(f.delta_e.size(), 3u);
    // Measured about 1.0 on the fire pixels; a black render scores about 14 there.
    for (const auto& d : f.delta_e) EXPECT_LT(d.fire, 2.0) << d.camera;
    // Measured 110 to 160 K; a uniform random start in 300..2300 K gives about 700 K.
    EXPECT_GE(f.truth_rms_k, 0);
    EXPECT_LT(f.truth_rms_k, 250);
    EXPECT_GT(f.truth_voxels, f.truth_visible / 2);
    EXPECT_EQ(f.truth_frame, static_cast<int>(f.frame));
    EXPECT_TRUE(fs::exists(dir / "out" / (FrameName(f.frame) + ".vdb")));
    EXPECT_TRUE(fs::exists(dir / "out" / "blender" / (FrameName(f.frame) + ".vdb")));
    EXPECT_TRUE(fs::exists(dir / "out" / "tomography" / (FrameName(f.frame) + ".vdb")));
    EXPECT_TRUE(fs::exists(dir / "out" / "frames" / (FrameName(f.frame) + ".png")));
    // The sigma's coverage is that of the written volume's sigma grid against the truth file.
    const TruthError written =
        CompareWithTruth(ReadVdb((fs::path(o.truth_dir) / (FrameName(f.frame) + ".vdb")).string()),
                         ReadVdb((dir / "out" / (FrameName(f.frame) + ".vdb")).string()));
    ASSERT_TRUE(written.have_sigma);
    EXPECT_EQ(f.truth_within_1_sigma, written.within_1_sigma);
    EXPECT_EQ(f.truth_spread_k, written.truth_spread_k);
    EXPECT_GT(f.truth_spread_k, 0);
    EXPECT_EQ(f.truth_weighted_rms_k, written.weighted_rms_k);
    EXPECT_EQ(f.truth_weighted_bias_k, written.weighted_mean_k);
    EXPECT_EQ(f.truth_visible_soot, written.truth_visible_soot);
    EXPECT_EQ(f.visible_soot, written.fit_visible_soot);
    EXPECT_GT(f.truth_visible_soot, 0);
    EXPECT_LT(f.truth_visible_soot, f.truth_soot);
    // The fit's limit: the truth's light on the fitted grid, scored as the fit is. This fit's grid
    // is the truth's (24), so the limit is the truth itself, to the emission table's kelvin
    // (measured: soot within 0.03%, RMS 0.29 K, where the fit's is 110 to 130 K).
    {
      const FireVolume truth =
          ReadVdb((fs::path(o.truth_dir) / (FrameName(f.frame) + ".vdb")).string());
      const FireVolume fitted = ReadVdb((dir / "out" / (FrameName(f.frame) + ".vdb")).string());
      const TruthError limit = CompareWithTruth(
          truth, LightEquivalentTruth(truth, fitted.geometry,
                                      AbsorptionModel::FromName(DatasetAbsorption(o.rig_path))));
      EXPECT_EQ(f.limit_rms_k, limit.rms_k);
      EXPECT_EQ(f.limit_bias_k, limit.mean_k);
      EXPECT_EQ(f.limit_visible_soot, limit.fit_visible_soot);
      EXPECT_NEAR(f.limit_soot, limit.fit_soot, 1e-9 * limit.fit_soot);  // the .vdb's voxel size
      EXPECT_NEAR(f.limit_visible_soot / f.truth_visible_soot, 1.0, 0.002);
      EXPECT_NEAR(f.limit_soot / f.truth_soot, 1.0, 0.002);
      EXPECT_LT(f.limit_rms_k, 1.0);
    }
    EXPECT_GT(f.truth_weighted_rms_k, 0);
    EXPECT_NE(f.Line().find("emission-weighted RMS "), std::string::npos) << f.Line();
    EXPECT_NE(f.Line().find("(a constant: "), std::string::npos) << f.Line();
    EXPECT_EQ(f.truth_within_2_sigma, written.within_2_sigma);
    EXPECT_GE(f.truth_within_2_sigma, f.truth_within_1_sigma);
    EXPECT_GT(f.truth_median_sigma_k, 0);
    EXPECT_NE(f.Line().find("within 1 sigma"), std::string::npos) << f.Line();
    // The determined voxels scored apart: their share and the two RMS make up the whole RMS.
    EXPECT_EQ(f.truth_determined_share, written.determined_share);
    EXPECT_EQ(f.truth_determined_rms_k, written.determined_rms_k);
    const double share = f.truth_determined_share;
    const double det = std::max(0.0, f.truth_determined_rms_k),
                 rest = std::max(0.0, f.truth_undetermined_rms_k);
    EXPECT_NEAR(share * det * det + (1 - share) * rest * rest, f.truth_rms_k * f.truth_rms_k,
                1e-6 * f.truth_rms_k * f.truth_rms_k);
    EXPECT_NE(f.Line().find("% determined"), std::string::npos) << f.Line();
    // The summary on disk is the one returned.
    const auto back = ReadFrameSummaries(o.out_dir, f.frame, f.frame + 1);
    ASSERT_EQ(back.size(), 1u);
    EXPECT_EQ(back[0].ToJson(), f.ToJson());
  }
  // The brief report splits the computed frames' time between tomography and fit (sums of the
  // frames' own times, in seconds with one decimal).
  double tomo_ms = 0, fit_ms = 0;
  for (const auto& f : run.frames) tomo_ms += f.reconstruct_ms, fit_ms += f.fit_ms;
  char split[96];
  std::snprintf(split, sizeof split, "tomography %.1f s, fit %.1f s)", tomo_ms / 1000,
                fit_ms / 1000);
  EXPECT_NE(run.BriefReport().find(split), std::string::npos) << run.BriefReport();
  // The matrix built once, then reused while the fire stays in its envelope.
  EXPECT_EQ(run.frames[0].matrix_source, "built");
  int reused = 0;
  for (const auto& f : run.frames) reused += f.matrix_source == "reused (envelope)";
  EXPECT_GE(reused, 2);
  // The output volume carries its exposure and renders: temperature and density present.
  const FireVolume v = ReadVdb((dir / "out" / "frame_000002.vdb").string());
  EXPECT_GT(v.metadata_numbers.at("exposure"), 0);
  EXPECT_EQ(v.metadata_numbers.at("frame"), 2);
  // Soot: the volume fraction beside the density, each voxel's particles of 20 nm radius.
  ASSERT_EQ(v.metadata_text.at("absorption_model"), "soot");
  ASSERT_EQ(v.soot_volume_fraction.size(), v.geometry.num_voxels());
  const double particle = 4.0 / 3.0 * 3.14159265358979 * 20e-9 * 20e-9 * 20e-9;
  double fraction_sum = 0;
  for (std::size_t i = 0; i < v.geometry.num_voxels(); ++i) {
    ASSERT_NEAR(v.soot_volume_fraction[i], v.density_per_m3[i] * particle,
                1e-6 * v.density_per_m3[i] * particle + 1e-30);
    fraction_sum += v.soot_volume_fraction[i];
  }
  EXPECT_NEAR(v.metadata_numbers.at("soot_volume_m3"),
              fraction_sum * v.geometry.voxel_size_m.prod(),
              1e-4 * v.metadata_numbers.at("soot_volume_m3"));
  EXPECT_GT(fraction_sum, 0);
  // The frame's summary carries that soot volume: the particles it counts times one's volume.
  EXPECT_NEAR(run.frames[2].soot_volume_m3, fraction_sum * v.geometry.voxel_size_m.prod(),
              1e-4 * run.frames[2].soot_volume_m3);
  EXPECT_NEAR(run.frames[2].soot_volume_m3, run.frames[2].soot * particle,
              1e-4 * run.frames[2].soot_volume_m3);

  // The report: a page with its pictures.
  RunReportInfo info;
  info.truth_dir = o.truth_dir;
  const std::string page = WriteRunReport(o.out_dir, run.frames, info);
  std::ifstream in(page);
  const std::string html((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  for (const char* picture : {"errors.png", "timing.png", "contact.png", "slices_000000.png"}) {
    EXPECT_NE(html.find(picture), std::string::npos) << picture;
    EXPECT_FALSE(ReadImageU8((fs::path(page).parent_path() / picture).string()).empty());
  }
  EXPECT_NE(html.find("K RMS"), std::string::npos);
  // The error plot draws the constant's error beside the fit's: per frame the truth's spread.
  {
    std::ifstream dat(fs::path(page).parent_path() / "errors.dat");
    std::string line;
    // And the fit's limit: per frame its RMS.
    std::map<std::size_t, double> spread, limit;
    std::map<std::size_t, double>* block = nullptr;
    while (std::getline(dat, line)) {
      if (line.rfind("# ", 0) == 0) {
        block = line.find("a constant temperature's RMS error") != std::string::npos ? &spread
                : line.find("the fit's limit") != std::string::npos                  ? &limit
                                                                                     : nullptr;
      } else if (block && !line.empty()) {
        std::istringstream xy(line);
        double x = -1, y = -1;
        xy >> x >> y;
        (*block)[std::size_t(x)] = y;
      }
    }
    ASSERT_EQ(spread.size(), run.frames.size());
    ASSERT_EQ(limit.size(), run.frames.size());
    for (const auto& f : run.frames) {
      EXPECT_EQ(spread.at(f.frame), f.truth_spread_k) << f.frame;
      EXPECT_NEAR(limit.at(f.frame), f.limit_rms_k, 1e-6 + 1e-6 * f.limit_rms_k) << f.frame;
    }
    EXPECT_NE(html.find("tells less than a constant"), std::string::npos);
    EXPECT_NE(html.find("The fit's limit is the error"), std::string::npos);
  }
  EXPECT_TRUE(fs::exists(dir / "out" / "frames.csv"));
  // frames.csv, read by Python's csv module: each frame's soot volume in mm^3.
  {
    const auto mm3 = FramesCsvColumn(dir / "out" / "frames.csv", "soot_volume_mm3");
    ASSERT_EQ(mm3.size(), run.frames.size());
    for (const auto& f : run.frames) {
      EXPECT_GT(f.soot_volume_m3, 0) << f.frame;
      EXPECT_NEAR(std::stod(mm3.at(f.frame)), f.soot_volume_m3 * 1e9,
                  1e-5 * f.soot_volume_m3 * 1e9);
    }
  }
  // Every frame's numbers as JSON, read back by Python's json module (an independent reader):
  // the frame, its status, the truth's error and a view's Delta E as the summary holds them.
  for (const auto& f : run.frames) {
    const fs::path json = fs::path(page).parent_path() / (FrameName(f.frame) + ".json");
    ASSERT_TRUE(fs::exists(json)) << json;
    const std::string command =
        "/usr/bin/python3 -c \"import json,sys; j=json.load(open(sys.argv[1])); "
        "print(j['frame'], j['status'].split()[0], '%.17g' % j['truth_rms_k'], "
        "'%.17g' % j['delta_e'][0]['fire'], j['delta_e'][0]['camera'], "
        "'%.17g' % j['soot_volume_m3'])\" " +
        json.string();
    std::unique_ptr<FILE, int (*)(FILE*)> pipe(popen(command.c_str(), "r"), pclose);
    ASSERT_TRUE(pipe);
    char line[512] = {0};
    ASSERT_TRUE(fgets(line, sizeof line, pipe.get())) << command;
    std::istringstream words(line);
    std::size_t frame = 0;
    std::string status, camera;
    double rms = 0, fire = 0, soot_volume = -1;
    words >> frame >> status >> rms >> fire >> camera >> soot_volume;
    EXPECT_EQ(soot_volume, f.soot_volume_m3);
    EXPECT_EQ(frame, f.frame);
    EXPECT_EQ(status, f.status.substr(0, f.status.find(' ')));
    EXPECT_EQ(rms, f.truth_rms_k);
    ASSERT_FALSE(f.delta_e.empty());
    EXPECT_EQ(fire, f.delta_e[0].fire);
    EXPECT_EQ(camera, f.delta_e[0].camera);
  }

  // Nothing left to do: a second call reads what is there.
  const RunSummary again = RunAll(o);
  EXPECT_EQ(again.resumed, 4u);
  EXPECT_EQ(again.computed, 0u);
  fs::remove_all(dir);
}

// An axisymmetric run starts every frame's fit from its own tomography (RunOptions::warm_start):
// on one thread, frame 1 of a warm-started run is frame 1 of a cold one to the bit. The control:
// an untied run's warm start does change frame 1, so the comparison can tell.
TEST(RunFrames, AnAxisymmetricRunStartsEveryFrameFromItsOwnTomography) {
  const tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
  const fs::path dir = TempDir("axisymmetric");
  SimulateDataset(dir / "sim", 2);
  auto second_frame = [&](bool axisymmetric, bool warm_start, const std::string& name,
                          std::size_t first = 0) {
    RunOptions o = SmallRun(dir / "sim", dir / name);
    o.fit.axisymmetric = axisymmetric;
    o.warm_start = warm_start;
    o.first = first;
    o.sigma = o.blender = o.pictures = false;
    const RunSummary run = RunAll(o);
    EXPECT_EQ(run.computed, 2u - first) << name;
    return ReadVdb((dir / name / "frame_000001.vdb").string());
  };
  const FireVolume tied_warm = second_frame(true, true, "tied_warm");
  const FireVolume tied_cold = second_frame(true, false, "tied_cold");
  EXPECT_GT(tied_warm.metadata_numbers.at("axisymmetric_rings"), 0);
  EXPECT_EQ(tied_warm.temperature_k, tied_cold.temperature_k);
  EXPECT_EQ(tied_warm.density_per_m3, tied_cold.density_per_m3);
  const FireVolume free_warm = second_frame(false, true, "free_warm");
  const FireVolume free_cold = second_frame(false, false, "free_cold");
  EXPECT_NE(free_warm.temperature_k, free_cold.temperature_k);
  // A frame started cold is its own images' alone, tomography included: what the same frame gives
  // in a run of its own (whose matrix is built for its hull, where the two-frame run's was built
  // for the first frame's and reused: the sums differ in rounding, not more).
  auto max_difference = [](const std::vector<float>& a, const std::vector<float>& b) {
    double d = a.size() == b.size() ? 0.0 : 1e30;
    for (std::size_t i = 0; i < a.size() && i < b.size(); ++i)
      d = std::max(d, std::abs(double(a[i]) - b[i]));
    return d;
  };
  const FireVolume tied_alone = second_frame(true, true, "tied_alone", 1);
  const FireVolume free_alone = second_frame(false, false, "free_alone", 1);
  EXPECT_LT(max_difference(tied_alone.temperature_k, tied_warm.temperature_k), 1.0);
  EXPECT_LT(max_difference(free_alone.temperature_k, free_cold.temperature_k), 1.0);
  EXPECT_GT(max_difference(free_alone.temperature_k, free_warm.temperature_k), 10.0);
  // Each tied frame's radial profile beside its summary (fit_report.h's WriteRingProfileCsv): a
  // header and a row per ring, with the truth's ring means (the run has a truth), and heights
  // along the rig's up (+y here).
  const fs::path frames = dir / "tied_warm" / "frames";
  ASSERT_TRUE(fs::exists(frames / "frame_000000_profile.csv"));
  std::ifstream csv(frames / "frame_000001_profile.csv");
  ASSERT_TRUE(csv.good());
  double lines = 0;
  std::string csv_header;
  for (std::string line; std::getline(csv, line);) ++lines == 1 ? void(csv_header = line) : void();
  EXPECT_EQ(lines - 1, tied_warm.metadata_numbers.at("axisymmetric_rings"));
  EXPECT_NE(csv_header.find(",truth_temperature_k,truth_voxels"), std::string::npos) << csv_header;
  const std::vector<RingProfilePoint> rings =
      ReadRingProfileCsv((frames / "frame_000001_profile.csv").string());
  ASSERT_FALSE(rings.empty());
  // The tied fit's limit pools the truth's light over its rings: the summary's figures are those
  // of the truth so pooled over the written profile's rings and the fit's voxels with medium,
  // and the rings show less than the voxels do (one temperature for a ring's hot and cool
  // voxels). Its rings are the fit's own (fit.cc's MakeRingTie, which ties each ring's voxels to
  // one value): the fit's voxels that share a temperature and density share the limit's.
  {
    const FrameSummary tied = ReadFrameSummaries((dir / "tied_warm").string(), 1, 2).at(0);
    const FireVolume truth = ReadVdb((dir / "sim" / "truth" / "frame_000001.vdb").string());
    const AbsorptionModel soot = AbsorptionModel::FromName("soot");
    const FireVolume limit = LightEquivalentTruth(truth, tied_warm.geometry, soot, Rigid3(), &rings,
                                                  &tied_warm.density_per_m3);
    std::map<std::pair<float, float>, std::pair<float, float>> ring_of_fit;
    std::size_t members = 0;
    for (std::size_t f = 0; f < tied_warm.geometry.num_voxels(); ++f) {
      if (!(tied_warm.density_per_m3[f] > 0)) continue;
      const std::pair<float, float> shown{limit.temperature_k[f], limit.density_per_m3[f]};
      const auto [it, added] = ring_of_fit.emplace(
          std::make_pair(tied_warm.temperature_k[f], tied_warm.density_per_m3[f]), shown);
      if (!added) {
        ++members;
        EXPECT_EQ(it->second, shown) << "voxel " << f;
      }
    }
    EXPECT_GT(members, ring_of_fit.size());  // rings of more than one voxel
    const TruthError on_rings = CompareWithTruth(truth, limit);
    const TruthError on_voxels =
        CompareWithTruth(truth, LightEquivalentTruth(truth, tied_warm.geometry, soot));
    EXPECT_EQ(tied.limit_rms_k, on_rings.rms_k);
    EXPECT_EQ(tied.limit_visible_soot, on_rings.fit_visible_soot);
    EXPECT_LT(on_rings.fit_visible_soot, on_voxels.fit_visible_soot);
    EXPECT_GT(on_rings.rms_k, on_voxels.rms_k);
  }
  for (const auto& p : rings) EXPECT_EQ(p.height_m, p.axis_y_m);
  // The same rig said to be up -y (as one calibrated in its first camera's frame): the same
  // rings, their heights now -y, growing up the flame.
  {
    Rig down = Rig::Load((dir / "sim" / "rig.yaml").string());
    down.up_in_rig = -Eigen::Vector3d::UnitY();
    down.Save((dir / "sim" / "rig_down.yaml").string());
    RunOptions o = SmallRun(dir / "sim", dir / "tied_down");
    o.rig_path = (dir / "sim" / "rig_down.yaml").string();
    o.fit.axisymmetric = true;
    o.first = 1;
    o.sigma = o.blender = o.pictures = false;
    ASSERT_EQ(RunAll(o).computed, 1u);
    auto profile_of = [&](const std::string& run) {
      return ReadRingProfileCsv((dir / run / "frames" / "frame_000001_profile.csv").string());
    };
    const std::vector<RingProfilePoint> up = profile_of("tied_alone"),
                                        flipped = profile_of("tied_down");
    ASSERT_EQ(flipped.size(), up.size());
    for (std::size_t k = 0; k < up.size(); ++k) {
      EXPECT_EQ(flipped[k].layer, up[k].layer);
      EXPECT_EQ(flipped[k].temperature_k, up[k].temperature_k);
      EXPECT_EQ(flipped[k].axis_y_m, up[k].axis_y_m);
      EXPECT_EQ(up[k].height_m, up[k].axis_y_m);
      EXPECT_EQ(flipped[k].height_m, -up[k].axis_y_m);
    }
    EXPECT_GT(flipped.front().height_m, flipped.back().height_m);
  }
  EXPECT_FALSE(fs::exists(dir / "free_warm" / "frames" / "frame_000001_profile.csv"));
  // The run's report draws them, the truth beside them.
  RunReportInfo info;
  info.truth_dir = (dir / "sim" / "truth").string();
  const std::string page = WriteRunReport(
      (dir / "tied_warm").string(), ReadFrameSummaries((dir / "tied_warm").string(), 0, 2), info);
  std::ifstream in(page);
  const std::string html((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_NE(html.find("Radial profiles"), std::string::npos);
  for (const char* picture : {"profile_000000.png", "profile_000001.png"}) {
    EXPECT_NE(html.find(picture), std::string::npos) << picture;
    EXPECT_FALSE(ReadImageU8((fs::path(page).parent_path() / picture).string()).empty());
  }
  const std::string dat = [&] {
    std::ifstream d(fs::path(page).parent_path() / "profile_000001.dat");
    return std::string((std::istreambuf_iterator<char>(d)), std::istreambuf_iterator<char>());
  }();
  EXPECT_NE(dat.find("# truth at"), std::string::npos);
  fs::remove_all(dir);
}

// The exposure (issue 19): a known one (the dataset's) is held on every frame; an unknown one is
// fitted on the take's first frame and held after it, across a resume too; --fit-exposure fits a
// free one per frame (the paper's). Oracles: the dataset's exposure, and frame 0's own.
TEST(RunFrames, AKnownExposureIsHeldAndAnUnknownOneIsFittedOncePerTake) {
  const fs::path dir = TempDir("exposure");
  SimulateDataset(dir / "sim", 3);
  RunOptions o = SmallRun(dir / "sim", dir / "known");
  const ImagesExposure dataset = ResolveExposure(0, o.rig_path);
  ASSERT_TRUE(dataset.known);
  EXPECT_EQ(dataset.from, (dir / "sim" / "dataset.yaml").string());
  // A rig from elsewhere (calibrate-radiometry's output folder) filming the dataset's images: the
  // dataset the images belong to says, as DATASET/frames (run) or one frame set's folder (fit).
  for (const fs::path& images : {dir / "sim" / "frames", dir / "sim" / "frames" / "frame_000000"}) {
    const ImagesExposure e = ResolveExposure(0, (dir / "cal" / "rig.yaml").string(), images);
    EXPECT_TRUE(e.known) << images;
    EXPECT_EQ(e.value, dataset.value) << images;
    EXPECT_EQ(fs::path(e.from), fs::weakly_canonical(dir / "sim" / "dataset.yaml")) << images;
  }
  EXPECT_FALSE(ResolveExposure(0, (dir / "cal" / "rig.yaml").string(), dir / "sim").known);
  EXPECT_FALSE(ResolveExposure(0, (dir / "cal" / "rig.yaml").string()).known);
  EXPECT_EQ(ResolveExposure(2.5, o.rig_path).from, "--exposure");
  for (const auto& f : RunAll(o).frames) {
    SCOPED_TRACE(f.Line());
    EXPECT_EQ(f.exposure_from, "known");
    EXPECT_NEAR(f.exposure, dataset.value, 1e-8 * dataset.value);
    EXPECT_GT(f.soot, 0);
    EXPECT_GT(f.truth_soot, 0);
    const FireVolume v = ReadVdb((dir / "known" / (FrameName(f.frame) + ".vdb")).string());
    EXPECT_DOUBLE_EQ(v.metadata_numbers.at("exposure"), dataset.value);
  }
  // A given exposure outside the fit's range is refused before any work.
  RunOptions far = o;
  far.out_dir = (dir / "far").string();
  far.exposure = 1e6;
  EXPECT_THROW(RunAll(far), InputError);

  // The dataset without its exposure (nor the unit that gives it a time: a unit alone is refused,
  // naming the file): unknown.
  {
    const fs::path yaml = dir / "sim" / "dataset.yaml";
    YAML::Node root = YAML::LoadFile(yaml.string());
    root["dataset"].remove("exposure");
    std::ofstream(yaml) << root;
    try {
      ResolveExposure(0, o.rig_path);
      ADD_FAILURE() << "an exposure unit without the exposure it is the time of";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(yaml.string() + ": dataset.exposure is missing"),
                std::string::npos)
          << e.what();
    }
    root["dataset"].remove("exposure_unit_us");
    std::ofstream(yaml) << root;
  }
  ASSERT_FALSE(ResolveExposure(0, o.rig_path).known);
  o.out_dir = (dir / "unknown").string();
  o.count = 2;  // two frames, then the third after a resume
  RunAll(o);
  o.count = 3;
  const RunSummary unknown = RunAll(o);
  ASSERT_EQ(unknown.frames.size(), 3u);
  EXPECT_EQ(unknown.computed, 1u);
  const std::vector<std::string> from = {"fitted", "held from frame 0", "held from frame 0"};
  for (const auto& f : unknown.frames) {
    SCOPED_TRACE(f.Line());
    EXPECT_EQ(f.status, "computed");
    EXPECT_EQ(f.exposure_from, from[f.frame]);
    EXPECT_NEAR(f.exposure, unknown.frames[0].exposure, 1e-8 * unknown.frames[0].exposure);
  }
  // Free per frame: each frame's own.
  o.out_dir = (dir / "free").string();
  o.fit_exposure = true;
  const RunSummary free = RunAll(o);
  for (const auto& f : free.frames) EXPECT_EQ(f.exposure_from, "fitted (free)") << f.Line();
  EXPECT_NE(free.frames[1].exposure, free.frames[0].exposure);
  fs::remove_all(dir);
}

// A two-colour rig through `run` (issue 19, item 6): four mono cameras, pairs a few degrees apart
// behind 650 and 550 nm filters; every frame (the second warm-started) reconstructs each band on
// its own and starts the fit from their ratio, said in the frame's notes, and its temperature is
// measured: scored against the simulator's truth, where without the bands a mono rig's start is
// the middle of the search range and its bias some -350 K (pipeline_camera_model_test).
TEST(RunFrames, ATwoColourRigStartsEveryFrameFromItsBands) {
  const fs::path dir = TempDir("two_colour");
  CameraRadiometry mono;
  mono.transfer = TransferFunction::kLinear;
  mono.bit_depth = 12;
  mono.black_level = 64;
  mono.spectral.kind = SpectralSensitivity::Kind::kBands;
  mono.spectral.bands = {{600, 250}};
  SimulateConfig c;
  c.frames = 2;
  c.grid_resolution = 32;
  c.ring.cameras = 4;
  c.ring.azimuths_deg = {0, 6, 90, 96};
  c.ring.width = 120;
  c.ring.height = 90;
  c.calibration = false;
  c.radiometry = mono;
  c.camera_filters = {SpectralBand{650, 40}, SpectralBand{550, 40}, SpectralBand{650, 40},
                      SpectralBand{550, 40}};
  Simulate(c, (dir / "sim").string());
  RunOptions o = SmallRun(dir / "sim", dir / "out");
  const RunSummary run = RunAll(o);
  ASSERT_EQ(run.frames.size(), 2u);
  for (const auto& f : run.frames) {
    SCOPED_TRACE(f.Line());
    EXPECT_EQ(f.status, "computed");
    bool said = false;
    for (const auto& n : f.notes) said = said || n.find("two-colour start from 2 bands") == 0;
    EXPECT_TRUE(said);
    // The fit used the bands (the warm-started frame for its new voxels).
    const FireVolume v = ReadVdb((dir / "out" / (FrameName(f.frame) + ".vdb")).string());
    EXPECT_NE(v.metadata_text.at("method").find("two-colour start from 2 bands"), std::string::npos)
        << v.metadata_text.at("method");
    std::printf("frame %zu: temperature bias %.1f K, RMS %.1f K\n", f.frame, f.truth_bias_k,
                f.truth_rms_k);
    EXPECT_LT(std::abs(f.truth_bias_k), 150.0);
    EXPECT_LT(f.truth_rms_k, 250.0);  // without the bands 436 and 428 K
  }
  fs::remove_all(dir);
}

// run --stop-camera: the tomography leaves the camera out and stops on it (said in the frame's
// notes), the fit still uses it; a stop camera that is the held-out one or not in the rig is an
// error before any work.
TEST(RunFrames, AStopCameraStopsTheTomographyAndTheFitStillUsesIt) {
  const fs::path dir = TempDir("stop");
  SimulateDataset(dir / "sim", 1);
  RunOptions o = SmallRun(dir / "sim", dir / "out");
  const std::string stop = Rig::Load(o.rig_path).cameras[1].name;
  o.reconstruct.stop_camera = stop;
  const RunSummary run = RunAll(o);
  ASSERT_EQ(run.frames.size(), 1u);
  const FrameSummary& f = run.frames[0];
  EXPECT_EQ(f.status, "computed") << f.Line();
  bool fitted = false;  // the stop camera is one of the fit's views, not held out
  for (const ViewDeltaE& d : f.delta_e) fitted = fitted || (d.camera == stop && !d.held_out);
  EXPECT_TRUE(fitted) << f.Line();
  bool said = false;
  for (const std::string& n : f.notes) said = said || n.find("tomography stopped on " + stop) == 0;
  EXPECT_TRUE(said) << f.Line();
  RunOptions both = o;
  both.out_dir = (dir / "both").string();
  both.holdout_camera = stop;
  EXPECT_THROW(RunAll(both), InputError);
  RunOptions unknown = o;
  unknown.out_dir = (dir / "unknown").string();
  unknown.reconstruct.stop_camera = "nobody";
  try {
    RunAll(unknown);
    ADD_FAILURE() << "an unknown stop camera was taken";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("'nobody'"), std::string::npos) << e.what();
  }
  fs::remove_all(dir);
}

// A frame whose images did not change beyond noise reuses the previous result.
TEST(RunFrames, UnchangedFramesReuseThePreviousResult) {
  const fs::path dir = TempDir("unchanged");
  SimulateDataset(dir / "sim", 3);
  // Frame 2 becomes frame 1 again, with new sensor noise.
  const fs::path frames = dir / "sim" / "frames";
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0, 0.5);
  for (const auto& e : fs::directory_iterator(frames / "frame_000001")) {
    ImageU8 image = ReadImageU8(e.path().string(), 3);
    for (auto& p : image.pixels)
      p = static_cast<std::uint8_t>(std::clamp(std::lround(p + noise(rng)), 0L, 255L));
    WritePng((frames / "frame_000002" / e.path().filename()).string(), image);
  }
  const RunOptions o = SmallRun(dir / "sim", dir / "out");
  const RunSummary run = RunAll(o);
  ASSERT_EQ(run.frames.size(), 3u);
  EXPECT_EQ(run.frames[1].status, "computed");
  EXPECT_EQ(run.frames[2].status, "unchanged (reused frame 1)") << run.frames[2].Line();
  EXPECT_EQ(run.unchanged, 1u);
  EXPECT_EQ(run.frames[2].fit_ms, 0);
  ExpectSameVolume(dir / "out" / "frame_000001.vdb", dir / "out" / "frame_000002.vdb");
  // Its own frame number and set id, and where it came from (a byte copy said frame 1).
  const FireVolume second = ReadVdb((dir / "out" / "frame_000001.vdb").string());
  const FireVolume third = ReadVdb((dir / "out" / "frame_000002.vdb").string());
  EXPECT_EQ(third.metadata_numbers.at("frame"), 2);
  EXPECT_EQ(third.metadata_numbers.at("reused_from_frame"), 1);
  EXPECT_NE(third.metadata_numbers.at("source_frame_id"),
            second.metadata_numbers.at("source_frame_id"));
  // With the skip off, it is computed.
  RunOptions all = o;
  all.out_dir = (dir / "out2").string();
  all.skip_unchanged = false;
  EXPECT_EQ(RunAll(all).frames[2].status, "computed");
  // An axisymmetric run reuses the frame's radial profile too; an untied one has none.
  RunOptions tied = o;
  tied.out_dir = (dir / "tied").string();
  tied.fit.axisymmetric = true;
  EXPECT_EQ(RunAll(tied).frames[2].status, "unchanged (reused frame 1)");
  auto text = [](const fs::path& path) {
    std::ifstream in(path);
    return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  };
  const std::string profile = text(dir / "tied" / "frames" / "frame_000001_profile.csv");
  EXPECT_NE(profile.find("radius_m"), std::string::npos) << profile;
  // The fit's columns are frame 1's; the truth's, each frame's own (its truth frame differs).
  auto fitted_columns = [&](const fs::path& path) {
    std::istringstream in(text(path));
    std::string out;
    for (std::string line; std::getline(in, line);) {
      for (int k = 0; k < 2; ++k) line.erase(line.rfind(','));
      out += line + "\n";
    }
    return out;
  };
  EXPECT_EQ(fitted_columns(dir / "tied" / "frames" / "frame_000002_profile.csv"),
            fitted_columns(dir / "tied" / "frames" / "frame_000001_profile.csv"));
  EXPECT_NE(profile.find(",truth_temperature_k,truth_voxels"), std::string::npos);
  EXPECT_FALSE(fs::exists(dir / "out" / "frames" / "frame_000002_profile.csv"));
  // Under a temperature bound below the candle's (about 2000 K), voxels are held at it: each
  // summary counts them as its .vdb does, the report's frames.csv (read by Python's csv module)
  // says so, and the reused frame copies the count of the frame it reuses from its state file.
  RunOptions capped = o;
  capped.out_dir = (dir / "capped").string();
  capped.fit.objective.t_max_k = 1600;
  const RunSummary held = RunAll(capped);
  ASSERT_EQ(held.frames.size(), 3u);
  EXPECT_EQ(held.frames[2].status, "unchanged (reused frame 1)");
  const std::size_t at_bound = held.frames[1].voxels_at_temperature_bound;
  EXPECT_GT(at_bound, 0u);
  EXPECT_EQ(ReadVdb((dir / "capped" / "frame_000001.vdb").string())
                .metadata_numbers.at("voxels_at_temperature_bound"),
            double(at_bound));
  EXPECT_EQ(held.frames[2].voxels_at_temperature_bound, at_bound);  // read from frame 1's state
  WriteRunReport(capped.out_dir, held.frames, RunReportInfo());
  const auto column = FramesCsvColumn(dir / "capped" / "frames.csv", "voxels_at_temperature_bound");
  ASSERT_EQ(column.size(), held.frames.size());
  for (const FrameSummary& f : held.frames)
    EXPECT_EQ(column.at(f.frame), std::to_string(f.voxels_at_temperature_bound)) << f.frame;
  fs::remove_all(dir);
}

// A damaged frame fails alone, whatever the source: a corrupt PNG in the middle of a folder, and
// a StreamPix sequence that a crash cut short inside its last frame. The frames around it are
// computed, the failed one names the file, and the one after it starts cold.
TEST(RunFrames, ADamagedFrameFailsAloneWhateverTheSource) {
  const fs::path dir = TempDir("damaged");
  SimulateDataset(dir / "sim", 3);
  const Rig rig = Rig::Load((dir / "sim" / "rig.yaml").string());
  // StreamPix sequences of the same frames, one per camera, before the PNG is damaged.
  std::vector<std::string> seqs;
  for (const auto& c : rig.cameras) {
    std::vector<ImageU8> frames;
    for (int f = 0; f < 3; ++f)
      frames.push_back(
          ReadImageU8((dir / "sim" / "frames" / FrameName(f) / (c.name + ".png")).string(), 3));
    seqs.push_back((dir / (c.name + ".seq")).string());
    WriteStreamPix(seqs.back(), frames);
  }
  const fs::path bad_png = dir / "sim" / "frames" / "frame_000001" / (rig.cameras[1].name + ".png");
  std::ofstream(bad_png, std::ios::binary | std::ios::trunc) << "\x89PNG\r\n\x1a\n not an image";
  {
    SCOPED_TRACE("PNG folder");
    const RunSummary run = RunAll(SmallRun(dir / "sim", dir / "out_png"));
    ASSERT_EQ(run.frames.size(), 3u);
    EXPECT_EQ(run.frames[0].status, "computed");
    EXPECT_EQ(run.frames[1].status.rfind("failed: ", 0), 0u) << run.frames[1].status;
    EXPECT_NE(run.frames[1].status.find(bad_png.string()), std::string::npos)
        << run.frames[1].status;
    EXPECT_EQ(run.frames[2].status, "computed");
    EXPECT_EQ(run.failed, 1u);
    EXPECT_EQ(run.computed, 2u);
    EXPECT_FALSE(fs::exists(dir / "out_png" / "frame_000001.vdb"));
  }
  {
    SCOPED_TRACE("StreamPix");
    fs::resize_file(seqs[2], fs::file_size(seqs[2]) - 1000);  // inside frame 2 of camera 2
    RunOptions o = SmallRun(dir / "sim", dir / "out_seq");
    o.source.images_dir.clear();
    o.source.seq_files = seqs;
    const RunSummary run = RunAll(o);
    ASSERT_EQ(run.frames.size(), 3u);
    EXPECT_EQ(run.frames[0].status, "computed");
    EXPECT_EQ(run.frames[1].status, "computed");
    EXPECT_EQ(run.frames[2].status.rfind("failed: ", 0), 0u) << run.frames[2].status;
    EXPECT_NE(run.frames[2].status.find("cut short"), std::string::npos) << run.frames[2].status;
    EXPECT_EQ(run.failed, 1u);
  }
  fs::remove_all(dir);
}

// A take filmed before ignition or after the flame is out: frame sets that hold no fire are not
// failures. Frame 1's cameras see only sensor noise, frame 2's fire is seen by one camera of three
// (the hull needs two); each is written as an empty volume (no soot, ambient temperature, the
// take's exposure, metadata no_fire) with its Blender frame, so the sequence has no gap, and the
// run succeeds. The frame after them starts cold: its volume is a cold run's, bit for bit. A rig
// whose box lies beside the fire, which the cameras see, is still a failed frame, and says why.
TEST(RunFrames, FramesWithoutFireAreEmptyVolumesNotFailures) {
  const fs::path dir = TempDir("no_fire");
  SimulateDataset(dir / "sim", 4);
  const Rig rig = Rig::Load((dir / "sim" / "rig.yaml").string());
  const fs::path frames = dir / "sim" / "frames";
  for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
    const std::string png = rig.cameras[c].name + ".png";
    ImageU8 dark = ReadImageU8((frames / "frame_000001" / png).string(), 3);
    std::fill(dark.pixels.begin(), dark.pixels.end(), 0);
    AddSensorNoise(&dark, 1.5, 11 + c);
    WritePng((frames / "frame_000001" / png).string(), dark);
    if (c > 0) WritePng((frames / "frame_000002" / png).string(), dark);
  }
  const RunOptions o = SmallRun(dir / "sim", dir / "out");
  const RunSummary run = RunAll(o);
  ASSERT_EQ(run.frames.size(), 4u);
  EXPECT_EQ(run.failed, 0u);
  EXPECT_EQ(run.no_fire, 2u);
  EXPECT_EQ(run.computed, 2u);
  EXPECT_NE(run.BriefReport().find("2 without fire"), std::string::npos) << run.BriefReport();
  EXPECT_EQ(run.frames[0].status, "computed");
  EXPECT_EQ(run.frames[3].status, "computed");
  for (int f : {1, 2}) {
    SCOPED_TRACE(f);
    const FrameSummary& s = run.frames[f];
    EXPECT_EQ(s.status, "no fire") << s.Line();
    EXPECT_EQ(s.active_voxels, 0u);
    EXPECT_EQ(s.soot, 0);
    EXPECT_TRUE(s.delta_e.empty());
    EXPECT_EQ(s.truth_rms_k, -1);  // not scored
    const FireVolume v = ReadVdb((dir / "out" / (FrameName(f) + ".vdb")).string());
    EXPECT_EQ(v.metadata_numbers.at("no_fire"), 1);
    EXPECT_EQ(v.metadata_numbers.at("exposure"), run.frames[0].exposure);
    EXPECT_EQ(v.geometry.num_voxels(), std::size_t(v.density_per_m3.size()));
    EXPECT_TRUE(std::all_of(v.density_per_m3.begin(), v.density_per_m3.end(),
                            [](float n) { return n == 0; }));
    EXPECT_TRUE(std::all_of(v.temperature_k.begin(), v.temperature_k.end(),
                            [&](float t) { return t == float(o.fit.objective.t_min_k); }));
    // Blender's frame says so too (its metadata, as the fitted volume's).
    openvdb::initialize();
    openvdb::io::File blender((dir / "out" / "blender" / (FrameName(f) + ".vdb")).string());
    blender.open();
    EXPECT_EQ(blender.getMetadata()->metaValue<double>("no_fire"), 1.0);
    blender.close();
    EXPECT_TRUE(fs::exists(dir / "out" / "frames" / (FrameName(f) + ".png")));
  }
  const std::string none = run.frames[1].Line(), one = run.frames[2].Line();
  EXPECT_NE(none.find("no camera sees fire"), std::string::npos) << none;
  // `flamerig fit` of the dark set alone: an error naming the folder that says nothing was
  // written, and nothing is.
  FitJob dark;
  dark.rig_path = o.rig_path;
  dark.images_dir = (frames / "frame_000001").string();
  dark.out_path = (dir / "dark_fit.vdb").string();
  dark.resolution = 24;
  try {
    RunFitJob(dark);
    ADD_FAILURE() << "fit of a set without fire did not fail";
  } catch (const DataError& e) {
    EXPECT_NE(std::string(e.what()).find(dark.images_dir + ": no fire to fit, nothing written to " +
                                         dark.out_path),
              std::string::npos)
        << e.what();
  }
  EXPECT_FALSE(fs::exists(dark.out_path));
  EXPECT_NE(one.find("only " + rig.cameras[0].name + " ("), std::string::npos) << one;
  // The frame after them as a run that starts every frame cold computes it (one thread each, so
  // that the sums' order is the same).
  RunOptions cold = o;
  cold.out_dir = (dir / "cold").string();
  cold.warm_start = false;
  RunOptions warm = o;
  warm.out_dir = (dir / "warm").string();
  {
    const tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
    EXPECT_EQ(RunAll(cold).no_fire, 2u);
    EXPECT_EQ(RunAll(warm).no_fire, 2u);
  }
  ExpectSameVolume(dir / "warm" / "frame_000003.vdb", dir / "cold" / "frame_000003.vdb");
  // A run stopped after the set without fire and started again computes the same frame 3.
  RunOptions split = o;
  split.out_dir = (dir / "split").string();
  {
    const tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
    split.count = 2;
    EXPECT_EQ(RunAll(split).no_fire, 1u);
    split.count = o.count;
    const RunSummary rest = RunAll(split);
    EXPECT_EQ(rest.resumed, 2u);
    EXPECT_EQ(rest.no_fire, 2u);  // the resumed one counted too
  }
  ExpectSameVolume(dir / "warm" / "frame_000003.vdb", dir / "split" / "frame_000003.vdb");
  // A second run into the same folder finds every frame done.
  const RunSummary again = RunAll(o);
  EXPECT_EQ(again.resumed, 4u);
  EXPECT_EQ(again.failed, 0u);
  // The box moved beside the fire: the cameras see fire that no voxel of the box holds.
  std::string text;
  {
    std::ifstream in(dir / "sim" / "rig.yaml");
    text.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  YAML::Node moved = YAML::Load(text);
  YAML::Node box = moved["rig"]["box"];
  ASSERT_TRUE(box.IsDefined()) << text;
  const double width = box["max"][0].as<double>() - box["min"][0].as<double>();
  box["min"][0] = box["min"][0].as<double>() + 2 * width;
  box["max"][0] = box["max"][0].as<double>() + 2 * width;
  {
    YAML::Emitter e;
    e << moved;
    std::ofstream(dir / "sim" / "beside.yaml") << e.c_str();
  }
  RunOptions beside = o;
  beside.rig_path = (dir / "sim" / "beside.yaml").string();
  beside.out_dir = (dir / "beside").string();
  beside.count = 1;
  const RunSummary wrong = RunAll(beside);
  ASSERT_EQ(wrong.frames.size(), 1u);
  EXPECT_EQ(wrong.failed, 1u);
  EXPECT_NE(wrong.frames[0].status.find("do not meet inside the box"), std::string::npos)
      << wrong.frames[0].status;
  fs::remove_all(dir);
}

// A truth volume that cannot be read is a note on a frame whose output is written, not a failed
// frame (a failed frame would start the next one cold and never be computed again).
// A run through another calibration of the simulated cameras: the same cameras and box in a frame
// moved by a few millimetres (a calibration's gauge; translation only, so that the fit's grid
// moves with the box and the fit is the same). Scored with the truth's rig given, the truth is
// moved into the run's frame and the error is the unmoved run's; without it, the gauge counts.
TEST(RunFrames, ATruthFromAnotherRigFrameIsMovedIntoTheRunsFrame) {
  const fs::path dir = TempDir("truth_rig");
  const fs::path sim = SimulateDataset(dir / "sim", 1);
  Rig moved = Rig::Load((sim / "rig.yaml").string());
  const Rigid3 moved_from_sim(Eigen::Quaterniond::Identity(),
                              Eigen::Vector3d(0.002, -0.001, 0.0015));
  for (RigCamera& c : moved.cameras)
    c.model.set_cam_from_rig(c.model.cam_from_rig() * moved_from_sim.Inverse());
  moved.box.min_in_rig = moved_from_sim * moved.box.min_in_rig;
  moved.box.max_in_rig = moved_from_sim * moved.box.max_in_rig;
  fs::create_directories(dir / "moved");
  moved.Save((dir / "moved" / "rig.yaml").string());
  fs::copy_file(sim / "dataset.yaml", dir / "moved" / "dataset.yaml");  // the exposure

  const RunSummary same = RunAll(SmallRun(sim, dir / "same"));
  RunOptions o = SmallRun(sim, dir / "registered");
  o.rig_path = (dir / "moved" / "rig.yaml").string();
  o.truth_rig = (sim / "rig.yaml").string();
  const RunSummary registered = RunAll(o);
  o.out_dir = (dir / "gauge").string();
  o.truth_rig.clear();
  const RunSummary gauge = RunAll(o);
  ASSERT_EQ(same.frames.size(), 1u);
  ASSERT_EQ(registered.frames.size(), 1u);
  ASSERT_EQ(gauge.frames.size(), 1u);
  const FrameSummary &a = same.frames[0], &b = registered.frames[0], &c = gauge.frames[0];
  // Measured: 80.593 K against 80.592 K over the same 272 voxels; 151.6 K over 182 unmoved.
  EXPECT_EQ(b.truth_voxels, a.truth_voxels);
  EXPECT_NEAR(b.truth_rms_k, a.truth_rms_k, 0.5);
  EXPECT_NEAR(b.truth_bias_k, a.truth_bias_k, 0.5);
  EXPECT_GT(c.truth_rms_k, a.truth_rms_k + 30);
  // A truth rig without a truth, or one that is not a rig of these cameras, is an input error
  // before any frame is read.
  o.truth_dir.clear();
  o.truth_rig = (sim / "rig.yaml").string();
  EXPECT_THROW(o.Validate(), InputError);
  // A rig and a calibration to make one: which would be used is not the caller's to guess.
  o = SmallRun(sim, dir / "both");
  o.calibration.images_dir = (sim / "calibration").string();
  try {
    o.Validate();
    ADD_FAILURE() << "a rig and a calibration were both accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("not both"), std::string::npos) << e.what();
  }
  o = SmallRun(sim, dir / "other");
  Rig other = Rig::Load((sim / "rig.yaml").string());
  other.cameras[0].name = "front";
  fs::create_directories(dir / "other_rig");
  other.Save((dir / "other_rig" / "rig.yaml").string());
  o.truth_rig = (dir / "other_rig" / "rig.yaml").string();
  try {
    RunAll(o);
    ADD_FAILURE() << "a truth rig of other cameras was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("other_rig"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("'front'"), std::string::npos) << e.what();
  }
  fs::remove_all(dir);
}

TEST(RunFrames, AnUnreadableTruthIsANoteNotAFailedFrame) {
  const fs::path dir = TempDir("truth");
  SimulateDataset(dir / "sim", 2);
  std::ofstream(dir / "sim" / "truth" / "frame_000001.vdb", std::ios::trunc) << "not a volume";
  const RunSummary run = RunAll(SmallRun(dir / "sim", dir / "out"));
  ASSERT_EQ(run.frames.size(), 2u);
  EXPECT_EQ(run.failed, 0u);
  EXPECT_EQ(run.frames[1].status, "computed");
  ASSERT_FALSE(run.frames[1].notes.empty());
  EXPECT_NE(run.frames[1].notes.back().find("truth not compared"), std::string::npos)
      << run.frames[1].Line();
  EXPECT_GE(run.frames[0].truth_rms_k, 0);
  fs::remove_all(dir);
}

// The stages can be replaced one by one: a fit that fails on one frame fails that frame only, a
// reconstruction that is watched sees every frame it is asked for.
TEST(RunFrames, StagesCanBeReplacedOneByOne) {
  const fs::path dir = TempDir("stages");
  SimulateDataset(dir / "sim", 3);
  const RunOptions o = SmallRun(dir / "sim", dir / "out");
  struct Stages : FrameStages {
    using FrameStages::FrameStages;
    std::vector<std::size_t> reconstructed;
    void Reconstruct(FrameWork* w, const ProgressCallback& p) override {
      reconstructed.push_back(w->index);
      FrameStages::Reconstruct(w, p);
    }
    void Fit(FrameWork* w, const ProgressCallback& p) override {
      if (w->index == 1) throw DataError("a fit that cannot converge on this frame");
      FrameStages::Fit(w, p);
    }
  } stages(o, o.rig_path, 0);
  const RunSummary run = RunFrames(o, o.rig_path, 0, 3, nullptr, &stages);
  EXPECT_EQ((std::vector<std::size_t>{0, 1, 2}), stages.reconstructed);
  ASSERT_EQ(run.frames.size(), 3u);
  EXPECT_EQ(run.frames[1].status, "failed: a fit that cannot converge on this frame");
  EXPECT_EQ(run.frames[2].status, "computed");
  fs::remove_all(dir);
}

// A cancel inside a frame (here at the first iteration of frame 1's fit) stops the run without
// committing that frame; the same run started again computes it and the rest.
TEST(RunFrames, ACancelInsideAFrameCommitsNothingOfItAndTheRunResumes) {
  const fs::path dir = TempDir("cancel");
  SimulateDataset(dir / "sim", 3);
  const RunOptions o = SmallRun(dir / "sim", dir / "out");
  int frames_done = 0;
  const RunSummary stopped = RunFrames(o, o.rig_path, 0, 3, [&](const Progress& p) {
    if (p.stage == "frames") ++frames_done;
    return frames_done == 1 && p.stage == "fit" ? ProgressAction::kCancel
                                                : ProgressAction::kContinue;
  });
  EXPECT_TRUE(stopped.cancelled);
  ASSERT_EQ(stopped.frames.size(), 1u);
  EXPECT_EQ(stopped.frames[0].status, "computed");
  EXPECT_TRUE(fs::exists(dir / "out" / "frames" / "frame_000000.yaml"));
  EXPECT_FALSE(fs::exists(dir / "out" / "frames" / "frame_000001.yaml"));
  for (const auto& e : fs::recursive_directory_iterator(dir / "out"))
    EXPECT_EQ(e.path().string().find(".tmp"), std::string::npos) << e.path();
  const RunSummary resumed = RunAll(o);
  EXPECT_FALSE(resumed.cancelled);
  EXPECT_EQ(resumed.resumed, 1u);
  EXPECT_EQ(resumed.computed, 2u);
  ASSERT_EQ(resumed.frames.size(), 3u);
  for (const auto& f : resumed.frames) EXPECT_EQ(f.status, "computed") << f.Line();
  fs::remove_all(dir);
}

// A resumed run takes a frame as done only when its volume is there (a volume deleted after the
// run is computed again, with the frames after it), and refuses an OUT whose frames were fitted
// with other options, which it took as done until 2026-12-01.
TEST(RunFrames, AResumeRecomputesAMissingVolumeAndRefusesOtherOptions) {
  const fs::path dir = TempDir("resume_options");
  SimulateDataset(dir / "sim", 3);
  const RunOptions o = SmallRun(dir / "sim", dir / "out");
  ASSERT_EQ(RunAll(o).computed, 3u);
  fs::remove(dir / "out" / "frame_000001.vdb");
  const RunSummary again = RunAll(o);
  EXPECT_EQ(again.resumed, 1u);
  EXPECT_EQ(again.computed, 2u);
  EXPECT_TRUE(fs::exists(dir / "out" / "frame_000001.vdb"));
  EXPECT_EQ(RunAll(o).resumed, 3u);  // all there now
  RunOptions other = o;
  other.fit.objective.w_sm *= 2;
  try {
    RunAll(other);
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("holds frames fitted with other options"),
              std::string::npos)
        << e.what();
  }
  // An option the hand-written key of 2026-12-01 left out (the temperature's upper bound).
  RunOptions bounds = o;
  bounds.fit.objective.t_max_k = 2500;
  EXPECT_THROW(RunAll(bounds), InputError);
  EXPECT_TRUE(fs::exists(dir / "out" / "frame_000002.vdb"));  // nothing of it was touched
  fs::remove_all(dir);
}

// The orchestration of ranks, in process: two ranks as threads split the frames contiguously,
// rank 0 writes the one report with every frame, in order.
TEST(RunDistributed, TwoRanksAsThreadsShareTheFramesAndOneReport) {
  const fs::path dir = TempDir("ranks");
  SimulateDataset(dir / "sim", 3);
  const RunOptions o = SmallRun(dir / "sim", dir / "out");
  ThreadRanks ranks(2);
  std::array<DistributedRun, 2> runs;
  DistributedOptions d;
  d.threads = 1;
  std::vector<std::thread> threads;
  for (int r = 0; r < 2; ++r)
    threads.emplace_back([&, r] { runs[r] = RunDistributed(o, d, ranks.rank(r)); });
  for (auto& t : threads) t.join();
  EXPECT_EQ(runs[0].mine.begin, 0u);
  EXPECT_EQ(runs[0].mine.end, 2u);
  EXPECT_EQ(runs[1].mine.begin, 2u);
  EXPECT_EQ(runs[1].mine.end, 3u);
  ASSERT_EQ(runs[0].frames.size(), 3u);
  for (std::size_t i = 0; i < 3; ++i) EXPECT_EQ(runs[0].frames[i].frame, i);
  EXPECT_TRUE(runs[1].frames.empty());
  EXPECT_TRUE(fs::exists(runs[0].report)) << runs[0].report;
  EXPECT_EQ(runs[0].failed, 0u);
  fs::remove_all(dir);
}

// Records the first `sets` frame sets of a dataset's three 120x90 cameras into `rec_dir` as a
// hardware-triggered take in `format` (RGB8, or a Bayer mosaic of the dataset's pixels: 8-bit, or
// 16-bit words of a deeper camera's codes); `frame(s, c, &f)` sees every frame before it is
// submitted, may change it, and returns false to drop it; `start(&metadata)` may change the
// recording's metadata (the cameras' settings at its start: the defaults' 10000 us, 0 dB; their
// drivers; features) before it starts.
void RecordDataset(const fs::path& dataset, const Rig& rig, const fs::path& rec_dir, int sets,
                   PixelFormat format, const std::function<bool(int, int, Frame*)>& frame,
                   const std::string& driver = "sim",
                   const std::function<void(RecordingMetadata*)>& start = nullptr) {
  RecordingMetadata meta;
  meta.sync_mode = "hardware-trigger";
  for (const auto& c : rig.cameras) {
    RecordingCamera rc;
    rc.name = c.name;
    rc.description.driver = driver;
    rc.settings.width = 120;
    rc.settings.height = 90;
    rc.settings.pixel_format = format;
    meta.cameras.push_back(rc);
  }
  if (start) start(&meta);
  const BayerLayout layout = BayerLayoutOf(format);
  Recorder recorder(rec_dir.string(), meta);
  for (int s = 0; s < sets; ++s) {
    FrameSet set;
    set.index = s;
    set.trigger_id = s;
    set.frames.resize(3);
    for (int c = 0; c < 3; ++c) {
      ImageU8 image;
      ImageU16 deep;
      const int bits =
          ReadImage((dataset / "frames" / FrameName(s) / (rig.cameras[c].name + ".png")).string(),
                    &image, &deep, 3);
      ASSERT_EQ(bits, BytesPerPixel(format) == 2 ? 16 : 8) << ToString(format);
      auto bytes = std::make_shared<std::vector<std::uint8_t>>(image.pixels);
      if (layout != BayerLayout::kNone && bits == 8) {
        bytes->resize(image.num_pixels());
        for (int y = 0; y < image.height; ++y)
          for (int x = 0; x < image.width; ++x)
            (*bytes)[std::size_t(y) * image.width + x] = image.at(x, y, BayerColour(layout, x, y));
      } else if (layout != BayerLayout::kNone) {
        bytes->resize(2 * deep.num_pixels());
        for (int y = 0; y < deep.height; ++y)
          for (int x = 0; x < deep.width; ++x) {
            const std::uint16_t v = deep.at(x, y, BayerColour(layout, x, y));
            std::memcpy(bytes->data() + 2 * (std::size_t(y) * deep.width + x), &v, 2);
          }
      }
      Frame f;
      f.info.camera = c;
      f.info.frame_id = 100 + s;
      f.info.trigger_id = s;
      f.info.pixel_format = format;
      f.info.width = 120;
      f.info.height = 90;
      f.data = bytes;
      if (frame(s, c, &f)) set.frames[c] = f;
    }
    ASSERT_TRUE(recorder.Submit(set));
  }
  EXPECT_EQ(recorder.Close().sets_recorded, static_cast<std::size_t>(sets));
}

// A camera whose exposure or gain was changed while it recorded (`ctl configure CAM exposure_us`,
// live): the frames' own records say so, and each set after the change carries the factor, a note
// and frames decoded at their own exposure. Frames that record no exposure say nothing.
TEST(FrameSource, ARecordingSaysWhenACamerasExposureChanged) {
  const fs::path dir = TempDir("exposure_change");
  SimulateDataset(dir / "sim", 3);
  const Rig rig = Rig::Load((dir / "sim" / "rig.yaml").string());
  const fs::path rec_dir = dir / "rec";
  // The recording started at the settings' 10000 us and 0 dB.
  RecordDataset(dir / "sim", rig, rec_dir, 3, PixelFormat::kRgb8, [](int s, int c, Frame* f) {
    f->info.exposure_us = c == 2 ? 0 : 10000;  // camera 2's frames record none
    if (s == 2 && c == 0) f->info.exposure_us = 8000;
    if (s >= 1 && c == 1) f->info.gain_db = 6;
    return true;
  });
  FrameSourceSpec spec;
  spec.recording_dir = rec_dir.string();
  const FrameSource source(spec, rig);
  const SourceFrameSet first = source.Read(0, 1.0), last = source.Read(2, 1.0);
  ASSERT_EQ(first.exposure_ratio.size(), 3u);
  for (int c = 0; c < 3; ++c) EXPECT_EQ(first.exposure_ratio[c], 1.0) << c;
  EXPECT_TRUE(first.notes.empty());
  EXPECT_NEAR(last.exposure_ratio[0], 0.8, 1e-12);
  EXPECT_NEAR(last.exposure_ratio[1], std::pow(10.0, 6.0 / 20), 1e-12);  // 6 dB: 1.995 times
  EXPECT_EQ(last.exposure_ratio[2], 1.0);
  ASSERT_EQ(last.notes.size(), 2u);
  EXPECT_NE(last.notes[0].find(rig.cameras[0].name + " exposed at 0.8 times"), std::string::npos)
      << last.notes[0];
  EXPECT_NE(last.notes[0].find("8000 us, 0 dB; it started at 10000 us, 0 dB): fitted at that "
                               "exposure"),
            std::string::npos)
      << last.notes[0];
  // Its frame is decoded at its own exposure: radiance = signal / (0.8 x the take's exposure).
  const ImageF& signal = last.signal[0];
  const ImageF& radiance = last.linear[0].radiance;
  std::size_t lit = 0;
  for (std::size_t p = 0; p < signal.pixels.size(); ++p)
    if (signal.pixels[p] > 0.05f) {
      ++lit;
      ASSERT_NEAR(radiance.pixels[p], signal.pixels[p] / 0.8, 1e-5) << p;
    }
  EXPECT_GT(lit, 100u);
  EXPECT_NE(last.notes[1].find(rig.cameras[1].name + " exposed at 2 times"), std::string::npos)
      << last.notes[1];
  const SourceFrameSet second = source.Read(1, 1.0);  // the gain alone changed
  ASSERT_EQ(second.notes.size(), 1u);
  EXPECT_NE(second.notes[0].find(rig.cameras[1].name + " exposed at"), std::string::npos)
      << second.notes[0];
  // The same from V4L2 cameras, whose gain is in the device's own units: the gain's change has no
  // known factor (the exposure time's still counts), and the note says so.
  RecordDataset(
      dir / "sim", rig, dir / "rec_v4l2", 3, PixelFormat::kRgb8,
      [](int s, int c, Frame* f) {
        f->info.exposure_us = 10000;
        if (s == 2 && c == 0) f->info.exposure_us = 8000;
        if (s >= 1 && c == 1) f->info.gain_db = 6;
        if (s == 2 && c == 2) f->info.exposure_us = 1e12;  // a damaged record: 1e8 times
        return true;
      },
      "v4l2");
  FrameSourceSpec v4l2_spec;
  v4l2_spec.recording_dir = (dir / "rec_v4l2").string();
  const SourceFrameSet raw_gain = FrameSource(v4l2_spec, rig).Read(2, 1.0);
  EXPECT_NEAR(raw_gain.exposure_ratio[0], 0.8, 1e-12);
  EXPECT_EQ(raw_gain.exposure_ratio[1], 1.0);
  EXPECT_EQ(raw_gain.exposure_ratio[2], 1.0);
  EXPECT_EQ(raw_gain.exposure_unknown, (std::vector<bool>{false, true, true}));
  EXPECT_EQ(last.exposure_unknown, (std::vector<bool>{false, false, false}));
  ASSERT_EQ(raw_gain.notes.size(), 3u);
  EXPECT_NE(raw_gain.notes[2].find(rig.cameras[2].name + "'s frame records 1e+12 us, 0 dB"),
            std::string::npos)
      << raw_gain.notes[2];
  EXPECT_NE(raw_gain.notes[2].find("not believed (a damaged record?), so not applied"),
            std::string::npos)
      << raw_gain.notes[2];
  EXPECT_NE(raw_gain.notes[1].find(rig.cameras[1].name +
                                   "'s gain is 6 where the recording started at 0, in the "
                                   "device's own units (v4l2 records no gain in dB)"),
            std::string::npos)
      << raw_gain.notes[1];
  // Exported, the set's folder says so in sets.csv, and reads back at the same exposure: as a
  // folder of sets, and as the one set's folder.
  ExportRecording(rec_dir.string(), (dir / "png").string(), ExportOptions());
  FrameSourceSpec png_spec;
  png_spec.images_dir = (dir / "png").string();
  const FrameSource png(png_spec, rig);
  for (const SourceFrameSet& back :
       {png.Read(2, 1.0), ReadFrameFolder(rig, (dir / "png" / FrameName(2)).string(), 1.0)}) {
    EXPECT_NEAR(back.exposure_ratio[0], 0.8, 1e-9);
    EXPECT_NEAR(back.exposure_ratio[1], std::pow(10.0, 6.0 / 20), 1e-8);
    EXPECT_EQ(back.exposure_ratio[2], 1.0);
    ASSERT_EQ(back.notes.size(), 2u);
    EXPECT_NE(back.notes[0].find(rig.cameras[0].name + " exposed at 0.8 times"), std::string::npos)
        << back.notes[0];
    for (std::size_t p = 0; p < back.signal[0].pixels.size(); p += 97)
      ASSERT_NEAR(back.linear[0].radiance.pixels[p], back.signal[0].pixels[p] / 0.8, 1e-5) << p;
  }
  EXPECT_TRUE(png.Read(0, 1.0).notes.empty());
  // The V4L2 take exported: camera 1's gain change (device units) and camera 2's damaged record
  // read back as unknown, camera 0's exposure time as it was, like the recording itself.
  ExportRecording((dir / "rec_v4l2").string(), (dir / "png_v4l2").string(), ExportOptions());
  FrameSourceSpec png_v4l2;
  png_v4l2.images_dir = (dir / "png_v4l2").string();
  const SourceFrameSet raw_back = FrameSource(png_v4l2, rig).Read(2, 1.0);
  EXPECT_EQ(raw_back.exposure_ratio, raw_gain.exposure_ratio);
  EXPECT_EQ(raw_back.exposure_unknown, raw_gain.exposure_unknown);
  ASSERT_EQ(raw_back.notes.size(), 3u);
  EXPECT_NE(raw_back.notes[1].find(rig.cameras[1].name +
                                   "'s exposure changed by a factor its recording does not give"),
            std::string::npos)
      << raw_back.notes[1];
  // A damaged cell (CRLF line ends too, as a copy through Windows leaves them) fails its own set
  // with an error naming the file, its line and the column; the other sets read.
  std::string csv = ReadFile((dir / "png" / "sets.csv").string());
  const std::size_t at = csv.find(",0.8,");
  ASSERT_NE(at, std::string::npos) << csv;
  csv.replace(at, 5, ",zero,");
  std::string crlf;
  for (char ch : csv) crlf += ch == '\n' ? std::string("\r\n") : std::string(1, ch);
  WriteFileAtomically((dir / "png" / "sets.csv").string(), crlf);
  const FrameSource damaged(png_spec, rig);
  EXPECT_NEAR(damaged.Read(1, 1.0).exposure_ratio[1], std::pow(10.0, 6.0 / 20), 1e-8);
  try {
    damaged.Read(2, 1.0);
    ADD_FAILURE() << "a damaged exposure accepted";
  } catch (const DataError& e) {
    EXPECT_NE(std::string(e.what()).find("sets.csv, line 4: " + rig.cameras[0].name +
                                         "_exposure 'zero' is not an exposure factor"),
              std::string::npos)
        << e.what();
  }
  // The run computes such a set, and its summary line carries the note.
  RunOptions o = SmallRun(dir / "sim", dir / "out");
  o.source = spec;
  const RunSummary run = RunAll(o);
  ASSERT_EQ(run.frames.size(), 3u);
  EXPECT_EQ(run.frames[2].status, "computed");
  EXPECT_NE(run.frames[2].Line().find("fitted at that exposure"), std::string::npos)
      << run.frames[2].Line();
  EXPECT_EQ(run.frames[0].Line().find("exposed at"), std::string::npos) << run.frames[0].Line();
  fs::remove_all(dir);
}

// Cameras of one take started at different settings (a rig balanced per camera): each camera's
// frames are decoded at its exposure time x gain over the recording's first camera's, the take's
// reference, on every set; its own later changes count from its start. Gains are compared in dB
// only; a gain in a device's own units is not compared across cameras. The source says once which
// cameras started elsewhere, and an export's sets.csv carries the same factors.
TEST(FrameSource, ACameraStartedAtOtherSettingsIsDecodedAtItsOwn) {
  const fs::path dir = TempDir("exposure_start");
  SimulateDataset(dir / "sim", 2);
  const Rig rig = Rig::Load((dir / "sim" / "rig.yaml").string());
  // cam0 (the reference) at 10000 us, 0 dB; cam1 at 5000 us; cam2 at 10000 us and 6 dB, and its
  // exposure time changed to 8000 us on set 1.
  const auto start = [](RecordingMetadata* m) {
    m->cameras[1].settings.exposure_us = 5000;
    m->cameras[2].settings.gain_db = 6;
  };
  const auto frames = [](int s, int c, Frame* f) {
    f->info.exposure_us = c == 1 ? 5000 : 10000;
    f->info.gain_db = c == 2 ? 6 : 0;
    if (s == 1 && c == 2) f->info.exposure_us = 8000;
    return true;
  };
  RecordDataset(dir / "sim", rig, dir / "rec", 2, PixelFormat::kRgb8, frames, "sim", start);
  FrameSourceSpec spec;
  spec.recording_dir = (dir / "rec").string();
  const FrameSource source(spec, rig);
  const double six_db = std::pow(10.0, 6.0 / 20);  // 1.995
  ASSERT_EQ(source.notes().size(), 2u);
  EXPECT_NE(source.notes()[0].find(rig.cameras[1].name + " started at 5000 us, 0 dB, 0.5 times " +
                                   rig.cameras[0].name + "'s 10000 us, 0 dB"),
            std::string::npos)
      << source.notes()[0];
  EXPECT_NE(source.notes()[1].find(rig.cameras[2].name + " started at 10000 us, 6 dB, 2 times"),
            std::string::npos)
      << source.notes()[1];
  for (std::size_t i = 0; i < 2; ++i) {
    SCOPED_TRACE(i);
    const SourceFrameSet set = source.Read(i, 1.0);
    const double own = i == 1 ? 0.8 : 1.0;  // cam2's own change on set 1
    EXPECT_EQ(set.exposure_ratio[0], 1.0);
    EXPECT_NEAR(set.exposure_ratio[1], 0.5, 1e-12);
    EXPECT_NEAR(set.exposure_ratio[2], six_db * own, 1e-12);
    EXPECT_NEAR(set.exposure_start_ratio[1], 0.5, 1e-12);
    EXPECT_NEAR(set.exposure_start_ratio[2], six_db, 1e-12);
    EXPECT_EQ(set.exposure_unknown, (std::vector<bool>{false, false, false}));
    // The per-set note is the camera's own change only.
    ASSERT_EQ(set.notes.size(), i) << (set.notes.empty() ? "" : set.notes[0]);
    if (i == 1) {
      EXPECT_NE(set.notes[0].find(rig.cameras[2].name + " exposed at 0.8 times"), std::string::npos)
          << set.notes[0];
    }
    // Decoded at its own exposure: radiance = signal / (factor x the take's exposure).
    for (std::size_t p = 0; p < set.signal[1].pixels.size(); p += 31)
      ASSERT_NEAR(set.linear[1].radiance.pixels[p], set.signal[1].pixels[p] / 0.5, 1e-5) << p;
  }
  // Exported: sets.csv carries the whole factor, and reads back at it.
  const ExportSummary exported =
      ExportRecording((dir / "rec").string(), (dir / "png").string(), ExportOptions());
  ASSERT_GE(exported.notes.size(), 2u);
  EXPECT_NE(exported.notes[0].find("camera " + rig.cameras[1].name + " started at 5000 us"),
            std::string::npos)
      << exported.notes[0];
  FrameSourceSpec png_spec;
  png_spec.images_dir = (dir / "png").string();
  const SourceFrameSet back = FrameSource(png_spec, rig).Read(1, 1.0);
  EXPECT_NEAR(back.exposure_ratio[1], 0.5, 1e-9);
  EXPECT_NEAR(back.exposure_ratio[2], six_db * 0.8, 1e-8);
  EXPECT_NEAR(back.exposure_start_ratio[1], 0.5, 1e-9);
  EXPECT_NEAR(back.exposure_start_ratio[2], six_db, 1e-8);
  ASSERT_EQ(back.notes.size(), 1u);  // cam2's own change only, as from the recording
  EXPECT_NE(back.notes[0].find(rig.cameras[2].name + " exposed at 0.8 times its start"),
            std::string::npos)
      << back.notes[0];
  // Aravis cameras, the first one's gain in the device's units (GainRaw) and the others' in dB
  // (GenICam's Gain): the exposure times compare with the first camera's, the gains in dB with the
  // first camera that gives one (cam1), so cam2's 6 dB over cam1's 0 counts.
  RecordDataset(
      dir / "sim", rig, dir / "rec_aravis", 1, PixelFormat::kRgb8,
      [](int, int c, Frame* f) {
        f->info.exposure_us = 10000;
        f->info.gain_db = c == 2 ? 6 : c == 0 ? 3 : 0;
        return true;
      },
      "aravis",
      [](RecordingMetadata* m) {
        m->cameras[0].settings.gain_db = 3;  // GainRaw 3
        m->cameras[2].settings.gain_db = 6;
        for (int c : {1, 2}) m->features[m->cameras[c].name + ".Gain"] = "0";
      });
  FrameSourceSpec aravis_spec;
  aravis_spec.recording_dir = (dir / "rec_aravis").string();
  const FrameSource aravis(aravis_spec, rig);
  const SourceFrameSet mixed = aravis.Read(0, 1.0);
  EXPECT_EQ(mixed.exposure_ratio[0], 1.0);
  EXPECT_EQ(mixed.exposure_ratio[1], 1.0);
  EXPECT_NEAR(mixed.exposure_ratio[2], six_db, 1e-12);
  ASSERT_EQ(aravis.notes().size(), 1u);
  EXPECT_NE(aravis.notes()[0].find(rig.cameras[2].name + " started at 10000 us, 6 dB, 2 times " +
                                   rig.cameras[0].name + "'s 10000 us and " + rig.cameras[1].name +
                                   "'s 0 dB"),
            std::string::npos)
      << aravis.notes()[0];
  // V4L2 cameras: the exposure times compare, gains in the device's own units do not (cam2's 6
  // against cam0's 0 is not a factor of 2), and the note says so.
  RecordDataset(dir / "sim", rig, dir / "rec_v4l2", 1, PixelFormat::kRgb8, frames, "v4l2", start);
  FrameSourceSpec v4l2_spec;
  v4l2_spec.recording_dir = (dir / "rec_v4l2").string();
  const FrameSource v4l2(v4l2_spec, rig);
  const SourceFrameSet raw = v4l2.Read(0, 1.0);
  EXPECT_NEAR(raw.exposure_ratio[1], 0.5, 1e-12);
  EXPECT_EQ(raw.exposure_ratio[2], 1.0);
  EXPECT_EQ(raw.exposure_unknown, (std::vector<bool>{false, false, false}));
  ASSERT_EQ(v4l2.notes().size(), 1u);
  EXPECT_NE(v4l2.notes()[0].find(rig.cameras[1].name + " started at 5000 us, 0.5 times " +
                                 rig.cameras[0].name + "'s 10000 us (the take's exposure"),
            std::string::npos)
      << v4l2.notes()[0];
  // A damaged start record (1e12 us) is not believed: 1, and said.
  RecordDataset(
      dir / "sim", rig, dir / "rec_damaged", 1, PixelFormat::kRgb8,
      [](int, int, Frame*) { return true; }, "sim",
      [](RecordingMetadata* m) { m->cameras[1].settings.exposure_us = 1e12; });
  FrameSourceSpec damaged_spec;
  damaged_spec.recording_dir = (dir / "rec_damaged").string();
  const FrameSource damaged(damaged_spec, rig);
  EXPECT_EQ(damaged.Read(0, 1.0).exposure_ratio[1], 1.0);
  ASSERT_EQ(damaged.notes().size(), 1u);
  EXPECT_NE(damaged.notes()[0].find("not believed (a damaged record?), so not applied"),
            std::string::npos)
      << damaged.notes()[0];
  fs::remove_all(dir);
}

// A camera re-exposed while recording (`ctl configure CAM exposure_us`, live) at half its start's
// exposure, its frames half as bright as the others': fitted at the exposure its frames record,
// the set fits as the same set recorded unchanged does (soot within 5%, temperature RMS against
// the generator's truth within 5 K, the camera's Delta E within 0.5); the same darkened frames
// recorded without saying so (the take's one exposure) are not matched. The camera writes 8-bit
// sRGB, so its halved frame is coarser in the dark, as a real camera's is.
TEST(RunFrames, ACameraReExposedWhileRecordingIsFittedAtItsOwnExposure) {
  const fs::path dir = TempDir("reexposed");
  SimulateDataset(dir / "sim", 2);
  const Rig rig = Rig::Load((dir / "sim" / "rig.yaml").string());
  // Camera 1's frame of set 1 at half the exposure: half the linear light, 8-bit sRGB again.
  const auto halve = [](Frame* f) {
    auto darker = std::make_shared<std::vector<std::uint8_t>>(*f->data);
    for (auto& v : *darker)
      v = static_cast<std::uint8_t>(std::lround(255 * SrgbEncode(0.5 * SrgbDecode(v / 255.0))));
    f->data = darker;
  };
  // `started`: camera 1 recorded the whole take at 5000 us, set so before it started, against
  // the other cameras' 10000 us (the take's reference is camera 0's).
  const auto record = [&](const char* name, bool darken, bool say, bool started = false) {
    RecordDataset(
        dir / "sim", rig, dir / name, 2, PixelFormat::kRgb8,
        [&](int s, int c, Frame* f) {
          f->info.exposure_us = 10000;
          if (c == 1 && ((s == 1 && darken) || started)) {
            halve(f);
            if (say || started) f->info.exposure_us = 5000;
          }
          return true;
        },
        "sim",
        [&](RecordingMetadata* m) {
          if (started) m->cameras[1].settings.exposure_us = 5000;
        });
    RunOptions o = SmallRun(dir / "sim", dir / (std::string(name) + "_out"));
    o.source = FrameSourceSpec();
    o.source.recording_dir = (dir / name).string();
    o.sigma = o.blender = o.pictures = false;
    const RunSummary run = RunAll(o);
    EXPECT_EQ(run.failed, 0u) << name;
    return run.frames.at(1);
  };
  const FrameSummary unchanged = record("unchanged", false, false);
  const FrameSummary said = record("said", true, true);
  const FrameSummary unsaid = record("unsaid", true, false);
  const FrameSummary started = record("started", false, false, true);
  for (const FrameSummary* f : {&unchanged, &said, &unsaid, &started}) {
    ASSERT_EQ(f->status, "computed");
    ASSERT_GT(f->truth_rms_k, 0);
    ASSERT_GT(f->soot, 0);
  }
  std::printf(
      "re-exposed camera, frame 1: soot / unchanged's %.3f (said) %.3f (unsaid); "
      "T RMS %.1f K (unchanged) %.1f K (said) %.1f K (unsaid); truth spread %.1f K\n",
      said.soot / unchanged.soot, unsaid.soot / unchanged.soot, unchanged.truth_rms_k,
      said.truth_rms_k, unsaid.truth_rms_k, unchanged.truth_spread_k);
  std::printf(
      "camera 1 started at half the others' exposure: soot / unchanged's %.3f, T RMS "
      "%.1f K\n",
      started.soot / unchanged.soot, started.truth_rms_k);
  for (const FrameSummary* f : {&unchanged, &said, &unsaid, &started}) {
    for (const ViewDeltaE& d : f->delta_e) std::printf("  %s %.2f", d.camera.c_str(), d.fire);
    std::printf("  exposure %.4f %s bias %.1f\n", f->exposure, f->exposure_from.c_str(),
                f->truth_bias_k);
  }
  EXPECT_NE(said.Line().find("exposed at 0.5 times"), std::string::npos) << said.Line();
  EXPECT_NEAR(said.soot / unchanged.soot, 1.0, 0.05);
  EXPECT_NEAR(said.truth_rms_k, unchanged.truth_rms_k, 5.0);
  // The re-exposed camera's fire pixels match as the unchanged camera's do (Delta E about 0.8);
  // unsaid, its frame is twice as dark as anything the volume can render for it (measured:
  // 11.3), while the other two cameras outvote it (the robust data term), so its soot hardly moves
  // (0.997).
  ASSERT_EQ(said.delta_e.size(), 3u);
  ASSERT_EQ(unsaid.delta_e.size(), 3u);
  EXPECT_NEAR(said.delta_e[1].fire, unchanged.delta_e[1].fire, 0.5);
  EXPECT_GT(unsaid.delta_e[1].fire, 5 * said.delta_e[1].fire);
  // A camera that recorded the whole take at half the others' exposure time is fitted at its own
  // (a set that only the darkened camera's record tells apart from the unsaid one).
  EXPECT_NEAR(started.soot / unchanged.soot, 1.0, 0.05);
  EXPECT_NEAR(started.truth_rms_k, unchanged.truth_rms_k, 5.0);
  ASSERT_EQ(started.delta_e.size(), 3u);
  EXPECT_NEAR(started.delta_e[1].fire, unchanged.delta_e[1].fire, 0.5);
  // Exported, set 1 alone through `flamerig fit` (its folder beside the export's sets.csv): the
  // same, the re-exposed camera fitted at its frame's exposure as `run` fits it.
  const auto fit_exported = [&](const char* name) {
    ExportRecording((dir / name).string(), (dir / (std::string(name) + "_png")).string(),
                    ExportOptions());
    FitJob job;
    job.rig_path = (dir / "sim" / "rig.yaml").string();
    job.images_dir = (dir / (std::string(name) + "_png") / FrameName(1)).string();
    job.out_path = (dir / (std::string(name) + "_fit.vdb")).string();
    job.resolution = 24;
    const FitJobResult r = RunFitJob(job);
    EXPECT_EQ(r.scores.size(), 3u) << name;
    return r.scores.size() == 3 ? r.scores[1].fire_delta_e : -1.0;
  };
  const double fit_unchanged = fit_exported("unchanged"), fit_said = fit_exported("said"),
               fit_unsaid = fit_exported("unsaid"), fit_started = fit_exported("started");
  std::printf(
      "fit of the exported set 1, camera 1's fire Delta E: %.2f unchanged, %.2f said, "
      "%.2f unsaid, %.2f started at half\n",
      fit_unchanged, fit_said, fit_unsaid, fit_started);
  EXPECT_NEAR(fit_said, fit_unchanged, 0.5);
  EXPECT_NEAR(fit_started, fit_unchanged, 0.5);
  EXPECT_GT(fit_unsaid, 5 * fit_said);
  fs::remove_all(dir);
}

// The same through the capture daemon, as an operator does it: sim cameras replay the dataset,
// and while the take records cam1's exposure is halved live (`ctl configure cam1 exposure_us`):
// its frames darken (the replay scales their light), carry the new exposure, and `run` fits them
// at it, as well as the frames before the change (cam1's Delta E on fire pixels after the change
// within 0.5 of before; the soot of a set against the set of the same dataset frame before the
// change within 5%).
TEST(RunFrames, AnExposureChangedLiveInTheDaemonIsFittedAtTheFramesOwn) {
  const fs::path dir = TempDir("live_exposure");
  SimulateDataset(dir / "sim", 2);
  const Rig rig = Rig::Load((dir / "sim" / "rig.yaml").string());
  std::string yaml = "data_dir: " + (dir / "rec").string() +
                     "\nsync: software-trigger\ntrigger_rate_hz: 10\ncameras:\n";
  for (const auto& cam : rig.cameras)
    yaml += "  - {name: " + cam.name + ", width: 120, height: 90, pixel_format: RGB8, " +
            "exposure_us: 10000, sim: {replay: " + (dir / "sim").string() + "}}\n";
  const CaptureConfig config = CaptureConfig::Parse(yaml, (dir / "capture.yaml").string());
  SystemClock clock;
  std::string take;
  {
    CaptureDaemon daemon(config, MakeCameras(config, {&clock, nullptr}), &clock, nullptr);
    daemon.Start();
    take = daemon.StartRecording("take");
    std::this_thread::sleep_for(std::chrono::milliseconds(700));
    daemon.SetCameraSetting(rig.cameras[1].name, "exposure_us", "5000");
    std::this_thread::sleep_for(std::chrono::milliseconds(700));
    daemon.StopRecording();
    daemon.Stop();
  }
  RunOptions o = SmallRun(dir / "sim", dir / "out");
  o.source = FrameSourceSpec();
  o.source.recording_dir = take;
  o.sigma = o.blender = o.pictures = false;
  const RunSummary run = RunAll(o);
  ASSERT_GE(run.frames.size(), 8u);
  EXPECT_EQ(run.failed, 0u);
  // Per dataset frame (the replay cycles the dataset's two): cam1's Delta E and the soot, before
  // and after the change.
  std::map<int, std::vector<const FrameSummary*>> before, after;
  for (const FrameSummary& f : run.frames) {
    ASSERT_EQ(f.status, "computed") << f.Line();
    ASSERT_EQ(f.delta_e.size(), 3u);
    const bool changed =
        f.Line().find(rig.cameras[1].name + " exposed at 0.5 times") != std::string::npos;
    (changed ? after : before)[f.truth_frame].push_back(&f);
  }
  ASSERT_FALSE(before.empty());
  ASSERT_FALSE(after.empty());
  for (const auto& [truth, frames] : after) {
    SCOPED_TRACE(truth);
    ASSERT_TRUE(before.count(truth));
    const FrameSummary& was = *before[truth].back();  // warm-started, as the ones after
    for (const FrameSummary* f : frames) {
      std::printf(
          "dataset frame %d: cam1 fire Delta E %.2f after, %.2f before; soot %.3f of "
          "before's\n",
          truth, f->delta_e[1].fire, was.delta_e[1].fire, f->soot / was.soot);
      EXPECT_NEAR(f->delta_e[1].fire, was.delta_e[1].fire, 0.5);
      EXPECT_NEAR(f->soot / was.soot, 1.0, 0.05);
    }
  }
  fs::remove_all(dir);
}

// A rig that knows its exposure unit (a radiometric calibration whose shots gave their exposure
// times, Rig::exposure_unit_us) fits a recording at the exposure its first camera's settings give,
// with no --exposure and no dataset.yaml beside it: the dataset's own exposure, exactly, when the
// unit is the camera's 10000 us over it (the oracle: the simulator's exposure). The same rig
// without the unit fits the exposure instead.
TEST(RunFrames, ARigThatKnowsItsExposureUnitHoldsARecordingsExposure) {
  const fs::path dir = TempDir("exposure_unit");
  SimulateDataset(dir / "sim", 2);
  const Rig rig = Rig::Load((dir / "sim" / "rig.yaml").string());
  double dataset_exposure = 0;
  ASSERT_TRUE(DatasetExposure((dir / "sim" / "rig.yaml").string(), &dataset_exposure));
  RecordDataset(dir / "sim", rig, dir / "rec", 2, PixelFormat::kRgb8, [](int, int, Frame* f) {
    f->info.exposure_us = 10000;  // the settings' default, at 0 dB
    return true;
  });
  Rig calibrated = rig;
  calibrated.exposure_unit_us = 10000 / dataset_exposure;
  calibrated.Save((dir / "cal" / "rig.yaml").string());
  calibrated.exposure_unit_us = 0;
  calibrated.Save((dir / "nounit" / "rig.yaml").string());
  const auto run = [&](const char* rig_dir) {
    RunOptions o = SmallRun(dir / "sim", dir / (std::string(rig_dir) + "_out"));
    o.rig_path = (dir / rig_dir / "rig.yaml").string();
    o.source = FrameSourceSpec();
    o.source.recording_dir = (dir / "rec").string();
    o.sigma = o.blender = o.pictures = false;
    const RunSummary r = RunAll(o);
    EXPECT_EQ(r.failed, 0u) << rig_dir;
    return r;
  };
  const RunSummary known = run("cal"), fitted = run("nounit");
  ASSERT_EQ(known.frames.size(), 2u);
  ASSERT_EQ(fitted.frames.size(), 2u);
  for (const FrameSummary& f : known.frames) {
    EXPECT_EQ(f.exposure_from, "known") << f.Line();
    EXPECT_NEAR(f.exposure / dataset_exposure, 1.0, 1e-12) << f.Line();
  }
  EXPECT_EQ(fitted.frames[0].exposure_from, "fitted") << fitted.frames[0].Line();
  std::printf(
      "exposure %.6f known from the settings (the dataset's %.6f); %.6f fitted without "
      "the unit; T RMS %.1f K known, %.1f K fitted\n",
      known.frames[0].exposure, dataset_exposure, fitted.frames[0].exposure,
      known.frames[0].truth_rms_k, fitted.frames[0].truth_rms_k);
  // Exported: the folder through `run`, a set of it through `fit` and `reconstruct`, know the
  // same exposure from the export's exposure_reference.yaml; through the rig without the unit the
  // fit finds its own. A reference whose exposure time is not one is an error naming the file.
  ExportRecording((dir / "rec").string(), (dir / "png").string(), ExportOptions());
  ASSERT_TRUE(fs::exists(dir / "png" / kExportedReferenceFile));
  RunOptions o = SmallRun(dir / "sim", dir / "png_out");
  o.rig_path = (dir / "cal" / "rig.yaml").string();
  o.source.images_dir = (dir / "png").string();
  o.sigma = o.blender = o.pictures = false;
  const RunSummary exported = RunAll(o);
  ASSERT_EQ(exported.frames.size(), 2u);
  for (const FrameSummary& f : exported.frames) {
    EXPECT_EQ(f.exposure_from, "known") << f.Line();
    EXPECT_NEAR(f.exposure / dataset_exposure, 1.0, 1e-12) << f.Line();
  }
  const auto fit_set = [&](const char* rig_dir, double exposure = 0) {
    FitJob job;
    job.rig_path = (dir / rig_dir / "rig.yaml").string();
    job.images_dir = (dir / "png" / FrameName(1)).string();
    job.out_path = (dir / (std::string(rig_dir) + "_fit.vdb")).string();
    job.resolution = 24;
    job.exposure = exposure;
    return RunFitJob(job).result.exposure;
  };
  EXPECT_NEAR(fit_set("cal") / dataset_exposure, 1.0, 1e-12);
  const double found = fit_set("nounit");  // fitted: not held at any value
  EXPECT_GT(std::abs(found / dataset_exposure - 1), 1e-6) << found;
  ReconstructJob rj;
  rj.rig_path = (dir / "cal" / "rig.yaml").string();
  rj.images_dir = (dir / "png" / FrameName(1)).string();
  rj.out_path = (dir / "tomography.vdb").string();
  rj.reconstruct.resolution = 24;
  const ReconstructJobResult tomography = RunReconstructJob(rj);
  EXPECT_NEAR(tomography.exposure / dataset_exposure, 1.0, 1e-12);
  EXPECT_NE(tomography.exposure_source.find("exposure unit"), std::string::npos)
      << tomography.exposure_source;
  std::ofstream(dir / "png" / kExportedReferenceFile)
      << "reference: {camera: " << rig.cameras[0].name << ", exposure_us: -5}\n";
  EXPECT_EQ(fit_set("cal", 2.0), 2.0);  // --exposure: the file is not read
  EXPECT_GT(fit_set("nounit"), 0.0);    // no unit: the file is not read
  try {
    fit_set("cal");
    ADD_FAILURE() << "a reference whose exposure time is not one";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(std::string(kExportedReferenceFile) +
                                         ": reference.exposure_us must be"),
              std::string::npos)
        << e.what();
  }
  fs::remove_all(dir);
}

// A rig whose cameras are configured at different exposure times, as an operator balances them:
// sim cameras replay the dataset, cam1 at half the others' exposure time from the start (its
// frames darker: the replay scales their light against the time the dataset's exposure stands
// for, 10000 us), and `run` fits it at its own, as well as the same take with every camera alike
// (cam1's fire Delta E within 0.5, the soot within 5% of the same dataset frame's; the run says
// once that cam1 started elsewhere). And a take with every camera at half that time, run through
// a rig that knows the exposure unit (a radiometric calibration's; here the dataset's), with no
// exposure given and no dataset.yaml beside the rig, and through the dataset's own rig (its
// dataset.yaml beside it: its exposure is the 10000 us take's, and the unit it states turns the
// recorded settings into this take's): every camera recorded half the light, the runs hold half
// the dataset's exposure (the oracle: the simulator's exposure x 5000 / 10000), and the densities
// are absolute: the soot within 5% of the take at 10000 us.
TEST(RunFrames, CamerasConfiguredAtDifferentExposuresAreFittedAtTheirOwn) {
  const fs::path dir = TempDir("exposures_apart");
  SimulateDataset(dir / "sim", 2);
  const Rig rig = Rig::Load((dir / "sim" / "rig.yaml").string());
  double dataset_exposure = 0;
  ASSERT_TRUE(DatasetExposure((dir / "sim" / "rig.yaml").string(), &dataset_exposure));
  Rig calibrated = rig;
  calibrated.exposure_unit_us =
      YAML::LoadFile((dir / "sim" / "dataset.yaml").string())["dataset"]["exposure_unit_us"]
          .as<double>();
  EXPECT_NEAR(calibrated.exposure_unit_us * dataset_exposure, 10000, 1e-6);
  calibrated.Save((dir / "cal" / "rig.yaml").string());
  std::map<std::string, std::map<int, std::vector<double>>> recorded;
  const auto record = [&](const char* name, int cam1_exposure_us, int exposure_us = 10000,
                          std::string rig_path = "") {
    std::string yaml = "data_dir: " + (dir / name).string() +
                       "\nsync: software-trigger\ntrigger_rate_hz: 10\ncameras:\n";
    for (const auto& cam : rig.cameras)
      yaml += "  - {name: " + cam.name + ", width: 120, height: 90, pixel_format: RGB8, " +
              "exposure_us: " +
              std::to_string(cam.name == rig.cameras[1].name ? cam1_exposure_us : exposure_us) +
              ", sim: {replay: " + (dir / "sim").string() + "}}\n";
    const CaptureConfig config =
        CaptureConfig::Parse(yaml, (dir / (std::string(name) + ".yaml")).string());
    SystemClock clock;
    std::string take;
    {
      CaptureDaemon daemon(config, MakeCameras(config, {&clock, nullptr}), &clock, nullptr);
      daemon.Start();
      take = daemon.StartRecording("take");
      std::this_thread::sleep_for(std::chrono::milliseconds(500));
      daemon.StopRecording();
      daemon.Stop();
    }
    FrameSourceSpec spec;
    spec.recording_dir = take;
    const FrameSource source(spec, rig);
    // What each camera recorded of sets 0 and 1 (the dataset's two frames, in some order): the
    // sums of their linear signals (no exposure applied), by dataset frame.
    for (std::size_t i = 0; i < 2; ++i) {
      const SourceFrameSet set = source.Read(i, 1.0);
      std::vector<double>& light = recorded[name][static_cast<int>(set.frame_id % 2)];
      for (const ImageF& signal : set.signal)
        light.push_back(std::accumulate(signal.pixels.begin(), signal.pixels.end(), 0.0));
    }
    RunOptions o = SmallRun(dir / "sim", dir / (std::string(name) + "_out"));
    if (!rig_path.empty()) o.rig_path = rig_path;
    o.source = spec;
    o.sigma = o.blender = o.pictures = false;
    o.count = 4;
    const RunSummary run = RunAll(o);
    EXPECT_EQ(run.failed, 0u) << name;
    return std::make_pair(run, source.notes());
  };
  const auto [alike, alike_notes] = record("alike", 10000);
  const auto [apart, apart_notes] = record("apart", 5000);
  const auto [dim, dim_notes] = record("dim", 5000, 5000, (dir / "cal" / "rig.yaml").string());
  const auto [dim_beside, dim_beside_notes] = record("dim_beside", 5000, 5000);
  // cam1 recorded half the light of the same dataset frame (the replay's sRGB round trip: within
  // 2%), the other cameras the same.
  for (int frame : {0, 1}) {
    const std::vector<double>&a = recorded["alike"][frame], &b = recorded["apart"][frame];
    ASSERT_EQ(a.size(), 3u);
    ASSERT_EQ(b.size(), 3u);
    std::printf("recorded light of dataset frame %d, apart over alike: %.4f %.4f %.4f\n", frame,
                b[0] / a[0], b[1] / a[1], b[2] / a[2]);
    EXPECT_NEAR(b[0] / a[0], 1.0, 1e-9);
    EXPECT_NEAR(b[1] / a[1], 0.5, 0.01);
    EXPECT_NEAR(b[2] / a[2], 1.0, 1e-9);
    for (const char* take : {"dim", "dim_beside"}) {
      const std::vector<double>& d = recorded[take][frame];
      ASSERT_EQ(d.size(), 3u);
      std::printf("recorded light of dataset frame %d, %s over alike: %.4f %.4f %.4f\n", frame,
                  take, d[0] / a[0], d[1] / a[1], d[2] / a[2]);
      for (int c = 0; c < 3; ++c) EXPECT_NEAR(d[c] / a[c], 0.5, 0.01) << take << " " << c;
    }
  }
  EXPECT_TRUE(alike_notes.empty());
  EXPECT_TRUE(dim_notes.empty());
  EXPECT_TRUE(dim_beside_notes.empty());
  ASSERT_EQ(apart_notes.size(), 1u);
  EXPECT_NE(apart_notes[0].find(rig.cameras[1].name + " started at 5000 us, 0 dB, 0.5 times"),
            std::string::npos)
      << apart_notes[0];
  // Set by set against alike's last set of the same dataset frame (the replay cycles its two).
  ASSERT_GE(alike.frames.size(), 3u);
  ASSERT_GE(apart.frames.size(), 3u);
  std::map<int, const FrameSummary*> alike_of;
  for (const FrameSummary& a : alike.frames) {
    ASSERT_EQ(a.status, "computed") << a.Line();
    alike_of[a.truth_frame] = &a;
  }
  for (const FrameSummary& b : apart.frames) {
    SCOPED_TRACE(b.frame);
    ASSERT_EQ(b.status, "computed") << b.Line();
    ASSERT_TRUE(alike_of.count(b.truth_frame));
    const FrameSummary& a = *alike_of[b.truth_frame];
    ASSERT_EQ(b.delta_e.size(), 3u);
    std::printf(
        "dataset frame %d: cam1 fire Delta E %.2f apart, %.2f alike; soot %.3f of alike's\n",
        b.truth_frame, b.delta_e[1].fire, a.delta_e[1].fire, b.soot / a.soot);
    EXPECT_NEAR(b.delta_e[1].fire, a.delta_e[1].fire, 0.5);
    EXPECT_NEAR(b.soot / a.soot, 1.0, 0.05);
  }
  ASSERT_GE(dim.frames.size(), 3u);
  ASSERT_GE(dim_beside.frames.size(), 3u);
  std::vector<FrameSummary> dims = dim.frames;
  dims.insert(dims.end(), dim_beside.frames.begin(), dim_beside.frames.end());
  for (const FrameSummary& d : dims) {
    SCOPED_TRACE(d.frame);
    ASSERT_EQ(d.status, "computed") << d.Line();
    EXPECT_EQ(d.exposure_from, "known") << d.Line();
    EXPECT_NEAR(d.exposure / dataset_exposure, 0.5, 1e-9) << d.Line();
    ASSERT_TRUE(alike_of.count(d.truth_frame));
    const FrameSummary& a = *alike_of[d.truth_frame];
    ASSERT_EQ(d.delta_e.size(), 3u);
    std::printf(
        "dataset frame %d, every camera at 5000 us: exposure %.6f (the dataset's %.6f); fire "
        "Delta E %.2f %.2f %.2f (alike %.2f %.2f %.2f); soot %.3f of alike's\n",
        d.truth_frame, d.exposure, dataset_exposure, d.delta_e[0].fire, d.delta_e[1].fire,
        d.delta_e[2].fire, a.delta_e[0].fire, a.delta_e[1].fire, a.delta_e[2].fire,
        d.soot / a.soot);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(d.delta_e[c].fire, a.delta_e[c].fire, 0.5) << c;
    EXPECT_NEAR(d.soot / a.soot, 1.0, 0.05);
  }
  fs::remove_all(dir);
}

// Both fits of a Bayer take scored the same way, through the mosaic (each run's own report scores
// as it fitted): the mean fire Delta E over the three cameras of `set` (set `frame` of the take)
// of the volume the run in dir/name fitted. Also runs `run` on `spec` with and without the mosaic
// model into dir/through and dir/as_measured.
struct MosaicRuns {
  RunSummary through, as_measured;
  double score_through = 0, score_as_measured = 0;
};
MosaicRuns RunAndScoreThroughTheMosaic(const fs::path& dir, const Rig& rig,
                                       const FrameSourceSpec& spec, const SourceFrameSet& set,
                                       int frame) {
  MosaicRuns out;
  auto run = [&](bool model_mosaic, const char* name) {
    RunOptions o = SmallRun(dir / "sim", dir / name);
    o.source = spec;
    o.fit.objective.model_mosaic = model_mosaic;
    o.sigma = o.blender = o.pictures = false;
    return RunAll(o);
  };
  out.through = run(true, "through");
  out.as_measured = run(false, "as_measured");
  std::vector<std::unique_ptr<CameraRays>> rays;
  std::vector<FitView> views;
  for (int c = 0; c < 3; ++c) {
    rays.push_back(std::make_unique<CameraRays>(rig.cameras[c].model));
    FitView v;
    v.name = rig.cameras[c].name;
    v.rays = rays.back().get();
    v.image = set.images[c];
    v.signal = set.signal[c];
    v.mosaic = MakeBayerRecord(set.mosaic[c], set.radiometry[c], v.name, set.bits[c]);
    views.push_back(std::move(v));
  }
  const AbsorptionModel absorption =
      AbsorptionModel::FromName(DatasetAbsorption((dir / "sim" / "rig.yaml").string()));
  auto score = [&](const char* name) {
    FitResult r;
    r.volume = ReadVdb((dir / name / (FrameName(frame) + ".vdb")).string());
    r.exposure = r.volume.metadata_numbers.at("exposure");
    double sum = 0;
    for (const ViewScore& v : WriteFitReport("", r, views, {}, absorption, RenderOptions{}, ""))
      sum += v.fire_delta_e;
    return sum / 3;
  };
  out.score_through = score("through");
  out.score_as_measured = score("as_measured");
  return out;
}

// A take from colour cameras that send their Bayer mosaics (BayerRG8): the frame source says so,
// and `run` fits and scores every view through the mosaic and the host's demosaicing
// (fitting/mosaic.h). Fitting the interpolated colours as if measured (model_mosaic off, as until
// 2026-11-29) leaves their fringes in the images' error.
TEST(RunFrames, ABayerRecordingIsFittedThroughItsMosaic) {
  const fs::path dir = TempDir("bayer_recording");
  SimulateDataset(dir / "sim", 2);
  const Rig rig = Rig::Load((dir / "sim" / "rig.yaml").string());
  const fs::path rec_dir = dir / "rec";
  std::vector<std::vector<Frame>> sent(2);
  RecordDataset(dir / "sim", rig, rec_dir, 2, PixelFormat::kBayerRg8, [&](int s, int, Frame* f) {
    sent[s].push_back(*f);
    return true;
  });
  FrameSourceSpec spec;
  spec.recording_dir = rec_dir.string();
  const SourceFrameSet set = FrameSource(spec, rig).Read(1, 1.0);
  for (int c = 0; c < 3; ++c) {
    EXPECT_EQ(set.mosaic[c], BayerLayout::kRggb) << c;
    ImageU8 decoded;
    ImageU16 unused;
    DecodeFrame(sent[1][c], &decoded, &unused);
    EXPECT_EQ(set.images[c].pixels, decoded.pixels) << c;
  }
  const MosaicRuns runs = RunAndScoreThroughTheMosaic(dir, rig, spec, set, 1);
  const RunSummary& through = runs.through;
  const RunSummary& as_measured = runs.as_measured;
  ASSERT_EQ(through.computed, 2u);
  ASSERT_EQ(as_measured.computed, 2u);
  // Both fits of set 1 scored the same way, through the mosaic: the one that fitted through it
  // matches the recording better. (Each run's own report scores as it fitted.)
  const double fitted_through = runs.score_through, fitted_as_measured = runs.score_as_measured;
  std::printf(
      "set 1 through the mosaic: fire Delta E %.2f fitted through it, %.2f fitted as "
      "measured; each run's own report: %.2f and %.2f\n",
      fitted_through, fitted_as_measured, through.frames[1].MeanFittedDeltaE(),
      as_measured.frames[1].MeanFittedDeltaE());
  EXPECT_LT(fitted_through, 0.8 * fitted_as_measured);

  // Exported as PNG frame sets, the take keeps its mosaic: `export` writes each camera's pixel
  // format beside the sets, and a folder of them (or one set's folder) is read back as Bayer.
  const fs::path exported = dir / "exported";
  ExportRecording(rec_dir.string(), exported.string(), ExportOptions{});
  ASSERT_TRUE(fs::exists(exported / kExportedFormatsFile));
  FrameSourceSpec images;
  images.images_dir = exported.string();
  const SourceFrameSet from_images = FrameSource(images, rig).Read(1, 1.0);
  const SourceFrameSet one_set = ReadFrameFolder(rig, (exported / FrameName(1)).string(), 1.0);
  for (int c = 0; c < 3; ++c) {
    EXPECT_EQ(from_images.mosaic[c], BayerLayout::kRggb) << c;
    EXPECT_EQ(one_set.mosaic[c], BayerLayout::kRggb) << c;
    EXPECT_EQ(from_images.images[c].pixels, set.images[c].pixels) << c;
  }
  RunOptions o = SmallRun(dir / "sim", dir / "from_images");
  o.source = images;
  o.sigma = o.blender = o.pictures = false;
  const RunSummary from_export = RunAll(o);
  ASSERT_EQ(from_export.computed, 2u);
  for (std::size_t f = 0; f < 2; ++f)
    for (std::size_t v = 0; v < from_export.frames[f].delta_e.size(); ++v)
      EXPECT_NEAR(from_export.frames[f].delta_e[v].fire, through.frames[f].delta_e[v].fire, 0.2);
  // A folder named as a set but outside an export (no sets.csv above it) carries no mosaic; an
  // image that the formats file calls a mosaic but is not RGB is refused, naming it.
  const fs::path lone = dir / "lone" / FrameName(1);
  fs::create_directories(lone);
  for (int c = 0; c < 3; ++c)
    fs::copy_file(exported / FrameName(1) / (rig.cameras[c].name + ".png"),
                  lone / (rig.cameras[c].name + ".png"));
  fs::copy_file(exported / kExportedFormatsFile, dir / "lone" / kExportedFormatsFile);
  EXPECT_EQ(ReadFrameFolder(rig, lone.string(), 1.0).mosaic,
            std::vector<BayerLayout>(3, BayerLayout::kNone));
  fs::copy_file(exported / "sets.csv", dir / "lone" / "sets.csv");
  EXPECT_EQ(ReadFrameFolder(rig, (lone / ".").string(), 1.0).mosaic,
            std::vector<BayerLayout>(3, BayerLayout::kRggb));
  WritePng16((lone / (rig.cameras[0].name + ".png")).string(), ImageU16(120, 90, 1, 1000));
  try {
    ReadFrameFolder(rig, lone.string(), 1.0);
    ADD_FAILURE() << "a grey image was taken as a demosaiced Bayer frame";
  } catch (const DataError& e) {
    EXPECT_NE(std::string(e.what()).find(rig.cameras[0].name + ".png"), std::string::npos)
        << e.what();
  }
  // Plain image folders carry no mosaic; a damaged formats file is an error naming it.
  EXPECT_EQ(ReadFrameFolder(rig, (dir / "sim" / "frames" / FrameName(0)).string(), 1.0).mosaic,
            std::vector<BayerLayout>(3, BayerLayout::kNone));
  std::ofstream(exported / kExportedFormatsFile) << "cameras: {cam0: BayerXY8}\n";
  try {
    FrameSource(images, rig);
    ADD_FAILURE() << "a bad pixel format was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(kExportedFormatsFile), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("BayerXY8"), std::string::npos) << e.what();
  }
  for (const char* bad : {"- cam0\n", "cameras: {[cam0]: BayerRG8}\n", "7\n", "cameras: [\n"}) {
    std::ofstream(exported / kExportedFormatsFile) << bad;
    EXPECT_THROW(ReadFrameFolder(rig, (exported / FrameName(1)).string(), 1.0), InputError) << bad;
  }
  fs::remove_all(dir);
}

// Records `frames` as the one frame set of a take described by `meta`, in `dir`.
void RecordTake(const RecordingMetadata& meta, const std::vector<Frame>& frames,
                const fs::path& dir) {
  Recorder recorder(dir.string(), meta);
  FrameSet set;
  set.index = 0;
  set.trigger_id = 0;
  for (const Frame& f : frames) set.frames.push_back(f);
  ASSERT_TRUE(recorder.Submit(set));
  recorder.Close();
}

// A take from raw 12-bit colour cameras (linear, black level 64) sending 16-bit Bayer mosaics
// (BayerRG16, the codes in the words' low bits, as the rig's bit depth says): the frame source
// reads 16-bit frames, and the fit through the mosaic decodes their codes as the camera's (an
// 8-bit decoding of a 12-bit camera is refused); scored alike through the mosaic it matches the
// recording better than fitting the interpolated colours as measured. (Both Delta E are about 3:
// the simulated noise, 0.5 DN at 8 bits scaled to 12, is 1.8 L* near black in a linear camera.)
TEST(RunFrames, ASixteenBitBayerRecordingIsFittedThroughItsMosaic) {
  const fs::path dir = TempDir("bayer16_recording");
  SimulateRawTwelveBit(dir / "sim");
  const Rig rig = Rig::Load((dir / "sim" / "rig.yaml").string());
  ASSERT_EQ(rig.cameras[0].radiometry.bit_depth, 12);
  const fs::path rec_dir = dir / "rec";
  std::vector<Frame> sent;
  RecordDataset(dir / "sim", rig, rec_dir, 1, PixelFormat::kBayerRg16, [&](int, int, Frame* f) {
    sent.push_back(*f);
    return true;
  });
  FrameSourceSpec spec;
  spec.recording_dir = rec_dir.string();
  const SourceFrameSet set = FrameSource(spec, rig).Read(0, 1.0);
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(set.mosaic[k], BayerLayout::kRggb) << k;
    EXPECT_EQ(set.bits[k], 16) << k;
    ImageU8 unused;
    ImageU16 decoded;
    ASSERT_EQ(DecodeFrame(sent[k], &unused, &decoded), 16);
    std::uint16_t top = 0;
    for (std::uint16_t v : decoded.pixels) top = std::max(top, v);
    EXPECT_GT(top, 1000) << k;  // the fire's codes, not a dark frame
    EXPECT_LE(top, 4095) << k;
  }
  const MosaicRuns runs = RunAndScoreThroughTheMosaic(dir, rig, spec, set, 0);
  const RunSummary& through = runs.through;
  const RunSummary& as_measured = runs.as_measured;
  ASSERT_EQ(through.computed, 1u);
  ASSERT_EQ(as_measured.computed, 1u);
  const double e_through = runs.score_through, e_measured = runs.score_as_measured;
  std::printf(
      "16-bit mosaic: fire Delta E %.2f fitted through it, %.2f fitted as measured; "
      "temperature RMS %.0f K and %.0f K\n",
      e_through, e_measured, through.frames[0].truth_rms_k, as_measured.frames[0].truth_rms_k);
  EXPECT_LT(e_through, e_measured);
  // The same codes as an Aravis camera's BayerRG12p arrive: unpacked into the words' high bits
  // (UnpackTo16Bit), the take's settings naming the wire format. The rig's 12-bit entry reads them
  // as the same signal, and the fit's mosaic model with it.
  const fs::path packed_dir = dir / "rec_packed";
  const RecordingMetadata low_bits_meta = Recording::Open(rec_dir.string()).metadata();
  RecordingMetadata packed_meta = low_bits_meta;
  for (auto& cam : packed_meta.cameras) cam.settings.SetPixelFormat("BayerRG12p");
  std::vector<Frame> packed;  // as the driver unpacks them; frames that do not say (sent_pfnc 0)
  for (const Frame& f : sent) {
    Frame g = f;
    auto words = std::make_shared<std::vector<std::uint8_t>>(*f.data);
    for (std::size_t i = 0; i + 1 < words->size(); i += 2) {
      const unsigned v = ((*words)[i] | (*words)[i + 1] << 8) << 4;
      (*words)[i] = static_cast<std::uint8_t>(v & 0xff);
      (*words)[i + 1] = static_cast<std::uint8_t>(v >> 8);
    }
    g.data = words;
    packed.push_back(g);
  }
  RecordTake(packed_meta, packed, packed_dir);
  FrameSourceSpec packed_spec;
  packed_spec.recording_dir = packed_dir.string();
  const SourceFrameSet from_packed = FrameSource(packed_spec, rig).Read(0, 1.0);
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(from_packed.radiometry[k].bit_depth, 16) << k;
    EXPECT_EQ(from_packed.radiometry[k].black_level, 64 * 16) << k;
    ASSERT_EQ(from_packed.signal[k].pixels.size(), set.signal[k].pixels.size());
    double worst = 0;
    for (std::size_t i = 0; i < set.signal[k].pixels.size(); ++i)
      worst = std::max(worst,
                       double(std::abs(from_packed.signal[k].pixels[i] - set.signal[k].pixels[i])));
    // The demosaicing rounds its interpolated words: to a code in the low bits, to 1/16 of one in
    // the high bits; half a code of the 4031 above black apart at most.
    EXPECT_LE(worst, 0.5 / 4031 + 1e-6) << k;
  }
  {
    RunOptions o = SmallRun(dir / "sim", dir / "packed");
    o.source = packed_spec;
    o.sigma = o.blender = o.pictures = false;
    const RunSummary packed_run = RunAll(o);
    ASSERT_EQ(packed_run.computed, 1u);
    EXPECT_NEAR(packed_run.frames[0].MeanFittedDeltaE(), through.frames[0].MeanFittedDeltaE(),
                0.05);
  }
  // A driver may deliver another format than the settings name (it sets a buffer's format
  // itself): a take whose settings say Mono12p but whose frames are the BayerRG16 mosaic above,
  // codes in the low bits, is read as those frames are, with the rig's 12-bit entry as it stands
  // (WireBitsOf), and its export names the frames' own format.
  const fs::path mislabelled_dir = dir / "rec_mislabelled";
  RecordingMetadata mono_meta = low_bits_meta;
  for (auto& cam : mono_meta.cameras) cam.settings.SetPixelFormat("Mono12p");
  RecordTake(mono_meta, sent, mislabelled_dir);
  FrameSourceSpec mislabelled_spec;
  mislabelled_spec.recording_dir = mislabelled_dir.string();
  const SourceFrameSet from_mislabelled = FrameSource(mislabelled_spec, rig).Read(0, 1.0);
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(from_mislabelled.radiometry[k].bit_depth, 12) << k;
    EXPECT_EQ(from_mislabelled.radiometry[k].black_level, 64) << k;
    EXPECT_EQ(from_mislabelled.signal[k].pixels, set.signal[k].pixels) << k;
  }
  ExportRecording(mislabelled_dir.string(), (dir / "exported_mislabelled").string(),
                  ExportOptions{});
  {
    std::ifstream yaml(dir / "exported_mislabelled" / kExportedFormatsFile);
    const std::string text((std::istreambuf_iterator<char>(yaml)), {});
    EXPECT_NE(text.find("BayerRG16"), std::string::npos) << text;
    EXPECT_EQ(text.find("Mono12p"), std::string::npos) << text;
  }
  // A camera mirrored after it was set up sends BayerGR12p under its BayerRG12p settings, and the
  // driver stores BayerGR16: read in the words' high bits all the same, through the GR mosaic,
  // and exported under the layout's own wire format.
  const fs::path mirrored_dir = dir / "rec_mirrored";
  std::vector<Frame> mirrored = packed;
  for (Frame& f : mirrored) f.info.pixel_format = PixelFormat::kBayerGr16;
  RecordTake(packed_meta, mirrored, mirrored_dir);
  FrameSourceSpec mirrored_spec;
  mirrored_spec.recording_dir = mirrored_dir.string();
  const SourceFrameSet from_mirrored = FrameSource(mirrored_spec, rig).Read(0, 1.0);
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(from_mirrored.mosaic[k], BayerLayout::kGrbg) << k;
    EXPECT_EQ(from_mirrored.radiometry[k].bit_depth, 16) << k;
    EXPECT_EQ(from_mirrored.radiometry[k].black_level, 64 * 16) << k;
  }
  ExportRecording(mirrored_dir.string(), (dir / "exported_mirrored").string(), ExportOptions{});
  {
    std::ifstream yaml(dir / "exported_mirrored" / kExportedFormatsFile);
    const std::string text((std::istreambuf_iterator<char>(yaml)), {});
    EXPECT_NE(text.find("BayerGR12p"), std::string::npos) << text;
  }
  // Frames that say what they were sent in (FrameInfo::sent_pfnc, as the Aravis driver records
  // it) are read by what they say, not by the settings: a camera switched to BayerRG16 under its
  // BayerRG12p settings is read at its own scale with the rig's 12-bit entry as it stands (the
  // settings alone would take it as 12-bit words), and the packed words under Mono12p settings
  // in the words' high bits (the settings alone would take them at 16 bits).
  {
    std::vector<Frame> said16 = sent, said12 = packed;
    for (Frame& f : said16) f.info.sent_pfnc = PfncOf(PixelFormat::kBayerRg16);
    for (Frame& f : said12) f.info.sent_pfnc = WireFormatFromName("BayerRG12p")->pfnc;
    RecordTake(packed_meta, said16, dir / "rec_said16");
    RecordTake(mono_meta, said12, dir / "rec_said12");
    FrameSourceSpec said16_spec, said12_spec;
    said16_spec.recording_dir = (dir / "rec_said16").string();
    said12_spec.recording_dir = (dir / "rec_said12").string();
    const SourceFrameSet from16 = FrameSource(said16_spec, rig).Read(0, 1.0);
    const SourceFrameSet from12 = FrameSource(said12_spec, rig).Read(0, 1.0);
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(from16.radiometry[k].bit_depth, 12) << k;
      EXPECT_EQ(from16.radiometry[k].black_level, 64) << k;
      EXPECT_EQ(from16.signal[k].pixels, set.signal[k].pixels) << k;
      EXPECT_EQ(from12.radiometry[k].bit_depth, 16) << k;
      EXPECT_EQ(from12.radiometry[k].black_level, 64 * 16) << k;
      EXPECT_EQ(from12.signal[k].pixels, from_packed.signal[k].pixels) << k;
    }
    const ExportSummary said16_export = ExportRecording(
        said16_spec.recording_dir, (dir / "exported_said16").string(), ExportOptions{});
    EXPECT_TRUE(said16_export.notes.empty());
    std::ifstream yaml(dir / "exported_said16" / kExportedFormatsFile);
    const std::string text((std::istreambuf_iterator<char>(yaml)), {});
    EXPECT_NE(text.find("BayerRG16"), std::string::npos) << text;
    EXPECT_EQ(text.find("BayerRG12p"), std::string::npos) << text;
    // A take whose frames change what they were sent in: the export names the last good frame's
    // and says so, once per camera; an incomplete frame after it does not count.
    {
      Recorder recorder((dir / "rec_changed").string(), packed_meta);
      for (int k = 0; k < 3; ++k) {
        FrameSet set;
        set.index = k;
        set.trigger_id = k;
        for (int c = 0; c < 3; ++c) {
          Frame f = k == 1 ? said16[c] : said12[c];
          if (k == 2) f.info.status = FrameStatus::kIncomplete;
          set.frames.push_back(f);
        }
        ASSERT_TRUE(recorder.Submit(set));
      }
      recorder.Close();
    }
    const ExportSummary changed = ExportRecording(
        (dir / "rec_changed").string(), (dir / "exported_changed").string(), ExportOptions{});
    ASSERT_EQ(changed.notes.size(), 3u);
    EXPECT_NE(changed.notes[0].find("BayerRG12p to BayerRG16 at set 1"), std::string::npos)
        << changed.notes[0];
    std::ifstream changed_yaml(dir / "exported_changed" / kExportedFormatsFile);
    const std::string changed_text((std::istreambuf_iterator<char>(changed_yaml)), {});
    EXPECT_NE(changed_text.find("BayerRG16"), std::string::npos) << changed_text;
    EXPECT_EQ(changed_text.find("BayerRG12p"), std::string::npos) << changed_text;
  }
  // Exported, the take's frames are 16-bit RGB PNGs of the demosaiced codes, read back as the
  // recording's 16-bit mosaic.
  const fs::path exported = dir / "exported";
  ExportRecording(rec_dir.string(), exported.string(), ExportOptions{});
  FrameSourceSpec images;
  images.images_dir = exported.string();
  const SourceFrameSet from_images = FrameSource(images, rig).Read(0, 1.0);
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(from_images.mosaic[k], BayerLayout::kRggb) << k;
    EXPECT_EQ(from_images.bits[k], 16) << k;
    EXPECT_EQ(from_images.signal[k].pixels, set.signal[k].pixels) << k;
  }
  // The BayerRG12p take exported: its PNGs keep the words' high bits, and pixel_formats.yaml names
  // the wire format, so that the same 12-bit rig entry reads them as it read the take (a folder
  // of one set too), where naming the stored BayerRG16 made every such pixel an error.
  const fs::path exported_packed = dir / "exported_packed";
  ExportRecording(packed_dir.string(), exported_packed.string(), ExportOptions{});
  {
    std::ifstream yaml(exported_packed / kExportedFormatsFile);
    const std::string text((std::istreambuf_iterator<char>(yaml)), {});
    EXPECT_NE(text.find("BayerRG12p"), std::string::npos) << text;
  }
  FrameSourceSpec packed_images;
  packed_images.images_dir = exported_packed.string();
  const SourceFrameSet from_packed_images = FrameSource(packed_images, rig).Read(0, 1.0);
  const SourceFrameSet from_packed_folder =
      ReadFrameFolder(rig, (exported_packed / "frame_000000").string(), 1.0);
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(from_packed_images.mosaic[k], BayerLayout::kRggb) << k;
    EXPECT_EQ(from_packed_images.radiometry[k].black_level, 64 * 16) << k;
    EXPECT_EQ(from_packed_images.signal[k].pixels, from_packed.signal[k].pixels) << k;
    EXPECT_EQ(from_packed_folder.mosaic[k], BayerLayout::kRggb) << k;
    EXPECT_EQ(from_packed_folder.signal[k].pixels, from_packed.signal[k].pixels) << k;
  }
  fs::remove_all(dir);
}

// A recording: a camera that dropped a set and a frame delivered incomplete are left out of their
// frame with a note; a set whose pixels fail their checksum is a failed frame naming the file, and
// the run goes on.
TEST(RunFrames, RecordingsWithDropsAndCorruptionAreReportedPerFrame) {
  const fs::path dir = TempDir("recording");
  SimulateDataset(dir / "sim", 4);
  const Rig rig = Rig::Load((dir / "sim" / "rig.yaml").string());
  const fs::path rec_dir = dir / "rec";
  RecordDataset(dir / "sim", rig, rec_dir, 4, PixelFormat::kRgb8, [](int s, int c, Frame* f) {
    if (s == 2 && c == 0) f->info.status = FrameStatus::kIncomplete;
    return !(s == 1 && c == 2);  // dropped
  });
  // Corrupt a pixel of camera 1's frame in set 3.
  {
    const Recording r = Recording::Open(rec_dir.string());
    const std::uint64_t offset = r.frames(1)[3].offset + sizeof(FrameRecord) + 1000;
    std::fstream f(rec_dir / CameraDataFile(1), std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(static_cast<std::streamoff>(offset));
    const char c = static_cast<char>(f.get());
    f.seekp(static_cast<std::streamoff>(offset));
    f.put(static_cast<char>(c ^ 0x40));
  }
  RunOptions o = SmallRun(dir / "sim", dir / "out");
  o.source = FrameSourceSpec();
  o.source.recording_dir = rec_dir.string();
  const RunSummary run = RunAll(o);
  ASSERT_EQ(run.frames.size(), 4u);
  EXPECT_EQ(run.frames[0].status, "computed");
  EXPECT_EQ(run.frames[0].cameras_used, 3);
  // Set 1: cam2 dropped.
  EXPECT_EQ(run.frames[1].status, "computed");
  EXPECT_EQ(run.frames[1].cameras_used, 2);
  ASSERT_FALSE(run.frames[1].notes.empty());
  EXPECT_NE(run.frames[1].notes[0].find(rig.cameras[2].name + " left out"), std::string::npos);
  EXPECT_EQ(run.frames[1].delta_e.size(), 2u);
  // Set 2: cam0's frame incomplete.
  EXPECT_EQ(run.frames[2].cameras_used, 2);
  ASSERT_FALSE(run.frames[2].notes.empty());
  EXPECT_NE(run.frames[2].notes[0].find("incomplete"), std::string::npos) << run.frames[2].notes[0];
  // Set 3: corrupt, named.
  EXPECT_EQ(run.frames[3].status.rfind("failed", 0), 0u) << run.frames[3].status;
  EXPECT_NE(run.frames[3].status.find(CameraDataFile(1)), std::string::npos)
      << run.frames[3].status;
  EXPECT_FALSE(fs::exists(dir / "out" / "frame_000003.vdb"));
  // The truth of a recorded set is found by its frame id (100 + s) modulo the 4 truth volumes.
  EXPECT_EQ(run.frames[1].truth_frame, 1);

  // A rig camera the recording lacks, and frames of the wrong size: errors that name them.
  Rig renamed = rig;
  renamed.cameras[1].name = "side";
  try {
    FrameSource s(o.source, renamed);
    ADD_FAILURE() << "a camera the recording lacks was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("no camera named side"), std::string::npos) << e.what();
  }
  const fs::path bad = dir / "bad" / "frame_000000";
  fs::create_directories(bad);
  for (const auto& c : rig.cameras)
    WritePng((bad / (c.name + ".png")).string(), ImageU8(64, 48, 3));
  FrameSourceSpec images;
  images.images_dir = (dir / "bad").string();
  const FrameSource wrong(images, rig);
  try {
    wrong.Read(0, 1.0);
    ADD_FAILURE() << "a wrongly sized image was accepted";
  } catch (const DataError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("64x48"), std::string::npos) << m;
    EXPECT_NE(m.find("120x90"), std::string::npos) << m;
    EXPECT_NE(m.find(rig.cameras[0].name), std::string::npos) << m;
  }
  fs::remove_all(dir);
}

// The Blender grids against their definitions: kappa = sigma_550 n, temperature zero outside the
// soot, emission luminance = n x the luminance of sigma B_T (the Planck curve through the colour
// matching functions), and a transform that stands the Y-up rig on Blender's Z up.
TEST(RunFrames, BlenderGridsFollowTheirDefinitions) {
  FireVolume v;
  v.geometry.dims = Eigen::Vector3i(4, 6, 5);
  v.geometry.origin_in_rig = Eigen::Vector3d(-0.02, 0.01, -0.03);
  v.geometry.voxel_size_m = Eigen::Vector3d::Constant(0.005);
  const std::size_t n = v.geometry.num_voxels();
  v.temperature_k.assign(n, 300.0f);
  v.density_per_m3.assign(n, 0.0f);
  const std::size_t hot = v.geometry.Flat(1, 4, 2), warm = v.geometry.Flat(2, 1, 3);
  v.temperature_k[hot] = 2300;
  v.density_per_m3[hot] = 2e16f;
  v.temperature_k[warm] = 1300;
  v.density_per_m3[warm] = 2e16f;
  v.metadata_numbers["exposure"] = 3.5;
  const AbsorptionModel grey = AbsorptionModel::DefaultGrey();
  const BlenderGrids b = MakeBlenderGrids(v, grey);
  EXPECT_FLOAT_EQ(b.density_per_m[hot], grey.CrossSectionM2(550) * 2e16);
  EXPECT_EQ(b.temperature_k[hot], 2300.0f);
  EXPECT_EQ(b.temperature_k[0], 0.0f);  // no soot: no glow in Blender
  EXPECT_EQ(b.density_per_m[0], 0.0f);
  // Luminance per metre of a grey body: sigma n integral(B ybar) / integral(ybar), by quadrature of
  // the Planck formula over colord-data's independent copy of CIE 1931 (5 nm, from 360 nm).
  std::vector<double> ybar;
  {
    std::ifstream cmf("/usr/share/colord/cmf/CIE1931-2deg-XYZ.cmf");
    ASSERT_TRUE(cmf) << "colord-data is missing: scripts/install-deps.sh installs it";
    std::string line;
    while (std::getline(cmf, line) && line.rfind("BEGIN_DATA", 0) != 0 &&
           line.rfind("BEGIN_DATA_FORMAT", 0) != 0) {
    }
    while (std::getline(cmf, line) && line.rfind("BEGIN_DATA", 0) != 0) {
    }
    std::getline(cmf, line);  // xbar
    std::getline(cmf, line);  // ybar
    std::istringstream values(line);
    for (double y; values >> y;) ybar.push_back(y);
    ASSERT_EQ(ybar.size(), 95u);
  }
  auto luminance = [&](double t) {
    double num = 0, den = 0;
    for (std::size_t i = 0; i < ybar.size(); ++i) {
      num += physics::PlanckRadiancePerNm(360.0 + 5.0 * i, t) * ybar[i];
      den += ybar[i];
    }
    return grey.CrossSectionM2(550) * 2e16 * num / den;
  };
  EXPECT_NEAR(b.flame[hot] / luminance(2300), 1.0, 0.01);
  EXPECT_NEAR(b.flame[warm] / luminance(1300), 1.0, 0.01);
  // notes/physics.md: Y(2300 K) is about 3650 Y(1300 K).
  EXPECT_NEAR(b.flame[hot] / b.flame[warm], 3650, 150);

  const fs::path dir = TempDir("blender");
  const std::string path = (dir / "b.vdb").string();
  WriteBlenderVdb(path, v, grey);
  openvdb::initialize();
  openvdb::io::File file(path);
  file.open();
  auto grid = openvdb::gridPtrCast<openvdb::FloatGrid>(file.readGrid("temperature"));
  for (const auto& name : {"density", "temperature", "emission", "flame"})
    EXPECT_TRUE(file.hasGrid(name)) << name;
  file.close();
  ASSERT_TRUE(grid);
  EXPECT_EQ(grid->tree().getValue(openvdb::Coord(1, 4, 2)), 2300.0f);
  const Eigen::Vector3d rig = v.geometry.VoxelCenter(1, 4, 2);
  const openvdb::Vec3d world = grid->indexToWorld(openvdb::Vec3d(1, 4, 2));
  EXPECT_NEAR(world.x(), rig.x(), 1e-9);
  EXPECT_NEAR(world.y(), -rig.z(), 1e-9);  // Blender's y is the rig's -z
  EXPECT_NEAR(world.z(), rig.y(), 1e-9);   // Blender's z (up) is the rig's y (up)
  // A rig in its first camera's frame (calibrate without a config): up is -y (the camera's y
  // points down), and Blender's z is the rig's -y, its y the rig's z (the view direction), so a
  // Blender camera looking along +y sees what that camera saw; the frame and the set's id are
  // kept. Every rig was taken as y-up until 2026-12-02, and this one's fire stood on its head.
  v.metadata_numbers["frame"] = 7;
  v.metadata_numbers["source_frame_id"] = 1234;
  const std::string down = (dir / "down.vdb").string();
  WriteBlenderVdb(down, v, grey, -Eigen::Vector3d::UnitY());
  openvdb::io::File down_file(down);
  down_file.open();
  const auto down_grid =
      openvdb::gridPtrCast<openvdb::FloatGrid>(down_file.readGrid("temperature"));
  const openvdb::MetaMap::Ptr meta = down_file.getMetadata();
  down_file.close();
  ASSERT_TRUE(down_grid && meta);
  const openvdb::Vec3d turned = down_grid->indexToWorld(openvdb::Vec3d(1, 4, 2));
  EXPECT_NEAR(turned.x(), rig.x(), 1e-9);
  EXPECT_NEAR(turned.y(), rig.z(), 1e-9);
  EXPECT_NEAR(turned.z(), -rig.y(), 1e-9);
  EXPECT_EQ(meta->metaValue<double>("frame"), 7);
  EXPECT_EQ(meta->metaValue<double>("source_frame_id"), 1234);
  // Any other up: taken to Blender's +z by a rotation (lengths and handedness kept).
  const Eigen::Vector3d tilted = Eigen::Vector3d(1, 2, 2) / 3;
  WriteBlenderVdb(down, v, grey, tilted);
  openvdb::io::File tilted_file(down);
  tilted_file.open();
  const auto tilted_grid =
      openvdb::gridPtrCast<openvdb::FloatGrid>(tilted_file.readGrid("temperature"));
  tilted_file.close();
  const Eigen::Vector3d c0 = v.geometry.VoxelCenter(0, 0, 0);
  auto world_of = [&](const Eigen::Vector3d& ijk) {
    const openvdb::Vec3d w = tilted_grid->indexToWorld(openvdb::Vec3d(ijk.x(), ijk.y(), ijk.z()));
    return Eigen::Vector3d(w.x(), w.y(), w.z());
  };
  // The index step that moves along `tilted` in the rig moves along Blender's +z.
  const Eigen::Vector3d step = tilted.cwiseQuotient(v.geometry.voxel_size_m);
  const Eigen::Vector3d along = world_of(step) - world_of(Eigen::Vector3d::Zero());
  EXPECT_NEAR(along.norm(), 1.0, 1e-9);
  EXPECT_NEAR(along.z(), 1.0, 1e-9);
  EXPECT_NEAR(world_of(Eigen::Vector3d::Zero()).norm(), c0.norm(), 1e-9) << "not a rotation";
  fs::remove_all(dir);
}

}  // namespace
}  // namespace flamerig
