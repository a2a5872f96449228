// The ray marcher against closed forms (homogeneous slab, optically thin limit), against itself at
// finer steps (convergence), between its paths (fast vs spectral, skipping vs not), and under
// stress.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "core/error.h"
#include "fitting/colour.h"
#include "fitting/physics.h"
#include "fitting/renderer.h"

namespace flamerig {
namespace {

// A pinhole camera on the +z axis looking at the origin (towards -z), y up in the rig.
CameraModel AxisCamera(double distance_m, int width = 41, int height = 31, double f = 60) {
  Rigid3 cam_from_rig = LookAt(Eigen::Vector3d(0, 0, distance_m), Eigen::Vector3d::Zero());
  return CameraModel::Pinhole(f, f, 0.5 * (width - 1), 0.5 * (height - 1), cam_from_rig, width,
                              height);
}

struct Uniform {
  GridGeometry grid;
  std::vector<float> temperature, density;
};

Uniform UniformVolume(const Box3& box, Eigen::Vector3i dims, float t, float n) {
  Uniform u;
  u.grid = GridGeometry::FromBoxAndDims(box, dims);
  u.temperature.assign(u.grid.num_voxels(), t);
  u.density.assign(u.grid.num_voxels(), n);
  return u;
}

Eigen::Vector3d Pixel(const ImageF& img, int x, int y) {
  return Eigen::Vector3d(img.at(x, y, 0), img.at(x, y, 1), img.at(x, y, 2));
}

// Closed form for a homogeneous slab: L = B(T) (1 - exp(-kappa * path)), per wavelength.
Eigen::Vector3d SlabRgb(const AbsorptionModel& absorption, double t, double n, double path_m) {
  Eigen::Vector3d xyz = colour::CieObserver::Cie1931TwoDegree().Integrate([&](double nm) {
    double kappa = absorption.CrossSectionM2(nm) * n;
    return physics::PlanckRadiancePerNm(nm, t) * -std::expm1(-kappa * path_m);
  });
  return colour::LinearSrgbFromXyz() * xyz;
}

class SlabTest : public ::testing::TestWithParam<std::tuple<bool, bool, double>> {};

TEST_P(SlabTest, MatchesClosedForm) {
  const auto [soot, use_double, step] = GetParam();
  // A thin slab, 2 cm thick along z, wide in x and y, uniform at 1900 K.
  Box3 box{Eigen::Vector3d(-0.5, -0.5, -0.01), Eigen::Vector3d(0.5, 0.5, 0.01)};
  AbsorptionModel absorption =
      soot ? AbsorptionModel::DefaultSoot() : AbsorptionModel::DefaultGrey();
  // Optical depth about 1 across the slab at 550 nm.
  const double n = 1.0 / (absorption.CrossSectionM2(550) * 0.02);
  Uniform u = UniformVolume(box, {8, 8, 5}, 1900.0f, static_cast<float>(n));
  RenderOptions options;
  options.double_precision = use_double;
  options.step_voxels = step;
  options.min_transmittance = 0;
  // The spectral path at 1 nm integrates exactly like the closed form.
  options.spectral_first_nm = 360;
  options.spectral_last_nm = 830;
  options.spectral_step_nm = 1;
  FireRenderer renderer(absorption, options);
  renderer.SetVolume(u.grid, u.temperature, u.density);
  CameraModel camera = AxisCamera(1.0);
  CameraRays rays(camera);
  ImageF image;
  RenderSummary summary = renderer.Render(rays, &image);
  EXPECT_EQ(summary.path_used, soot ? SpectralPath::kSpectral : SpectralPath::kFast);
  for (auto [x, y] : {std::pair{20, 15}, std::pair{0, 0}, std::pair{40, 30}, std::pair{5, 22}}) {
    // Independent path length: the ray through pixel (x, y) crosses the slab at angle theta to z.
    Eigen::Vector3d d((x - 20) / 60.0, (y - 15) / 60.0, 1.0);
    double path = 0.02 * d.norm() / d.z();
    Eigen::Vector3d expected = SlabRgb(absorption, 1900.0, n, path);
    Eigen::Vector3d got = Pixel(image, x, y);
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(got[c], expected[c], 2e-4 * expected.cwiseAbs().maxCoeff())
          << "pixel " << x << "," << y << " channel " << c;
    }
  }
}

INSTANTIATE_TEST_SUITE_P(PathsPrecisionsSteps, SlabTest,
                         ::testing::Combine(::testing::Bool(), ::testing::Bool(),
                                            ::testing::Values(0.25, 0.5, 2.0)));

// Rays through points inside the pixels (CameraRays with an offset), averaged by RenderPixelArea
// (what `simulate`'s pixel_samples uses): a pixel that a slab's sharp edge crosses gets the slab's light times the
// share of the pixel the slab covers. The slab's edge (the grid box's face, so not smeared by
// interpolation) projects to column 10.25 of the axis camera; 4 x 4 points a pixel at offsets
// -3/8, -1/8, 1/8, 3/8 put one of every four columns of points of pixel 10 inside, the pixel's area
// right of 10.25 is a quarter of it; one ray through the centre (10.0) sees nothing.
TEST(Renderer, RaysInsideThePixelAverageToItsCoveredShare) {
  const double x_edge = (10.25 - 20.0) / 60.0;  // pixel column 10.25 at the camera's distance, 1 m
  Box3 box{Eigen::Vector3d(x_edge, -0.5, -0.0005), Eigen::Vector3d(0.5, 0.5, 0.0005)};
  Uniform u = UniformVolume(box, {16, 16, 2}, 1800.0f, 1e17f);
  FireRenderer renderer(AbsorptionModel::DefaultGrey(), RenderOptions());
  renderer.SetVolume(u.grid, u.temperature, u.density);
  const CameraModel camera = AxisCamera(1.0);
  ImageF centre, sum;
  renderer.Render(CameraRays(camera), &centre);
  renderer.RenderPixelArea(camera, 4, &sum);
  const double inside = Pixel(centre, 11, 15).norm();
  ASSERT_GT(inside, 0);
  EXPECT_EQ(Pixel(centre, 10, 15).norm(), 0.0);  // its centre lies outside the slab
  EXPECT_EQ(Pixel(sum, 9, 15).norm(), 0.0);      // wholly outside
  EXPECT_NEAR(Pixel(sum, 10, 15).norm() / inside, 0.25, 0.01);
  EXPECT_NEAR(Pixel(sum, 11, 15).norm() / inside, 1.0, 0.01);  // wholly inside
  // The offset moves the ray as the lens model says: through pixel (x + 0.3, y - 0.2).
  const CameraRays moved(camera, Eigen::Vector2d(0.3, -0.2));
  const Ray expected = camera.Unproject(Eigen::Vector2d(7.3, 4.8));
  EXPECT_NEAR((moved.at(7, 5).direction_in_rig - expected.direction_in_rig).norm(), 0.0, 1e-12);
}

TEST(Renderer, OpticallyThickSlabApproachesBlackbody) {
  Box3 box{Eigen::Vector3d(-0.5, -0.5, -0.01), Eigen::Vector3d(0.5, 0.5, 0.01)};
  AbsorptionModel grey = AbsorptionModel::DefaultGrey();
  Uniform u =
      UniformVolume(box, {4, 4, 4}, 1600.0f, static_cast<float>(1e6 / grey.CrossSectionM2(550)));
  FireRenderer renderer(grey);
  renderer.SetVolume(u.grid, u.temperature, u.density);
  CameraRays rays(AxisCamera(1.0));
  ImageF image;
  RenderSummary summary = renderer.Render(rays, &image);
  Eigen::Vector3d expected = colour::LinearSrgbFromXyz() * colour::BlackbodyXyz(1600.0);
  Eigen::Vector3d got = Pixel(image, 20, 15);
  for (int c = 0; c < 3; ++c)
    EXPECT_NEAR(got[c], expected[c], 1e-4 * expected.cwiseAbs().maxCoeff());
  EXPECT_EQ(summary.rays_terminated_early,
            summary.rays_hit_box);  // every ray stopped after one step
}

TEST(Renderer, OpticallyThinLimitIsLinearInDensity) {
  Box3 box{Eigen::Vector3d(-0.05, -0.05, -0.05), Eigen::Vector3d(0.05, 0.05, 0.05)};
  for (bool soot : {false, true}) {
    AbsorptionModel absorption =
        soot ? AbsorptionModel::DefaultSoot() : AbsorptionModel::DefaultGrey();
    // Optical depth about 1e-5 across the box.
    double n = 1e-4 / absorption.CrossSectionM2(550);
    ImageF a, b;
    for (double scale : {1.0, 2.0}) {
      Uniform u = UniformVolume(box, {6, 6, 6}, 2000.0f, static_cast<float>(n * scale));
      FireRenderer renderer(absorption);
      renderer.SetVolume(u.grid, u.temperature, u.density);
      renderer.Render(CameraRays(AxisCamera(0.5)), scale == 1.0 ? &a : &b);
    }
    const double r0 = a.at(20, 15, 0);
    ASSERT_GT(r0, 0);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(b.at(20, 15, c) / a.at(20, 15, c), 2.0, 1e-4);
  }
}

// A smooth Gaussian fire used by the convergence and consistency tests.
Uniform SmoothFire(int n, double peak_tau_per_m) {
  Box3 box{Eigen::Vector3d(-0.05, -0.05, -0.05), Eigen::Vector3d(0.05, 0.05, 0.05)};
  Uniform u = UniformVolume(box, {n, n, n}, 300.0f, 0.0f);
  AbsorptionModel grey = AbsorptionModel::DefaultGrey();
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        Eigen::Vector3d p = u.grid.VoxelCenter(i, j, k);
        double r2 = (p - Eigen::Vector3d(0.005, -0.003, 0.002)).squaredNorm() / (0.025 * 0.025);
        double g = std::exp(-r2);
        std::size_t f = u.grid.Flat(i, j, k);
        u.temperature[f] = static_cast<float>(300 + 1800 * g);
        u.density[f] =
            r2 < 2.25 ? static_cast<float>(peak_tau_per_m / grey.CrossSectionM2(550) * g) : 0.0f;
      }
  return u;
}

