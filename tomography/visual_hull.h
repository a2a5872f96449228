// Frames as the tomography sees them, and the conservative visual hull that carves empty space
// before the system matrix is built.
//
// Decoding: an 8-bit sRGB image becomes linear RGB divided by the camera exposure, i.e. radiance in
// the renderer's units (renderer.h: image = exposure * linear radiance). Pixels with any channel at
// full scale are marked saturated: they only say "at least this bright".
//
// Fire masks, per camera, as real footage needs them (an exactly black background, codec specks,
// hot pixels):
//  1. noise: estimated from the darkest three quarters of the pixels unless given, and never below
//     one quantisation step of the frame at black (LinearFrame::quantum): on a background that
//     reads exactly 0 the estimate is 0, and a threshold of "5 x 0" would take every 1 DN
//     compression speck for fire;
//  2. fire: a pixel whose brightest channel exceeds threshold_sigmas times that noise;
//  3. specks removed: 8-connected regions of fire pixels smaller than min_speck_px (by default half
//     the area a voxel at the box centre projects to: a region that small cannot be the image of
//     anything the grid holds);
//  4. dilated by dilation_px plus the projected radius of a voxel.
// Hull: a voxel stays when no camera that sees it (its centre projects inside the image) sees
// background there, and at least min(min_views, cameras that see it) cameras see fire there.
// Conservative by construction: dilation only adds voxels.
#ifndef FLAMERIG_TOMOGRAPHY_VISUAL_HULL_H_
#define FLAMERIG_TOMOGRAPHY_VISUAL_HULL_H_

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "calibration/rig.h"
#include "core/image.h"
#include "tomography/volume.h"

