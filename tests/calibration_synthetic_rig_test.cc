// Synthetic rigs and calibration boards: rings of cameras looking at the box, boards rendered
// through the lens models and detected at their true corners, views seen by the cameras listed.
#include <gtest/gtest.h>

#include <filesystem>
#include <opencv2/aruco/charuco.hpp>
#include <opencv2/calib3d.hpp>

#include "calibration/synthetic_rig.h"
#include "core/error.h"

namespace flamerig::synthetic {
namespace {

const Box3 kBox{Eigen::Vector3d(-0.02, 0.0, -0.02), Eigen::Vector3d(0.02, 0.08, 0.02)};

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

}  // namespace
}  // namespace flamerig::synthetic
