// Frames as the tomography sees them, and the conservative visual hull that carves empty space
// before the system matrix is built.
//
// Decoding: an 8-bit sRGB image becomes linear RGB divided by the camera exposure, i.e. radiance in
// the renderer's units (renderer.h: image = exposure * linear radiance). Pixels with any channel at
// full scale are marked saturated: they only say "at least this bright".
//
// Hull: per camera, a pixel shows fire when its brightest channel exceeds threshold_sigmas times
// the image noise (estimated from the darkest three quarters of the pixels unless given) and at
// least one 8-bit step; the fire mask is dilated by dilation_px plus the projected radius of a
// voxel. A voxel stays in the hull when no camera that sees it (its centre projects inside the
// image) sees background there, and at least min(min_views, cameras that see it) cameras see fire
// there. Conservative by construction: dilation only adds voxels.
#ifndef FLAMERIG_TOMOGRAPHY_VISUAL_HULL_H_
#define FLAMERIG_TOMOGRAPHY_VISUAL_HULL_H_

#include <cstdint>
#include <string>
#include <vector>

#include "core/image.h"
#include "calibration/rig.h"
#include "tomography/volume.h"

namespace flamerig {

struct LinearFrame {
  ImageF radiance;  // 3 channels, linear RGB / exposure (a camera's: its unit-gain channels)
  std::vector<std::uint8_t> saturated;  // per pixel: some channel at full scale
  double full_scale = 1.0;  // the radiance a saturated channel stands for (1 / exposure; with
                            // gains, the largest over the channels)
};

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
  void Validate() const;          // throws InputError naming the field
};

struct VisualHull {
  std::vector<std::uint8_t> voxel_inside;            // per voxel (volume.h order)
  std::vector<std::vector<std::uint8_t>> fire_mask;  // per camera, per pixel, dilated
  std::vector<double> noise_sigma;                   // per camera, radiance units
  std::vector<double> threshold;                     // per camera, radiance units
  std::vector<double> fire_pixel_fraction;           // per camera, of the dilated mask
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

// One camera's dilated fire mask, as the hull computes it. Throws InputError naming the
// camera when the frame's size is not the camera's.
struct FireMask {
  std::vector<std::uint8_t> mask;
  double noise_sigma = 0, threshold = 0, fraction = 0;
};
FireMask ComputeFireMask(const GridGeometry& grid, const RigCamera& camera,
                         const LinearFrame& frame, const VisualHullOptions& options);

// Square (Chebyshev) dilation of a per-pixel mask by `radius` pixels.
std::vector<std::uint8_t> DilateMask(const std::vector<std::uint8_t>& mask, int width, int height,
                                     int radius);

// Noise level of an image: the RMS about zero of the darkest three quarters of the pixels'
// brightest channel (robust to the fire, which covers less than a quarter of the frame, and to
// noise clipped at black).
double EstimateNoiseSigma(const ImageF& radiance);

}  // namespace flamerig

#endif  // FLAMERIG_TOMOGRAPHY_VISUAL_HULL_H_
