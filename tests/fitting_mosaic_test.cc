// The fit's model of a Bayer camera (fitting/mosaic.h) against its oracles: OpenCV's demosaicing
// as DecodeFrame applies it to a recorded frame, the transpose's defining identity, central
// finite differences, and a rendered truth that only the model explains.
#include "fitting/mosaic.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "acquisition/frame.h"
#include "calibration/camera_rays.h"
#include "calibration/radiometry.h"
#include "calibration/synthetic_rig.h"
#include "core/error.h"
#include "fitting/objective.h"
#include "fitting/renderer.h"

namespace flamerig {
namespace {

constexpr PixelFormat kFormats[] = {PixelFormat::kBayerRg8, PixelFormat::kBayerGr8,
                                    PixelFormat::kBayerGb8, PixelFormat::kBayerBg8};

// A recorded frame of `format` whose site (x, y) holds codes(x, y, its colour).
Frame MosaicFrame(const ImageU8& codes, PixelFormat format) {
  const BayerLayout layout = BayerLayoutOf(format);
  auto bytes = std::make_shared<std::vector<std::uint8_t>>(codes.num_pixels());
  for (int y = 0; y < codes.height; ++y)
    for (int x = 0; x < codes.width; ++x)
      (*bytes)[std::size_t(y) * codes.width + x] = codes.at(x, y, BayerColour(layout, x, y));
  Frame f;
  f.info.pixel_format = format;
  f.info.width = codes.width;
  f.info.height = codes.height;
  f.data = bytes;
  return f;
}

constexpr PixelFormat kFormats16[] = {PixelFormat::kBayerRg16, PixelFormat::kBayerGr16,
                                      PixelFormat::kBayerGb16, PixelFormat::kBayerBg16};

// The same for a 16-bit mosaic (little-endian words).
Frame MosaicFrame16(const ImageU16& codes, PixelFormat format) {
  const BayerLayout layout = BayerLayoutOf(format);
  auto bytes = std::make_shared<std::vector<std::uint8_t>>(2 * codes.num_pixels());
  for (int y = 0; y < codes.height; ++y)
    for (int x = 0; x < codes.width; ++x) {
      const std::uint16_t v = codes.at(x, y, BayerColour(layout, x, y));
      const std::size_t i = std::size_t(y) * codes.width + x;
      (*bytes)[2 * i] = static_cast<std::uint8_t>(v & 0xff);
      (*bytes)[2 * i + 1] = static_cast<std::uint8_t>(v >> 8);
    }
  Frame f;
  f.info.pixel_format = format;
  f.info.width = codes.width;
  f.info.height = codes.height;
  f.data = bytes;
  return f;
}

TEST(BayerLayout, FollowsTheGenICamNames) {
  // BayerRG8: R at (0, 0), G at (1, 0) and (0, 1), B at (1, 1); the others by their names.
  const char* cells[] = {"RGGB", "GRBG", "GBRG", "BGGR"};
  const char colours[] = "RGB";
  for (int i = 0; i < 4; ++i) {
    const BayerLayout layout = BayerLayoutOf(kFormats[i]);
    EXPECT_STREQ(ToString(layout), cells[i]);
    const std::string read = {
        colours[BayerColour(layout, 0, 0)], colours[BayerColour(layout, 1, 0)],
        colours[BayerColour(layout, 0, 1)], colours[BayerColour(layout, 1, 1)]};
    EXPECT_EQ(read, cells[i]);
    EXPECT_EQ(BayerColour(layout, 6, 4), BayerColour(layout, 0, 0));  // the cell repeats
    EXPECT_EQ(BayerColour(layout, 3, 5), BayerColour(layout, 1, 1));
  }
  EXPECT_EQ(BayerLayoutOf(PixelFormat::kRgb8), BayerLayout::kNone);
  EXPECT_EQ(BayerLayoutOf(PixelFormat::kMono8), BayerLayout::kNone);
  EXPECT_EQ(BayerLayoutOf(PixelFormat::kMono16), BayerLayout::kNone);
  for (int i = 0; i < 4; ++i) EXPECT_EQ(BayerLayoutOf(kFormats16[i]), BayerLayoutOf(kFormats[i]));
}

// The interpolation the model renders is the one DecodeFrame (OpenCV) applies to a recording,
// borders included, to OpenCV's rounding of the interpolated codes.
TEST(BayerResample, IsWhatDecodeFrameMakesOfTheMosaic) {
  std::mt19937 rng(5);
  std::uniform_int_distribution<int> code(0, 255);
  for (const auto& [w, h] : {std::pair{13, 10}, std::pair{12, 9}, std::pair{3, 3}}) {
    ImageU8 codes(w, h, 3);
    for (auto& c : codes.pixels) c = static_cast<std::uint8_t>(code(rng));
    ImageF as_float(w, h, 3);
    for (std::size_t i = 0; i < codes.pixels.size(); ++i) as_float.pixels[i] = codes.pixels[i];
    for (PixelFormat format : kFormats) {
      ImageU8 decoded;
      ImageU16 unused;
      ASSERT_EQ(DecodeFrame(MosaicFrame(codes, format), &decoded, &unused), 8);
      const ImageF model = BayerResample(as_float, BayerLayoutOf(format));
      double worst = 0;
      for (std::size_t i = 0; i < model.pixels.size(); ++i)
        worst = std::max(worst, std::abs(double(model.pixels[i]) - decoded.pixels[i]));
      EXPECT_LE(worst, 0.5 + 1e-4) << ToString(format) << " " << w << "x" << h;
    }
    // 16-bit mosaics: full-scale words and a 12-bit camera's codes.
    for (int top : {65535, 4095}) {
      std::uniform_int_distribution<int> code16(0, top);
      ImageU16 codes16(w, h, 3);
      for (auto& c : codes16.pixels) c = static_cast<std::uint16_t>(code16(rng));
      ImageF as_float16(w, h, 3);
      for (std::size_t i = 0; i < codes16.pixels.size(); ++i)
        as_float16.pixels[i] = codes16.pixels[i];
      for (PixelFormat format : kFormats16) {
        ImageU8 unused;
        ImageU16 decoded;
        ASSERT_EQ(DecodeFrame(MosaicFrame16(codes16, format), &unused, &decoded), 16);
        ASSERT_EQ(decoded.channels, 3);
        const ImageF model = BayerResample(as_float16, BayerLayoutOf(format));
        double worst = 0;
        for (std::size_t i = 0; i < model.pixels.size(); ++i)
          worst = std::max(worst, std::abs(double(model.pixels[i]) - decoded.pixels[i]));
        EXPECT_LE(worst, 0.5 + 1e-2) << ToString(format) << " " << w << "x" << h << " to " << top;
      }
    }
  }
}

TEST(BayerResample, AdjointIsItsTranspose) {
  std::mt19937 rng(9);
  std::normal_distribution<float> g(0, 1);
  ImageF a(11, 8, 3), b(11, 8, 3);
  for (auto& v : a.pixels) v = g(rng);
  for (auto& v : b.pixels) v = g(rng);
  for (PixelFormat format : kFormats) {
    const BayerLayout layout = BayerLayoutOf(format);
    const ImageF ra = BayerResample(a, layout), rtb = BayerResampleAdjoint(b, layout);
    double lhs = 0, rhs = 0, scale = 0;
    for (std::size_t i = 0; i < a.pixels.size(); ++i) {
      lhs += double(ra.pixels[i]) * b.pixels[i];
      rhs += double(a.pixels[i]) * rtb.pixels[i];
      scale += std::abs(double(ra.pixels[i]) * b.pixels[i]);
    }
    EXPECT_NEAR(lhs, rhs, 1e-5 * scale) << ToString(format);
  }
}

TEST(BayerResample, RefusesWhatItCannotInterpolate) {
  EXPECT_THROW(BayerResample(ImageF(2, 5, 3), BayerLayout::kRggb), InputError);
  EXPECT_THROW(BayerResample(ImageF(5, 5, 1), BayerLayout::kRggb), InputError);
  EXPECT_THROW(BayerResample(ImageF(5, 5, 3), BayerLayout::kNone), InputError);
  EXPECT_THROW(BayerRecord(BayerLayout::kNone, CameraRadiometry{}), InputError);
  CameraRadiometry mono;
  mono.spectral.kind = SpectralSensitivity::Kind::kBands;
  mono.spectral.bands = {SpectralBand{550, 40}};
  EXPECT_THROW(BayerRecord(BayerLayout::kRggb, mono), InputError);
  EXPECT_EQ(MakeBayerRecord(BayerLayout::kNone, CameraRadiometry{}), nullptr);
}

// Two cameras: the default (8-bit sRGB codes) and a raw one (linear, black level 16, saturating
// at 250, unequal gains: the gains are the renderer's, so they do not enter here).
std::vector<CameraRadiometry> Cameras() {
  CameraRadiometry raw;
  raw.transfer = TransferFunction::kLinear;
  raw.bit_depth = 8;
  raw.black_level = 16;
  raw.saturation_level = 250;
  return {CameraRadiometry{}, raw};
}

// Forward() is what the camera records (each site's code of its channel, rounded) and the host
// decodes (DecodeFrame's demosaicing, then the camera's decoding), to within the codes' rounding.
TEST(BayerRecord, ForwardIsWhatTheCameraRecordsAndTheHostDecodes) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0, 1.3f);
  const double s = 0.8;
  ImageF linear(17, 12, 3);
  for (auto& v : linear.pixels) v = u(rng);
  for (const CameraRadiometry& camera : Cameras()) {
    const CameraRadiometry::Decoding d = camera.DecodingFor(8);
    ImageU8 codes(linear.width, linear.height, 3);
    for (std::size_t i = 0; i < codes.pixels.size(); ++i)
      codes.pixels[i] = static_cast<std::uint8_t>(camera.Code(s * linear.pixels[i], d));
    for (PixelFormat format : kFormats) {
      ImageU8 decoded;
      ImageU16 unused;
      DecodeFrame(MosaicFrame(codes, format), &decoded, &unused);
      const ImageF model = BayerRecord(BayerLayoutOf(format), camera).Forward(linear, s);
      double worst = 0;
      for (std::size_t i = 0; i < model.pixels.size(); ++i)
        worst = std::max(worst, std::abs(camera.Encode(model.pixels[i], d) - decoded.pixels[i]));
      // Each site's code rounded (0.5), OpenCV's interpolated code rounded (0.5).
      EXPECT_LE(worst, 1.0 + 1e-3) << ToString(format) << ", " << camera.Describe();
    }
  }
  // 16-bit mosaics: a raw 12-bit camera (linear, black 64, saturating at 4000; its codes in the
  // words' low bits) and a full-scale linear one (the default decoding of 16-bit frames).
  CameraRadiometry raw12;
  raw12.transfer = TransferFunction::kLinear;
  raw12.bit_depth = 12;
  raw12.black_level = 64;
  raw12.saturation_level = 4000;
  for (const CameraRadiometry& camera : {raw12, CameraRadiometry{}}) {
    const CameraRadiometry::Decoding d = camera.DecodingFor(16);
    ImageU16 codes(linear.width, linear.height, 3);
    for (std::size_t i = 0; i < codes.pixels.size(); ++i)
      codes.pixels[i] = static_cast<std::uint16_t>(camera.Code(s * linear.pixels[i], d));
    for (PixelFormat format : kFormats16) {
      ImageU8 unused;
      ImageU16 decoded;
      DecodeFrame(MosaicFrame16(codes, format), &unused, &decoded);
      const ImageF model = BayerRecord(BayerLayoutOf(format), camera, 16).Forward(linear, s);
      double worst = 0;
      for (std::size_t i = 0; i < model.pixels.size(); ++i)
        worst = std::max(worst, std::abs(camera.Encode(model.pixels[i], d) - decoded.pixels[i]));
      EXPECT_LE(worst, 1.0 + 0.05) << ToString(format) << ", " << camera.Describe();
    }
  }
  // A 12-bit camera's mosaic cannot arrive in 8 bits: refused, naming the camera.
  try {
    MakeBayerRecord(BayerLayout::kRggb, raw12, "cam3");
    ADD_FAILURE() << "a 12-bit camera decoded from 8-bit frames";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("cam3"), std::string::npos) << e.what();
  }
  EXPECT_EQ(MakeBayerRecord(BayerLayout::kRggb, raw12, "cam3", 16)->frame_bits(), 16);
}

