// Joint calibration of a rig of cameras from views of a calibration board, with mrcal.
//
// Flow (DESIGN.md section 4):
//   images or a recording -> DetectViews() (OpenCV board detection, cached by image content)
//   -> Calibrate(): intrinsics seeded from the board homographies (or a given focal length),
//      per-view board poses from solvePnP, camera poses chained through views that neighbouring
//      cameras share (cameras around a flame never all see one board), then one joint
//      mrcal_optimize over all intrinsics, extrinsics and board poses: first with the lens
//      distortion held at zero, then everything, with mrcal's outlier rejection when asked
//   -> a Rig in a frame the user can rely on (see RigFrame), with the reconstruction box given in
//      that frame (or a default one around the boards seen), and a CalibrationSummary with the
//      residuals; EstimateProjectionUncertainty() then says how well it projects over the box.
//
// Gauge: mrcal's reference frame is the first camera's. The rig frame is then chosen by
// RigFrame::kFirstCamera (default) or kRing; changing frame moves every camera by the same rigid
// transform and changes no residual.
//
// Residuals: a corner's reprojection error is the distance in pixels between where it was detected
// and where the solved model projects it. RMS "per point" is sqrt(mean(dx^2 + dy^2)); RMS "per
// coordinate" (mrcal's convention) is sqrt(mean over dx and dy separately), smaller by sqrt(2). Both
// are over the inliers and reported with their names. mrcal-calibrate-cameras's figure is per
// coordinate but divides by every board corner, outliers and corners not detected included
// (CalibrationSummary::mrcal_rms_px).
//
// Errors: bad input (a camera that never sees the board, too few views, a disconnected camera
// graph, images of different sizes for one camera) throws CalibrationError with a message naming
// the camera and the reason. Library code prints nothing; progress goes to a callback.
#ifndef FLAMERIG_CALIBRATION_CALIBRATE_H_
#define FLAMERIG_CALIBRATION_CALIBRATE_H_

#include <functional>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "calibration/board.h"
#include "calibration/rig.h"
#include "core/error.h"
#include "core/progress.h"

