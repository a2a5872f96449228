#include "tomography/reconstruct.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <zlib.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <stdexcept>
#include <string>

#include "core/atomic_file.h"
#include "core/error.h"
#include "core/log.h"
#include "core/memory.h"
#include "core/srgb.h"
#include "tomography/ray_march.h"

namespace flamerig {
namespace {

// Whether any valid ray of `rays` enters `box` in front of its origin.
bool AnyRayMeetsBox(const CameraRays& rays, const Box3& box) {
  double t_enter, t_exit;
  for (const Ray& r : rays.rays())
    if (r.valid && IntersectBox(r.origin_in_rig, r.direction_in_rig, box.min_in_rig, box.max_in_rig,
                                &t_enter, &t_exit))
      return true;
  return false;
}

std::string FormatPoint(const Eigen::Vector3d& p) {
  char text[96];
  std::snprintf(text, sizeof text, "(%.3g, %.3g, %.3g)", p.x(), p.y(), p.z());
  return text;
}

using Clock = std::chrono::steady_clock;
double Ms(Clock::time_point since) {
  return std::chrono::duration<double, std::milli>(Clock::now() - since).count();
}

// Box dilation of a voxel mask by `r` voxels along each axis (separable).
std::vector<std::uint8_t> DilateVoxels(const GridGeometry& g, const std::vector<std::uint8_t>& mask,
                                       int r) {
  if (r <= 0) return mask;
  std::vector<std::uint8_t> a = mask, b(mask.size());
  const int d[3] = {g.dims.x(), g.dims.y(), g.dims.z()};
  for (int axis = 0; axis < 3; ++axis) {
    std::fill(b.begin(), b.end(), 0);
    for (int k = 0; k < d[2]; ++k)
      for (int j = 0; j < d[1]; ++j)
        for (int i = 0; i < d[0]; ++i) {
          if (!a[g.Flat(i, j, k)]) continue;
          int idx[3] = {i, j, k};
          for (int o = -r; o <= r; ++o) {
            int t[3] = {idx[0], idx[1], idx[2]};
            t[axis] += o;
            if (t[axis] < 0 || t[axis] >= d[axis]) continue;
            b[g.Flat(t[0], t[1], t[2])] = 1;
          }
        }
    std::swap(a, b);
  }
  return a;
}

bool Contains(const std::vector<std::uint8_t>& outer, const std::vector<std::uint8_t>& inner) {
  if (outer.size() != inner.size()) return false;
  for (std::size_t i = 0; i < inner.size(); ++i)
    if (inner[i] && !outer[i]) return false;
  return true;
}

// (inner pixels not in outer, inner pixels).
std::pair<std::size_t, std::size_t> CountOutside(const std::vector<std::uint8_t>& outer,
                                                 const std::vector<std::uint8_t>& inner) {
  std::size_t outside = 0, total = 0;
  for (std::size_t i = 0; i < inner.size(); ++i) {
    total += inner[i] != 0;
    outside += inner[i] && (i >= outer.size() || !outer[i]);
  }
  return {outside, total};
}

std::vector<std::uint8_t> Union(const std::vector<std::uint8_t>& a,
                                const std::vector<std::uint8_t>& b) {
  if (a.size() != b.size()) return b;
  std::vector<std::uint8_t> u(a.size());
  for (std::size_t i = 0; i < a.size(); ++i) u[i] = a[i] | b[i];
  return u;
}

std::string HexKey(std::uint64_t key) {
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%016llx", static_cast<unsigned long long>(key));
  return buffer;
}

}  // namespace

void ReconstructOptions::Validate() const {
  auto fail = [](const std::string& what) { throw InputError("ReconstructOptions." + what); };
  if (resolution < 1 || resolution > 1024) fail("resolution must be in [1, 1024]");
  if (!(exposure > 0) || !std::isfinite(exposure)) fail("exposure must be finite and > 0");
  if (coarse_iterations < 1) fail("coarse_iterations must be >= 1");
  if (bin < 1 || bin > 16) fail("bin must be in [1, 16]");
  if (!(warm_stagnation_tolerance >= 0 && warm_stagnation_tolerance <= 1) &&
      warm_stagnation_tolerance != -1)
    fail("warm_stagnation_tolerance must be in [0, 1], or -1 for the solve's own");
  if (two_view_fine_iterations < 1 && two_view_fine_iterations != -1)
    fail("two_view_fine_iterations must be >= 1, or -1 for the solve's own rules");
  if (envelope_margin_voxels < 0 || envelope_margin_voxels > 16)
    fail("envelope_margin_voxels must be in [0, 16]");
  if (!(envelope_pixel_tolerance >= 0) || !(envelope_pixel_tolerance <= 0.1))
    fail("envelope_pixel_tolerance must be in [0, 0.1]");
  hull.Validate();
  matrix.Validate();
  solve.Validate();
}

std::string ReconstructSummary::BriefReport() const {
  std::ostringstream s;
  s.precision(3);
  s << "grid " << grid.dims.x() << "x" << grid.dims.y() << "x" << grid.dims.z();
  if (bin > 1) s << ", pixels binned " << bin << "x" << bin;
  s << ", hull " << voxel_fraction_in_hull * 100 << "% of voxels (fire pixels per camera:";
  for (const CameraMaskSummary& m : masks) {
    s << " " << m.camera << (m.held_out ? " (held out)" : "") << " " << m.fraction * 100
      << "% (noise " << m.noise_sigma;
    if (m.speck_regions)
      s << ", " << m.speck_regions << " specks of " << m.speck_pixels << " px removed";
    s << ")";
  }
  s << "), matrix " << matrix_rows << "x" << matrix_cols << " (" << matrix_nnz << " non-zeros, "
    << matrix_bytes / 1048576.0 << " MB, " << matrix_source << ", " << matrix_build_ms << " ms)";
  if (fire_pixels_outside_envelope > 0)
    s << ", " << fire_pixels_outside_envelope << " fire pixels outside its envelope left out";
  s << ", light on the box's faces " << box_face_light_share * 100 << "%";
  if (!box_faces_lit.empty()) s << " (" << box_faces_lit << ")";
  for (const auto& solve : solves) s << "; " << solve.BriefReport();
  if (!stop_camera.empty()) s << "; stopped on " << stop_camera;
  if (holdout_rms >= 0)
    s << "; held-out " << holdout_camera << " RMS " << holdout_rms << " (relative "
      << holdout_relative << ")";
  for (const auto& skipped : skipped_cameras) s << "; skipped " << skipped;
  s << "; total " << total_ms << " ms (decode " << decode_ms << ", hull " << hull_ms << ", matrix "
    << matrix_ms << ", solve " << solve_ms;
  if (holdout_ms > 0) s << ", scoring the held-out camera " << holdout_ms;
  s << "), matrices and vectors " << working_bytes / 1048576.0 << " MB, process peak "
    << process_peak_bytes / 1048576.0 << " MB";
  return s.str();
}

struct Reconstructor::Level {
  GridGeometry grid;
  bool has_matrix = false;
  SystemMatrix a;
  std::vector<std::uint8_t> envelope_voxels;
  std::vector<std::vector<std::uint8_t>> envelope_pixels;  // per solve camera
  std::vector<int> cameras;  // the rig indices the matrix was built for
  SystemMatrix stop;
  std::vector<std::uint8_t> stop_pixels;  // the stop camera's pixels it was built for
  bool has_stop = false;
  VoxelProjections projections;  // every rig camera, computed on first use
};

Reconstructor::Reconstructor(const Rig& rig, const ReconstructOptions& options)
    : rig_(rig), options_(options) {
  options_.Validate();
  if (rig_.cameras.empty()) throw InputError("Reconstructor: the rig has no cameras");
  grid_ = GridGeometry::FromBox(rig_.box, options_.resolution);
  for (auto& c : rig_.cameras) {
    frame_sizes_.emplace_back(c.model.width(), c.model.height());
    if (options_.bin > 1) {
      try {
        c.model = c.model.Binned(options_.bin);
      } catch (const InputError& e) {
        throw InputError("ReconstructOptions.bin: camera '" + c.name + "': " + e.what());
      }
    }
    rays_.push_back(std::make_unique<CameraRays>(c.model));
    if (!AnyRayMeetsBox(*rays_.back(), rig_.box)) {
      const Eigen::Vector3d eye = c.model.cam_from_rig().Inverse().translation;
      throw InputError(
          "camera '" + c.name + "' (at " + FormatPoint(eye) +
          " m in the rig frame) sees none of the reconstruction box (" +
          FormatPoint(rig_.box.min_in_rig) + " to " + FormatPoint(rig_.box.max_in_rig) +
          " m): its pose or intrinsics are wrong, or the box is not where the fire is");
    }
  }
  auto find = [&](const std::string& name, const char* field) {
    if (name.empty()) return -1;
    const int index = rig_.FindCamera(name);
    if (index < 0)
      throw InputError(std::string("ReconstructOptions.") + field + ": no camera named '" + name +
                       "' in rig '" + rig_.name + "'");
    return index;
  };
  holdout_index_ = find(options_.holdout_camera, "holdout_camera");
  stop_index_ = find(options_.stop_camera, "stop_camera");
  if (holdout_index_ >= 0 && holdout_index_ == stop_index_)
    throw InputError("ReconstructOptions: camera '" + options_.holdout_camera +
                     "' cannot both stop the solve and score it (give another stop camera)");
  fine_ = std::make_unique<Level>();
  fine_->grid = grid_;
  if (options_.coarse_to_fine && options_.resolution >= 16) {
    coarse_ = std::make_unique<Level>();
    coarse_->grid = GridGeometry::FromBox(rig_.box, options_.resolution / 2);
  }
  state_key_ = StateKey();
}

Reconstructor::~Reconstructor() = default;
Reconstructor::Reconstructor(Reconstructor&&) noexcept = default;
Reconstructor& Reconstructor::operator=(Reconstructor&&) noexcept = default;

FireVolume Reconstructor::Reconstruct(const std::vector<ImageU8>& images,
                                      ReconstructSummary* summary, const FireVolume* warm_start,
                                      const ProgressCallback& progress) {
  const auto start = Clock::now();
  if (images.size() != rig_.cameras.size()) {
    throw InputError("reconstruct: " + std::to_string(images.size()) + " images for " +
                     std::to_string(rig_.cameras.size()) + " cameras of rig '" + rig_.name + "'");
  }
  std::vector<LinearFrame> frames(images.size());
  for (std::size_t c = 0; c < images.size(); ++c) {
    if (images[c].empty()) continue;
    try {
      frames[c] = DecodeSrgb8(images[c], options_.exposure);
    } catch (const InputError& e) {
      throw InputError("camera '" + rig_.cameras[c].name + "': " + e.what());
    }
  }
  const double decode_ms = Ms(start);
  FireVolume v = Reconstruct(frames, summary, warm_start, progress);
  if (summary) {
    summary->decode_ms = decode_ms;
    summary->total_ms += decode_ms;
  }
  return v;
}

FireVolume Reconstructor::Reconstruct(const std::vector<LinearFrame>& input_frames,
                                      ReconstructSummary* summary_out, const FireVolume* warm_start,
                                      const ProgressCallback& progress) {
  const auto start = Clock::now();
  ReconstructSummary summary;
  summary.grid = grid_;
  summary.bin = options_.bin;
  if (input_frames.size() != rig_.cameras.size()) {
    throw InputError("reconstruct: " + std::to_string(input_frames.size()) + " frames for " +
                     std::to_string(rig_.cameras.size()) + " cameras");
  }
  std::vector<LinearFrame> binned;
  if (options_.bin > 1) {
    binned.resize(input_frames.size());
    for (std::size_t c = 0; c < input_frames.size(); ++c) {
      const LinearFrame& f = input_frames[c];
      if (f.radiance.empty()) continue;
      if (f.radiance.width != frame_sizes_[c].first || f.radiance.height != frame_sizes_[c].second)
        throw DataError("camera '" + rig_.cameras[c].name + "': frame is " +
                        std::to_string(f.radiance.width) + "x" + std::to_string(f.radiance.height) +
                        ", its model's imager is " + std::to_string(frame_sizes_[c].first) + "x" +
                        std::to_string(frame_sizes_[c].second));
      binned[c] = BinFrame(f, options_.bin);
    }
  }
  const std::vector<LinearFrame>& frames = options_.bin > 1 ? binned : input_frames;
  // Cameras taking part in the solve.
  std::vector<int> solve_cameras;
  for (std::size_t c = 0; c < frames.size(); ++c) {
    const auto& cam = rig_.cameras[c];
    if (frames[c].radiance.empty()) {
      summary.skipped_cameras.push_back(cam.name + " (no frame)");
      continue;
    }
    if (frames[c].radiance.width != cam.model.width() ||
        frames[c].radiance.height != cam.model.height()) {
      throw DataError("camera '" + cam.name + "': frame is " +
                      std::to_string(frames[c].radiance.width) + "x" +
                      std::to_string(frames[c].radiance.height) + ", its model's imager is " +
                      std::to_string(cam.model.width()) + "x" + std::to_string(cam.model.height()));
    }
    if (static_cast<int>(c) == holdout_index_ || static_cast<int>(c) == stop_index_) continue;
    solve_cameras.push_back(static_cast<int>(c));
  }
  if (solve_cameras.empty()) {
    throw DataError("reconstruct: no camera with a usable frame to reconstruct from");
  }
  const bool use_holdout = holdout_index_ >= 0 && !frames[holdout_index_].radiance.empty();
  if (use_holdout) summary.holdout_camera = rig_.cameras[holdout_index_].name;
  const bool use_stop = stop_index_ >= 0 && !frames[stop_index_].radiance.empty();
  if (use_stop) summary.stop_camera = rig_.cameras[stop_index_].name;

  std::vector<RigCamera> cams;
  std::vector<LinearFrame> solve_frames;
  std::vector<const CameraRays*> solve_rays;
  for (int c : solve_cameras) {
    cams.push_back(rig_.cameras[c]);
    solve_frames.push_back(frames[c]);
    solve_rays.push_back(rays_[c].get());
  }

  // The warm start on the fine grid: the previous frame's own emission when it has the same voxels
  // (read in place, not copied: 25 MB at 128^3), else resampled.
  std::vector<float> resampled_start;
  const std::vector<float>* x_fine_start = nullptr;
  if (warm_start && !warm_start->emission_rgb.empty()) {
    if (warm_start->emission_rgb.size() != warm_start->geometry.num_voxels() * 3)
      throw InputError("reconstruct: the warm start's emission has " +
                       std::to_string(warm_start->emission_rgb.size()) + " values for " +
                       std::to_string(warm_start->geometry.num_voxels()) + " voxels (3 each)");
    if (warm_start->geometry.SameVoxels(grid_)) {
      x_fine_start = &warm_start->emission_rgb;
    } else {
      resampled_start = ResampleEmission(warm_start->geometry, warm_start->emission_rgb, grid_);
      x_fine_start = &resampled_start;
    }
  }
  const bool have_start = x_fine_start != nullptr;

  std::vector<float> previous_level_emission;  // full-grid emission of the coarse level
  GridGeometry previous_grid;
  std::vector<Level*> levels;
  if (coarse_ && !have_start) levels.push_back(coarse_.get());
  levels.push_back(fine_.get());
  std::size_t peak = 0;
  FireVolume out;
  for (Level* level : levels) {
    const bool is_fine = level == fine_.get();
    const GridGeometry& g = level->grid;
    auto t0 = Clock::now();
    if (level->projections.pixel.empty())
      level->projections = ComputeVoxelProjections(g, rig_.cameras);
    VisualHull hull =
        ComputeVisualHull(g, cams, solve_frames, options_.hull, level->projections, solve_cameras);
    summary.hull_ms += Ms(t0);
    if (is_fine) {
      summary.voxel_fraction_in_hull = hull.voxel_fraction;
      for (std::size_t c = 0; c < cams.size(); ++c) {
        CameraMaskSummary m;
        static_cast<FireMaskStats&>(m) = hull.masks[c];
        m.camera = cams[c].name;
        m.width = cams[c].model.width();
        m.height = cams[c].model.height();
        summary.masks.push_back(std::move(m));
      }
      std::vector<int> mask_cameras = solve_cameras;
      std::vector<const LinearFrame*> mask_frames;
      for (const LinearFrame& f : solve_frames) mask_frames.push_back(&f);
      for (const int left_out : {stop_index_, holdout_index_}) {
        if (left_out < 0 || frames[left_out].radiance.empty()) continue;
        const RigCamera& held = rig_.cameras[left_out];
        CameraMaskSummary m;
        static_cast<FireMaskStats&>(m) = ComputeFireMask(g, held, frames[left_out], options_.hull);
        m.camera = held.name;
        m.held_out = true;
        m.width = held.model.width();
        m.height = held.model.height();
        summary.masks.push_back(std::move(m));
        mask_cameras.push_back(left_out);
        mask_frames.push_back(&frames[left_out]);
      }
      if (options_.keep_masks)
        KeepMasks(g, level->projections, mask_cameras, mask_frames, hull, &summary.masks);
    }
    // Matrix: reuse while the hull fits the envelope it was built for.
    t0 = Clock::now();
    // A few fire pixels outside the envelope (a flicker at the edge, noise) do not force a rebuild:
    // their data are left out of this frame and counted.
    bool fits = level->has_matrix && level->cameras == solve_cameras &&
                Contains(level->envelope_voxels, hull.voxel_inside);
    std::size_t pixels_outside = 0;
    for (std::size_t c = 0; fits && c < cams.size(); ++c) {
      const auto [outside, fire] = CountOutside(level->envelope_pixels[c], hull.fire_mask[c]);
      fits = outside <= options_.envelope_pixel_tolerance * fire;
      pixels_outside += outside;
    }
    if (is_fine) summary.fire_pixels_outside_envelope = fits ? pixels_outside : 0;
    std::string source = "reused (envelope)";
    if (!fits) {
      std::vector<std::uint8_t> envelope =
          DilateVoxels(g, hull.voxel_inside, options_.envelope_margin_voxels);
      // The envelope: this frame's hull and masks grown by a margin, so that the next frames of a
      // moving fire still fit (a voxel margin and the pixels it projects to).
      std::vector<std::vector<std::uint8_t>> pixels(cams.size());
      for (std::size_t c = 0; c < cams.size(); ++c) {
        const double f = cams[c].model.intrinsics()[0];
        const double z = std::max(1e-6, (cams[c].model.cam_from_rig() * g.box().center()).z());
        const int radius = static_cast<int>(std::ceil(
            std::min(64.0, options_.envelope_margin_voxels * f * g.voxel_size_m.maxCoeff() / z)));
        pixels[c] =
            DilateMask(hull.fire_mask[c], cams[c].model.width(), cams[c].model.height(), radius);
      }
      if (level->has_matrix && level->cameras == solve_cameras) {
        envelope = Union(level->envelope_voxels, envelope);
        for (std::size_t c = 0; c < cams.size(); ++c)
          pixels[c] = Union(level->envelope_pixels[c], pixels[c]);
      }
      source = MakeMatrix(level, solve_cameras, std::move(pixels), std::move(envelope));
    }
    const SystemMatrix& a = level->a;
    if (use_stop && !level->has_stop) {
      // The held-out camera is scored where it sees fire (its own mask, dilated like the others): the
      // rest of its image is background that the hull already keeps dark.
      FireMask mask =
          ComputeFireMask(g, rig_.cameras[stop_index_], frames[stop_index_], options_.hull);
      MakeStopMatrix(level, std::move(mask.mask));
    }
    summary.matrix_ms += Ms(t0);
    if (is_fine) {
      summary.matrix_rows = a.rows();
      summary.matrix_cols = a.cols();
      summary.matrix_nnz = a.nnz();
      summary.matrix_stored_entries = a.stored_entries();
      summary.matrix_bytes = a.bytes();
      summary.matrix_source = source;
      summary.matrix_build_ms = a.build_ms();
    }

    // The data.
    SolveProblem problem;
    problem.a = &a;
    problem.grid = &g;
    problem.b.resize(a.rows() * 3);
    problem.lower_bound_rows.resize(a.rows());
    std::vector<int> camera_slot(rig_.cameras.size(), -1);
    for (std::size_t s = 0; s < solve_cameras.size(); ++s)
      camera_slot[solve_cameras[s]] = static_cast<int>(s);
    for (std::size_t r = 0; r < a.rows(); ++r) {
      const LinearFrame& f = solve_frames[a.row_camera(r)];
      const std::size_t p = static_cast<std::size_t>(a.row_pixel(r));
      for (int ch = 0; ch < 3; ++ch) problem.b[r * 3 + ch] = f.radiance.pixels[3 * p + ch];
      problem.lower_bound_rows[r] = f.saturated[p];
      // The dilated margin's pixels that the mask calls background are black: what a codec or
      // the noise left there is not light for the solve to explain.
      if (options_.black_below_threshold) {
        const float* v = &f.radiance.pixels[3 * p];
        if (std::max({v[0], v[1], v[2]}) <= hull.masks[a.row_camera(r)].threshold)
          for (int ch = 0; ch < 3; ++ch) problem.b[r * 3 + ch] = 0.0f;
      }
    }
    problem.active_cols.resize(a.cols());
    for (std::size_t j = 0; j < a.cols(); ++j)
      problem.active_cols[j] = hull.voxel_inside[a.col_voxel(j)];
    // Grey data (mono cameras: every pixel's channels equal) are solved as one channel, a third
    // of the work, and the result copied to the three.
    bool grey = true;
    for (std::size_t r = 0; r < a.rows() && grey; ++r)
      grey = problem.b[r * 3] == problem.b[r * 3 + 1] && problem.b[r * 3] == problem.b[r * 3 + 2];
    if (grey) {
      std::vector<float> one(a.rows());
      for (std::size_t r = 0; r < a.rows(); ++r) one[r] = problem.b[r * 3];
      problem.b = std::move(one);  // the three channels' memory goes
      problem.channels = 1;
    }
    const int nc = problem.channels;

    // Initial guess (from colour emission to grey: the channels' mean).
    std::vector<float> x(a.cols() * nc, 0.0f);
    const std::vector<float>* full = nullptr;
    std::vector<float> resampled;
    if (is_fine && have_start) {
      full = x_fine_start;
    } else if (!previous_level_emission.empty()) {
      resampled = ResampleEmission(previous_grid, previous_level_emission, g);
      full = &resampled;
    }
    if (full) {
      for (std::size_t j = 0; j < a.cols(); ++j) {
        const float* e = &(*full)[a.col_voxel(j) * 3];
        if (grey)
          x[j] = (e[0] + e[1] + e[2]) / 3.0f;
        else
          for (int ch = 0; ch < 3; ++ch) x[j * 3 + ch] = e[ch];
      }
    }

    // Early stopping.
    SolveOptions solve_options = options_.solve;
    // A warm start from the previous frame is near its answer: OS-EM's later iterations fit noise
    // (ReconstructOptions::warm_stagnation_tolerance, with four cameras or more).
    if (is_fine && have_start && solve_options.stagnation_tolerance < 0 &&
        options_.warm_stagnation_tolerance >= 0 && solve_options.solver == "osem" &&
        solve_cameras.size() >= 4)
      solve_options.stagnation_tolerance = options_.warm_stagnation_tolerance;
    if (!is_fine)
      solve_options.max_iterations =
          std::min(solve_options.max_iterations, options_.coarse_iterations);
    // Two views' fine level refines a start (ReconstructOptions::two_view_fine_iterations): with
    // a solver that sweeps subsets (OS-EM, OS-SART), the solves it was measured on.
    if (is_fine && full && !use_stop && solve_cameras.size() <= 2 &&
        options_.two_view_fine_iterations > 0 &&
        FindTomographySolver(solve_options.solver).make(nc)->SweepsSubsets(problem, solve_options))
      solve_options.max_iterations =
          std::min(solve_options.max_iterations, options_.two_view_fine_iterations);
    if (solve_options.noise_sigma == 0 && !use_stop) {
      // The discrepancy principle needs the noise of the data actually fitted: the sensor noise
      // seen in the background plus 8-bit quantisation, whose step in radiance grows with the
      // pixel's level (the sRGB curve): variance q^2 / 12 with q the radiance of one 8-bit step at
      // that level.
      // Each row's share in parallel (three powers a value), summed in row order.
      std::vector<double> row_variance(a.rows(), 0.0);
      tbb::parallel_for(tbb::blocked_range<std::size_t>(0, a.rows(), 4096),
                        [&](const tbb::blocked_range<std::size_t>& range) {
                          for (std::size_t r = range.begin(); r < range.end(); ++r) {
                            if (problem.lower_bound_rows[r]) continue;
                            const double sigma = hull.masks[a.row_camera(r)].noise_estimate;
                            for (int ch = 0; ch < nc; ++ch) {
                              const double v =
                                  problem.b[r * nc + ch] * options_.exposure;  // camera signal
                              const double encoded = SrgbEncode(v);
                              const double q = (SrgbDecode(std::min(1.0, encoded + 0.5 / 255)) -
                                                SrgbDecode(std::max(0.0, encoded - 0.5 / 255))) /
                                               options_.exposure;
                              row_variance[r] += sigma * sigma + q * q / 12.0;
                            }
                          }
                        });
      double variance = 0;
      std::size_t counted = 0;
      for (std::size_t r = 0; r < a.rows(); ++r) {
        if (problem.lower_bound_rows[r]) continue;
        variance += row_variance[r];
        counted += nc;
      }
      solve_options.noise_sigma = counted ? std::sqrt(variance / counted) : 0.0;
    }
    HoldoutScorer scorer = nullptr;
    std::vector<float> hb;
    std::vector<std::uint8_t> hvalid;
    if (use_stop) {
      const SystemMatrix& h = level->stop;
      const LinearFrame& f = frames[stop_index_];
      // Its images in the solve's channels (a grey solve scores the stop camera's mean: its
      // frames are grey too when the rig is mono).
      hb.resize(h.rows() * nc);
      hvalid.resize(h.rows());
      for (std::size_t r = 0; r < h.rows(); ++r) {
        const std::size_t p = static_cast<std::size_t>(h.row_pixel(r));
        const float* v = &f.radiance.pixels[3 * p];
        if (nc == 1)
          hb[r] = (v[0] + v[1] + v[2]) / 3.0f;
        else
          for (int ch = 0; ch < 3; ++ch) hb[r * 3 + ch] = v[ch];
        hvalid[r] = !f.saturated[p];
      }
      scorer = [&h, &hb, &hvalid, nc](const std::vector<float>& xs) {
        std::vector<float> y(h.rows() * nc);
        h.Multiply(xs.data(), y.data(), nc);
        double sum = 0;
        std::size_t n = 0;
        for (std::size_t r = 0; r < h.rows(); ++r) {
          if (!hvalid[r]) continue;
          for (int ch = 0; ch < nc; ++ch) {
            const double d = y[r * nc + ch] - hb[r * nc + ch];
            sum += d * d;
          }
          n += nc;
        }
        return n ? std::sqrt(sum / n) : 0.0;
      };
    }
    t0 = Clock::now();
    SolveSummary solve = SolveTomography(problem, &x, solve_options, scorer, progress);
    if (solve.stop == SolveStop::kCancelled) throw Cancelled("reconstruct: cancelled");
    summary.solve_ms += Ms(t0);
    summary.solves.push_back(solve);
    peak =
        std::max(peak, a.bytes() + (level->has_stop ? level->stop.bytes() : 0) +
                           level->projections.bytes() + (problem.b.size() * 4 + x.size() * 4) * 4);

    // Back to the full grid.
    std::vector<float> emission(g.num_voxels() * 3, 0.0f);
    for (std::size_t j = 0; j < a.cols(); ++j)
      for (int ch = 0; ch < 3; ++ch)
        emission[a.col_voxel(j) * 3 + ch] = x[j * nc + (grey ? 0 : ch)];
    if (is_fine) {
      out.geometry = g;
      out.emission_rgb = std::move(emission);
    } else {
      previous_level_emission = std::move(emission);
      previous_grid = g;
      if (!options_.keep_coarse_matrix) {
        level->a = SystemMatrix();
        level->stop = SystemMatrix();
        level->has_matrix = level->has_stop = false;
        level->projections = VoxelProjections();
      }
    }
  }
  if (use_holdout) {
    // The held-out camera scores the result on every pixel of its image (saturated ones left
    // out); it took no part in the solve or its stopping.
    const auto holdout_start = Clock::now();
    const LinearFrame& f = frames[holdout_index_];
    const ImageF image = RenderThinEmission(out.geometry, out.emission_rgb, *rays_[holdout_index_],
                                            options_.matrix.step_voxels);
    double error = 0, data = 0;
    std::size_t n = 0;
    for (std::size_t p = 0; p < f.saturated.size(); ++p) {
      if (f.saturated[p]) continue;
      for (int ch = 0; ch < 3; ++ch) {
        const double d = image.pixels[3 * p + ch] - f.radiance.pixels[3 * p + ch];
        error += d * d;
        data += double(f.radiance.pixels[3 * p + ch]) * f.radiance.pixels[3 * p + ch];
      }
      n += 3;
    }
    summary.holdout_rms = n ? std::sqrt(error / n) : 0.0;
    summary.holdout_relative = data > 0 ? std::sqrt(error / data) : 0.0;
    summary.holdout_ms = Ms(holdout_start);
  }
  // Light on the box's faces: a box that cuts the fire.
  {
    const GridGeometry& g = out.geometry;
    double all = 0, on_faces = 0;
    std::array<double, 6> face{};  // x-min, x-max, y-min, y-max, z-min, z-max
    if (out.emission_rgb.size() == 3 * g.num_voxels())
      for (int k = 0; k < g.dims.z(); ++k)
        for (int j = 0; j < g.dims.y(); ++j)
          for (int i = 0; i < g.dims.x(); ++i) {
            const float* e = &out.emission_rgb[3 * g.Flat(i, j, k)];
            const double light = double(e[0]) + e[1] + e[2];
            if (!(light > 0)) continue;
            all += light;
            const std::array<bool, 6> at = {i == 0, i == g.dims.x() - 1,
                                            j == 0, j == g.dims.y() - 1,
                                            k == 0, k == g.dims.z() - 1};
            bool on = false;
            for (int f = 0; f < 6; ++f)
              if (at[f]) {
                face[f] += light;
                on = true;
              }
            if (on) on_faces += light;
          }
    summary.box_face_light_share = all > 0 ? on_faces / all : 0.0;
    static const char* kFaceNames[6] = {"x-min", "x-max", "y-min", "y-max", "z-min", "z-max"};
    for (int f = 0; f < 6; ++f)
      if (all > 0 && face[f] / all > 0.01)
        summary.box_faces_lit +=
            (summary.box_faces_lit.empty() ? "" : " ") + std::string(kFaceNames[f]);
    if (summary.box_face_light_share > ReconstructSummary::kBoxFaceWarning)
      Log().warn(
          "reconstruct: {:.0f}% of the fire's light lies on the box's faces ({}): the box cuts "
          "the fire; widen the rig's box (rig.yaml: box) on those sides",
          100 * summary.box_face_light_share, summary.box_faces_lit);
  }
  summary.working_bytes = peak;
  summary.process_peak_bytes = PeakResidentBytes();
  summary.total_ms = Ms(start);
  out.metadata_numbers["exposure"] = options_.exposure;
  out.metadata_numbers["hull_voxel_fraction"] = summary.voxel_fraction_in_hull;
  out.metadata_numbers["iterations"] =
      summary.solves.empty() ? 0 : summary.solves.back().iterations;
  out.metadata_text["solver"] = options_.solve.solver;
  if (options_.bin > 1) out.metadata_numbers["pixel_bin"] = options_.bin;
  if (const double w = PriorWeight(options_.solve); w > 0) {
    out.metadata_text["prior"] = options_.solve.prior;
    out.metadata_numbers["prior_weight"] = w;
  }
  out.metadata_text["emission_units"] =
      "linear sRGB radiance per metre (W m^-2 sr^-1 nm^-1 m^-1, luminance-normalised)";
  if (summary_out) *summary_out = summary;
  return out;
}

ImageF RenderThinEmission(const GridGeometry& grid, const std::vector<float>& emission_rgb,
                          const CameraRays& rays, double step_voxels) {
  if (emission_rgb.size() != grid.num_voxels() * 3) {
    throw InputError("RenderThinEmission: emission needs 3 values per voxel");
  }
  ImageF image(rays.width(), rays.height(), 3, 0.0f);
  const double step_m = step_voxels * grid.voxel_size_m.minCoeff();
  const std::size_t nx = grid.dims.x(), nxy = nx * grid.dims.y();
  tbb::parallel_for(tbb::blocked_range<int>(0, rays.height()),
                    [&](const tbb::blocked_range<int>& r) {
                      for (int y = r.begin(); y < r.end(); ++y)
                        for (int x = 0; x < rays.width(); ++x) {
                          RayMarch march;
                          if (!RayMarch::Make(grid, rays.at(x, y), step_m, &march)) continue;
                          double acc[3] = {0, 0, 0};
                          for (std::int64_t k = 0; k < march.n_steps; ++k) {
                            double length;
                            Eigen::Vector3d p;
                            march.Step(k, &length, &p);
                            TrilinearStencil<double> s(grid.dims, p.x(), p.y(), p.z());
                            std::size_t flat[8];
                            double w[8];
                            s.Corners(nx, nxy, flat, w);
                            for (int n = 0; n < 8; ++n)
                              for (int ch = 0; ch < 3; ++ch)
                                acc[ch] += w[n] * length * emission_rgb[flat[n] * 3 + ch];
                          }
                          for (int ch = 0; ch < 3; ++ch)
                            image.at(x, y, ch) = static_cast<float>(acc[ch]);
                        }
                    });
  return image;
}

std::vector<float> ResampleEmission(const GridGeometry& from,
                                    const std::vector<float>& emission_rgb,
                                    const GridGeometry& to) {
  if (emission_rgb.size() != from.num_voxels() * 3) {
    throw InputError("ResampleEmission: emission needs 3 values per voxel of the source grid");
  }
  std::vector<float> out(to.num_voxels() * 3, 0.0f);
  const std::size_t nx = from.dims.x(), nxy = nx * from.dims.y();
  const Box3 box = from.box();
  tbb::parallel_for(0, to.dims.z(), [&](int k) {
    for (int j = 0; j < to.dims.y(); ++j)
      for (int i = 0; i < to.dims.x(); ++i) {
        const Eigen::Vector3d p = to.VoxelCenter(i, j, k);
        if ((p.array() < box.min_in_rig.array()).any() ||
            (p.array() > box.max_in_rig.array()).any())
          continue;
        const Eigen::Vector3d q = from.IndexFromRig(p);
        TrilinearStencil<double> s(from.dims, q.x(), q.y(), q.z());
        std::size_t flat[8];
        double w[8];
        s.Corners(nx, nxy, flat, w);
        for (int ch = 0; ch < 3; ++ch) {
          double v = 0;
          for (int n = 0; n < 8; ++n) v += w[n] * emission_rgb[flat[n] * 3 + ch];
          out[to.Flat(i, j, k) * 3 + ch] = static_cast<float>(v);
        }
      }
  });
  return out;
}

}  // namespace flamerig