// dE/d(linear) and dE/ds of E = sum of weights x Forward() against central differences; channels
// a site does not measure have no derivative.
TEST(BayerRecord, AdjointMatchesFiniteDifferences) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0.08f, 1.1f);  // s I within (0.07, 0.94)
  std::normal_distribution<float> g(0, 1);
  const double s = 0.85;
  ImageF linear(9, 8, 3), weights(9, 8, 3);
  for (auto& v : linear.pixels) v = u(rng);
  for (auto& v : weights.pixels) v = g(rng);
  // Two saturated pixels (s I = 2.55): no derivative there, and their sites' codes held.
  for (int ch = 0; ch < 3; ++ch) linear.at(4, 3, ch) = linear.at(0, 7, ch) = 3.0f;
  for (const CameraRadiometry& camera : Cameras()) {
    for (PixelFormat format : {PixelFormat::kBayerRg8, PixelFormat::kBayerGb8}) {
      const BayerRecord record(BayerLayoutOf(format), camera);
      auto energy = [&](const ImageF& image, double exposure) {
        const ImageF out = record.Forward(image, exposure);
        double e = 0;
        for (std::size_t i = 0; i < out.pixels.size(); ++i)
          e += double(weights.pixels[i]) * out.pixels[i];
        return e;
      };
      double d_s = 0;
      const ImageF grad = record.Adjoint(linear, s, weights, &d_s);
      double scale = 0;
      for (float v : grad.pixels) scale = std::max(scale, double(std::abs(v)));
      ASSERT_GT(scale, 0);
      for (int y : {0, 3, 7})
        for (int x : {0, 4, 8})
          for (int ch = 0; ch < 3; ++ch) {
            const double h = 2e-3;
            ImageF plus = linear, minus = linear;
            plus.at(x, y, ch) += h;
            minus.at(x, y, ch) -= h;
            const double fd = (energy(plus, s) - energy(minus, s)) / (2 * h);
            EXPECT_NEAR(grad.at(x, y, ch), fd, 2e-3 * scale)
                << ToString(format) << " (" << x << ", " << y << ") channel " << ch;
            if (ch != BayerColour(record.layout(), x, y) || linear.at(x, y, ch) == 3.0f) {
              EXPECT_EQ(grad.at(x, y, ch), 0.0f);
            }
          }
      const double fd_s = (energy(linear, s * 1.001) - energy(linear, s * 0.999)) / (0.002 * s);
      EXPECT_NEAR(d_s, fd_s, 2e-3 * std::abs(fd_s) + 1e-6) << ToString(format);
      // Forward's codes handed to the adjoint give the same gradient as working them out again.
      ImageF codes;
      record.Forward(linear, s, &codes);
      double d_s_codes = 0;
      const ImageF grad_codes = record.Adjoint(linear, s, weights, &d_s_codes, &codes);
      EXPECT_EQ(grad_codes.pixels, grad.pixels) << ToString(format);
      EXPECT_EQ(d_s_codes, d_s) << ToString(format);
      const ImageF wrong_size(4, 4, 3);
      EXPECT_THROW(record.Adjoint(linear, s, weights, nullptr, &wrong_size), InputError);
    }
  }
}

