#include "calibration/calibrate.h"

#include <tbb/parallel_for.h>
#include <zlib.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <mutex>
#include <numeric>
#include <opencv2/calib3d.hpp>
#include <queue>
#include <random>
#include <set>
#include <sstream>

#include <spdlog/fmt/fmt.h>

#include "acquisition/frame.h"
#include "acquisition/recording.h"
#include "calibration/mrcal_inputs.h"
#include "core/atomic_file.h"
#include "core/error.h"
#include "core/read_file.h"

extern "C" {
#include <mrcal/mrcal.h>
}

namespace flamerig {

namespace fs = std::filesystem;

void CalibrationOptions::Validate() const {
  mrcal_lensmodel_t lm;
  if (!mrcal_lensmodel_from_name(&lm, lensmodel.c_str()) || !mrcal_lensmodel_type_is_valid(lm.type))
    throw InputError("calibrate.lensmodel: '" + lensmodel + "' is not an mrcal lens model name");
  const mrcal_lensmodel_metadata_t meta = mrcal_lensmodel_metadata(&lm);
  if (!meta.has_core)
    throw InputError("calibrate.lensmodel: '" + lensmodel +
                     "' has no fx fy cx cy core; use a PINHOLE or OPENCV model");
  // mrcal_optimize needs the model's gradients, which CAHVORE does not have (mrcal aborts).
  if (!meta.has_gradients)
    throw InputError("calibrate.lensmodel: '" + lensmodel +
                     "' has no gradients in mrcal, so mrcal cannot solve for it; use CAHVOR or an "
                     "OPENCV or SPLINED_STEREOGRAPHIC model");
  // mrcal's splines are quadratic or cubic, on a grid of at least order + 1 knots a side (it
  // aborts otherwise).
  if (lm.type == MRCAL_LENSMODEL_SPLINED_STEREOGRAPHIC) {
    const auto& cfg = lm.LENSMODEL_SPLINED_STEREOGRAPHIC__config;
    if (cfg.order != 2 && cfg.order != 3)
      throw InputError("calibrate.lensmodel: '" + lensmodel + "': order must be 2 or 3, got " +
                       std::to_string(cfg.order));
    if (cfg.Nx < cfg.order + 1 || cfg.Ny < cfg.order + 1)
      throw InputError("calibrate.lensmodel: '" + lensmodel + "': Nx and Ny must be at least " +
                       std::to_string(cfg.order + 1) + " for order " + std::to_string(cfg.order));
    if (cfg.fov_x_deg == 0 || cfg.fov_x_deg >= 360)
      throw InputError("calibrate.lensmodel: '" + lensmodel + "': fov_x_deg must be in (0, 360)");
  }
  if (!(focal_px >= 0 && focal_px <= 1e6))
    throw InputError("calibrate.focal_px: must be 0 (estimate) or a focal length in (0, 1e6] px");
  if (min_views_per_camera < 1) throw InputError("calibrate.min_views_per_camera: must be >= 1");
  if (!ring_origin_m.allFinite()) throw InputError("calibrate.ring_origin: must be finite");
  if (rig_name.empty()) throw InputError("calibrate.name: must not be empty");
}

// ---- Detection
// ----------------------------------------------------------------------------------

int ParseDetectionCache(const std::string& text, const BoardSpec& board,
                        const DetectOptions& detect,
                        std::map<std::string, BoardDetection>* entries) {
  std::istringstream in(text);
  std::string line;
  if (!std::getline(in, line) || line != "# flamerig board detections v2") return 0;
  if (!std::getline(in, line) || line != "board " + board.Describe()) return 0;  // another board
  if (!std::getline(in, line) || line != "detect " + detect.Describe()) return 0;
  const int corners = board.num_corners();
  std::map<std::string, BoardDetection> read;
  std::set<std::string> bad;
  while (std::getline(in, line)) {
    std::istringstream s(line);
    std::string key, second;
    if (!(s >> key >> second)) continue;
    if (second == "detector" || second == "reject") {
      auto it = read.find(key);
      if (it == read.end()) continue;
      if (second == "detector") {
        std::string name;
        s >> name;
        if (name == "sb" || name == "classic" || name == "charuco")
          it->second.detector = name;
        else
          bad.insert(key);
        continue;
      }
      RejectedCorner r;
      const std::vector<int>& kept_ids = it->second.corner_ids;
      const auto& rejected = it->second.rejected;
      // A corner of this board, found, not also kept, in ascending order.
      const bool good = it->second.found() &&
                        static_cast<bool>(s >> r.corner_id >> r.px.x() >> r.px.y()) &&
                        r.corner_id >= 0 && r.corner_id < corners && r.px.allFinite() &&
                        !std::binary_search(kept_ids.begin(), kept_ids.end(), r.corner_id) &&
                        (rejected.empty() || r.corner_id > rejected.back().corner_id);
      if (!good) {
        bad.insert(key);
        continue;
      }
      s >> std::ws;
      std::getline(s, r.reason);
      it->second.rejected.push_back(std::move(r));
      continue;
    }
    long long n = 0;
    try {
      std::size_t used = 0;
      n = std::stoll(second, &used);
      if (used != second.size()) n = -1;
    } catch (const std::exception&) {
      n = -1;
    }
    // A detection DetectBoard would not have kept (fewer corners than it asks for) is as bad as a
    // malformed line: the image is detected again.
    if (n < 0 || n > corners || (n > 0 && n < detect.min_corners)) {
      bad.insert(key);
      continue;
    }
    BoardDetection d;
    if (n == 0) {
      s >> std::ws;
      std::getline(s, d.failure);
      if (d.failure.empty()) d.failure = "no board";
    }
    bool good = true;
    for (long long i = 0; good && i < n; ++i) {
      int id;
      double x, y;
      // A corner of this board, at a finite position, in ascending order (so never twice).
      good = static_cast<bool>(s >> id >> x >> y) && id >= 0 && id < corners && std::isfinite(x) &&
             std::isfinite(y) && (d.corner_ids.empty() || id > d.corner_ids.back());
      if (good) {
        d.corner_ids.push_back(id);
        d.corners_px.emplace_back(x, y);
      }
    }
    if (good && n > 0) {  // nothing may follow the corners
      s >> std::ws;
      good = s.eof();
    }
    if (!good) {
      bad.insert(key);
      continue;
    }
    read[key] = std::move(d);
    bad.erase(key);
  }
  int kept = 0;
  for (auto& [key, d] : read) {
    if (bad.count(key)) continue;
    (*entries)[key] = std::move(d);
    ++kept;
  }
  return kept;
}

namespace {

// Cached detections, keyed by "<crc32 of the pixels>_<width>x<height>".
class DetectionCache {
 public:
  DetectionCache(std::string path, const BoardSpec& board, const DetectOptions& detect)
      : path_(std::move(path)), board_(board.Describe()), detect_(detect.Describe()) {
    if (path_.empty()) return;
    const std::optional<std::string> text = ReadFileIfPresent(path_);
    if (!text) return;
    ParseDetectionCache(*text, board, detect, &entries_);
  }