TEST(Renderer, ConvergesAsStepShrinks) {
  Uniform u = SmoothFire(24, 40.0);
  AbsorptionModel grey = AbsorptionModel::DefaultGrey();
  CameraRays rays(AxisCamera(0.4, 61, 61, 300));
  auto render = [&](double step) {
    RenderOptions o;
    o.step_voxels = step;
    o.double_precision = true;
    o.min_transmittance = 0;
    FireRenderer r(grey, o);
    r.SetVolume(u.grid, u.temperature, u.density);
    ImageF img;
    r.Render(rays, &img);
    return img;
  };
  ImageF reference = render(1.0 / 64);
  auto error = [&](const ImageF& img) {
    double e = 0;
    for (std::size_t i = 0; i < img.pixels.size(); ++i)
      e += std::abs(img.pixels[i] - reference.pixels[i]);
    return e;
  };
  double previous = INFINITY;
  std::vector<double> errors;
  // From one voxel down (coarser steps alias with the lattice and their error is erratic).
  for (double step : {1.0, 0.5, 0.25, 0.125}) {
    double e = error(render(step));
    errors.push_back(e);
    EXPECT_LT(e, previous) << "step " << step;
    previous = e;
  }
  // Midpoint sampling of a smooth field: the error falls by about 4 per halving; ask for at
  // least 2.5.
  for (std::size_t i = 1; i < errors.size(); ++i) EXPECT_GT(errors[i - 1] / errors[i], 2.5) << i;
}

