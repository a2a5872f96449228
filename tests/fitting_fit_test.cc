// The fit's energy against independent references (colour.h's Lab, finite differences of the
// whole energy), and the fast fit's synthetic round trip as in the paper's validation: a known
// fire rendered from two views, reconstructed by tomography, fitted, and checked on the fitted
// views, on a held-out view and against the true temperatures.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "fitting/colour.h"
#include "fitting/fit.h"
#include "tomography/reconstruct.h"
#include "tools/simulate.h"
#include "tools/synthetic.h"

namespace flamerig {
namespace {

TEST(CameraLab, MatchesColourLabAndItsJacobianMatchesFiniteDifferences) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0.0, 1.2);
  for (int trial = 0; trial < 50; ++trial) {
    const Eigen::Vector3d linear(u(rng), u(rng) * 0.5, u(rng) * 0.1);
    const double s = 0.9;
    Eigen::Matrix3d jac;
    const Eigen::Vector3d lab = CameraLab(linear, s, &jac);
    const Eigen::Vector3d c = (s * linear).cwiseMin(1.0).cwiseMax(0.0);
    const Eigen::Vector3d ref = colour::XyzToLab(colour::XyzFromLinearSrgb() * c);
    EXPECT_LT((lab - ref).norm(), 1e-9);
    for (int k = 0; k < 3; ++k) {
      const double v = s * linear[k];
      if (std::abs(v - 1) < 1e-3) continue;  // the clamp's kink
      Eigen::Vector3d p = linear, m = linear;
      p[k] += 1e-7;
      m[k] -= 1e-7;
      const Eigen::Vector3d fd = (CameraLab(p, s) - CameraLab(m, s)) / 2e-7;
      EXPECT_LT((fd - jac.col(k)).norm(), 1e-4 * (1 + fd.norm())) << trial << " " << k;
    }
  }
  // Black is Lab 0; saturated white is Lab (100, 0, 0).
  EXPECT_LT(CameraLab(Eigen::Vector3d::Zero(), 1).norm(), 1e-12);
  EXPECT_LT((CameraLab(Eigen::Vector3d(5, 5, 5), 1) - Eigen::Vector3d(100, 0, 0)).norm(), 1e-9);
}

struct SmallScene {
  GridGeometry grid;
  std::vector<std::uint32_t> active;
  std::vector<double> t, n;
  std::unique_ptr<CameraRays> rays0, rays1;
  std::vector<FitView> views;
};

// An 8x8x8 blob seen by two cameras; images rendered from a different volume so that the energy
// is far from zero.
SmallScene MakeSmallScene(const AbsorptionModel& absorption) {
  SmallScene s;
  Box3 box{Eigen::Vector3d(-0.02, 0, -0.02), Eigen::Vector3d(0.02, 0.04, 0.02)};
  s.grid = GridGeometry::FromBox(box, 8);
  synthetic::RingOptions ring;
  ring.cameras = 2;
  ring.width = 24;
  ring.height = 18;
  ring.distance_m = 0.15;
  Rig rig = synthetic::MakeRingRig(box, ring);
  s.rays0 = std::make_unique<CameraRays>(rig.cameras[0].model);
  s.rays1 = std::make_unique<CameraRays>(rig.cameras[1].model);
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> u(0, 1);
  const DensityBounds b = DensityBounds::Plausible(absorption);
  std::vector<float> tt(s.grid.num_voxels(), 0), nn(s.grid.num_voxels(), 0);
  for (std::uint32_t v = 0; v < s.grid.num_voxels(); ++v) {
    const Eigen::Vector3d c = s.grid.VoxelCenter(v % 8, (v / 8) % 8, v / 64);
    if ((c - box.center()).norm() > 0.017) continue;
    s.active.push_back(v);
    s.t.push_back(1500 + 600 * u(rng));
    // Optical depth about 0.3 per voxel at its densest.
    s.n.push_back(0.3 / (absorption.CrossSectionM2(550) * s.grid.voxel_size_m.x()) * (0.3 + u(rng)));
    tt[v] = static_cast<float>(1800 + 200 * u(rng));
    nn[v] = static_cast<float>(s.n.back() * (0.5 + u(rng)));
  }
  (void)b;
  FireRenderer r(absorption);
  r.SetVolume(s.grid, tt, nn);
  for (const CameraRays* rays : {s.rays0.get(), s.rays1.get()}) {
    ImageF lin;
    r.Render(*rays, &lin);
    FitView v;
    v.name = "cam";
    v.rays = rays;
    v.image = ApplyCameraResponse(lin, 0.05);
    s.views.push_back(std::move(v));
  }
  return s;
}