// A fire filmed by two Bayer cameras (RGGB, 64x48) and demosaiced on the host, with its truth: a
// hot core in a cooler shell with sharp edges, so that colour changes within a pixel or two. Each
// site's code gets Gaussian noise of `noise_codes` where the fire is (clean code >= 8).
struct BayerScene {
  AbsorptionModel absorption = AbsorptionModel::DefaultGrey();
  GridGeometry grid;
  std::vector<std::uint32_t> active;
  std::vector<double> t, n;
  double exposure = 0;
  std::vector<std::unique_ptr<CameraRays>> rays;
  std::vector<FitView> views;
};

BayerScene MakeBayerScene(double noise_codes) {
  BayerScene s;
  const Box3 box{Eigen::Vector3d(-0.02, 0, -0.02), Eigen::Vector3d(0.02, 0.04, 0.02)};
  s.grid = GridGeometry::FromBox(box, 16);
  synthetic::RingOptions ring;
  ring.cameras = 2;
  ring.width = 64;
  ring.height = 48;
  ring.distance_m = 0.15;
  const Rig rig = synthetic::MakeRingRig(box, ring);
  std::vector<float> tt(s.grid.num_voxels(), 0), nn(s.grid.num_voxels(), 0);
  const double n0 = 0.2 / (s.absorption.CrossSectionM2(550) * s.grid.voxel_size_m.x());
  for (std::uint32_t v = 0; v < s.grid.num_voxels(); ++v) {
    const Eigen::Vector3i i = s.grid.Unflat(v);
    const double r = (s.grid.VoxelCenter(i.x(), i.y(), i.z()) - box.center()).norm();
    if (r > 0.014) continue;
    s.active.push_back(v);
    s.t.push_back(r < 0.007 ? 2000 : 1500);
    s.n.push_back(n0);
    tt[v] = static_cast<float>(s.t.back());
    nn[v] = static_cast<float>(n0);
  }
  FireRenderer renderer(s.absorption);
  renderer.SetVolume(s.grid, tt, nn);
  std::mt19937 rng(17);
  std::normal_distribution<double> noise(0, noise_codes);
  for (const RigCamera& camera : rig.cameras) {
    s.rays.push_back(std::make_unique<CameraRays>(camera.model));
    ImageF linear;
    renderer.Render(*s.rays.back(), &linear);
    if (s.exposure == 0) {  // the brightest channel at 0.9 of full scale
      float peak = 0;
      for (float v : linear.pixels) peak = std::max(peak, v);
      s.exposure = 0.9 / peak;
    }
    ImageU8 codes(linear.width, linear.height, 3);
    const CameraRadiometry srgb;
    const CameraRadiometry::Decoding d = srgb.DecodingFor(8);
    for (std::size_t i = 0; i < codes.pixels.size(); ++i) {
      double code = srgb.Encode(s.exposure * linear.pixels[i], d);
      if (code >= 8) code += noise(rng);
      codes.pixels[i] = static_cast<std::uint8_t>(std::clamp(std::round(code), 0.0, 255.0));
    }
    FitView view;
    view.name = camera.name;
    view.rays = s.rays.back().get();
    ImageU16 unused;
    DecodeFrame(MosaicFrame(codes, PixelFormat::kBayerRg8), &view.image, &unused);
    view.mosaic = MakeBayerRecord(BayerLayout::kRggb, srgb);
    s.views.push_back(std::move(view));
  }
  return s;
}

