// `flamerig calibrate`: from board views (a folder of images or a recording) to a rig on disk, with
// a report a person can read.
//
// Config (YAML, every key optional; see config/calibrate_sim.yaml):
//   calibrate:
//     board: {type: charuco, squares: [7, 5], square_m: 0.006, marker_m: 0.0045,
//             aruco_dictionary: 0}   # or board_file: PATH (a board.yaml); default: the
//                                    # board.yaml beside the images, if there is one
//     cameras: [cam0, cam1]          # order (the first is mrcal's reference); default: sorted
//     lensmodel: LENSMODEL_OPENCV8
//     focal_px: 0                    # seed; 0 = estimate from the board
//     outlier_rejection: true
//     board_warp: true               # solve the board's bow (mrcal's calobject_warp)
//     uncertainty_trials: 20         # Monte Carlo solves for the projection uncertainty; 0: off
//                                    # (each figure uncertain by 1/sqrt(2(N-1)): 16% at 20)
//     regularization: true           # mrcal's light pull of the distortion towards zero
//     valid_intrinsics_region_parameters: [1, 0.5, 1.5, 3, 0]
//                                    # mrcal-calibrate-cameras's, in its order: uncertainty and
//                                    # stdev (x the residuals' deviation), mean (px), count, and
//                                    # the distance (m) the uncertainty is evaluated at (0:
//                                    # infinity; a rig's working distance is more telling)
//     detect:                        # calibration/board.h DetectOptions
//       detector: auto               # chessboards: auto (classic, then sb) | classic | sb
//       min_corners: 6
//       max_misfit_squares: 0.1      # consistency with the neighbouring corners
//       sb_accuracy: true
//       subpix_half_window: 0        # classic: cornerSubPix half window, px (0: 5 or less)
//       subpix_iterations: 40
//       subpix_epsilon: 0.001
//     min_views_per_camera: 3
//     frame: first-camera            # first-camera | ring (calibration/calibrate.h)
//     ring_origin: [0, 0, 0]         # the rig origin in the ring frame, metres
//     box: {min: [x, y, z], max: [x, y, z]}   # reconstruction box in that frame, metres
//                                    # (default: a cube around the boards seen, or the ring's
//                                    # origin)
//     name: calibrated
//
// Outputs in OUT:
//   rig.yaml, cameras/<camera>.cameramodel   the rig (reconstruct and fit read it; mrcal's tools
//                                            read the models)
//   report.md                                RMS (per point and per coordinate), per-camera
//                                            residuals, projection uncertainty over the box (in
//                                            pixels and voxels of the default grid, a warning
//                                            over half a voxel), worst corners, every image
//                                            without a
//                                            board and every corner left out (with the reason),
//                                            notes, pictures:
//   coverage_<camera>.png                    the image area covered by corners, coloured by error
//   residuals_<camera>.png                   each corner's residual as an arrow over the image
//   per_image_<camera>.png                   the RMS residual of each of its images
//   rig_top.png                              the rig from above: cameras, box, board positions
//   corners.vnl                              the detections in mrcal's corners format (re-solve
//                                            with mrcal-calibrate-cameras)
//   detections.cache                         so that a second run detects nothing again
#ifndef FLAMERIG_PIPELINE_CALIBRATE_JOB_H_
#define FLAMERIG_PIPELINE_CALIBRATE_JOB_H_

#include <optional>
#include <string>
#include <vector>

#include "calibration/calibrate.h"
#include "pipeline/valid_region.h"

namespace flamerig {

struct CalibrateConfig {
  std::optional<BoardSpec> board;  // unset: board.yaml beside the images
  std::vector<std::string> cameras;
  CalibrationOptions options;
  DetectOptions detect;
  // Monte Carlo solves for the projection uncertainty (calibration/calibrate.h); 0: none.
  int uncertainty_trials = 20;
  // The valid-intrinsics region written into each model (pipeline/valid_region.h).
  ValidRegionParameters valid_region;
  // Reads the `calibrate:` map of a YAML file; errors (InputError) name the file and
  // key. Relative board_file paths are relative to the config file.
  static CalibrateConfig Load(const std::string& path);
};

struct CalibrateInput {
  std::string images_dir;     // DIR/<view>/<camera>.png, or
  std::string recording_dir;  // a flamerig recording
};

// Detects, solves and writes everything listed above into out_dir. Into an out_dir holding an
// earlier calibration (a rig.yaml) only the detection cache is written before the solve and the
// uncertainty are done, so that a failed or cancelled run leaves it whole; into a fresh one
// corners.vnl is written first, for mrcal's tools when the solve fails. Refuses (InputError) an
// input that is not a folder and an out_dir holding a simulated dataset (dataset.yaml: its rig is
// the truth). Returns the summary; the data (detections) through *data when not null.
CalibrationSummary RunCalibration(const CalibrateConfig& config, const CalibrateInput& input,
                                  const std::string& out_dir,
                                  const CalibrationProgress& progress = nullptr,
                                  CalibrationData* data = nullptr);

// The report pictures, exposed for tests: corners over the image area (RGB, at most 800 px wide),
// and the rig from above (RGB, size x size).
ImageU8 CoveragePicture(const CalibrationData& data, const CalibrationSummary& summary, int camera,
                        double* covered_fraction);
ImageU8 RigFromAbove(const CalibrationSummary& summary, int size = 700);
// Each inlier corner's residual as an arrow over the image area (magnified so that the 95th
// percentile is 25 picture pixels long; the factor is in the label): a calibrator reads a lens
// model that does not fit from arrows that turn together. RGB, at most 800 px wide.
ImageU8 ResidualVectorsPicture(const CalibrationData& data, const CalibrationSummary& summary,
                               int camera);
// The RMS residual of each board observation of one camera, in view order, with the camera's
// median, so that a bad image stands out. RGB.
ImageU8 ResidualsPerImagePicture(const CalibrationData& data, const CalibrationSummary& summary,
                                 int camera);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_CALIBRATE_JOB_H_
