// Calibration boards: their description, and finding their corners in images.
//
// Two board types, both with an orientation that cannot be mistaken (a mis-ordered board must never
// enter a solve, notes/mrcal.md):
//  - ChArUco (default): a chessboard whose white squares carry ArUco markers. Every corner is
//    identified by the markers around it, so partial views are fine.
//  - chessboard: plain squares, squares_x != squares_y. The grid's mirror image is rejected by the
//    handedness of the found grid (the printed side faces the camera), and its 180-degree turn by
//    the colours of its squares (black at the board origin: square (x, y) is black when x + y is
//    even).
//
// Board frame: origin at the top-left corner of the pattern (the outer corner of its first
// square), x along squares_x, y along squares_y, z = x cross y pointing into the board; the printed
// side faces -z. Corners are the (squares_x-1) x (squares_y-1) inner corners, numbered row-major:
// corner i = r * (squares_x-1) + c sits at ((c+1) * square_m, (r+1) * square_m, 0). This is also
// mrcal's calibration-object layout (width_n = squares_x-1, height_n = squares_y-1, spacing
// square_m), so a detection is directly one mrcal board observation.
//
// Pixel coordinates put the centre of the top-left pixel at (0, 0) (mrcal's convention).
// OpenCV 4.6's ChArUco interpolation reports corners half a pixel off that convention (measured:
// tests/tools_synthetic_test.cc); DetectBoard() corrects it.
//
// Thread safety: every function here is safe to call concurrently.
#ifndef FLAMERIG_CALIBRATION_BOARD_H_
#define FLAMERIG_CALIBRATION_BOARD_H_

#include <yaml-cpp/yaml.h>

#include <Eigen/Core>
#include <string>
#include <vector>

#include "core/image.h"

namespace flamerig {

enum class BoardType { kCharuco, kChessboard };

struct BoardSpec {
  BoardType type = BoardType::kCharuco;
  int squares_x = 7;         // squares across
  int squares_y = 5;         // squares down
  double square_m = 0.012;   // edge of one square, metres
  double marker_m = 0.009;   // ChArUco marker edge, metres
  int aruco_dictionary = 0;  // cv::aruco::PREDEFINED_DICTIONARY_NAME, 0 = DICT_4X4_50