TEST(Renderer, FastAndSpectralPathsAgreeForGreyMedia) {
  Uniform u = SmoothFire(32, 60.0);
  AbsorptionModel grey = AbsorptionModel::DefaultGrey();
  CameraRays rays(AxisCamera(0.4, 81, 61, 300));
  RenderOptions fast_options, spectral_options;
  spectral_options.path = SpectralPath::kSpectral;
  spectral_options.spectral_step_nm = 5;
  FireRenderer fast(grey, fast_options), spectral(grey, spectral_options);
  fast.SetVolume(u.grid, u.temperature, u.density);
  spectral.SetVolume(u.grid, u.temperature, u.density);
  ImageF a, b;
  EXPECT_EQ(fast.Render(rays, &a).path_used, SpectralPath::kFast);
  EXPECT_EQ(spectral.Render(rays, &b).path_used, SpectralPath::kSpectral);
  double peak = 0;
  for (float v : a.pixels) peak = std::max(peak, double(v));
  ASSERT_GT(peak, 0);
  for (std::size_t i = 0; i < a.pixels.size(); ++i)
    ASSERT_NEAR(a.pixels[i], b.pixels[i], 2e-3 * peak) << i;
}

TEST(Renderer, EmptySpaceSkippingIsExact) {
  Uniform u = SmoothFire(48, 80.0);
  for (bool soot : {false, true}) {
    AbsorptionModel absorption =
        soot ? AbsorptionModel::DefaultSoot() : AbsorptionModel::DefaultGrey();
    CameraRays rays(AxisCamera(0.3, 81, 61, 250));
    RenderOptions with, without;
    without.skip_empty_space = false;
    FireRenderer a(absorption, with), b(absorption, without);
    a.SetVolume(u.grid, u.temperature, u.density);
    b.SetVolume(u.grid, u.temperature, u.density);
    ImageF ia, ib;
    RenderSummary sa = a.Render(rays, &ia), sb = b.Render(rays, &ib);
    EXPECT_GT(sa.steps_skipped_empty, 0);
    EXPECT_EQ(sb.steps_skipped_empty, 0);
    EXPECT_LT(sa.steps_evaluated, sb.steps_evaluated);
    EXPECT_EQ(ia.pixels, ib.pixels);  // bit-identical
  }
}

