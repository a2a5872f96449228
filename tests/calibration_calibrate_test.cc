// Calibration against known truth: a 4-camera ring (tests/calibration_ring.h: cameras 90 degrees
// apart, boards seen by neighbours only, plus close-ups), boards rendered and detected in images;
// mrcal's own tool on the same detections; and bad input.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/file.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <opencv2/imgproc.hpp>
#include <random>
#include <regex>
#include <set>

#include <yaml-cpp/yaml.h>

#include "acquisition/recording.h"
#include "calibration/calibrate.h"
#include "calibration/synthetic_rig.h"
#include "tests/calibration_ring.h"

namespace flamerig {
namespace {

double AngleDeg(const Eigen::Quaterniond& a, const Eigen::Quaterniond& b) {
  return Eigen::AngleAxisd(a.inverse() * b).angle() * kRadToDeg;
}

// Relative poses cam_i_from_cam_0 do not depend on the rig frame: compare them with the truth.
void ExpectExtrinsicsNear(const Rig& got, const Rig& truth, double max_deg, double max_m) {
  ASSERT_EQ(got.cameras.size(), truth.cameras.size());
  const Rigid3 g0 = got.cameras[0].model.cam_from_rig(), t0 = truth.cameras[0].model.cam_from_rig();
  for (std::size_t c = 1; c < got.cameras.size(); ++c) {
    const Rigid3 g = got.cameras[c].model.cam_from_rig() * g0.Inverse();
    const Rigid3 t = truth.cameras[c].model.cam_from_rig() * t0.Inverse();
    EXPECT_LT(AngleDeg(g.rotation, t.rotation), max_deg) << got.cameras[c].name;
    EXPECT_LT((g.translation - t.translation).norm(), max_m) << got.cameras[c].name;
  }
}

// The worst pixel disagreement between two models of one camera over points of the reconstruction
// box, each model in its own rig frame (`got_from_truth` maps truth rig points to the other).
double WorstProjectionDifferencePx(const CameraModel& got, const CameraModel& truth,
                                   const Box3& box, const Rigid3& got_from_truth) {
  double worst = 0;
  for (int i = 0; i <= 4; ++i)
    for (int j = 0; j <= 4; ++j)
      for (int k = 0; k <= 4; ++k) {
        const Eigen::Vector3d p =
            box.min_in_rig + box.size().cwiseProduct(Eigen::Vector3d(i, j, k) / 4.0);
        worst = std::max(worst, (got.Project(got_from_truth * p) - truth.Project(p)).norm());
      }
  return worst;
}

TEST_F(Ring, RecoversTheRingFromRenderedImages) {
  const CalibrationData data = Detect();
  ASSERT_EQ(data.camera_names.size(), 4u);
  // No view is seen by all cameras, and some by one camera only (close-ups).
  std::map<int, int> cameras_per_view;
  for (const auto& o : data.observations) ++cameras_per_view[o.view];
  int singles = 0, most = 0;
  for (const auto& [v, n] : cameras_per_view) {
    singles += n == 1;
    most = std::max(most, n);
  }
  EXPECT_GT(singles, 0);
  EXPECT_LE(most, 2);

  CalibrationOptions options;
  options.frame = RigFrame::kRing;
  options.ring_origin_m = -Eigen::Vector3d(0, 0.035, 0);  // the simulated box centre
  const CalibrationSummary s = Calibrate(data, options);
  // Rendered boards with sensor noise: corners to about a tenth of a pixel.
  EXPECT_LT(s.rms_px_per_point, 0.3);
  EXPECT_NEAR(s.rms_px_per_coordinate * std::sqrt(2.0), s.rms_px_per_point, 1e-9);
  // Our residuals, recomputed through our camera models, agree with mrcal's own figure.
  EXPECT_NEAR(s.rms_px_per_coordinate, s.mrcal_rms_px, 0.25 * s.mrcal_rms_px);
  // The bar: 0.1 degree and 3 mm (measured: 0.073 degree and 0.46 mm at worst). It holds
  // because the shared views vary in depth and tilt; boards all at the ring's centre and nearly
  // square-on to both cameras gave 0.2 degree (rotation trades against translation).
  ExpectExtrinsicsNear(s.rig, *truth_, 0.1, 0.003);
  // The ring frame is the simulated rig frame (both: y up, z towards cam0, origin as set).
  for (std::size_t c = 0; c < 4; ++c) {
    const Rigid3& g = s.rig.cameras[c].model.cam_from_rig();
    const Rigid3& t = truth_->cameras[c].model.cam_from_rig();
    EXPECT_LT(AngleDeg(g.rotation, t.rotation), 0.2) << c;
    EXPECT_LT(
        (s.rig.cameras[c].model.center_in_rig() - truth_->cameras[c].model.center_in_rig()).norm(),
        0.004)
        << c;
    // Where the box projects, each model in its own rig frame: within a pixel everywhere (this
    // includes the ring frame's own error, from noisy optical axes).
    EXPECT_LT(WorstProjectionDifferencePx(s.rig.cameras[c].model, truth_->cameras[c].model,
                                          truth_->box, Rigid3()),
              1.0)
        << c;
    // The principal point within 2 px (it trades against rotation; measured about 1 px).
    EXPECT_NEAR(s.rig.cameras[c].model.intrinsics()[2], truth_->cameras[c].model.intrinsics()[2],
                2.0);
    EXPECT_NEAR(s.rig.cameras[c].model.intrinsics()[3], truth_->cameras[c].model.intrinsics()[3],
                2.0);
    const auto& gi = s.rig.cameras[c].model.intrinsics();
    const auto& ti = truth_->cameras[c].model.intrinsics();
    EXPECT_NEAR(gi[0] / ti[0], 1.0, 0.002) << "fx of camera " << c;  // measured 0.01 %
    EXPECT_NEAR(gi[1] / ti[1], 1.0, 0.002) << "fy of camera " << c;
  }
}

// With exact corners (projected through the true models) the solve must give back the truth to
// solver precision: a check of the whole mrcal plumbing (board layout, frames, gauge).
TEST_F(Ring, ExactCornersGiveTheTruthBack) {
  const CalibrationData data = ExactCorners(Detect(), *dir_ / "calibration", *truth_);
  YAML::Node views = YAML::LoadFile((*dir_ / "calibration" / "board.yaml").string())["views"];
  std::map<std::string, Rigid3> pose;
  for (const auto& v : views) {
    std::array<double, 6> rt;
    for (int i = 0; i < 6; ++i) rt[i] = v["rt_rig_from_board"][i].as<double>();
    pose[v["name"].as<std::string>()] = Rigid3::FromRt(rt);
  }
  CalibrationOptions options;
  options.outlier_rejection = false;  // notes/mrcal.md: it misfires on exact corners
  options.regularization = false;     // it pulls the (true, non-zero) distortion towards zero
  options.frame = RigFrame::kRing;
  options.ring_origin_m = -Eigen::Vector3d(0, 0.035, 0);
  const CalibrationSummary s = Calibrate(data, options);
  EXPECT_LT(s.rms_px_per_point, 1e-4);
  EXPECT_EQ(s.outliers, 0);
  ExpectExtrinsicsNear(s.rig, *truth_, 1e-5, 1e-7);
  for (std::size_t c = 0; c < 4; ++c) {
    const auto& gi = s.rig.cameras[c].model.intrinsics();
    const auto& ti = truth_->cameras[c].model.intrinsics();
    for (std::size_t i = 0; i < 4; ++i) EXPECT_NEAR(gi[i], ti[i], 1e-3) << c << " " << i;
    EXPECT_LT(WorstProjectionDifferencePx(s.rig.cameras[c].model, truth_->cameras[c].model,
                                          truth_->box, Rigid3()),
              1e-3);
  }
  // The board poses come back too.
  for (std::size_t v = 0; v < data.view_names.size(); ++v) {
    if (!s.view_used[v]) continue;
    const Rigid3& t = pose.at(data.view_names[v]);
    EXPECT_LT((s.rig_from_board[v].translation - t.translation).norm(), 1e-6);
  }
}

// The expected noise of the intrinsics, by Monte Carlo (mrcal's uncertainty is only in its Python
// tools): exact corners plus Gaussian noise at the rendered corners' RMS, solved 40 times (6 gave
// standard deviations that varied by a factor of two from one seed to the next). The rendered
// solve's intrinsics must lie within 5 standard deviations (plus 0.05 px) of the truth. Measured
// 2026-11-24: every parameter within 1.6 sd but cam3's focal length, 3.9 to 4.4 sd (0.09%) low
// with either consistency check (the global homography this replaced or the local one): a bias
// of the ChArUco corners detected in these rendered images, not of the solve (exact corners give
// the truth back), and not yet explained.
TEST_F(Ring, IntrinsicsAreWithinTheirExpectedNoise) {
  const CalibrationData rendered = Detect();
  CalibrationOptions options;
  options.frame = RigFrame::kRing;
  options.ring_origin_m = -Eigen::Vector3d(0, 0.035, 0);
  const CalibrationSummary s = Calibrate(rendered, options);
  const double sigma_px = s.rms_px_per_coordinate;
  const CalibrationData exact = ExactCorners(rendered, *dir_ / "calibration", *truth_);
  std::mt19937_64 rng(99);
  std::normal_distribution<double> noise(0.0, sigma_px);
  const int trials = 40;
  std::vector<std::array<double, 4>> sum(4, {0, 0, 0, 0}), sum_sq(4, {0, 0, 0, 0});
  for (int t = 0; t < trials; ++t) {
    CalibrationData d = exact;
    for (auto& o : d.observations)
      for (auto& p : o.detection.corners_px) p += Eigen::Vector2d(noise(rng), noise(rng));
    const CalibrationSummary trial = Calibrate(d, options);
    for (int c = 0; c < 4; ++c)
      for (int i = 0; i < 4; ++i) {
        const double v = trial.rig.cameras[c].model.intrinsics()[i];
        sum[c][i] += v;
        sum_sq[c][i] += v * v;
      }
  }
  for (int c = 0; c < 4; ++c)
    for (int i = 0; i < 4; ++i) {
      const double mean = sum[c][i] / trials;
      const double sd =
          std::sqrt(std::max(0.0, sum_sq[c][i] / trials - mean * mean) * trials / (trials - 1));
      const double got = s.rig.cameras[c].model.intrinsics()[i];
      const double want = truth_->cameras[c].model.intrinsics()[i];
      std::fprintf(stderr, "cam%d %s: truth %.3f rendered %.3f (%.2f sd), noise sd %.3f\n", c,
                   std::array<const char*, 4>{"fx", "fy", "cx", "cy"}[i], want, got,
                   (got - want) / sd, sd);
      EXPECT_LT(std::abs(got - want), 5 * sd + 0.05) << "camera " << c << " parameter " << i;
    }
}

// mrcal's own tool, run on our detections, agrees with our solve: the same RMS within 1%, camera
// rotations within 0.01 degree and positions within 0.1 mm, with the board's warp solved (as
// the tool does by default) and without it.
void ExpectTheToolAgrees(const CalibrationData& data, bool warp) {
  CalibrationOptions options;
  options.board_warp = warp;
  const CalibrationSummary ours = Calibrate(data, options);
  const fs::path work = TempDir(warp ? "mrcal_tool_warp" : "mrcal_tool");
  WriteMrcalCorners(data, (work / "corners.vnl").string(), "views");
  std::string cmd = "cd " + work.string() +
                    " && mrcal-calibrate-cameras --corners-cache corners.vnl --lensmodel "
                    "LENSMODEL_OPENCV8 --focal 700 --imagersize 640 480 --object-spacing " +
                    std::to_string(data.board.square_m) + " --object-width-n " +
                    std::to_string(data.board.corners_x()) + " --object-height-n " +
                    std::to_string(data.board.corners_y()) +
                    (warp ? "" : " --skip-calobject-warp-solve") + " --outdir " + work.string();
  for (const auto& name : data.camera_names) cmd += " 'views/*/" + name + ".png'";
  cmd += " > tool.log 2>&1";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << "see " << (work / "tool.log");
  std::ifstream log(work / "tool.log");
  std::string text((std::istreambuf_iterator<char>(log)), std::istreambuf_iterator<char>());
  // The tool prints "## RMS error: X" after each stage, the final one last (its summary line
  // rounds to one decimal).
  double tool_rms = -1;
  const std::regex stage_rms("## RMS error: ([0-9.eE+-]+)");
  for (auto it = std::sregex_iterator(text.begin(), text.end(), stage_rms);
       it != std::sregex_iterator(); ++it)
    tool_rms = std::stod((*it)[1]);
  ASSERT_GT(tool_rms, 0) << text;
  // mrcal prints the RMS per coordinate; ours is recomputed through our own models (and, with
  // warp, our own bowed board), so agreement checks both.
  std::fprintf(stderr, "warp %d: tool RMS %.6f, ours %.6f (mrcal_optimize's figure %.6f)\n", warp,
               tool_rms, ours.rms_px_per_coordinate, ours.mrcal_rms_px);
  EXPECT_NEAR(ours.mrcal_rms_px, tool_rms, 0.01 * tool_rms) << text;
  // mrcal's figure divides by every corner of every board observation, the outliers and the
  // corners not detected included (their residuals are zero); ours by the inliers only.
  const double inliers = ours.points - ours.outliers, all = ours.points + ours.missing_corners;
  EXPECT_EQ(ours.mrcal_outliers, ours.outliers + ours.missing_corners);
  EXPECT_NEAR(ours.rms_px_per_coordinate * std::sqrt(inliers / all), tool_rms, 0.01 * tool_rms)
      << text;
  if (warp) {
    // The tool writes the warp it solved into each model's optimization_inputs.
    const std::string py =
        "/usr/bin/python3 -c \"import mrcal,glob; "
        "m=mrcal.cameramodel(sorted(glob.glob('" +
        work.string() +
        "/*.cameramodel'))[0]); "
        "print(*m.optimization_inputs()['calobject_warp'])\" > " +
        (work / "warp.txt").string();
    ASSERT_EQ(std::system(py.c_str()), 0);
    std::ifstream in(work / "warp.txt");
    double x2 = 0, y2 = 0;
    ASSERT_TRUE(in >> x2 >> y2);
    EXPECT_NEAR(ours.board_warp_x_m, x2, 2e-6 + 0.01 * std::abs(x2));
    EXPECT_NEAR(ours.board_warp_y_m, y2, 2e-6 + 0.01 * std::abs(y2));
  } else {
    EXPECT_EQ(ours.board_warp_x_m, 0);
    EXPECT_EQ(ours.board_warp_y_m, 0);
  }
  std::vector<fs::path> models;
  for (const auto& e : fs::directory_iterator(work))
    if (e.path().extension() == ".cameramodel") models.push_back(e.path());
  std::sort(models.begin(), models.end());
  ASSERT_EQ(models.size(), 4u) << text;
  Rig tool;
  for (std::size_t c = 0; c < models.size(); ++c)
    tool.cameras.push_back(RigCamera{data.camera_names[c], "", CameraModel::Load(models[c]), {}});
  ExpectExtrinsicsNear(ours.rig, tool, 0.01, 0.0001);
  for (std::size_t c = 0; c < 4; ++c) {
    const auto& a = ours.rig.cameras[c].model.intrinsics();
    const auto& b = tool.cameras[c].model.intrinsics();
    EXPECT_NEAR(a[0] / b[0], 1.0, 0.002) << c;
    EXPECT_NEAR(a[2], b[2], 0.5) << c;
    EXPECT_NEAR(a[3], b[3], 0.5) << c;
  }
  fs::remove_all(work);
}

TEST_F(Ring, AgreesWithMrcalCalibrateCameras) {
  if (std::system("command -v mrcal-calibrate-cameras > /dev/null 2>&1") != 0)
    GTEST_SKIP() << "mrcal-calibrate-cameras is not installed (Debian package mrcal)";
  // Whole boards only: with partial (ChArUco) views the tool solves, then fails computing its
  // valid-intrinsics region ("factorization computation failed") and writes no models.
  CalibrationData data = Detect();
  std::erase_if(data.observations, [&](const BoardObservation& o) {
    return static_cast<int>(o.detection.corner_ids.size()) < data.board.num_corners();
  });
  ExpectTheToolAgrees(data, false);
  ExpectTheToolAgrees(data, true);
}

TEST_F(Ring, SecondRunDetectsNothingAgain) {
  const fs::path work = TempDir("cache");
  const std::string cache = (work / "detections.cache").string();
  const CalibrationData first = Detect(cache);
  EXPECT_EQ(first.from_cache, 0);
  EXPECT_GT(first.detected, 0);
  const CalibrationData second = Detect(cache);
  EXPECT_EQ(second.detected, 0);
  EXPECT_EQ(second.from_cache, first.detected);
  ASSERT_EQ(second.observations.size(), first.observations.size());
  for (std::size_t i = 0; i < first.observations.size(); ++i) {
    EXPECT_EQ(second.observations[i].detection.corner_ids,
              first.observations[i].detection.corner_ids);
    for (std::size_t k = 0; k < first.observations[i].detection.corners_px.size(); ++k)
      EXPECT_LT((second.observations[i].detection.corners_px[k] -
                 first.observations[i].detection.corners_px[k])
                    .norm(),
                1e-6);
    EXPECT_EQ(second.observations[i].detection.detector, "charuco");
    EXPECT_EQ(second.observations[i].detection.rejected.size(),
              first.observations[i].detection.rejected.size());
  }
  // Other detector settings detect again.
  DetectOptions tighter;
  tighter.max_misfit_squares = 0.05;
  const CalibrationData third = DetectViewsInFolder(
      (*dir_ / "calibration").string(),
      LoadBoardSpec((*dir_ / "calibration" / "board.yaml").string()), {}, cache, tighter);
  EXPECT_EQ(third.from_cache, 0);
  EXPECT_EQ(third.detected, first.detected);
  fs::remove_all(work);
}

// mrcal's corners file names each image with the extension it has (a .jpg stays a .jpg), and
// frames from a recording as .png.
TEST(WriteMrcalCorners, KeepsTheImagesExtension) {
  CalibrationData data;
  data.camera_names = {"left", "right"};
  data.view_names = {"v0"};
  BoardDetection d;
  d.corner_ids = {0};
  d.corners_px = {Eigen::Vector2d(1, 2)};
  data.observations.push_back(BoardObservation{0, 0, "/photos/v0/left.JPG", d});
  data.observations.push_back(BoardObservation{1, 0, "take set 0 camera right", d});
  const fs::path work = TempDir("vnl");
  WriteMrcalCorners(data, (work / "corners.vnl").string(), "views");
  std::ifstream in(work / "corners.vnl");
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("views/v0/left.JPG 1 2 0"), std::string::npos) << text;
  EXPECT_NE(text.find("views/v0/right.png 1 2 0"), std::string::npos) << text;
  fs::remove_all(work);
}

// The cache keeps the corners left out and why, and a damaged reject line never passes.
TEST(DetectionCache, KeepsRejectedCornersAndDropsBadLines) {
  BoardSpec board;  // ChArUco 7x5: 24 corners
  const DetectOptions detect;
  const std::string head = "# flamerig board detections v2\nboard " + board.Describe() +
                           "\ndetect " + detect.Describe() + "\n";
  std::map<std::string, BoardDetection> entries;
  const std::string six = " 6 0 1 1 1 2 1 2 3 1 4 4 1 5 5 1 6 6 1\n";  // corners 0, 1, 2, 4, 5, 6
  EXPECT_EQ(ParseDetectionCache(head + "a_1x1" + six + "a_1x1 detector charuco\n" +
                                    "a_1x1 reject 3 7.5 8.5 6.1 px from where its 8 neighbours\n" +
                                    "b_1x1" + six + "b_1x1 reject 99 7.5 8.5 not on the board\n" +
                                    "c_1x1" + six + "c_1x1 reject 3 nan 8.5 not finite\n",
                                board, detect, &entries),
            1);
  ASSERT_EQ(entries.count("a_1x1"), 1u);
  const BoardDetection& a = entries["a_1x1"];
  EXPECT_EQ(a.detector, "charuco");
  ASSERT_EQ(a.rejected.size(), 1u);
  EXPECT_EQ(a.rejected[0].corner_id, 3);
  EXPECT_EQ(a.rejected[0].px, Eigen::Vector2d(7.5, 8.5));
  EXPECT_EQ(a.rejected[0].reason, "6.1 px from where its 8 neighbours");
  // Lines DetectBoard could not have written are dropped with their image: fewer corners than it
  // keeps, anything after the corners, a corner both kept and rejected, an unknown detector.
  entries.clear();
  EXPECT_EQ(ParseDetectionCache(head + "short_1x1 2 0 1 2 5 3 4\n"
                                       "d_1x1 6 0 1 1 1 2 1 2 3 1 4 4 1 5 5 1 6 6 1\n"
                                       "junk_1x1 6 0 1 1 1 2 1 2 3 1 4 4 1 5 5 1 6 6 1 x 9\n"
                                       "both_1x1 6 0 1 1 1 2 1 2 3 1 4 4 1 5 5 1 6 6 1\n"
                                       "both_1x1 reject 2 1 1 kept and rejected\n"
                                       "who_1x1 6 0 1 1 1 2 1 2 3 1 4 4 1 5 5 1 6 6 1\n"
                                       "who_1x1 detector mrgingham\n",
                                board, detect, &entries),
            1);
  EXPECT_EQ(entries.count("d_1x1"), 1u);
  // Another detector setting: nothing is read.
  DetectOptions other;
  other.detector = ChessboardDetector::kClassic;
  entries.clear();
  EXPECT_EQ(ParseDetectionCache(head + "a_1x1" + six, board, other, &entries), 0);
}

// A calibration recording (frame sets with a camera missing where it did not see the board) gives
// the same detections as the folder of images.
TEST_F(Ring, ReadsARecording) {
  const CalibrationData folder = Detect();
  const fs::path rec_dir = TempDir("recording") / "take";
  RecordingMetadata meta;
  meta.sync_mode = "hardware-trigger";
  for (const auto& name : folder.camera_names) {
    RecordingCamera rc;
    rc.name = name;
    rc.settings.width = 640;
    rc.settings.height = 480;
    rc.settings.pixel_format = PixelFormat::kMono8;
    meta.cameras.push_back(rc);
  }
  {
    Recorder recorder(rec_dir.string(), meta);
    for (std::size_t v = 0; v < folder.view_names.size(); ++v) {
      FrameSet set;
      set.index = v;
      set.frames.resize(folder.camera_names.size());
      for (std::size_t c = 0; c < folder.camera_names.size(); ++c) {
        const fs::path img =
            *dir_ / "calibration" / folder.view_names[v] / (folder.camera_names[c] + ".png");
        if (!fs::exists(img)) continue;
        ImageU8 grey = ReadImageU8(img.string(), 1);
        Frame f;
        f.info.camera = static_cast<int>(c);
        f.info.frame_id = v;
        f.info.width = grey.width;
        f.info.height = grey.height;
        f.info.pixel_format = PixelFormat::kMono8;
        f.data = std::make_shared<std::vector<std::uint8_t>>(grey.pixels);
        set.frames[c] = std::move(f);
      }
      ASSERT_TRUE(recorder.Submit(set));
    }
    recorder.Close();
  }
  const CalibrationData rec = DetectViewsInRecording(rec_dir.string(), folder.board, {}, "");
  ASSERT_EQ(rec.observations.size(), folder.observations.size());
  for (std::size_t i = 0; i < rec.observations.size(); ++i) {
    EXPECT_EQ(rec.observations[i].camera, folder.observations[i].camera);
    EXPECT_EQ(rec.observations[i].view, folder.observations[i].view);
    EXPECT_EQ(rec.observations[i].detection.corner_ids,
              folder.observations[i].detection.corner_ids);
  }
  EXPECT_EQ(rec.unreadable, 0);
  // A damaged take costs the frames it touches (README, "Damage costs only the frames it
  // touches"): a flipped pixel byte in the first camera's last frame (its pixels end the data
  // file) leaves that frame out, named, and every other detection as it was. It stopped the whole
  // calibration until 2026-12-02.
  int last_view = -1;
  for (std::size_t v = 0; v < folder.view_names.size(); ++v)
    if (fs::exists(*dir_ / "calibration" / folder.view_names[v] /
                   (folder.camera_names[0] + ".png")))
      last_view = static_cast<int>(v);
  ASSERT_GE(last_view, 0);
  {
    std::fstream data(rec_dir / "cam00.data", std::ios::in | std::ios::out | std::ios::binary);
    data.seekg(-100, std::ios::end);
    const char byte = static_cast<char>(data.get());
    data.seekp(-100, std::ios::end);
    data.put(static_cast<char>(byte ^ 0x55));
  }
  const CalibrationData damaged = DetectViewsInRecording(rec_dir.string(), folder.board, {}, "");
  EXPECT_EQ(damaged.unreadable, 1);
  std::size_t expected = 0;
  for (const auto& o : folder.observations) expected += !(o.camera == 0 && o.view == last_view);
  EXPECT_EQ(damaged.observations.size(), expected);
  for (const auto& o : damaged.observations) EXPECT_FALSE(o.camera == 0 && o.view == last_view);
  const auto& failures = damaged.failures_per_camera[0];
  ASSERT_FALSE(failures.empty());
  const std::string& why = failures.back();
  EXPECT_NE(why.find("set " + std::to_string(last_view) + " camera " + folder.camera_names[0] +
                     ": unreadable"),
            std::string::npos)
      << why;
  EXPECT_NE(why.find("checksum"), std::string::npos) << why;
  fs::remove_all(rec_dir.parent_path());
}

TEST_F(Ring, TooFewViewsNamesTheCamera) {
  CalibrationData data = Detect();
  // Keep only two views of cam2.
  int kept = 0;
  std::erase_if(data.observations, [&](const BoardObservation& o) {
    return data.camera_names[o.camera] == "cam2" && ++kept > 2;
  });
  const std::string e = ErrorOf([&] { Calibrate(data, CalibrationOptions{}); });
  EXPECT_NE(e.find("camera cam2 sees the board in only 2 views"), std::string::npos) << e;
}

TEST_F(Ring, ACameraThatNeverSeesTheBoardIsNamed) {
  CalibrationData data = Detect();
  std::erase_if(data.observations,
                [&](const BoardObservation& o) { return data.camera_names[o.camera] == "cam1"; });
  const std::string e = ErrorOf([&] { Calibrate(data, CalibrationOptions{}); });
  EXPECT_NE(e.find("camera cam1 never sees the board"), std::string::npos) << e;
}

TEST_F(Ring, ADisconnectedCameraGraphIsNamed) {
  CalibrationData data = Detect();
  // Remove every view shared between {cam0, cam1} and {cam2, cam3}: two islands.
  std::map<int, std::set<int>> cams_of_view;
  for (const auto& o : data.observations) cams_of_view[o.view].insert(o.camera);
  auto island = [](int c) { return c < 2 ? 0 : 1; };
  std::erase_if(data.observations, [&](const BoardObservation& o) {
    const auto& cams = cams_of_view[o.view];
    return cams.size() == 2 && island(*cams.begin()) != island(*cams.rbegin());
  });
  const std::string e = ErrorOf([&] { Calibrate(data, CalibrationOptions{}); });
  EXPECT_NE(e.find("disconnected"), std::string::npos) << e;
  EXPECT_NE(e.find("cam2, cam3"), std::string::npos) << e;
}

TEST_F(Ring, BlurredImagesAreReportedPerCamera) {
  const fs::path work = TempDir("blur");
  for (const auto& v : fs::directory_iterator(*dir_ / "calibration")) {
    if (!v.is_directory()) continue;
    fs::create_directories(work / v.path().filename());
    for (const auto& f : fs::directory_iterator(v.path())) {
      ImageU8 img = ReadImageU8(f.path().string(), 1);
      if (f.path().stem() == "cam3") {
        cv::Mat m(img.height, img.width, CV_8UC1, img.pixels.data());
        cv::GaussianBlur(m, m, cv::Size(0, 0), 8.0);
      }
      WritePng((work / v.path().filename() / f.path().filename()).string(), img);
    }
  }
  const CalibrationData data = DetectViewsInFolder(
      work.string(), LoadBoardSpec((*dir_ / "calibration/board.yaml").string()), {}, "");
  const std::string e = ErrorOf([&] { Calibrate(data, CalibrationOptions{}); });
  EXPECT_NE(e.find("camera cam3 never sees the board"), std::string::npos) << e;
  EXPECT_NE(e.find("cam3.png: "), std::string::npos) << e;  // an example image and its reason
  fs::remove_all(work);
}

// A folder of 16-bit images (what `flamerig export` writes of a 16-bit camera's take; here a
// 12-bit camera's codes in the words' low bits, v x 16) is found as its 8-bit views are.
TEST_F(Ring, SixteenBitImagesAreDetectedAsTheirEightBitViews) {
  const fs::path work = TempDir("deep");
  for (const auto& v : fs::directory_iterator(*dir_ / "calibration")) {
    if (!v.is_directory()) continue;
    fs::create_directories(work / v.path().filename());
    for (const auto& f : fs::directory_iterator(v.path())) {
      const ImageU8 img = ReadImageU8(f.path().string(), 1);
      ImageU16 deep(img.width, img.height, 1);
      for (std::size_t i = 0; i < img.pixels.size(); ++i) deep.pixels[i] = img.pixels[i] * 16;
      WritePng16((work / v.path().filename() / f.path().filename()).string(), deep);
    }
  }
  const BoardSpec board = LoadBoardSpec((*dir_ / "calibration/board.yaml").string());
  const CalibrationData deep = DetectViewsInFolder(work.string(), board, {}, "");
  const CalibrationData narrow =
      DetectViewsInFolder((*dir_ / "calibration").string(), board, {}, "");
  ASSERT_GT(narrow.observations.size(), 0u);
  EXPECT_EQ(deep.observations.size(), narrow.observations.size());
  fs::remove_all(work);
}

TEST_F(Ring, ATruncatedImageIsNamed) {
  const fs::path work = TempDir("truncated");
  fs::copy(*dir_ / "calibration", work / "calibration", fs::copy_options::recursive);
  const fs::path victim = work / "calibration" / "view_000" / "cam0.png";
  ASSERT_TRUE(fs::exists(victim));
  fs::resize_file(victim, fs::file_size(victim) / 3);
  const std::string e = ErrorOf([&] {
    DetectViewsInFolder((work / "calibration").string(),
                        LoadBoardSpec((*dir_ / "calibration/board.yaml").string()), {}, "");
  });
  EXPECT_NE(e.find(victim.string()), std::string::npos) << e;
  fs::remove_all(work);
}

TEST_F(Ring, AWrongBoardSizeNeverReachesTheSolve) {
  BoardSpec wrong = LoadBoardSpec((*dir_ / "calibration/board.yaml").string());
  wrong.squares_x += 2;
  wrong.squares_y += 2;
  const CalibrationData data = DetectViewsInFolder((*dir_ / "calibration").string(), wrong, {}, "");
  // Nearly every view is refused. A view showing only a few markers can be consistent with both
  // layouts (the first row of markers is the same on a 7x5 and a 9x7 board) and pass; too few to
  // calibrate, and the error says why the others were refused.
  const CalibrationData right = Detect();
  EXPECT_LT(data.observations.size(), right.observations.size() / 20)
      << data.observations.size() << " views kept";
  const std::string e = ErrorOf([&] { Calibrate(data, CalibrationOptions{}); });
  EXPECT_TRUE(e.find("never sees the board") != std::string::npos ||
              e.find("sees the board in only") != std::string::npos)
      << e;
  EXPECT_NE(e.find("wrong board size"), std::string::npos) << e;
}

// A board described one square too wide and too tall. On `simulate`'s ChArUco views a third of
// the images still detect (the first rows of markers agree) and mrcal converged on nonsense (a
// reviewer measured 45 px RMS, fx 0.69 px, cx -163 px, written with exit 0: refused now after the
// solve, as the next test checks). On this ring few views survive; whichever error stops it names
// the camera and how many images the detection refused for not fitting the board.
TEST_F(Ring, AWrongBoardOneSquareOffNamesWhatTheDetectionSaid) {
  BoardSpec wrong = LoadBoardSpec((*dir_ / "calibration/board.yaml").string());
  wrong.squares_x += 1;
  wrong.squares_y += 1;
  const CalibrationData data = DetectViewsInFolder((*dir_ / "calibration").string(), wrong, {}, "");
  const std::string e = ErrorOf([&] { Calibrate(data, CalibrationOptions{}); });
  std::fprintf(stderr, "%zu views kept; error: %s\n", data.observations.size(), e.c_str());
  EXPECT_NE(e, "(no error)");
  EXPECT_NE(e.find("camera cam"), std::string::npos) << e;
  EXPECT_NE(e.find("do not fit the board described"), std::string::npos) << e;
}

// The same refusal without detection: exact corners numbered as if the board had one more column,
// so every row wraps onto the next (a board's geometry no lens can give).
TEST_F(Ring, CornersOfAnotherBoardAreRefusedAfterTheSolve) {
  CalibrationData data = ExactCorners(Detect(), *dir_ / "calibration", *truth_);
  ++data.board.squares_x;
  for (auto& o : data.observations) o.detection.rejected.clear();
  const std::string e = ErrorOf([&] { Calibrate(data, CalibrationOptions{}); });
  EXPECT_TRUE(e.find("not a calibration") != std::string::npos ||
              e.find("px RMS from where its model puts them") != std::string::npos)
      << e;
  EXPECT_NE(e.find("camera cam"), std::string::npos) << e;
}

// A cancel is taken after mrcal's last solve (it cannot stop one half way), and between the
// uncertainty's solves: Cancelled, nothing returned.
TEST_F(Ring, ACancelAfterTheSolveOrDuringTheUncertaintyStops) {
  const CalibrationData data = Detect();
  std::vector<int> seen;
  auto cancel_at = [&](const std::string& stage, int done) {
    return [&seen, stage, done](const Progress& p) {
      if (p.stage == stage) seen.push_back(static_cast<int>(p.done));
      return p.stage == stage && p.done == done ? ProgressAction::kCancel
                                                : ProgressAction::kContinue;
    };
  };
  std::string e = ErrorOf([&] { Calibrate(data, CalibrationOptions{}, cancel_at("solve", 2)); });
  EXPECT_NE(e.find("cancelled after the solve"), std::string::npos) << e;
  EXPECT_EQ(seen, (std::vector<int>{0, 1, 2}));
  const CalibrationSummary s = Calibrate(data, CalibrationOptions{});
  seen.clear();
  e = ErrorOf([&] {
    EstimateProjectionUncertainty(data, s, CalibrationOptions{}, 5, 0.001, 1,
                                  cancel_at("uncertainty", 2));
  });
  EXPECT_NE(e.find("cancelled after 2 of 5 solves"), std::string::npos) << e;
  EXPECT_EQ(seen, (std::vector<int>{0, 1, 2}));
}

}  // namespace
}  // namespace flamerig
