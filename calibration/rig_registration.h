// Where one rig's frame lies in another's, as their cameras see it.
//
// Two calibrations of the same cameras (or a simulator's rig and the rig `flamerig calibrate`
// builds from its board views) agree on what each camera sees, but not on the frame they express
// it in: the rig frame is a gauge that the calibration chooses (calibrate.h's RigFrame: the first
// camera's frame, or where the optical axes pass closest), and from noisy board corners it lands a
// little away from where another calibration put it. On the main job's calibrated rig (72 board
// views) the frame is 2.7 mm and 5.6 mrad from the simulator's, two or three fit voxels, while the
// motion between them explains what the cameras see to 0.012 mm. Comparing a fit in the calibrated
// frame with a truth in the simulator's, voxel by voxel, then scores that gauge as temperature error.
//
// RegisterRigs measures the rigid motion between the frames from the images, not from the camera
// poses (a calibration trades a camera's rotation against its principal point, and its distance
// against its focal length, without changing what it sees): points on a grid filling `from`'s box
// are projected by each of `from`'s cameras, the pixels are unprojected by the camera of the same
// name in `to`, and the rays are triangulated (the point nearest to all of them in the least-squares
// sense). The rigid motion that best maps the grid onto the triangulated points (Umeyama's, without
// scale) is `to_from_from`. What it cannot take up is the residual: the disagreement between the
// two rigs about the geometry itself (a scale, a lens).
#ifndef FLAMERIG_CALIBRATION_RIG_REGISTRATION_H_
#define FLAMERIG_CALIBRATION_RIG_REGISTRATION_H_

#include <string>

#include "calibration/pose.h"
#include "calibration/rig.h"

namespace flamerig {

struct RigRegistration {
  Rigid3 to_from_from;            // point_in_to = to_from_from * point_in_from
  double box_center_shift_m = 0;  // how far the motion moves the centre of `from`'s box
  double rotation_rad = 0;        // the motion's rotation angle
  double residual_rms_m = 0;      // triangulated points against the moved grid, RMS distance
  int points = 0;                 // grid points seen by at least two cameras of `to`
  // One line for a log or report: "1.16 mm, 1.53 mrad, residual 0.020 mm over 729 points".
  std::string Describe() const;
};

// The motion of `from`'s frame into `to`'s (see above), from a grid of samples_per_axis^3 points
// in `from`'s box. Cameras are paired by name; a grid point counts when it projects inside the
// image of at least two cameras and their rays in `to` meet it from different directions. Throws
// InputError when `from`'s box is invalid, when a camera of `from` is missing from `to` or has
// another image size there (naming it), when fewer than two cameras are paired, or when fewer than
// 4 points are seen.
RigRegistration RegisterRigs(const Rig& from, const Rig& to, int samples_per_axis = 9);

}  // namespace flamerig

#endif  // FLAMERIG_CALIBRATION_RIG_REGISTRATION_H_
