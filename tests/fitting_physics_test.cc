// Planck's law against published constants and closed forms (Stefan-Boltzmann, Wien), and its
// numerical stability over 1 K .. 1e5 K.
#include <gtest/gtest.h>

#include <cmath>

#include "fitting/physics.h"

namespace flamerig::physics {
namespace {

TEST(Constants, MatchCodata2018) {
  // Published derived constants (notes/physics.md, CODATA 2018).
  EXPECT_NEAR(kC1L, 1.191042972e-16, 1e-25);
  EXPECT_NEAR(kC2, 1.438776877e-2, 1e-11);
  EXPECT_NEAR(kStefanBoltzmann, 5.670374419e-8, 1e-17);
}

TEST(Planck, PublishedValues) {
  EXPECT_NEAR(PlanckRadiancePerNm(550.0, 2000.0), 4.9389, 5e-4);
  EXPECT_NEAR(PlanckRadiancePerNm(650.0, 1500.0), 0.40051, 5e-5);
}

// Integral of B over wavelength = sigma T^4 / pi. Integrated numerically in log wavelength from 50
// nm to 1 m with Simpson's rule.
double IntegratedRadiance(double temperature_k) {
  const double a = std::log(50e-9), b = std::log(1.0);
  const int n = 200000;
  const double h = (b - a) / n;
  double sum = 0;
  for (int i = 0; i <= n; ++i) {
    double lambda = std::exp(a + i * h);
    double f = PlanckRadiance(lambda, temperature_k) * lambda;  // d lambda = lambda d ln lambda
    double w = (i == 0 || i == n) ? 1 : (i % 2 ? 4 : 2);
    sum += w * f;
  }
  return sum * h / 3;
}

TEST(Planck, StefanBoltzmannIntegral) {
  for (double t : {300.0, 1000.0, 2000.0, 5000.0}) {
    double expected = kStefanBoltzmann * std::pow(t, 4) / kPi;
    EXPECT_NEAR(IntegratedRadiance(t) / expected, 1.0, 1e-6) << "T = " << t;
  }
}

TEST(Planck, WienDisplacementLaw) {
  for (double t : {800.0, 1500.0, 2300.0, 6000.0}) {
    // Golden-section search for the peak of B(lambda).
    double lo = 100e-9, hi = 20000e-9;
    const double g = (std::sqrt(5.0) - 1) / 2;
    for (int it = 0; it < 200; ++it) {
      double m1 = hi - g * (hi - lo), m2 = lo + g * (hi - lo);
      if (PlanckRadiance(m1, t) > PlanckRadiance(m2, t))
        hi = m2;
      else
        lo = m1;
    }
    EXPECT_NEAR(0.5 * (lo + hi) * t, 2.897771955e-3, 1e-9) << "T = " << t;
  }
}

TEST(Planck, DerivativeMatchesFiniteDifferences) {
  for (double t : {500.0, 1300.0, 2000.0, 3000.0, 20000.0}) {
    for (double nm : {400.0, 550.0, 700.0}) {
      double h = t * 1e-6;
      double fd = (PlanckRadiancePerNm(nm, t + h) - PlanckRadiancePerNm(nm, t - h)) / (2 * h);
      double analytic = PlanckRadiancePerNmDerivative(nm, t);
      EXPECT_NEAR(analytic / fd, 1.0, 1e-6) << nm << " nm, " << t << " K";
    }
  }
}

TEST(Planck, StableOverWholeRange) {
  for (double t = 1.0; t <= 1e5; t *= 1.1) {
    for (double nm = 300; nm <= 900; nm += 7) {
      double b = PlanckRadiancePerNm(nm, t);
      double d = PlanckRadiancePerNmDerivative(nm, t);
      ASSERT_TRUE(std::isfinite(b) && b >= 0) << nm << " nm " << t << " K: " << b;
      ASSERT_TRUE(std::isfinite(d) && d >= 0) << nm << " nm " << t << " K: " << d;
    }
  }
  EXPECT_EQ(PlanckRadiancePerNm(550, 0.0), 0.0);
  EXPECT_EQ(PlanckRadiancePerNm(550, -10.0), 0.0);
  EXPECT_EQ(PlanckRadiancePerNm(550, std::nan("")), 0.0);
  EXPECT_EQ(PlanckRadiancePerNm(550, INFINITY), 0.0);
  // Monotonic in temperature at a fixed wavelength.
  double previous = 0;
  for (double t = 200; t < 1e5; t *= 1.05) {
    double b = PlanckRadiancePerNm(600, t);
    EXPECT_GE(b, previous);
    previous = b;
  }
}

TEST(Planck, RayleighJeansLimitAtHighTemperature) {
  // For lambda k T >> h c: B -> 2 c k T / lambda^4.
  double t = 1e7, lambda = 800e-9;
  double rj = 2 * kSpeedOfLightMps * kBoltzmannJpK * t / std::pow(lambda, 4);
  EXPECT_NEAR(PlanckRadiance(lambda, t) / rj, 1.0, 1e-3);
}

}  // namespace
}  // namespace flamerig::physics