  bool Find(const std::string& key, BoardDetection* d) const {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = entries_.find(key);
    if (it == entries_.end()) return false;
    *d = it->second;
    return true;
  }
  void Put(const std::string& key, const BoardDetection& d) {
    std::lock_guard<std::mutex> lock(mutex_);
    entries_[key] = d;
    dirty_ = true;
  }
  // Written to a temporary file and renamed, so that a killed run never leaves a torn cache.
  void Save() const {
    if (path_.empty() || !dirty_) return;
    std::ostringstream out;
    out << "# flamerig board detections v2\nboard " << board_ << "\ndetect " << detect_ << "\n";
    char buf[64];
    for (const auto& [key, d] : entries_) {
      out << key << " " << d.corner_ids.size();
      if (!d.found()) out << " " << d.failure;
      for (std::size_t i = 0; i < d.corner_ids.size(); ++i) {
        std::snprintf(buf, sizeof(buf), " %d %.9g %.9g", d.corner_ids[i], d.corners_px[i].x(),
                      d.corners_px[i].y());
        out << buf;
      }
      out << "\n";
      if (!d.detector.empty()) out << key << " detector " << d.detector << "\n";
      for (const auto& r : d.rejected) {
        std::snprintf(buf, sizeof(buf), " %d %.9g %.9g ", r.corner_id, r.px.x(), r.px.y());
        out << key << " reject" << buf << r.reason << "\n";
      }
    }
    WriteFileAtomically(path_, out.str());
  }

 private:
  std::string path_, board_, detect_;
  std::map<std::string, BoardDetection> entries_;
  mutable std::mutex mutex_;
  bool dirty_ = false;
};

std::string PixelKey(const ImageU8& image) {
  const uLong crc = crc32_z(0L, image.pixels.data(), image.pixels.size());
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%08lx_%dx%d", static_cast<unsigned long>(crc), image.width,
                image.height);
  return buf;
}

// One image to detect in: where it comes from and how to load it (as 8-bit grey).
struct DetectJob {
  int view = 0, camera = 0;
  std::string source;
  std::function<ImageU8()> load;
};

struct DetectResult {
  BoardDetection detection;
  std::string unreadable;  // a recording's frame that did not read: why
  int width = 0, height = 0;
  bool cached = false;
};

CalibrationData RunDetection(CalibrationData data, std::vector<DetectJob> jobs,
                             const std::string& cache_path, const DetectOptions& detect,
                             const CalibrationProgress& progress) {
  const auto start = std::chrono::steady_clock::now();
  data.board.Validate();
  DetectionCache cache(cache_path, data.board, detect);
  std::vector<DetectResult> results(jobs.size());
  std::vector<std::string> errors(jobs.size());
  std::atomic<int> done{0};
  std::atomic<bool> cancelled{false};
  std::mutex progress_mutex;
  tbb::parallel_for(std::size_t{0}, jobs.size(), [&](std::size_t i) {
    if (cancelled) return;
    try {
      ImageU8 image = jobs[i].load();
      results[i].width = image.width;
      results[i].height = image.height;
      const std::string key = PixelKey(image);
      if (cache.Find(key, &results[i].detection)) {
        results[i].cached = true;
      } else {
        results[i].detection = DetectBoard(image, data.board, detect);
        cache.Put(key, results[i].detection);
      }
    } catch (const RecordingError& e) {  // a damaged take costs the frames it touches
      results[i].unreadable = e.what();
    } catch (const std::exception& e) {
      errors[i] = e.what();
    }
    const int n = ++done;
    if (progress) {
      std::lock_guard<std::mutex> lock(progress_mutex);
      Progress p;
      p.stage = "detect";
      p.unit = "images";
      p.done = n;
      p.total = static_cast<std::int64_t>(jobs.size());
      if (!cancelled && progress(p) == ProgressAction::kCancel) cancelled = true;
    }
  });
  cache.Save();  // keep what was detected even when an image below is refused
  if (cancelled) throw Cancelled("calibration: cancelled during board detection");
  for (std::size_t i = 0; i < jobs.size(); ++i)
    if (!errors[i].empty()) {
      const std::string& e = errors[i];
      throw CalibrationError(
          e.find(jobs[i].source) != std::string::npos ? e : jobs[i].source + ": " + e);
    }
  const std::size_t num_cameras = data.camera_names.size();
  data.widths.assign(num_cameras, 0);
  data.heights.assign(num_cameras, 0);
  data.images_per_camera.assign(num_cameras, 0);
  data.failures_per_camera.assign(num_cameras, {});
  std::vector<std::string> size_source(num_cameras);
  for (std::size_t i = 0; i < jobs.size(); ++i) {
    const DetectJob& job = jobs[i];
    DetectResult& r = results[i];
    const int c = job.camera;
    if (!r.unreadable.empty()) {
      ++data.images_per_camera[c];
      ++data.unreadable;
      data.failures_per_camera[c].push_back(job.source + ": unreadable (" + r.unreadable + ")");
      continue;
    }
    if (data.widths[c] == 0) {
      data.widths[c] = r.width;
      data.heights[c] = r.height;
      size_source[c] = job.source;
    } else if (data.widths[c] != r.width || data.heights[c] != r.height) {
      throw CalibrationError(job.source + ": camera " + data.camera_names[c] + "'s image is " +
                             std::to_string(r.width) + "x" + std::to_string(r.height) +
                             " but its image " + size_source[c] + " is " +
                             std::to_string(data.widths[c]) + "x" +
                             std::to_string(data.heights[c]));
    }
    ++data.images_per_camera[c];
    (r.cached ? data.from_cache : data.detected)++;
    if (r.detection.found()) {
      data.observations.push_back(
          BoardObservation{c, job.view, job.source, std::move(r.detection)});
    } else {
      data.failures_per_camera[c].push_back(job.source + ": " + r.detection.failure);
    }
  }
  std::stable_sort(data.observations.begin(), data.observations.end(),
                   [](const BoardObservation& a, const BoardObservation& b) {
                     return a.view != b.view ? a.view < b.view : a.camera < b.camera;
                   });
  data.detect_time_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return data;
}

// Camera names in the requested order, checked against what is there.
std::vector<std::string> OrderCameras(const std::set<std::string>& found,
                                      const std::vector<std::string>& requested,
                                      const std::string& where) {
  if (found.empty()) throw CalibrationError(where + ": no camera images found");
  if (requested.empty()) return {found.begin(), found.end()};
  for (std::size_t i = 0; i < requested.size(); ++i)
    for (std::size_t j = 0; j < i; ++j)
      if (requested[i] == requested[j])
        throw CalibrationError(where + ": camera " + requested[i] +
                               " is listed twice in 'cameras'");
  for (const auto& name : requested)
    if (!found.count(name))
      throw CalibrationError(where + ": camera " + name + " has no images there");
  return requested;
}

// An image file by its extension, in any case (.png, .JPG, .jpeg, ...).
bool IsImageFile(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char ch) { return static_cast<char>(std::tolower(ch)); });
  for (const char* known : {".png", ".pgm", ".ppm", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp"})
    if (ext == known) return true;
  return false;
}

ImageU8 ToGrey(const ImageU8& image) {
  if (image.channels == 1) return image;
  ImageU8 grey(image.width, image.height, 1);
  for (std::size_t p = 0; p < grey.num_pixels(); ++p) {
    const std::uint8_t* rgb = &image.pixels[p * image.channels];
    grey.pixels[p] =
        static_cast<std::uint8_t>(std::lround(0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2]));
  }
  return grey;
}

