// A rig: the calibrated cameras of one capture setup in one common frame (the rig frame), plus the
// reconstruction box, the axis-aligned region of the rig frame where the fire is reconstructed.
//
// On disk a rig is a YAML file that refers to one mrcal .cameramodel file per camera (paths
// relative to the YAML file):
//
//   rig:
//     name: sim                     # free text
//     up: [0, 1, 0]                 # the rig frame's up direction (y up by default)
//     box:                          # reconstruction box in the rig frame, metres
//       min: [-0.05, 0.0, -0.05]
//       max: [ 0.05, 0.15, 0.05]
//     exposure_unit_us: 2000        # optional: the exposure time (us, at 0 dB) that a fit's
//                                   # exposure 1 stands for, from a radiometric calibration whose
//                                   # shots gave their exposure times
//     cameras:
//       - name: cam0                # unique; used to name images and outputs
//         model: cameras/cam0.cameramodel
//         radiometry: {transfer: linear, bit_depth: 12}   # optional; radiometry.h
//
// Load errors name the file, the field and the rule broken (InputError).
#ifndef FLAMERIG_CALIBRATION_RIG_H_
#define FLAMERIG_CALIBRATION_RIG_H_

#include <Eigen/Core>
#include <string>
#include <vector>

#include "calibration/camera_model.h"
#include "calibration/radiometry.h"

namespace flamerig {

// An axis-aligned box in the rig frame, metres.
struct Box3 {
  Eigen::Vector3d min_in_rig = Eigen::Vector3d::Zero();
  Eigen::Vector3d max_in_rig = Eigen::Vector3d::Zero();

  Eigen::Vector3d center() const { return 0.5 * (min_in_rig + max_in_rig); }
  Eigen::Vector3d size() const { return max_in_rig - min_in_rig; }
  bool IsValid() const {
    return min_in_rig.allFinite() && max_in_rig.allFinite() &&
           (max_in_rig.array() > min_in_rig.array()).all();
  }
};

struct RigCamera {
  std::string name;
  std::string model_path;  // as written in the YAML (relative to it), for Save()
  CameraModel model;
  // How its pixels' codes relate to radiance (radiometry.h); the default is today's sRGB camera.
  CameraRadiometry radiometry;
};

struct Rig {
  std::string name;
  Eigen::Vector3d up_in_rig = Eigen::Vector3d::UnitY();
  Box3 box;
  std::vector<RigCamera> cameras;
  // The exposure time in microseconds, at 0 dB of gain, that the renderer's exposure 1 stands for
  // in the cameras' radiometric gains: set by `flamerig calibrate-radiometry` when its shots give
  // their exposure times (pipeline/radiometric_calibration.h); 0 when the rig does not know. With
  // it a recording's exposure is known from its first camera's settings at the start (`run`).
  double exposure_unit_us = 0;

  // Index of the camera called `name`, or -1.
  int FindCamera(const std::string& camera_name) const;

  // Reads a rig YAML file and every camera model it names.
  static Rig Load(const std::string& yaml_path);
  // Writes the YAML and one .cameramodel per camera (at the cameras' model_path, relative to the
  // YAML file's directory; default cameras/<name>.cameramodel). Creates directories as needed.
  void Save(const std::string& yaml_path) const;
};

}  // namespace flamerig

#endif  // FLAMERIG_CALIBRATION_RIG_H_
