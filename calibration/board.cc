#include "calibration/board.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <opencv2/aruco/charuco.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <stdexcept>

#include "core/error.h"
#include "core/config_reader.h"

namespace flamerig {

void BoardSpec::Validate() const {
  auto fail = [](const std::string& what) { throw InputError("board: " + what); };
  if (squares_x < 3 || squares_y < 3 || squares_x > 64 || squares_y > 64)
    fail("squares must be in [3, 64], got [" + std::to_string(squares_x) + ", " +
         std::to_string(squares_y) + "]");
  if (type == BoardType::kChessboard && (squares_x + squares_y) % 2 == 0) {
    fail("a chessboard needs one odd and one even side (got [" + std::to_string(squares_x) + ", " +
         std::to_string(squares_y) + "]), or its orientation is ambiguous");
  }
  if (!(square_m > 0) || !std::isfinite(square_m)) fail("square_m must be > 0");
  if (type == BoardType::kCharuco && (!(marker_m > 0) || !(marker_m < square_m)))
    fail("marker_m must be in (0, square_m)");
  if (type == BoardType::kCharuco && (aruco_dictionary < 0 || aruco_dictionary > 20))
    fail("aruco_dictionary must be an OpenCV predefined dictionary, 0..20");
}

std::vector<Eigen::Vector3d> BoardSpec::InnerCornersInBoard() const {
  std::vector<Eigen::Vector3d> corners;
  for (int y = 1; y < squares_y; ++y)
    for (int x = 1; x < squares_x; ++x) corners.emplace_back(x * square_m, y * square_m, 0.0);
  return corners;
}

std::string BoardSpec::Describe() const {
  std::ostringstream s;
  s.precision(17);
  s << (type == BoardType::kCharuco ? "charuco " : "chessboard ") << squares_x << "x" << squares_y
    << " squares of " << square_m << " m";
  if (type == BoardType::kCharuco)
    s << ", markers " << marker_m << " m, dictionary " << aruco_dictionary;
  return s.str();
}

BoardSpec LoadBoardSpec(const std::string& yaml_path) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(yaml_path);
  } catch (const YAML::Exception& e) {
    throw InputError(yaml_path + ": cannot read the board description: " + e.what());
  }
  const YAML::Node node = root["board"] ? root["board"] : root;
  try {
    return ParseBoardSpec(node, yaml_path + ": board");
  } catch (const InputError& e) {
    throw InputError(e.what());
  }
}

BoardSpec ParseBoardSpec(const YAML::Node& node, const std::string& where) {
  if (!node.IsMap()) throw InputError(where + ": must be a map");
  ConfigReader r(node, where);
  BoardSpec b;
  const std::string type = r.Get<std::string>("type", "charuco");
  if (type == "charuco")
    b.type = BoardType::kCharuco;
  else if (type == "chessboard")
    b.type = BoardType::kChessboard;
  else
    throw InputError(where + ": 'type' must be charuco or chessboard");
  const auto squares = r.Get<std::vector<int>>("squares", {b.squares_x, b.squares_y});
  if (squares.size() != 2) throw InputError(where + ": 'squares' must be [x, y]");
  b.squares_x = squares[0];
  b.squares_y = squares[1];
  b.square_m = r.Positive("square_m", b.square_m);
  b.marker_m = r.Positive("marker_m", b.marker_m);
  b.aruco_dictionary = r.Get<int>("aruco_dictionary", b.aruco_dictionary);
  r.Seen("frame");  // free text written by `flamerig simulate`
  r.CheckKnown();
  try {
    b.Validate();
  } catch (const InputError& e) {
    throw InputError(where + ": " + e.what());
  }
  return b;
}

