// The tomography's smoothness priors (tomography/prior.h): the energy against its closed form, the
// gradient against finite differences of the energy, and settings that are errors. What a prior is
// for (a noisy solve nearer the truth) is tested on Shepp-Logan in tomography_reconstruct_test.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "core/error.h"
#include "tomography/prior.h"
#include "tomography/solvers.h"

namespace flamerig {
namespace {

GridGeometry Cube(int n) {
  return GridGeometry::FromBoxAndDims(Box3{Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(1, 1, 1)},
                                      Eigen::Vector3i(n, n, n));
}

// The oracle: every pair of face neighbours of the dense grid, each voxel valued by its column
// or 0, counted when at least one of the two is a column.
double DenseEnergy(PriorKind kind, const GridGeometry& g, const std::vector<std::uint32_t>& cols,
                   const std::vector<float>& x, const float scale[3], double edge) {
  std::vector<double> dense(g.num_voxels() * 3, 0.0);
  std::vector<bool> is_col(g.num_voxels(), false);
  for (std::size_t c = 0; c < cols.size(); ++c) {
    is_col[cols[c]] = true;
    for (int ch = 0; ch < 3; ++ch) dense[cols[c] * 3 + ch] = x[c * 3 + ch];
  }
  const double n = g.dims.maxCoeff();
  double u = 0;
  for (int k = 0; k < g.dims.z(); ++k)
    for (int j = 0; j < g.dims.y(); ++j)
      for (int i = 0; i < g.dims.x(); ++i)
        for (int axis = 0; axis < 3; ++axis) {
          const int a = i + (axis == 0), b = j + (axis == 1), d = k + (axis == 2);
          if (a >= g.dims.x() || b >= g.dims.y() || d >= g.dims.z()) continue;
          const std::size_t p = g.Flat(i, j, k), q = g.Flat(a, b, d);
          if (!is_col[p] && !is_col[q]) continue;
          for (int ch = 0; ch < 3; ++ch) {
            const double v = n * (dense[p * 3 + ch] - dense[q * 3 + ch]) / scale[ch];
            u += kind == PriorKind::kQuadratic ? 0.5 * v * v : std::sqrt(v * v + edge * edge);
          }
        }
  return u / (n * n * n);
}

TEST(GridPrior, EnergyCountsColumnPairsAndTheHullsEdgeAgainstEmptySpace) {
  const GridGeometry g = Cube(3);
  // Three columns in a row along x and one above the first; every other voxel is empty.
  const std::vector<std::uint32_t> cols = {
      std::uint32_t(g.Flat(0, 0, 0)), std::uint32_t(g.Flat(1, 0, 0)),
      std::uint32_t(g.Flat(2, 0, 0)), std::uint32_t(g.Flat(0, 1, 0))};
  const float scale[3] = {2, 1, 0.5f};
  std::vector<float> x(cols.size() * 3, 0.0f);
  x[0] = 1, x[3] = 3, x[6] = 3, x[9] = 0, x[4] = 0.5f, x[11] = 2;
  const GridPrior q(PriorKind::kQuadratic, g, cols, 0.1);
  EXPECT_EQ(q.NeighbourCount(0), 3);  // (1,0,0), (0,1,0), (0,0,1): the corner of the grid
  EXPECT_EQ(q.NeighbourCount(1), 4);
  // A case by hand, quadratic, channel 0 only (x = 1, 3, 3, 0; N = 3, L = 2, g = 1.5 dx): the
  // pairs (0,1) -3, (1,2) 0, (0,3) 1.5 and, against empty voxels, the first column once (1.5, to
  // (0,0,1)), the second and the third twice each (4.5, above and behind them).
  std::vector<float> x0(cols.size() * 3, 0.0f);
  x0[0] = 1, x0[3] = 3, x0[6] = 3;
  const double by_hand = 0.5 * (9 + 0 + 2.25 + 2.25 + 4 * 20.25) / 27;
  EXPECT_NEAR(q.Energy(x0.data(), 3, scale), by_hand, 1e-12);
  // The same field as one channel (grey data): the same energy, and the gradient of channel 0.
  const std::vector<float> x1 = {1, 3, 3, 0};
  EXPECT_NEAR(q.Energy(x1.data(), 1, scale), by_hand, 1e-12);
  std::vector<float> g1(cols.size()), g3(cols.size() * 3);
  q.Gradient(x1.data(), 1, scale, g1.data());
  q.Gradient(x0.data(), 3, scale, g3.data());
  for (std::size_t c = 0; c < cols.size(); ++c) EXPECT_EQ(g1[c], g3[c * 3]) << c;
  EXPECT_NEAR(q.Energy(x0.data(), 3, scale),
              DenseEnergy(PriorKind::kQuadratic, g, cols, x0, scale, 0.1), 1e-12);
  for (double e : {0.1, 0.3, 2.0}) {
    const GridPrior tv(PriorKind::kTotalVariation, g, cols, e);
    EXPECT_NEAR(tv.Energy(x.data(), 3, scale),
                DenseEnergy(PriorKind::kTotalVariation, g, cols, x, scale, e), 1e-12);
  }
  EXPECT_NEAR(q.Energy(x.data(), 3, scale),
              DenseEnergy(PriorKind::kQuadratic, g, cols, x, scale, 0.1), 1e-12);
  EXPECT_EQ(GridPrior(PriorKind::kNone, g, cols, 0.1).Energy(x.data(), 3, scale), 0.0);
}

// A random hull with holes (70% of a 6^3 grid's voxels) and a random three-channel field on it,
// values in [0, 5).
void RandomHullAndField(const GridGeometry& g, std::uint32_t seed, std::vector<std::uint32_t>* cols,
                        std::vector<float>* x) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0, 1);
  cols->clear();
  for (std::uint32_t v = 0; v < g.num_voxels(); ++v)
    if (u(rng) < 0.7) cols->push_back(v);
  x->resize(cols->size() * 3);
  for (float& v : *x) v = 5 * u(rng);
}

