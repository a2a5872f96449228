// Fire lighting a scene: energy against closed forms (a small thin fire is a point source of its
// total intensity: inverse square and cosine laws; an optically thick cube dims by
// (1 - exp(-kappa a)) / (kappa a)), closed shadows, Reinhard's formula, convergence with samples,
// determinism and stress.
#include <gtest/gtest.h>
#include <tbb/global_control.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "core/error.h"
#include "core/srgb.h"
#include "fitting/physics.h"
#include "fitting/scene.h"
#include "fitting/tonemap.h"
#include "tomography/vdb_io.h"
#include "tests/scene_util.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

// The luminance of a grey body's emission per metre per unit cross-section and density: the Planck
// radiance weighted by ybar over ybar's integral, by quadrature on colord-data's independent copy
// of CIE 1931 (5 nm).
double PlanckLuminance(double temperature_k) {
  std::ifstream cmf("/usr/share/colord/cmf/CIE1931-2deg-XYZ.cmf");
  EXPECT_TRUE(cmf) << "colord-data is missing";
  std::string line;
  while (std::getline(cmf, line) && line.rfind("BEGIN_DATA", 0) != 0) {
  }
  while (std::getline(cmf, line) && line.rfind("BEGIN_DATA", 0) != 0) {
  }
  std::getline(cmf, line);  // xbar
  std::getline(cmf, line);  // ybar
  std::istringstream in(line);
  double num = 0, den = 0, y;
  for (int i = 0; in >> y; ++i) {
    num += physics::PlanckRadiancePerNm(360.0 + 5 * i, temperature_k) * y;
    den += y;
  }
  return num / den;
}

TEST(Scene, ASmallThinFireIsAPointSourceOfItsTotalIntensity) {
  const AbsorptionModel grey = AbsorptionModel::DefaultGrey();
  const double sigma = grey.CrossSectionM2(550);
  const double t = 1800, a = 0.004, height = 0.5;
  const double density = 0.1 / sigma;  // kappa = 0.1 / m: tau across the cube 4e-4
  Scene scene = FloorScene();
  SceneFire fire;
  fire.volume = UniformCube(4, a, t, density);
  fire.absorption = grey;
  fire.translate = Eigen::Vector3d(-a / 2, height - a / 2, -a / 2);  // centred at (0, 0.5, 0)
  scene.fires.push_back(fire);
  const SceneRenderer renderer(scene);
  // Total intensity (luminance): j V = sigma n Y(B_T) a^3.
  const double intensity = sigma * density * PlanckLuminance(t) * a * a * a;
  EXPECT_NEAR(Luminance(renderer.light().intensity_rgb) / intensity, 1.0, 2e-3);
  for (double x : {0.0, 0.25, 0.5, 1.0, 2.0}) {
    const Eigen::Vector3d p(x, 0, 0);
    const double d2 = x * x + height * height, cosine = height / std::sqrt(d2);
    const double expected = intensity * cosine / d2;
    const Eigen::Vector3d e =
        renderer.Irradiance(p, Eigen::Vector3d::UnitY(), SceneLighting::kFireVolume, 4096, 3);
    EXPECT_NEAR(Luminance(e) / expected, 1.0, 5e-3) << "x = " << x;
    // The comparison point light has the same total intensity at the centroid.
    const Eigen::Vector3d point =
        renderer.Irradiance(p, Eigen::Vector3d::UnitY(), SceneLighting::kPointLight, 1, 3);
    EXPECT_NEAR(Luminance(point) / expected, 1.0, 1e-3) << "x = " << x;
  }
  // A surface facing away receives nothing.
  EXPECT_EQ(
      renderer.Irradiance({0, 0, 0}, -Eigen::Vector3d::UnitY(), SceneLighting::kFireVolume, 256, 1)
          .norm(),
      0.0);
}

