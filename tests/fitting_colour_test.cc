// Colour science against published anchors and an independent copy of the CIE table.
#include <gtest/gtest.h>

#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "core/error.h"
#include "fitting/absorption.h"
#include "fitting/colour.h"
#include "fitting/physics.h"
#include "fitting/spectral_tables.h"

namespace flamerig::colour {
namespace {

TEST(CieObserver, IntegralOfYbar) {
  // Published: the integral of ybar over 360..830 nm at 1 nm is 106.856895.
  EXPECT_NEAR(CieObserver::Cie1931TwoDegree().YIntegral(), 106.856895, 106.856895 * 1e-6);
}

TEST(CieObserver, PeakOfYbarIsOneAt555nm) {
  const auto& cie = CieObserver::Cie1931TwoDegree();
  EXPECT_DOUBLE_EQ(cie.At(555).y(), 1.0);
  for (int nm = 360; nm <= 830; ++nm) EXPECT_LE(cie.At(nm).y(), 1.0);
}

// Debian's colord-data ships the same standard at 5 nm: every 5 nm row of ours must match it.
TEST(CieObserver, MatchesColordTable) {
  const std::string path = "/usr/share/colord/cmf/CIE1931-2deg-XYZ.cmf";
  std::ifstream file(path);
  ASSERT_TRUE(file) << path << " is missing: scripts/install-deps.sh installs colord-data";
  std::string line;
  while (std::getline(file, line) &&
         line.substr(0, line.find_last_not_of(" \t\r") + 1) != "BEGIN_DATA") {
  }
  std::vector<std::vector<double>> rows;
  while (std::getline(file, line) && line.rfind("END_DATA", 0) != 0) {
    std::istringstream s(line);
    std::vector<double> values;
    double v;
    while (s >> v) values.push_back(v);
    rows.push_back(values);
  }
  ASSERT_EQ(rows.size(), 3u);
  const auto& cie = CieObserver::Cie1931TwoDegree();
  for (int c = 0; c < 3; ++c) {
    ASSERT_EQ(rows[c].size(), 95u);
    for (int i = 0; i < 95; ++i) {
      int nm = 360 + 5 * i;
      double ours = cie.At(nm)[c];
      EXPECT_NEAR(ours, rows[c][i], 1e-6 * std::max(1.0, rows[c][i]) + 1e-10)
          << "channel " << c << " at " << nm;
    }
  }
}

TEST(Blackbody, IlluminantAChromaticity) {
  // CIE Illuminant A is a Planckian radiator at 2856 K: x = 0.44757, y = 0.40745.
  Eigen::Vector2d xy = Chromaticity(BlackbodyXyz(2856.0));
  EXPECT_NEAR(xy.x(), 0.44757, 5e-4);
  EXPECT_NEAR(xy.y(), 0.40745, 5e-4);
}

TEST(Blackbody, YIsLuminanceWeightedRadiance) {
  // With XYZ normalised by the integral of ybar, a flat spectrum has Y = 1, and Y of a black body
  // lies between the smallest and largest radiance inside the ybar band.
  Eigen::Vector3d flat = CieObserver::Cie1931TwoDegree().Integrate([](double) { return 1.0; });
  EXPECT_NEAR(flat.y(), 1.0, 1e-12);
  double y = BlackbodyXyz(2000).y();
  EXPECT_GT(y, physics::PlanckRadiancePerNm(500, 2000));
  EXPECT_LT(y, physics::PlanckRadiancePerNm(650, 2000));
  // The dynamic range the paper's fit lives with: Y(2300 K) / Y(1300 K) is about 3650.
  EXPECT_NEAR(BlackbodyXyz(2300).y() / BlackbodyXyz(1300).y(), 3650, 150);
}

TEST(Srgb, LabAnchors) {
  // Published sRGB (D65) to CIELab anchors.
  Eigen::Vector3d red = SrgbU8ToLab(255, 0, 0);
  EXPECT_NEAR(red[0], 53.24, 0.01);
  EXPECT_NEAR(red[1], 80.09, 0.01);
  EXPECT_NEAR(red[2], 67.20, 0.01);
  Eigen::Vector3d white = SrgbU8ToLab(255, 255, 255);
  EXPECT_NEAR(white[0], 100.0, 1e-9);
  EXPECT_NEAR(white[1], 0.0, 1e-9);
  EXPECT_NEAR(white[2], 0.0, 1e-9);
  Eigen::Vector3d grey = SrgbU8ToLab(128, 128, 128);
  EXPECT_NEAR(grey[0], 53.59, 0.01);
  EXPECT_NEAR(grey[1], 0.0, 1e-6);
  EXPECT_NEAR(grey[2], 0.0, 1e-6);
  EXPECT_NEAR(SrgbU8ToLab(0, 0, 0)[0], 0.0, 1e-12);
}

TEST(Srgb, D65WhiteAndMatrices) {
  Eigen::Vector3d w = D65White();
  EXPECT_NEAR(w.x(), 0.95047, 2e-4);
  EXPECT_NEAR(w.y(), 1.0, 1e-6);
  EXPECT_NEAR(w.z(), 1.08883, 2e-3);
  EXPECT_TRUE(
      (LinearSrgbFromXyz() * XyzFromLinearSrgb()).isApprox(Eigen::Matrix3d::Identity(), 1e-12));
  // The inverse matrix as published by B. Lindbloom for sRGB (D65), 7 digits.
  const double published[3][3] = {{3.2404542, -1.5371385, -0.4985314},
                                  {-0.9692660, 1.8760108, 0.0415560},
                                  {0.0556434, -0.2040259, 1.0572252}};
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      EXPECT_NEAR(LinearSrgbFromXyz()(r, c), published[r][c], 1e-6) << r << "," << c;
}

TEST(Srgb, TransferCurveAndQuantisation) {
  for (int i = 0; i <= 255; ++i) {
    double e = i / 255.0;
    EXPECT_NEAR(SrgbEncode(SrgbDecode(e)), e, 1e-12);
    EXPECT_EQ(QuantizeU8(e), i);
  }
  EXPECT_NEAR(SrgbEncode(0.0031308), 12.92 * 0.0031308, 1e-12);
  EXPECT_NEAR(SrgbEncode(0.5), 0.735356983, 1e-8);  // 1.055 * 0.5^(1/2.4) - 0.055
  EXPECT_EQ(QuantizeU8(SrgbEncode(7.5)), 255);      // saturation
  EXPECT_EQ(QuantizeU8(SrgbEncode(-3.0)), 0);
  EXPECT_EQ(QuantizeU8(SrgbEncode(std::nan(""))), 0);
  EXPECT_EQ(QuantizeU8(SrgbEncode(INFINITY)), 255);
}

TEST(Absorption, SootCrossSectionIsRayleigh) {
  AbsorptionModel soot = AbsorptionModel::DefaultSoot();
  // Closed form for alpha = 1: C = 48 pi^2 R^3 n k / (lambda ((n^2-k^2+2)^2 + 4 n^2 k^2)).
  const double n = 1.57, k = 0.56, r = 20e-9, l = 600e-9, pi = physics::kPi;
  double expected =
      48 * pi * pi * r * r * r * n * k / (l * (std::pow(n * n - k * k + 2, 2) + 4 * n * n * k * k));
  EXPECT_NEAR(soot.CrossSectionM2(600) / expected, 1.0, 1e-12);
  // Proportional to 1 / lambda for alpha = 1.
  EXPECT_NEAR(soot.CrossSectionM2(400) / soot.CrossSectionM2(800), 2.0, 1e-12);
  // A candle's peak soot volume fraction (1e-6) absorbs of order 10 per metre (notes/physics.md).
  double kappa = soot.DensityFromVolumeFraction(1e-6) * soot.CrossSectionM2(550);
  EXPECT_GT(kappa, 3.0);
  EXPECT_LT(kappa, 30.0);
  // alpha changes the spectral slope but keeps the value at the reference wavelength.
  SootParameters p;
  p.alpha = 1.39;
  AbsorptionModel tilted = AbsorptionModel::Soot(p);
  EXPECT_NEAR(tilted.CrossSectionM2(550) / soot.CrossSectionM2(550), 1.0, 1e-12);
  EXPECT_NEAR(tilted.CrossSectionM2(400) / tilted.CrossSectionM2(800), std::pow(2.0, 1.39), 1e-9);
}

TEST(Absorption, BadParametersNameTheField) {
  SootParameters p;
  p.particle_radius_m = -1;
  try {
    AbsorptionModel::Soot(p);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("particle_radius_m"), std::string::npos);
  }
  EXPECT_THROW(AbsorptionModel::Grey(std::nan("")), InputError);
  EXPECT_THROW(AbsorptionModel::FromName("purple"), InputError);
}

TEST(Absorption, DensityBounds) {
  AbsorptionModel soot = AbsorptionModel::DefaultSoot();
  DensityBounds b = DensityBounds::Plausible(soot);
  EXPECT_NEAR(soot.VolumeFraction(b.min_per_m3), 1e-9, 1e-20);
  EXPECT_NEAR(soot.VolumeFraction(b.max_per_m3), 1e-4, 1e-15);
  // The paper's range implies volume fractions far above 1 (DESIGN section 5).
  EXPECT_GT(soot.VolumeFraction(DensityBounds::Paper().min_per_m3), 1.0);
}

TEST(Tables, BlackbodyTableMatchesDirectIntegration) {
  const auto& table = BlackbodyXyzTable::Get();
  for (double t : {800.3, 1300.7, 2000.0, 2345.5, 9999.9, 25000.0}) {
    double v[3];
    table.Lookup(t, v);
    Eigen::Vector3d exact = BlackbodyXyz(t);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(v[c] / exact[c], 1.0, 3e-4) << t << " K channel " << c;
  }
  float f[3];
  table.Lookup(-5.0f, f);
  EXPECT_EQ(f[0], 0.0f);
  table.Lookup(std::nanf(""), f);
  EXPECT_EQ(f[1], 0.0f);
}

TEST(Tables, SpectralBinsIntegrateLikeTheTable) {
  SpectralBins bins(380, 780, 10);
  EXPECT_EQ(bins.count(), 41);
  for (double t : {1300.0, 2000.0, 3000.0}) {
    Eigen::Vector3d xyz = Eigen::Vector3d::Zero();
    for (int i = 0; i < bins.count(); ++i) xyz += bins.Planck(i, t) * bins.weight(i);
    Eigen::Vector3d exact = BlackbodyXyz(t);
    // 10 nm bins: Planck's steep blue flank at low temperature costs Z most.
    for (int c = 0; c < 3; ++c)
      EXPECT_NEAR(xyz[c] / exact[c], 1.0, c == 2 ? 1e-2 : 2e-3) << t << " K channel " << c;
  }
  // 1 nm bins over the whole table integrate exactly like the direct sum.
  SpectralBins fine(360, 830, 1);
  Eigen::Vector3d xyz = Eigen::Vector3d::Zero();
  for (int i = 0; i < fine.count(); ++i) xyz += fine.Planck(i, 1500.0) * fine.weight(i);
  Eigen::Vector3d exact = BlackbodyXyz(1500.0);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(xyz[c] / exact[c], 1.0, 3e-4) << c;
  EXPECT_THROW(SpectralBins(300, 780, 10), InputError);
  EXPECT_THROW(SpectralBins(380, 780, 0), InputError);
  // A step so small that the bin count overflows an int: the same clear error.
  EXPECT_THROW(SpectralBins(380, 780, 1e-9), InputError);
  // z-bar is 0 from 650 nm on (CIE 1931): a range there could not give blue transmittance.
  try {
    SpectralBins red(660, 780, 10);
    ADD_FAILURE() << "660..780 nm accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("z-bar"), std::string::npos) << e.what();
  }
  EXPECT_NO_THROW(SpectralBins(380, 700, 10));
}

}  // namespace
}  // namespace flamerig::colour