TEST(GridPrior, GradientMatchesFiniteDifferences) {
  const GridGeometry g = Cube(6);
  std::vector<std::uint32_t> cols;
  std::vector<float> x;
  RandomHullAndField(g, 3, &cols, &x);
  const float scale[3] = {1.5f, 0.7f, 3.0f};
  for (PriorKind kind : {PriorKind::kQuadratic, PriorKind::kTotalVariation}) {
    SCOPED_TRACE(ToString(kind));
    const GridPrior prior(kind, g, cols, 2.0);  // g here is about 4 per unit of x
    std::vector<float> grad(x.size());
    prior.Gradient(x.data(), 3, scale, grad.data());
    double worst = 0, largest = 0;
    for (std::size_t k = 0; k < x.size(); k += 7) {
      std::vector<float> p = x, m = x;
      const float h = 1e-2f;
      p[k] += h;
      m[k] -= h;
      const double fd =
          (prior.Energy(p.data(), 3, scale) - prior.Energy(m.data(), 3, scale)) / (2 * h);
      worst = std::max(worst, std::abs(fd - grad[k]));
      largest = std::max(largest, std::abs(fd));
    }
    EXPECT_GT(largest, 1e-3);
    EXPECT_LT(worst, 2e-3 * largest);
  }
}

// The majoriser that keeps OS-EM's MAP step stable (osem.cc): it touches U at x0 (equal gradients)
// and lies above it everywhere else (on random points near and far from x0), for both priors and
// a hull with holes, so that minimising it cannot raise U.
TEST(GridPrior, MajoriserTouchesAtTheIterateAndBoundsTheEnergyAbove) {
  const GridGeometry g = Cube(6);
  std::vector<std::uint32_t> cols;
  std::vector<float> x0;
  RandomHullAndField(g, 5, &cols, &x0);
  std::mt19937 rng(6);
  std::uniform_real_distribution<float> u(0, 1);
  const float scale[3] = {1.5f, 0.7f, 3.0f};
  for (PriorKind kind : {PriorKind::kQuadratic, PriorKind::kTotalVariation}) {
    SCOPED_TRACE(ToString(kind));
    const GridPrior prior(kind, g, cols, 2.0);
    std::vector<double> k(x0.size()), m(x0.size());
    for (std::size_t c = 0; c < cols.size(); ++c)
      prior.MajoriserAt(c, x0.data(), 3, scale, &k[3 * c], &m[3 * c]);
    std::vector<float> grad(x0.size());
    prior.Gradient(x0.data(), 3, scale, grad.data());
    double worst = 0, largest = 0;
    for (std::size_t q = 0; q < x0.size(); ++q) {
      EXPECT_GE(k[q], 0.0);
      worst = std::max(worst, std::abs(k[q] * x0[q] - m[q] - grad[q]));
      largest = std::max(largest, std::abs(double(grad[q])));
    }
    EXPECT_GT(largest, 1e-3);
    EXPECT_LT(worst, 1e-5 * largest);
    auto surrogate = [&](const std::vector<float>& x) {
      double s = 0;
      for (std::size_t q = 0; q < x.size(); ++q) s += 0.5 * k[q] * x[q] * x[q] - m[q] * x[q];
      return s;
    };
    const double u0 = prior.Energy(x0.data(), 3, scale), q0 = surrogate(x0);
    for (double spread : {0.01, 0.3, 3.0, 30.0}) {
      for (int trial = 0; trial < 20; ++trial) {
        std::vector<float> x = x0;
        for (float& v : x) v = std::max(0.0f, v + static_cast<float>(spread * (u(rng) - 0.5)));
        const double du = prior.Energy(x.data(), 3, scale) - u0, dq = surrogate(x) - q0;
        EXPECT_GE(dq, du - 1e-9 * (1 + std::abs(du))) << spread;
      }
    }
  }
}

TEST(GridPrior, BadSettingsAreErrors) {
  const GridGeometry g = Cube(2);
  EXPECT_THROW(GridPrior(PriorKind::kTotalVariation, g, {0, 1}, 0.0), InputError);
  EXPECT_THROW(GridPrior(PriorKind::kTotalVariation, g, {0, 99}, 0.1), InputError);
  EXPECT_THROW(ParsePriorKind("laplace"), InputError);
  SolveOptions o;
  o.prior = "tv";
  o.solver = "sart";
  EXPECT_THROW(o.Validate(), InputError);  // OS-EM only
  o.solver = "osem";
  EXPECT_NO_THROW(o.Validate());
  EXPECT_DOUBLE_EQ(PriorWeight(o), DefaultPriorWeight(PriorKind::kTotalVariation));
  o.prior_weight = -2;
  EXPECT_THROW(o.Validate(), InputError);
  o.prior_weight = 0.5;
  EXPECT_DOUBLE_EQ(PriorWeight(o), 0.5);
  o.prior = "none";
  EXPECT_DOUBLE_EQ(PriorWeight(o), 0.0);
}

}  // namespace
}  // namespace flamerig
