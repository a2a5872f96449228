#include "tools/synthetic.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <opencv2/aruco/charuco.hpp>
#include <opencv2/imgproc.hpp>
#include <random>
#include <stdexcept>

#include "core/error.h"
#include "fitting/colour.h"
#include "fitting/physics.h"
#include "fitting/spectral_tables.h"

namespace flamerig::synthetic {
namespace {

constexpr double kPi = 3.14159265358979323846;

// ---- Deterministic value noise
// -------------------------------------------------------------------

std::uint64_t Mix(std::uint64_t x) {  // splitmix64 finaliser
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

double LatticeValue(std::uint64_t seed, std::int64_t i, std::int64_t j, std::int64_t k) {
  std::uint64_t h =
      Mix(seed ^ Mix(static_cast<std::uint64_t>(i) ^
                     Mix(static_cast<std::uint64_t>(j) ^ Mix(static_cast<std::uint64_t>(k)))));
  return (h >> 11) * (1.0 / 9007199254740992.0) * 2.0 - 1.0;  // [-1, 1)
}

double Fade(double t) { return t * t * t * (t * (t * 6 - 15) + 10); }

double ValueNoise(std::uint64_t seed, double x, double y, double z) {
  double fx = std::floor(x), fy = std::floor(y), fz = std::floor(z);
  auto i = static_cast<std::int64_t>(fx), j = static_cast<std::int64_t>(fy),
       k = static_cast<std::int64_t>(fz);
  double u = Fade(x - fx), v = Fade(y - fy), w = Fade(z - fz);
  double c[2][2][2];
  for (int a = 0; a < 2; ++a)
    for (int b = 0; b < 2; ++b)
      for (int d = 0; d < 2; ++d) c[a][b][d] = LatticeValue(seed, i + a, j + b, k + d);
  auto lerp = [](double p, double q, double t) { return p + t * (q - p); };
  return lerp(lerp(lerp(c[0][0][0], c[1][0][0], u), lerp(c[0][1][0], c[1][1][0], u), v),
              lerp(lerp(c[0][0][1], c[1][0][1], u), lerp(c[0][1][1], c[1][1][1], u), v), w);
}

double Fbm(std::uint64_t seed, double x, double y, double z, int octaves = 4) {
  double sum = 0, amplitude = 0.5, frequency = 1;
  for (int o = 0; o < octaves; ++o) {
    sum += amplitude * ValueNoise(seed + 7919 * o, x * frequency, y * frequency, z * frequency);
    amplitude *= 0.5;
    frequency *= 2.0;
  }
  return sum;  // about [-1, 1]
}

double Smoothstep(double edge0, double edge1, double x) {
  double t = std::clamp((x - edge0) / (edge1 - edge0), 0.0, 1.0);
  return t * t * (3 - 2 * t);
}

// ---- Procedural fires in normalised box coordinates
// ---------------------------------------------- u, w in [-1, 1] across the box (x and z), v in [0,
// 1] up. Returns flame "heat" h in [0, 1] (drives temperature) and "soot" s in [0, 1] (drives
// density).

struct FlameSample {
  double heat = 0;
  double soot = 0;
};

class CandleFlame {
 public:
  CandleFlame(std::uint64_t seed, double time_s) : seed_(seed), time_s_(time_s) {
    std::mt19937_64 rng(seed);
    phase_ = std::uniform_real_distribution<double>(0, 2 * kPi)(rng);
  }
  FlameSample operator()(double u, double v, double w) const {
    FlameSample out;
    const double v0 = 0.06, v1 = 0.94;
    double s = (v - v0) / (v1 - v0);  // 0 at the wick, 1 at the tip
    if (s <= 0 || s >= 1) return out;
    double sway = 0.06 * std::sin(2 * kPi * 1.3 * time_s_ + phase_) * s * s;
    double flicker = 1.0 + 0.04 * std::sin(2 * kPi * 7.1 * time_s_ + 2 * phase_);
    // Teardrop radius, peak near s = 0.38, normalised to 0.55 of the half-width.
    double profile = std::sqrt(s) * std::pow(1 - s, 0.8);
    double radius = 0.8 * profile / 0.4795 * flicker;
    double turbulence = 0.10 * Fbm(seed_, 3 * u, 4 * v - 2.5 * time_s_, 3 * w);
    double r = std::hypot(u - sway, w) / std::max(radius, 1e-6) * (1 + turbulence);
    if (r >= 1) return out;
    double inside = Smoothstep(1.0, 0.7, r);
    double sheath = std::exp(-std::pow((r - 0.7) / 0.35, 2));
    double axial = Smoothstep(0.0, 0.12, s) * (1 - 0.25 * s * s * s);
    out.heat = inside * axial * (0.72 + 0.28 * sheath);
    double soot_zone = Smoothstep(0.0, 0.4, s) * (1 - Smoothstep(0.8, 1.0, s));
    out.soot = inside * soot_zone * (0.55 + 0.45 * (1 - r)) *
               std::clamp(1 + 0.3 * Fbm(seed_ + 17, 5 * u, 6 * v - 3 * time_s_, 5 * w), 0.3, 1.6);
    out.soot = std::clamp(out.soot, 0.0, 1.0);
    return out;
  }

 private:
  std::uint64_t seed_;
  double time_s_;
  double phase_ = 0;
};

class LicksFire {
 public:
  LicksFire(std::uint64_t seed, double time_s, int count) : seed_(seed), time_s_(time_s) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> uni(0, 1);
    if (count <= 0) count = 3 + static_cast<int>(uni(rng) * 4);  // 3..6
    for (int i = 0; i < count; ++i) {
      Lick l;
      double a = 2 * kPi * uni(rng), rr = 0.35 * std::sqrt(uni(rng));
      l.base_u = rr * std::cos(a);
      l.base_w = rr * std::sin(a);
      l.height = 0.55 + 0.4 * uni(rng);
      l.radius = 0.28 + 0.17 * uni(rng);
      l.lean_u = 0.5 * (uni(rng) - 0.5);
      l.lean_w = 0.5 * (uni(rng) - 0.5);
      l.phase = 2 * kPi * uni(rng);
      l.frequency_hz = 1.5 + 2.0 * uni(rng);
      licks_.push_back(l);
    }
  }
  FlameSample operator()(double u, double v, double w) const {
    FlameSample out;
    if (v <= 0 || v >= 1) return out;
    // Turbulent displacement rising with the flow.
    double du = 0.15 * Fbm(seed_ + 1, 2.5 * u, 3 * v - 2 * time_s_, 2.5 * w);
    double dw = 0.15 * Fbm(seed_ + 2, 2.5 * u, 3 * v - 2 * time_s_, 2.5 * w);
    double best = 0;
    for (const Lick& l : licks_) {
      double height =
          l.height * (1 + 0.06 * std::sin(2 * kPi * l.frequency_hz * time_s_ + l.phase));
      double s = v / height;
      if (s >= 1) continue;
      double sway = 0.08 * std::sin(2 * kPi * 0.8 * l.frequency_hz * time_s_ + l.phase) * s * s;
      double cu = l.base_u + l.lean_u * s * height + sway;
      double cw = l.base_w + l.lean_w * s * height;
      double radius = l.radius * std::pow(1 - s, 0.5) * (0.75 + 0.25 * std::sqrt(s));
      double r = std::hypot(u + du - cu, w + dw - cw) / std::max(radius, 1e-6);
      if (r >= 1) continue;
      double value = Smoothstep(1.0, 0.6, r) * (1 - 0.2 * s) * Smoothstep(0.0, 0.05, v);
      best = std::max(best, value);
    }
    // A shallow pool of flame joining the bases.
    double pool = Smoothstep(0.75, 0.3, std::hypot(u + du, w + dw)) * Smoothstep(0.16, 0.04, v) *
                  Smoothstep(0.0, 0.03, v) * 0.8;
    best = std::max(best, pool);
    if (best <= 0) return out;
    out.heat = best;
    out.soot =
        best * std::clamp(0.7 + 0.5 * Fbm(seed_ + 3, 4 * u, 5 * v - 3 * time_s_, 4 * w), 0.2, 1.2);
    out.soot = std::clamp(out.soot, 0.0, 1.0);
    return out;
  }

 private:
  struct Lick {
    double base_u, base_w, height, radius, lean_u, lean_w, phase, frequency_hz;
  };
  std::uint64_t seed_;
  double time_s_;
  std::vector<Lick> licks_;
};

}  // namespace

FireKind FireKindFromName(const std::string& name) {
  if (name == "candle") return FireKind::kCandle;
  if (name == "licks") return FireKind::kLicks;
  throw InputError("fire kind '" + name + "' is unknown; use 'candle' or 'licks'");
}

const char* ToString(FireKind kind) { return kind == FireKind::kCandle ? "candle" : "licks"; }

void FireOptions::Validate() const {
  auto fail = [](const std::string& what) { throw InputError("FireOptions." + what); };
  if (!(peak_temperature_k > ambient_temperature_k) || !(peak_temperature_k <= 1e5)) {
    fail("peak_temperature_k must exceed ambient_temperature_k and be <= 1e5");
  }
  if (!(ambient_temperature_k >= 0)) fail("ambient_temperature_k must be >= 0");
  if (!(peak_soot_volume_fraction > 0) || !(peak_soot_volume_fraction < 1)) {
    fail("peak_soot_volume_fraction must be in (0, 1)");
  }
  if (supersample < 1 || supersample > 8) fail("supersample must be in [1, 8]");
  if (licks < 0 || licks > 64) fail("licks must be in [0, 64]");
  if (!std::isfinite(time_s)) fail("time_s must be finite");
}

FireVolume MakeFire(const GridGeometry& geometry, const FireOptions& options,
                    const AbsorptionModel& absorption) {
  options.Validate();
  geometry.Validate();
  FireVolume fire;
  fire.geometry = geometry;
  fire.temperature_k.assign(geometry.num_voxels(),
                            static_cast<float>(options.ambient_temperature_k));
  fire.density_per_m3.assign(geometry.num_voxels(), 0.0f);
  const Box3 box = options.region.IsValid() ? options.region : geometry.box();
  const Eigen::Vector3d c = box.center(), half = 0.5 * box.size();
  const double peak_density =
      absorption.DensityFromVolumeFraction(options.peak_soot_volume_fraction);
  CandleFlame candle(options.seed, options.time_s);
  LicksFire licks(options.seed, options.time_s, options.licks);
  const int ss = options.supersample;
  tbb::parallel_for(
      tbb::blocked_range<int>(0, geometry.dims.z()), [&](const tbb::blocked_range<int>& r) {
        for (int k = r.begin(); k < r.end(); ++k)
          for (int j = 0; j < geometry.dims.y(); ++j)
            for (int i = 0; i < geometry.dims.x(); ++i) {
              double heat = 0, soot = 0;
              for (int a = 0; a < ss; ++a)
                for (int b = 0; b < ss; ++b)
                  for (int d = 0; d < ss; ++d) {
                    Eigen::Vector3d p =
                        geometry.origin_in_rig +
                        Eigen::Vector3d(i + (a + 0.5) / ss, j + (b + 0.5) / ss, k + (d + 0.5) / ss)
                            .cwiseProduct(geometry.voxel_size_m);
                    double u = (p.x() - c.x()) / half.x(), w = (p.z() - c.z()) / half.z();
                    double v = (p.y() - box.min_in_rig.y()) / box.size().y();
                    if (std::abs(u) >= 1 || std::abs(w) >= 1)
                      continue;  // outside the fire's region
                    FlameSample s =
                        options.kind == FireKind::kCandle ? candle(u, v, w) : licks(u, v, w);
                    heat += s.heat;
                    soot += s.soot;
                  }
              heat /= ss * ss * ss;
              soot /= ss * ss * ss;
              std::size_t f = geometry.Flat(i, j, k);
              fire.temperature_k[f] = static_cast<float>(
                  options.ambient_temperature_k +
                  (options.peak_temperature_k - options.ambient_temperature_k) * heat);
              fire.density_per_m3[f] = static_cast<float>(peak_density * soot);
            }
      });
  fire.metadata_text["fire"] = ToString(options.kind);
  fire.metadata_numbers["seed"] = static_cast<double>(options.seed);
  fire.metadata_numbers["time_s"] = options.time_s;
  fire.metadata_text["absorption_model"] = absorption.name();
  return fire;
}

std::vector<float> ThinEmissionRgb(const FireVolume& fire, const AbsorptionModel& absorption) {
  const std::size_t n = fire.geometry.num_voxels();
  std::vector<float> rgb(3 * n, 0.0f);
  const Eigen::Matrix3d& to_rgb = colour::LinearSrgbFromXyz();
  const auto& cie = colour::CieObserver::Cie1931TwoDegree();
  const BlackbodyXyzTable& table = BlackbodyXyzTable::Get();
  const double sigma550 = absorption.CrossSectionM2(550);
  std::vector<double> sigma(colour::CieObserver::kCount);
  for (int i = 0; i < colour::CieObserver::kCount; ++i) {
    sigma[i] = absorption.CrossSectionM2(colour::CieObserver::kFirstNm + i);
  }
  tbb::parallel_for(std::size_t(0), n, [&](std::size_t f) {
    double density = fire.density_per_m3[f];
    if (!(density > 0)) return;
    double t = fire.temperature_k[f];
    Eigen::Vector3d xyz;
    if (absorption.is_grey()) {
      double v[3];
      table.Lookup(t, v);
      xyz = sigma550 * density * Eigen::Vector3d(v[0], v[1], v[2]);
    } else {
      int i = 0;
      xyz = cie.Integrate(
          [&](double nm) { return sigma[i++] * density * physics::PlanckRadiancePerNm(nm, t); });
    }
    Eigen::Vector3d c = to_rgb * xyz;
    for (int ch = 0; ch < 3; ++ch) rgb[3 * f + ch] = static_cast<float>(c[ch]);
  });
  return rgb;
}

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
  if (lensmodel != "LENSMODEL_OPENCV8" && lensmodel != "LENSMODEL_PINHOLE") {
    fail("lensmodel must be LENSMODEL_OPENCV8 or LENSMODEL_PINHOLE");
  }
}

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
    double cx = 0.5 * (options.width - 1), cy = 0.5 * (options.height - 1);
    std::vector<double> intrinsics = {f, f, cx, cy};
    if (options.lensmodel == "LENSMODEL_OPENCV8") {
      // k1 k2 p1 p2 k3 k4 k5 k6: a mild barrel distortion, slightly different per camera.
      double k1 = -0.06 + 0.01 * i / std::max(1, options.cameras - 1);
      intrinsics.insert(intrinsics.end(), {k1, 0.02, 4e-4, -3e-4, 0.0, 0.0, 0.0, 0.0});
    }
    std::string cam_name = "cam" + std::to_string(i);
    rig.cameras.push_back(RigCamera{
        cam_name, "cameras/" + cam_name + ".cameramodel",
        CameraModel(options.lensmodel, intrinsics, cam_from_rig, options.width, options.height)});
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

ImageU8 RenderBoard(const CameraModel& camera, const BoardSpec& board, const Rigid3& rig_from_board,
                    double noise_dn, std::uint64_t seed, int supersample) {
  return RenderBoard(camera, camera.UnprojectAllPixels(), board, rig_from_board, noise_dn, seed,
                     supersample);
}

ImageU8 RenderBoard(const CameraModel& camera, const std::vector<Ray>& rays, const BoardSpec& board,
                    const Rigid3& rig_from_board, double noise_dn, std::uint64_t seed,
                    int supersample) {
  board.Validate();
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
    return 25.0 + value * (210.0 / 255.0);  // print contrast: black ink ~25, white paper ~235
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

}  // namespace flamerig::synthetic