namespace flamerig {

namespace {

// The state file: "FRRS", version, the state key, then per level (fine, coarse) its masks; all
// masks as bits, lengths as uint64; a CRC-32 of everything before it at the end.
constexpr char kStateMagic[4] = {'F', 'R', 'R', 'S'};
constexpr std::uint32_t kStateVersion = 1;

// Bytes in a std::string: GCC 12 misreads small std::vector<char> inserts inlined into SaveState
// as overflows (-Wstringop-overflow, -Warray-bounds: false positives that -Werror turns fatal).
class StateWriter {
 public:
  template <typename T>
  void Value(const T& v) {
    bytes_.append(reinterpret_cast<const char*>(&v), sizeof(T));
  }
  void Mask(const std::vector<std::uint8_t>& mask) {
    Value(static_cast<std::uint64_t>(mask.size()));
    std::string bits((mask.size() + 7) / 8, '\0');
    for (std::size_t i = 0; i < mask.size(); ++i)
      if (mask[i]) bits[i / 8] = static_cast<char>(bits[i / 8] | (1 << (i % 8)));
    bytes_ += bits;
  }
  const std::string& bytes() const { return bytes_; }

 private:
  std::string bytes_;
};

class StateReader {
 public:
  StateReader(const std::vector<char>& bytes, const std::string& path)
      : bytes_(bytes), path_(path) {}
  template <typename T>
  T Value() {
    Need(sizeof(T));
    T v;
    std::memcpy(&v, bytes_.data() + at_, sizeof(T));
    at_ += sizeof(T);
    return v;
  }
  std::vector<std::uint8_t> Mask(std::size_t max_size) {
    const auto n = Value<std::uint64_t>();
    if (n > max_size) Fail("a mask of " + std::to_string(n) + " entries");
    Need((n + 7) / 8);
    std::vector<std::uint8_t> mask(n);
    for (std::size_t i = 0; i < n; ++i) mask[i] = (bytes_[at_ + i / 8] >> (i % 8)) & 1;
    at_ += (n + 7) / 8;
    return mask;
  }
  [[noreturn]] void Fail(const std::string& what) const {
    throw DataError(path_ + ": reconstructor state is corrupt (" + what + " at byte " +
                    std::to_string(at_) + ")");
  }