namespace {

// Mean grey level in a 3x3 patch around (x, y), or -1 outside the image.
double PatchMean(const cv::Mat& grey, const Eigen::Vector2d& p) {
  const int x = static_cast<int>(std::lround(p.x())), y = static_cast<int>(std::lround(p.y()));
  if (x < 1 || y < 1 || x >= grey.cols - 1 || y >= grey.rows - 1) return -1;
  return cv::mean(grey(cv::Rect(x - 1, y - 1, 3, 3)))[0];
}

BoardDetection Failure(std::string why) {
  BoardDetection d;
  d.failure = std::move(why);
  return d;
}

BoardDetection DetectChessboard(const cv::Mat& grey, const BoardSpec& board,
                                const DetectOptions& options) {
  const int nx = board.corners_x(), ny = board.corners_y();
  std::vector<cv::Point2f> found;
  const int flags = cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_EXHAUSTIVE |
                    (options.accurate_chessboard ? cv::CALIB_CB_ACCURACY : 0);
  if (!cv::findChessboardCornersSB(grey, cv::Size(nx, ny), found, flags) ||
      static_cast<int>(found.size()) != nx * ny)
    return Failure("no complete chessboard found");
  std::vector<Eigen::Vector2d> c(found.size());
  for (std::size_t i = 0; i < found.size(); ++i) c[i] = Eigen::Vector2d(found[i].x, found[i].y);
  // Handedness: seen from its printed side, board x runs right of board y in the image (x right, y
  // down). A mirrored grid is turned into the right one by reversing each row.
  auto cross = [&] {
    const Eigen::Vector2d ex = c[1] - c[0], ey = c[nx] - c[0];
    return ex.x() * ey.y() - ex.y() * ey.x();
  };
  if (cross() < 0)
    for (int r = 0; r < ny; ++r) std::reverse(c.begin() + r * nx, c.begin() + (r + 1) * nx);
  // 180-degree turn: the first square (at the board origin) is black, its neighbour along x
  // white. With one odd and one even side a turned board has a white first square.
  const Eigen::Vector2d ex = c[1] - c[0], ey = c[nx] - c[0];
  const double first = PatchMean(grey, c[0] - 0.5 * ex - 0.5 * ey);
  const double next = PatchMean(grey, c[0] + 0.5 * ex - 0.5 * ey);
  const double last = PatchMean(grey, c.back() + 0.5 * ex + 0.5 * ey);
  if (first < 0 || next < 0 || last < 0)
    return Failure("board orientation unknown: its outer squares are outside the image");
  if (first > next) {
    std::reverse(c.begin(), c.end());
  }
  if (std::abs(first - next) < 20 || std::abs(first - last) < 20)
    return Failure("board orientation unknown: too little contrast between squares");
  BoardDetection d;
  for (int i = 0; i < nx * ny; ++i) d.corner_ids.push_back(i);
  d.corners_px = std::move(c);
  return d;
}

BoardDetection DetectCharuco(const cv::Mat& grey, const BoardSpec& board) {
  auto dictionary = cv::aruco::getPredefinedDictionary(board.aruco_dictionary);
  auto charuco = cv::aruco::CharucoBoard::create(board.squares_x, board.squares_y,
                                                 static_cast<float>(board.square_m),
                                                 static_cast<float>(board.marker_m), dictionary);
  std::vector<std::vector<cv::Point2f>> marker_corners, rejected;
  std::vector<int> marker_ids;
  auto params = cv::aruco::DetectorParameters::create();
  cv::aruco::detectMarkers(grey, dictionary, marker_corners, marker_ids, params, rejected);
  if (marker_ids.empty()) return Failure("no ArUco markers found");
  // Markers whose id is not on this board (another board in view, a wrong dictionary) are left
  // out, and a wrong board is said so.
  const int num_markers = static_cast<int>(charuco->ids.size());
  std::vector<std::vector<cv::Point2f>> keep_corners;
  std::vector<int> keep_ids;
  for (std::size_t i = 0; i < marker_ids.size(); ++i)
    if (marker_ids[i] >= 0 && marker_ids[i] < num_markers) {
      keep_corners.push_back(marker_corners[i]);
      keep_ids.push_back(marker_ids[i]);
    }
  if (keep_ids.empty())
    return Failure("markers found, but none belongs to this board (wrong board or dictionary?)");
  std::vector<cv::Point2f> corners;
  std::vector<int> ids;
  cv::aruco::interpolateCornersCharuco(keep_corners, keep_ids, grey, charuco, corners, ids);
  if (ids.empty()) return Failure("markers found, but no ChArUco corner between them");
  // OpenCV's ChArUco object points may have y up (its 4.6 layout) or down: the first marker's
  // corners (clockwise from its top-left as drawn) tell which.
  const auto& m0 = charuco->objPoints.at(0);
  const bool y_up = m0[0].y > m0[3].y;
  const int nx = board.corners_x(), ny = board.corners_y();
  std::vector<std::pair<int, Eigen::Vector2d>> out;
  for (std::size_t i = 0; i < ids.size(); ++i) {
    const cv::Point3f obj = charuco->chessboardCorners.at(ids[i]);
    const int col = static_cast<int>(std::lround(obj.x / board.square_m)) - 1;
    const int row_obj = static_cast<int>(std::lround(obj.y / board.square_m));
    const int row = y_up ? board.squares_y - row_obj - 1 : row_obj - 1;
    if (col < 0 || col >= nx || row < 0 || row >= ny) continue;
    // Half a pixel: OpenCV 4.6's ChArUco corners are in a pixel-corner convention.
    out.emplace_back(row * nx + col, Eigen::Vector2d(corners[i].x - 0.5, corners[i].y - 0.5));
  }
  std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  BoardDetection d;
  for (const auto& [id, px] : out) {
    d.corner_ids.push_back(id);
    d.corners_px.push_back(px);
  }
  return d;
}

// The corners must sit where one plane seen through a lens puts them: a homography from the board
// plane fits them to a fraction of a square (lens distortion bends a board by far less). Corners
// that do not fit are dropped; when too many do not fit, the view is refused: a wrong board size or
// dictionary gives corners at the wrong places, and they must never reach a solve.
BoardDetection CheckGeometry(BoardDetection d, const BoardSpec& board,
                             const DetectOptions& options) {
  const auto corners = board.InnerCornersInBoard();
  std::vector<cv::Point2f> plane, image;
  for (std::size_t i = 0; i < d.corner_ids.size(); ++i) {
    const auto& c = corners[d.corner_ids[i]];
    plane.emplace_back(static_cast<float>(c.x() / board.square_m),
                       static_cast<float>(c.y() / board.square_m));
    image.emplace_back(static_cast<float>(d.corners_px[i].x()),
                       static_cast<float>(d.corners_px[i].y()));
  }
  // Square size in pixels around the middle of the found corners, from a first fit.
  cv::Mat h = cv::findHomography(plane, image, cv::LMEDS);
  if (h.empty()) return Failure("corners do not fit any view of a plane");
  cv::Point2f mid(0, 0);
  for (const auto& p : plane) mid += p;
  mid *= 1.0f / plane.size();
  std::vector<cv::Point2f> probe{mid, mid + cv::Point2f(1, 0), mid + cv::Point2f(0, 1)}, seen;
  cv::perspectiveTransform(probe, seen, h);
  const double square_px = 0.5 * (cv::norm(seen[1] - seen[0]) + cv::norm(seen[2] - seen[0]));
  const double tolerance_px = std::max(1.0, options.max_misfit_squares * square_px);
  std::vector<cv::Point2f> fitted;
  cv::perspectiveTransform(plane, fitted, h);
  BoardDetection kept;
  for (std::size_t i = 0; i < fitted.size(); ++i)
    if (cv::norm(fitted[i] - image[i]) <= tolerance_px) {
      kept.corner_ids.push_back(d.corner_ids[i]);
      kept.corners_px.push_back(d.corners_px[i]);
    }
  const std::size_t dropped = d.corner_ids.size() - kept.corner_ids.size();
  if (dropped > 0.2 * d.corner_ids.size() ||
      static_cast<int>(kept.corner_ids.size()) < options.min_corners)
    return Failure("corners do not fit the board's geometry (" + std::to_string(dropped) + " of " +
                   std::to_string(d.corner_ids.size()) + " off by more than " +
                   std::to_string(options.max_misfit_squares) +
                   " square): wrong board size or dictionary?");
  return kept;
}

}  // namespace

