#include "pipeline/calibrate_job.h"

#include <fmt/format.h>

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "calibration/mrcal_inputs.h"
#include "core/atomic_file.h"
#include "core/config_reader.h"
#include "core/error.h"
#include "core/format.h"
#include "core/log.h"
#include "pipeline/picture.h"
#include "pipeline/report_page.h"
#include "pipeline/valid_region.h"
#include "tomography/reconstruct.h"

namespace flamerig {

namespace fs = std::filesystem;

namespace {

Eigen::Vector3d ReadVector3(const YAML::Node& node, const std::string& where) {
  if (!node || !node.IsSequence() || node.size() != 3)
    throw InputError(where + " must be [x, y, z]");
  try {
    return Eigen::Vector3d(node[0].as<double>(), node[1].as<double>(), node[2].as<double>());
  } catch (const YAML::Exception&) {
    throw InputError(where + " must hold three numbers");
  }
}

ImageU8 FromBgr(const cv::Mat& bgr) {
  cv::Mat rgb;
  cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
  ImageU8 out(rgb.cols, rgb.rows, 3);
  for (int y = 0; y < rgb.rows; ++y)
    std::copy(rgb.ptr<std::uint8_t>(y), rgb.ptr<std::uint8_t>(y) + 3 * rgb.cols, &out.at(0, y, 0));
  return out;
}

// Green (0 px) through yellow to red (at `scale` px and above), BGR.
cv::Scalar ErrorColour(double error_px, double scale) {
  const double t = std::clamp(error_px / std::max(scale, 1e-9), 0.0, 1.0);
  return t < 0.5 ? cv::Scalar(0, 200, 510 * t) : cv::Scalar(0, 200 * (1 - t) * 2, 255);
}

// The pictures drawn per camera, each written as OUT/<prefix><camera>.png: their names, what the
// Markdown report calls them and what the page says under them, in one place for the writer, both
// reports and the removal of a gone camera's pictures.
struct CameraPicture {
  const char* prefix;
  const char* alt;
  const char* caption;  // follows the camera's name
  std::string File(const std::string& camera) const { return prefix + camera + ".png"; }
};
enum CameraPictureKind { kCoverage, kResiduals, kPerImage };
constexpr CameraPicture kCameraPictures[] = {
    {"coverage_", "coverage",
     ": where its corners fell on the image, each coloured by its reprojection error; magenta "
     "crosses are outliers; the cyan outline is mrcal's valid-intrinsics region."},
    {"residuals_", "residuals",
     ": each corner's residual as an arrow, magnified; arrows that turn together over the image "
     "mean a lens model that does not fit."},
    {"per_image_", "residuals per image",
     ": the RMS residual of each image; a bad image stands out."},
};

}  // namespace

CalibrateConfig CalibrateConfig::Load(const std::string& path) {
  YAML::Node root;
  if (!fs::exists(path)) throw InputError(path + ": no such file");
  try {
    root = YAML::LoadFile(path);
    RejectDuplicateKeys(root, path);
  } catch (const YAML::Exception& e) {
    throw InputError(path + ": cannot read the calibration config: " + e.what());
  }
  if (!root["calibrate"] || !root["calibrate"].IsMap())
    throw InputError(path + ": needs a 'calibrate:' map");
  const YAML::Node node = root["calibrate"];
  const std::string where = path + ": calibrate";
  ConfigReader r(node, where);
  CalibrateConfig c;
  r.Seen("board");
  r.Seen("board_file");
  r.Seen("box");
  r.Seen("ring_origin");
  if (node["ring_origin"])
    c.options.ring_origin_m = ReadVector3(node["ring_origin"], where + ".ring_origin");
  if (node["board"] && node["board_file"])
    throw InputError(where + ": give 'board' or 'board_file', not both");
  if (node["board"]) c.board = ParseBoardSpec(node["board"], where + ".board");
  if (node["board_file"]) {
    fs::path f = node["board_file"].as<std::string>();
    if (f.is_relative()) f = fs::path(path).parent_path() / f;
    try {
      c.board = LoadBoardSpec(f.string());
    } catch (const std::exception& ex) {
      throw InputError(where + ".board_file: " + ex.what());
    }
  }
  c.cameras = r.Get<std::vector<std::string>>("cameras", {});
  c.options.lensmodel = r.Get<std::string>("lensmodel", c.options.lensmodel);
  c.options.focal_px = r.Get<double>("focal_px", 0.0);
  c.options.outlier_rejection = r.Get<bool>("outlier_rejection", true);
  c.options.min_views_per_camera = r.Get<int>("min_views_per_camera", 3);
  c.options.board_warp = r.Get<bool>("board_warp", c.options.board_warp);
  c.uncertainty_trials = r.Get<int>("uncertainty_trials", c.uncertainty_trials);
  if (c.uncertainty_trials != 0 && (c.uncertainty_trials < 2 || c.uncertainty_trials > 1000))
    throw InputError(where + ": 'uncertainty_trials' must be 0 (off) or in [2, 1000]");
  c.options.regularization = r.Get<bool>("regularization", c.options.regularization);
  if (node["valid_intrinsics_region_parameters"]) {
    const std::string key = where + ".valid_intrinsics_region_parameters";
    c.valid_region = ValidRegionParameters::FromMrcal(
        r.Get<std::vector<double>>("valid_intrinsics_region_parameters", {}), key);
  }
  if (const YAML::Node detect = node["detect"]) {
    r.Seen("detect");
    if (!detect.IsMap()) throw InputError(where + ".detect: must be a map");
    ConfigReader dr(detect, where + ".detect");
    DetectOptions& d = c.detect;
    try {
      d.detector = ChessboardDetectorFromName(
          dr.Get<std::string>("detector", ChessboardDetectorName(d.detector)));
    } catch (const InputError& e) {
      throw InputError(where + ".detect: " + e.what());
    }
    d.min_corners = dr.Get<int>("min_corners", d.min_corners);
    d.max_misfit_squares = dr.Get<double>("max_misfit_squares", d.max_misfit_squares);
    d.accurate_chessboard = dr.Get<bool>("sb_accuracy", d.accurate_chessboard);
    d.subpix_half_window = dr.Get<int>("subpix_half_window", d.subpix_half_window);
    d.subpix_iterations = dr.Get<int>("subpix_iterations", d.subpix_iterations);
    d.subpix_epsilon = dr.Get<double>("subpix_epsilon", d.subpix_epsilon);
    dr.CheckKnown();
    try {
      d.Validate();
    } catch (const InputError& e) {
      throw InputError(where + ".detect: " + e.what());
    }
  }
  const std::string frame = r.Get<std::string>("frame", "first-camera");
  if (frame == "ring")
    c.options.frame = RigFrame::kRing;
  else if (frame == "first-camera")
    c.options.frame = RigFrame::kFirstCamera;
  else
    throw InputError(where + ": 'frame' must be ring or first-camera, not '" + frame + "'");
  c.options.rig_name = r.Get<std::string>("name", c.options.rig_name);
  if (const YAML::Node box = node["box"]) {
    ConfigReader br(box, where + ".box");
    br.Seen("min");
    br.Seen("max");
    br.CheckKnown();
    c.options.box.min_in_rig = ReadVector3(box["min"], where + ".box.min");
    c.options.box.max_in_rig = ReadVector3(box["max"], where + ".box.max");
    if (!c.options.box.min_in_rig.allFinite() || !c.options.box.max_in_rig.allFinite())
      throw InputError(where + ".box: min and max must be finite numbers");
    if (!c.options.box.IsValid())
      throw InputError(where + ".box: max must be greater than min on every axis");
  }
  r.CheckKnown();
  try {
    c.options.Validate();
  } catch (const InputError& e) {
    throw InputError(path + ": " + e.what());
  }
  return c;
}

// `region`: the camera's valid-intrinsics region (null: not computed), outlined in cyan.
ImageU8 CoveragePicture(const CalibrationData& data, const CalibrationSummary& summary, int camera,
                        double* covered_fraction, const ValidRegion* region) {
  const int w = data.widths.at(camera), h = data.heights.at(camera);
  const double scale = std::min(1.0, 800.0 / w);
  const int W = std::max(1, static_cast<int>(w * scale)),
            H = std::max(1, static_cast<int>(h * scale));
  cv::Mat img(H, W, CV_8UC3, cv::Scalar(30, 30, 30));
  // Coverage: the image split into 10 x 10 cells; a cell is covered when a corner falls in it.
  const int cells = 10;
  std::vector<bool> covered(cells * cells, false);
  double error_scale = 0;
  for (const auto& c : summary.cameras)
    if (c.name == data.camera_names[camera]) error_scale = std::max(2 * c.p95_px, 0.1);
  // Cells first, then the corners over them; summary.errors follows the observations' order.
  for (const auto& o : data.observations) {
    if (o.camera != camera) continue;
    for (const auto& p : o.detection.corners_px) {
      const int cx = std::clamp(static_cast<int>(p.x() / w * cells), 0, cells - 1);
      const int cy = std::clamp(static_cast<int>(p.y() / h * cells), 0, cells - 1);
      covered[cy * cells + cx] = true;
    }
  }
  for (int cy = 0; cy < cells; ++cy)
    for (int cx = 0; cx < cells; ++cx)
      if (covered[cy * cells + cx])
        cv::rectangle(img, cv::Point(cx * W / cells, cy * H / cells),
                      cv::Point((cx + 1) * W / cells - 1, (cy + 1) * H / cells - 1),
                      cv::Scalar(70, 60, 50), cv::FILLED);
  std::size_t k = 0;
  for (const auto& o : data.observations) {
    for (std::size_t i = 0; i < o.detection.corner_ids.size(); ++i, ++k) {
      if (o.camera != camera || k >= summary.errors.size()) continue;
      const ObservationError& e = summary.errors[k];
      const Eigen::Vector2d p = o.detection.corners_px[i] * scale;
      const cv::Point q(static_cast<int>(std::lround(p.x())), static_cast<int>(std::lround(p.y())));
      if (e.outlier)
        cv::drawMarker(img, q, cv::Scalar(255, 0, 255), cv::MARKER_TILTED_CROSS, 7, 1);
      else
        cv::circle(img, q, 2, ErrorColour(e.error_px, error_scale), cv::FILLED, cv::LINE_AA);
    }
  }
  std::string region_text = "no valid-intrinsics region (see the notes)";
  if (region && region->computed) {
    std::vector<cv::Point> outline;
    for (const Eigen::Vector2i& q : region->contour)
      outline.emplace_back(static_cast<int>(std::lround(q.x() * scale)),
                           static_cast<int>(std::lround(q.y() * scale)));
    if (!outline.empty())
      cv::polylines(img, outline, true, cv::Scalar(255, 255, 0), 2, cv::LINE_AA);
    region_text = outline.empty() ? "mrcal's valid-intrinsics region: empty"
                                  : fmt::format("cyan: mrcal's valid-intrinsics region ({:.0f}%)",
                                                100 * region->imager_fraction);
  }
  int n = 0;
  for (bool b : covered) n += b;
  if (covered_fraction) *covered_fraction = static_cast<double>(n) / covered.size();
  return Labelled(
      FromBgr(img),
      fmt::format("{}: {}% of the image covered by corners\n"
                  "corner error: green 0 px, red {:.2f} px; magenta x: outlier\n{}",
                  data.camera_names[camera], 100 * n / (cells * cells), error_scale, region_text));
}

ImageU8 ResidualVectorsPicture(const CalibrationData& data, const CalibrationSummary& summary,
                               int camera) {
  const int w = data.widths.at(camera), h = data.heights.at(camera);
  const double scale = std::min(1.0, 800.0 / w);
  const int W = std::max(1, static_cast<int>(w * scale)),
            H = std::max(1, static_cast<int>(h * scale));
  cv::Mat img(H, W, CV_8UC3, cv::Scalar(255, 255, 255));
  cv::rectangle(img, cv::Point(0, 0), cv::Point(W - 1, H - 1), cv::Scalar(0, 0, 0), 1);
  double p95 = 0;
  for (const auto& c : summary.cameras)
    if (c.name == data.camera_names[camera]) p95 = c.p95_px;
  const double magnify = p95 > 0 ? 25.0 / (p95 * scale) : 1.0;
  std::size_t k = 0;
  for (const auto& o : data.observations)
    for (std::size_t i = 0; i < o.detection.corner_ids.size(); ++i, ++k) {
      if (o.camera != camera || k >= summary.errors.size()) continue;
      const ObservationError& e = summary.errors[k];
      const Eigen::Vector2d from = o.detection.corners_px[i] * scale;
      const cv::Point a(static_cast<int>(std::lround(from.x())),
                        static_cast<int>(std::lround(from.y())));
      if (e.outlier) {
        cv::drawMarker(img, a, cv::Scalar(255, 0, 255), cv::MARKER_TILTED_CROSS, 7, 1);
        continue;
      }
      const Eigen::Vector2d to = from + magnify * scale * e.residual_px;
      cv::arrowedLine(
          img, a,
          cv::Point(static_cast<int>(std::lround(to.x())), static_cast<int>(std::lround(to.y()))),
          cv::Scalar(160, 60, 0), 1, cv::LINE_AA, 0, 0.25);
    }
  char text[240];
  std::snprintf(text, sizeof(text),
                "%s: each corner's residual (projected minus detected), magnified %.0fx "
                "(an arrow of 25 px is the 95th percentile, %.3f px); magenta x: outlier",
                data.camera_names[camera].c_str(), magnify, p95);
  return Labelled(FromBgr(img), text);
}

ImageU8 ResidualsPerImagePicture(const CalibrationData& data, const CalibrationSummary& summary,
                                 int camera) {
  // RMS per observation of this camera, in observation (view) order.
  std::vector<double> rms;
  std::vector<std::string> names;
  std::size_t k = 0;
  for (const auto& o : data.observations) {
    double sq = 0;
    int n = 0;
    for (std::size_t i = 0; i < o.detection.corner_ids.size(); ++i, ++k) {
      if (o.camera != camera || k >= summary.errors.size() || summary.errors[k].outlier) continue;
      sq += summary.errors[k].error_px * summary.errors[k].error_px;
      ++n;
    }
    if (o.camera != camera) continue;
    rms.push_back(n ? std::sqrt(sq / n) : 0.0);
    names.push_back(data.view_names[o.view]);
  }
  const int width = 800, height = 300, left = 60, bottom = 40, top = 20;
  cv::Mat img(height, width, CV_8UC3, cv::Scalar(255, 255, 255));
  const double top_value =
      std::max(1e-6, rms.empty() ? 1.0 : *std::max_element(rms.begin(), rms.end()));
  const int plot_w = width - left - 10, plot_h = height - bottom - top;
  cv::line(img, cv::Point(left, top), cv::Point(left, top + plot_h), cv::Scalar(0, 0, 0), 1);
  cv::line(img, cv::Point(left, top + plot_h), cv::Point(left + plot_w, top + plot_h),
           cv::Scalar(0, 0, 0), 1);
  const double bar = rms.empty() ? 1.0 : static_cast<double>(plot_w) / rms.size();
  for (std::size_t i = 0; i < rms.size(); ++i) {
    const int x0 = left + static_cast<int>(i * bar),
              x1 = left + static_cast<int>((i + 1) * bar) - 1;
    const int y = top + plot_h - static_cast<int>(plot_h * rms[i] / top_value);
    cv::rectangle(img, cv::Point(x0, y), cv::Point(std::max(x0, x1), top + plot_h - 1),
                  cv::Scalar(160, 60, 0), cv::FILLED);
  }
  std::vector<double> sorted = rms;
  std::sort(sorted.begin(), sorted.end());
  const double median = sorted.empty() ? 0 : sorted[sorted.size() / 2];
  const int ym = top + plot_h - static_cast<int>(plot_h * median / top_value);
  cv::line(img, cv::Point(left, ym), cv::Point(left + plot_w, ym), cv::Scalar(0, 140, 255), 1);
  char label[64];
  std::snprintf(label, sizeof(label), "%.3f", top_value);
  cv::putText(img, label, cv::Point(4, top + 10), cv::FONT_HERSHEY_SIMPLEX, 0.4,
              cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  cv::putText(img, "0", cv::Point(40, top + plot_h), cv::FONT_HERSHEY_SIMPLEX, 0.4,
              cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  if (!names.empty()) {
    cv::putText(img, names.front(), cv::Point(left, height - 22), cv::FONT_HERSHEY_SIMPLEX, 0.4,
                cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
    cv::putText(img, names.back(), cv::Point(std::max(left, left + plot_w - 80), height - 22),
                cv::FONT_HERSHEY_SIMPLEX, 0.4, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  }
  char text[200];
  std::snprintf(text, sizeof(text),
                "%s: RMS residual (px, inliers) of each of its %zu images, in view order; "
                "orange: the median, %.3f px",
                data.camera_names[camera].c_str(), rms.size(), median);
  return Labelled(FromBgr(img), text);
}

ImageU8 RigFromAbove(const CalibrationSummary& summary, int size) {
  const Rig& rig = summary.rig;
  // Top view: looking down the rig's up axis. Horizontal axes: the two rig axes most orthogonal to
  // up (x and z for a y-up rig).
  const Eigen::Vector3d up = rig.up_in_rig.normalized();
  Eigen::Vector3d a = std::abs(up.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitZ();
  a = (a - a.dot(up) * up).normalized();
  const Eigen::Vector3d b = up.cross(a);  // right-handed: looking down, a right, b down the page
  std::vector<Eigen::Vector2d> pts;
  auto plane = [&](const Eigen::Vector3d& p) { return Eigen::Vector2d(p.dot(a), p.dot(b)); };
  for (const auto& c : rig.cameras) pts.push_back(plane(c.model.center_in_rig()));
  for (int i = 0; i < 8; ++i)
    pts.push_back(plane(Eigen::Vector3d(i & 1 ? rig.box.max_in_rig.x() : rig.box.min_in_rig.x(),
                                        i & 2 ? rig.box.max_in_rig.y() : rig.box.min_in_rig.y(),
                                        i & 4 ? rig.box.max_in_rig.z() : rig.box.min_in_rig.z())));
  Eigen::Vector2d lo = pts[0], hi = pts[0];
  for (const auto& p : pts) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  const double extent = std::max((hi - lo).maxCoeff(), 1e-6);
  const Eigen::Vector2d mid = 0.5 * (lo + hi);
  const double s = 0.8 * size / extent;
  auto px = [&](const Eigen::Vector3d& p) {
    const Eigen::Vector2d q = (plane(p) - mid) * s;
    return cv::Point(static_cast<int>(size / 2 + q.x()), static_cast<int>(size / 2 + q.y()));
  };
  cv::Mat img(size, size, CV_8UC3, cv::Scalar(255, 255, 255));
  // Board positions (views used), then the box, then the cameras with their viewing direction.
  for (std::size_t v = 0; v < summary.rig_from_board.size(); ++v)
    if (v < summary.view_used.size() && summary.view_used[v])
      cv::circle(img, px(summary.rig_from_board[v].translation), 2, cv::Scalar(180, 180, 180),
                 cv::FILLED);
  const Box3& box = rig.box;
  const Eigen::Vector3d c = box.center();
  std::vector<cv::Point> outline;
  for (int i : {0, 1, 3, 2}) {
    Eigen::Vector3d corner = c;
    const Eigen::Vector3d h = 0.5 * box.size();
    corner += (i & 1 ? 1 : -1) * std::abs(h.dot(a)) * a + (i & 2 ? 1 : -1) * std::abs(h.dot(b)) * b;
    outline.push_back(px(corner));
  }
  cv::polylines(img, outline, true, cv::Scalar(0, 120, 255), 2, cv::LINE_AA);
  const double arrow_m = 0.25 * extent;
  for (const auto& cam : rig.cameras) {
    const Rigid3 rig_from_cam = cam.model.cam_from_rig().Inverse();
    const Eigen::Vector3d o = rig_from_cam.translation;
    const Eigen::Vector3d d = rig_from_cam.rotation * Eigen::Vector3d::UnitZ();
    cv::arrowedLine(img, px(o), px(o + arrow_m * d), cv::Scalar(200, 80, 0), 2, cv::LINE_AA, 0,
                    0.2);
    cv::circle(img, px(o), 5, cv::Scalar(0, 0, 0), cv::FILLED, cv::LINE_AA);
    cv::putText(img, cam.name, px(o) + cv::Point(8, -8), cv::FONT_HERSHEY_SIMPLEX, 0.5,
                cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  }
  char text[160];
  std::snprintf(text, sizeof(text),
                "rig '%s' from above: cameras (blue: view), box (orange), "
                "boards (grey); %.3f m across",
                rig.name.c_str(), extent);
  cv::putText(img, text, cv::Point(8, size - 10), cv::FONT_HERSHEY_SIMPLEX, 0.4,
              cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  return FromBgr(img);
}

using Rows = std::vector<std::vector<std::string>>;

CalibrationSummary RunCalibration(const CalibrateConfig& config, const CalibrateInput& input,
                                  const std::string& out_dir, const CalibrationProgress& progress,
                                  CalibrationData* data_out) {
  if (input.images_dir.empty() == input.recording_dir.empty())
    throw InputError("calibrate: give either images or a recording");
  const std::string source = input.images_dir.empty() ? input.recording_dir : input.images_dir;
  if (!fs::is_directory(source)) throw InputError("calibrate: " + source + " is not a folder");
  // A simulated dataset's rig.yaml and cameras are its truth: calibrating into it would replace
  // them with the estimate they are meant to check.
  if (fs::exists(fs::path(out_dir) / "dataset.yaml"))
    throw InputError("calibrate: --out " + out_dir +
                     " holds a simulated dataset (dataset.yaml), whose rig.yaml and cameras/ are "
                     "the truth; write the calibration to another folder");
  BoardSpec board;
  const fs::path beside = fs::path(source) / "board.yaml";
  // A board given (--board, the config) that is not the one described beside the views: a square
  // size off by a factor scales the whole rig, and nothing in the solve can tell.
  std::string board_mismatch;
  if (config.board) {
    board = *config.board;
    if (fs::exists(beside)) {
      try {
        const BoardSpec there = LoadBoardSpec(beside.string());
        if (there.Describe() != board.Describe())
          board_mismatch = "the board given (" + board.Describe() + ") is not the one " +
                           beside.string() + " describes (" + there.Describe() +
                           "): the one given is used, and a wrong square size scales the whole "
                           "rig";
      } catch (const std::exception& e) {
        board_mismatch = "the board given is used; " + beside.string() +
                         " beside the views is not readable: " + e.what();
      }
      if (!board_mismatch.empty()) Log().warn("calibrate: {}", board_mismatch);
    }
  } else {
    if (!fs::exists(beside))
      throw InputError(
          "calibrate: no board described: give --board FILE, one in the config (board: or "
          "board_file:), or put a board.yaml beside the images or recording (" +
          beside.string() + " does not exist)");
    board = LoadBoardSpec(beside.string());
  }
  fs::create_directories(out_dir);
  const std::string cache = (fs::path(out_dir) / "detections.cache").string();
  CalibrationData data = input.images_dir.empty()
                             ? DetectViewsInRecording(input.recording_dir, board, config.cameras,
                                                      cache, config.detect, progress)
                             : DetectViewsInFolder(input.images_dir, board, config.cameras, cache,
                                                   config.detect, progress);
  if (data.unreadable > 0)
    Log().warn(
        "calibrate: {} frame(s) of {} could not be read (a damaged take) and are left out; "
        "the report lists each, and `flamerig recover --recording {}` lists the take's "
        "lost frames",
        data.unreadable, input.recording_dir, input.recording_dir);
  // Into a folder with an earlier calibration nothing but the detection cache is written until the
  // solve and the uncertainty are done, so that one that fails or is cancelled leaves it whole;
  // into a fresh folder the detections go first, for mrcal's tools when the solve fails.
  if (!fs::exists(fs::path(out_dir) / "rig.yaml"))
    WriteMrcalCorners(data, (fs::path(out_dir) / "corners.vnl").string(), "views");
  const char* kNotWritten =
      "; the calibration is not written (the detections are cached: a second run detects "
      "nothing again, and `uncertainty_trials: 0` calibrates without the uncertainty)";
  CalibrationSummary summary;
  try {
    summary = Calibrate(data, config.options, progress);
  } catch (const Cancelled& e) {
    throw Cancelled(e.what() + std::string(kNotWritten));
  }
  if (!board_mismatch.empty()) summary.notes.push_back("WARNING: " + board_mismatch);
  // Projection uncertainty over the box, in voxels of the grid `flamerig reconstruct` makes of it
  // by default.
  ProjectionUncertainty uncertainty;
  if (config.uncertainty_trials > 0) {
    const double voxel_m = summary.rig.box.size().maxCoeff() / ReconstructOptions{}.resolution;
    try {
      uncertainty = EstimateProjectionUncertainty(
          data, summary, config.options, config.uncertainty_trials, voxel_m, /*seed=*/1, progress);
    } catch (const Cancelled& e) {
      throw Cancelled(std::string(e.what()) + kNotWritten);
    } catch (const CalibrationError& e) {
      // The rig is still written; the report says why its uncertainty is missing.
      summary.notes.push_back(std::string("WARNING: projection uncertainty not computed: ") +
                              e.what());
    }
    for (const auto& w : uncertainty.warnings) summary.notes.push_back("WARNING: " + w);
  }
  // Each model carries the solve, as mrcal-calibrate-cameras's do, for mrcal's uncertainty tools.
  const std::string inputs = summary.mrcal_problem
                                 ? SerializeMrcalOptimizationInputs(*summary.mrcal_problem)
                                 : std::string();
  // Everything is written into a staging folder and then moved into OUT file by file (a rename
  // each), rig.yaml last: `run` takes a rig.yaml for a finished calibration, and a failure while
  // writing (a full disk) leaves the earlier calibration in OUT whole. A staging folder left by a
  // killed run is removed here.
  const fs::path stage = fs::path(out_dir) / ".calibrate-partial";
  fs::remove_all(stage);
  fs::create_directories(stage);
  struct RemovedOnExit {  // whether the calibration is written, fails or is cancelled
    fs::path path;
    ~RemovedOnExit() {
      std::error_code ignored;
      fs::remove_all(path, ignored);
    }
  } stage_guard{stage};
  WriteMrcalCorners(data, (stage / "corners.vnl").string(), "views");
  summary.rig.Save((stage / "rig.yaml").string());
  // And, from the solve, the valid-intrinsics region mrcal-calibrate-cameras writes (mrcal's own
  // function, pipeline/valid_region.h).
  std::vector<ValidRegion> regions;
  if (!inputs.empty()) {
    std::vector<std::string> model_paths;
    for (std::size_t c = 0; c < summary.rig.cameras.size(); ++c) {
      model_paths.push_back((stage / summary.rig.cameras[c].model_path).string());
      AddMrcalOptimizationInputs(model_paths.back(), inputs, static_cast<int>(c));
    }
    const ValidRegionParameters& region_parameters = config.valid_region;
    regions = AddValidIntrinsicsRegions(model_paths, region_parameters);
    for (std::size_t c = 0; c < regions.size(); ++c) {
      const ValidRegion& r = regions[c];
      const std::string& name = summary.rig.cameras[c].name;
      if (!r.computed) {
        summary.notes.push_back("WARNING: no valid-intrinsics region in " + name +
                                "'s model: " + r.error);
      } else if (r.contour.empty()) {
        summary.notes.push_back(fmt::format(
            "{}'s valid-intrinsics region is empty: mrcal's projection uncertainty {} is at "
            "least {:.3f} px (median {:.3f} px) over the image, above its threshold of {} x the "
            "residuals' {:.3f} px, or the corners in each part of the image are too few (mrcal "
            "asks for more than {} in each of its cells) or their residuals biased. More board "
            "views, nearer the camera and tilted, over the whole image, shrink it. The "
            "projection over the box is in the uncertainty section{}.",
            name, region_parameters.DistanceText(), r.min_uncertainty_px, r.median_uncertainty_px,
            FormatNumber(region_parameters.uncertainty), r.residual_sigma_px,
            region_parameters.count,
            region_parameters.distance_m > 0
                ? ""
                : "; `valid_intrinsics_region_parameters` can evaluate the region at the rig's "
                  "working distance"));
      }
    }
  }
  const std::vector<std::string> uncertainty_header = {"camera", "max px (1 sigma)", "mean px",
                                                       "max voxels"};
  Rows uncertainty_rows;
  for (const auto& cu : uncertainty.cameras)
    uncertainty_rows.push_back({cu.name, fmt::format("{:.3f}", cu.max_px),
                                fmt::format("{:.3f}", cu.mean_px),
                                fmt::format("{:.3f}", cu.max_voxels)});
  const std::string uncertainty_text =
      uncertainty.cameras.empty()
          ? "Not computed (uncertainty_trials: 0, or see the notes)."
          : fmt::format(
                "How far each camera's projection of the reconstruction box's points moves (1 "
                "sigma in the worst direction, a point held fixed relative to the boards: "
                "mrcal's 'worstdirection-stdev' with its mean-frames convention) when the corners "
                "carry the noise the solve found in them ({:.3f} px per coordinate): {} solves by "
                "Monte Carlo in {:.1f} s. Each figure is a standard deviation from {} samples, "
                "uncertain by about {:.0f}% of itself (1 / sqrt(2 (N - 1)); the largest leans "
                "high by about as much); more `uncertainty_trials` narrow it (5% at 200). "
                "mrcal's linearised figure comes from the models themselves, which carry the "
                "solve's optimization_inputs: mrcal-show-projection-uncertainty "
                "cameras/<camera>.cameramodel. Voxels: of the default {}-voxel grid ({:.2f} mm). "
                "Over half a voxel, the reconstruction is limited by the calibration.",
                uncertainty.noise_px, uncertainty.trials, uncertainty.time_s, uncertainty.trials,
                100 / std::sqrt(2.0 * (uncertainty.trials - 1)), ReconstructOptions{}.resolution,
                uncertainty.voxel_m * 1e3);

  // The report: the same tables as Markdown (report.md) and as a page (index.html).
  const std::vector<std::string> camera_header = {
      "camera",    "views",  "corners", "outliers",      "RMS px",
      "median px", "p95 px", "max px",  "image covered", "valid region"};
  Rows camera_rows;
  for (std::size_t c = 0; c < summary.cameras.size(); ++c) {
    const auto& s = summary.cameras[c];
    double covered = 0;
    WritePng((stage / kCameraPictures[kCoverage].File(s.name)).string(),
             CoveragePicture(data, summary, static_cast<int>(c), &covered,
                             c < regions.size() ? &regions[c] : nullptr));
    WritePng((stage / kCameraPictures[kResiduals].File(s.name)).string(),
             ResidualVectorsPicture(data, summary, static_cast<int>(c)));
    WritePng((stage / kCameraPictures[kPerImage].File(s.name)).string(),
             ResidualsPerImagePicture(data, summary, static_cast<int>(c)));
    camera_rows.push_back({s.name, std::to_string(s.views), std::to_string(s.points),
                           std::to_string(s.outliers), fmt::format("{:.3f}", s.rms_px_per_point),
                           fmt::format("{:.3f}", s.median_px), fmt::format("{:.3f}", s.p95_px),
                           fmt::format("{:.3f}", s.max_px), fmt::format("{:.0f}%", 100 * covered),
                           c < regions.size() && regions[c].computed
                               ? fmt::format("{:.0f}%", 100 * regions[c].imager_fraction)
                               : std::string("-")});
  }
  const std::vector<std::string> worst_header = {"camera", "view", "corner", "error px"};
  Rows worst_rows;
  for (const auto& e : summary.worst)
    worst_rows.push_back({data.camera_names[e.camera], data.view_names[e.view],
                          std::to_string(e.corner), fmt::format("{:.3f}", e.error_px)});
  const std::vector<std::string> pose_header = {"camera", "centre m", "viewing direction"};
  Rows pose_rows;
  for (const auto& cam : summary.rig.cameras) {
    const Rigid3 rig_from_cam = cam.model.cam_from_rig().Inverse();
    const Eigen::Vector3d o = rig_from_cam.translation,
                          d = rig_from_cam.rotation * Eigen::Vector3d::UnitZ();
    pose_rows.push_back({cam.name, fmt::format("({:.4f}, {:.4f}, {:.4f})", o.x(), o.y(), o.z()),
                         fmt::format("({:.3f}, {:.3f}, {:.3f})", d.x(), d.y(), d.z())});
  }
  std::vector<std::string> notes = summary.notes;
  // Every image without a board and every corner found but left out, with the reason.
  const std::vector<std::string> refused_header = {"camera", "image", "why no board"};
  Rows refused_rows;
  for (std::size_t c = 0; c < data.camera_names.size(); ++c)
    for (const auto& f : data.failures_per_camera[c]) {
      const std::size_t colon = f.find(": ");
      refused_rows.push_back({data.camera_names[c], f.substr(0, colon),
                              colon == std::string::npos ? "" : f.substr(colon + 2)});
    }
  const std::vector<std::string> dropped_header = {"camera", "image", "corner", "at px", "why"};
  Rows dropped_rows;
  for (const auto& o : data.observations)
    for (const auto& r : o.detection.rejected)
      dropped_rows.push_back({data.camera_names[o.camera], o.source, std::to_string(r.corner_id),
                              fmt::format("({:.1f}, {:.1f})", r.px.x(), r.px.y()), r.reason});
  WritePng((stage / "rig_top.png").string(), RigFromAbove(summary));
  std::ostringstream mrcal;
  mrcal << "mrcal-calibrate-cameras --corners-cache corners.vnl --lensmodel "
        << config.options.lensmodel << " --focal F --object-spacing " << board.square_m
        << " --object-width-n " << board.corners_x() << " --object-height-n " << board.corners_y();
  for (std::size_t c = 0; c < data.camera_names.size(); ++c) {
    std::string ext = ".png";
    for (const auto& o : data.observations)
      if (o.camera == static_cast<int>(c)) {
        ext = MrcalImageExtension(o.source);
        break;
      }
    mrcal << " 'views/*/" << data.camera_names[c] << ext << "'";
  }
  std::ostringstream header;
  header << "Board: " << board.Describe() << ". Lens model: " << config.options.lensmodel
         << ". Detection: " << data.detected << " images detected, " << data.from_cache
         << " from the cache"
         << (data.unreadable > 0
                 ? ", " + std::to_string(data.unreadable) + " frames unreadable (damaged)"
                 : std::string())
         << ", in " << data.detect_time_s << " s. Solve: " << summary.solve_time_s << " s.";
  const std::string rms_note = fmt::format(
      "The RMS per point is sqrt(mean(dx^2 + dy^2)) over inlier corners; per coordinate "
      "(mrcal's convention) it is smaller by sqrt(2). mrcal-calibrate-cameras prints a smaller "
      "figure still: it divides by every board corner, the outliers and the corners not detected "
      "included. The valid region is the share of the image inside the valid-intrinsics region "
      "each model carries, as mrcal-calibrate-cameras computes it (mrcal's own function, "
      "--valid-intrinsics-region-parameters {}{}): where the projection {} is certain and the "
      "residuals are small and unbiased; mrcal-show-valid-intrinsics-region "
      "cameras/<camera>.cameramodel draws it.",
      config.valid_region.ToMrcal(),
      config.valid_region.ToMrcal() == ValidRegionParameters().ToMrcal() ? ", its defaults" : "",
      config.valid_region.DistanceText());

  std::ostringstream md;
  auto md_table = [&md](const std::vector<std::string>& head, const Rows& rows) {
    for (const auto& h : head) md << "| " << h << " ";
    md << "|\n";
    for (std::size_t k = 0; k < head.size(); ++k) md << "|---";
    md << "|\n";
    for (const auto& row : rows) {
      for (const auto& cell : row) md << "| " << cell << " ";
      md << "|\n";
    }
  };
  md << "# Calibration of rig '" << summary.rig.name << "'\n\n"
     << header.str() << "\n\n```\n"
     << summary.BriefReport() << "```\n\n"
     << rms_note << "\n\n";
  md_table(camera_header, camera_rows);
  md << "\n## Projection uncertainty over the box\n\n" << uncertainty_text << "\n\n";
  if (!uncertainty_rows.empty()) md_table(uncertainty_header, uncertainty_rows);
  md << "\n## Worst corners (inliers)\n\n";
  md_table(worst_header, worst_rows);
  md << "\n## Camera poses (rig frame)\n\n";
  md_table(pose_header, pose_rows);
  md << "\n## Images without a board (" << refused_rows.size() << ")\n\n";
  if (!refused_rows.empty()) md_table(refused_header, refused_rows);
  md << "\n## Corners found but left out by the consistency check (" << dropped_rows.size()
     << ")\n\n";
  if (!dropped_rows.empty()) md_table(dropped_header, dropped_rows);
  md << "\n## Notes\n\n";
  for (const auto& n : notes) md << "- " << n << "\n";
  md << "\n![rig from above](rig_top.png)\n\n";
  for (const auto& s : summary.cameras)
    for (const CameraPicture& picture : kCameraPictures)
      md << "![" << picture.alt << " " << s.name << "](" << picture.File(s.name) << ")\n";
  // mrcal 2.2 seeds its board poses from every corner, missing ones included (calibrate.h's
  // WriteMrcalCorners): its solve of part boards starts far off.
  int part_boards = 0;
  for (const auto& o : data.observations)
    if (static_cast<int>(o.detection.corner_ids.size()) < board.num_corners()) ++part_boards;
  const std::string mrcal_caveat =
      part_boards == 0
          ? std::string()
          : fmt::format(
                " Caution: {} of the {} board views hold part of the board, and mrcal "
                "2.2's tool seeds its solve from every corner, the missing ones' "
                "placeholders included, so on them it does not find this solve (measured "
                "on part ChArUco views: 3.5 px RMS, a third of the corners outliers); it "
                "reproduces this one on whole boards.",
                part_boards, data.observations.size());
  md << "\nTo solve the same detections with mrcal's own tool: `" << mrcal.str()
     << "` (with `--imagersize W H` since the paths are virtual)." << mrcal_caveat << "\n";

  ReportPage page("Calibration of rig '" + summary.rig.name + "'",
                  {{"images", input.images_dir.empty() ? input.recording_dir : input.images_dir}});
  page.Text(header.str());
  page.Html("<pre>" + HtmlEscape(summary.BriefReport()) + "</pre>");
  page.Section("Residuals per camera");
  page.Text(rms_note);
  page.Table(camera_header, camera_rows);
  for (const auto& s : summary.cameras)
    for (const CameraPicture& picture : kCameraPictures)
      page.Figure(picture.File(s.name), s.name + picture.caption);
  page.Section("Projection uncertainty over the box");
  page.Text(uncertainty_text);
  if (!uncertainty_rows.empty()) page.Table(uncertainty_header, uncertainty_rows);
  page.Section("The rig");
  page.Table(pose_header, pose_rows);
  page.Figure("rig_top.png",
              "The rig from above: cameras and their views, the reconstruction "
              "box and the boards.");
  page.Section("Worst corners (inliers)");
  page.Table(worst_header, worst_rows);
  page.Section("Images without a board (" + std::to_string(refused_rows.size()) + ")");
  if (!refused_rows.empty()) page.Table(refused_header, refused_rows);
  page.Section("Corners found but left out by the consistency check (" +
               std::to_string(dropped_rows.size()) + ")");
  if (!dropped_rows.empty()) page.Table(dropped_header, dropped_rows);
  if (!notes.empty()) {
    page.Section("Notes");
    page.List([&] {
      std::vector<std::string> items;
      for (const auto& n : notes) items.push_back(HtmlEscape(n));
      return items;
    }());
  }
  page.Section("Data");
  page.Files({{"rig.yaml", "the calibrated rig"},
              {"cameras/", "each camera as an mrcal .cameramodel"},
              {"corners.vnl", "every detected corner, in mrcal's corners-cache format"},
              {"report.md", "this report as Markdown"}});
  page.Html("The same detections through mrcal's own tool: <code>" + HtmlEscape(mrcal.str()) +
            "</code> (with <code>--imagersize W H</code>, the paths being virtual)." +
            HtmlEscape(mrcal_caveat));
  page.Write((stage / "index.html").string());
  WriteFileAtomically((stage / "report.md").string(), md.str());
  // The last chance to stop: nothing of this calibration is in OUT yet.
  Progress writing;
  writing.stage = "write";
  writing.unit = "files";
  if (ReportProgress(progress, writing))
    throw Cancelled(std::string("calibration: cancelled before writing") + kNotWritten);
  // What an earlier calibration in OUT wrote for cameras this one does not have (a rig that had
  // more cameras): removed once the new rig.yaml is in place, so that cameras/*.cameramodel, which
  // mrcal's tools take by the folder, holds this rig's cameras only. Files it did not write stay.
  std::vector<fs::path> stale;
  if (fs::exists(fs::path(out_dir) / "rig.yaml")) {
    try {
      const Rig earlier = Rig::Load((fs::path(out_dir) / "rig.yaml").string());
      for (const RigCamera& c : earlier.cameras) {
        if (summary.rig.FindCamera(c.name) >= 0) continue;
        // Only the model where calibrate writes it: a rig.yaml edited to name a model elsewhere
        // (outside OUT) keeps that file.
        if (fs::path(c.model_path) == fs::path("cameras") / (c.name + ".cameramodel"))
          stale.push_back(fs::path(out_dir) / c.model_path);
        for (const CameraPicture& picture : kCameraPictures)
          stale.push_back(fs::path(out_dir) / picture.File(c.name));
      }
    } catch (const std::exception& e) {
      Log().warn("calibrate: the earlier {}/rig.yaml is not readable ({}); its files are left",
                 out_dir, e.what());
    }
  }
  std::vector<fs::path> files;
  for (const auto& e : fs::recursive_directory_iterator(stage))
    if (e.is_regular_file() && e.path() != stage / "rig.yaml") files.push_back(e.path());
  files.push_back(stage / "rig.yaml");
  for (const fs::path& f : files) {
    const fs::path to = fs::path(out_dir) / fs::relative(f, stage);
    fs::create_directories(to.parent_path());
    fs::rename(f, to);
  }
  for (const fs::path& f : stale) {
    std::error_code ignored;
    fs::remove(f, ignored);
  }
  if (data_out) *data_out = std::move(data);
  return summary;
}

}  // namespace flamerig