 private:
  void Need(std::size_t n) const {
    if (at_ + n > bytes_.size()) Fail("truncated");
  }
  const std::vector<char>& bytes_;
  std::string path_;
  std::size_t at_ = 0;
};

}  // namespace

std::uint64_t Reconstructor::StateKey() const {
  // The grid and the options that shape envelopes and matrices; the rig through the key of a matrix
  // over all its cameras' rays with empty masks (cheap: no matrix is built).
  std::vector<const CameraRays*> rays;
  std::vector<std::vector<std::uint8_t>> pixels;
  for (const auto& r : rays_) {
    rays.push_back(r.get());
    pixels.emplace_back();
  }
  std::uint64_t key = SystemMatrix::Key(grid_, rays, pixels, {}, options_.matrix);
  const double numbers[] = {static_cast<double>(options_.envelope_margin_voxels),
                            options_.envelope_pixel_tolerance, static_cast<double>(stop_index_),
                            static_cast<double>(coarse_ != nullptr)};
  for (double v : numbers) {
    std::uint64_t bits;
    std::memcpy(&bits, &v, sizeof bits);
    key = (key ^ bits) * 1099511628211ull;
  }
  return key;
}

std::string Reconstructor::MakeMatrix(Level* level, const std::vector<int>& cameras,
                                      std::vector<std::vector<std::uint8_t>> pixels,
                                      std::vector<std::uint8_t> envelope) {
  std::vector<const CameraRays*> rays;
  for (int c : cameras) rays.push_back(rays_[c].get());
  const GridGeometry& g = level->grid;
  const std::uint64_t key = SystemMatrix::Key(g, rays, pixels, envelope, options_.matrix);
  std::string path;
  bool loaded = false;
  if (!options_.cache_dir.empty()) {
    std::filesystem::create_directories(options_.cache_dir);
    path = (std::filesystem::path(options_.cache_dir) / ("system_matrix_" + HexKey(key) + ".bin"))
               .string();
    // A file whose indices do not fit this rig and grid (corrupt, with the right key) is rebuilt.
    loaded = level->a.Load(path, key) && level->a.IndicesFit(rays, g.num_voxels());
  }
  std::string source = "disk cache";
  if (!loaded) {
    level->a = SystemMatrix::Build(g, rays, pixels, envelope, options_.matrix, key);
    source = "built";
    if (!path.empty()) level->a.Save(path);
  }
  level->envelope_voxels = std::move(envelope);
  level->envelope_pixels = std::move(pixels);
  level->cameras = cameras;
  level->has_matrix = true;
  level->has_stop = false;
  level->stop_pixels.clear();
  return source;
}

void Reconstructor::MakeStopMatrix(Level* level, std::vector<std::uint8_t> pixels) {
  level->stop = SystemMatrix::Build(level->grid, {rays_[stop_index_].get()}, {pixels},
                                    level->envelope_voxels, options_.matrix);
  level->stop_pixels = std::move(pixels);
  level->has_stop = true;
}

void Reconstructor::KeepMasks(const GridGeometry& g, const VoxelProjections& projections,
                              const std::vector<int>& rig_cameras,
                              const std::vector<const LinearFrame*>& frames, const VisualHull& hull,
                              std::vector<CameraMaskSummary>* masks) const {
  for (std::size_t i = 0; i < rig_cameras.size(); ++i) {
    const RigCamera& cam = rig_.cameras[rig_cameras[i]];
    const FireMask mask = ComputeFireMask(g, cam, *frames[i], options_.hull, /*keep_labels=*/true);
    const int radius = static_cast<int>(std::ceil(0.5 * VoxelFootprintPx(g, cam)));
    const std::vector<std::uint8_t> silhouette =
        HullSilhouette(hull.voxel_inside, projections.pixel[rig_cameras[i]], cam.model.width(),
                       cam.model.height(), radius);
    std::vector<std::uint8_t>& labels = (*masks)[i].labels;
    labels = mask.labels;
    for (std::size_t p = 0; p < labels.size(); ++p) {
      if (mask.mask[p]) labels[p] |= CameraMaskSummary::kMaskDilated;
      if (silhouette[p]) labels[p] |= CameraMaskSummary::kMaskHull;
    }
  }
}

void Reconstructor::SaveState(const std::string& path) const {
  StateWriter w;
  for (char c : kStateMagic) w.Value(c);
  w.Value(kStateVersion);
  w.Value(state_key_);
  for (const Level* level : {fine_.get(), coarse_.get()}) {
    const bool has = level && level->has_matrix;
    w.Value(static_cast<std::uint8_t>(has));
    if (!has) continue;
    w.Value(static_cast<std::uint64_t>(level->cameras.size()));
    for (std::size_t c = 0; c < level->cameras.size(); ++c) {
      w.Value(static_cast<std::int32_t>(level->cameras[c]));
      w.Mask(level->envelope_pixels[c]);
    }
    w.Mask(level->envelope_voxels);
    w.Value(static_cast<std::uint8_t>(level->has_stop));
    if (level->has_stop) w.Mask(level->stop_pixels);
  }
  std::string bytes = w.bytes();
  const std::uint32_t crc = static_cast<std::uint32_t>(
      crc32_z(0, reinterpret_cast<const Bytef*>(bytes.data()), bytes.size()));
  bytes.append(reinterpret_cast<const char*>(&crc), sizeof crc);
  WriteFileAtomically(path, bytes);
}

void Reconstructor::LoadState(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw IoError(path + ": cannot read the reconstructor state");
  std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (bytes.size() < 4 + 4 + 8 + 4) throw DataError(path + ": reconstructor state is truncated");
  std::uint32_t crc;
  std::memcpy(&crc, bytes.data() + bytes.size() - 4, 4);
  bytes.resize(bytes.size() - 4);
  if (crc != static_cast<std::uint32_t>(
                 crc32_z(0, reinterpret_cast<const Bytef*>(bytes.data()), bytes.size())))
    throw DataError(path + ": reconstructor state fails its checksum");
  StateReader r(bytes, path);
  for (char c : kStateMagic)
    if (r.Value<char>() != c) r.Fail("not a reconstructor state file");
  if (r.Value<std::uint32_t>() != kStateVersion) r.Fail("unknown version");
  if (r.Value<std::uint64_t>() != state_key_)
    throw InputError(path + ": reconstructor state was saved for another rig, grid or options");
  for (Level* level : {fine_.get(), coarse_.get()}) {
    const bool has = r.Value<std::uint8_t>() != 0;
    if (!has) {
      if (level) level->has_matrix = level->has_stop = false;
      continue;
    }
    if (!level) r.Fail("a coarse level this reconstructor does not have");
    const std::size_t pixels_per_camera = 1u << 28;
    const auto ncam = r.Value<std::uint64_t>();
    if (ncam > rays_.size()) r.Fail("more cameras than the rig has");
    std::vector<int> cameras;
    std::vector<std::vector<std::uint8_t>> pixels;
    for (std::size_t c = 0; c < ncam; ++c) {
      const int index = r.Value<std::int32_t>();
      if (index < 0 || index >= static_cast<int>(rays_.size())) r.Fail("a camera index");
      cameras.push_back(index);
      pixels.push_back(r.Mask(pixels_per_camera));
      const std::size_t n =
          static_cast<std::size_t>(rays_[index]->width()) * rays_[index]->height();
      if (pixels.back().size() != n) r.Fail("a pixel mask of the wrong size");
    }
    std::vector<std::uint8_t> envelope = r.Mask(level->grid.num_voxels());
    if (envelope.size() != level->grid.num_voxels()) r.Fail("a voxel mask of the wrong size");
    const bool has_stop = r.Value<std::uint8_t>() != 0;
    std::vector<std::uint8_t> stop;
    if (has_stop) stop = r.Mask(pixels_per_camera);
    if (has_stop && stop_index_ < 0) r.Fail("a stop camera this reconstructor lacks");
    MakeMatrix(level, cameras, std::move(pixels), std::move(envelope));
    if (has_stop) MakeStopMatrix(level, std::move(stop));
  }
}

}  // namespace flamerig
