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

TEST(GridPrior, EnergyIsTheClosedFormOverPairsOfColumns) {
  const GridGeometry g = Cube(3);
  // Three columns in a row along x (0,0,0), (1,0,0), (2,0,0), and (0,1,0) above the first; the
  // voxel (1,1,0) is not a column, so the pair it would make with (0,1,0) does not count.
  const std::vector<std::uint32_t> cols = {
      std::uint32_t(g.Flat(0, 0, 0)), std::uint32_t(g.Flat(1, 0, 0)),
      std::uint32_t(g.Flat(2, 0, 0)), std::uint32_t(g.Flat(0, 1, 0))};
  const float scale[3] = {2, 1, 0.5f};
  // Channel values: x = 1, 3, 3, 0 in channel 0; zero elsewhere.
  std::vector<float> x(cols.size() * 3, 0.0f);
  x[0] = 1, x[3] = 3, x[6] = 3, x[9] = 0;
  const GridPrior q(PriorKind::kQuadratic, g, cols, 0.1);
  EXPECT_EQ(q.NeighbourCount(0), 2);
  EXPECT_EQ(q.NeighbourCount(1), 2);
  EXPECT_EQ(q.NeighbourCount(3), 1);
  // N = 3; g = N dx / L: pairs (0,1): 3 * -2 / 2 = -3, (1,2): 0, (0,3): 3 * 1 / 2 = 1.5; U is the
  // sum over N^3 = 27.
  EXPECT_NEAR(q.Energy(x.data(), scale), 0.5 * (9 + 2.25) / 27, 1e-12);
  const double e = 0.3;
  const GridPrior tv(PriorKind::kTotalVariation, g, cols, e);
  // Three pairs per channel; channels 1 and 2 have d = 0 and give e each.
  const double want = (std::sqrt(9 + e * e) + e + std::sqrt(2.25 + e * e) + 6 * e) / 27;
  EXPECT_NEAR(tv.Energy(x.data(), scale), want, 1e-12);
  EXPECT_EQ(GridPrior(PriorKind::kNone, g, cols, 0.1).Energy(x.data(), scale), 0.0);
}

TEST(GridPrior, GradientMatchesFiniteDifferences) {
  const GridGeometry g = Cube(6);
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0, 1);
  std::vector<std::uint32_t> cols;
  for (std::uint32_t v = 0; v < g.num_voxels(); ++v)
    if (u(rng) < 0.7) cols.push_back(v);  // a hull with holes
  std::vector<float> x(cols.size() * 3);
  for (float& v : x) v = 5 * u(rng);
  const float scale[3] = {1.5f, 0.7f, 3.0f};
  for (PriorKind kind : {PriorKind::kQuadratic, PriorKind::kTotalVariation}) {
    SCOPED_TRACE(ToString(kind));
    const GridPrior prior(kind, g, cols, 2.0);  // g here is about 4 per unit of x
    std::vector<float> grad(x.size());
    prior.Gradient(x.data(), scale, grad.data());
    double worst = 0, largest = 0;
    for (std::size_t k = 0; k < x.size(); k += 7) {
      std::vector<float> p = x, m = x;
      const float h = 1e-2f;
      p[k] += h;
      m[k] -= h;
      const double fd = (prior.Energy(p.data(), scale) - prior.Energy(m.data(), scale)) / (2 * h);
      worst = std::max(worst, std::abs(fd - grad[k]));
      largest = std::max(largest, std::abs(fd));
    }
    EXPECT_GT(largest, 1e-3);
    EXPECT_LT(worst, 2e-3 * largest);
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
