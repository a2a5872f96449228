// Synthetic fires whose truth is known: deterministic, seeded, physical, and their thin-limit
// emission is what the renderer integrates.
#include <gtest/gtest.h>

#include <filesystem>

#include "core/error.h"
#include "fitting/colour.h"
#include "fitting/renderer.h"
#include "fitting/synthetic_fire.h"

namespace flamerig::synthetic {
namespace {

const Box3 kBox{Eigen::Vector3d(-0.02, 0.0, -0.02), Eigen::Vector3d(0.02, 0.08, 0.02)};

TEST(Fire, DeterministicSeededAndPhysical) {
  GridGeometry g = GridGeometry::FromBox(kBox, 32);
  AbsorptionModel soot = AbsorptionModel::DefaultSoot();
  for (FireKind kind : {FireKind::kCandle, FireKind::kLicks}) {
    FireOptions o;
    o.kind = kind;
    o.seed = 3;
    FireVolume a = MakeFire(g, o, soot), b = MakeFire(g, o, soot);
    EXPECT_EQ(a.temperature_k, b.temperature_k);
    EXPECT_EQ(a.density_per_m3, b.density_per_m3);
    o.seed = 4;
    FireVolume c = MakeFire(g, o, soot);
    EXPECT_NE(a.density_per_m3, c.density_per_m3) << ToString(kind);
    o.seed = 3;
    o.time_s = 0.1;
    FireVolume d = MakeFire(g, o, soot);
    EXPECT_NE(a.temperature_k, d.temperature_k) << ToString(kind);

    float t_max = 0, t_min = 1e9f, n_max = 0;
    std::size_t burning = 0;
    for (std::size_t i = 0; i < g.num_voxels(); ++i) {
      t_max = std::max(t_max, a.temperature_k[i]);
      t_min = std::min(t_min, a.temperature_k[i]);
      n_max = std::max(n_max, a.density_per_m3[i]);
      if (a.density_per_m3[i] > 0) ++burning;
    }
    EXPECT_GE(t_min, 300.0f);
    EXPECT_LE(t_max, 2000.0f);
    EXPECT_GT(t_max, 1700.0f) << ToString(kind);
    EXPECT_LE(n_max, soot.DensityFromVolumeFraction(1e-6) * 1.0001);
    EXPECT_GT(n_max, soot.DensityFromVolumeFraction(1e-6) * 0.3);
    // The flame fills a part of the box, and nothing touches its sides.
    double fraction = double(burning) / g.num_voxels();
    EXPECT_GT(fraction, 0.02) << ToString(kind);
    EXPECT_LT(fraction, 0.6) << ToString(kind);
    for (int k = 0; k < g.dims.z(); ++k)
      for (int j = 0; j < g.dims.y(); ++j) {
        EXPECT_EQ(a.density_per_m3[g.Flat(0, j, k)], 0.0f);
        EXPECT_EQ(a.density_per_m3[g.Flat(g.dims.x() - 1, j, k)], 0.0f);
      }
  }
}

TEST(Fire, ThinEmissionIsWhatTheRendererIntegrates) {
  // A uniform, optically thin block: the pixel is emission per metre times the path length.
  GridGeometry g = GridGeometry::FromBoxAndDims(
      Box3{Eigen::Vector3d(-0.5, -0.5, -0.01), Eigen::Vector3d(0.5, 0.5, 0.01)},
      Eigen::Vector3i(4, 4, 4));
  for (bool soot : {false, true}) {
    AbsorptionModel absorption =
        soot ? AbsorptionModel::DefaultSoot() : AbsorptionModel::DefaultGrey();
    FireVolume fire;
    fire.geometry = g;
    fire.temperature_k.assign(g.num_voxels(), 1800.0f);
    fire.density_per_m3.assign(g.num_voxels(),
                               static_cast<float>(1e-4 / absorption.CrossSectionM2(550)));
    std::vector<float> emission = ThinEmissionRgb(fire, absorption);
    RenderOptions o;
    o.spectral_first_nm = 360;
    o.spectral_last_nm = 830;
    o.spectral_step_nm = 1;
    FireRenderer renderer(absorption, o);
    renderer.SetVolume(g, fire.temperature_k, fire.density_per_m3);
    Rigid3 pose = LookAt(Eigen::Vector3d(0, 0, 1), Eigen::Vector3d::Zero());
    ImageF image;
    renderer.Render(CameraRays(CameraModel::Pinhole(50, 50, 10, 10, pose, 21, 21)), &image);
    // Relative to the brightest channel: the blue channel of an 1800 K fire is a near-cancellation.
    const double scale =
        0.02 * std::max({std::abs(emission[0]), std::abs(emission[1]), std::abs(emission[2])});
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(image.at(10, 10, c), emission[c] * 0.02, 2e-4 * scale)
          << "soot " << soot << " channel " << c;
    }
  }
}

}  // namespace
}  // namespace flamerig::synthetic
