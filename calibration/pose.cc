#include "calibration/pose.h"

#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>

#include "core/error.h"
#include "core/format.h"

namespace flamerig {

std::array<double, 6> Rigid3::ToRt() const {
  // Eigen's quaternion-to-angle-axis uses atan2 on the vector and scalar parts, which stays
  // accurate at every angle including pi (unlike acos((trace - 1) / 2)).
  Eigen::Quaterniond q = rotation.normalized();
  if (q.w() < 0) q.coeffs() = -q.coeffs();  // angle in [0, pi]
  Eigen::AngleAxisd aa(q);
  Eigen::Vector3d r = aa.axis() * aa.angle();
  if (!std::isfinite(r.x()) || aa.angle() == 0.0) r.setZero();
  return {r.x(), r.y(), r.z(), translation.x(), translation.y(), translation.z()};
}

Rigid3 Rigid3::FromRt(const double* rt) {
  for (int i = 0; i < 6; ++i)
    if (!std::isfinite(rt[i]))
      throw InputError("pose rt[" + std::to_string(i) + "] = " + FormatNumber(rt[i]) +
                       " is not finite");
  Eigen::Vector3d r(rt[0], rt[1], rt[2]);
  // stableNorm: |r| of a vector like (1e300, 0, 0) without overflowing its square.
  double angle = r.stableNorm();
  if (angle > kMaxRotationAngle)
    throw InputError("pose rotation vector of " + FormatNumber(angle) +
                     " rad is not an angle (at most " + FormatNumber(kMaxRotationAngle) +
                     " rad: a rotation holds its angle modulo 2 pi, and cos and sin of a larger "
                     "one lose its digits)");
  Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
  if (angle > 0) q = Eigen::Quaterniond(Eigen::AngleAxisd(angle, r / angle));
  return Rigid3(q, Eigen::Vector3d(rt[3], rt[4], rt[5]));
}

Rigid3 Rigid3::FromRt(const std::array<double, 6>& rt) { return FromRt(rt.data()); }

Rigid3 LookAt(const Eigen::Vector3d& eye_in_rig, const Eigen::Vector3d& target_in_rig,
              const Eigen::Vector3d& up_in_rig) {
  Eigen::Vector3d z = target_in_rig - eye_in_rig;
  if (z.norm() < 1e-12) throw InputError("LookAt: eye and target coincide");
  z.normalize();
  Eigen::Vector3d x = z.cross(up_in_rig);
  if (x.norm() < 1e-9) throw InputError("LookAt: viewing direction is parallel to up");
  x.normalize();
  Eigen::Vector3d y = z.cross(x);  // image down
  Eigen::Matrix3d rig_from_cam_rotation;
  rig_from_cam_rotation << x, y, z;
  Rigid3 rig_from_cam(Eigen::Quaterniond(rig_from_cam_rotation), eye_in_rig);
  return rig_from_cam.Inverse();
}

}  // namespace flamerig