// An 8-bit frame as it is; a 16-bit one scaled to 8 bits by its own top (full-scale words, and a
// deeper camera's codes in their low bits, alike), for the board's detection.
ImageU8 To8Bit(int bits, ImageU8 u8, const ImageU16& u16) {
  if (bits != 16) return u8;
  std::uint16_t top = 255;
  for (std::uint16_t v : u16.pixels) top = std::max(top, v);
  u8 = ImageU8(u16.width, u16.height, u16.channels);
  for (std::size_t i = 0; i < u16.pixels.size(); ++i)
    u8.pixels[i] = static_cast<std::uint8_t>((u16.pixels[i] * 255u + top / 2) / top);
  return u8;
}

}  // namespace

CalibrationData DetectViewsInFolder(const std::string& dir, const BoardSpec& board,
                                    const std::vector<std::string>& cameras,
                                    const std::string& cache_path, const DetectOptions& detect,
                                    const CalibrationProgress& progress) {
  if (!fs::is_directory(dir)) throw CalibrationError(dir + ": not a folder of board views");
  std::vector<fs::path> view_dirs;
  for (const auto& e : fs::directory_iterator(dir))
    if (e.is_directory()) view_dirs.push_back(e.path());
  std::sort(view_dirs.begin(), view_dirs.end());
  std::set<std::string> found;
  std::vector<std::vector<fs::path>> images(view_dirs.size());
  for (std::size_t v = 0; v < view_dirs.size(); ++v) {
    for (const auto& e : fs::directory_iterator(view_dirs[v])) {
      if (!e.is_regular_file() || !IsImageFile(e.path())) continue;
      images[v].push_back(e.path());
      found.insert(e.path().stem().string());
    }
    std::sort(images[v].begin(), images[v].end());
  }
  CalibrationData data;
  data.board = board;
  data.camera_names = OrderCameras(found, cameras, dir);
  std::map<std::string, int> index;
  for (std::size_t c = 0; c < data.camera_names.size(); ++c) index[data.camera_names[c]] = c;
  std::vector<DetectJob> jobs;
  for (std::size_t v = 0; v < view_dirs.size(); ++v) {
    if (images[v].empty()) continue;
    const int view = static_cast<int>(data.view_names.size());
    data.view_names.push_back(view_dirs[v].filename().string());
    for (const auto& path : images[v]) {
      auto it = index.find(path.stem().string());
      if (it == index.end()) continue;  // a camera not asked for
      const std::string p = path.string();
      jobs.push_back(DetectJob{view, it->second, p, [p] {
                                 ImageU8 u8;
                                 ImageU16 u16;
                                 const int bits = ReadImage(p, &u8, &u16, 1);
                                 return ToGrey(To8Bit(bits, std::move(u8), u16));
                               }});
    }
  }
  return RunDetection(std::move(data), std::move(jobs), cache_path, detect, progress);
}

CalibrationData DetectViewsInRecording(const std::string& recording_dir, const BoardSpec& board,
                                       const std::vector<std::string>& cameras,
                                       const std::string& cache_path, const DetectOptions& detect,
                                       const CalibrationProgress& progress) {
  auto recording = std::make_shared<Recording>(Recording::Open(recording_dir));
  std::set<std::string> found;
  for (const auto& cam : recording->metadata().cameras) found.insert(cam.name);
  CalibrationData data;
  data.board = board;
  data.camera_names = OrderCameras(found, cameras, recording_dir);
  std::map<std::string, int> index;
  for (std::size_t c = 0; c < data.camera_names.size(); ++c) index[data.camera_names[c]] = c;
  std::vector<DetectJob> jobs;
  for (std::size_t s = 0; s < recording->num_sets(); ++s) {
    char name[32];
    std::snprintf(name, sizeof(name), "set_%06zu", s);
    const int view = static_cast<int>(data.view_names.size());
    data.view_names.push_back(name);
    for (int rc = 0; rc < recording->num_cameras(); ++rc) {
      // A frame lost to a damaged file is tried too: its read fails and the reason is listed.
      if (!recording->HasFrame(s, rc) && !recording->FrameLost(s, rc)) continue;
      auto it = index.find(recording->metadata().cameras[rc].name);
      if (it == index.end()) continue;
      const std::string source = recording_dir + " set " + std::to_string(s) + " camera " +
                                 recording->metadata().cameras[rc].name;
      jobs.push_back(DetectJob{view, it->second, source, [recording, s, rc, source] {
                                 std::optional<Frame> frame = recording->ReadFrame(s, rc);
                                 ImageU8 u8;
                                 ImageU16 u16;
                                 const int bits = DecodeFrame(*frame, &u8, &u16);
                                 return ToGrey(To8Bit(bits, std::move(u8), u16));
                               }});
    }
  }
  return RunDetection(std::move(data), std::move(jobs), cache_path, detect, progress);
}

// ---- The solve
// ----------------------------------------------------------------------------------

namespace {

Rigid3 FromCv(const cv::Mat& rvec, const cv::Mat& tvec) {
  std::array<double, 6> rt{rvec.at<double>(0), rvec.at<double>(1), rvec.at<double>(2),
                           tvec.at<double>(0), tvec.at<double>(1), tvec.at<double>(2)};
  return Rigid3::FromRt(rt);
}

mrcal_point3_t Point3(double x, double y, double z) {
  mrcal_point3_t p;
  p.x = x;
  p.y = y;
  p.z = z;
  return p;
}

mrcal_pose_t ToMrcal(const Rigid3& pose) {
  const auto rt = pose.ToRt();
  mrcal_pose_t p;
  p.r = Point3(rt[0], rt[1], rt[2]);
  p.t = Point3(rt[3], rt[4], rt[5]);
  return p;
}

Rigid3 FromMrcal(const mrcal_pose_t& p) {
  return Rigid3::FromRt(std::array<double, 6>{p.r.x, p.r.y, p.r.z, p.t.x, p.t.y, p.t.z});
}

double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<std::size_t>(q * (v.size() - 1) + 0.5))];
}

