// Algebraic tomography of one frame set: from calibrated images to an RGB emission volume that,
// rendered in the optically thin limit, reproduces them (DESIGN section 6).
//
// Per frame: decode (sRGB -> linear / exposure) -> visual hull (visual_hull.h) -> system matrix
// inside the hull (system_matrix.h) -> SART or CGLS with non-negativity and early stopping
// (solvers.h). Optional coarse-to-fine (a half-resolution solve, upsampled, starts the full one)
// and warm start (the previous frame's volume starts the solve).
//
// Reuse across the frames of a recording: a Reconstructor keeps the last system matrix and the hull
// "envelope" it was built for (the union of the hulls seen so far, dilated by
// envelope_margin_voxels). A frame whose hull and fire masks fit inside the envelope reuses the
// matrix, with the voxels outside its own hull pinned at zero (up to envelope_pixel_tolerance of
// a camera's fire pixels may fall outside; they are left out and counted); otherwise the envelope
// grows and the matrix is rebuilt. Matrices are also cached on disk (cache_dir) under a hash of everything they
// depend on, so a second run skips the build.
//
// Grey data (mono cameras, whose frames carry one value in all three channels) are solved as one
// channel, a third of the arithmetic and of the solve's vectors, and the result copied to the three
// (SolveSummary::channels). The matrix is read once per product whatever the channels, so the
// solve takes 0.4 to 0.7 of the colour solve's time (BENCHMARKS.md, "Tomography", mono rows).
//
// Output: FireVolume with `emission_rgb` (linear RGB radiance per metre, the renderer's units: an
// image is exposure times the line integral) and metadata (exposure, solver, iterations, hull
// fraction).
#ifndef FLAMERIG_TOMOGRAPHY_RECONSTRUCT_H_
#define FLAMERIG_TOMOGRAPHY_RECONSTRUCT_H_

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "calibration/camera_rays.h"
#include "calibration/rig.h"
#include "tomography/solvers.h"
#include "tomography/system_matrix.h"
#include "tomography/visual_hull.h"

