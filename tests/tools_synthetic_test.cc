// The synthetic rig: fires, rings of cameras and calibration boards whose truth is known.
#include <gtest/gtest.h>

#include <filesystem>
#include <opencv2/aruco/charuco.hpp>
#include <opencv2/calib3d.hpp>

#include "core/error.h"
#include "fitting/colour.h"
#include "fitting/renderer.h"
#include "tomography/vdb_io.h"
#include "tools/simulate.h"
#include "tools/synthetic.h"

namespace flamerig::synthetic {
namespace {

namespace fs = std::filesystem;

const Box3 kBox{Eigen::Vector3d(-0.02, 0.0, -0.02), Eigen::Vector3d(0.02, 0.08, 0.02)};

TEST(Fire, DeterministicSeededAndPhysical) {
  GridGeometry g = GridGeometry::FromBox(kBox, 32);
  AbsorptionModel soot = AbsorptionModel::DefaultSoot();
  for (FireKind kind : {FireKind::kCandle, FireKind::kLicks}) {
    FireOptions o;
    o.kind = kind;
    o.seed = 3;
    FireVolume a = MakeFire(g, o, soot), b = MakeFire(g, o, soot);
    EXPECT_EQ(a.temperature_k, b.temperature_k);
    EXPECT_EQ(a.density_per_m3, b.density_per_m3);
    o.seed = 4;
    FireVolume c = MakeFire(g, o, soot);
    EXPECT_NE(a.density_per_m3, c.density_per_m3) << ToString(kind);
    o.seed = 3;
    o.time_s = 0.1;
    FireVolume d = MakeFire(g, o, soot);
    EXPECT_NE(a.temperature_k, d.temperature_k) << ToString(kind);

    float t_max = 0, t_min = 1e9f, n_max = 0;
    std::size_t burning = 0;
    for (std::size_t i = 0; i < g.num_voxels(); ++i) {
      t_max = std::max(t_max, a.temperature_k[i]);
      t_min = std::min(t_min, a.temperature_k[i]);
      n_max = std::max(n_max, a.density_per_m3[i]);
      if (a.density_per_m3[i] > 0) ++burning;
    }
    EXPECT_GE(t_min, 300.0f);
    EXPECT_LE(t_max, 2000.0f);
    EXPECT_GT(t_max, 1700.0f) << ToString(kind);
    EXPECT_LE(n_max, soot.DensityFromVolumeFraction(1e-6) * 1.0001);
    EXPECT_GT(n_max, soot.DensityFromVolumeFraction(1e-6) * 0.3);
    // The flame fills a part of the box, and nothing touches its sides.
    double fraction = double(burning) / g.num_voxels();
    EXPECT_GT(fraction, 0.02) << ToString(kind);
    EXPECT_LT(fraction, 0.6) << ToString(kind);
    for (int k = 0; k < g.dims.z(); ++k)
      for (int j = 0; j < g.dims.y(); ++j) {
        EXPECT_EQ(a.density_per_m3[g.Flat(0, j, k)], 0.0f);
        EXPECT_EQ(a.density_per_m3[g.Flat(g.dims.x() - 1, j, k)], 0.0f);
      }
  }
}

TEST(Fire, ThinEmissionIsWhatTheRendererIntegrates) {
  // A uniform, optically thin block: the pixel is emission per metre times the path length.
  GridGeometry g = GridGeometry::FromBoxAndDims(
      Box3{Eigen::Vector3d(-0.5, -0.5, -0.01), Eigen::Vector3d(0.5, 0.5, 0.01)},
      Eigen::Vector3i(4, 4, 4));
  for (bool soot : {false, true}) {
    AbsorptionModel absorption =
        soot ? AbsorptionModel::DefaultSoot() : AbsorptionModel::DefaultGrey();
    FireVolume fire;
    fire.geometry = g;
    fire.temperature_k.assign(g.num_voxels(), 1800.0f);
    fire.density_per_m3.assign(g.num_voxels(),
                               static_cast<float>(1e-4 / absorption.CrossSectionM2(550)));
    std::vector<float> emission = ThinEmissionRgb(fire, absorption);
    RenderOptions o;
    o.spectral_first_nm = 360;
    o.spectral_last_nm = 830;
    o.spectral_step_nm = 1;
    FireRenderer renderer(absorption, o);
    renderer.SetVolume(g, fire.temperature_k, fire.density_per_m3);
    Rigid3 pose = LookAt(Eigen::Vector3d(0, 0, 1), Eigen::Vector3d::Zero());
    ImageF image;
    renderer.Render(CameraRays(CameraModel::Pinhole(50, 50, 10, 10, pose, 21, 21)), &image);
    // Relative to the brightest channel: the blue channel of an 1800 K fire is a near-cancellation.
    const double scale =
        0.02 * std::max({std::abs(emission[0]), std::abs(emission[1]), std::abs(emission[2])});
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(image.at(10, 10, c), emission[c] * 0.02, 2e-4 * scale)
          << "soot " << soot << " channel " << c;
    }
  }
}

TEST(Ring, CamerasLookAtTheBoxCentre) {
  RingOptions o;
  o.cameras = 4;
  Rig rig = MakeRingRig(kBox, o);
  ASSERT_EQ(rig.cameras.size(), 4u);
  for (const auto& c : rig.cameras) {
    Eigen::Vector2d q = c.model.Project(kBox.center());
    EXPECT_NEAR(q.x(), 159.5, 1e-6);
    EXPECT_NEAR(q.y(), 119.5, 1e-6);
    EXPECT_NEAR((c.model.center_in_rig() - kBox.center()).norm(), o.distance_m, 1e-12);
    // The whole box is in view.
    for (int corner = 0; corner < 8; ++corner) {
      Eigen::Vector3d p(corner & 1 ? kBox.max_in_rig.x() : kBox.min_in_rig.x(),
                        corner & 2 ? kBox.max_in_rig.y() : kBox.min_in_rig.y(),
                        corner & 4 ? kBox.max_in_rig.z() : kBox.min_in_rig.z());
      Eigen::Vector2d qc = c.model.Project(p);
      EXPECT_TRUE(qc.x() > 0 && qc.y() > 0 && qc.x() < 319 && qc.y() < 239) << c.name;
    }
  }
  // Two cameras default to the paper's front and 90-degree side views.
  RingOptions two;
  Rig pair = MakeRingRig(kBox, two);
  Eigen::Vector3d a = pair.cameras[0].model.center_in_rig() - kBox.center();
  Eigen::Vector3d b = pair.cameras[1].model.center_in_rig() - kBox.center();
  EXPECT_NEAR(a.normalized().dot(b.normalized()), 0.0, 1e-12);
  o.distance_m = 0.01;
  EXPECT_THROW(MakeRingRig(kBox, o), InputError);
}

// A rendered chessboard is found by OpenCV where the board's true corners project.
TEST(Board, RenderedChessboardIsDetectedAtTheTrueCorners) {
  BoardSpec board;
  board.type = BoardType::kChessboard;
  board.squares_x = 8;
  board.squares_y = 5;
  board.square_m = 0.02;
  Rigid3 cam_from_rig = LookAt(Eigen::Vector3d(0.05, 0.02, -0.4), Eigen::Vector3d(0.08, 0.06, 0));
  CameraModel camera("LENSMODEL_OPENCV8", {600, 600, 319.5, 239.5, -0.08, 0.02, 0, 0, 0, 0, 0, 0},
                     cam_from_rig, 640, 480);
  // Board in the z = 0 plane of the rig, printed side facing the camera (at negative z), slightly
  // tilted.
  Rigid3 rig_from_board(Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitY())),
                        Eigen::Vector3d::Zero());
  ImageU8 image = RenderBoard(camera, board, rig_from_board, 1.0, 5);
  cv::Mat mat(image.height, image.width, CV_8UC1, image.pixels.data());
  std::vector<cv::Point2f> found;
  ASSERT_TRUE(cv::findChessboardCornersSB(mat, cv::Size(7, 4), found, cv::CALIB_CB_ACCURACY));
  std::vector<Eigen::Vector3d> truth_in_rig;
  for (const auto& c : board.InnerCornersInBoard()) truth_in_rig.push_back(rig_from_board * c);
  std::vector<Eigen::Vector2d> truth = camera.Project(truth_in_rig);
  ASSERT_EQ(found.size(), truth.size());
  double worst = 0;
  for (const auto& t : truth) {
    double best = 1e9;
    for (const auto& f : found) best = std::min(best, std::hypot(f.x - t.x(), f.y - t.y()));
    worst = std::max(worst, best);
  }
  EXPECT_LT(worst, 0.3) << "px";
}

