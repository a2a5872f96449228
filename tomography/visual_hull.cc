#include "tomography/visual_hull.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <stdexcept>

#include "acquisition/srgb.h"

namespace flamerig {

LinearFrame DecodeSrgb8(const ImageU8& image, double exposure) {
  if (!(exposure > 0) || !std::isfinite(exposure)) {
    throw std::invalid_argument("exposure = " + std::to_string(exposure) +
                                " must be finite and > 0");
  }
  if (image.channels != 1 && image.channels != 3) {
    throw std::invalid_argument("an 8-bit frame must have 1 or 3 channels, not " +
                                std::to_string(image.channels));
  }
  const auto& table = SrgbU8ToLinearTable();
  LinearFrame f;
  f.radiance = ImageF(image.width, image.height, 3);
  f.saturated.assign(image.num_pixels(), 0);
  f.full_scale = 1.0 / exposure;
  for (std::size_t p = 0; p < image.num_pixels(); ++p) {
    for (int c = 0; c < 3; ++c) {
      std::uint8_t v = image.pixels[p * image.channels + (image.channels == 1 ? 0 : c)];
      f.radiance.pixels[3 * p + c] = static_cast<float>(table[v] / exposure);
      if (v == 255) f.saturated[p] = 1;
    }
  }
  return f;
}

LinearFrame DecodeLinear16(const ImageU16& image, double exposure, double white) {
  if (!(exposure > 0) || !std::isfinite(exposure)) {
    throw std::invalid_argument("exposure = " + std::to_string(exposure) +
                                " must be finite and > 0");
  }
  if (!(white > 0)) throw std::invalid_argument("white level must be > 0");
  if (image.channels != 1 && image.channels != 3) {
    throw std::invalid_argument("a 16-bit frame must have 1 or 3 channels");
  }
  LinearFrame f;
  f.radiance = ImageF(image.width, image.height, 3);
  f.saturated.assign(image.num_pixels(), 0);
  f.full_scale = 1.0 / exposure;
  for (std::size_t p = 0; p < image.num_pixels(); ++p) {
    for (int c = 0; c < 3; ++c) {
      double v = image.pixels[p * image.channels + (image.channels == 1 ? 0 : c)];
      f.radiance.pixels[3 * p + c] = static_cast<float>(std::min(v / white, 1.0) / exposure);
      if (v >= white) f.saturated[p] = 1;
    }
  }
  return f;
}

void VisualHullOptions::Validate() const {
  auto fail = [](const std::string& what) {
    throw std::invalid_argument("VisualHullOptions." + what);
  };
  if (!(noise_sigma >= 0) || !std::isfinite(noise_sigma))
    fail("noise_sigma must be finite and >= 0");
  if (!(threshold_sigmas > 0) || !std::isfinite(threshold_sigmas))
    fail("threshold_sigmas must be > 0");
  if (dilation_px < 0 || dilation_px > 64) fail("dilation_px must be in [0, 64]");
  if (min_views < 1) fail("min_views must be >= 1");
}

double EstimateNoiseSigma(const ImageF& radiance) {
  const std::size_t n = radiance.num_pixels();
  if (n == 0) return 0;
  std::vector<float> v(n);
  for (std::size_t p = 0; p < n; ++p) {
    v[p] =
        std::max({radiance.pixels[3 * p], radiance.pixels[3 * p + 1], radiance.pixels[3 * p + 2]});
  }
  // The darkest three quarters are background (the rig frames the fire to cover less than a quarter
  // of each image). Their RMS about zero, not their spread about the median: a dark sensor's noise
  // is clipped at black and quantised, so most background pixels read exactly 0 and a median
  // absolute deviation would say "no noise" while a third of them read one or two levels.
  const std::size_t half = std::max<std::size_t>(1, 3 * n / 4);
  std::nth_element(v.begin(), v.begin() + (half - 1), v.end());
  double sum = 0;
  for (std::size_t i = 0; i < half; ++i) sum += double(v[i]) * v[i];
  return std::sqrt(sum / half);
}

std::vector<std::uint8_t> DilateMask(const std::vector<std::uint8_t>& mask, int width, int height,
                                     int radius) {
  if (radius <= 0) return mask;
  // Separable square dilation (Chebyshev radius): rows, then columns.
  std::vector<std::uint8_t> tmp(mask.size(), 0), out(mask.size(), 0);
  for (int y = 0; y < height; ++y) {
    int last = -1000000;
    for (int x = 0; x < width; ++x) {
      if (mask[y * width + x]) last = x;
      if (x - last <= radius) tmp[y * width + x] = 1;
    }
    last = 1000000;
    for (int x = width - 1; x >= 0; --x) {
      if (mask[y * width + x]) last = x;
      if (last - x <= radius) tmp[y * width + x] = 1;
    }
  }
  for (int x = 0; x < width; ++x) {
    int last = -1000000;
    for (int y = 0; y < height; ++y) {
      if (tmp[y * width + x]) last = y;
      if (y - last <= radius) out[y * width + x] = 1;
    }
    last = 1000000;
    for (int y = height - 1; y >= 0; --y) {
      if (tmp[y * width + x]) last = y;
      if (last - y <= radius) out[y * width + x] = 1;
    }
  }
  return out;
}

VisualHull ComputeVisualHull(const GridGeometry& grid, const std::vector<RigCamera>& cameras,
                             const std::vector<LinearFrame>& frames,
                             const VisualHullOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  options.Validate();
  grid.Validate();
  if (cameras.size() != frames.size()) {
    throw std::invalid_argument("visual hull: " + std::to_string(frames.size()) + " frames for " +
                                std::to_string(cameras.size()) + " cameras");
  }
  const std::size_t ncam = cameras.size();
  VisualHull hull;
  hull.fire_mask.resize(ncam);
  hull.noise_sigma.resize(ncam);
  hull.threshold.resize(ncam);
  hull.fire_pixel_fraction.resize(ncam);
  hull.cameras_seeing_box.assign(ncam, 0);
  const Box3 box = grid.box();
  for (std::size_t c = 0; c < ncam; ++c) {
    const CameraModel& cam = cameras[c].model;
    const LinearFrame& f = frames[c];
    if (f.radiance.width != cam.width() || f.radiance.height != cam.height()) {
      throw std::invalid_argument(
          "camera '" + cameras[c].name + "': frame is " + std::to_string(f.radiance.width) + "x" +
          std::to_string(f.radiance.height) + ", the camera model's imager is " +
          std::to_string(cam.width()) + "x" + std::to_string(cam.height()));
    }
    double sigma = options.noise_sigma > 0 ? options.noise_sigma : EstimateNoiseSigma(f.radiance);
    // At least one 8-bit step above black, wherever the sensor is noise-free.
    const double one_step = SrgbDecode(1.0 / 255.0) * f.full_scale;
    hull.noise_sigma[c] = sigma;
    hull.threshold[c] = std::max(options.threshold_sigmas * sigma, 0.99 * one_step);
    std::vector<std::uint8_t> fire(f.radiance.num_pixels(), 0);
    for (std::size_t p = 0; p < fire.size(); ++p) {
      float m = std::max(
          {f.radiance.pixels[3 * p], f.radiance.pixels[3 * p + 1], f.radiance.pixels[3 * p + 2]});
      fire[p] = m > hull.threshold[c] ? 1 : 0;
    }
    // Dilate by the projected size of a voxel at the box centre, plus the margin asked for.
    const Eigen::Vector3d center_in_cam = cam.cam_from_rig() * box.center();
    const double focal =
        cam.intrinsics().size() >= 2 ? std::max(cam.intrinsics()[0], cam.intrinsics()[1]) : 1.0;
    const double voxel_px = center_in_cam.z() > 0
                                ? focal * 0.87 * grid.voxel_size_m.maxCoeff() / center_in_cam.z()
                                : 0.0;
    const int radius = options.dilation_px + static_cast<int>(std::ceil(std::min(voxel_px, 64.0)));
    hull.fire_mask[c] = DilateMask(fire, cam.width(), cam.height(), radius);
    std::size_t lit = std::count(hull.fire_mask[c].begin(), hull.fire_mask[c].end(), 1);
    hull.fire_pixel_fraction[c] = double(lit) / std::max<std::size_t>(1, fire.size());
  }

  hull.voxel_inside.assign(grid.num_voxels(), 0);
  std::vector<std::atomic<int>> sees(ncam);
  for (auto& s : sees) s = 0;
  std::atomic<std::size_t> inside{0};
  const int nx = grid.dims.x(), ny = grid.dims.y();
  tbb::parallel_for(
      tbb::blocked_range<int>(0, grid.dims.z()), [&](const tbb::blocked_range<int>& r) {
        std::vector<Eigen::Vector3d> points(static_cast<std::size_t>(nx) * ny);
        std::vector<int> fire_votes(points.size()), background_votes(points.size()),
            visible(points.size());
        std::vector<int> local_sees(ncam, 0);
        std::size_t local_inside = 0;
        for (int k = r.begin(); k < r.end(); ++k) {
          for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i)
              points[static_cast<std::size_t>(j) * nx + i] = grid.VoxelCenter(i, j, k);
          std::fill(fire_votes.begin(), fire_votes.end(), 0);
          std::fill(background_votes.begin(), background_votes.end(), 0);
          std::fill(visible.begin(), visible.end(), 0);
          for (std::size_t c = 0; c < ncam; ++c) {
            const CameraModel& cam = cameras[c].model;
            std::vector<Eigen::Vector2d> q = cam.Project(points);
            for (std::size_t n = 0; n < points.size(); ++n) {
              if (!cam.InFront(points[n]) || !q[n].allFinite()) continue;
              const long x = std::lround(q[n].x()), y = std::lround(q[n].y());
              if (x < 0 || y < 0 || x >= cam.width() || y >= cam.height()) continue;
              ++visible[n];
              local_sees[c] = 1;
              if (hull.fire_mask[c][static_cast<std::size_t>(y) * cam.width() + x]) {
                ++fire_votes[n];
              } else {
                ++background_votes[n];
              }
            }
          }
          for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) {
              const std::size_t n = static_cast<std::size_t>(j) * nx + i;
              const int need = std::min(options.min_views, visible[n]);
              if (visible[n] > 0 && background_votes[n] == 0 && fire_votes[n] >= need) {
                hull.voxel_inside[grid.Flat(i, j, k)] = 1;
                ++local_inside;
              }
            }
        }
        inside += local_inside;
        for (std::size_t c = 0; c < ncam; ++c)
          if (local_sees[c]) sees[c] = 1;
      });
  hull.voxels_inside = inside;
  hull.voxel_fraction = double(hull.voxels_inside) / grid.num_voxels();
  for (std::size_t c = 0; c < ncam; ++c) hull.cameras_seeing_box[c] = sees[c];
  hull.time_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  return hull;
}

}  // namespace flamerig