void CheckEnergyGradient(const AbsorptionModel& absorption) {
  SmallScene s = MakeSmallScene(absorption);
  RenderOptions render;
  render.double_precision = true;
  render.min_transmittance = 0;
  render.spectral_step_nm = 40;
  ObjectiveOptions o;
  o.smooth_delta_e = 0.5;
  o.smooth_neighbour = 0.01;
  FitObjective objective(s.grid, s.active, s.views, absorption, render, o);
  ASSERT_GT(objective.neighbour_pairs().size(), s.active.size());  // the 18-neighbourhood
  const double exposure = 0.04;
  std::vector<double> d_t, d_n;
  double d_s = 0;
  const EnergyTerms terms = objective.Evaluate(s.t, s.n, exposure, true, &d_t, &d_n, &d_s);
  ASSERT_GT(terms.data_exact, 0);
  ASSERT_GT(terms.smooth_exact, 0);
  auto energy = [&](const std::vector<double>& t, const std::vector<double>& n, double e) {
    return objective.Evaluate(t, n, e, true).energy;
  };
  double max_t = 0, max_n = 0;
  for (std::size_t a = 0; a < s.active.size(); ++a) {
    max_t = std::max(max_t, std::abs(d_t[a]));
    max_n = std::max(max_n, std::abs(d_n[a] * s.n[a]));
  }
  for (std::size_t a = 0; a < s.active.size(); a += 5) {
    // Temperature: stay on one 1 K segment of the tables (start at x.5).
    std::vector<double> t = s.t;
    t[a] = std::floor(t[a]) + 0.5;
    std::vector<double> tp = t, tm = t;
    tp[a] += 0.4;
    tm[a] -= 0.4;
    std::vector<double> g_t;
    objective.Evaluate(t, s.n, exposure, true, &g_t);
    const double fd_t = (energy(tp, s.n, exposure) - energy(tm, s.n, exposure)) / 0.8;
    EXPECT_NEAR(g_t[a], fd_t, 2e-3 * max_t + 2e-3 * std::abs(fd_t)) << "voxel " << a;
    std::vector<double> np = s.n, nm = s.n;
    np[a] *= 1.002;
    nm[a] *= 0.998;
    const double fd_n = (energy(s.t, np, exposure) - energy(s.t, nm, exposure)) / (np[a] - nm[a]);
    EXPECT_NEAR(d_n[a] * s.n[a], fd_n * s.n[a], 2e-3 * max_n + 2e-3 * std::abs(fd_n * s.n[a]))
        << "voxel " << a;
  }
  const double fd_s =
      (energy(s.t, s.n, exposure * 1.001) - energy(s.t, s.n, exposure * 0.999)) / (0.002 * exposure);
  EXPECT_NEAR(d_s, fd_s, 2e-3 * std::abs(fd_s));
}

TEST(FitObjective, GradientMatchesFiniteDifferencesGrey) {
  CheckEnergyGradient(AbsorptionModel::DefaultGrey());
}

TEST(FitObjective, GradientMatchesFiniteDifferencesSoot) {
  CheckEnergyGradient(AbsorptionModel::DefaultSoot());
}

TEST(FitObjective, RejectsBadInput) {
  const AbsorptionModel grey = AbsorptionModel::DefaultGrey();
  SmallScene s = MakeSmallScene(grey);
  RenderOptions render;
  ObjectiveOptions o;
  EXPECT_THROW(FitObjective(s.grid, s.active, {}, grey, render, o), std::invalid_argument);
  std::vector<FitView> wrong = s.views;
  wrong[1].image = ImageU8(5, 5, 3);
  EXPECT_THROW(FitObjective(s.grid, s.active, wrong, grey, render, o), std::invalid_argument);
  std::vector<std::uint32_t> repeated = s.active;
  repeated.push_back(repeated.front());
  EXPECT_THROW(FitObjective(s.grid, repeated, s.views, grey, render, o), std::invalid_argument);
  FitObjective objective(s.grid, s.active, s.views, grey, render, o);
  std::vector<double> t = s.t;
  t[3] = std::nan("");
  EXPECT_THROW(objective.Evaluate(t, s.n, 1.0, true), std::invalid_argument);
  EXPECT_THROW(objective.Evaluate(s.t, s.n, 0.0, true), std::invalid_argument);
  ObjectiveOptions bad;
  bad.t_max_k = 100;
  EXPECT_THROW(FitObjective(s.grid, s.active, s.views, grey, render, bad), std::invalid_argument);
}

TEST(ThinEmissionTable, RecoversTheTemperatureOfABlackBodyColour) {
  for (const AbsorptionModel& m : {AbsorptionModel::DefaultGrey(), AbsorptionModel::DefaultSoot()}) {
    ThinEmissionTable table(m, 300, 2300);
    for (double t : {900.0, 1300.0, 1750.0, 2250.0}) {
      EXPECT_NEAR(table.TemperatureOf(table.RgbPerDensity(t) * 3.7), t, 1.0) << m.name();
    }
    EXPECT_EQ(table.TemperatureOf(Eigen::Vector3d::Zero()), 300);
  }
}

}  // namespace
}  // namespace flamerig