// The bricks a ray crosses are walked by a DDA (renderer.cc, MarchRay): a brick it missed or took
// out of turn would drop or add samples. Oblique and grazing rays, rays from inside the box, a
// grid whose sides are not whole bricks, steps that do not divide a brick or are longer than a
// voxel, and two media: small separate blobs (most bricks empty), and a checkerboard of bricks
// whose medium stays a voxel clear of their faces, so that the neighbours across every face are
// unoccupied even after their one-voxel dilation (a sample put in the wrong brick is dropped, not
// saved by the dilation). Every image and gradient must equal the march that evaluates every step.
TEST(Renderer, EmptySpaceSkippingIsExactAlongObliqueRays) {
  Box3 box{Eigen::Vector3d(-0.05, -0.04, -0.06), Eigen::Vector3d(0.05, 0.04, 0.06)};
  const Eigen::Vector3i dims(37, 29, 45);  // 4 x 8 + 5, 3 x 8 + 5, 5 x 8 + 5: partial last bricks
  const double n0 = 60.0 / AbsorptionModel::DefaultGrey().CrossSectionM2(550);
  Uniform blobs = UniformVolume(box, dims, 300.0f, 0.0f);
  Uniform checkerboard = blobs;
  const Eigen::Vector3d centres[5] = {
      Eigen::Vector3d(0.03, 0.02, -0.04), Eigen::Vector3d(-0.035, -0.025, 0.01),
      Eigen::Vector3d(0.0, 0.0, 0.045), Eigen::Vector3d(0.046, 0.036, 0.0),
      Eigen::Vector3d(0.046, -0.02, 0.056)};
  for (int k = 0; k < dims.z(); ++k)
    for (int j = 0; j < dims.y(); ++j)
      for (int i = 0; i < dims.x(); ++i) {
        const std::size_t f = blobs.grid.Flat(i, j, k);
        const Eigen::Vector3d p = blobs.grid.VoxelCenter(i, j, k);
        for (const Eigen::Vector3d& c : centres) {
          if ((p - c).norm() < 0.008) {
            blobs.temperature[f] = 1900.0f;
            blobs.density[f] = static_cast<float>(n0);
          }
        }
        const bool even_brick = (i / 8 + j / 8 + k / 8) % 2 == 0;
        const bool inner =
            i % 8 >= 1 && i % 8 <= 6 && j % 8 >= 1 && j % 8 <= 6 && k % 8 >= 1 && k % 8 <= 6;
        if (even_brick && inner) {
          checkerboard.temperature[f] = 1700.0f;
          checkerboard.density[f] = static_cast<float>(0.2 * n0);
        }
      }
  struct View {
    Eigen::Vector3d eye, target;
  };
  const View views[] = {
      {Eigen::Vector3d(0.21, 0.13, 0.17), Eigen::Vector3d(0, 0, 0)},  // oblique
      {Eigen::Vector3d(-0.23, -0.17, -0.19),
       Eigen::Vector3d(0.02, 0.01, 0.03)},  // out by the far faces
      {Eigen::Vector3d(-0.3, 0.0401, 0.0), Eigen::Vector3d(0.0, 0.0401, 0.0)},  // grazing a face
      {Eigen::Vector3d(0.001, -0.002, 0.003), Eigen::Vector3d(1, 0.7, -0.4)},   // from inside
  };
  for (const Uniform* u : {&blobs, &checkerboard})
    for (bool soot : {false, true}) {
      AbsorptionModel absorption =
          soot ? AbsorptionModel::DefaultSoot() : AbsorptionModel::DefaultGrey();
      // Steps longer than a voxel (RenderOptions allows up to 4) shift a short last step's midpoint
      // by more than the bricks' one-voxel dilation covers.
      for (double step : {0.5, 1.0, 0.37, 2.0, 3.3, 4.0}) {
        RenderOptions with, without;
        with.step_voxels = without.step_voxels = step;
        without.skip_empty_space = false;
        FireRenderer a(absorption, with), b(absorption, without);
        a.SetVolume(u->grid, u->temperature, u->density);
        b.SetVolume(u->grid, u->temperature, u->density);
        for (const View& view : views) {
          CameraRays rays(
              CameraModel::Pinhole(70, 70, 40, 30, LookAt(view.eye, view.target), 81, 61));
          ImageF ia, ib;
          RenderSummary sa = a.Render(rays, &ia), sb = b.Render(rays, &ib);
          EXPECT_GT(sa.steps_skipped_empty, 0);
          EXPECT_LT(sa.steps_evaluated, sb.steps_evaluated);
          EXPECT_EQ(sa.steps_evaluated + sa.steps_skipped_empty + sa.steps_after_termination,
                    sb.steps_evaluated + sb.steps_after_termination)
              << "every step is either evaluated or skipped";
          double peak = 0;
          for (float v : ib.pixels) peak = std::max(peak, double(v));
          EXPECT_GT(peak, 0) << "the view sees the blobs";
          EXPECT_EQ(ia.pixels, ib.pixels) << (u == &blobs ? "blobs, " : "checkerboard, ")
                                          << (soot ? "soot" : "grey") << ", step " << step;
          ImageF ones(ia.width, ia.height, 3, 1.0f);
          std::vector<double> dta, dna, dtb, dnb;
          a.RenderGradient(rays, ones, &dta, &dna);
          b.RenderGradient(rays, ones, &dtb, &dnb);
          // The gradients are summed in float per thread, in an order that varies from run to run:
          // equal to float rounding, and zero where the other is.
          ASSERT_EQ(dta.size(), dtb.size());
          double t_scale = 0, n_scale = 0;
          for (std::size_t v = 0; v < dtb.size(); ++v) {
            t_scale = std::max(t_scale, std::abs(dtb[v]));
            n_scale = std::max(n_scale, std::abs(dnb[v]));
          }
          EXPECT_GT(t_scale, 0);
          for (std::size_t v = 0; v < dtb.size(); ++v) {
            ASSERT_NEAR(dta[v], dtb[v], 1e-6 * t_scale) << v;
            ASSERT_NEAR(dna[v], dnb[v], 1e-6 * n_scale) << v;
            ASSERT_EQ(dta[v] == 0, dtb[v] == 0) << v;
          }
        }
      }
    }
}

