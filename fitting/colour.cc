#include "fitting/colour.h"

#include <Eigen/LU>
#include <cmath>

#include "fitting/physics.h"

namespace flamerig::colour {
namespace {

struct CieRow {
  double nm, x, y, z;
};
constexpr CieRow kCieRows[] = {
#include "cie1931_2deg_1nm.inc"
};
static_assert(sizeof(kCieRows) / sizeof(kCieRows[0]) == CieObserver::kCount,
              "the CIE table must have one row per nm from 360 to 830");

}  // namespace

CieObserver::CieObserver() {
  y_integral_ = 0;
  for (int i = 0; i < kCount; ++i) {
    table_[i] = Eigen::Vector3d(kCieRows[i].x, kCieRows[i].y, kCieRows[i].z);
    y_integral_ += kCieRows[i].y;
  }
}

const CieObserver& CieObserver::Cie1931TwoDegree() {
  static const CieObserver observer;
  return observer;
}

Eigen::Vector3d CieObserver::At(int wavelength_nm) const {
  if (wavelength_nm < kFirstNm || wavelength_nm > kLastNm) return Eigen::Vector3d::Zero();
  return table_[wavelength_nm - kFirstNm];
}

Eigen::Vector3d CieObserver::Interpolate(double wavelength_nm) const {
  if (!(wavelength_nm >= kFirstNm) || !(wavelength_nm <= kLastNm)) return Eigen::Vector3d::Zero();
  double u = wavelength_nm - kFirstNm;
  int i = std::min(static_cast<int>(u), kCount - 2);
  double f = u - i;
  return (1 - f) * table_[i] + f * table_[i + 1];
}

Eigen::Vector3d BlackbodyXyz(double temperature_k) {
  return CieObserver::Cie1931TwoDegree().Integrate(
      [&](double nm) { return physics::PlanckRadiancePerNm(nm, temperature_k); });
}

Eigen::Vector2d Chromaticity(const Eigen::Vector3d& xyz) {
  double s = xyz.sum();
  if (!(s > 0)) return Eigen::Vector2d::Zero();
  return Eigen::Vector2d(xyz.x() / s, xyz.y() / s);
}

const Eigen::Matrix3d& XyzFromLinearSrgb() {
  static const Eigen::Matrix3d m = [] {
    Eigen::Matrix3d r;
    // IEC 61966-2-1 primaries with D65 white, to 7 digits.
    r << 0.4124564, 0.3575761, 0.1804375,  //
        0.2126729, 0.7151522, 0.0721750,   //
        0.0193339, 0.1191920, 0.9503041;
    return r;
  }();
  return m;
}

const Eigen::Matrix3d& LinearSrgbFromXyz() {
  static const Eigen::Matrix3d m = XyzFromLinearSrgb().inverse();
  return m;
}

Eigen::Vector3d D65White() { return XyzFromLinearSrgb() * Eigen::Vector3d::Ones(); }

Eigen::Vector3d XyzToLab(const Eigen::Vector3d& xyz, const Eigen::Vector3d& white_xyz) {
  auto f = [](double t) {
    constexpr double d = 6.0 / 29.0;
    if (!(t > d * d * d)) return t / (3 * d * d) + 4.0 / 29.0;
    return std::cbrt(t);
  };
  double fx = f(xyz.x() / white_xyz.x());
  double fy = f(xyz.y() / white_xyz.y());
  double fz = f(xyz.z() / white_xyz.z());
  return Eigen::Vector3d(116 * fy - 16, 500 * (fx - fy), 200 * (fy - fz));
}

Eigen::Vector3d XyzToLab(const Eigen::Vector3d& xyz) {
  static const Eigen::Vector3d white = D65White();
  return XyzToLab(xyz, white);
}

Eigen::Vector3d SrgbU8ToLab(std::uint8_t r, std::uint8_t g, std::uint8_t b) {
  const auto& lin = SrgbU8ToLinearTable();
  return XyzToLab(XyzFromLinearSrgb() * Eigen::Vector3d(lin[r], lin[g], lin[b]));
}

}  // namespace flamerig::colour