// The rig frame kRing: see calibrate.h. Returns rig_from_ref.
Rigid3 RingFrame(const std::vector<Rigid3>& cam_from_ref) {
  const int n = static_cast<int>(cam_from_ref.size());
  Eigen::Matrix3d a = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero(), down = Eigen::Vector3d::Zero();
  std::vector<Eigen::Vector3d> centres;
  for (const auto& pose : cam_from_ref) {
    const Rigid3 ref_from_cam = pose.Inverse();
    const Eigen::Vector3d c = ref_from_cam.translation;
    const Eigen::Vector3d d = ref_from_cam.rotation * Eigen::Vector3d::UnitZ();
    const Eigen::Matrix3d p = Eigen::Matrix3d::Identity() - d * d.transpose();
    a += p;
    b += p * c;
    down += ref_from_cam.rotation * Eigen::Vector3d::UnitY();
    centres.push_back(c);
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(a);
  if (n < 2 || eig.eigenvalues()(0) < 1e-3 * n)
    throw CalibrationError(
        "rig frame 'ring': the cameras' optical axes do not meet (fewer than two cameras, or "
        "parallel axes); use frame: first-camera (the default)");
  const Eigen::Vector3d origin = a.ldlt().solve(b);
  if (down.norm() < 1e-9)
    throw CalibrationError("rig frame 'ring': the cameras' image-down directions cancel out");
  const Eigen::Vector3d up = -down.normalized();
  Eigen::Vector3d z = centres[0] - origin;
  z -= z.dot(up) * up;
  if (z.norm() < 1e-9) {  // the first camera straight above or below: use its viewing direction
    z = -(cam_from_ref[0].Inverse().rotation * Eigen::Vector3d::UnitZ());
    z -= z.dot(up) * up;
  }
  z.normalize();
  const Eigen::Vector3d x = up.cross(z);
  Eigen::Matrix3d r;
  r.row(0) = x;
  r.row(1) = up;
  r.row(2) = z;
  return Rigid3(Eigen::Quaterniond(r), -(r * origin));
}

// A board corner bowed by mrcal's calobject_warp: mrcal moves each corner of its object (first
// corner at its origin, spacing s, W x H corners) along z by x2 * (1 - xr^2) + y2 * (1 - yr^2),
// with xr, yr its position scaled to [-1, 1] across the corners (mrcal's board_reference_points).
// Our board frame has the first corner one square in, on the same axes.
Eigen::Vector3d WarpedCorner(const Eigen::Vector3d& corner, const BoardSpec& board,
                             const mrcal_calobject_warp_t& warp) {
  const int w = board.corners_x(), h = board.corners_y();
  const double i = corner.x() / board.square_m - 1, j = corner.y() / board.square_m - 1;
  const double xr = w > 1 ? 2 * i / (w - 1) - 1 : 0, yr = h > 1 ? 2 * j / (h - 1) - 1 : 0;
  return corner + Eigen::Vector3d(0, 0, warp.x2 * (1 - xr * xr) + warp.y2 * (1 - yr * yr));
}

// When detection refused images because their corners did not fit the board (board.cc: "wrong
// board size or dictionary?"), a sentence saying how many, for the errors that follow from too few
// views; otherwise empty.
// `camera` >= 0: that camera's images only.
std::string BoardMisfitHint(const CalibrationData& data, int camera = -1) {
  int misfit = 0, images = 0;
  for (std::size_t c = 0; c < data.failures_per_camera.size(); ++c)
    if (camera < 0 || static_cast<int>(c) == camera)
      for (const auto& f : data.failures_per_camera[c])
        if (f.find("wrong board size") != std::string::npos) ++misfit;
  for (std::size_t c = 0; c < data.images_per_camera.size(); ++c)
    if (camera < 0 || static_cast<int>(c) == camera) images += data.images_per_camera[c];
  if (misfit == 0) return "";
  return "; " + std::to_string(misfit) + " of " + std::to_string(images) +
         (camera < 0 ? " images" : " of its images") +
         " were refused because their corners do not fit the board described (" +
         data.board.Describe() + "): check its squares, square size and dictionary";
}

// A solve can converge on nonsense: a board described with the wrong number of squares puts every
// corner at the wrong place, and mrcal then fits a focal length under a pixel at 45 px RMS. Such a
// calibration is refused (not written): intrinsics no lens gives (a focal length outside 0.05 to
// 100 times the imager's larger side, a principal point more than half the imager outside it),
// checked before the models are made of them, or a camera's inlier RMS over kRefusedRmsPx; over
// kWarnedRmsPx (a detector's corners are good to a few tenths of a pixel) a warning in the notes.
constexpr double kRefusedRmsPx = 10, kWarnedRmsPx = 2;
void CheckSolvedIntrinsics(const CalibrationData& data, const std::vector<double>& intrinsics,
                           int num_params) {
  for (std::size_t c = 0; c < data.camera_names.size(); ++c) {
    const double* in = intrinsics.data() + c * num_params;
    const double w = data.widths[c], h = data.heights[c], side = std::max(w, h);
    const std::string& name = data.camera_names[c];
    const std::string imager = fmt::format("its {}x{} imager", w, h);
    if (!(std::min(in[0], in[1]) >= 0.05 * side && std::max(in[0], in[1]) <= 100 * side))
      throw CalibrationError(fmt::format(
          "camera {}: the solve gives focal lengths of {:.4g} and {:.4g} px for {} (a lens gives "
          "0.05 to 100 times its larger side): not a calibration{}",
          name, in[0], in[1], imager, BoardMisfitHint(data, static_cast<int>(c))));
    if (!(in[2] >= -0.5 * w && in[2] <= 1.5 * w && in[3] >= -0.5 * h && in[3] <= 1.5 * h))
      throw CalibrationError(fmt::format(
          "camera {}: the solve puts the principal point at ({:.4g}, {:.4g}) px, more than half "
          "of {} outside it: not a calibration{}",
          name, in[2], in[3], imager, BoardMisfitHint(data, static_cast<int>(c))));
  }
}
void CheckSolvedResiduals(const CalibrationData& data, CalibrationSummary* summary) {
  for (std::size_t c = 0; c < data.camera_names.size(); ++c) {
    const std::string& name = data.camera_names[c];
    const CameraResidualStats& stats = summary->cameras[c];
    // Outlier rejection can hide a bad solve: every corner thrown out leaves an RMS of 0.
    if (stats.points > 0 && stats.outliers == stats.points)
      throw CalibrationError(
          fmt::format("camera {}: mrcal's outlier rejection threw out all {} of its corners: not a "
                      "calibration{}",
                      name, stats.points, BoardMisfitHint(data, static_cast<int>(c))));
    if (stats.outliers > stats.points / 2)
      summary->notes.push_back(fmt::format(
          "WARNING: camera {}: mrcal's outlier rejection threw out {} of its {} corners, more "
          "than half: its residuals describe the rest only",
          name, stats.outliers, stats.points));
    const double rms = stats.rms_px_per_point;
    if (rms > kRefusedRmsPx)
      throw CalibrationError(fmt::format(
          "camera {}: the solve's corners are {:.3g} px RMS from where its model puts them "
          "(refused above {} px; a board's detected corners are good to a few tenths): a wrong "
          "board description or lens model{}",
          name, rms, kRefusedRmsPx, BoardMisfitHint(data, static_cast<int>(c))));
    if (rms > kWarnedRmsPx)
      summary->notes.push_back(fmt::format(
          "WARNING: camera {}: RMS {:.3g} px per point, more than {} px: check the board's "
          "description, the lens model and the worst corners below",
          name, rms, kWarnedRmsPx));
  }
}

}  // namespace

