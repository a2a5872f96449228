// mrcal's "optimization inputs": everything a calibration solve used (every camera's intrinsics
// and pose, every board pose, every corner with its outlier mark, the board and the solve's
// switches), stored in each .cameramodel as mrcal-calibrate-cameras stores them, so that mrcal's
// own tools (mrcal-show-projection-uncertainty, mrcal-show-valid-intrinsics-region,
// mrcal.projection_uncertainty, mrcal.cameramodel.optimization_inputs) work on our models.
//
// Format (mrcal 2.2, mrcal/cameramodel.py's _serialize_optimization_inputs): a dict of numpy
// arrays and scalars written as a numpy .npz (a zip of .npy files, here deflated), encoded with
// base85 (Python's base64.b85encode alphabet) and stored as the model's
// 'optimization_inputs': b'...' entry, beside 'icam_intrinsics': the camera's index in the solve.
// None is stored as '' (mrcal's convention). The keys are those mrcal-calibrate-cameras 2.2 writes
// for a board calibration: lensmodel, intrinsics, extrinsics_rt_fromref, frames_rt_toref,
// points (None), calobject_warp, indices_frame_camintrinsics_camextrinsics, observations_board,
// indices_point_camintrinsics_camextrinsics (None), observations_point (None),
// calibration_object_spacing, imagersizes, the do_optimize_* and do_apply_* switches, verbose.
#ifndef FLAMERIG_CALIBRATION_MRCAL_INPUTS_H_
#define FLAMERIG_CALIBRATION_MRCAL_INPUTS_H_

#include <array>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace flamerig {

// One board solve as mrcal_optimize took it, after the solve (outliers marked), in mrcal's frame
// (the first camera's).
struct MrcalProblem {
  std::string lensmodel;
  int num_cameras = 0;
  int num_params = 0;                               // intrinsics per camera
  std::vector<double> intrinsics;                   // num_cameras x num_params
  std::vector<std::array<double, 6>> extrinsics;    // rt_cam_ref of cameras 1.., num_cameras - 1
  std::vector<std::array<double, 6>> frames;        // rt_ref_board, one per frame
  std::array<double, 2> calobject_warp{0, 0};       // x2, y2
  std::vector<std::array<int32_t, 3>> indices;      // per observation: frame, camera, camera - 1
  int board_width = 0, board_height = 0;            // corners along x and y
  std::vector<double> observations;                 // per observation H x W x (x, y, weight)
  std::vector<std::array<int32_t, 2>> imagersizes;  // per camera
  double spacing_m = 0;                             // the board's corner spacing
  bool optimize_intrinsics_core = true, optimize_intrinsics_distortions = true,
       optimize_extrinsics = true, optimize_frames = true, optimize_calobject_warp = true,
       apply_regularization = true, apply_outlier_rejection = true;
};

// The problem as mrcal serialises it: the base85 text of its .npz (without the b'' quotes).
// Throws DataError when its arrays' sizes disagree with its counts, the lens model's name is not
// ASCII, or the .npz would exceed 4 GiB (no zip64).
std::string SerializeMrcalOptimizationInputs(const MrcalProblem& problem);

// Adds 'icam_intrinsics' and 'optimization_inputs' to a .cameramodel that CameraModel::Save
// wrote (AddCameraModelFields). Throws as that does.
void AddMrcalOptimizationInputs(const std::string& cameramodel_path, const std::string& serialized,
                                int icam_intrinsics);

// Inserts `fields` (lines of "    'key': value,\n", comments allowed) before a .cameramodel's
// closing brace; the file is rewritten atomically. Throws IoError when the file cannot be read or
// written, DataError when it has no closing brace.
void AddCameraModelFields(const std::string& cameramodel_path, const std::string& fields);

namespace internal {
// Exposed for tests: Python's base64.b85encode(bytes) (pad=False), and a .npz of named .npy
// members (zip, deflated) as numpy.savez_compressed writes one.
std::string Base85Encode(std::string_view bytes);
struct NpyMember {
  std::string name;                // without ".npy"
  std::string descr;               // numpy dtype: "<f8", "<i4", "|b1", "<U17"
  std::vector<std::size_t> shape;  // empty: a scalar
  std::string data;                // the raw little-endian values, C order
};
std::string WriteNpz(const std::vector<NpyMember>& members);
}  // namespace internal

}  // namespace flamerig

#endif  // FLAMERIG_CALIBRATION_MRCAL_INPUTS_H_
