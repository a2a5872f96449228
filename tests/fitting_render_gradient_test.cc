// The renderer's adjoint (RenderGradient) against central finite differences of Render(), on both
// paths, in double precision, through absorption strong enough that transmittance matters.
#include <gtest/gtest.h>

#include <cmath>
#include <mutex>
#include <random>
#include <set>

#include "core/cpu.h"
#include "core/error.h"
#include "fitting/renderer.h"

namespace flamerig {
namespace {

struct Scene {
  GridGeometry grid;
  std::vector<float> temperature, density;
  CameraModel camera = CameraModel::Pinhole(40, 40, 7.5, 5.5, Rigid3(), 16, 12);
};

// A 6x7x5 grid with a random blob of medium (some voxels empty), seen by a small pinhole camera
// at an angle so that rays cross voxels obliquely. Temperatures sit mid-way between whole kelvins
// so that +-0.45 K stays on one segment of the renderer's 1 K tables.
Scene MakeScene(const AbsorptionModel& absorption, double optical_depth_per_voxel, unsigned seed) {
  Scene s;
  Box3 box{Eigen::Vector3d(-0.03, -0.035, -0.025), Eigen::Vector3d(0.03, 0.035, 0.025)};
  s.grid = GridGeometry::FromBoxAndDims(box, Eigen::Vector3i(6, 7, 5));
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u01(0, 1);
  const double n_unit =
      optical_depth_per_voxel / (absorption.CrossSectionM2(550) * s.grid.voxel_size_m.x());
  for (std::size_t v = 0; v < s.grid.num_voxels(); ++v) {
    const bool empty = u01(rng) < 0.2;
    s.temperature.push_back(static_cast<float>(std::floor(1200 + 1000 * u01(rng)) + 0.5));
    s.density.push_back(empty ? 0.0f : static_cast<float>(n_unit * (0.2 + u01(rng))));
  }
  Rigid3 cam_from_rig = LookAt(Eigen::Vector3d(0.12, 0.05, 0.2), Eigen::Vector3d::Zero());
  s.camera = CameraModel::Pinhole(40, 40, 7.5, 5.5, cam_from_rig, 16, 12);
  return s;
}

// Loss = sum over pixels and channels of c * rgb with fixed random c, so dLoss/drgb = c.
double Loss(const FireRenderer& r, const CameraRays& rays, const ImageF& c) {
  ImageF image;
  r.Render(rays, &image);
  double sum = 0;
  for (std::size_t i = 0; i < image.pixels.size(); ++i)
    sum += double(c.pixels[i]) * image.pixels[i];
  return sum;
}

void CheckGradient(const AbsorptionModel& absorption, double optical_depth_per_voxel,
                   std::shared_ptr<const ChannelResponse> response = nullptr) {
  Scene s = MakeScene(absorption, optical_depth_per_voxel, 7);
  RenderOptions options;
  options.response = response;
  options.spectral_step_nm = 40;  // 11 bins: the same code as 41, a quarter of the test's time
  options.double_precision = true;
  options.min_transmittance = 0;  // no early termination: FD would straddle the cut
  options.brick_size_voxels = 2;  // some bricks are empty and skipped
  FireRenderer renderer(absorption, options);
  renderer.SetVolume(s.grid, s.temperature, s.density);
  CameraRays rays(s.camera);
  ImageF c(s.camera.width(), s.camera.height(), 3, 0.0f);
  std::mt19937 rng(3);
  std::normal_distribution<double> normal(0, 1);
  for (float& v : c.pixels) v = static_cast<float>(normal(rng));
  std::vector<double> dt, dn;
  renderer.RenderGradient(rays, c, &dt, &dn);
  ASSERT_EQ(dt.size(), s.grid.num_voxels());

  double max_dt = 0, max_dn = 0;
  for (std::size_t v = 0; v < dt.size(); ++v) {
    max_dt = std::max(max_dt, std::abs(dt[v]));
    max_dn = std::max(max_dn, std::abs(dn[v] * s.density[v]));
  }
  ASSERT_GT(max_dt, 0);
  ASSERT_GT(max_dn, 0);
  int checked = 0;
  for (std::size_t v = 0; v < s.grid.num_voxels(); ++v) {
    if (v % 2) continue;  // half the voxels keep the test quick
    if (s.density[v] == 0) {
      EXPECT_EQ(dt[v], 0.0);
      EXPECT_EQ(dn[v], 0.0);
      continue;
    }
    auto with = [&](std::vector<float> t, std::vector<float> n) {
      FireRenderer r(absorption, options);
      r.SetVolume(s.grid, t, n);
      return Loss(r, rays, c);
    };
    // Temperature: +-0.45 K (the same table segment).
    std::vector<float> tp = s.temperature, tm = s.temperature;
    tp[v] += 0.45f;
    tm[v] -= 0.45f;
    const double fd_t = (with(tp, s.density) - with(tm, s.density)) / (double(tp[v]) - tm[v]);
    EXPECT_NEAR(dt[v], fd_t, 1e-4 * max_dt + 1e-4 * std::abs(fd_t)) << "voxel " << v;
    // Density: relative step 5e-3 (float storage), compared in units of n dLoss/dn.
    std::vector<float> np = s.density, nm = s.density;
    np[v] *= 1.005f;
    nm[v] *= 0.995f;
    const double fd_n =
        (with(s.temperature, np) - with(s.temperature, nm)) / (double(np[v]) - nm[v]);
    EXPECT_NEAR(dn[v] * s.density[v], fd_n * s.density[v],
                1e-4 * max_dn + 1e-3 * std::abs(fd_n * s.density[v]))
        << "voxel " << v;
    ++checked;
  }
  EXPECT_GT(checked, 50);
}

TEST(RenderGradient, FastPathMatchesFiniteDifferencesThin) {
  CheckGradient(AbsorptionModel::DefaultGrey(), 0.05);
}

TEST(RenderGradient, FastPathMatchesFiniteDifferencesThick) {
  CheckGradient(AbsorptionModel::DefaultGrey(), 1.5);
}

TEST(RenderGradient, SpectralPathMatchesFiniteDifferences) {
  CheckGradient(AbsorptionModel::DefaultSoot(), 0.8);
}

// A camera that is not the observer: its own basis channels, and a mono camera's three equal ones.
std::shared_ptr<const ChannelResponse> BandCamera(int channels) {
  CameraRadiometry r;
  r.spectral.kind = SpectralSensitivity::Kind::kBands;
  r.spectral.bands = {{620, 70}, {540, 70}, {460, 70}};
  r.spectral.bands.resize(channels);
  if (channels == 3) r.gain = Eigen::Vector3d(1.3, 1, 0.7);
  return ChannelResponse::ForCamera(r);
}

TEST(RenderGradient, FastPathWithACameraResponseMatchesFiniteDifferences) {
  CheckGradient(AbsorptionModel::DefaultGrey(), 1.5, BandCamera(3));
}

TEST(RenderGradient, SpectralPathWithAMonoCameraMatchesFiniteDifferences) {
  CheckGradient(AbsorptionModel::DefaultSoot(), 0.8, BandCamera(1));
}

TEST(RenderGradient, FloatAgreesWithDoubleAndCountsOnlyMarchedPixels) {
  const AbsorptionModel grey = AbsorptionModel::DefaultGrey();
  Scene s = MakeScene(grey, 0.5, 11);
  RenderOptions opt_d, opt_f;
  opt_d.double_precision = true;
  FireRenderer rd(grey, opt_d), rf(grey, opt_f);
  rd.SetVolume(s.grid, s.temperature, s.density);
  rf.SetVolume(s.grid, s.temperature, s.density);
  CameraRays rays(s.camera);
  ImageF c(s.camera.width(), s.camera.height(), 3, 0.0f);
  c.at(8, 6, 1) = 1.0f;  // one pixel only
  std::vector<double> dt_d, dn_d, dt_f, dn_f;
  RenderSummary sd = rd.RenderGradient(rays, c, &dt_d, &dn_d);
  rf.RenderGradient(rays, c, &dt_f, &dn_f);
  EXPECT_EQ(sd.rays_hit_box, 1);
  double scale = 0;
  for (double v : dt_d) scale = std::max(scale, std::abs(v));
  ASSERT_GT(scale, 0);
  for (std::size_t v = 0; v < dt_d.size(); ++v) EXPECT_NEAR(dt_f[v], dt_d[v], 1e-4 * scale);
  // Accumulates: a second call doubles the gradient.
  rd.RenderGradient(rays, c, &dt_d, &dn_d);
  std::vector<double> dt1, dn1;
  rd.RenderGradient(rays, c, &dt1, &dn1);
  for (std::size_t v = 0; v < dt_d.size(); ++v) EXPECT_NEAR(dt_d[v], 2 * dt1[v], 1e-12 * scale);
}

// The float kernels, in their AVX2 + FMA build (where the CPU has it: core/cpu.h) and their
// baseline build, against the double-precision kernel: images and gradients on both paths, in a
// medium thin in every bin (the spectral path's series-only step) and one that is not, with a few
// voxels hotter than the renderer's kelvin tables reach.
TEST(RenderGradient, FloatKernelsOfBothBuildsAgreeWithDouble) {
  for (bool soot : {false, true}) {
    const AbsorptionModel absorption =
        soot ? AbsorptionModel::DefaultSoot() : AbsorptionModel::DefaultGrey();
    for (double depth : {0.002, 1.0}) {
      Scene s = MakeScene(absorption, depth, 13);
      for (std::size_t v = 0; v < s.temperature.size(); v += 17) s.temperature[v] = 25000.5f;
      CameraRays rays(s.camera);
      ImageF c(s.camera.width(), s.camera.height(), 3, 0.0f);
      std::mt19937 rng(5);
      std::normal_distribution<double> normal(0, 1);
      for (float& v : c.pixels) v = static_cast<float>(normal(rng));
      auto run = [&](bool use_double, bool wide, ImageF* image, std::vector<double>* dt,
                     std::vector<double>* dn) {
        RenderOptions o;
        o.spectral_step_nm = 20;  // 21 bins: padded to 24, a partial last vector
        o.double_precision = use_double;
        o.wide_kernels = wide;
        o.min_transmittance = 0;
        FireRenderer r(absorption, o);
        r.SetVolume(s.grid, s.temperature, s.density);
        const RenderSummary rendered = r.Render(rays, image);
        r.RenderGradient(rays, c, dt, dn);
        // The build asked for is the build that ran (the wide one only where the CPU has it).
        EXPECT_EQ(rendered.wide_kernels, !use_double && wide && UseWideKernels());
      };
      ImageF ref;
      std::vector<double> dt_ref, dn_ref;
      run(true, false, &ref, &dt_ref, &dn_ref);
      double image_scale = 0, dt_scale = 0, dn_scale = 0;
      for (float v : ref.pixels) image_scale = std::max(image_scale, double(std::abs(v)));
      for (std::size_t v = 0; v < dt_ref.size(); ++v) {
        dt_scale = std::max(dt_scale, std::abs(dt_ref[v]));
        dn_scale = std::max(dn_scale, std::abs(dn_ref[v] * s.density[v]));
      }
      ASSERT_GT(image_scale, 0);
      ASSERT_GT(dt_scale, 0);
      for (bool wide : {true, false}) {
        ImageF image;
        std::vector<double> dt, dn;
        run(false, wide, &image, &dt, &dn);
        const std::string what = std::string(soot ? "soot" : "grey") + ", depth " +
                                 std::to_string(depth) + (wide ? ", wide" : ", baseline");
        for (std::size_t i = 0; i < image.pixels.size(); ++i)
          ASSERT_NEAR(image.pixels[i], ref.pixels[i], 2e-5 * image_scale) << what << " pixel " << i;
        for (std::size_t v = 0; v < dt.size(); ++v) {
          ASSERT_NEAR(dt[v], dt_ref[v], 2e-4 * dt_scale) << what << " voxel " << v;
          ASSERT_NEAR(dn[v] * s.density[v], dn_ref[v] * s.density[v], 2e-4 * dn_scale)
              << what << " voxel " << v;
        }
      }
    }
  }
}

// RenderAndGradient (one pass) against Render then RenderGradient, with a gradient that depends
// on the rendered pixel as the fit's does, on both paths and both builds: the same image, the same
// gradients, every pixel asked once, and pixels given a zero gradient not marched back.
TEST(RenderGradient, RenderAndGradientEqualsRenderThenGradient) {
  for (bool soot : {false, true}) {
    const AbsorptionModel absorption =
        soot ? AbsorptionModel::DefaultSoot() : AbsorptionModel::DefaultGrey();
    Scene s = MakeScene(absorption, 0.7, 17);
    CameraRays rays(s.camera);
    const int w = s.camera.width(), h = s.camera.height();
    // dLoss/dRGB = (rgb - 1)^2 style: a function of the pixel, zero on the left third.
    auto gradient_of = [&](int x, int y, const Eigen::Vector3d& rgb) -> Eigen::Vector3d {
      if (x < w / 3) return Eigen::Vector3d::Zero();
      return Eigen::Vector3d(2 * (rgb[0] - 0.3), rgb[1] + 0.1 * y, -rgb[2]);
    };
    for (bool wide : {true, false}) {
      RenderOptions o;
      o.spectral_step_nm = 20;
      o.wide_kernels = wide;
      FireRenderer r(absorption, o);
      r.SetVolume(s.grid, s.temperature, s.density);
      ImageF image;
      r.Render(rays, &image);
      ImageF d(w, h, 3, 0.0f);
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
          const Eigen::Vector3d g = gradient_of(
              x, y, Eigen::Vector3d(image.at(x, y, 0), image.at(x, y, 1), image.at(x, y, 2)));
          for (int c = 0; c < 3; ++c) d.at(x, y, c) = static_cast<float>(g[c]);
        }
      std::vector<double> dt, dn;
      r.RenderGradient(rays, d, &dt, &dn);

      std::vector<int> asked(static_cast<std::size_t>(w) * h, 0);
      auto fn = [&](int x, int y, const Eigen::Vector3d& rgb) -> Eigen::Vector3d {
        ++asked[static_cast<std::size_t>(y) * w + x];  // distinct pixels: no race
        return gradient_of(x, y, rgb).cast<float>().cast<double>();
      };
      ImageF fused_image;
      std::vector<double> fdt, fdn;
      const RenderSummary summary = r.RenderAndGradient(rays, fn, &fused_image, &fdt, &fdn);
      const std::string what = std::string(soot ? "soot" : "grey") + (wide ? ", wide" : "");
      for (int count : asked) ASSERT_EQ(count, 1) << what;
      EXPECT_GT(summary.rays_hit_box, 0);
      for (std::size_t i = 0; i < image.pixels.size(); ++i)
        ASSERT_EQ(fused_image.pixels[i], image.pixels[i]) << what << " pixel value " << i;
      // The threads' buffers are summed in whatever order the threads ran: equal to rounding. The
      // spectral path's buffers of dLoss/dE per voxel and bin are floats, each a sum over the rays
      // one thread took, in its order; in a density derivative the emission's part and the
      // absorption's nearly cancel, so their float rounding shows at about 1e-7 of the largest
      // (1.1e-7 seen on the soot scene in one run of three under load), hence 5e-7.
      double scale = 0, dn_scale = 0;
      for (std::size_t v = 0; v < dt.size(); ++v) {
        scale = std::max(scale, std::abs(dt[v]));
        dn_scale = std::max(dn_scale, std::abs(dn[v]));
      }
      ASSERT_GT(scale, 0) << what;
      for (std::size_t v = 0; v < dt.size(); ++v) {
        ASSERT_NEAR(fdt[v], dt[v], 5e-7 * scale) << what << " voxel " << v;
        ASSERT_NEAR(fdn[v], dn[v], 5e-7 * dn_scale) << what << " voxel " << v;
      }
    }
  }
}

TEST(RenderGradient, ExtremeVolumesGiveFiniteGradients) {
  const AbsorptionModel grey = AbsorptionModel::DefaultGrey();
  for (auto [t, n] : {std::pair{1.0f, 1e30f}, std::pair{1e5f, 1e30f}, std::pair{2000.0f, 1e-30f},
                      std::pair{30000.0f, 1e10f}}) {
    Scene s = MakeScene(grey, 1.0, 5);
    for (std::size_t v = 0; v < s.grid.num_voxels(); ++v) {
      s.temperature[v] = t;
      if (s.density[v] > 0) s.density[v] = n;
    }
    for (bool soot : {false, true}) {
      FireRenderer r(soot ? AbsorptionModel::DefaultSoot() : grey);
      r.SetVolume(s.grid, s.temperature, s.density);
      CameraRays rays(s.camera);
      ImageF c(s.camera.width(), s.camera.height(), 3, 1.0f);
      std::vector<double> dt, dn;
      r.RenderGradient(rays, c, &dt, &dn);
      for (std::size_t v = 0; v < dt.size(); ++v) {
        ASSERT_TRUE(std::isfinite(dt[v]) && std::isfinite(dn[v]))
            << "T " << t << " n " << n << " voxel " << v << (soot ? " soot" : " grey");
      }
    }
  }
}

// RenderJacobian hands over, ray by ray, what RenderCurvature sums: the outer products of its
// per-voxel Jacobians, summed over the rays, are RenderCurvature's blocks (both paths, the float
// kernels the fit uses); each ray reports each voxel once, and only voxels with medium.
void CheckJacobianAgainstCurvature(const AbsorptionModel& absorption) {
  Scene s = MakeScene(absorption, 0.8, 5);
  RenderOptions options;
  options.spectral_step_nm = 40;
  options.brick_size_voxels = 2;
  FireRenderer renderer(absorption, options);
  renderer.SetVolume(s.grid, s.temperature, s.density);
  CameraRays rays(s.camera);
  std::vector<Eigen::Matrix3f> jacobians(rays.width() * rays.height());
  std::mt19937 rng(11);
  std::normal_distribution<float> normal(0, 1);
  for (auto& j : jacobians)
    for (int k = 0; k < 9; ++k) j.data()[k] = normal(rng);
  jacobians[3].setZero();  // a pixel that does not count
  std::vector<double> tt, tn, nn;
  renderer.RenderCurvature(rays, jacobians, &tt, &tn, &nn);
  std::mutex mutex;
  std::vector<double> jtt(s.grid.num_voxels(), 0.0), jtn(jtt), jnn(jtt);
  std::size_t rays_seen = 0;
  renderer.RenderJacobian(rays, jacobians, [&](const FireRenderer::RayJacobian& ray) {
    std::lock_guard<std::mutex> lock(mutex);
    ++rays_seen;
    EXPECT_NE(ray.pixel, 3u);
    EXPECT_EQ(ray.voxels.size(), ray.d.size());
    std::set<std::uint32_t> once(ray.voxels.begin(), ray.voxels.end());
    EXPECT_EQ(once.size(), ray.voxels.size()) << "pixel " << ray.pixel;
    for (std::size_t i = 0; i < ray.voxels.size(); ++i) {
      const std::uint32_t v = ray.voxels[i];
      EXPECT_GT(s.density[v], 0) << v;
      jtt[v] += ray.d[i].col(0).squaredNorm();
      jtn[v] += ray.d[i].col(0).dot(ray.d[i].col(1));
      jnn[v] += ray.d[i].col(1).squaredNorm();
    }
  });
  EXPECT_GT(rays_seen, 20u);
  double max_tt = 0, max_nn = 0;
  for (std::size_t v = 0; v < tt.size(); ++v) {
    max_tt = std::max(max_tt, tt[v]);
    max_nn = std::max(max_nn, nn[v]);
  }
  ASSERT_GT(max_tt, 0);
  for (std::size_t v = 0; v < tt.size(); ++v) {
    EXPECT_NEAR(jtt[v], tt[v], 1e-9 * max_tt) << v;
    EXPECT_NEAR(jnn[v], nn[v], 1e-9 * max_nn) << v;
    EXPECT_NEAR(jtn[v], tn[v], 1e-9 * std::sqrt(max_tt * max_nn)) << v;
  }
  std::vector<Eigen::Matrix3f> wrong(7);
  EXPECT_THROW(renderer.RenderJacobian(rays, wrong, [](const FireRenderer::RayJacobian&) {}),
               InputError);
  EXPECT_THROW(renderer.RenderJacobian(rays, jacobians, nullptr), InputError);
}

TEST(RenderGradient, RenderJacobianIsWhatRenderCurvatureSumsFast) {
  CheckJacobianAgainstCurvature(AbsorptionModel::DefaultGrey());
}

TEST(RenderGradient, RenderJacobianIsWhatRenderCurvatureSumsSpectral) {
  CheckJacobianAgainstCurvature(AbsorptionModel::DefaultSoot());
}

TEST(RenderGradient, RejectsMisSizedInputs) {
  const AbsorptionModel grey = AbsorptionModel::DefaultGrey();
  Scene s = MakeScene(grey, 0.5, 1);
  FireRenderer r(grey);
  CameraRays rays(s.camera);
  ImageF c(s.camera.width(), s.camera.height(), 3, 1.0f);
  std::vector<double> dt, dn;
  EXPECT_THROW(r.RenderGradient(rays, c, &dt, &dn), std::logic_error);  // no volume yet
  r.SetVolume(s.grid, s.temperature, s.density);
  ImageF wrong(3, 3, 3, 1.0f);
  EXPECT_THROW(r.RenderGradient(rays, wrong, &dt, &dn), InputError);
  std::vector<double> short_dt(5), dn2;
  EXPECT_THROW(r.RenderGradient(rays, c, &short_dt, &dn2), InputError);
}

}  // namespace
}  // namespace flamerig
