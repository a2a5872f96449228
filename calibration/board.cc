#include "calibration/board.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <opencv2/aruco/charuco.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <set>
#include <sstream>
#include <stdexcept>

#include "core/config_reader.h"
#include "core/error.h"
#include "core/format.h"

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
  s << (type == BoardType::kCharuco ? "charuco " : "chessboard ") << squares_x << "x" << squares_y
    << " squares of " << FormatExact(square_m) << " m";
  if (type == BoardType::kCharuco)
    s << ", markers " << FormatExact(marker_m) << " m, dictionary " << aruco_dictionary;
  return s.str();
}

BoardSpec LoadBoardSpec(const std::string& yaml_path) {
  YAML::Node root;
  if (!std::filesystem::exists(yaml_path)) throw InputError(yaml_path + ": no such file");
  try {
    root = YAML::LoadFile(yaml_path);
    RejectDuplicateKeys(root, yaml_path);
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

void DetectOptions::Validate() const {
  auto fail = [](const std::string& what) { throw InputError("board detection: " + what); };
  // Each corner is checked against a homography of the others: four points fit one exactly.
  if (min_corners < 5) fail("min_corners must be >= 5");
  if (!(min_span_fraction >= 0 && min_span_fraction <= 1))
    fail("min_span_fraction must be in [0, 1]");
  if (!(max_misfit_squares > 0) || !std::isfinite(max_misfit_squares))
    fail("max_misfit_squares must be > 0");
  if (subpix_half_window < 0 || subpix_half_window > 50)
    fail("subpix_half_window must be in [0, 50] px (0: from the board's size in the image)");
  if (subpix_iterations < 1 || subpix_iterations > 1000)
    fail("subpix_iterations must be in [1, 1000]");
  if (!(subpix_epsilon > 0) || !std::isfinite(subpix_epsilon))
    fail("subpix_epsilon must be > 0 px");
}

std::string DetectOptions::Describe() const {
  std::ostringstream s;
  s << "detector " << ChessboardDetectorName(detector) << ", min_corners " << min_corners
    << ", min_span " << FormatExact(min_span_fraction) << ", misfit "
    << FormatExact(max_misfit_squares) << " squares";
  if (detector != ChessboardDetector::kClassic) s << ", sb accuracy " << accurate_chessboard;
  if (detector != ChessboardDetector::kSb)
    s << ", subpix " << subpix_half_window << " px " << subpix_iterations << " iterations "
      << FormatExact(subpix_epsilon) << " px";
  return s.str();
}

ChessboardDetector ChessboardDetectorFromName(const std::string& name) {
  if (name == "auto") return ChessboardDetector::kAuto;
  if (name == "sb") return ChessboardDetector::kSb;
  if (name == "classic") return ChessboardDetector::kClassic;
  throw InputError("board detection: detector must be auto, sb or classic, not '" + name + "'");
}

const char* ChessboardDetectorName(ChessboardDetector detector) {
  switch (detector) {
    case ChessboardDetector::kSb:
      return "sb";
    case ChessboardDetector::kClassic:
      return "classic";
    case ChessboardDetector::kAuto:
      break;
  }
  return "auto";
}

namespace {

// Mean grey level over nine points spread across the middle half of the quadrilateral square with
// corners a (top-left), b (top-right), c (bottom-left), d (bottom-right); -1 when a point falls
// outside the image.
double SquareLevel(const cv::Mat& grey, const Eigen::Vector2d& a, const Eigen::Vector2d& b,
                   const Eigen::Vector2d& c, const Eigen::Vector2d& d) {
  double sum = 0;
  for (double v : {0.25, 0.5, 0.75})
    for (double u : {0.25, 0.5, 0.75}) {
      const Eigen::Vector2d p = (1 - v) * ((1 - u) * a + u * b) + v * ((1 - u) * c + u * d);
      const long x = std::lround(p.x()), y = std::lround(p.y());
      if (!p.allFinite() || x < 0 || y < 0 || x >= grey.cols || y >= grey.rows) return -1;
      sum += grey.at<std::uint8_t>(static_cast<int>(y), static_cast<int>(x));
    }
  return sum / 9;
}

BoardDetection Failure(std::string why) {
  BoardDetection d;
  d.failure = std::move(why);
  return d;
}

// findChessboardCornersSB; empty when it finds nothing.
std::vector<cv::Point2f> FindSb(const cv::Mat& grey, const cv::Size& size,
                                const DetectOptions& options) {
  std::vector<cv::Point2f> found;
  const int flags = cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_EXHAUSTIVE |
                    (options.accurate_chessboard ? cv::CALIB_CB_ACCURACY : 0);
  if (!cv::findChessboardCornersSB(grey, size, found, flags)) found.clear();
  return found;
}

// findChessboardCorners, refined by cornerSubPix; empty when it finds nothing.
std::vector<cv::Point2f> FindClassic(const cv::Mat& grey, const cv::Size& size,
                                     const DetectOptions& options) {
  std::vector<cv::Point2f> found;
  if (!cv::findChessboardCorners(grey, size, found,
                                 cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE))
    return {};
  int half = options.subpix_half_window;
  if (half == 0) {
    // OpenCV's usual 11x11 window, or a quarter of the smallest square when that is smaller, so
    // that the window never reaches the next corner; a larger window takes in more of a shadow's
    // edge, which pulls the corner (measured: 8 px at a quarter of a 45 px square).
    double smallest = 1e30;
    for (int r = 0; r < size.height; ++r)
      for (int c = 0; c < size.width; ++c) {
        const cv::Point2f& p = found[r * size.width + c];
        if (c + 1 < size.width)
          smallest = std::min(smallest, cv::norm(found[r * size.width + c + 1] - p));
        if (r + 1 < size.height)
          smallest = std::min(smallest, cv::norm(found[(r + 1) * size.width + c] - p));
      }
    half = std::clamp(static_cast<int>(smallest / 4), 2, 5);
  }
  // cornerSubPix needs the window (plus a margin) inside the image.
  half = std::min(half, (std::min(grey.rows, grey.cols) - 5) / 2);
  if (half < 1) return {};
  cv::cornerSubPix(grey, found, cv::Size(half, half), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT,
                                    options.subpix_iterations, options.subpix_epsilon));
  return found;
}

BoardDetection DetectChessboard(const cv::Mat& grey, const BoardSpec& board,
                                const DetectOptions& options) {
  const int nx = board.corners_x(), ny = board.corners_y();
  const cv::Size size(nx, ny);
  std::vector<cv::Point2f> found;
  const char* detector = "classic";
  if (options.detector != ChessboardDetector::kSb) found = FindClassic(grey, size, options);
  if (found.empty() && options.detector != ChessboardDetector::kClassic) {
    found = FindSb(grey, size, options);
    detector = "sb";
  }
  if (static_cast<int>(found.size()) != nx * ny) return Failure("no complete chessboard found");
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
  // 180-degree turn: the square between corners (r, k) and (r + 1, k + 1) is board square
  // (k + 1, r + 1), black when r + k is even. Turned by 180 degrees (one odd and one even side),
  // every square between the corners changes colour. Each pair of neighbouring squares votes on
  // which of the two is darker: a shadow edge or a gradient can make a white square in the shade
  // darker than a black one in the light, but only for the pairs the edge crosses.
  std::vector<double> level((nx - 1) * (ny - 1));
  for (int r = 0; r + 1 < ny; ++r)
    for (int k = 0; k + 1 < nx; ++k)
      level[r * (nx - 1) + k] = SquareLevel(grey, c[r * nx + k], c[r * nx + k + 1],
                                            c[(r + 1) * nx + k], c[(r + 1) * nx + k + 1]);
  const double min_contrast = 5;  // grey levels: below this a pair does not vote
  int agree = 0, disagree = 0;
  auto vote = [&](int r0, int k0, int r1, int k1) {
    const double a = level[r0 * (nx - 1) + k0], b = level[r1 * (nx - 1) + k1];
    if (a < 0 || b < 0) return;
    const double white_minus_black = (r0 + k0) % 2 == 0 ? b - a : a - b;
    if (white_minus_black > min_contrast) ++agree;
    if (white_minus_black < -min_contrast) ++disagree;
  };
  for (int r = 0; r + 1 < ny; ++r)
    for (int k = 0; k + 1 < nx; ++k) {
      if (k + 2 < nx) vote(r, k, r, k + 1);
      if (r + 2 < ny) vote(r, k, r + 1, k);
    }
  const int votes = agree + disagree;
  if (votes == 0) return Failure("board orientation unknown: too little contrast between squares");
  if (std::max(agree, disagree) < 0.8 * votes)
    return Failure("board orientation unknown: of " + std::to_string(votes) +
                   " pairs of neighbouring squares, " + std::to_string(agree) +
                   " say one way and " + std::to_string(disagree) + " the other");
  if (disagree > agree) std::reverse(c.begin(), c.end());
  BoardDetection d;
  for (int i = 0; i < nx * ny; ++i) d.corner_ids.push_back(i);
  d.corners_px = std::move(c);
  d.detector = detector;
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
  d.detector = "charuco";
  return d;
}

// The corners must sit where one plane seen through a lens puts them. Over a few squares any lens
// is close to a homography, so each corner is predicted from its neighbours on the board (the
// smallest block around it, 3x3 up to 7x7, that holds at least six of them on two rows and two
// columns; all the others when no block does), fitted robustly so that one bad neighbour does not
// spoil it. Corners far from their prediction are rejected and listed; when too many are, the view
// is refused: a wrong board size or dictionary gives corners at the wrong places, and they must
// never reach a solve.
BoardDetection CheckGeometry(BoardDetection d, const BoardSpec& board,
                             const DetectOptions& options) {
  const int nx = board.corners_x();
  const std::size_t n = d.corner_ids.size();
  std::vector<cv::Point2f> plane(n), image(n);
  for (std::size_t i = 0; i < n; ++i) {
    plane[i] = cv::Point2f(static_cast<float>(d.corner_ids[i] % nx),
                           static_cast<float>(d.corner_ids[i] / nx));
    image[i] = cv::Point2f(static_cast<float>(d.corners_px[i].x()),
                           static_cast<float>(d.corners_px[i].y()));
  }
  BoardDetection kept;
  kept.detector = d.detector;
  for (std::size_t i = 0; i < n; ++i) {
    std::vector<cv::Point2f> from, to;
    for (int radius = 1; radius <= 4; ++radius) {
      from.clear();
      to.clear();
      std::set<int> rows, cols;
      for (std::size_t j = 0; j < n; ++j) {
        if (j == i) continue;
        const float dx = std::abs(plane[j].x - plane[i].x), dy = std::abs(plane[j].y - plane[i].y);
        if (radius < 4 && (dx > radius || dy > radius)) continue;  // 4: every other corner
        from.push_back(plane[j]);
        to.push_back(image[j]);
        rows.insert(static_cast<int>(plane[j].y));
        cols.insert(static_cast<int>(plane[j].x));
      }
      if (from.size() >= 6 && rows.size() >= 2 && cols.size() >= 2) break;
    }
    double error_px = 1e30, tolerance_px = 1;
    if (from.size() >= 4) {
      // RANSAC finds the neighbours consistent with each other, at half the tolerance for the
      // size of a square here (the median distance between neighbours next to each other on the
      // board; the corner itself may be wrong); the fit is then refined on them.
      std::vector<double> px_per_square{1.0};
      for (std::size_t j = 0; j < from.size(); ++j)
        for (std::size_t k = j + 1; k < from.size(); ++k)
          if (std::abs(cv::norm(from[j] - from[k]) - 1.0) < 1e-3)
            px_per_square.push_back(cv::norm(to[j] - to[k]));
      std::nth_element(px_per_square.begin(), px_per_square.begin() + px_per_square.size() / 2,
                       px_per_square.end());
      const double threshold_px =
          std::max(1.0, 0.5 * options.max_misfit_squares * px_per_square[px_per_square.size() / 2]);
      const cv::Mat h = cv::findHomography(from, to, cv::RANSAC, threshold_px);
      if (!h.empty()) {
        std::vector<cv::Point2f> probe{plane[i], plane[i] + cv::Point2f(1, 0),
                                       plane[i] + cv::Point2f(0, 1)},
            seen;
        cv::perspectiveTransform(probe, seen, h);
        const double square_px = 0.5 * (cv::norm(seen[1] - seen[0]) + cv::norm(seen[2] - seen[0]));
        tolerance_px = std::max(1.0, options.max_misfit_squares * square_px);
        error_px = cv::norm(seen[0] - image[i]);
        if (!std::isfinite(error_px)) error_px = 1e30;
      }
    }
    if (error_px <= tolerance_px) {
      kept.corner_ids.push_back(d.corner_ids[i]);
      kept.corners_px.push_back(d.corners_px[i]);
    } else {
      char why[160];
      if (error_px >= 1e30)
        std::snprintf(why, sizeof(why), "its %zu neighbours fit no view of a plane", from.size());
      else
        std::snprintf(why, sizeof(why),
                      "%.1f px from where its %zu neighbours put it (tolerance %.1f px)", error_px,
                      from.size(), tolerance_px);
      kept.rejected.push_back(RejectedCorner{d.corner_ids[i], d.corners_px[i], why});
    }
  }
  const std::size_t dropped = kept.rejected.size();
  if (dropped > 0.2 * n || static_cast<int>(kept.corner_ids.size()) < options.min_corners)
    return Failure("corners do not fit the board's geometry (" + std::to_string(dropped) + " of " +
                   std::to_string(n) + " off by more than " +
                   std::to_string(options.max_misfit_squares) +
                   " square from where their neighbours put them): wrong board size or "
                   "dictionary?");
  return kept;
}

}  // namespace

BoardDetection DetectBoard(const ImageU8& image, const BoardSpec& board,
                           const DetectOptions& options) {
  board.Validate();
  options.Validate();
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

BoardDetection CheckBoardGeometry(BoardDetection detection, const BoardSpec& board,
                                  const DetectOptions& options) {
  board.Validate();
  options.Validate();
  for (int id : detection.corner_ids)
    if (id < 0 || id >= board.num_corners())
      throw InputError("CheckBoardGeometry: corner id " + std::to_string(id) +
                       " is not on the board");
  if (detection.corner_ids.size() != detection.corners_px.size())
    throw InputError("CheckBoardGeometry: one position per corner id needed");
  return CheckGeometry(std::move(detection), board, options);
}

}  // namespace flamerig
