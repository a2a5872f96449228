// Board detection: every corner found is the board corner it claims to be, however the board is
// turned in the image (the true corners come from projecting the rendered board's known pose).
#include <gtest/gtest.h>

#include "core/error.h"
#include "calibration/board.h"
#include "calibration/synthetic_rig.h"

namespace flamerig {
namespace {

// Renders `board` seen by a camera rolled by `roll_rad` about its optical axis and checks every
// detected corner against the projection of the corner it is labelled as.
void ExpectLabelsAreTrue(const BoardSpec& board, double roll_rad, double max_px) {
  const double w = board.squares_x * board.square_m, h = board.squares_y * board.square_m;
  const Eigen::Vector3d centre(0.5 * w, 0.5 * h, 0);
  Rigid3 look =
      LookAt(centre + Eigen::Vector3d(0.03, -0.02, -0.35), centre, -Eigen::Vector3d::UnitY());
  const Rigid3 roll(Eigen::Quaterniond(Eigen::AngleAxisd(roll_rad, Eigen::Vector3d::UnitZ())),
                    Eigen::Vector3d::Zero());
  CameraModel camera("LENSMODEL_OPENCV8", {700, 700, 319.5, 239.5, -0.05, 0.02, 0, 0, 0, 0, 0, 0},
                     roll * look, 640, 480);
  const ImageU8 image = synthetic::RenderBoard(camera, board, Rigid3(), 1.0, 3);
  const BoardDetection d = DetectBoard(image, board);
  ASSERT_TRUE(d.found()) << d.failure << " (roll " << roll_rad << ")";
  EXPECT_GE(d.corner_ids.size(), static_cast<std::size_t>(board.num_corners() * 3 / 4));
  const auto corners = board.InnerCornersInBoard();
  for (std::size_t i = 0; i < d.corner_ids.size(); ++i) {
    const Eigen::Vector2d truth = camera.Project(corners[d.corner_ids[i]]);
    EXPECT_LT((truth - d.corners_px[i]).norm(), max_px)
        << "corner " << d.corner_ids[i] << " at roll " << roll_rad;
  }
}

TEST(DetectBoard, CharucoLabelsAreTrueAtAnyRoll) {
  BoardSpec board;
  board.square_m = 0.02;
  board.marker_m = 0.015;
  for (double roll : {0.0, 0.5 * M_PI, M_PI, 1.5 * M_PI, 0.3})
    ExpectLabelsAreTrue(board, roll, 0.15);
}

TEST(DetectBoard, ChessboardLabelsAreTrueAtAnyRoll) {
  BoardSpec board;
  board.type = BoardType::kChessboard;
  board.squares_x = 8;
  board.squares_y = 5;
  board.square_m = 0.02;
  // findChessboardCornersSB is accurate to about half a pixel here; a wrong label would be a
  // whole square (about 40 px) off.
  for (double roll : {0.0, 0.5 * M_PI, M_PI, 1.5 * M_PI, 2.8})
    ExpectLabelsAreTrue(board, roll, 0.6);
}

TEST(DetectBoard, NoBoardIsAReasonNotAnError) {
  ImageU8 blank(320, 240, 1, 40);
  BoardSpec charuco;
  BoardDetection d = DetectBoard(blank, charuco);
  EXPECT_FALSE(d.found());
  EXPECT_FALSE(d.failure.empty());
  BoardSpec chess;
  chess.type = BoardType::kChessboard;
  chess.squares_x = 8;
  chess.squares_y = 5;
  d = DetectBoard(blank, chess);
  EXPECT_FALSE(d.found());
  EXPECT_FALSE(d.failure.empty());
  EXPECT_THROW(DetectBoard(ImageU8(10, 10, 3), charuco), InputError);
}

TEST(BoardSpec, AmbiguousChessboardsAreRefused) {
  BoardSpec b;
  b.type = BoardType::kChessboard;
  b.squares_x = 8;
  b.squares_y = 6;  // turned by 180 degrees it looks the same
  EXPECT_THROW(b.Validate(), InputError);
  b.squares_y = 5;
  EXPECT_NO_THROW(b.Validate());
}

}  // namespace
}  // namespace flamerig