// At the true volume, the energy that renders through the mosaic sees only the codes' rounding,
// and the one that takes the interpolated colours as measured sees the interpolation's fringes at
// the fire's edges.
TEST(BayerRecord, OnlyTheMosaicModelExplainsADemosaicedRecordingOfTheTruth) {
  const BayerScene s = MakeBayerScene(0);
  ObjectiveOptions with, without;
  with.w_sm = without.w_sm = 0;
  without.model_mosaic = false;
  const RenderOptions render;
  const FitObjective modelled(s.grid, s.active, s.views, s.absorption, render, with);
  const FitObjective as_measured(s.grid, s.active, s.views, s.absorption, render, without);
  ASSERT_TRUE(modelled.any_mosaic());
  ASSERT_FALSE(as_measured.any_mosaic());
  const double e_model = modelled.Evaluate(s.t, s.n, s.exposure).data_exact;
  const double e_plain = as_measured.Evaluate(s.t, s.n, s.exposure).data_exact;
  std::printf("summed Delta E at the truth: through the mosaic %.1f, as measured %.1f\n", e_model,
              e_plain);
  EXPECT_LT(e_model, 0.25 * e_plain);
  // The cheap path (DataTermAt, for exposure searches on one render) agrees with Evaluate.
  EXPECT_NEAR(modelled.DataTermAt(modelled.Render(s.t, s.n), s.exposure), e_model, 1e-3 * e_model);
}

// The sigma's noise level (DataCurvature's differences of residuals) where the model is exact:
// the residuals at the truth are the noise alone, so their own mean square is the level to find.
// Neighbouring pixels interpolated from the same sites share their noise; the differences are
// taken three pixels apart.
TEST(BayerRecord, TheNoiseLevelOfABayerViewIsItsResidualsWhereTheModelIsExact) {
  const BayerScene s = MakeBayerScene(3.0);
  ObjectiveOptions o;
  o.w_sm = 0;
  const FitObjective objective(s.grid, s.active, s.views, s.absorption, RenderOptions{}, o);
  const FitObjective::Curvature c = objective.DataCurvature(s.t, s.n, s.exposure);
  ASSERT_GT(c.residuals, 1000);  // about 500 fire pixels
  ASSERT_GT(c.differences, 1000);
  const double from_residuals = c.residual_sq / c.residuals;
  const double from_differences = c.difference_sq / c.differences;
  std::printf("noise variance (Lab^2): residuals %.3f, differences %.3f\n", from_residuals,
              from_differences);
  EXPECT_NEAR(from_differences / from_residuals, 1.0, 0.15);
}

}  // namespace
}  // namespace flamerig
