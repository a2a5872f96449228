// Fire masks and the visual hull on frames as real footage gives them: exactly black backgrounds,
// specks of one or two codes, hot pixels (tomography/visual_hull.h).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "calibration/synthetic_rig.h"
#include "core/srgb.h"
#include "fitting/renderer.h"
#include "fitting/synthetic_fire.h"
#include "tomography/reconstruct.h"
#include "tomography/visual_hull.h"

namespace flamerig {
namespace {

std::size_t Count(const std::vector<std::uint8_t>& mask) {
  return static_cast<std::size_t>(std::count(mask.begin(), mask.end(), 1));
}

// Regions are 8-connected; those of fewer pixels than the minimum go, the others stay whole.
TEST(RemoveSpecks, RemovesSmallRegionsOnly) {
  const int w = 40, h = 30;
  std::vector<std::uint8_t> mask(w * h, 0);
  auto set = [&](int x, int y) { mask[y * w + x] = 1; };
  for (int y = 5; y < 10; ++y)
    for (int x = 5; x < 10; ++x) set(x, y);         // 25 px: kept
  set(25, 22);                                      // 1 px
  set(30, 5), set(31, 5), set(30, 6), set(31, 6);   // 2x2: 4 px
  set(2, 25), set(3, 26);                           // a diagonal pair: 2 px, one region
  for (int i = 0; i < 5; ++i) set(15 + i, 15 + i);  // a diagonal line of 5: one region, kept
  std::vector<std::uint8_t> cleaned = mask;
  const auto [regions, pixels] = RemoveSpecks(&cleaned, w, h, 5);
  EXPECT_EQ(regions, 3u);
  EXPECT_EQ(pixels, 7u);
  EXPECT_EQ(Count(cleaned), 25u + 5u);
  EXPECT_EQ(cleaned[7 * w + 7], 1);
  EXPECT_EQ(cleaned[17 * w + 17], 1);
  // A minimum of 1 (or 0) keeps everything.
  std::vector<std::uint8_t> kept = mask;
  EXPECT_EQ(RemoveSpecks(&kept, w, h, 1).first, 0u);
  EXPECT_EQ(kept, mask);
}

// One camera looking at a box, and a frame: an exactly black background with a bright block (the
// fire), specks of 1 and 2 codes and a 2x2 hot blob of 60 codes.
struct Scene {
  Rig rig;
  GridGeometry grid;
  ImageU8 image;
  const RigCamera& camera() const { return rig.cameras[0]; }
};

Scene MakeScene() {
  Scene s;
  const Box3 box{Eigen::Vector3d(-0.015, 0.0, -0.015), Eigen::Vector3d(0.015, 0.07, 0.015)};
  synthetic::RingOptions ring;
  ring.cameras = 1;
  ring.azimuths_deg = {0};
  ring.width = 96;
  ring.height = 72;
  s.rig = synthetic::MakeRingRig(box, ring);
  s.grid = GridGeometry::FromBox(box, 32);
  s.image = ImageU8(96, 72, 3, 0);
  for (int y = 20; y < 50; ++y)
    for (int x = 40; x < 56; ++x)
      for (int c = 0; c < 3; ++c) s.image.at(x, y, c) = static_cast<std::uint8_t>(200 - 40 * c);
  std::mt19937 rng(3);
  for (int i = 0; i < 300; ++i) {
    const int x = static_cast<int>(rng() % 96), y = static_cast<int>(rng() % 72);
    if (x >= 36 && x < 60 && y >= 16 && y < 54) continue;  // away from the fire
    s.image.at(x, y, static_cast<int>(rng() % 3)) = static_cast<std::uint8_t>(1 + rng() % 2);
  }
  for (int y = 60; y < 62; ++y)
    for (int x = 10; x < 12; ++x) s.image.at(x, y, 0) = 60;
  return s;
}

TEST(FireMask, AnExactlyBlackBackgroundGetsANoiseFloorOfOneCode) {
  const Scene s = MakeScene();
  const double exposure = 0.5;
  const LinearFrame frame = DecodeSrgb8(s.image, exposure);
  // One code above black in sRGB: 1 / 255 / 12.92 of full scale.
  EXPECT_NEAR(frame.quantum, 1.0 / 255 / 12.92 / exposure, 1e-12);
  VisualHullOptions options;
  options.min_speck_px = 5;
  options.dilation_px = 0;
  const FireMask mask = ComputeFireMask(s.grid, s.camera(), frame, options, /*keep_labels=*/true);
  // The darkest three quarters read 0 (the specks are fewer than a quarter of the pixels).
  EXPECT_EQ(mask.noise_estimate, 0.0);
  EXPECT_NEAR(mask.noise_sigma, frame.quantum, 1e-12);
  EXPECT_NEAR(mask.threshold, 5 * frame.quantum, 1e-12);
  // Fire: the block; the 1-2 code specks are below the threshold; the hot blob is a speck.
  EXPECT_EQ(mask.fire_pixels, 30u * 16u);
  EXPECT_EQ(mask.speck_regions, 1u);
  EXPECT_EQ(mask.speck_pixels, 4u);
  EXPECT_EQ(mask.labels[60 * 96 + 10], kMaskSpeck);
  EXPECT_EQ(mask.labels[30 * 96 + 45], kMaskFire);
  // The dilated mask reaches no background speck.
  for (int y = 0; y < 72; ++y)
    for (int x = 0; x < 96; ++x)
      if (x < 30 || x >= 66 || y < 10 || y >= 60) {
        EXPECT_EQ(mask.mask[y * 96 + x], 0) << x << "," << y;
      }
  // The rule it replaced (a threshold of one code, every region kept) takes specks for fire.
  VisualHullOptions old = options;
  old.threshold_sigmas = 0.99;
  old.min_speck_px = 0;
  const FireMask before = ComputeFireMask(s.grid, s.camera(), frame, old);
  EXPECT_GT(before.fire_pixels, mask.fire_pixels + 100);
}

// A mono machine-vision camera's frame: 12-bit linear, its black level subtracted, Gaussian
// noise of 4 DN clipped at black (half the background reads 0), a block of fire. The estimate is
// the noise's deviation (the oracle: the generator's), and the mask is the block: with the colour
// rule (a third of the deviation) the threshold was 1.5 sigma and noise covered the image.
TEST(FireMask, AMonoCamerasClippedNoiseIsEstimatedAtItsDeviation) {
  const Scene s = MakeScene();
  const double sigma = 4.0 / 4095;
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, sigma);
  LinearFrame frame;
  frame.radiance = ImageF(96, 72, 3, 0.0f);
  frame.quantum = 1.0 / 4095;
  for (int y = 0; y < 72; ++y)
    for (int x = 0; x < 96; ++x) {
      const bool fire = x >= 30 && x < 66 && y >= 10 && y < 26;
      const float v = static_cast<float>(std::max(0.0, (fire ? 0.3 : 0.0) + noise(rng)));
      for (int c = 0; c < 3; ++c) frame.radiance.at(x, y, c) = v;
    }
  const double estimate = EstimateNoiseSigma(frame.radiance);
  std::printf("noise %.3g, estimated %.3g\n", sigma, estimate);
  EXPECT_NEAR(estimate, sigma, 0.1 * sigma);
  VisualHullOptions options;
  options.dilation_px = 0;
  const FireMask mask = ComputeFireMask(s.grid, s.camera(), frame, options);
  EXPECT_EQ(mask.fire_pixels, 36u * 16u);
  EXPECT_LE(mask.speck_pixels, 3u);  // 5 sigma: about one background pixel in 3.5 million
}

TEST(FireMask, SixteenBitLinearFramesStepByOneCode) {
  ImageU16 image(8, 8, 1, 0);
  image.at(3, 3) = 1000;
  const LinearFrame frame = DecodeLinear16(image, 2.0);
  EXPECT_DOUBLE_EQ(frame.quantum, 1.0 / 65535 / 2.0);
  EXPECT_NEAR(frame.radiance.at(3, 3, 1), 1000.0 / 65535 / 2.0, 1e-9);
}

TEST(FireMask, AutomaticSpeckSizeIsHalfAVoxelsImage) {
  const Scene s = MakeScene();
  const LinearFrame frame = DecodeSrgb8(s.image, 1.0);
  const double voxel = VoxelFootprintPx(s.grid, s.camera());
  ASSERT_GT(voxel, 0);
  // The footprint by hand: focal length times the voxel edge over the box centre's depth.
  const Eigen::Vector3d centre = s.camera().model.cam_from_rig() * s.grid.box().center();
  EXPECT_NEAR(voxel,
              std::max(s.camera().model.intrinsics()[0], s.camera().model.intrinsics()[1]) *
                  s.grid.voxel_size_m.maxCoeff() / centre.z(),
              1e-9);
  const FireMask mask = ComputeFireMask(s.grid, s.camera(), frame, VisualHullOptions());
  EXPECT_EQ(mask.min_speck_px, std::max(2, static_cast<int>(0.5 * voxel * voxel)));
}

// A ring of 96x72 cameras at these azimuths around a 3 x 7 x 3 cm box, a grid of 24 over it, and
// the linear images of a grey fire in the middle of the box (the generator's soot unless given).
struct RingScene {
  Rig rig;
  GridGeometry grid;
  std::vector<ImageF> linear;
};

RingScene MakeRingScene(const std::vector<double>& azimuths_deg, double soot_fraction = -1) {
  const Box3 box{Eigen::Vector3d(-0.015, 0.0, -0.015), Eigen::Vector3d(0.015, 0.07, 0.015)};
  synthetic::RingOptions ring;
  ring.cameras = static_cast<int>(azimuths_deg.size());
  ring.azimuths_deg = azimuths_deg;
  ring.width = 96;
  ring.height = 72;
  RingScene s;
  s.rig = synthetic::MakeRingRig(box, ring);
  s.grid = GridGeometry::FromBox(box, 24);
  const AbsorptionModel grey = AbsorptionModel::DefaultGrey();
  synthetic::FireOptions fire;
  if (soot_fraction >= 0) fire.peak_soot_volume_fraction = soot_fraction;
  fire.region = Box3{Eigen::Vector3d(-0.006, 0.01, -0.006), Eigen::Vector3d(0.006, 0.04, 0.006)};
  const FireVolume truth = synthetic::MakeFire(s.grid, fire, grey);
  FireRenderer renderer(grey);
  renderer.SetVolume(s.grid, truth.temperature_k, truth.density_per_m3);
  for (const auto& c : s.rig.cameras) {
    s.linear.emplace_back();
    renderer.Render(CameraRays(c.model), &s.linear.back());
  }
  return s;
}

// The whole reconstruction on frames with specks: the hull and the result stay what they are on
// clean frames, while the old rule grows the hull.
TEST(VisualHull, SpecksOnABlackBackgroundDoNotGrowTheHull) {
  const RingScene scene = MakeRingScene({0, 45, 90, 135}, 1e-7);
  const Rig& rig = scene.rig;
  const std::vector<ImageF>& linear = scene.linear;
  float peak = 0;
  for (const ImageF& l : linear)
    for (float v : l.pixels) peak = std::max(peak, v);
  const double exposure = 0.9 / peak;
  std::vector<ImageU8> clean, specked;
  std::mt19937 rng(9);
  for (const ImageF& l : linear) {
    clean.push_back(ApplyCameraResponse(l, exposure));
    ImageU8 s = clean.back();
    for (std::size_t p = 0; p < s.num_pixels(); ++p) {
      const bool black = !s.pixels[3 * p] && !s.pixels[3 * p + 1] && !s.pixels[3 * p + 2];
      if (black && rng() % 10 == 0)
        s.pixels[3 * p + rng() % 3] = static_cast<std::uint8_t>(1 + rng() % 2);
    }
    specked.push_back(std::move(s));
  }
  ReconstructOptions options;
  options.resolution = 24;
  options.exposure = exposure;
  ReconstructSummary a, b, c;
  Reconstructor(rig, options).Reconstruct(clean, &a);
  Reconstructor(rig, options).Reconstruct(specked, &b);
  EXPECT_GT(a.voxel_fraction_in_hull, 0.01);
  EXPECT_NEAR(b.voxel_fraction_in_hull, a.voxel_fraction_in_hull, 0.01 * a.voxel_fraction_in_hull);
  ReconstructOptions old = options;
  old.hull.threshold_sigmas = 0.99;  // a threshold of one code, every region kept
  old.hull.min_speck_px = 0;
  Reconstructor(rig, old).Reconstruct(specked, &c);
  EXPECT_GT(c.voxel_fraction_in_hull, 1.5 * a.voxel_fraction_in_hull);
}

// The hull against its definition, evaluated here voxel by voxel from each camera's own mask: a
// voxel is inside when no camera that sees it sees background there and at least min(min_views,
// cameras that see it) see fire. The hull's masks are each camera's ComputeFireMask (the hull
// computes them in parallel and rules a voxel out at its first background camera). With frames of
// the wrong size for two cameras, the error names the first of them in the rig's order, however
// the threads ran.
TEST(VisualHull, IsItsDefinitionAndNamesTheFirstCameraInError) {
  const RingScene scene = MakeRingScene({0, 30, 60, 90, 120, 150});
  const Rig& rig = scene.rig;
  const GridGeometry& grid = scene.grid;
  std::vector<LinearFrame> frames;
  for (const ImageF& linear : scene.linear) {
    float peak = 0;
    for (float v : linear.pixels) peak = std::max(peak, v);
    frames.push_back(DecodeSrgb8(ApplyCameraResponse(linear, 0.9 / peak), 1.0));
  }
  for (const int min_views : {1, 2, 4}) {
    VisualHullOptions options;
    options.min_views = min_views;
    const VoxelProjections projections = ComputeVoxelProjections(grid, rig.cameras);
    const VisualHull hull = ComputeVisualHull(grid, rig.cameras, frames, options, projections);
    std::vector<std::vector<std::uint8_t>> masks;
    for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
      const FireMask mask = ComputeFireMask(grid, rig.cameras[c], frames[c], options);
      EXPECT_EQ(hull.fire_mask[c], mask.mask) << "camera " << c;
      EXPECT_EQ(hull.masks[c].fire_pixels, mask.fire_pixels) << "camera " << c;
      EXPECT_EQ(hull.masks[c].threshold, mask.threshold) << "camera " << c;
      masks.push_back(mask.mask);
    }
    std::size_t inside = 0, mismatched = 0;
    for (std::size_t v = 0; v < grid.num_voxels(); ++v) {
      int visible = 0, fire_views = 0;
      bool background = false;
      for (std::size_t c = 0; c < masks.size(); ++c) {
        const std::int32_t p = projections.pixel[c][v];
        if (p < 0) continue;
        ++visible;
        if (masks[c][p])
          ++fire_views;
        else
          background = true;
      }
      const bool expected =
          visible > 0 && !background && fire_views >= std::min(min_views, visible);
      inside += expected;
      mismatched += expected != (hull.voxel_inside[v] != 0);
    }
    EXPECT_GT(inside, grid.num_voxels() / 100) << "min_views " << min_views;
    EXPECT_LT(inside, grid.num_voxels() / 2) << "min_views " << min_views;
    EXPECT_EQ(mismatched, 0u) << "min_views " << min_views;
    EXPECT_EQ(hull.voxels_inside, inside) << "min_views " << min_views;
  }
  std::vector<LinearFrame> wrong = frames;
  for (const int c : {2, 4}) {
    LinearFrame small;
    small.radiance = ImageF(48, 36, 3, 0.0f);
    small.saturated.assign(48 * 36, 0);
    wrong[c] = small;
  }
  for (int run = 0; run < 20; ++run) {
    try {
      ComputeVisualHull(grid, rig.cameras, wrong, VisualHullOptions());
      ADD_FAILURE() << "frames of the wrong size were accepted";
    } catch (const DataError& e) {
      EXPECT_NE(std::string(e.what()).find("'" + rig.cameras[2].name + "'"), std::string::npos)
          << e.what();
    }
  }
}

}  // namespace
}  // namespace flamerig
