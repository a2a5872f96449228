// Per-voxel confidence through the fit job (fitting/uncertainty.h): every fitted .vdb carries
// temperature_sigma, density_sigma and determined grids that round-trip, sigma is positive where
// the fit has medium and zero elsewhere, more views shrink it (information adds up), and its
// coverage of the simulator's truth (finer than the fit's grid) is measured, printed and held to
// issue 19's calibration target.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>

#include "pipeline/fit_job.h"
#include "pipeline/simulate.h"
#include "tomography/vdb_io.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

double Median(std::vector<float> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + std::ptrdiff_t(v.size() / 2), v.end());
  return v[v.size() / 2];
}

TEST(Uncertainty, FittedVolumesCarrySigmaGridsThatShrinkWithMoreViews) {
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_uncertainty_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  SimulateConfig config;
  config.grid_resolution = 48;
  config.ring.cameras = 4;
  config.ring.width = 160;
  config.ring.height = 120;
  config.calibration = false;
  const SimulateSummary s = Simulate(config, (dir / "data").string());
  auto fit = [&](const std::vector<std::string>& views, const std::string& name) {
    FitJob job;
    job.rig_path = (dir / "data" / "rig.yaml").string();
    job.images_dir = (dir / "data" / "frames" / "frame_000000").string();
    job.out_path = (dir / (name + ".vdb")).string();
    job.views = views;
    job.resolution = 32;
    job.exposure = s.exposure;
    job.truth_path = (dir / "data" / "truth" / "frame_000000.vdb").string();
    return RunFitJob(job);
  };
  const FitJobResult two = fit({"cam0", "cam1"}, "two");
  const FitJobResult four = fit({"cam0", "cam1", "cam2", "cam3"}, "four");
  const FireVolume back = ReadVdb((dir / "two.vdb").string());
  const FireVolume& fitted = two.result.volume;
  ASSERT_EQ(back.temperature_sigma_k.size(), fitted.geometry.num_voxels());
  ASSERT_EQ(back.density_sigma.size(), fitted.geometry.num_voxels());
  ASSERT_EQ(back.determined.size(), fitted.geometry.num_voxels());
  std::vector<float> sigma_two, sigma_four;
  const double prior = (2300.0 - 300.0) / std::sqrt(12.0);
  for (std::size_t i = 0; i < fitted.geometry.num_voxels(); ++i) {
    EXPECT_EQ(back.temperature_sigma_k[i], fitted.temperature_sigma_k[i]);
    if (fitted.density_per_m3[i] > 0) {
      EXPECT_GT(fitted.temperature_sigma_k[i], 0) << i;
      EXPECT_LE(fitted.temperature_sigma_k[i], prior + 1e-3) << i;
      EXPECT_GT(fitted.density_sigma[i], 0) << i;
      EXPECT_TRUE(fitted.determined[i] == 0 || fitted.determined[i] == 1) << i;
      sigma_two.push_back(fitted.temperature_sigma_k[i]);
      if (four.result.volume.density_per_m3[i] > 0)
        sigma_four.push_back(four.result.volume.temperature_sigma_k[i]);
    } else {
      EXPECT_EQ(fitted.temperature_sigma_k[i], 0) << i;
    }
  }
  ASSERT_FALSE(sigma_two.empty());
  ASSERT_FALSE(sigma_four.empty());
  const double m2 = Median(sigma_two), m4 = Median(sigma_four);
  for (const FitJobResult* r : {&two, &four})
    std::printf(
        "%zu views: RMS %.1f K, bias %+.1f K; %.0f%% of visible voxels within one sigma, %.0f%% "
        "within two; median sigma %.0f K; %.0f%% determined; noise %.2f per Lab residual\n",
        r->scores.size(), r->truth.rms_k, r->truth.mean_k, 100 * r->truth.within_1_sigma,
        100 * r->truth.within_2_sigma, r->truth.median_sigma_k, 100 * r->truth.determined_share,
        r->result.uncertainty.sigma_lab);
  EXPECT_LT(m4, m2) << "two views " << m2 << " K, four " << m4 << " K";
  ASSERT_TRUE(two.truth.have_sigma);
  EXPECT_LE(two.truth.within_1_sigma, two.truth.within_2_sigma);
  EXPECT_GT(two.truth.within_2_sigma, 0.0);
  // Calibrated (issue 19: 68% +- 10% of the visible voxels within one sigma): 75% on two views and
  // 69% on four with the neighbour weight scaled to this 32-voxel grid (76% and 68% unscaled; 85%
  // and 83% while the noise level was the residuals' level, model error and all).
  EXPECT_LE(two.truth.within_1_sigma, 0.8);
  EXPECT_GE(four.truth.within_1_sigma, 0.58);
  EXPECT_LE(four.truth.within_1_sigma, 0.78);
  EXPECT_GE(four.truth.within_2_sigma, 0.85);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace flamerig
