// The calibrate job (`flamerig calibrate`): the rig, its models at full precision and the report
// from the calibration tests' ring; config errors name the file and key.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <regex>
#include <string>

#include "pipeline/calibrate_job.h"
#include "tests/calibration_ring.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

// The simulated rig's calibration config (config/calibrate_sim.yaml).
CalibrateConfig SimConfig() {
  return CalibrateConfig::Load(std::string(FLAMERIG_SOURCE_DIR) + "/config/calibrate_sim.yaml");
}

std::string ReadText(const fs::path& path) {
  std::ifstream in(path);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

TEST_F(Ring, WritesARigThatLoadsAndAReport) {
  const fs::path out = TempDir("job");
  CalibrateConfig config = SimConfig();
  // The board given is the one beside the views: no warning that they differ.
  config.board = LoadBoardSpec((*dir_ / "calibration" / "board.yaml").string());
  // The valid-intrinsics region at a working distance rather than mrcal's infinity.
  config.valid_region.distance_m = 0.3;
  const CalibrationSummary s =
      RunCalibration(config, CalibrateInput{(*dir_ / "calibration").string(), ""}, out.string());
  for (const auto& note : s.notes)
    EXPECT_EQ(note.find("is not the one"), std::string::npos) << note;
  const Rig rig = Rig::Load((out / "rig.yaml").string());
  ASSERT_EQ(rig.cameras.size(), 4u);
  EXPECT_EQ(rig.box.min_in_rig, config.options.box.min_in_rig);
  // Each model carries the solve for mrcal's tools (read back by mrcal in
  // calibration_mrcal_inputs_test and pipeline_calibrate_rigs_test), its own camera's index.
  for (int c = 0; c < 4; ++c) {
    const std::string model =
        ReadText(out / "cameras" / ("cam" + std::to_string(c) + ".cameramodel"));
    EXPECT_NE(model.find("'icam_intrinsics': " + std::to_string(c) + ","), std::string::npos);
    EXPECT_NE(model.find("'optimization_inputs': b'"), std::string::npos);
    // And the valid-intrinsics region mrcal-calibrate-cameras would write (compared with the
    // tool's own in pipeline_calibrate_rigs_test), here empty or not.
    EXPECT_NE(model.find("'valid_intrinsics_region': ["), std::string::npos) << c;
    EXPECT_NE(model.find("--valid-intrinsics-region-parameters 1 0.5 1.5 3 0.3)"),
              std::string::npos)
        << c;
  }
  for (const auto& note : s.notes)
    EXPECT_EQ(note.find("no valid-intrinsics region"), std::string::npos) << note;
  // The models on disk are the solved ones, at full precision.
  for (std::size_t c = 0; c < 4; ++c)
    for (std::size_t i = 0; i < rig.cameras[c].model.intrinsics().size(); ++i)
      EXPECT_EQ(rig.cameras[c].model.intrinsics()[i], s.rig.cameras[c].model.intrinsics()[i]);
  for (const char* f :
       {"report.md", "rig_top.png", "coverage_cam0.png", "coverage_cam3.png", "residuals_cam0.png",
        "per_image_cam3.png", "corners.vnl", "detections.cache"})
    EXPECT_TRUE(fs::exists(out / f)) << f;
  const std::string text = ReadText(out / "report.md");
  EXPECT_NE(text.find("per coordinate"), std::string::npos);
  EXPECT_NE(text.find("Worst corners"), std::string::npos);
  EXPECT_NE(text.find("## Images without a board"), std::string::npos);
  EXPECT_NE(text.find("## Corners found but left out"), std::string::npos);
  EXPECT_NE(text.find("mrcal counts"), std::string::npos);
  EXPECT_NE(text.find("## Projection uncertainty over the box"), std::string::npos);
  EXPECT_NE(text.find("| max voxels |"), std::string::npos);
  EXPECT_NE(text.find("--valid-intrinsics-region-parameters 1 0.5 1.5 3 0.3): where the "
                      "projection at 0.3 m is certain"),
            std::string::npos)
      << text;
  // Each camera's row ends with the share of its image in the region (a percentage).
  EXPECT_TRUE(
      std::regex_search(text, std::regex("\\| cam2 \\|[^\n]* \\| [0-9]+% \\| [0-9]+% \\|\n")))
      << text;
  // A row of the uncertainty table: four cells, all numbers.
  EXPECT_TRUE(
      std::regex_search(text, std::regex("\\| cam3 \\| [0-9.]+ \\| [0-9.]+ \\| [0-9.]+ \\|\n")))
      << text;
  fs::remove_all(out);
}

// A board given with squares 1.5 times those of the board.yaml beside the views (and of the board
// filmed): the solve cannot tell, and the rig comes out 1.5 times too large, so the report warns.
TEST_F(Ring, ABoardGivenThatIsNotTheOneBesideTheViewsIsAWarning) {
  const fs::path out = TempDir("scaled");
  CalibrateConfig config = SimConfig();
  config.uncertainty_trials = 0;
  BoardSpec board = LoadBoardSpec((*dir_ / "calibration" / "board.yaml").string());
  ASSERT_EQ(board.square_m, 0.012);
  board.square_m = 0.018;
  board.marker_m = 0.0135;
  config.board = board;
  const CalibrationSummary s =
      RunCalibration(config, CalibrateInput{(*dir_ / "calibration").string(), ""}, out.string());
  // The oracle for the scale: the simulator's true rig.
  const Eigen::Vector3d truth =
      truth_->cameras[0].model.center_in_rig() - truth_->cameras[2].model.center_in_rig();
  const Eigen::Vector3d solved =
      s.rig.cameras[0].model.center_in_rig() - s.rig.cameras[2].model.center_in_rig();
  EXPECT_NEAR(solved.norm() / truth.norm(), 1.5, 0.01);
  std::string warning;
  for (const auto& note : s.notes)
    if (note.find("is not the one") != std::string::npos) warning = note;
  EXPECT_NE(warning.find("WARNING: the board given (charuco"), std::string::npos) << warning;
  EXPECT_NE(warning.find("squares of 0.018 m"), std::string::npos) << warning;
  EXPECT_NE(warning.find("board.yaml describes (charuco"), std::string::npos) << warning;
  EXPECT_NE(warning.find("squares of 0.012 m"), std::string::npos) << warning;
  const std::string text = ReadText(out / "report.md");
  EXPECT_NE(text.find("a wrong square size scales the whole rig"), std::string::npos);
  fs::remove_all(out);
}

// Calibrating fewer cameras into a folder that holds a larger rig: the cameras that are gone
// leave no model or picture behind (mrcal's tools take cameras/*.cameramodel), and files the
// calibration did not write stay.
TEST_F(Ring, ACameraLessLeavesNoStaleModel) {
  const fs::path out = TempDir("fewer");
  CalibrateConfig config = SimConfig();
  config.uncertainty_trials = 0;
  const CalibrateInput input{(*dir_ / "calibration").string(), ""};
  RunCalibration(config, input, out.string());
  ASSERT_TRUE(fs::exists(out / "cameras" / "cam3.cameramodel"));
  ASSERT_TRUE(fs::exists(out / "coverage_cam3.png"));
  std::ofstream(out / "cameras" / "notes.txt") << "lens serials\n";
  config.cameras = {"cam0", "cam1", "cam2"};
  RunCalibration(config, input, out.string());
  EXPECT_EQ(Rig::Load((out / "rig.yaml").string()).cameras.size(), 3u);
  for (const char* gone : {"cameras/cam3.cameramodel", "coverage_cam3.png", "residuals_cam3.png",
                           "per_image_cam3.png"})
    EXPECT_FALSE(fs::exists(out / gone)) << gone;
  for (const char* kept : {"cameras/cam2.cameramodel", "coverage_cam2.png", "cameras/notes.txt"})
    EXPECT_TRUE(fs::exists(out / kept)) << kept;
  // A rig.yaml edited to take cam2's model from elsewhere: that file is not calibrate's to remove.
  const fs::path elsewhere = TempDir("elsewhere");
  fs::copy_file(out / "cameras" / "cam2.cameramodel", elsewhere / "cam2.cameramodel");
  std::string yaml = ReadText(out / "rig.yaml");
  const std::string from = "cameras/cam2.cameramodel";
  ASSERT_NE(yaml.find(from), std::string::npos) << yaml;
  yaml.replace(yaml.find(from), from.size(), (elsewhere / "cam2.cameramodel").string());
  std::ofstream(out / "rig.yaml", std::ios::trunc) << yaml;
  config.cameras = {"cam0", "cam1"};
  RunCalibration(config, input, out.string());
  EXPECT_TRUE(fs::exists(elsewhere / "cam2.cameramodel"));
  EXPECT_FALSE(fs::exists(out / "coverage_cam2.png"));
  fs::remove_all(elsewhere);
  fs::remove_all(out);
}

TEST(CalibrateConfig, ErrorsNameTheFileAndKey) {
  const fs::path dir = TempDir("config");
  auto write = [&](const std::string& text) {
    std::ofstream((dir / "c.yaml").string()) << text;
    return ErrorOf([&] { CalibrateConfig::Load((dir / "c.yaml").string()); });
  };
  EXPECT_NE(write("calibrate: {lensmodel: LENSMODEL_NOPE}\n").find("LENSMODEL_NOPE"),
            std::string::npos);
  EXPECT_NE(write("calibrate: {frame: sideways}\n").find("'frame'"), std::string::npos);
  EXPECT_NE(write("calibrate: {bogus: 1}\n").find("unknown key 'bogus'"), std::string::npos);
  EXPECT_NE(write("calibrate: {box: {min: [0, 0, 0], max: [1, -1, 1]}}\n").find("box"),
            std::string::npos);
  std::string d = write("calibrate: {detect: {detector: mrgingham}}\n");
  EXPECT_NE(d.find("calibrate.detect"), std::string::npos) << d;
  EXPECT_NE(d.find("mrgingham"), std::string::npos) << d;
  d = write("calibrate: {detect: {subpix_iterations: 0}}\n");
  EXPECT_NE(d.find("subpix_iterations"), std::string::npos) << d;
  d = write("calibrate: {detect: {windows: 3}}\n");
  EXPECT_NE(d.find("unknown key 'windows'"), std::string::npos) << d;
  // A file that is not there says so (yaml-cpp says "bad file"), for the board's too.
  d = ErrorOf([&] { CalibrateConfig::Load((dir / "none.yaml").string()); });
  EXPECT_NE(d.find("none.yaml: no such file"), std::string::npos) << d;
  d = ErrorOf([&] { LoadBoardSpec((dir / "no_board.yaml").string()); });
  EXPECT_NE(d.find("no_board.yaml: no such file"), std::string::npos) << d;
  const CalibrateConfig classic = [&] {
    std::ofstream((dir / "ok.yaml").string())
        << "calibrate: {board_warp: false, detect: {detector: classic, subpix_half_window: 4}}\n";
    return CalibrateConfig::Load((dir / "ok.yaml").string());
  }();
  EXPECT_FALSE(classic.options.board_warp);
  EXPECT_EQ(classic.detect.detector, ChessboardDetector::kClassic);
  EXPECT_EQ(classic.detect.subpix_half_window, 4);
  const std::string e = write("calibrate: {board: {type: chessboard, squares: [8, 6]}}\n");
  EXPECT_NE(e.find("c.yaml"), std::string::npos) << e;
  EXPECT_NE(e.find("one odd and one even"), std::string::npos) << e;
  // Lens models mrcal names but cannot solve (it aborts on them), refused with the rule.
  d = write("calibrate: {lensmodel: LENSMODEL_CAHVORE_linearity=0.00}\n");
  EXPECT_NE(d.find("c.yaml: calibrate.lensmodel"), std::string::npos) << d;
  EXPECT_NE(d.find("no gradients"), std::string::npos) << d;
  d = write(
      "calibrate: {lensmodel: LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=3_Ny=3_fov_x_deg=200}\n");
  EXPECT_NE(d.find("Nx and Ny must be at least 4 for order 3"), std::string::npos) << d;
  d = write(
      "calibrate: {lensmodel: LENSMODEL_SPLINED_STEREOGRAPHIC_order=4_Nx=9_Ny=9_fov_x_deg=200}\n");
  EXPECT_NE(d.find("order must be 2 or 3"), std::string::npos) << d;
  EXPECT_EQ(write("calibrate: {lensmodel: "
                  "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=4_Ny=4_fov_x_deg=200}\n"),
            "(no error)");
  EXPECT_EQ(write("calibrate: {lensmodel: LENSMODEL_CAHVOR}\n"), "(no error)");
  // A focal length no lens has, a name that is empty, a box that is not finite.
  d = write("calibrate: {focal_px: 1e308}\n");
  EXPECT_NE(d.find("calibrate.focal_px"), std::string::npos) << d;
  d = write("calibrate: {name: ''}\n");
  EXPECT_NE(d.find("calibrate.name: must not be empty"), std::string::npos) << d;
  d = write("calibrate: {box: {min: [0, .nan, 0], max: [1, 1, 1]}}\n");
  EXPECT_NE(d.find("box: min and max must be finite"), std::string::npos) << d;
  // mrcal-calibrate-cameras's five numbers for the valid-intrinsics region, each rule named.
  const std::string key = "c.yaml: calibrate.valid_intrinsics_region_parameters: ";
  d = write("calibrate: {valid_intrinsics_region_parameters: [1, 0.5, 1.5, 3]}\n");
  EXPECT_NE(d.find(key + "needs mrcal's five numbers"), std::string::npos) << d;
  d = write("calibrate: {valid_intrinsics_region_parameters: [1, 0.5, 1.5, 2.5, 0]}\n");
  EXPECT_NE(d.find(key + "the count (the fourth number) must be a whole number"), std::string::npos)
      << d;
  d = write("calibrate: {valid_intrinsics_region_parameters: [1, 0.5, 1.5, 3, -0.3]}\n");
  EXPECT_NE(d.find(key + "the distance (the fifth number) must be 0"), std::string::npos) << d;
  d = write("calibrate: {valid_intrinsics_region_parameters: [0, 0.5, 1.5, 3, 0]}\n");
  EXPECT_NE(d.find(key + "the thresholds"), std::string::npos) << d;
  d = write("calibrate: {valid_intrinsics_region_parameters: [1, .nan, 1.5, 3, 0]}\n");
  EXPECT_NE(d.find(key + "nan is not finite"), std::string::npos) << d;
  d = write("calibrate: {valid_intrinsics_region_parameters: 3}\n");
  EXPECT_NE(d.find("valid_intrinsics_region_parameters"), std::string::npos) << d;
  EXPECT_EQ(CalibrateConfig::Load((dir / "ok.yaml").string()).valid_region.ToMrcal(),
            "1 0.5 1.5 3 0");
  std::ofstream((dir / "near.yaml").string())
      << "calibrate: {valid_intrinsics_region_parameters: [2, 0.25, 1, 5, 0.3]}\n";
  const ValidRegionParameters near =
      CalibrateConfig::Load((dir / "near.yaml").string()).valid_region;
  EXPECT_EQ(near.uncertainty, 2);
  EXPECT_EQ(near.mean, 0.25);
  EXPECT_EQ(near.stdev, 1);
  EXPECT_EQ(near.count, 5);
  EXPECT_EQ(near.distance_m, 0.3);
  EXPECT_EQ(near.DistanceText(), "at 0.3 m");
  fs::remove_all(dir);
}

// A calibration that fails leaves the one already in OUT whole (its corners.vnl included); a
// simulated dataset's folder, whose rig is the truth, is refused as OUT; a camera listed twice is
// named.
TEST_F(Ring, AFailedRunKeepsTheEarlierCalibrationAndTheTruthIsNotOverwritten) {
  const fs::path out = TempDir("keep");
  CalibrateConfig config = SimConfig();
  config.uncertainty_trials = 0;
  RunCalibration(config, CalibrateInput{(*dir_ / "calibration").string(), ""}, out.string());
  const std::string corners = ReadText(out / "corners.vnl"), rig = ReadText(out / "rig.yaml");
  ASSERT_FALSE(corners.empty());
  // Two views: too few for any camera.
  const fs::path few = TempDir("few");
  fs::copy_file(*dir_ / "calibration" / "board.yaml", few / "board.yaml");
  int copied = 0;
  for (const auto& v : fs::directory_iterator(*dir_ / "calibration"))
    if (v.is_directory() && copied++ < 2)
      fs::copy(v.path(), few / v.path().filename(), fs::copy_options::recursive);
  const std::string e = ErrorOf([&] {
    RunCalibration(config, CalibrateInput{few.string(), ""}, out.string());
  });
  EXPECT_NE(e.find("views"), std::string::npos) << e;
  EXPECT_EQ(ReadText(out / "corners.vnl"), corners);
  EXPECT_EQ(ReadText(out / "rig.yaml"), rig);

  // Stopped after the uncertainty's last solve, or just before writing: the earlier calibration
  // (its models and report too) stays as it was, and no staging folder is left.
  const std::string model = ReadText(out / "cameras" / "cam2.cameramodel"),
                    report = ReadText(out / "report.md");
  for (const std::string stop : {"uncertainty", "write"}) {
    CalibrateConfig with_uncertainty = config;
    with_uncertainty.uncertainty_trials = 3;
    const std::string cancelled = ErrorOf([&] {
      RunCalibration(with_uncertainty, CalibrateInput{(*dir_ / "calibration").string(), ""},
                     out.string(), [&](const Progress& p) {
                       return p.stage == stop && (stop == "write" || p.done == 3)
                                  ? ProgressAction::kCancel
                                  : ProgressAction::kContinue;
                     });
    });
    EXPECT_NE(cancelled.find("the calibration is not written"), std::string::npos) << cancelled;
    EXPECT_EQ(ReadText(out / "rig.yaml"), rig) << stop;
    EXPECT_EQ(ReadText(out / "cameras" / "cam2.cameramodel"), model) << stop;
    EXPECT_EQ(ReadText(out / "report.md"), report) << stop;
    EXPECT_FALSE(fs::exists(out / ".calibrate-partial")) << stop;
  }

  std::ofstream(out / "dataset.yaml") << "seed: 1\n";
  const std::string truth = ErrorOf([&] {
    RunCalibration(config, CalibrateInput{(*dir_ / "calibration").string(), ""}, out.string());
  });
  EXPECT_NE(truth.find("holds a simulated dataset"), std::string::npos) << truth;
  EXPECT_EQ(ReadText(out / "rig.yaml"), rig);
  fs::remove(out / "dataset.yaml");

  const std::string none = ErrorOf([&] {
    RunCalibration(config, CalibrateInput{(few / "none").string(), ""}, out.string());
  });
  EXPECT_NE(none.find("none is not a folder"), std::string::npos) << none;

  config.cameras = {"cam0", "cam1", "cam0"};
  const std::string twice = ErrorOf([&] {
    RunCalibration(config, CalibrateInput{(*dir_ / "calibration").string(), ""}, out.string());
  });
  EXPECT_NE(twice.find("camera cam0 is listed twice"), std::string::npos) << twice;
  fs::remove_all(out);
  fs::remove_all(few);
}

}  // namespace
}  // namespace flamerig