namespace flamerig {

struct LinearFrame {
  ImageF radiance;  // 3 channels, linear RGB / exposure (a camera's: its unit-gain channels)
  std::vector<std::uint8_t> saturated;  // per pixel: some channel at full scale
  double full_scale = 1.0;  // the radiance a saturated channel stands for (1 / exposure; with
                            // gains, the largest over the channels)
  // The radiance of the first code above black (the largest over the channels): the frame's
  // quantisation step where the background lies, and the floor of its noise. 0 = unknown (taken
  // as one 8-bit sRGB step of full_scale).
  double quantum = 0.0;
};

// The frame with its pixels binned factor x factor (as CameraModel::Binned): each pixel the mean
// of its block's radiance, saturated when any of them is; the rows and columns that do not fill a
// block are dropped. The quantum stays the original's: a lone code above black is a speck, and
// its block's mean falls under the noise floor. Throws InputError for a factor below 1 or larger
// than the image.
LinearFrame BinFrame(const LinearFrame& frame, int factor);

// Throws InputError unless exposure is finite and > 0 and the image has 1 or 3 channels
// (grey is replicated to RGB).
LinearFrame DecodeSrgb8(const ImageU8& image, double exposure);
// 16-bit linear images: value / white is the linear signal.
LinearFrame DecodeLinear16(const ImageU16& image, double exposure, double white = 65535.0);

struct VisualHullOptions {
  double noise_sigma = 0.0;       // image noise, radiance units; 0 = estimate per camera
  double threshold_sigmas = 5.0;  // fire when brighter than this many sigmas; > 0
  int dilation_px = 2;            // extra dilation of the fire masks, pixels; [0, 64]
  int min_views = 2;              // cameras that must see fire at a voxel; >= 1
  // Fire regions (8-connected, before dilation) of fewer pixels are specks and removed; -1 = half
  // the projected area of a voxel at the box centre (at least 2), 0 = keep every region;
  // [-1, 1000000].
  int min_speck_px = -1;
  void Validate() const;  // throws InputError naming the field
};

// What one camera's fire mask (steps 1 to 4 above) found.
struct FireMaskStats {
  double noise_estimate = 0;    // radiance units: estimated (or the given noise_sigma)
  double noise_sigma = 0;       // after the floor of one quantisation step
  double threshold = 0;         // radiance units
  double fraction = 0;          // of the pixels, dilated mask
  std::size_t fire_pixels = 0;  // above the threshold, specks removed, before dilation
  std::size_t speck_regions = 0, speck_pixels = 0;  // removed as specks
  int min_speck_px = 0;                             // the speck size used
};
struct FireMask : FireMaskStats {
  std::vector<std::uint8_t> mask;  // per pixel: 1 inside the dilated mask
  // Optional (ComputeFireMask's keep_labels): per pixel, kMaskFire | kMaskSpeck (before dilation).
  std::vector<std::uint8_t> labels;
};
enum MaskLabel : std::uint8_t { kMaskFire = 1, kMaskSpeck = 2 };

struct VisualHull {
  std::vector<std::uint8_t> voxel_inside;            // per voxel (volume.h order)
  std::vector<std::vector<std::uint8_t>> fire_mask;  // per camera, per pixel, dilated
  std::vector<FireMaskStats> masks;                  // per camera
  std::vector<int> cameras_seeing_box;  // per camera: 1 when any voxel centre projects inside
  std::size_t voxels_inside = 0;
  double voxel_fraction = 0;
  double time_ms = 0;
};

// `cameras` and `frames` are parallel (one frame per rig camera). Throws InputError when
// a frame's size differs from its camera's imager (naming the camera) or the counts differ.
VisualHull ComputeVisualHull(const GridGeometry& grid, const std::vector<RigCamera>& cameras,
                             const std::vector<LinearFrame>& frames,
                             const VisualHullOptions& options);

// Where every voxel centre lands in every camera: per camera, per voxel, the pixel index
// (y * width + x, rounded) or -1 when the centre is behind the camera or outside its image. It
// depends only on the rig and the grid, so a recording computes it once (projecting 2M voxels into
// 8 cameras through mrcal takes about half a second) and every frame's hull is then table look-ups.
struct VoxelProjections {
  std::vector<std::vector<std::int32_t>> pixel;  // [camera][voxel]
  std::size_t bytes() const;
};
VoxelProjections ComputeVoxelProjections(const GridGeometry& grid,
                                         const std::vector<RigCamera>& cameras);
// The same hull from precomputed projections: camera c of `cameras` uses
// projections.pixel[projection_index[c]] (empty projection_index: the same c).
VisualHull ComputeVisualHull(const GridGeometry& grid, const std::vector<RigCamera>& cameras,
                             const std::vector<LinearFrame>& frames,
                             const VisualHullOptions& options, const VoxelProjections& projections,
                             const std::vector<int>& projection_index = {});

// One camera's dilated fire mask, as the hull computes it; `keep_labels` also fills its labels.
// Throws DataError naming the camera when the frame's size is not the camera's.
FireMask ComputeFireMask(const GridGeometry& grid, const RigCamera& camera,
                         const LinearFrame& frame, const VisualHullOptions& options,
                         bool keep_labels = false);

// Removes 8-connected regions of fewer than `min_pixels` set pixels from `mask` (width x height,
// 0/1) in place; returns (regions removed, pixels removed). min_pixels <= 1 removes nothing.
std::pair<std::size_t, std::size_t> RemoveSpecks(std::vector<std::uint8_t>* mask, int width,
                                                 int height, int min_pixels);

// Where the hull lies in a camera's image: per pixel 1 when a hull voxel's centre projects there,
// dilated by `radius_px` (about half a voxel's projected size, so that the dots join).
std::vector<std::uint8_t> HullSilhouette(const std::vector<std::uint8_t>& voxel_inside,
                                         const std::vector<std::int32_t>& projections, int width,
                                         int height, int radius_px);
// The projected edge of one voxel at the box centre in a camera, pixels (0 behind the camera).
double VoxelFootprintPx(const GridGeometry& grid, const RigCamera& camera);

// Square (Chebyshev) dilation of a per-pixel mask by `radius` pixels.
std::vector<std::uint8_t> DilateMask(const std::vector<std::uint8_t>& mask, int width, int height,
                                     int radius);

// Noise level of an image, from the darkest three quarters of its pixels (the fire covers less
// than a quarter of the frame), whose noise is clipped at black:
//  - colour: the RMS about zero of the pixels' brightest channel;
//  - grey (every pixel's channels equal: a mono camera): the 75th percentile over 0.674, that of
//    a zero-mean Gaussian clipped at 0, taken again over the pixels below five times the first
//    estimate (the fire lifts the percentile of the whole frame). The colour rule would give a third of the deviation here
//    (half the pixels read 0, the rest the low half of the positive side, where three channels'
//    maximum lies higher): 12-bit mono frames with 4 DN of noise got a threshold of 1.5 sigma,
//    and 87% of each image became fire.
double EstimateNoiseSigma(const ImageF& radiance);

}  // namespace flamerig

#endif  // FLAMERIG_TOMOGRAPHY_VISUAL_HULL_H_