namespace flamerig {

struct MrcalProblem;  // calibration/mrcal_inputs.h

class CalibrationError : public DataError {
 public:
  using DataError::DataError;
};

// One camera's view of the board at one instant.
struct BoardObservation {
  int camera = 0;            // index into CalibrationData::camera_names
  int view = 0;              // index into CalibrationData::view_names
  std::string source;        // the image file or "recording set N", for messages and the report
  BoardDetection detection;  // found() is true for every observation kept
};

// Everything a solve needs, gathered from images or a recording.
struct CalibrationData {
  BoardSpec board;
  std::vector<std::string> camera_names;
  std::vector<int> widths, heights;            // imager size per camera, pixels
  std::vector<std::string> view_names;         // one per instant (a folder, a frame set)
  std::vector<BoardObservation> observations;  // found boards only, sorted by view then camera
  // Per camera: images looked at, and why the board was not found in the others.
  std::vector<int> images_per_camera;
  std::vector<std::vector<std::string>> failures_per_camera;  // every one, "<source>: <reason>"
  // A recording's frames that could not be read (a damaged file: a checksum that fails, a data
  // file cut short or gone): each is one of failures_per_camera, "unreadable: <why>", and the
  // calibration goes on without it, as `export` and `run` do. An image file that does not read
  // is an error.
  int unreadable = 0;
  // Detection work: images detected now, and images whose detection came from the cache.
  int detected = 0;
  int from_cache = 0;
  double detect_time_s = 0;
};

// Progress (core/progress.h): stages "detect" (unit images) and "solve" (unit solves). A cancel
// stops detection at the next image (what was detected is kept in the cache) or before the solve,
// and throws Cancelled.
using CalibrationProgress = ProgressCallback;

// Reads board views from a folder laid out as `flamerig simulate` and `flamerig export` write
// them: DIR/<view>/<camera>.png, one subfolder per instant (view_000, frame_000000, ...), or from a
// recording (frame sets decoded to grey). Camera names are the image stems (or the recording's
// camera names), sorted; `cameras`, when not empty, gives the order and must all be present.
// Detections are cached in `cache_path` (empty: no cache) keyed by the board description and a
// CRC of each image's pixels, so that a second run detects nothing again. Detection runs on all
// cores. Unreadable or corrupt images throw CalibrationError naming the file.
CalibrationData DetectViewsInFolder(const std::string& dir, const BoardSpec& board,
                                    const std::vector<std::string>& cameras,
                                    const std::string& cache_path, const DetectOptions& detect = {},
                                    const CalibrationProgress& progress = nullptr);
CalibrationData DetectViewsInRecording(const std::string& recording_dir, const BoardSpec& board,
                                       const std::vector<std::string>& cameras,
                                       const std::string& cache_path,
                                       const DetectOptions& detect = {},
                                       const CalibrationProgress& progress = nullptr);

// The rig frame of the result.
enum class RigFrame {
  // Origin where the cameras' optical axes pass closest to each other (the flame, for a ring of
  // cameras looking at it), y up (opposite to the mean of the cameras' image-down directions), z
  // towards the first camera (horizontally). For `flamerig simulate`'s rigs this is the simulated
  // rig frame moved to the box centre.
  kRing,
  // mrcal's reference: the first camera's frame (x right, y down, z forward); up is -y.
  kFirstCamera,
};

struct CalibrationOptions {
  std::string lensmodel = "LENSMODEL_OPENCV8";  // any mrcal lens model with a core (fx fy cx cy)
  double focal_px = 0;            // seed focal length; 0: estimated from the board homographies
  bool outlier_rejection = true;  // mrcal's; turn off only for exact synthetic corners
  bool regularization = true;     // mrcal's light pull of the distortion towards zero
  // Solve for the board's flatness as mrcal does (calobject_warp: a parabolic bow along each of
  // its axes, in metres at the board's centre), as mrcal-calibrate-cameras does by default: a
  // printed board is never quite flat, and an unmodelled bow biases the intrinsics.
  bool board_warp = true;
  int min_views_per_camera = 3;  // fewer views give weak intrinsics: an error
  // The first camera's frame fits any rig (a stereo pair, a row, a ring). The ring frame only when
  // asked: it needs at least two cameras whose optical axes meet, which is checked on the first
  // estimate of the camera poses, before the solve.
  RigFrame frame = RigFrame::kFirstCamera;
  // kRing only: where the rig origin sits in the ring frame, metres. (0, -0.035, 0) puts it 35 mm
  // below the point where the optical axes meet (the burner under a flame, say).
  Eigen::Vector3d ring_origin_m = Eigen::Vector3d::Zero();
  // Reconstruction box in the rig frame. Invalid (the default): a cube of side 0.3 times the mean
  // camera distance, around the origin for kRing, around the middle of the boards seen (where
  // the calibration was done, which is where the cameras look) for kFirstCamera.
  Box3 box;
  std::string rig_name = "calibrated";
  // Refuse a solve no lens gives (Calibrate's comment). Off only for the uncertainty's Monte Carlo
  // trials of a solve that passed.
  bool check_solve = true;
  // Throws InputError naming the field and the rule.
  void Validate() const;
};

struct ObservationError {
  int camera = 0, view = 0, corner = 0;
  double error_px = 0;  // distance between detected and projected corner
  bool outlier = false;
  Eigen::Vector2d residual_px =
      Eigen::Vector2d::Zero();  // projected minus detected (0 if not finite)
};

struct CameraResidualStats {
  std::string name;
  int views = 0, points = 0, outliers = 0;
  double rms_px_per_point = 0, median_px = 0, p95_px = 0, max_px = 0;  // inliers
};

struct CalibrationSummary {
  Rig rig;
  std::vector<Rigid3> rig_from_board;  // per view (identity where no camera saw it)
  std::vector<bool> view_used;
  double rms_px_per_coordinate = 0;  // inliers; mrcal's per-coordinate convention
  double rms_px_per_point = 0;       // inliers
  double seed_rms_px_per_point = 0;  // before the joint solve (pinhole seed)
  // mrcal_optimize's own figure (mrcal_stats_t, what mrcal-calibrate-cameras prints): per
  // coordinate, but divided by every corner of every board observation, outliers and corners not
  // detected included, so smaller than rms_px_per_coordinate by sqrt(inliers / all corners).
  double mrcal_rms_px = 0;
  // Corners detected and used (`points`), and of those the ones mrcal's outlier rejection threw
  // out (`outliers`).
  int points = 0, outliers = 0, views_used = 0;
  // Board corners in the observations that were not detected (outside the image, hidden, or left
  // out by the detection's consistency check: `rejected_in_detection` of them). mrcal counts them
  // as outliers too: mrcal_outliers (its Noutliers) = outliers + missing_corners.
  int missing_corners = 0, rejected_in_detection = 0, mrcal_outliers = 0;
  // The board's bow solved with board_warp (mrcal's calobject_warp x2, y2), metres; 0 without.
  double board_warp_x_m = 0, board_warp_y_m = 0;
  std::vector<CameraResidualStats> cameras;
  std::vector<ObservationError> errors;  // every corner, observation order
  std::vector<ObservationError> worst;   // the largest inlier errors, largest first (up to 12)
  double solve_time_s = 0;
  std::vector<std::string> notes;  // views left out and why, frame choice, ...
  // The final solve as mrcal took it (mrcal's frame, outliers marked), for the models'
  // optimization_inputs (calibration/mrcal_inputs.h), so that mrcal's tools read them.
  std::shared_ptr<const MrcalProblem> mrcal_problem;
  std::string BriefReport() const;
};

// Solves the calibration. Throws CalibrationError naming the camera and reason when the data
// cannot give a calibration (see the file comment) or the solve gives one no lens has (a focal
// length outside 0.05 to 100 times the imager's larger side, a principal point more than half the
// imager outside it, a camera's corners over 10 px RMS or every one an outlier: a wrong board
// description, say; over 2 px, or over half the corners outliers, is a warning in the notes),
// InputError for invalid options. Progress: stage "solve"; a cancel
// before, between or after mrcal's two solves throws Cancelled.
CalibrationSummary Calibrate(const CalibrationData& data, const CalibrationOptions& options,
                             const CalibrationProgress& progress = nullptr);

// The projection uncertainty of each calibrated camera over the reconstruction box: how far, in
// pixels (1 sigma), the camera's projection of a point of the box moves when the corners carry
// the noise the solve found in them. mrcal computes this by linearising its solve (in its Python
// tools only, notes/mrcal.md); here it is computed as mrcal's own tests check that linearisation:
// by Monte Carlo. The solved rig and board poses are taken as the truth, their corners re-made
// exactly, Gaussian noise at the solve's RMS per coordinate added, and the calibration solved
// again `trials` times with the same options; the spread of each box point's projection is the
// uncertainty. As in mrcal ("mean-frames"), a point is held fixed in the world the boards define
// (carried through every board pose and averaged), not in the first camera's frame: near where
// the boards were, a shift of the principal point and a turn of the camera cancel.
struct CameraUncertainty {
  std::string name;
  // 1 sigma in the worst direction (mrcal's 'worstdirection-stdev'), over a 5x5x5 grid of the
  // box's points.
  double max_px = 0, mean_px = 0;
  // max_px as a distance at the point's depth, in voxels of `voxel_m` (the default grid's).
  double max_voxels = 0;
};
struct ProjectionUncertainty {
  std::vector<CameraUncertainty> cameras;
  int trials = 0;
  double noise_px = 0;  // the noise added, per coordinate
  double voxel_m = 0;
  double time_s = 0;
  // "cam1: 0.62 voxel (1 sigma) over the box, more than half a voxel" for each camera over half a
  // voxel; empty when none is.
  std::vector<std::string> warnings;
};
// Progress: stage "uncertainty", unit solves, before each trial; a cancel there throws Cancelled.
// Throws CalibrationError when a trial's solve fails; InputError for trials < 2 or a voxel size
// that is not positive. Each figure is a standard deviation from `trials` samples, so it carries
// a sampling error of about 1 / sqrt(2 (trials - 1)) of itself (16% at 20, 5% at 200); the
// largest over the box's points leans high by about as much.
ProjectionUncertainty EstimateProjectionUncertainty(const CalibrationData& data,
                                                    const CalibrationSummary& summary,
                                                    const CalibrationOptions& options, int trials,
                                                    double voxel_m, std::uint64_t seed = 1,
                                                    const CalibrationProgress& progress = nullptr);

// Reads the text of a detection cache (the file DetectViews keeps): a first line
// "# flamerig board detections v2", then "board <BoardSpec::Describe()>" and
// "detect <DetectOptions::Describe()>" (a cache made for another board or other detector settings
// is ignored), then per image: "<key> <n> <failure reason>" for n = 0, else "<key> <n>" and n
// triples "<corner id> <x px> <y px>" in ascending id order; after it, optionally,
// "<key> detector <name>" and one "<key> reject <corner id> <x px> <y px> <reason>" per corner
// left out. A line that is malformed, names a corner the board does not have, is out of order or
// gives a non-finite position is dropped (the image is then detected again; a bad reject line
// drops its image's entry). Adds the entries to *entries and returns how many; never throws.
int ParseDetectionCache(const std::string& text, const BoardSpec& board,
                        const DetectOptions& detect,
                        std::map<std::string, BoardDetection>* entries);

// The extension an observation's image has in mrcal's corners file: the image file's own (".jpg",
// ".JPG", ...) or ".png" for frames from a recording.
std::string MrcalImageExtension(const std::string& source);

// Writes our detections as mrcal's corners cache (vnlog "# filename x y level"; a missing corner
// has level "-"), with file names <dir_prefix>/<view>/<camera><ext> (ext: MrcalImageExtension of
// the image the corners came from), so that
// `mrcal-calibrate-cameras --corners-cache F --object-width-n W --object-height-n H
// 'prefix/*/cam0.png' ...` solves the same problem (for whole boards: mrcal 2.2 seeds its board
// poses from every corner, the missing ones' placeholder positions included, so views of part of a
// ChArUco board start it far off; measured: RMS 3.5 px and a third of the corners outliers where
// our solve has 0.08 px). Written atomically; throws CalibrationError when it cannot be.
void WriteMrcalCorners(const CalibrationData& data, const std::string& path,
                       const std::string& dir_prefix);

}  // namespace flamerig

#endif  // FLAMERIG_CALIBRATION_CALIBRATE_H_