namespace flamerig {

struct ReconstructOptions {
  int resolution = 64;    // voxels along the box's longest axis (cubic voxels); [1, 1024]
  double exposure = 1.0;  // the exposure the images were recorded with; (0, inf)
  VisualHullOptions hull;
  SystemMatrixOptions matrix;
  SolveOptions solve;
  // Pixel binning, [1, 16]: each camera's images are averaged over blocks of bin x bin pixels and
  // its model binned to match (CameraModel::Binned) before the masks and the solve: bin^2 times
  // fewer rays, so less memory and time, for detail finer than a block (`benchmark footage`
  // measures the error it costs). Everything in pixels is then in binned pixels: the masks, their
  // dilation (hull.dilation_px), the speck size, the held-out camera's score.
  int bin = 1;
  bool coarse_to_fine = true;  // half-resolution solve first (when resolution >= 16)
  int coarse_iterations = 30;  // iterations of the coarse solve
  // An OS-EM solve warm-started from the previous frame, with four cameras or more, stops when an
  // iteration improves the residual by less than this (while solve.stagnation_tolerance is -1,
  // the solver's own); -1 = as a cold solve. OS-EM's tail fits noise, and a warm start is near the
  // answer: on the 8-view licks at 128^3 (frames 2 to 5) 0.02 stops after 6 or 7 iterations
  // instead of 18 to 21, with the volume error lower (0.151, 0.166, 0.184, 0.199 against 0.152,
  // 0.169, 0.192, 0.215; 0.01 stops after 8, 0.04 after 5 or 6, both in between) (issue 24). Not
  // with fewer cameras: from two (the main job) the shorter warm solves left 29 voxels (0.005: 10)
  // at the fit's upper temperature bound, where full solves leave none; two views hold a volume
  // less, and the fit starts from its colours. (The "full" two-view solves of that measurement
  // were one sweep: two_view_fine_iterations, below.)
  double warm_stagnation_tolerance = 0.02;
  // With two solve cameras (or one), no stop camera and a solver that sweeps subsets of rows
  // (IterativeSolver::SweepsSubsets: OS-EM, and SART with ordered_subsets), the fine level, when it
  // starts from the coarse level or a warm start, takes at most this many iterations; -1 = the
  // solve's own rules. CGLS and plain SART, which the old rule below never stopped early and which
  // were not measured so, keep their own rules.
  // Two views do not hold the fine grid, and its sweeps fit their streaks: on `simulate`'s candle
  // (seeds 3 and 5, frame 1) the volume's relative L2 error against the truth grows from the
  // first sweep on (0.604 / 0.610 after one, 0.616 / 0.619 after 10, 0.672 / 0.668 after 50), and
  // the main job's fits from 100 sweeps are worse than from one (untied T RMS 156 against 152 K,
  // tied bias +17.7 against +12.7 K; BENCHMARKS.md, "The fine level's stop on two views"). On two
  // views of the licks at right angles the solve stagnates after 10 sweeps at 0.493 against 0.499
  // after one. Until 2026-12-03 a stopping rule that compared the first sweep's residual with the
  // start's (solvers.h, IterativeSolver::SweepsSubsets) stopped the candle after one sweep by
  // accident; this keeps that, on purpose.
  int two_view_fine_iterations = 1;
  // A camera left out of the solve and scored on every pixel of its image afterwards (binned like
  // the others with `bin`); it does not stop the solve (a score that also chose the iterate would
  // flatter it). "" = none.
  std::string holdout_camera;
  // A camera left out of the solve whose error chooses the iterate and stops the solve (and keeps
  // the coarse stage when the fine one does not improve on it); "" = none: the solve stops on its
  // residual. Must not be the held-out camera.
  std::string stop_camera;
  int envelope_margin_voxels = 4;  // dilation of the hull envelope that matrices are built for
  // Share of a camera's fire pixels that may fall outside the envelope before the matrix is
  // rebuilt (those pixels are left out of that frame); [0, 0.1].
  double envelope_pixel_tolerance = 0.01;
  std::string cache_dir;  // on-disk matrix cache; "" = memory only
  // Pixels of the solve (the dilated fire masks) below their camera's fire threshold count as
  // black: the mask's margin then says "no light here", and codec specks and noise near the fire
  // leave less ghost emission (`benchmark footage`, H.264 frames: the emission outside the fire's
  // support fell from 0.74% to 0.65% at 640x360, from 0.65% to 0.21% in its --quick form).
  bool black_below_threshold = true;
  // Keep every camera's mask labels (ReconstructSummary::masks) for pictures and mask files.
  bool keep_masks = false;
  // Keep the coarse level's system matrix for the next frame that starts cold (a recording). false
  // (one frame): it is freed once its solve is done, before the full grid's is built, so that the
  // two are never held at once.
  bool keep_coarse_matrix = true;
  void Validate() const;  // throws InputError naming the field
};

// One camera's fire mask on the full-resolution grid (visual_hull.h), as a person checks it.
struct CameraMaskSummary : FireMaskStats {
  std::string camera;
  bool held_out = false;
  int width = 0, height = 0;
  // With ReconstructOptions::keep_masks, per pixel: kMaskFire, kMaskSpeck (visual_hull.h),
  // kMaskDilated (inside the dilated mask, the rows the solve uses) and kMaskHull (a hull voxel's
  // centre projects near it); else empty.
  std::vector<std::uint8_t> labels;
  static constexpr std::uint8_t kMaskDilated = 4, kMaskHull = 8;
};

struct ReconstructSummary {
  GridGeometry grid;
  int bin = 1;  // pixels binned bin x bin (ReconstructOptions::bin)
  double voxel_fraction_in_hull = 0;
  std::vector<CameraMaskSummary> masks;  // per camera with a frame (solve cameras, then held out)
  std::size_t matrix_rows = 0, matrix_cols = 0, matrix_nnz = 0, matrix_bytes = 0;
  std::size_t matrix_stored_entries = 0;  // the non-zeros and the padding of the products' runs
  std::string matrix_source;              // "built", "reused (envelope)", "disk cache"
  std::size_t fire_pixels_outside_envelope = 0;  // left out of a frame that reused the matrix
  // The share of the result's light (R + G + B emission) in the voxels on the box's six faces,
  // and the faces that hold light ("x-min z-max"). A fire inside its box leaves them dark (a
  // candle's box: under 0.1%); a box that cuts the fire piles the light it cannot place onto
  // them, and the fit then matches half a flame (Delta E 15 and 26 where 2 to 3 is usual, with no
  // word until 2026-12-02). Above kBoxFaceWarning the reconstruction warns, naming the faces.
  double box_face_light_share = 0;
  std::string box_faces_lit;
  static constexpr double kBoxFaceWarning = 0.05;
  double matrix_build_ms = 0;
  std::vector<SolveSummary> solves;  // coarse (if any), then full resolution
  std::string holdout_camera, stop_camera;
  double holdout_rms = -1;       // RMS radiance error on the held-out camera, -1 if none
  double holdout_relative = -1;  // the same over the RMS of its image
  std::vector<std::string> skipped_cameras;  // cameras without a usable frame, with the reason
  double decode_ms = 0, hull_ms = 0, matrix_ms = 0, solve_ms = 0, total_ms = 0;
  double holdout_ms = 0;          // of total_ms, scoring the held-out camera (a render of its view)
  std::size_t working_bytes = 0;  // system matrices, projections and solver vectors
  std::size_t process_peak_bytes = 0;  // the process's peak resident memory so far (VmHWM)
  std::string BriefReport() const;
};

class Reconstructor {
 public:
  // Unprojects every camera's rays once. Throws InputError for invalid options, a rig
  // without cameras, or a held-out camera that is not in the rig.
  Reconstructor(const Rig& rig, const ReconstructOptions& options);
  ~Reconstructor();
  Reconstructor(Reconstructor&&) noexcept;
  Reconstructor& operator=(Reconstructor&&) noexcept;