TEST(Board, RenderedCharucoIsDetected) {
  BoardSpec board;  // ChArUco 7x5
  board.square_m = 0.02;
  board.marker_m = 0.015;
  Rigid3 cam_from_rig = LookAt(Eigen::Vector3d(0.07, 0.05, -0.35), Eigen::Vector3d(0.07, 0.05, 0));
  CameraModel camera = CameraModel::Pinhole(700, 700, 319.5, 239.5, cam_from_rig, 640, 480);
  ImageU8 image = RenderBoard(camera, board, Rigid3(), 1.0, 6);
  cv::Mat mat(image.height, image.width, CV_8UC1, image.pixels.data());
  auto dictionary = cv::aruco::getPredefinedDictionary(board.aruco_dictionary);
  std::vector<std::vector<cv::Point2f>> corners;
  std::vector<int> ids;
  cv::aruco::detectMarkers(mat, dictionary, corners, ids);
  EXPECT_EQ(ids.size(), 17u);  // a 7x5 ChArUco board carries 17 markers
  auto charuco = cv::aruco::CharucoBoard::create(7, 5, 0.02f, 0.015f, dictionary);
  std::vector<cv::Point2f> charuco_corners;
  std::vector<int> charuco_ids;
  cv::aruco::interpolateCornersCharuco(corners, ids, mat, charuco, charuco_corners, charuco_ids);
  EXPECT_EQ(charuco_ids.size(), 24u);
  // Every detected corner lies on a true inner corner, up to a constant offset of (+0.5, +0.5) px:
  // OpenCV 4.6's interpolateCornersCharuco reports corners in a pixel-corner convention (measured
  // here; findChessboardCornersSB on the same renderer agrees with the pixel-centre convention to
  // 0.3 px). Calibration must subtract this offset from ChArUco detections.
  std::vector<Eigen::Vector3d> truth_in_rig = board.InnerCornersInBoard();
  std::vector<Eigen::Vector2d> truth = camera.Project(truth_in_rig);
  for (const auto& f : charuco_corners) {
    double best = 1e9;
    for (const auto& t : truth)
      best = std::min(best, std::hypot(f.x - 0.5 - t.x(), f.y - 0.5 - t.y()));
    EXPECT_LT(best, 0.05);
  }
}