CalibrationSummary Calibrate(const CalibrationData& data, const CalibrationOptions& options,
                             const CalibrationProgress& progress) {
  options.Validate();
  data.board.Validate();
  const auto start = std::chrono::steady_clock::now();
  const int num_cameras = static_cast<int>(data.camera_names.size());
  const int num_views = static_cast<int>(data.view_names.size());
  if (num_cameras == 0) throw CalibrationError("calibration: no cameras");
  if (static_cast<int>(data.widths.size()) != num_cameras)
    throw CalibrationError("calibration: imager sizes missing");
  const BoardSpec& board = data.board;
  const int W = board.corners_x(), H = board.corners_y();
  const std::vector<Eigen::Vector3d> corners_in_board = board.InnerCornersInBoard();
  CalibrationSummary summary;

  // Views per camera: every camera must see the board often enough.
  std::vector<int> views_of(num_cameras, 0);
  for (const auto& o : data.observations) ++views_of[o.camera];
  for (int c = 0; c < num_cameras; ++c) {
    const std::string& name = data.camera_names[c];
    std::string why;
    if (c < static_cast<int>(data.failures_per_camera.size()) &&
        !data.failures_per_camera[c].empty())
      why = " (for example " + data.failures_per_camera[c][0] + ")";
    if (views_of[c] == 0)
      throw CalibrationError("camera " + name + " never sees the board in its " +
                             std::to_string(c < static_cast<int>(data.images_per_camera.size())
                                                ? data.images_per_camera[c]
                                                : 0) +
                             " images" + why + BoardMisfitHint(data, c));
    if (views_of[c] < options.min_views_per_camera)
      throw CalibrationError("camera " + name + " sees the board in only " +
                             std::to_string(views_of[c]) + " views (at least " +
                             std::to_string(options.min_views_per_camera) + " needed)" + why +
                             BoardMisfitHint(data, c));
  }

  // Intrinsics seeds: a pinhole core from the board homographies (or the focal given).
  mrcal_lensmodel_t lensmodel;
  mrcal_lensmodel_from_name(&lensmodel, options.lensmodel.c_str());
  const int num_params = mrcal_lensmodel_num_params(&lensmodel);
  std::vector<double> intrinsics(static_cast<std::size_t>(num_cameras) * num_params, 0.0);
  std::vector<cv::Mat> camera_matrix(num_cameras);
  for (int c = 0; c < num_cameras; ++c) {
    const double cx = 0.5 * (data.widths[c] - 1), cy = 0.5 * (data.heights[c] - 1);
    double f = options.focal_px;
    if (f == 0) {
      std::vector<std::vector<cv::Point3f>> obj;
      std::vector<std::vector<cv::Point2f>> img;
      for (const auto& o : data.observations) {
        if (o.camera != c || o.detection.corner_ids.size() < 6) continue;
        obj.emplace_back();
        img.emplace_back();
        for (std::size_t i = 0; i < o.detection.corner_ids.size(); ++i) {
          const auto& p = corners_in_board[o.detection.corner_ids[i]];
          obj.back().emplace_back(p.x(), p.y(), 0.f);
          img.back().emplace_back(o.detection.corners_px[i].x(), o.detection.corners_px[i].y());
        }
      }
      cv::Mat k = cv::initCameraMatrix2D(obj, img, cv::Size(data.widths[c], data.heights[c]), 1.0);
      f = 0.5 * (k.at<double>(0, 0) + k.at<double>(1, 1));
      if (!(f > 0) || !std::isfinite(f))
        throw CalibrationError("camera " + data.camera_names[c] +
                               ": cannot estimate a focal length from its board views; give "
                               "focal_px in the config");
    }
    double* in = &intrinsics[static_cast<std::size_t>(c) * num_params];
    in[0] = in[1] = f;
    in[2] = cx;
    in[3] = cy;
    camera_matrix[c] = (cv::Mat_<double>(3, 3) << f, 0, cx, 0, f, cy, 0, 0, 1);
  }

  // Per-observation board poses (planar PnP on the pinhole seed).
  const std::size_t num_obs = data.observations.size();
  std::vector<Rigid3> cam_from_board(num_obs);
  double seed_sq = 0;
  int seed_n = 0;
  for (std::size_t i = 0; i < num_obs; ++i) {
    const auto& o = data.observations[i];
    if (o.camera < 0 || o.camera >= num_cameras || o.view < 0 || o.view >= num_views)
      throw CalibrationError("calibration: observation " + std::to_string(i) + " (" + o.source +
                             ") names a camera or view that does not exist");
    std::vector<cv::Point3f> obj;
    std::vector<cv::Point2f> img;
    for (std::size_t k = 0; k < o.detection.corner_ids.size(); ++k) {
      const int id = o.detection.corner_ids[k];
      if (id < 0 || id >= board.num_corners())
        throw CalibrationError(o.source + ": corner id " + std::to_string(id) +
                               " is not on the board");
      obj.emplace_back(corners_in_board[id].x(), corners_in_board[id].y(), 0.f);
      img.emplace_back(o.detection.corners_px[k].x(), o.detection.corners_px[k].y());
    }
    cv::Mat rvec, tvec;
    if (obj.size() < 4 || !cv::solvePnP(obj, img, camera_matrix[o.camera], cv::noArray(), rvec,
                                        tvec, false, cv::SOLVEPNP_IPPE))
      throw CalibrationError(o.source + ": no board pose from its " + std::to_string(obj.size()) +
                             " corners");
    cam_from_board[i] = FromCv(rvec, tvec);
    std::vector<cv::Point2f> reproj;
    cv::projectPoints(obj, rvec, tvec, camera_matrix[o.camera], cv::noArray(), reproj);
    for (std::size_t k = 0; k < reproj.size(); ++k) {
      seed_sq += std::pow(reproj[k].x - img[k].x, 2) + std::pow(reproj[k].y - img[k].y, 2);
      ++seed_n;
    }
  }
  summary.seed_rms_px_per_point = std::sqrt(seed_sq / std::max(1, seed_n));

  // Chain camera poses through shared views, breadth first from the first camera. For each pair
  // the view where both saw the most corners gives the relative pose.
  std::map<std::pair<int, int>, std::pair<int, Rigid3>> best_edge;  // (a, b) -> (corners, b_from_a)
  {
    std::map<int, std::vector<std::size_t>> by_view;
    for (std::size_t i = 0; i < num_obs; ++i) by_view[data.observations[i].view].push_back(i);
    for (const auto& [view, obs] : by_view)
      for (std::size_t ia : obs)
        for (std::size_t ib : obs) {
          const int a = data.observations[ia].camera, b = data.observations[ib].camera;
          if (a == b) continue;
          const int n =
              static_cast<int>(std::min(data.observations[ia].detection.corner_ids.size(),
                                        data.observations[ib].detection.corner_ids.size()));
          auto& e = best_edge[{a, b}];
          if (n > e.first) e = {n, cam_from_board[ib] * cam_from_board[ia].Inverse()};
        }
  }
  std::vector<Rigid3> cam_from_ref(num_cameras);
  std::vector<bool> reached(num_cameras, false);
  reached[0] = true;
  std::queue<int> queue;
  queue.push(0);
  while (!queue.empty()) {
    const int a = queue.front();
    queue.pop();
    for (int b = 0; b < num_cameras; ++b) {
      auto it = best_edge.find({a, b});
      if (reached[b] || it == best_edge.end()) continue;
      cam_from_ref[b] = it->second.second * cam_from_ref[a];
      reached[b] = true;
      queue.push(b);
    }
  }
  {
    std::string lost, linked;
    for (int c = 0; c < num_cameras; ++c)
      (reached[c] ? linked : lost) +=
          (reached[c] ? linked : lost).empty() ? data.camera_names[c] : ", " + data.camera_names[c];
    if (!lost.empty())
      throw CalibrationError("the camera graph is disconnected: camera(s) " + lost +
                             " share no board view with " + data.camera_names[0] + "'s group (" +
                             linked + "); record views that neighbouring cameras see together" +
                             BoardMisfitHint(data));
  }

  // The ring frame's precondition, on these first poses: a rig whose axes do not meet is refused
  // now rather than after the solve.
  if (options.frame == RigFrame::kRing) RingFrame(cam_from_ref);

  // mrcal's calibration object has its first corner at its origin; ours sits one square in.
  const Rigid3 board_from_mrcal_object(Eigen::Quaterniond::Identity(),
                                       Eigen::Vector3d(board.square_m, board.square_m, 0));
  // Board poses in the reference frame, from the observation with the most corners; views that no
  // camera saw are left out of the solve.
  std::vector<int> frame_of_view(num_views, -1);
  std::vector<mrcal_pose_t> frames;
  std::vector<int> view_of_frame;
  {
    std::vector<std::size_t> best(num_views, num_obs);
    for (std::size_t i = 0; i < num_obs; ++i) {
      const auto& o = data.observations[i];
      if (best[o.view] == num_obs ||
          o.detection.corner_ids.size() >
              data.observations[best[o.view]].detection.corner_ids.size())
        best[o.view] = i;
    }
    for (int v = 0; v < num_views; ++v) {
      if (best[v] == num_obs) {
        summary.notes.push_back("view " + data.view_names[v] + ": no camera found the board");
        continue;
      }
      const auto& o = data.observations[best[v]];
      frame_of_view[v] = static_cast<int>(frames.size());
      view_of_frame.push_back(v);
      frames.push_back(ToMrcal(cam_from_ref[o.camera].Inverse() * cam_from_board[best[v]] *
                               board_from_mrcal_object));
    }
  }

  // The mrcal problem. Observations are in view order, so their frame indices do not decrease.
  std::vector<mrcal_observation_board_t> observations(num_obs);
  std::vector<mrcal_point3_t> pool(num_obs * W * H);
  for (std::size_t i = 0; i < num_obs; ++i) {
    const auto& o = data.observations[i];
    observations[i].icam.intrinsics = o.camera;
    observations[i].icam.extrinsics = o.camera - 1;
    observations[i].iframe = frame_of_view[o.view];
    mrcal_point3_t* p = &pool[i * W * H];
    for (int k = 0; k < W * H; ++k) p[k] = Point3(0.0, 0.0, -1.0);  // missing: an outlier
    for (std::size_t k = 0; k < o.detection.corner_ids.size(); ++k)
      p[o.detection.corner_ids[k]] =
          Point3(o.detection.corners_px[k].x(), o.detection.corners_px[k].y(), 1.0);
  }
  std::vector<mrcal_pose_t> extrinsics;
  for (int c = 1; c < num_cameras; ++c) extrinsics.push_back(ToMrcal(cam_from_ref[c]));
  std::vector<int> imagersizes;
  for (int c = 0; c < num_cameras; ++c) {
    imagersizes.push_back(data.widths[c]);
    imagersizes.push_back(data.heights[c]);
  }
  const mrcal_problem_constants_t constants = {.point_min_range = 1e-3, .point_max_range = 1e6};
  mrcal_calobject_warp_t warp{};  // flat until the last solve, as in mrcal-calibrate-cameras
  auto solve = [&](bool final_stage, bool distortions, bool outliers) {
    mrcal_problem_selections_t s{};
    s.do_optimize_intrinsics_core = true;
    s.do_optimize_intrinsics_distortions = distortions;
    s.do_optimize_extrinsics = num_cameras > 1;
    s.do_optimize_frames = true;
    s.do_optimize_calobject_warp = options.board_warp && final_stage;
    s.do_apply_regularization = options.regularization;
    s.do_apply_outlier_rejection = outliers;
    return mrcal_optimize(nullptr, 0, nullptr, 0, intrinsics.data(),
                          extrinsics.empty() ? nullptr : extrinsics.data(), frames.data(), nullptr,
                          &warp, num_cameras, num_cameras - 1, static_cast<int>(frames.size()), 0,
                          0, observations.data(), nullptr, static_cast<int>(num_obs), 0,
                          pool.data(), &lensmodel, imagersizes.data(), s, &constants,
                          board.square_m, W, H, false, false);
  };
  auto report = [&](int done) {
    Progress p;
    p.stage = "solve";
    p.unit = "solves";
    p.done = done;
    p.total = 2;
    // mrcal's solves cannot be stopped half way: a cancel is taken between them and after the
    // last (nothing is written then).
    if (ReportProgress(progress, p))
      throw Cancelled(done < 2 ? "calibration: cancelled before the solve"
                               : "calibration: cancelled after the solve");
  };
  report(0);
  mrcal_stats_t stats = solve(false, false, false);
  report(1);
  stats = solve(true, mrcal_lensmodel_num_params(&lensmodel) > 4, options.outlier_rejection);
  report(2);
  if (!std::isfinite(stats.rms_reproj_error__pixels) || stats.rms_reproj_error__pixels < 0)
    throw CalibrationError("calibration: mrcal's solve failed (RMS " +
                           std::to_string(stats.rms_reproj_error__pixels) + ")");
  for (double v : intrinsics)
    if (!std::isfinite(v))
      throw CalibrationError("calibration: the solve gave non-finite intrinsics");
  if (options.check_solve) CheckSolvedIntrinsics(data, intrinsics, num_params);

  // The rig in the chosen frame.
  std::vector<Rigid3> solved_cam_from_ref(num_cameras);
  for (int c = 1; c < num_cameras; ++c) solved_cam_from_ref[c] = FromMrcal(extrinsics[c - 1]);
  Rigid3 rig_from_ref;
  Rig& rig = summary.rig;
  rig.name = options.rig_name;
  if (options.frame == RigFrame::kRing) {
    rig_from_ref = Rigid3(Eigen::Quaterniond::Identity(), -options.ring_origin_m) *
                   RingFrame(solved_cam_from_ref);
    rig.up_in_rig = Eigen::Vector3d::UnitY();
  } else {
    rig.up_in_rig = -Eigen::Vector3d::UnitY();
  }
  const Rigid3 ref_from_rig = rig_from_ref.Inverse();
  for (int c = 0; c < num_cameras; ++c) {
    std::vector<double> in(intrinsics.begin() + static_cast<std::ptrdiff_t>(c) * num_params,
                           intrinsics.begin() + static_cast<std::ptrdiff_t>(c + 1) * num_params);
    rig.cameras.push_back(RigCamera{
        data.camera_names[c],
        "cameras/" + data.camera_names[c] + ".cameramodel",
        CameraModel(options.lensmodel, std::move(in), solved_cam_from_ref[c] * ref_from_rig,
                    data.widths[c], data.heights[c]),
        {}});
  }
  summary.rig_from_board.assign(num_views, Rigid3());
  summary.view_used.assign(num_views, false);
  for (std::size_t f = 0; f < frames.size(); ++f) {
    summary.rig_from_board[view_of_frame[f]] =
        rig_from_ref * FromMrcal(frames[f]) * board_from_mrcal_object.Inverse();
    summary.view_used[view_of_frame[f]] = true;
  }
  rig.box = options.box;
  if (!rig.box.IsValid()) {
    // The ring's origin, or the middle of the boards seen.
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    std::string where = "the rig origin";
    if (options.frame == RigFrame::kFirstCamera) {
      const Eigen::Vector3d board_middle(0.5 * board.squares_x * board.square_m,
                                         0.5 * board.squares_y * board.square_m, 0);
      for (int f : view_of_frame) centre += summary.rig_from_board[f] * board_middle;
      centre /= std::max<std::size_t>(1, view_of_frame.size());
      where = "the middle of the boards seen";
    }
    double d = 0;
    for (const auto& cam : rig.cameras) d += (cam.model.center_in_rig() - centre).norm();
    const double half = 0.15 * d / num_cameras;
    rig.box.min_in_rig = centre - Eigen::Vector3d::Constant(half);
    rig.box.max_in_rig = centre + Eigen::Vector3d::Constant(half);
    summary.notes.push_back("no box given: a cube of side " + std::to_string(2 * half) +
                            " m around " + where + " (set box in the config)");
  }
  summary.views_used = static_cast<int>(frames.size());
  {
    auto problem = std::make_shared<MrcalProblem>();
    MrcalProblem& p = *problem;
    p.lensmodel = options.lensmodel;
    p.num_cameras = num_cameras;
    p.num_params = num_params;
    p.intrinsics = intrinsics;
    auto rt = [](const mrcal_pose_t& pose) {
      return std::array<double, 6>{pose.r.x, pose.r.y, pose.r.z, pose.t.x, pose.t.y, pose.t.z};
    };
    for (const auto& e : extrinsics) p.extrinsics.push_back(rt(e));
    for (const auto& f : frames) p.frames.push_back(rt(f));
    p.calobject_warp = {warp.x2, warp.y2};
    for (const auto& o : observations)
      p.indices.push_back({o.iframe, o.icam.intrinsics, o.icam.extrinsics});
    p.board_width = W;
    p.board_height = H;
    for (const auto& q : pool) p.observations.insert(p.observations.end(), {q.x, q.y, q.z});
    for (int c = 0; c < num_cameras; ++c)
      p.imagersizes.push_back({data.widths[c], data.heights[c]});
    p.spacing_m = board.square_m;
    p.optimize_intrinsics_distortions = num_params > 4;
    // One camera has no extrinsics, so the switch changes nothing in the solve; true as
    // mrcal-calibrate-cameras stores it (mrcal's uncertainty refuses false).
    p.optimize_extrinsics = true;
    p.optimize_calobject_warp = options.board_warp;
    p.apply_regularization = options.regularization;
    p.apply_outlier_rejection = options.outlier_rejection;
    summary.mrcal_problem = std::move(problem);
  }
  summary.mrcal_rms_px = stats.rms_reproj_error__pixels;
  summary.mrcal_outliers = stats.Noutliers;
  summary.board_warp_x_m = warp.x2;
  summary.board_warp_y_m = warp.y2;

  // Residuals, recomputed through our own camera models (an independent check of mrcal's numbers).
  summary.cameras.resize(num_cameras);
  std::vector<std::vector<double>> inlier_errors(num_cameras);
  double sum_sq = 0;
  for (std::size_t i = 0; i < num_obs; ++i) {
    const auto& o = data.observations[i];
    const CameraModel& cam = rig.cameras[o.camera].model;
    const Rigid3& rig_from_board = summary.rig_from_board[o.view];
    ++summary.cameras[o.camera].views;
    summary.missing_corners += W * H - static_cast<int>(o.detection.corner_ids.size());
    summary.rejected_in_detection += static_cast<int>(o.detection.rejected.size());
    for (std::size_t k = 0; k < o.detection.corner_ids.size(); ++k) {
      const int id = o.detection.corner_ids[k];
      // Where the solved model puts the corner, on the board as solved (bowed when warp is on).
      const Eigen::Vector3d p = WarpedCorner(corners_in_board[id], board, warp);
      const Eigen::Vector2d q = cam.Project(rig_from_board * p);
      ObservationError e{o.camera,
                         o.view,
                         id,
                         (q - o.detection.corners_px[k]).norm(),
                         pool[i * W * H + id].z < 0,
                         q - o.detection.corners_px[k]};
      if (!std::isfinite(e.error_px)) {
        e.error_px = 1e30;
        e.residual_px.setZero();
      }
      summary.errors.push_back(e);
      ++summary.cameras[o.camera].points;
      if (e.outlier) {
        ++summary.cameras[o.camera].outliers;
        ++summary.outliers;
      } else {
        inlier_errors[o.camera].push_back(e.error_px);
        sum_sq += e.error_px * e.error_px;
      }
      ++summary.points;
    }
  }
  const int inliers = std::max(1, summary.points - summary.outliers);
  summary.rms_px_per_point = std::sqrt(sum_sq / inliers);
  summary.rms_px_per_coordinate = std::sqrt(sum_sq / (2.0 * inliers));
  for (int c = 0; c < num_cameras; ++c) {
    auto& s = summary.cameras[c];
    s.name = data.camera_names[c];
    const auto& v = inlier_errors[c];
    double sq = 0;
    for (double e : v) sq += e * e;
    s.rms_px_per_point = v.empty() ? 0 : std::sqrt(sq / v.size());
    s.median_px = Percentile(v, 0.5);
    s.p95_px = Percentile(v, 0.95);
    s.max_px = v.empty() ? 0 : *std::max_element(v.begin(), v.end());
  }
  if (options.check_solve) CheckSolvedResiduals(data, &summary);
  std::vector<ObservationError> sorted;
  for (const auto& e : summary.errors)
    if (!e.outlier) sorted.push_back(e);
  std::partial_sort(sorted.begin(), sorted.begin() + std::min<std::size_t>(12, sorted.size()),
                    sorted.end(),
                    [](const auto& a, const auto& b) { return a.error_px > b.error_px; });
  sorted.resize(std::min<std::size_t>(12, sorted.size()));
  summary.worst = std::move(sorted);
  summary.notes.push_back(std::string("rig frame: ") +
                          (options.frame == RigFrame::kRing
                               ? "ring (origin where the optical axes meet, y up, z towards " +
                                     data.camera_names[0] + ")"
                               : "first camera (" + data.camera_names[0] + ")"));
  summary.solve_time_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

ProjectionUncertainty EstimateProjectionUncertainty(const CalibrationData& data,
                                                    const CalibrationSummary& summary,
                                                    const CalibrationOptions& options, int trials,
                                                    double voxel_m, std::uint64_t seed,
                                                    const CalibrationProgress& progress) {
  if (trials < 2) throw InputError("projection uncertainty: need at least 2 trials");
  if (!(voxel_m > 0) || !std::isfinite(voxel_m))
    throw InputError("projection uncertainty: the voxel size must be > 0");
  const auto start = std::chrono::steady_clock::now();
  const Rig& rig = summary.rig;
  const int num_cameras = static_cast<int>(rig.cameras.size());
  if (static_cast<int>(data.camera_names.size()) != num_cameras ||
      summary.rig_from_board.size() != data.view_names.size() ||
      summary.view_used.size() != data.view_names.size())
    throw CalibrationError("projection uncertainty: the summary is not of this data");
  const std::vector<Eigen::Vector3d> corners = data.board.InnerCornersInBoard();
  mrcal_calobject_warp_t warp;
  warp.x2 = summary.board_warp_x_m;
  warp.y2 = summary.board_warp_y_m;
  // The solved corners, exactly where the solved rig puts them.
  CalibrationData exact = data;
  for (auto& o : exact.observations) {
    const CameraModel& cam = rig.cameras[o.camera].model;
    for (std::size_t k = 0; k < o.detection.corner_ids.size(); ++k)
      o.detection.corners_px[k] =
          cam.Project(summary.rig_from_board[o.view] *
                      WarpedCorner(corners[o.detection.corner_ids[k]], data.board, warp));
  }
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i < 5; ++i)
    for (int j = 0; j < 5; ++j)
      for (int k = 0; k < 5; ++k)
        points.push_back(rig.box.min_in_rig +
                         rig.box.size().cwiseProduct(Eigen::Vector3d(i, j, k) / 4.0));
  ProjectionUncertainty u;
  u.trials = trials;
  u.noise_px = summary.rms_px_per_coordinate;
  u.voxel_m = voxel_m;
  if (!(u.noise_px > 0) || !std::isfinite(u.noise_px)) {
    // Corners the solve fits exactly carry no noise to propagate: no uncertainty.
    for (const auto& cam : rig.cameras) u.cameras.push_back(CameraUncertainty{cam.name, 0, 0, 0});
    return u;
  }
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0.0, u.noise_px);
  // Per camera and point: the sum and sum of squares of the projections' offsets from the solved.
  const std::size_t n = points.size();
  std::vector<std::vector<Eigen::Vector2d>> sum(
      num_cameras, std::vector<Eigen::Vector2d>(n, Eigen::Vector2d::Zero()));
  std::vector<std::vector<Eigen::Matrix2d>> sum_outer(
      num_cameras, std::vector<Eigen::Matrix2d>(n, Eigen::Matrix2d::Zero()));
  std::vector<std::vector<int>> count(num_cameras, std::vector<int>(n, 0));
  std::vector<std::vector<Eigen::Vector2d>> solved(num_cameras);
  for (int c = 0; c < num_cameras; ++c) solved[c] = rig.cameras[c].model.Project(points);
  CalibrationOptions trial_options = options;
  trial_options.box = rig.box;  // the same box; no note about it
  // A solve that passed its checks is not refused for what a noisy trial of it does.
  trial_options.check_solve = false;
  // A report (and a chance to cancel) before each solve and after the last.
  for (int t = 0; t <= trials; ++t) {
    Progress p;
    p.stage = "uncertainty";
    p.unit = "solves";
    p.done = t;
    p.total = trials;
    if (ReportProgress(progress, p))
      throw Cancelled("projection uncertainty: cancelled after " + std::to_string(t) + " of " +
                      std::to_string(trials) + " solves");
    if (t == trials) break;
    CalibrationData noisy = exact;
    for (auto& o : noisy.observations)
      for (auto& p : o.detection.corners_px) p += Eigen::Vector2d(noise(rng), noise(rng));
    const CalibrationSummary trial = Calibrate(noisy, trial_options);
    // mrcal's "mean-frames": a point is held fixed in the world the boards define, not in the
    // first camera's frame (which moves with its own intrinsics): it is carried into the trial's
    // frame through every board pose both solves have, and the results averaged.
    std::vector<Eigen::Vector3d> moved(n, Eigen::Vector3d::Zero());
    int frames = 0;
    for (std::size_t v = 0; v < summary.rig_from_board.size(); ++v) {
      if (!summary.view_used[v] || v >= trial.view_used.size() || !trial.view_used[v]) continue;
      const Rigid3 trial_from_solved =
          trial.rig_from_board[v] * summary.rig_from_board[v].Inverse();
      for (std::size_t i = 0; i < n; ++i) moved[i] += trial_from_solved * points[i];
      ++frames;
    }
    if (frames == 0) throw CalibrationError("projection uncertainty: a trial kept no board view");
    for (auto& p : moved) p /= frames;
    for (int c = 0; c < num_cameras; ++c) {
      const std::vector<Eigen::Vector2d> q = trial.rig.cameras[c].model.Project(moved);
      for (std::size_t i = 0; i < n; ++i) {
        const Eigen::Vector2d d = q[i] - solved[c][i];
        if (!d.allFinite()) continue;
        sum[c][i] += d;
        sum_outer[c][i] += d * d.transpose();
        ++count[c][i];
      }
    }
  }
  for (int c = 0; c < num_cameras; ++c) {
    const CameraModel& cam = rig.cameras[c].model;
    CameraUncertainty cu;
    cu.name = rig.cameras[c].name;
    const double f = 0.5 * (cam.intrinsics()[0] + cam.intrinsics()[1]);
    int used = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const int m = count[c][i];  // a point behind the camera projects nowhere
      if (m < 2) continue;
      ++used;
      const Eigen::Vector2d mean = sum[c][i] / m;
      // 1 sigma in the worst direction (mrcal's default 'worstdirection-stdev'): the square root
      // of the largest eigenvalue of the projection's 2x2 covariance (Bessel-corrected).
      const Eigen::Matrix2d cov = (sum_outer[c][i] / m - mean * mean.transpose()) * m / (m - 1.0);
      const double sigma = std::sqrt(std::max(
          0.0, Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(cov).eigenvalues().maxCoeff()));
      cu.max_px = std::max(cu.max_px, sigma);
      cu.mean_px += sigma;
      const double depth = (cam.cam_from_rig() * points[i]).z();
      if (depth > 0 && f > 0) cu.max_voxels = std::max(cu.max_voxels, sigma * depth / f / voxel_m);
    }
    cu.mean_px /= std::max(1, used);
    if (cu.max_voxels > 0.5) {
      char buf[200];
      std::snprintf(buf, sizeof(buf),
                    "%s: projection uncertainty %.2f voxel (%.3f px, 1 sigma) over the box, more "
                    "than half a voxel",
                    cu.name.c_str(), cu.max_voxels, cu.max_px);
      u.warnings.push_back(buf);
    }
    u.cameras.push_back(cu);
  }
  u.time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return u;
}