  // One frame set, one image per rig camera in rig order (an empty image skips that camera).
  // `warm_start` (optional) is a previous result on the same grid. Progress: the solves' (stage
  // "solve", solvers.h); a cancel throws Cancelled after the solve stops. The reconstructor may
  // have rebuilt its matrices and envelope for the cancelled frame; they stay valid for the next
  // frame (a run that resumes loads the state saved after the last committed frame instead).
  FireVolume Reconstruct(const std::vector<ImageU8>& images, ReconstructSummary* summary,
                         const FireVolume* warm_start = nullptr,
                         const ProgressCallback& progress = nullptr);
  FireVolume Reconstruct(const std::vector<LinearFrame>& frames, ReconstructSummary* summary,
                         const FireVolume* warm_start = nullptr,
                         const ProgressCallback& progress = nullptr);

  // The state that the next frame's result depends on besides its images and warm start: per grid
  // level, the envelope its system matrix was built for (voxels, each camera's pixels, the held-out
  // camera's pixels) and the cameras it covers. A run stopped after a frame saves it and resumes
  // with exactly what an uninterrupted run would have had. SaveState writes a checksummed binary
  // file (to path.tmp, then renamed; IoError naming the path on I/O failure).
  // LoadState reads one back and rebuilds the matrices for it (from cache_dir when they are
  // there); it throws DataError naming the file when it is unreadable, corrupt, or was
  // saved for another rig, grid or set of options.
  void SaveState(const std::string& path) const;
  void LoadState(const std::string& path);

  const GridGeometry& grid() const { return grid_; }
  const Rig& rig() const { return rig_; }  // with its cameras binned (ReconstructOptions::bin)

 private:
  struct Level;
  Rig rig_;
  ReconstructOptions options_;
  GridGeometry grid_;
  std::vector<std::unique_ptr<CameraRays>> rays_;  // of the cameras as binned
  std::vector<std::pair<int, int>> frame_sizes_;   // each camera's frames, before binning
  // The matrix of `level` for `envelope` and the cameras' `pixels`: from the disk cache when it
  // is there, else built (and cached). Returns "disk cache" or "built".
  std::string MakeMatrix(Level* level, const std::vector<int>& cameras,
                         std::vector<std::vector<std::uint8_t>> pixels,
                         std::vector<std::uint8_t> envelope);
  void MakeStopMatrix(Level* level, std::vector<std::uint8_t> pixels);
  // Fills the labels of masks[i] for rig camera rig_cameras[i] and its frame.
  void KeepMasks(const GridGeometry& g, const VoxelProjections& projections,
                 const std::vector<int>& rig_cameras, const std::vector<const LinearFrame*>& frames,
                 const VisualHull& hull, std::vector<CameraMaskSummary>* masks) const;
  std::uint64_t StateKey() const;  // what a saved state must have been saved for
  std::uint64_t state_key_ = 0;    // StateKey(), computed once (it hashes every ray)
  std::unique_ptr<Level> fine_, coarse_;
  int holdout_index_ = -1, stop_index_ = -1;
};

// The thin-limit image of an emission volume through `rays` (what A e computes, for all pixels):
// linear RGB radiance. `step_voxels` as in SystemMatrixOptions.
ImageF RenderThinEmission(const GridGeometry& grid, const std::vector<float>& emission_rgb,
                          const CameraRays& rays, double step_voxels = 0.5);

// Emission resampled trilinearly onto another grid (coarse-to-fine, warm starts across
// resolutions).
std::vector<float> ResampleEmission(const GridGeometry& from,
                                    const std::vector<float>& emission_rgb, const GridGeometry& to);

}  // namespace flamerig

#endif  // FLAMERIG_TOMOGRAPHY_RECONSTRUCT_H_