// A camera listed for a view sees the whole chessboard, or most of a ChArUco board (identified by
// its markers, so partial views count).
TEST(Board, CalibrationViewsAreSeenByTheCamerasListed) {
  RingOptions o;
  o.cameras = 4;
  Rig rig = MakeRingRig(kBox, o);
  for (BoardType type : {BoardType::kCharuco, BoardType::kChessboard}) {
    BoardSpec board;
    board.type = type;
    board.squares_x = 7;
    board.squares_y = 4;
    board.square_m = 0.008;
    board.marker_m = 0.006;
    auto views = MakeCalibrationViews(rig, board, 1, 4, 2);
    int shared = 0;
    for (const auto& v : views) {
      ASSERT_FALSE(v.cameras.empty());
      if (v.cameras.size() >= 2) ++shared;
      for (int c : v.cameras) {
        int inside = 0, total = 0;
        for (const auto& p : board.InnerCornersInBoard()) {
          Eigen::Vector2d q = rig.cameras[c].model.Project(v.rig_from_board * p);
          inside += q.x() > 0 && q.y() > 0 && q.x() < 320 && q.y() < 240;
          ++total;
        }
        if (type == BoardType::kChessboard)
          EXPECT_EQ(inside, total);
        else
          EXPECT_GE(inside, 0.6 * total);
      }
    }
    EXPECT_GE(shared, 4 * 4);  // every neighbouring pair shares views
  }
}

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
  fs::remove_all(dir);
}

}  // namespace
}  // namespace flamerig::synthetic
