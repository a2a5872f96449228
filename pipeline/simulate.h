// `flamerig simulate`: writes a complete synthetic dataset from a YAML config
// (config/sim_rig.yaml):
//
//   OUT/dataset.yaml                 what was generated (config echo, exposure, seeds, file lists)
//                                    and `exposure_unit_us` (SimExposureUnitUs below)
//   OUT/rig.yaml, OUT/cameras/*.cameramodel   the rig (mrcal camera models, reconstruction box)
//   OUT/truth/frame_NNNNNN.vdb       ground truth: temperature (K), density (m^-3), thin emission
//   (RGB) OUT/frames/frame_NNNNNN/CAM.png  8-bit sRGB images of the fire per camera
//   OUT/calibration/board.yaml       the board and each view's true pose and cameras
//   OUT/calibration/view_NNN/CAM.png 8-bit grey images of the calibration board
//   OUT/preview.png                  a contact sheet of frame 0 (all cameras) and calibration views
//
// Config keys (all under `simulate:`; defaults in brackets):
//   seed [7], frames [1], frame_rate_hz [30]
//   fire: {kind [candle|licks], peak_temperature_k [2000], peak_soot_volume_fraction [1e-6], licks
//   [0]} absorption [soot|grey], grid_resolution [64], exposure [auto | number in [0.01, 1000]],
//   noise_dn [0.5], box: {min, max}
//   rig: {cameras [2], azimuths_deg, distance_m [0.3], elevation_deg [0], width [320], height
//   [240],
//         fill [0.85], lensmodel [LENSMODEL_OPENCV8; any mrcal model with a core],
//         distortion [the model's parameters after fx fy cx cy; default: a mild barrel for
//         OPENCV8, zeros otherwise; a strong lens: [-0.3, 0.08, 0, 0, 0, 0, 0, 0]]}
//   calibration: {enabled [true], board [charuco|chessboard], squares [7, 5], square_m [0.012],
//                 marker_m [0.009], shared_per_pair [6], closeups_per_camera [4],
//                 shadow [1: none; the light left in a shadow across half of each board],
//                 gradient [0], blur_px [0]}
//   render: {step_voxels [0.5], pixel_samples [1]}   pixel_samples N: N x N rays through each
//                        pixel, their radiance averaged: the pixel integrates light over its
//                        area, as a sensor does (1: one ray through its centre); [1, 8]
//   radiometry: {...}   every camera's radiometric model (calibration/radiometry.h) [the default
//                        8-bit sRGB camera]; written into OUT/rig.yaml. Cameras of more than 8 bits
//                        write 16-bit PNGs holding their codes (0..2^bits - 1), mono cameras grey.
//   codec: none | {codec [libx264], crf [30], preset [medium], pixel_format [yuv420p]}
//                        every 8-bit frame through a real video codec (video_codec.h, ffmpeg), as
//                        an intra-coded frame: block artefacts, ringing, chroma subsampling and
//                        specks on the black background [none]
//   camera_gains: [[r, g, b], ...]   per camera, multiplying radiometry.gain (white balance and
//                        sensor spread, what radiometric calibration recovers) [all 1]
//   camera_filters: [[centre_nm, fwhm_nm], ...]   per camera, the band-pass filter in front of it
//                        (replacing radiometry.spectral.filter; [0, 0] = none): two-colour
//                        pyrometry with mono cameras behind different filters [radiometry's]
//   radiometric_calibration: {enabled [false], temperatures_k [1300, 1600, 1900],
//                        levels [0.05, 0.15, 0.35, 0.6, 0.85, 1.3], emissivity [0.98]}
//                        images of a black-body calibrator per camera (FilmCalibrationSource in
//                        radiometric_calibration.h) at exposures putting its brightest channel at
//                        each level of full scale (above 1 saturates; the time rounded to whole
//                        microseconds from 100 us up), written with their shots file in the
//                        camera's terms
//                        (exposure_us at 0 dB, and the dataset's exposure_unit_us):
//                        OUT/radiometry/shots.yaml, OUT/radiometry/CAM_TK_I.png
#ifndef FLAMERIG_PIPELINE_SIMULATE_H_
#define FLAMERIG_PIPELINE_SIMULATE_H_

#include <functional>
#include <string>
#include <vector>

#include "calibration/synthetic_rig.h"
#include "core/progress.h"
#include "fitting/renderer.h"
#include "fitting/synthetic_fire.h"
#include "pipeline/video_codec.h"