TEST(Renderer, EarlyTerminationErrorIsBounded) {
  Uniform u = SmoothFire(24, 2000.0);  // optically thick core
  AbsorptionModel grey = AbsorptionModel::DefaultGrey();
  CameraRays rays(AxisCamera(0.3, 41, 41, 150));
  RenderOptions stop, full;
  stop.min_transmittance = 1e-3;
  full.min_transmittance = 0;
  full.double_precision = stop.double_precision = true;
  FireRenderer a(grey, stop), b(grey, full);
  a.SetVolume(u.grid, u.temperature, u.density);
  b.SetVolume(u.grid, u.temperature, u.density);
  ImageF ia, ib;
  RenderSummary sa = a.Render(rays, &ia);
  b.Render(rays, &ib);
  EXPECT_GT(sa.rays_terminated_early, 0);
  // What is cut is at most min_transmittance times the brightest black body on the ray.
  Eigen::Vector3d hottest = (colour::LinearSrgbFromXyz() * colour::BlackbodyXyz(2100)).cwiseAbs();
  for (std::size_t i = 0; i < ia.pixels.size(); ++i) {
    EXPECT_LE(std::abs(ia.pixels[i] - ib.pixels[i]), 1e-3 * hottest.maxCoeff() + 1e-9) << i;
  }
}