TEST(Scene, AnOpticallyThickCubeDimsByItsOwnAbsorption) {
  // Seen from far along x, a uniform cube's columns each give j (1 - exp(-kappa a)) / kappa: the
  // intensity is the thin one times (1 - exp(-kappa a)) / (kappa a).
  const AbsorptionModel grey = AbsorptionModel::DefaultGrey();
  const double sigma = grey.CrossSectionM2(550), a = 0.01, t = 1500, far = 3.0;
  for (double kappa_a : {0.5, 1.0, 2.0}) {
    Scene scene;
    scene.camera.width = scene.camera.height = 8;
    SceneFire fire;
    fire.volume = UniformCube(32, a, t, kappa_a / a / sigma);
    fire.absorption = grey;
    fire.translate = Eigen::Vector3d(-a / 2, -a / 2, -a / 2);
    scene.fires.push_back(fire);
    const SceneRenderer renderer(scene);
    const double thin = Luminance(renderer.light().intensity_rgb) / (far * far);
    const Eigen::Vector3d e =
        renderer.Irradiance(Eigen::Vector3d(far, 0, 0), -Eigen::Vector3d::UnitX(),
                            SceneLighting::kFireVolume, 20000, 7);
    const double expected = (1 - std::exp(-kappa_a)) / kappa_a;
    // Trilinear density at the cube's faces and 1-voxel march steps: within 2%.
    EXPECT_NEAR(Luminance(e) / thin, expected, 0.02) << "kappa a = " << kappa_a;
  }
}

TEST(Scene, ASurfaceInAClosedShadowReceivesNothing) {
  Scene scene = FloorScene();
  scene.geometry.AddBox(Eigen::Vector3d(-0.1, -0.05, -0.1), Eigen::Vector3d(0.1, 0.1, 0.1), 0);
  SceneFire fire;
  fire.volume = UniformCube(8, 0.02, 1900, 1e16);
  fire.translate = Eigen::Vector3d(-0.01, 0.4, -0.01);
  scene.fires.push_back(fire);
  const SceneRenderer renderer(scene);
  for (SceneLighting l :
       {SceneLighting::kFireVolume, SceneLighting::kPointLight, SceneLighting::kSphereLight}) {
    EXPECT_EQ(renderer.Irradiance({0, 0, 0}, Eigen::Vector3d::UnitY(), l, 512, 1, 0.05).norm(), 0.0)
        << ToString(l);
    // Outside the box, the same point of the floor is lit.
    EXPECT_GT(Luminance(renderer.Irradiance({0.5, 0, 0}, Eigen::Vector3d::UnitY(), l, 64, 1)), 0)
        << ToString(l);
  }
}

TEST(Scene, ReinhardMatchesItsFormula) {
  // Two grey pixels of luminance 1 and 4 (and their colour).
  ImageF image(2, 1, 3, 0.0f);
  for (int c = 0; c < 3; ++c) {
    image.at(0, 0, c) = 1.0f;
    image.at(1, 0, c) = 4.0f;
  }
  ToneMapOptions o;
  o.key = 0.18;
  ToneMapSummary summary;
  const ImageU8 out = ToneMapReinhard(image, o, &summary);
  const double average = std::exp(0.5 * (std::log(1 + o.delta) + std::log(4 + o.delta)));
  EXPECT_NEAR(summary.log_average, average, 1e-9);
  const double l1 = 0.18 / average * 1, l4 = 0.18 / average * 4;
  EXPECT_NEAR(summary.white, l4, 1e-9);  // the brightest pixel is the white point
  const double d1 = l1 * (1 + l1 / (l4 * l4)) / (1 + l1);
  EXPECT_EQ(out.at(0, 0, 0), QuantizeU8(SrgbEncode(d1)));
  EXPECT_EQ(out.at(1, 0, 0), 255);  // L_d(L_white) = 1
  // A given white: L_d = L (1 + L / w^2) / (1 + L).
  EXPECT_NEAR(ReinhardDisplayLuminance(0.5, 2.0), 0.5 * (1 + 0.5 / 4) / 1.5, 1e-12);
  EXPECT_NEAR(ReinhardDisplayLuminance(3.0, 0), 0.75, 1e-12);  // no white: L / (1 + L)
  // Colour is kept: a red pixel stays red.
  ImageF red(1, 1, 3, 0.0f);
  red.at(0, 0, 0) = 2.0f;
  red.at(0, 0, 1) = 0.5f;
  const ImageU8 r = ToneMapReinhard(red, o);
  EXPECT_GT(r.at(0, 0, 0), r.at(0, 0, 1));
  EXPECT_EQ(r.at(0, 0, 2), 0);
  // Black and NaN pixels are black, never NaN.
  ImageF bad(2, 1, 3, 0.0f);
  bad.at(1, 0, 1) = std::nanf("");
  const ImageU8 b = ToneMapReinhard(bad, o);
  for (auto v : b.pixels) EXPECT_EQ(v, 0);
  o.key = 0;
  EXPECT_THROW(ToneMapReinhard(image, o), InputError);
}