namespace flamerig {

struct SimulateConfig {
  std::uint64_t seed = 7;
  int frames = 1;
  double frame_rate_hz = 30.0;
  synthetic::FireOptions fire;
  std::string absorption = "soot";
  Box3 box{Eigen::Vector3d(-0.015, 0.0, -0.015), Eigen::Vector3d(0.015, 0.07, 0.015)};
  int grid_resolution = 64;
  bool auto_exposure = true;
  double exposure = 1.0;  // used when auto_exposure is false
  double noise_dn = 0.5;
  synthetic::RingOptions ring;
  bool calibration = true;
  synthetic::BoardSpec board;
  int shared_per_pair = 6;
  int closeups_per_camera = 4;
  synthetic::BoardLighting board_lighting;  // shadows, gradient and blur on the boards
  RenderOptions render;
  int pixel_samples = 1;        // N x N rays a pixel, averaged (render.pixel_samples); [1, 8]
  CameraRadiometry radiometry;  // of every camera
  bool codec_enabled = false;   // 8-bit frames through `codec`
  VideoCodecOptions codec;
  std::vector<Eigen::Vector3d>
      camera_gains;  // empty, or one per camera: multiplies radiometry.gain
  // Empty, or one per camera: the band-pass filter in front of that camera (replacing
  // radiometry's; fwhm 0 = none). Mono cameras behind two or more filters are two-colour
  // pyrometry's set-up.
  std::vector<SpectralBand> camera_filters;
  struct RadiometricShotsConfig {
    bool enabled = false;
    std::vector<double> temperatures_k{1300, 1600, 1900};
    std::vector<double> levels{0.05, 0.15, 0.35, 0.6, 0.85, 1.3};
    double emissivity = 0.98;
  } radiometric_calibration;
  // Camera c's radiometric model: radiometry with camera_gains[c] applied.
  CameraRadiometry CameraFilm(std::size_t c) const;

  // Reads the `simulate:` map of a YAML file; missing keys keep their defaults. Throws
  // InputError naming the file, the field and the rule.
  static SimulateConfig Load(const std::string& path);
  void Validate() const;  // throws InputError naming the field
};

struct SimulateSummary {
  std::string out_dir;
  int frames = 0;
  int cameras = 0;
  int calibration_views = 0;
  int calibration_images = 0;
  int radiometric_shots = 0;  // images of the black-body calibrator
  double exposure = 0;
  std::string exposure_source;          // "auto: ..." or "config"
  double saturated_pixel_fraction = 0;  // of fire pixels at frame 0
  RenderSummary last_render;  // with pixel_samples N > 1, of one of the N x N rays a pixel
  double time_s = 0;
};

// The camera settings at which a simulated camera records the dataset's frames as they were
// rendered: a capture config's default exposure time (CameraSettings::exposure_us, 10000 us) at
// 0 dB. dataset.yaml states it as `exposure_unit_us`, the exposure time at 0 dB that exposure 1
// stands for: that time over the dataset's exposure. The sim cameras' replay reads it
// (acquisition/sim_camera.h: a camera configured at half the time records half the light), and
// the radiometric calibrator's shots give their exposure as the camera's time over it
// (`exposure_us`, whole microseconds from 100 us up, `gain_db: 0`), so that the rig calibrated
// from them knows a recording's exposure from its cameras' settings, as a real rig's does
// (radiometric_calibration.h). Unlike a real sensor's, the unit is the dataset's own (its
// exposure is chosen per dataset): a rig calibrated from one dataset's shots holds for takes
// replaying that dataset, not another.
double SimExposureUnitUs(double exposure);

// The exposure that puts the 99.5th percentile of the brightest channel over the fire pixels
// (above 1e-3 of the brightest) of `linear` renders at full scale, so that the cores of the flame
// saturate slightly, as in real footage; 0 when no fire is visible. Not clamped to any range.
double AutoExposure(const std::vector<ImageF>& linear);

// What a camera with `radiometry` records of a linear render (in its response's channels, as
// FireRenderer gives it with RenderOptions::response): the signal clamp(exposure * linear, 0, 1)
// encoded to codes (radiometry.h), with Gaussian noise of `noise_dn` 8-bit units scaled to the
// camera's full scale added to the codes (rounded, clamped), deterministic in `seed`. Returns the
// bit depth of the frame written into *u8 (8: bit_depth 0 or 8) or *u16 (16: deeper cameras, codes
// in 0..2^bits - 1); one channel for a mono camera. The default camera gives exactly
// ApplyCameraResponse then AddSensorNoise.
int RecordCameraImage(const ImageF& linear, double exposure, const CameraRadiometry& radiometry,
                      double noise_dn, std::uint64_t seed, ImageU8* u8, ImageU16* u16);

// Writes the dataset into `out_dir`. Progress: stages "fire frames" (unit frames) and
// "calibration views" (unit views); cancelling throws Cancelled, leaving what was written.
// A folder that holds an earlier simulation (its dataset.yaml says `generator: flamerig
// simulate`) is simulated again: that simulation's folders (frames, truth, calibration,
// radiometry, cameras) are removed first, so that no frame of a longer earlier take stays behind.
// A folder that holds any of those but no simulation's dataset.yaml (an exported recording) is
// refused with an InputError, and nothing in it is touched. Other files in the folder are kept.
SimulateSummary Simulate(const SimulateConfig& config, const std::string& out_dir,
                         const ProgressCallback& progress = nullptr);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_SIMULATE_H_
