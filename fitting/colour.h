// Colour science for the forward model: the CIE 1931 2-degree observer, XYZ, linear and encoded
// sRGB, 8-bit quantisation and CIELab.
//
// Conventions:
//  - Spectra are radiances per nanometre. XYZ of a spectrum L is
//      X = sum L(l) xbar(l) dl / sum ybar(l) dl     (1 nm steps, 360..830 nm)
//    i.e. normalised by the integral of ybar (106.857), so Y is the luminance-weighted mean
//    spectral radiance (W m^-2 sr^-1 nm^-1) and a flat spectrum of 1 has Y = 1.
//  - Linear sRGB uses the IEC 61966-2-1 primaries and D65 white; the white point used for CIELab
//    is the XYZ of linear sRGB (1, 1, 1), so sRGB white maps to Lab (100, 0, 0) exactly.
//  - Encoded sRGB values are in [0, 1]; 8-bit values are round(255 * encoded), saturating at 0
//    and 255.
#ifndef FLAMERIG_FITTING_COLOUR_H_
#define FLAMERIG_FITTING_COLOUR_H_

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <vector>

#include "core/srgb.h"

namespace flamerig::colour {

// The CIE 1931 2-degree standard observer tabulated at 1 nm from 360 to 830 nm (471 rows), compiled
// in from fitting/data/cie1931_2deg_1nm.csv.
class CieObserver {
 public:
  static const CieObserver& Cie1931TwoDegree();

  static constexpr int kFirstNm = 360;
  static constexpr int kLastNm = 830;
  static constexpr int kCount = kLastNm - kFirstNm + 1;

  // (xbar, ybar, zbar) at an integer wavelength in [360, 830]; zero outside.
  Eigen::Vector3d At(int wavelength_nm) const;
  // Linear interpolation between table rows; zero outside [360, 830].
  Eigen::Vector3d Interpolate(double wavelength_nm) const;
  // sum of ybar * 1 nm over the table.
  double YIntegral() const { return y_integral_; }

  // XYZ (normalised as above) of the spectrum `radiance_per_nm(wavelength_nm)` sampled at every
  // table row.
  template <typename F>
  Eigen::Vector3d Integrate(F&& radiance_per_nm) const {
    Eigen::Vector3d xyz = Eigen::Vector3d::Zero();
    for (int i = 0; i < kCount; ++i) xyz += radiance_per_nm(double(kFirstNm + i)) * table_[i];
    return xyz / y_integral_;
  }

 private:
  CieObserver();
  std::array<Eigen::Vector3d, kCount> table_;
  double y_integral_ = 0;
};

// XYZ (normalised as above) of a black body at `temperature_k`: its luminance-weighted radiance.
Eigen::Vector3d BlackbodyXyz(double temperature_k);

// Chromaticity (x, y) = (X, Y) / (X + Y + Z); (0, 0) for black.
Eigen::Vector2d Chromaticity(const Eigen::Vector3d& xyz);

// 3x3 matrices between XYZ and linear sRGB (D65).
const Eigen::Matrix3d& LinearSrgbFromXyz();
const Eigen::Matrix3d& XyzFromLinearSrgb();
// XYZ of linear sRGB white (1, 1, 1): the D65 reference white used for CIELab.
Eigen::Vector3d D65White();

// The sRGB transfer curve and quantisation live with images (core/srgb.h).
using ::flamerig::QuantizeU8;
using ::flamerig::SrgbDecode;
using ::flamerig::SrgbEncode;
using ::flamerig::SrgbU8ToLinearTable;

// CIELab of an XYZ colour relative to `white_xyz` (D65 by default).
Eigen::Vector3d XyzToLab(const Eigen::Vector3d& xyz, const Eigen::Vector3d& white_xyz);
Eigen::Vector3d XyzToLab(const Eigen::Vector3d& xyz);
// CIELab of an 8-bit sRGB colour.
Eigen::Vector3d SrgbU8ToLab(std::uint8_t r, std::uint8_t g, std::uint8_t b);
// CIE 1976 colour difference: Euclidean distance in Lab (the paper's pixel distance).
inline double DeltaE76(const Eigen::Vector3d& lab1, const Eigen::Vector3d& lab2) {
  return (lab1 - lab2).norm();
}

}  // namespace flamerig::colour

#endif  // FLAMERIG_FITTING_COLOUR_H_