std::string CalibrationSummary::BriefReport() const {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(3);
  s << "calibrated " << rig.cameras.size() << " cameras from " << views_used << " views, " << points
    << " corners (" << outliers << " outliers) in " << solve_time_s << " s\n";
  s << "mrcal counts " << mrcal_outliers << " outliers: the " << outliers
    << " its rejection threw out and the " << missing_corners
    << " board corners not detected in the views used (" << rejected_in_detection
    << " of them found but left out by the detection's consistency check)\n";
  if (board_warp_x_m != 0 || board_warp_y_m != 0)
    s << "board warp (mrcal calobject_warp): " << board_warp_x_m * 1e3 << " mm along x, "
      << board_warp_y_m * 1e3 << " mm along y\n";
  s << "RMS reprojection error " << rms_px_per_point << " px per point (" << rms_px_per_coordinate
    << " px per coordinate; mrcal reports " << mrcal_rms_px
    << ", over every board corner, outliers and corners not detected included); seed "
    << seed_rms_px_per_point << " px per point\n";
  for (const auto& c : cameras)
    s << "  " << c.name << ": " << c.views << " views, " << c.points << " corners, " << c.outliers
      << " outliers, RMS " << c.rms_px_per_point << " px, median " << c.median_px << ", p95 "
      << c.p95_px << ", max " << c.max_px << "\n";
  return s.str();
}

