#include "tomography/visual_hull.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <exception>
#include <stdexcept>

#include "core/error.h"
#include "core/srgb.h"

namespace flamerig {

LinearFrame DecodeSrgb8(const ImageU8& image, double exposure) {
  if (!(exposure > 0) || !std::isfinite(exposure)) {
    throw InputError("exposure = " + std::to_string(exposure) + " must be finite and > 0");
  }
  if (image.channels != 1 && image.channels != 3) {
    throw InputError("an 8-bit frame must have 1 or 3 channels, not " +
                     std::to_string(image.channels));
  }
  const auto& table = SrgbU8ToLinearTable();
  LinearFrame f;
  f.radiance = ImageF(image.width, image.height, 3);
  f.saturated.assign(image.num_pixels(), 0);
  f.full_scale = 1.0 / exposure;
  f.quantum = table[1] / exposure;
  for (std::size_t p = 0; p < image.num_pixels(); ++p) {
    for (int c = 0; c < 3; ++c) {
      std::uint8_t v = image.pixels[p * image.channels + (image.channels == 1 ? 0 : c)];
      f.radiance.pixels[3 * p + c] = static_cast<float>(table[v] / exposure);
      if (v == 255) f.saturated[p] = 1;
    }
  }
  return f;
}

LinearFrame BinFrame(const LinearFrame& frame, int factor) {
  const int w = frame.radiance.width, h = frame.radiance.height;
  if (factor < 1 || factor > w || factor > h)
    throw InputError("binning " + std::to_string(factor) + "x" + std::to_string(factor) + " of a " +
                     std::to_string(w) + "x" + std::to_string(h) + " frame");
  if (factor == 1) return frame;
  const int bw = w / factor, bh = h / factor, nc = frame.radiance.channels;
  LinearFrame out;
  out.radiance = ImageF(bw, bh, nc);
  out.saturated.assign(static_cast<std::size_t>(bw) * bh, 0);
  out.full_scale = frame.full_scale;
  out.quantum = frame.quantum;
  const float share = 1.0f / (factor * factor);
  for (int by = 0; by < bh; ++by)
    for (int bx = 0; bx < bw; ++bx) {
      const std::size_t q = static_cast<std::size_t>(by) * bw + bx;
      for (int y = by * factor; y < (by + 1) * factor; ++y)
        for (int x = bx * factor; x < (bx + 1) * factor; ++x) {
          const std::size_t p = static_cast<std::size_t>(y) * w + x;
          for (int c = 0; c < nc; ++c)
            out.radiance.pixels[q * nc + c] += share * frame.radiance.pixels[p * nc + c];
          if (!frame.saturated.empty() && frame.saturated[p]) out.saturated[q] = 1;
        }
    }
  return out;
}

LinearFrame DecodeLinear16(const ImageU16& image, double exposure, double white) {
  if (!(exposure > 0) || !std::isfinite(exposure)) {
    throw InputError("exposure = " + std::to_string(exposure) + " must be finite and > 0");
  }
  if (!(white > 0)) throw InputError("white level must be > 0");
  if (image.channels != 1 && image.channels != 3) {
    throw InputError("a 16-bit frame must have 1 or 3 channels");
  }
  LinearFrame f;
  f.radiance = ImageF(image.width, image.height, 3);
  f.saturated.assign(image.num_pixels(), 0);
  f.full_scale = 1.0 / exposure;
  f.quantum = std::min(1.0 / white, 1.0) / exposure;
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
  auto fail = [](const std::string& what) { throw InputError("VisualHullOptions." + what); };
  if (!(noise_sigma >= 0) || !std::isfinite(noise_sigma))
    fail("noise_sigma must be finite and >= 0");
  if (!(threshold_sigmas > 0) || !std::isfinite(threshold_sigmas))
    fail("threshold_sigmas must be > 0");
  if (dilation_px < 0 || dilation_px > 64) fail("dilation_px must be in [0, 64]");
  if (min_views < 1) fail("min_views must be >= 1");
  if (min_speck_px < -1 || min_speck_px > 1000000)
    fail("min_speck_px must be in [-1, 1000000] (-1: from the voxel size)");
}

double EstimateNoiseSigma(const ImageF& radiance) {
  const std::size_t n = radiance.num_pixels();
  if (n == 0) return 0;
  std::vector<float> v(n);
  bool grey = true;
  for (std::size_t p = 0; p < n; ++p) {
    const float* c = &radiance.pixels[3 * p];
    v[p] = std::max({c[0], c[1], c[2]});
    grey = grey && c[0] == c[1] && c[1] == c[2];
  }
  if (grey) {
    // A zero-mean Gaussian clipped at 0: its 75th percentile is 0.6745 sigma. Of all the pixels
    // the fire lifts it (a tenth of the frame on fire: 1.35 sigma), so it is taken again over the
    // pixels below five of the first estimate, the background.
    auto q75 = [](std::vector<float>* w) {
      const std::size_t q = std::min(w->size() - 1, 3 * w->size() / 4);
      std::nth_element(w->begin(), w->begin() + q, w->end());
      return std::max(0.0, double((*w)[q]) / 0.6745);
    };
    const double first = q75(&v);
    v.erase(std::remove_if(v.begin(), v.end(), [&](float x) { return x > 5 * first; }), v.end());
    return v.empty() ? first : q75(&v);
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

double VoxelFootprintPx(const GridGeometry& grid, const RigCamera& camera) {
  const CameraModel& cam = camera.model;
  const Eigen::Vector3d center_in_cam = cam.cam_from_rig() * grid.box().center();
  const double focal =
      cam.intrinsics().size() >= 2 ? std::max(cam.intrinsics()[0], cam.intrinsics()[1]) : 1.0;
  return center_in_cam.z() > 0 ? focal * grid.voxel_size_m.maxCoeff() / center_in_cam.z() : 0.0;
}

std::pair<std::size_t, std::size_t> RemoveSpecks(std::vector<std::uint8_t>* mask, int width,
                                                 int height, int min_pixels) {
  if (min_pixels <= 1 || width <= 0 || height <= 0) return {0, 0};
  if (mask->size() != static_cast<std::size_t>(width) * height)
    throw InputError("RemoveSpecks: the mask is not width x height");
  cv::Mat binary(height, width, CV_8U, mask->data());
  cv::Mat labels, stats, centroids;
  const int n = cv::connectedComponentsWithStats(binary, labels, stats, centroids, 8, CV_32S);
  std::vector<std::uint8_t> speck(n, 0);
  std::size_t regions = 0, pixels = 0;
  for (int l = 1; l < n; ++l) {
    const int area = stats.at<int>(l, cv::CC_STAT_AREA);
    if (area < min_pixels) {
      speck[l] = 1;
      ++regions;
      pixels += area;
    }
  }
  if (regions == 0) return {0, 0};
  for (int y = 0; y < height; ++y) {
    const int* row = labels.ptr<int>(y);
    for (int x = 0; x < width; ++x)
      if (speck[row[x]]) (*mask)[static_cast<std::size_t>(y) * width + x] = 0;
  }
  return {regions, pixels};
}

FireMask ComputeFireMask(const GridGeometry& grid, const RigCamera& camera, const LinearFrame& f,
                         const VisualHullOptions& options, bool keep_labels) {
  const CameraModel& cam = camera.model;
  if (f.radiance.width != cam.width() || f.radiance.height != cam.height()) {
    throw DataError("camera '" + camera.name + "': frame is " + std::to_string(f.radiance.width) +
                    "x" + std::to_string(f.radiance.height) + ", the camera model's imager is " +
                    std::to_string(cam.width()) + "x" + std::to_string(cam.height()));
  }
  FireMask out;
  out.noise_estimate =
      options.noise_sigma > 0 ? options.noise_sigma : EstimateNoiseSigma(f.radiance);
  // Never below one quantisation step at black: a background that reads exactly 0 says nothing
  // about the noise, and compression leaves 1-2 code specks on it.
  const double quantum = f.quantum > 0 ? f.quantum : SrgbDecode(1.0 / 255.0) * f.full_scale;
  out.noise_sigma = std::max(out.noise_estimate, quantum);
  out.threshold = options.threshold_sigmas * out.noise_sigma;
  std::vector<std::uint8_t> fire(f.radiance.num_pixels(), 0);
  for (std::size_t p = 0; p < fire.size(); ++p) {
    const float m = std::max(
        {f.radiance.pixels[3 * p], f.radiance.pixels[3 * p + 1], f.radiance.pixels[3 * p + 2]});
    fire[p] = m > out.threshold ? 1 : 0;
  }
  const double voxel_px = VoxelFootprintPx(grid, camera);
  out.min_speck_px = options.min_speck_px >= 0
                         ? options.min_speck_px
                         : std::max(2, static_cast<int>(0.5 * std::min(voxel_px * voxel_px, 1e6)));
  std::vector<std::uint8_t> before;
  if (keep_labels) before = fire;
  const auto [regions, pixels] = RemoveSpecks(&fire, cam.width(), cam.height(), out.min_speck_px);
  out.speck_regions = regions;
  out.speck_pixels = pixels;
  out.fire_pixels = static_cast<std::size_t>(std::count(fire.begin(), fire.end(), 1));
  if (keep_labels) {
    out.labels.assign(fire.size(), 0);
    for (std::size_t p = 0; p < fire.size(); ++p)
      out.labels[p] = fire[p] ? kMaskFire : before[p] ? kMaskSpeck : 0;
  }
  // Dilate by the projected radius of a voxel at the box centre (half its diagonal), plus the
  // margin asked for.
  const int radius =
      options.dilation_px + static_cast<int>(std::ceil(std::min(0.87 * voxel_px, 64.0)));
  out.mask = DilateMask(fire, cam.width(), cam.height(), radius);
  const std::size_t lit = std::count(out.mask.begin(), out.mask.end(), 1);
  out.fraction = double(lit) / std::max<std::size_t>(1, fire.size());
  return out;
}

std::vector<std::uint8_t> HullSilhouette(const std::vector<std::uint8_t>& voxel_inside,
                                         const std::vector<std::int32_t>& projections, int width,
                                         int height, int radius_px) {
  if (voxel_inside.size() != projections.size())
    throw InputError("HullSilhouette: projections do not match the hull");
  std::vector<std::uint8_t> dots(static_cast<std::size_t>(width) * height, 0);
  for (std::size_t v = 0; v < voxel_inside.size(); ++v) {
    const std::int32_t p = projections[v];
    if (voxel_inside[v] && p >= 0 && static_cast<std::size_t>(p) < dots.size()) dots[p] = 1;
  }
  return DilateMask(dots, width, height, std::clamp(radius_px, 0, 64));
}

std::size_t VoxelProjections::bytes() const {
  std::size_t b = 0;
  for (const auto& p : pixel) b += p.size() * sizeof(std::int32_t);
  return b;
}

VoxelProjections ComputeVoxelProjections(const GridGeometry& grid,
                                         const std::vector<RigCamera>& cameras) {
  grid.Validate();
  VoxelProjections out;
  out.pixel.assign(cameras.size(), std::vector<std::int32_t>(grid.num_voxels(), -1));
  const int nx = grid.dims.x(), ny = grid.dims.y();
  tbb::parallel_for(
      tbb::blocked_range<int>(0, grid.dims.z()), [&](const tbb::blocked_range<int>& r) {
        std::vector<Eigen::Vector3d> points(static_cast<std::size_t>(nx) * ny);
        for (int k = r.begin(); k < r.end(); ++k) {
          for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i)
              points[static_cast<std::size_t>(j) * nx + i] = grid.VoxelCenter(i, j, k);
          for (std::size_t c = 0; c < cameras.size(); ++c) {
            const CameraModel& cam = cameras[c].model;
            const std::vector<Eigen::Vector2d> q = cam.Project(points);
            for (std::size_t n = 0; n < points.size(); ++n) {
              if (!cam.InFront(points[n]) || !q[n].allFinite()) continue;
              const long x = std::lround(q[n].x()), y = std::lround(q[n].y());
              if (x < 0 || y < 0 || x >= cam.width() || y >= cam.height()) continue;
              out.pixel[c][grid.Flat(static_cast<int>(n % nx), static_cast<int>(n / nx), k)] =
                  static_cast<std::int32_t>(y * cam.width() + x);
            }
          }
        }
      });
  return out;
}

VisualHull ComputeVisualHull(const GridGeometry& grid, const std::vector<RigCamera>& cameras,
                             const std::vector<LinearFrame>& frames,
                             const VisualHullOptions& options) {
  return ComputeVisualHull(grid, cameras, frames, options, ComputeVoxelProjections(grid, cameras));
}

VisualHull ComputeVisualHull(const GridGeometry& grid, const std::vector<RigCamera>& cameras,
                             const std::vector<LinearFrame>& frames,
                             const VisualHullOptions& options, const VoxelProjections& projections,
                             const std::vector<int>& projection_index) {
  const auto start = std::chrono::steady_clock::now();
  options.Validate();
  grid.Validate();
  std::vector<const std::vector<std::int32_t>*> table(cameras.size(), nullptr);
  for (std::size_t c = 0; c < cameras.size(); ++c) {
    const std::size_t k =
        projection_index.empty() ? c : static_cast<std::size_t>(projection_index[c]);
    if (k >= projections.pixel.size())
      throw InputError("visual hull: no projections for camera " + cameras[c].name);
    table[c] = &projections.pixel[k];
  }
  if (cameras.size() != frames.size()) {
    throw InputError("visual hull: " + std::to_string(frames.size()) + " frames for " +
                     std::to_string(cameras.size()) + " cameras");
  }
  const std::size_t ncam = cameras.size();
  VisualHull hull;
  hull.fire_mask.resize(ncam);
  hull.masks.resize(ncam);
  hull.cameras_seeing_box.assign(ncam, 0);
  // The cameras' masks are independent: computed in parallel, and the first camera's error (in
  // the rig's order, whatever the threads did) is the one reported.
  std::vector<std::exception_ptr> failed(ncam);
  tbb::parallel_for(std::size_t(0), ncam, [&](std::size_t c) {
    try {
      FireMask mask = ComputeFireMask(grid, cameras[c], frames[c], options);
      hull.fire_mask[c] = std::move(mask.mask);
      hull.masks[c] = std::move(mask);
    } catch (...) {
      failed[c] = std::current_exception();
    }
  });
  for (const std::exception_ptr& e : failed)
    if (e) std::rethrow_exception(e);

  hull.voxel_inside.assign(grid.num_voxels(), 0);
  std::vector<int> sees(ncam, 0);
  std::size_t inside = 0;
  for (std::size_t c = 0; c < ncam; ++c) {
    if (table[c]->size() != grid.num_voxels()) {
      throw InputError("visual hull: projections of camera '" + cameras[c].name +
                       "' do not match the grid");
    }
  }
  // Each voxel is visited once; counts per voxel are independent, so the loop is parallel.
  std::vector<std::uint8_t>& keep = hull.voxel_inside;
  std::vector<std::uint8_t> seen_by(ncam, 0);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, grid.num_voxels(), 4096),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t v = r.begin(); v < r.end(); ++v) {
                        // The first camera that sees background there rules the voxel out:
                        // most of the box is outside the hull, and most of it is ruled out by
                        // the first camera, so the others' tables are not read there.
                        int visible = 0, fire = 0, background = 0;
                        for (std::size_t c = 0; c < ncam && background == 0; ++c) {
                          const std::int32_t p = (*table[c])[v];
                          if (p < 0) continue;
                          ++visible;
                          if (hull.fire_mask[c][p])
                            ++fire;
                          else
                            ++background;
                        }
                        const int need = std::min(options.min_views, visible);
                        keep[v] = visible > 0 && background == 0 && fire >= need;
                      }
                    });
  for (std::size_t v = 0; v < keep.size(); ++v) inside += keep[v];
  for (std::size_t c = 0; c < ncam; ++c) {
    for (std::int32_t p : *table[c]) {
      if (p >= 0) {
        sees[c] = 1;
        break;
      }
    }
  }
  hull.voxels_inside = inside;
  hull.voxel_fraction = double(hull.voxels_inside) / grid.num_voxels();
  for (std::size_t c = 0; c < ncam; ++c) hull.cameras_seeing_box[c] = sees[c];
  hull.time_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  return hull;
}

}  // namespace flamerig
