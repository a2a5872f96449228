#include "calibration/synthetic_rig.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <opencv2/aruco/charuco.hpp>
#include <opencv2/imgproc.hpp>
#include <random>

#include "core/atomic_file.h"
#include "core/error.h"

extern "C" {
#include <mrcal/mrcal.h>
}

namespace flamerig::synthetic {
namespace {

constexpr double kPi = 3.14159265358979323846;

}  // namespace

void RingOptions::Validate() const {
  auto fail = [](const std::string& what) { throw InputError("RingOptions." + what); };
  if (cameras < 1 || cameras > 16) fail("cameras must be in [1, 16]");
  if (!azimuths_deg.empty() && static_cast<int>(azimuths_deg.size()) != cameras) {
    fail("azimuths_deg must have one entry per camera");
  }
  if (!(distance_m > 0) || !std::isfinite(distance_m)) fail("distance_m must be finite and > 0");
  if (!(std::abs(elevation_deg) < 85)) fail("elevation_deg must be in (-85, 85)");
  if (width < 8 || height < 8 || width > 16384 || height > 16384)
    fail("width and height must be in [8, 16384]");
  if (!(fill > 0) || !(fill <= 2)) fail("fill must be in (0, 2]");
  mrcal_lensmodel_t lm;
  if (!mrcal_lensmodel_from_name(&lm, lensmodel.c_str()) || !mrcal_lensmodel_type_is_valid(lm.type))
    fail("lensmodel '" + lensmodel + "' is not an mrcal lens model name");
  if (!mrcal_lensmodel_metadata(&lm).has_core)
    fail("lensmodel '" + lensmodel + "' has no fx fy cx cy core");
  const int extra = mrcal_lensmodel_num_params(&lm) - 4;
  if (!distortion.empty() && static_cast<int>(distortion.size()) != extra)
    fail("distortion must have " + std::to_string(extra) + " values for " + lensmodel + ", got " +
         std::to_string(distortion.size()));
  for (double v : distortion)
    if (!std::isfinite(v)) fail("distortion must be finite");
}

namespace {

// Camera i's intrinsics: the core, then the options' distortion or the default (see RingOptions).
std::vector<double> LensIntrinsics(const RingOptions& options, int i, double f) {
  const double cx = 0.5 * (options.width - 1), cy = 0.5 * (options.height - 1);
  std::vector<double> intrinsics = {f, f, cx, cy};
  if (!options.distortion.empty()) {
    intrinsics.insert(intrinsics.end(), options.distortion.begin(), options.distortion.end());
  } else if (options.lensmodel == "LENSMODEL_OPENCV8") {
    // k1 k2 p1 p2 k3 k4 k5 k6: a mild barrel distortion, slightly different per camera.
    const double k1 = -0.06 + 0.01 * i / std::max(1, options.cameras - 1);
    intrinsics.insert(intrinsics.end(), {k1, 0.02, 4e-4, -3e-4, 0.0, 0.0, 0.0, 0.0});
  } else {
    mrcal_lensmodel_t lm;
    mrcal_lensmodel_from_name(&lm, options.lensmodel.c_str());
    intrinsics.resize(static_cast<std::size_t>(mrcal_lensmodel_num_params(&lm)), 0.0);
  }
  return intrinsics;
}

}  // namespace

Rig MakeRingRig(const Box3& box, const RingOptions& options, const std::string& name) {
  options.Validate();
  if (!box.IsValid()) throw InputError("MakeRingRig: invalid box");
  std::vector<double> azimuths = options.azimuths_deg;
  if (azimuths.empty()) {
    if (options.cameras == 2) {
      azimuths = {0.0, 90.0};  // the paper's front and side views
    } else {
      for (int i = 0; i < options.cameras; ++i) azimuths.push_back(360.0 * i / options.cameras);
    }
  }
  const double radius = 0.5 * box.size().norm();
  if (options.distance_m <= radius * 1.05) {
    throw InputError("RingOptions.distance_m = " + std::to_string(options.distance_m) +
                     " puts the cameras inside the box's bounding sphere (radius " +
                     std::to_string(radius) + " m)");
  }
  const double half_angle = std::asin(radius / options.distance_m);
  const double f = 0.5 * options.fill * options.height / std::tan(half_angle);
  Rig rig;
  rig.name = name;
  rig.box = box;
  const double e = options.elevation_deg * kPi / 180;
  for (int i = 0; i < options.cameras; ++i) {
    double a = azimuths[i] * kPi / 180;
    Eigen::Vector3d eye =
        box.center() + options.distance_m * Eigen::Vector3d(std::sin(a) * std::cos(e), std::sin(e),
                                                            std::cos(a) * std::cos(e));
    Rigid3 cam_from_rig = LookAt(eye, box.center(), rig.up_in_rig);
    std::string cam_name = "cam" + std::to_string(i);
    rig.cameras.push_back(RigCamera{cam_name,
                                    "cameras/" + cam_name + ".cameramodel",
                                    CameraModel(options.lensmodel, LensIntrinsics(options, i, f),
                                                cam_from_rig, options.width, options.height),
                                    {}});
  }
  return rig;
}

Rig MakeRowRig(const Box3& box, const RingOptions& options, double spacing_m,
               const std::string& name) {
  options.Validate();
  if (!box.IsValid()) throw InputError("MakeRowRig: invalid box");
  if (!(spacing_m > 0) || !std::isfinite(spacing_m))
    throw InputError("MakeRowRig: spacing_m must be finite and > 0");
  const double radius = 0.5 * box.size().norm();
  if (options.distance_m <= radius * 1.05)
    throw InputError("RingOptions.distance_m = " + std::to_string(options.distance_m) +
                     " puts the cameras inside the box's bounding sphere (radius " +
                     std::to_string(radius) + " m)");
  const double f =
      0.5 * options.fill * options.height / std::tan(std::asin(radius / options.distance_m));
  Rig rig;
  rig.name = name;
  rig.box = box;
  for (int i = 0; i < options.cameras; ++i) {
    const Eigen::Vector3d eye =
        box.center() +
        Eigen::Vector3d((i - 0.5 * (options.cameras - 1)) * spacing_m, 0, options.distance_m);
    const Rigid3 cam_from_rig = LookAt(eye, eye - Eigen::Vector3d::UnitZ(), rig.up_in_rig);
    const std::string cam_name = "cam" + std::to_string(i);
    rig.cameras.push_back(RigCamera{cam_name,
                                    "cameras/" + cam_name + ".cameramodel",
                                    CameraModel(options.lensmodel, LensIntrinsics(options, i, f),
                                                cam_from_rig, options.width, options.height),
                                    {}});
  }
  return rig;
}

// ---- Calibration boards
// --------------------------------------------------------------------------

namespace {

// The printed board at `px_per_square` texels per square, with a one-square white margin.
cv::Mat BoardTexture(const BoardSpec& board, int px_per_square) {
  const int margin = px_per_square;
  const int w = board.squares_x * px_per_square, h = board.squares_y * px_per_square;
  cv::Mat texture(h + 2 * margin, w + 2 * margin, CV_8UC1, cv::Scalar(255));
  cv::Mat pattern;
  if (board.type == BoardType::kCharuco) {
    auto dictionary = cv::aruco::getPredefinedDictionary(board.aruco_dictionary);
    auto charuco = cv::aruco::CharucoBoard::create(board.squares_x, board.squares_y,
                                                   static_cast<float>(board.square_m),
                                                   static_cast<float>(board.marker_m), dictionary);
    cv::Mat drawn;
    charuco->draw(cv::Size(w, h), drawn, 0, 1);
    // OpenCV's drawing rounds square edges to whole texels (measured: ChArUco corners came out ~1
    // texel off), so the squares are redrawn exactly here and only the markers are taken from
    // OpenCV's image.
    pattern = cv::Mat(h, w, CV_8UC1, cv::Scalar(255));
    const int inset =
        std::max(1, static_cast<int>(std::lround(0.5 * (board.square_m - board.marker_m) /
                                                 board.square_m * px_per_square)) -
                        1);
    for (int y = 0; y < board.squares_y; ++y)
      for (int x = 0; x < board.squares_x; ++x) {
        cv::Rect square(x * px_per_square, y * px_per_square, px_per_square, px_per_square);
        bool black = drawn.at<std::uint8_t>(square.y + 2, square.x + 2) < 128;
        if (black) {
          pattern(square).setTo(0);
        } else {
          cv::Rect marker(square.x + inset, square.y + inset, px_per_square - 2 * inset,
                          px_per_square - 2 * inset);
          drawn(marker).copyTo(pattern(marker));
        }
      }
  } else {
    pattern = cv::Mat(h, w, CV_8UC1, cv::Scalar(255));
    for (int y = 0; y < board.squares_y; ++y)
      for (int x = 0; x < board.squares_x; ++x)
        if ((x + y) % 2 == 0) {
          pattern(cv::Rect(x * px_per_square, y * px_per_square, px_per_square, px_per_square))
              .setTo(0);
        }
  }
  pattern.copyTo(texture(cv::Rect(margin, margin, w, h)));
  return texture;
}

}  // namespace

void BoardLighting::Validate() const {
  auto fail = [](const std::string& what) { throw InputError("board lighting: " + what); };
  if (!(shadow >= 0 && shadow <= 1)) fail("shadow must be in [0, 1]");
  if (!std::isfinite(shadow_angle_deg) || !std::isfinite(shadow_offset_m))
    fail("the shadow's angle and offset must be finite");
  if (!(penumbra_m >= 0) || !std::isfinite(penumbra_m)) fail("penumbra_m must be >= 0");
  if (!(gradient >= 0 && gradient < 1)) fail("gradient must be in [0, 1)");
  if (!(blur_px >= 0 && blur_px <= 20)) fail("blur_px must be in [0, 20]");
}

ImageU8 RenderBoard(const CameraModel& camera, const BoardSpec& board, const Rigid3& rig_from_board,
                    double noise_dn, std::uint64_t seed, int supersample,
                    const BoardLighting& lighting) {
  return RenderBoard(camera, camera.UnprojectAllPixels(), board, rig_from_board, noise_dn, seed,
                     supersample, lighting);
}

ImageU8 RenderBoard(const CameraModel& camera, const std::vector<Ray>& rays, const BoardSpec& board,
                    const Rigid3& rig_from_board, double noise_dn, std::uint64_t seed,
                    int supersample, const BoardLighting& lighting) {
  board.Validate();
  lighting.Validate();
  if (rays.size() != static_cast<std::size_t>(camera.width()) * camera.height()) {
    throw InputError("RenderBoard: need one ray per pixel of the camera");
  }
  if (supersample < 1 || supersample > 8)
    throw InputError("RenderBoard: supersample must be in [1, 8]");
  const int px_per_square = 64;
  cv::Mat texture = BoardTexture(board, px_per_square);
  const double texels_per_m = px_per_square / board.square_m;
  const Rigid3 board_from_rig = rig_from_board.Inverse();
  const int width = camera.width(), height = camera.height();
  ImageU8 image(width, height, 1);

  const double pattern_w = board.squares_x * board.square_m,
               pattern_h = board.squares_y * board.square_m;
  const double angle = lighting.shadow_angle_deg * kPi / 180;
  auto light = [&](double x, double y) {
    double l = 1.0 - lighting.gradient * std::clamp(x / pattern_w, 0.0, 1.0);
    if (lighting.shadow < 1) {
      const double s = (x - 0.5 * pattern_w) * std::cos(angle) +
                       (y - 0.5 * pattern_h) * std::sin(angle) - lighting.shadow_offset_m;
      const double t =
          lighting.penumbra_m > 0 ? std::clamp(0.5 + s / lighting.penumbra_m, 0.0, 1.0) : s > 0;
      l *= 1.0 - (1.0 - lighting.shadow) * t;
    }
    return l;
  };
  auto shade = [&](const Eigen::Vector3d& origin, const Eigen::Vector3d& direction) -> double {
    const double background = 40.0;
    Eigen::Vector3d o = board_from_rig * origin;
    Eigen::Vector3d d = board_from_rig.rotation * direction;
    if (std::abs(d.z()) < 1e-12) return background;
    double t = -o.z() / d.z();
    if (t <= 0) return background;
    Eigen::Vector3d hit = o + t * d;
    double u = hit.x() * texels_per_m + px_per_square - 0.5;  // texel centres at integers
    double v = hit.y() * texels_per_m + px_per_square - 0.5;
    if (u < -0.5 || v < -0.5 || u > texture.cols - 0.5 || v > texture.rows - 0.5) return background;
    if (o.z() > 0) return 90.0;  // the back of the board: plain
    int u0 = static_cast<int>(std::floor(u)), v0 = static_cast<int>(std::floor(v));
    double fu = u - u0, fv = v - v0;
    auto texel = [&](int x, int y) {
      x = std::clamp(x, 0, texture.cols - 1);
      y = std::clamp(y, 0, texture.rows - 1);
      return double(texture.at<std::uint8_t>(y, x));
    };
    double value = (1 - fv) * ((1 - fu) * texel(u0, v0) + fu * texel(u0 + 1, v0)) +
                   fv * ((1 - fu) * texel(u0, v0 + 1) + fu * texel(u0 + 1, v0 + 1));
    // print contrast: black ink ~25, white paper ~235, in the light that falls there
    return (25.0 + value * (210.0 / 255.0)) * light(hit.x(), hit.y());
  };

  tbb::parallel_for(tbb::blocked_range<int>(0, height), [&](const tbb::blocked_range<int>& r) {
    for (int y = r.begin(); y < r.end(); ++y)
      for (int x = 0; x < width; ++x) {
        double sum = 0;
        int n = 0;
        for (int sy = 0; sy < supersample; ++sy)
          for (int sx = 0; sx < supersample; ++sx) {
            // Sub-pixel rays interpolated bilinearly between neighbouring pixel-centre rays.
            double px = x + (sx + 0.5) / supersample - 0.5, py = y + (sy + 0.5) / supersample - 0.5;
            int x0 = std::clamp(static_cast<int>(std::floor(px)), 0, width - 2);
            int y0 = std::clamp(static_cast<int>(std::floor(py)), 0, height - 2);
            double fx = px - x0, fy = py - y0;
            const Ray& a = rays[y0 * width + x0];
            const Ray& b = rays[y0 * width + x0 + 1];
            const Ray& c = rays[(y0 + 1) * width + x0];
            const Ray& d = rays[(y0 + 1) * width + x0 + 1];
            if (!a.valid || !b.valid || !c.valid || !d.valid) continue;
            Eigen::Vector3d dir =
                ((1 - fy) * ((1 - fx) * a.direction_in_rig + fx * b.direction_in_rig) +
                 fy * ((1 - fx) * c.direction_in_rig + fx * d.direction_in_rig))
                    .normalized();
            sum += shade(a.origin_in_rig, dir);
            ++n;
          }
        image.at(x, y) =
            static_cast<std::uint8_t>(std::clamp(std::lround(n ? sum / n : 0.0), 0L, 255L));
      }
  });
  if (lighting.blur_px > 0) {
    cv::Mat mat(height, width, CV_8UC1, image.pixels.data());
    cv::GaussianBlur(mat, mat, cv::Size(0, 0), lighting.blur_px);
  }
  if (noise_dn > 0) {
    std::mt19937_64 rng(seed);
    std::normal_distribution<double> noise(0.0, noise_dn);
    for (auto& p : image.pixels)
      p = static_cast<std::uint8_t>(std::clamp(std::lround(p + noise(rng)), 0L, 255L));
  }
  return image;
}

namespace {

bool SeesWholeBoard(const CameraModel& camera, const BoardSpec& board,
                    const Rigid3& rig_from_board) {
  const double margin_px = 8;
  // The printed side faces -z of the board: the camera must be on that side, not too oblique.
  Eigen::Vector3d normal_in_rig = rig_from_board.rotation * Eigen::Vector3d(0, 0, -1);
  Eigen::Vector3d center =
      rig_from_board * Eigen::Vector3d(0.5 * board.squares_x * board.square_m,
                                       0.5 * board.squares_y * board.square_m, 0);
  Eigen::Vector3d to_camera = (camera.center_in_rig() - center).normalized();
  if (normal_in_rig.dot(to_camera) < 0.3) return false;  // more oblique than ~72 degrees
  // A chessboard is found only whole, with its white border; a ChArUco board is identified by its
  // markers, so a view that shows most of its corners counts (views reaching the image edges are
  // what pins the principal point and the distortion down).
  std::vector<Eigen::Vector3d> pts;
  double W = board.squares_x * board.square_m, H = board.squares_y * board.square_m,
         m = board.square_m;
  const bool whole = board.type == BoardType::kChessboard;
  if (whole) {
    for (const auto& c : {Eigen::Vector3d(-m, -m, 0), Eigen::Vector3d(W + m, -m, 0),
                          Eigen::Vector3d(-m, H + m, 0), Eigen::Vector3d(W + m, H + m, 0)}) {
      pts.push_back(rig_from_board * c);
    }
  }
  for (const auto& c : board.InnerCornersInBoard()) pts.push_back(rig_from_board * c);
  for (const auto& p : pts) {
    if (!camera.InFront(p)) return false;
  }
  int inside = 0;
  for (const auto& q : camera.Project(pts)) {
    inside += q.allFinite() && q.x() >= margin_px && q.y() >= margin_px &&
              q.x() <= camera.width() - 1 - margin_px && q.y() <= camera.height() - 1 - margin_px;
  }
  if (whole ? inside < static_cast<int>(pts.size())
            : inside < 0.6 * static_cast<double>(pts.size()))
    return false;
  return true;
}

// A board centred at `center` whose printed side faces `facing` (unit, from the board towards the
// viewer), rotated by small random angles.
Rigid3 BoardPose(const BoardSpec& board, const Eigen::Vector3d& center,
                 const Eigen::Vector3d& facing, const Eigen::Vector3d& up, double tilt_rad,
                 std::mt19937_64& rng) {
  std::uniform_real_distribution<double> uni(-1, 1);
  Eigen::Vector3d z = -facing.normalized();  // board z points away from the viewer
  Eigen::Vector3d x = up.cross(z).normalized();
  Eigen::Vector3d y = z.cross(x);  // down the board
  Eigen::Matrix3d R;
  R << x, y, z;
  Eigen::Matrix3d jitter = (Eigen::AngleAxisd(tilt_rad * uni(rng), Eigen::Vector3d::UnitX()) *
                            Eigen::AngleAxisd(tilt_rad * uni(rng), Eigen::Vector3d::UnitY()) *
                            Eigen::AngleAxisd(0.5 * tilt_rad * uni(rng), Eigen::Vector3d::UnitZ()))
                               .toRotationMatrix();
  R = R * jitter;
  Eigen::Vector3d half(0.5 * board.squares_x * board.square_m,
                       0.5 * board.squares_y * board.square_m, 0);
  return Rigid3(Eigen::Quaterniond(R), center - R * half);
}

}  // namespace

std::vector<BoardView> MakeCalibrationViews(const Rig& rig, const BoardSpec& board,
                                            std::uint64_t seed, int shared_per_pair,
                                            int closeups_per_camera) {
  board.Validate();
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uni(-1, 1);
  std::vector<BoardView> views;
  const Eigen::Vector3d center = rig.box.center();
  const int n = static_cast<int>(rig.cameras.size());
  // Boards are spread over the cameras' fields of view (a calibration needs corners all over the
  // image, or the principal point and distortion are poorly determined): the half-width of the
  // narrowest field at unit distance.
  double half_field = 1e9;
  for (const auto& cam : rig.cameras)
    half_field = std::min(half_field, 0.5 * cam.model.width() / cam.model.intrinsics()[0]);
  auto lateral = [&](double fraction, double distance, const Eigen::Vector3d& axis) {
    const double rx = uni(rng), ry = uni(rng), rz = uni(rng);
    const Eigen::Vector3d r(rx, ry, rz);
    const Eigen::Vector3d across = r - r.dot(axis) * axis;  // across the line of sight
    return Eigen::Vector3d(fraction * half_field * distance * across);
  };
  auto add = [&](const Rigid3& pose, const std::string& kind) {
    BoardView v{pose, {}, kind};
    for (int c = 0; c < n; ++c) {
      if (SeesWholeBoard(rig.cameras[c].model, board, pose)) v.cameras.push_back(c);
    }
    if (!v.cameras.empty()) views.push_back(v);
  };
  // Shared views between neighbours (cameras sorted by azimuth around the box's up axis).
  std::vector<std::pair<double, int>> order;
  for (int c = 0; c < n; ++c) {
    Eigen::Vector3d d = rig.cameras[c].model.center_in_rig() - center;
    order.emplace_back(std::atan2(d.x(), d.z()), c);
  }
  std::sort(order.begin(), order.end());
  const int pairs = n == 2 ? 1 : (n > 2 ? n : 0);
  for (int p = 0; p < pairs; ++p) {
    int a = order[p].second, b = order[(p + 1) % n].second;
    Eigen::Vector3d da = (rig.cameras[a].model.center_in_rig() - center).normalized();
    Eigen::Vector3d db = (rig.cameras[b].model.center_in_rig() - center).normalized();
    if (da.dot(db) < -0.5) continue;  // more than 120 degrees apart: no common view possible
    Eigen::Vector3d facing = (da + db).normalized();
    for (int i = 0, tries = 0; i < shared_per_pair && tries < 50 * shared_per_pair; ++tries) {
      const double d = std::min((rig.cameras[a].model.center_in_rig() - center).norm(),
                                (rig.cameras[b].model.center_in_rig() - center).norm());
      // Seen whole by two cameras: only near the middle of both fields.
      // Towards the pair by up to a third of the way, and tilted, for depth across the board.
      Eigen::Vector3d c =
          center + facing * d * 0.35 * (uni(rng) + 1) / 2 + lateral(0.25, d, facing);
      Rigid3 pose = BoardPose(board, c, facing, rig.up_in_rig, 0.6, rng);
      if (SeesWholeBoard(rig.cameras[a].model, board, pose) &&
          SeesWholeBoard(rig.cameras[b].model, board, pose)) {
        add(pose, "shared");
        ++i;
      }
    }
  }
  for (int c = 0; c < n; ++c) {
    Eigen::Vector3d eye = rig.cameras[c].model.center_in_rig();
    Eigen::Vector3d to_eye = (eye - center).normalized();
    double distance = (eye - center).norm();
    for (int i = 0, tries = 0; i < closeups_per_camera && tries < 50 * closeups_per_camera;
         ++tries) {
      const double along = distance * (0.2 + 0.25 * (uni(rng) + 1) / 2);
      Eigen::Vector3d pos = center + to_eye * along + lateral(0.7, distance - along, to_eye);
      Rigid3 pose = BoardPose(board, pos, to_eye, rig.up_in_rig, 0.6, rng);
      if (SeesWholeBoard(rig.cameras[c].model, board, pose)) {
        add(pose, "closeup");
        ++i;
      }
    }
  }
  return views;
}

WrittenViews WriteCalibrationViews(const Rig& rig, const BoardSpec& board, std::uint64_t seed,
                                   int shared_per_pair, int closeups_per_camera, double noise_dn,
                                   const std::string& dir, const ProgressCallback& progress,
                                   const BoardLighting& lighting) {
  namespace fs = std::filesystem;
  lighting.Validate();
  std::mt19937_64 shadow_rng(seed * 104729ULL + 17);
  std::uniform_real_distribution<double> shadow_angle(0.0, 360.0);
  const std::vector<BoardView> views =
      MakeCalibrationViews(rig, board, seed + 1, shared_per_pair, closeups_per_camera);
  fs::create_directories(dir);
  std::vector<std::vector<Ray>> rays(rig.cameras.size());
  for (std::size_t c = 0; c < rig.cameras.size(); ++c)
    rays[c] = rig.cameras[c].model.UnprojectAllPixels();
  YAML::Emitter yaml;
  yaml << YAML::BeginMap << YAML::Key << "board" << YAML::Value << YAML::BeginMap;
  yaml << YAML::Key << "type" << YAML::Value
       << (board.type == BoardType::kCharuco ? "charuco" : "chessboard");
  yaml << YAML::Key << "squares" << YAML::Value << YAML::Flow
       << std::vector<int>{board.squares_x, board.squares_y};
  yaml << YAML::Key << "square_m" << YAML::Value << board.square_m;
  yaml << YAML::Key << "marker_m" << YAML::Value << board.marker_m;
  yaml << YAML::Key << "aruco_dictionary" << YAML::Value << board.aruco_dictionary;
  yaml << YAML::Key << "frame" << YAML::Value
       << "origin at the pattern's top-left corner, x along squares_x, y along squares_y, "
          "printed side faces -z";
  yaml << YAML::EndMap;
  yaml << YAML::Key << "views" << YAML::Value << YAML::BeginSeq;
  WrittenViews written;
  written.first_view.assign(rig.cameras.size(), ImageU8());
  for (std::size_t v = 0; v < views.size(); ++v) {
    Progress p;
    p.stage = "calibration views";
    p.unit = "views";
    p.done = static_cast<std::int64_t>(v);
    p.total = static_cast<std::int64_t>(views.size());
    if (ReportProgress(progress, p)) throw Cancelled("calibration views: cancelled");
    char name[32];
    std::snprintf(name, sizeof(name), "view_%03zu", v);
    fs::create_directories(fs::path(dir) / name);
    std::vector<std::string> names;
    BoardLighting light = lighting;
    if (light.shadow < 1) light.shadow_angle_deg = shadow_angle(shadow_rng);
    for (int c : views[v].cameras) {
      ImageU8 image = RenderBoard(rig.cameras[c].model, rays[c], board, views[v].rig_from_board,
                                  noise_dn > 0 ? std::max(noise_dn, 1.0) : 0.0,
                                  seed * 7919ULL + v * 31ULL + c, 3, light);
      WritePng((fs::path(dir) / name / (rig.cameras[c].name + ".png")).string(), image);
      names.push_back(rig.cameras[c].name);
      ++written.images;
      if (v == 0) written.first_view[static_cast<std::size_t>(c)] = std::move(image);
    }
    const auto rt = views[v].rig_from_board.ToRt();
    yaml << YAML::BeginMap << YAML::Key << "name" << YAML::Value << name << YAML::Key << "kind"
         << YAML::Value << views[v].kind << YAML::Key << "rt_rig_from_board" << YAML::Value
         << YAML::Flow << std::vector<double>(rt.begin(), rt.end()) << YAML::Key << "cameras"
         << YAML::Value << YAML::Flow << names << YAML::EndMap;
  }
  yaml << YAML::EndSeq << YAML::EndMap;
  WriteFileAtomically((fs::path(dir) / "board.yaml").string(), std::string(yaml.c_str()) + "\n");
  written.views = static_cast<int>(views.size());
  Progress done;
  done.stage = "calibration views";
  done.unit = "views";
  done.done = done.total = written.views;
  ReportProgress(progress, done);
  return written;
}

}  // namespace flamerig::synthetic