  int corners_x() const { return squares_x - 1; }
  int corners_y() const { return squares_y - 1; }
  int num_corners() const { return corners_x() * corners_y(); }
  // The inner corners in the board frame, row-major (see above).
  std::vector<Eigen::Vector3d> InnerCornersInBoard() const;
  // Throws InputError naming the field and the rule broken.
  void Validate() const;
  // A one-line description ("charuco 7x5 squares of 0.012 m, markers 0.009 m, dictionary 0"),
  // also the key that ties cached detections to the board they were made for.
  std::string Describe() const;
};

// Reads a board description from YAML: either a file whose top level has a `board:` map (the
// `calibration/board.yaml` that `flamerig simulate` writes) or a map given directly:
//   board: {type: charuco, squares: [7, 5], square_m: 0.012, marker_m: 0.009, aruco_dictionary: 0}
// Errors (InputError) name the file, the key and the rule.
BoardSpec LoadBoardSpec(const std::string& yaml_path);
// The same from a YAML map already read (the `board:` map of another config); errors
// (InputError) start with `where`.
BoardSpec ParseBoardSpec(const YAML::Node& node, const std::string& where);

// A corner a detector reported and DetectBoard left out, with the reason (for the report).
struct RejectedCorner {
  int corner_id = 0;   // index into InnerCornersInBoard()
  Eigen::Vector2d px;  // where the detector put it
  std::string reason;  // "12.3 px from where its 8 neighbours put it (tolerance 5.0 px)"
};

// Corners of one board found in one image.
struct BoardDetection {
  std::vector<int> corner_ids;              // indices into InnerCornersInBoard(), ascending
  std::vector<Eigen::Vector2d> corners_px;  // same order
  std::vector<RejectedCorner> rejected;     // corners found but left out, ascending id
  std::string detector;  // which detector found them ("sb", "classic", "charuco")
  std::string failure;   // why nothing was found; empty when found
  bool found() const { return !corner_ids.empty(); }
};

// Which OpenCV detector finds a plain chessboard (ChArUco boards always use the ArUco markers).
// Measured on a stereo pair with a k1 = -0.3 lens (tests/pipeline_calibrate_rigs_test.cc, lens
// error = RMS over the image of where the solved and the true lens project): on plain boards the
// classic detector's corners gave 0.10 and 0.22 px, within the Monte Carlo noise of the truth
// (0.24 and 0.25 px for the worst of 20 noise draws), at 0.045 px RMS residual; the SB detector's
// (with CALIB_CB_ACCURACY) 0.52 and 1.09 px, at 0.09 px residual: its fit is biased where a strong
// lens bends the squares. With shadows across the boards: auto 0.17 and 0.18 px (noise 0.25 and
// 0.29), SB alone 0.70 and 1.18 px. SB finds boards the classic one misses (it missed 2 of 74
// shadowed boards, classic 5), so auto tries it second.
enum class ChessboardDetector {
  kAuto,     // the classic detector, then findChessboardCornersSB where it finds nothing
  kSb,       // findChessboardCornersSB only (sector-based; sub-pixel by its own fit)
  kClassic,  // findChessboardCorners + cornerSubPix with the settings below
};

struct DetectOptions {
  // A detection with fewer corners than this is discarded (a pose from a few corners is weak);
  // at least 5.
  int min_corners = 6;
  // The corners must span at least this fraction of the board's extent in both directions, so
  // that they are not all on one line.
  double min_span_fraction = 0.3;
  // Consistency: each corner is predicted by a homography fitted (robustly, RANSAC at half the
  // tolerance) to its nearest neighbours on the board: the smallest block around it, 3x3 up to
  // 7x7, holding six of them on two rows and two columns (5x5 at the board's corners), else all
  // the others. A lens bends a board across its whole extent, but over two squares any lens is
  // close to a homography, so the most distorted
  // corners at the edge of a wide lens are kept (a global homography threw them out at 0.2 square).
  // A corner further than this (in squares, at least 1 px) from its neighbours' prediction is
  // rejected and listed with its distance; when more than a fifth are, the view is refused (a
  // wrong board description).
  double max_misfit_squares = 0.1;
  ChessboardDetector detector = ChessboardDetector::kAuto;
  // findChessboardCornersSB: CALIB_CB_ACCURACY (slower, sub-pixel accurate).
  bool accurate_chessboard = true;
  // Classic detector: cornerSubPix's half window (px; 0: 5 px, OpenCV's usual 11x11 window, or a
  // quarter of the board's smallest square in the image when that is smaller, at least 2 px), its
  // iteration cap and its stopping step (px).
  int subpix_half_window = 0;
  int subpix_iterations = 40;
  double subpix_epsilon = 0.001;
  // Throws InputError naming the field.
  void Validate() const;
  // A one-line description, part of the detection cache's key: changing a setting detects again.
  std::string Describe() const;
};

// "auto", "sb", "classic"; throws InputError for another name.
ChessboardDetector ChessboardDetectorFromName(const std::string& name);
const char* ChessboardDetectorName(ChessboardDetector detector);

// Finds the board in an 8-bit grey image. Never throws for an image without a board: the reason
// is in `failure` ("no markers", "too few corners (4 < 6)", "corners on a line", ...). Throws
// InputError for an image that is not 1-channel 8-bit, an invalid spec or invalid options.
//
// A chessboard's 180-degree turn is told by a vote of every pair of neighbouring squares between
// the found corners (which of the two is darker), so a shadow or a light gradient across the board,
// which changes the squares' levels but not which of two neighbours is darker, does not flip it.
BoardDetection DetectBoard(const ImageU8& grey, const BoardSpec& board,
                           const DetectOptions& options = {});

// The consistency check DetectBoard applies (see DetectOptions::max_misfit_squares), on its own
// for tests and for corners from elsewhere: the corners kept, the others in `rejected`, or a
// failure when too many do not fit.
BoardDetection CheckBoardGeometry(BoardDetection detection, const BoardSpec& board,
                                  const DetectOptions& options = {});

}  // namespace flamerig

#endif  // FLAMERIG_CALIBRATION_BOARD_H_
