// Rigid transforms with named frames.
//
// A Rigid3 named `b_from_a` maps a point expressed in frame a to the same point expressed in frame
// b: point_in_b = b_from_a * point_in_a. Compose as c_from_a = c_from_b * b_from_a. The rig frame
// is the common frame of all cameras of a rig; y is up in the rig frame unless a calibration
// defines otherwise. Camera frames follow mrcal and OpenCV: x right, y down, z forward (along the
// optical axis).
//
// mrcal stores poses as rt: a Rodrigues rotation vector r (axis times angle, radians) followed by a
// translation t, with point_in_b = R(r) point_in_a + t. ToRt/FromRt convert without the loss of
// precision that mrcal 2.2's mrcal_r_from_R has near 180 degrees (notes/mrcal.md).
#ifndef FLAMERIG_CALIBRATION_POSE_H_
#define FLAMERIG_CALIBRATION_POSE_H_

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>

namespace flamerig {

struct Rigid3 {
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();

  Rigid3() = default;
  Rigid3(const Eigen::Quaterniond& q, const Eigen::Vector3d& t)
      : rotation(q.normalized()), translation(t) {}

  Eigen::Vector3d operator*(const Eigen::Vector3d& point) const {
    return rotation * point + translation;
  }
  Rigid3 operator*(const Rigid3& other) const {
    return Rigid3(rotation * other.rotation, rotation * other.translation + translation);
  }
  Rigid3 Inverse() const {
    Eigen::Quaterniond inv = rotation.conjugate();
    return Rigid3(inv, -(inv * translation));
  }
  Eigen::Matrix3d RotationMatrix() const { return rotation.toRotationMatrix(); }

  // rt = (r, t), r a Rodrigues vector with |r| in [0, pi]. FromRt takes any |r| up to
  // kMaxRotationAngle and throws InputError for a larger one or a value that is not finite (a
  // camera model's extrinsics of 1e300 made NaN rotations that crashed the tomography).
  static constexpr double kMaxRotationAngle = 1000;
  std::array<double, 6> ToRt() const;
  static Rigid3 FromRt(const std::array<double, 6>& rt);
  static Rigid3 FromRt(const double* rt);
};

// The pose of a camera placed at `eye_in_rig` looking at `target_in_rig`, with image "up" as close
// as possible to `up_in_rig`. Returns cam_from_rig. Throws InputError when eye and
// target coincide or the viewing direction is parallel to up.
Rigid3 LookAt(const Eigen::Vector3d& eye_in_rig, const Eigen::Vector3d& target_in_rig,
              const Eigen::Vector3d& up_in_rig = Eigen::Vector3d::UnitY());

}  // namespace flamerig

#endif  // FLAMERIG_CALIBRATION_POSE_H_
