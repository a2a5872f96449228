#include "tomography/synthetic_fire.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "core/error.h"

namespace flamerig::synthetic {
namespace {

constexpr double kPi = 3.14159265358979323846;

// ---- Deterministic value noise

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
// u, w in [-1, 1] across the box (x and z), v in [0, 1] up. Returns flame "heat" h in [0, 1]
// (drives temperature) and "soot" s in [0, 1] (drives density).

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
                    double peak_density_per_m3) {
  options.Validate();
  geometry.Validate();
  FireVolume fire;
  fire.geometry = geometry;
  fire.temperature_k.assign(geometry.num_voxels(),
                            static_cast<float>(options.ambient_temperature_k));
  fire.density_per_m3.assign(geometry.num_voxels(), 0.0f);
  const Box3 box = options.region.IsValid() ? options.region : geometry.box();
  const Eigen::Vector3d c = box.center(), half = 0.5 * box.size();
  if (!(peak_density_per_m3 >= 0) || !std::isfinite(peak_density_per_m3))
    throw InputError("MakeFire: peak_density_per_m3 must be finite and >= 0");
  const double peak_density = peak_density_per_m3;
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
  return fire;
}

}  // namespace flamerig::synthetic