TEST(Renderer, RaysThatMissOrGrazeAndCamerasInsideTheBox) {
  Box3 box{Eigen::Vector3d(-0.05, -0.05, -0.05), Eigen::Vector3d(0.05, 0.05, 0.05)};
  Uniform u = UniformVolume(box, {8, 8, 8}, 2000.0f, 1e15f);
  FireRenderer renderer(AbsorptionModel::DefaultGrey());
  renderer.SetVolume(u.grid, u.temperature, u.density);
  // Looking away from the box: nothing.
  Rigid3 away = LookAt(Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(0, 0, 2));
  ImageF img;
  RenderSummary s =
      renderer.Render(CameraRays(CameraModel::Pinhole(50, 50, 20, 15, away, 41, 31)), &img);
  EXPECT_EQ(s.rays_hit_box, 0);
  for (float v : img.pixels) EXPECT_EQ(v, 0.0f);
  // Grazing: a camera in the plane of the box's top face, looking along it.
  Rigid3 graze = LookAt(Eigen::Vector3d(0, 0.05, 1), Eigen::Vector3d(0, 0.05, 0));
  renderer.Render(CameraRays(CameraModel::Pinhole(50, 50, 20, 15, graze, 41, 31)), &img);
  for (float v : img.pixels) ASSERT_TRUE(std::isfinite(v));
  // Inside the box, at its centre: every ray sees the medium from its origin outwards.
  Rigid3 inside = LookAt(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0, 0, -1));
  s = renderer.Render(CameraRays(CameraModel::Pinhole(20, 20, 20, 15, inside, 41, 31)), &img);
  EXPECT_EQ(s.rays_hit_box, 41 * 31);
  for (float v : img.pixels) ASSERT_TRUE(std::isfinite(v));
  EXPECT_GT(img.at(20, 15, 0), 0.0f);
}

// Stress: extreme temperatures, densities and exposures; float and double; no NaN or Inf anywhere.
TEST(Renderer, StressNoNanOrInf) {
  Box3 box{Eigen::Vector3d(-0.05, -0.05, -0.05), Eigen::Vector3d(0.05, 0.05, 0.05)};
  GridGeometry grid = GridGeometry::FromBoxAndDims(box, {10, 10, 10});
  std::mt19937 rng(3);
  const std::vector<double> temperatures = {0, 1, 10, 300, 1300, 2300, 5000, 2e4, 5e4, 1e5};
  const std::vector<double> densities = {0, 1, 1e10, 1e15, 1e18, 1e24, 1e27, 5e29, 1e35, 3e38};
  for (bool soot : {false, true}) {
    AbsorptionModel absorption =
        soot ? AbsorptionModel::DefaultSoot() : AbsorptionModel::DefaultGrey();
    for (bool use_double : {false, true}) {
      std::vector<float> t(grid.num_voxels()), n(grid.num_voxels());
      std::uniform_int_distribution<int> pick(0, 9);
      for (std::size_t i = 0; i < t.size(); ++i) {
        t[i] = static_cast<float>(temperatures[pick(rng)]);
        n[i] = static_cast<float>(densities[pick(rng)]);
      }
      RenderOptions o;
      o.double_precision = use_double;
      FireRenderer renderer(absorption, o);
      renderer.SetVolume(grid, t, n);
      ImageF img;
      const CameraModel inside = CameraModel::Pinhole(
          20, 20, 20, 15, LookAt(Eigen::Vector3d(0.01, 0, 0), Eigen::Vector3d(0, 0, -1)), 41, 31);
      for (const CameraModel& cam :
           {AxisCamera(0.3), AxisCamera(0.051), inside, AxisCamera(1e4, 41, 31, 1e6)}) {
        renderer.Render(CameraRays(cam), &img);
        for (float v : img.pixels)
          ASSERT_TRUE(std::isfinite(v)) << "soot " << soot << " double " << use_double;
        for (double exposure : {0.01, 1.0, 1000.0}) {
          ImageU8 out = ApplyCameraResponse(img, exposure);
          ASSERT_EQ(out.pixels.size(), img.pixels.size());
        }
      }
      // Uniform extremes.
      for (double tt : {1.0, 1e5}) {
        for (double nn : {1e-3, 3e38}) {
          std::vector<float> tu(grid.num_voxels(), float(tt)), nu(grid.num_voxels(), float(nn));
          renderer.SetVolume(grid, tu, nu);
          renderer.Render(CameraRays(AxisCamera(0.3)), &img);
          for (float v : img.pixels)
            ASSERT_TRUE(std::isfinite(v) && v > -1e30f) << tt << " K " << nn;
        }
      }
    }
  }
}

