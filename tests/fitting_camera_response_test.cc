// A camera's spectral response in the renderer (fitting/camera_response.h): narrow-band cameras
// read Planck's law directly (the oracle: physics's closed form at the band centre), gains scale
// channels, a mono camera fills three equal channels, the default is the sRGB observer exactly, and
// the renderer's two paths agree for a camera that is not the observer.
#include "fitting/camera_response.h"

#include <gtest/gtest.h>

#include <cmath>

#include "core/error.h"
#include "fitting/colour.h"
#include "fitting/physics.h"
#include "fitting/renderer.h"

namespace flamerig {
namespace {

CameraRadiometry Bands(std::vector<SpectralBand> bands,
                       Eigen::Vector3d gain = Eigen::Vector3d::Ones()) {
  CameraRadiometry r;
  r.spectral.kind = SpectralSensitivity::Kind::kBands;
  r.spectral.bands = std::move(bands);
  r.gain = gain;
  return r;
}

// The closed form: Planck's radiance per nm (physics.h is the formula, written from the constants).
double Planck(double nm, double t) {
  const double h = 6.62607015e-34, c = 299792458.0, k = 1.380649e-23;
  const double l = nm * 1e-9;
  return 2 * h * c * c / std::pow(l, 5) / (std::exp(h * c / (l * k * t)) - 1) * 1e-9;
}

TEST(ChannelResponse, TheDefaultCameraIsTheSrgbObserver) {
  const auto r = ChannelResponse::ForCamera(CameraRadiometry());
  EXPECT_EQ(r, ChannelResponse::SrgbObserver());
  EXPECT_TRUE(r->basis_is_xyz());
  const Eigen::Vector3d expected = colour::LinearSrgbFromXyz() * colour::BlackbodyXyz(1800);
  EXPECT_LT((r->Blackbody(1800) - expected).norm(), 1e-12 * expected.norm());
}

TEST(ChannelResponse, NarrowBandCamerasReadPlancksLaw) {
  const auto r = ChannelResponse::ForCamera(Bands({{650, 0.5}, {550, 0.5}, {450, 0.5}}));
  EXPECT_FALSE(r->basis_is_xyz());
  EXPECT_EQ(r->channels(), 3);
  for (double t : {900.0, 1300.5, 1900.25, 2600.0, 5000.0, 25000.0}) {
    SCOPED_TRACE(t);
    const Eigen::Vector3d exact = r->Blackbody(t);
    double table[3];
    r->Lookup(t, table);
    const double centres[3] = {650, 550, 450};
    for (int c = 0; c < 3; ++c) {
      // Equal bands are each scaled to integrate to Ybar: a channel is the band's mean radiance,
      // and a band 0.5 nm wide sampled at 1 nm is the radiance at its centre.
      EXPECT_NEAR(exact[c], Planck(centres[c], t), 2e-4 * Planck(centres[c], t));
      EXPECT_NEAR(table[c], exact[c], 3e-4 * exact[c]);
    }
  }
  // The derivative of the table is the slope of its segment; against the closed form's.
  double v[3], d[3];
  r->LookupWithDerivative(1500.5, v, d);
  const double fd = Planck(650, 1501) - Planck(650, 1500);
  EXPECT_NEAR(d[0], fd, 1e-3 * fd);
}

TEST(ChannelResponse, GainsScaleChannelsAndMonoFillsThree) {
  const auto unit = ChannelResponse::ForCamera(Bands({{620, 80}, {540, 80}, {460, 80}}));
  const auto gained = ChannelResponse::ForCamera(
      Bands({{620, 80}, {540, 80}, {460, 80}}, Eigen::Vector3d(2, 1, 0.5)));
  EXPECT_NE(unit, gained);
  EXPECT_EQ(unit, ChannelResponse::ForCamera(Bands({{620, 80}, {540, 80}, {460, 80}})));  // shared
  const Eigen::Vector3d a = unit->Blackbody(1700), b = gained->Blackbody(1700);
  EXPECT_NEAR(b[0], 2 * a[0], 1e-12 * a[0]);
  EXPECT_NEAR(b[1], a[1], 1e-12 * a[1]);
  EXPECT_NEAR(b[2], 0.5 * a[2], 1e-12 * a[2]);

  CameraRadiometry mono = Bands({{600, 200}});
  mono.spectral.filter = SpectralBand{650, 10};
  const auto m = ChannelResponse::ForCamera(mono);
  EXPECT_EQ(m->channels(), 1);
  const Eigen::Vector3d g = m->Blackbody(1700);
  EXPECT_EQ(g[0], g[1]);
  EXPECT_EQ(g[0], g[2]);
  // Behind a 10 nm filter the mono camera sees about B(650 nm): its ratio between two temperatures
  // is Planck's at 650 nm.
  EXPECT_NEAR(m->Blackbody(2000)[0] / m->Blackbody(1500)[0], Planck(650, 2000) / Planck(650, 1500),
              0.01 * Planck(650, 2000) / Planck(650, 1500));

  // The sRGB observer with gains: the gains scale linear sRGB.
  CameraRadiometry balanced;
  balanced.gain = Eigen::Vector3d(1.2, 1, 0.8);
  const auto w = ChannelResponse::ForCamera(balanced);
  EXPECT_TRUE(w->basis_is_xyz());
  const Eigen::Vector3d s = ChannelResponse::SrgbObserver()->Blackbody(1700);
  EXPECT_NEAR(w->Blackbody(1700)[2], 0.8 * s[2], 1e-12 * std::abs(s[2]));
}

CameraModel AxisCamera(double distance_m, int width, int height, double f) {
  Rigid3 cam_from_rig = LookAt(Eigen::Vector3d(0, 0, distance_m), Eigen::Vector3d::Zero());
  return CameraModel::Pinhole(f, f, 0.5 * (width - 1), 0.5 * (height - 1), cam_from_rig, width,
                              height);
}

TEST(ChannelResponse, AThickSlabSeenByANarrowBandCameraIsPlancksLaw) {
  const Box3 box{Eigen::Vector3d(-0.5, -0.5, -0.01), Eigen::Vector3d(0.5, 0.5, 0.01)};
  const AbsorptionModel grey = AbsorptionModel::DefaultGrey();
  const GridGeometry grid = GridGeometry::FromBoxAndDims(box, Eigen::Vector3i(4, 4, 4));
  const std::vector<float> t(grid.num_voxels(), 1600.0f),
      n(grid.num_voxels(), static_cast<float>(1e6 / grey.CrossSectionM2(550)));
  RenderOptions options;
  options.response = ChannelResponse::ForCamera(Bands({{700, 2}, {600, 2}, {500, 2}}));
  FireRenderer renderer(grey, options);
  renderer.SetVolume(grid, t, n);
  ImageF image;
  renderer.Render(CameraRays(AxisCamera(1.0, 41, 31, 60)), &image);
  const double centres[3] = {700, 600, 500};
  for (int c = 0; c < 3; ++c)
    EXPECT_NEAR(image.at(20, 15, c), Planck(centres[c], 1600), 1e-3 * Planck(centres[c], 1600));
}

// Soot's absorption depends on wavelength, so it takes the spectral path: a thick soot slab seen by
// near-infrared mono cameras (850 and 1050 nm, the long band of a two-colour pyrometer) is
// Planck's law at their wavelengths, from bins put where each camera responds (the observer's
// 380..780 nm rendered an 850 nm camera nearly black). A 650/40 nm camera needs 17 bins.
TEST(ChannelResponse, NearInfraredCamerasSeeSootAtTheirOwnWavelengths) {
  const Box3 box{Eigen::Vector3d(-0.5, -0.5, -0.01), Eigen::Vector3d(0.5, 0.5, 0.01)};
  const AbsorptionModel soot = AbsorptionModel::DefaultSoot();
  const GridGeometry grid = GridGeometry::FromBoxAndDims(box, Eigen::Vector3i(4, 4, 4));
  const std::vector<float> t(grid.num_voxels(), 1600.0f),
      n(grid.num_voxels(), static_cast<float>(1e6 / soot.CrossSectionM2(1100)));
  for (double centre : {850.0, 1050.0}) {
    SCOPED_TRACE(centre);
    RenderOptions options;
    options.response = ChannelResponse::ForCamera(Bands({{centre, 2}}));
    EXPECT_LE(options.response->support_first_nm(), centre - 2);
    EXPECT_GE(options.response->support_last_nm(), centre + 2);
    EXPECT_LT(options.response->support_last_nm() - options.response->support_first_nm(), 20);
    FireRenderer renderer(soot, options);
    renderer.SetVolume(grid, t, n);
    ImageF image;
    const RenderSummary summary = renderer.Render(CameraRays(AxisCamera(1.0, 41, 31, 60)), &image);
    EXPECT_EQ(summary.path_used, SpectralPath::kSpectral);
    EXPECT_LE(summary.spectral_bins, 2);
    for (int c = 0; c < 3; ++c)
      EXPECT_NEAR(image.at(20, 15, c), Planck(centre, 1600), 2e-3 * Planck(centre, 1600));
  }
  RenderOptions red;
  red.response = ChannelResponse::ForCamera(Bands({{650, 40}}));
  FireRenderer renderer(soot, red);
  renderer.SetVolume(grid, t, n);
  ImageF image;
  EXPECT_EQ(renderer.Render(CameraRays(AxisCamera(1.0, 9, 9, 12)), &image).spectral_bins, 17);
}

TEST(ChannelResponse, FastAndSpectralPathsAgreeForACamera) {
  const Box3 box{Eigen::Vector3d(-0.02, -0.02, -0.02), Eigen::Vector3d(0.02, 0.02, 0.02)};
  const AbsorptionModel grey = AbsorptionModel::DefaultGrey();
  const GridGeometry grid = GridGeometry::FromBoxAndDims(box, Eigen::Vector3i(16, 16, 16));
  std::vector<float> t(grid.num_voxels()), n(grid.num_voxels());
  for (int k = 0; k < 16; ++k)
    for (int j = 0; j < 16; ++j)
      for (int i = 0; i < 16; ++i) {
        const double r2 = (std::pow(i - 7.5, 2) + std::pow(j - 7.5, 2) + std::pow(k - 7.5, 2)) / 49;
        t[grid.Flat(i, j, k)] = static_cast<float>(1300 + 700 * std::exp(-r2));
        n[grid.Flat(i, j, k)] =
            r2 < 1 ? static_cast<float>(60 * (1 - r2) / grey.CrossSectionM2(550)) : 0.0f;
      }
  // A colour camera, and a mono camera in the near infrared behind a filter (whose light the
  // observer's 380..780 nm bins missed).
  for (const CameraRadiometry& camera :
       {Bands({{610, 60}, {530, 60}, {460, 60}}), Bands({{850, 40}})}) {
    RenderOptions fast_options, spectral_options;
    fast_options.response = ChannelResponse::ForCamera(camera);
    SCOPED_TRACE(fast_options.response->name());
    spectral_options = fast_options;
    spectral_options.path = SpectralPath::kSpectral;
    spectral_options.spectral_step_nm = 5;
    FireRenderer fast(grey, fast_options), spectral(grey, spectral_options);
    fast.SetVolume(grid, t, n);
    spectral.SetVolume(grid, t, n);
    const CameraRays rays(AxisCamera(0.3, 41, 41, 250));
    ImageF a, b;
    fast.Render(rays, &a);
    spectral.Render(rays, &b);
    double peak = 0;
    for (float v : a.pixels) peak = std::max(peak, double(v));
    ASSERT_GT(peak, 0);
    for (std::size_t i = 0; i < a.pixels.size(); ++i)
      ASSERT_NEAR(a.pixels[i], b.pixels[i], 2e-3 * peak) << i;
  }
}

// A frame exposed k times as long (or at k times the gain) as its take's start: the camera's
// output is k times as large, on both renderer paths, for the observer and for a camera's table;
// output / gain() is the same unit-gain light; the sensitivity, bands and name are unchanged.
// The oracle is the response at unit factor times k (exposure is linear in time and gain).
TEST(ChannelResponse, AFrameExposedKTimesAsLongSeesKTimesTheLight) {
  const Box3 box{Eigen::Vector3d(-0.02, -0.02, -0.02), Eigen::Vector3d(0.02, 0.02, 0.02)};
  const AbsorptionModel grey = AbsorptionModel::DefaultGrey();
  const GridGeometry grid = GridGeometry::FromBoxAndDims(box, Eigen::Vector3i(8, 8, 8));
  std::vector<float> t(grid.num_voxels()), n(grid.num_voxels());
  for (std::size_t i = 0; i < t.size(); ++i) {
    t[i] = static_cast<float>(1400 + 3 * (i % 97));
    n[i] = static_cast<float>((i % 5) * 10 / grey.CrossSectionM2(550));
  }
  const double k = 0.37;
  for (const auto& base :
       {ChannelResponse::SrgbObserver(),
        ChannelResponse::ForCamera(Bands({{610, 60}, {530, 60}, {460, 60}}, {1.5, 1, 0.7}))}) {
    SCOPED_TRACE(base->name());
    const auto exposed = ChannelResponse::Exposed(base, k);
    EXPECT_EQ(exposed->name(), base->name());
    EXPECT_EQ(exposed->channels(), base->channels());
    EXPECT_EQ(exposed->basis_is_xyz(), base->basis_is_xyz());
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(exposed->gain()[c], k * base->gain()[c], 1e-15);
    const Eigen::Vector3d a = base->Blackbody(1800), b = exposed->Blackbody(1800);
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(b[c], k * a[c], 1e-12 * std::abs(a[c]));
      EXPECT_NEAR(b[c] / exposed->gain()[c], a[c] / base->gain()[c], 1e-12 * std::abs(a[c]));
    }
    for (SpectralPath path : {SpectralPath::kFast, SpectralPath::kSpectral}) {
      RenderOptions options;
      options.path = path;
      options.response = base;
      FireRenderer at_start(grey, options);
      options.response = exposed;
      FireRenderer at_k(grey, options);
      at_start.SetVolume(grid, t, n);
      at_k.SetVolume(grid, t, n);
      const CameraRays rays(AxisCamera(0.3, 31, 31, 200));
      ImageF a_img, b_img;
      at_start.Render(rays, &a_img);
      at_k.Render(rays, &b_img);
      double peak = 0;
      for (float v : a_img.pixels) peak = std::max(peak, double(std::abs(v)));
      ASSERT_GT(peak, 0);
      for (std::size_t i = 0; i < a_img.pixels.size(); ++i)
        ASSERT_NEAR(b_img.pixels[i], k * a_img.pixels[i], 1e-5 * peak) << i;
    }
  }
  // The copy keeps the camera's table alive after every other user of the response it was made
  // from is gone (ForCamera's own cache holds its last 8 responses: 8 others are built after it).
  const CameraRadiometry alone_camera = Bands({{700, 20}, {600, 20}, {500, 20}}, {3, 1, 2});
  std::shared_ptr<const ChannelResponse> alone;
  std::weak_ptr<const ChannelResponse> source;
  float before[3];
  {
    const auto made = ChannelResponse::ForCamera(alone_camera);
    source = made;
    made->Lookup(1500.0f, before);
    alone = ChannelResponse::Exposed(made, 2.0);
  }
  for (int i = 0; i < 8; ++i)
    ChannelResponse::ForCamera(Bands({{700, 20.0 + i}, {600, 20}, {500, 20}}));
  EXPECT_FALSE(source.expired());  // held by the copy alone
  float out[3];
  alone->Lookup(1500.0f, out);
  for (int c = 0; c < 3; ++c) EXPECT_EQ(out[c], before[c]);  // the basis: the factor is outside
  // 1 is the response itself; a factor that is not finite and positive is an error.
  const auto observer = ChannelResponse::SrgbObserver();
  EXPECT_EQ(ChannelResponse::Exposed(observer, 1.0), observer);
  EXPECT_EQ(ChannelResponse::Exposed(nullptr, 1.0), observer);
  for (double bad : {0.0, -1.0, std::nan(""), HUGE_VAL})
    EXPECT_THROW(ChannelResponse::Exposed(observer, bad), InputError) << bad;
}

TEST(ChannelResponse, ExtremeTemperaturesStayFinite) {
  const auto r = ChannelResponse::ForCamera(Bands({{1000, 50}}));  // a near-infrared mono camera
  for (double t : {0.0, -5.0, 1e-3, 1.0, 300.0, 19999.9, 20000.0, 1e6}) {
    double v[3], d[3];
    r->LookupWithDerivative(t, v, d);
    for (int c = 0; c < 3; ++c) {
      EXPECT_TRUE(std::isfinite(v[c]) && std::isfinite(d[c])) << t;
      EXPECT_GE(v[c], 0) << t;
    }
  }
}

}  // namespace
}  // namespace flamerig