double Rmse(const ImageF& a, const ImageF& b) {
  double s = 0;
  for (std::size_t i = 0; i < a.pixels.size(); ++i)
    s += (double(a.pixels[i]) - b.pixels[i]) * (double(a.pixels[i]) - b.pixels[i]);
  return std::sqrt(s / a.pixels.size());
}

TEST(Scene, ErrorFallsAsSamplesGrowAndImagesAreDeterministic) {
  const SceneRenderer renderer(LitScene(48, 32));
  SceneRenderOptions o;
  o.seed = 99;
  o.samples_per_pixel = 1024;
  o.samples_per_pass = 64;
  ImageF reference;
  renderer.Render(o, &reference);
  std::vector<double> errors;
  for (int spp : {4, 16, 64, 256}) {
    o.seed = 5;
    o.samples_per_pixel = spp;
    o.samples_per_pass = 4;
    ImageF image;
    renderer.Render(o, &image);
    errors.push_back(Rmse(image, reference));
  }
  // Monte Carlo: the error falls as the samples grow, about as 1 / sqrt(samples) (measured: 1.7e-4,
  // 4.3e-5, 2.1e-5, 2.0e-5); the reference's own noise at 1024 samples is the floor of the last.
  EXPECT_LT(errors[1], errors[0]);
  EXPECT_LT(errors[2], errors[1]);
  EXPECT_LT(errors[2], 0.35 * errors[0]);  // 16 times the samples: 1/4 in theory
  EXPECT_LT(errors[3], 1.05 * errors[2]);
  // The same seed gives the same image whatever the number of threads.
  o.samples_per_pixel = 8;
  ImageF two, one;
  renderer.Render(o, &two);
  {
    const tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 1);
    renderer.Render(o, &one);
  }
  EXPECT_TRUE(one.pixels == two.pixels);
}

TEST(Scene, StaysFiniteOverThePhysicalRange) {
  for (double t : {1.0, 300.0, 1e5}) {
    for (double n : {0.0, 1e10, 1e30}) {
      Scene scene = LitScene(24, 16);
      for (auto& v : scene.fires[0].volume.temperature_k) v = static_cast<float>(t);
      for (auto& v : scene.fires[0].volume.density_per_m3) v = static_cast<float>(n);
      const SceneRenderer renderer(scene);
      SceneRenderOptions o;
      o.samples_per_pixel = 4;
      ImageF image;
      renderer.Render(o, &image);
      // Finite everywhere (linear sRGB: deep-red fire light has a slightly negative blue, outside
      // the sRGB gamut, which display images clip).
      for (float v : image.pixels) ASSERT_TRUE(std::isfinite(v)) << t << " K, " << n;
    }
  }
  // The camera inside the fire, and a surface through the fire.
  Scene inside = LitScene(24, 16);
  inside.camera.position = Eigen::Vector3d(0, 0.005, 0);
  inside.camera.look_at = Eigen::Vector3d(0.1, 0.005, 0);
  inside.geometry.AddQuad(Eigen::Vector3d(0, 0.005, 0), Eigen::Vector3d::UnitZ(), {0.1, 0.1}, 0);
  ImageF image;
  SceneRenderer(inside).Render(SceneRenderOptions(), &image);
  for (float v : image.pixels) ASSERT_TRUE(std::isfinite(v));
  // Degenerate cameras and scenes are refused, naming the field.
  Scene bad = LitScene(8, 8);
  bad.camera.look_at = bad.camera.position;
  EXPECT_THROW(SceneRenderer{bad}, InputError);
  bad = LitScene(8, 8);
  bad.fires[0].scale = 0;
  EXPECT_THROW(SceneRenderer{bad}, InputError);
  bad = LitScene(8, 8);
  bad.geometry.triangle_material[0] = 7;
  EXPECT_THROW(SceneRenderer{bad}, InputError);
}

}  // namespace
}  // namespace flamerig