TEST(Renderer, DegenerateGridsAndBadInput) {
  FireRenderer renderer(AbsorptionModel::DefaultGrey());
  ImageF img;
  EXPECT_THROW(renderer.Render(CameraRays(AxisCamera(1)), &img), std::logic_error);
  // A grid of one voxel.
  Box3 box{Eigen::Vector3d(-0.05, -0.05, -0.05), Eigen::Vector3d(0.05, 0.05, 0.05)};
  Uniform one = UniformVolume(box, {1, 1, 1}, 2000.0f, 1e16f);
  renderer.SetVolume(one.grid, one.temperature, one.density);
  renderer.Render(CameraRays(AxisCamera(0.5)), &img);
  for (float v : img.pixels) ASSERT_TRUE(std::isfinite(v));
  EXPECT_GT(img.at(20, 15, 0), 0.0f);
  // NaN, negative and mis-sized input are rejected with the voxel named.
  Uniform bad = UniformVolume(box, {4, 4, 4}, 2000.0f, 1e16f);
  bad.temperature[bad.grid.Flat(1, 2, 3)] = std::nanf("");
  try {
    renderer.SetVolume(bad.grid, bad.temperature, bad.density);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("(1, 2, 3)"), std::string::npos) << e.what();
  }
  bad.temperature[bad.grid.Flat(1, 2, 3)] = 2000;
  bad.density[0] = -1;
  EXPECT_THROW(renderer.SetVolume(bad.grid, bad.temperature, bad.density), InputError);
  bad.density.pop_back();
  EXPECT_THROW(renderer.SetVolume(bad.grid, bad.temperature, bad.density), InputError);
  // Options.
  RenderOptions o;
  o.step_voxels = 0;
  EXPECT_THROW(FireRenderer(AbsorptionModel::DefaultGrey(), o), InputError);
  o.step_voxels = 1e-9;  // a billion samples per voxel: hours, not more exact
  EXPECT_THROW(FireRenderer(AbsorptionModel::DefaultGrey(), o), InputError);
  o = RenderOptions();
  o.path = SpectralPath::kFast;
  EXPECT_THROW(FireRenderer(AbsorptionModel::DefaultSoot(), o), InputError);
  EXPECT_THROW(ApplyCameraResponse(img, 0.0), InputError);
  EXPECT_THROW(ApplyCameraResponse(img, std::nan("")), InputError);
  // Spectral bins beyond z-bar's end (650 nm): blue transmittance would be 0 / 0.
  o = RenderOptions();
  o.spectral_first_nm = 660;
  EXPECT_THROW(FireRenderer(AbsorptionModel::DefaultSoot(), o), InputError);
  // Explicit rays: a valid ray with a zero or NaN direction would march without end.
  std::vector<Ray> rays(4);
  for (Ray& r : rays) r.valid = true;
  EXPECT_NO_THROW(CameraRays(2, 2, rays));
  rays[3].direction_in_rig = Eigen::Vector3d::Zero();
  try {
    CameraRays(2, 2, rays);
    ADD_FAILURE() << "a zero direction accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("(1, 1)"), std::string::npos) << e.what();
  }
  rays[3].direction_in_rig = Eigen::Vector3d(0, std::nan(""), 1);
  EXPECT_THROW(CameraRays(2, 2, rays), InputError);
  rays[3].valid = false;  // an invalid ray carries no light: its direction does not matter
  EXPECT_NO_THROW(CameraRays(2, 2, rays));
}

TEST(CameraResponse, ExposureAndSaturation) {
  ImageF img(3, 1, 3, 0.0f);
  img.at(0, 0, 0) = 0.5f;
  img.at(1, 0, 1) = 0.25f;
  img.at(2, 0, 2) = -0.1f;
  ImageU8 out = ApplyCameraResponse(img, 2.0);
  EXPECT_EQ(out.at(0, 0, 0), 255);  // 1.0 -> full scale
  EXPECT_EQ(out.at(1, 0, 1), colour::QuantizeU8(colour::SrgbEncode(0.5)));
  EXPECT_EQ(out.at(2, 0, 2), 0);  // out of gamut clamps to 0
  EXPECT_EQ(ApplyCameraResponse(img, 1000.0).at(1, 0, 1), 255);
}

}  // namespace
}  // namespace flamerig