BoardDetection DetectBoard(const ImageU8& image, const BoardSpec& board,
                           const DetectOptions& options) {
  board.Validate();
  if (image.channels != 1 || image.empty())
    throw InputError("DetectBoard: need a non-empty 8-bit grey image, got " +
                                std::to_string(image.channels) + " channels");
  cv::Mat grey(image.height, image.width, CV_8UC1, const_cast<std::uint8_t*>(image.pixels.data()));
  BoardDetection d = board.type == BoardType::kCharuco ? DetectCharuco(grey, board)
                                                       : DetectChessboard(grey, board, options);
  if (!d.found()) return d;
  const int n = static_cast<int>(d.corner_ids.size());
  if (n < options.min_corners)
    return Failure("too few corners (" + std::to_string(n) + " < " +
                   std::to_string(options.min_corners) + ")");
  int min_c = 1 << 30, max_c = -1, min_r = 1 << 30, max_r = -1;
  for (int id : d.corner_ids) {
    min_c = std::min(min_c, id % board.corners_x());
    max_c = std::max(max_c, id % board.corners_x());
    min_r = std::min(min_r, id / board.corners_x());
    max_r = std::max(max_r, id / board.corners_x());
  }
  if (max_c - min_c < options.min_span_fraction * (board.corners_x() - 1) ||
      max_r - min_r < options.min_span_fraction * (board.corners_y() - 1))
    return Failure("corners cover too little of the board (a strip, " + std::to_string(n) +
                   " corners)");
  for (const auto& p : d.corners_px)
    if (!p.allFinite()) return Failure("a corner came back not finite");
  return CheckGeometry(std::move(d), board, options);
}

}  // namespace flamerig