std::string MrcalImageExtension(const std::string& source) {
  const fs::path p(source);
  return IsImageFile(p) ? p.extension().string() : ".png";
}

void WriteMrcalCorners(const CalibrationData& data, const std::string& path,
                       const std::string& dir_prefix) {
  std::ostringstream out;
  out << "# filename x y level\n";
  const int n = data.board.num_corners();
  char buf[128];
  for (const auto& o : data.observations) {
    const std::string name = dir_prefix + "/" + data.view_names[o.view] + "/" +
                             data.camera_names[o.camera] + MrcalImageExtension(o.source);
    std::vector<const Eigen::Vector2d*> at(n, nullptr);
    for (std::size_t k = 0; k < o.detection.corner_ids.size(); ++k)
      at[o.detection.corner_ids[k]] = &o.detection.corners_px[k];
    for (int k = 0; k < n; ++k) {
      if (at[k])
        std::snprintf(buf, sizeof(buf), " %.9g %.9g 0\n", at[k]->x(), at[k]->y());
      else
        std::snprintf(buf, sizeof(buf), " 0 0 -\n");
      out << name << buf;
    }
  }
  try {
    WriteFileAtomically(path, out.str());
  } catch (const std::exception& e) {
    throw CalibrationError(path + ": cannot write mrcal's corners file: " + e.what());
  }
}

}  // namespace flamerig
