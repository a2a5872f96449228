// RegisterRigs: the motion between two rigs' frames, as their cameras see it. The oracles are
// motions applied by the test itself, and a camera changed in a way its images cannot tell.
#include "calibration/rig_registration.h"

#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "calibration/synthetic_rig.h"
#include "core/error.h"

namespace flamerig {
namespace {

const Box3 kBox{Eigen::Vector3d(-0.015, 0.0, -0.015), Eigen::Vector3d(0.015, 0.07, 0.015)};

Rig TwoViews() {
  synthetic::RingOptions o;  // two cameras, front and side, as the paper's
  o.fill = 0.6;
  return synthetic::MakeRingRig(kBox, o, "true");
}

// The same cameras expressed in another frame: point_in_moved = moved_from_rig * point_in_rig.
Rig Moved(const Rig& rig, const Rigid3& moved_from_rig) {
  Rig out = rig;
  out.name = "moved";
  for (RigCamera& c : out.cameras)
    c.model.set_cam_from_rig(c.model.cam_from_rig() * moved_from_rig.Inverse());
  return out;
}

double AngleBetween(const Rigid3& a, const Rigid3& b) {
  return a.rotation.angularDistance(b.rotation);
}

TEST(RigRegistration, TheSameRigIsTheIdentity) {
  const Rig rig = TwoViews();
  const RigRegistration r = RegisterRigs(rig, rig);
  EXPECT_EQ(r.points, 9 * 9 * 9);  // every grid point is seen by both cameras
  EXPECT_LT(r.box_center_shift_m, 1e-9);
  EXPECT_LT(r.rotation_rad, 1e-9);
  EXPECT_LT(r.residual_rms_m, 1e-9);
}

// A calibration's gauge: the frame a millimetre and a few milliradians away. The motion comes
// back, and no residual is left because the cameras agree on the geometry.
TEST(RigRegistration, RecoversTheMotionBetweenTwoFramesOfTheSameCameras) {
  const Rig rig = TwoViews();
  const Rigid3 motion(
      Eigen::Quaterniond(Eigen::AngleAxisd(0.003, Eigen::Vector3d(1, 2, -1).normalized())),
      Eigen::Vector3d(0.0004, -0.0003, -0.0011));
  const RigRegistration r = RegisterRigs(rig, Moved(rig, motion));
  EXPECT_EQ(r.points, 9 * 9 * 9);
  EXPECT_LT(AngleBetween(r.to_from_from, motion), 1e-7);
  EXPECT_LT((r.to_from_from.translation - motion.translation).norm(), 1e-8);
  EXPECT_NEAR(r.rotation_rad, 0.003, 1e-7);
  EXPECT_NEAR(r.box_center_shift_m, (motion * kBox.center() - kBox.center()).norm(), 1e-8);
  EXPECT_LT(r.residual_rms_m, 1e-8);
  // And back.
  const RigRegistration back = RegisterRigs(Moved(rig, motion), rig);
  EXPECT_LT(AngleBetween(back.to_from_from, motion.Inverse()), 1e-7);
  EXPECT_LT((back.to_from_from * (motion * kBox.center()) - kBox.center()).norm(), 1e-8);
}

// A calibration trades a camera's rotation against its principal point: a pinhole camera turned
// by a small angle about its own y axis and with its principal point moved by fx tan(angle) sees
// the box's middle where it did. Comparing the camera poses reports the turn; the images do not.
TEST(RigRegistration, MeasuresWhatTheImagesSeeNotTheCameraPoses) {
  synthetic::RingOptions o;
  o.fill = 0.6;
  o.lensmodel = "LENSMODEL_PINHOLE";
  const Rig rig = synthetic::MakeRingRig(kBox, o, "true");
  Rig traded = rig;
  const double angle = 0.004;  // radians: 1.2 mm at the box, 2 px
  CameraModel& m = traded.cameras[1].model;
  std::vector<double> k = m.intrinsics();
  k[2] -= k[0] * std::tan(angle);
  m = CameraModel(m.lensmodel(), k, m.cam_from_rig(), m.width(), m.height());
  const Rigid3 turn(Eigen::Quaterniond(Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitY())),
                    Eigen::Vector3d::Zero());
  m.set_cam_from_rig(turn * m.cam_from_rig());
  // The pose moved by 4 mrad, the point at the box's centre stays within 0.01 px.
  const Eigen::Vector2d before = rig.cameras[1].model.Project(kBox.center());
  EXPECT_LT((m.Project(kBox.center()) - before).norm(), 0.01);
  EXPECT_NEAR(AngleBetween(m.cam_from_rig(), rig.cameras[1].model.cam_from_rig()), angle, 1e-9);
  // Measured: 1.2 micrometres and 3.6 microradians (the trade is exact on the axis only).
  const RigRegistration r = RegisterRigs(rig, traded);
  EXPECT_LT(r.box_center_shift_m, 1e-5);
  EXPECT_LT(r.rotation_rad, 0.01 * angle);
}

TEST(RigRegistration, BadRigsAreErrorsThatNameTheCamera) {
  const Rig rig = TwoViews();
  Rig renamed = rig;
  renamed.cameras[1].name = "side";
  try {
    RegisterRigs(rig, renamed);
    ADD_FAILURE() << "a missing camera was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("'cam1'"), std::string::npos) << e.what();
  }
  Rig binned = rig;
  binned.cameras[0].model = binned.cameras[0].model.Binned(2);
  try {
    RegisterRigs(rig, binned);
    ADD_FAILURE() << "another image size was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("160x120"), std::string::npos) << e.what();
  }
  Rig no_box = rig;
  no_box.box = Box3();
  EXPECT_THROW(RegisterRigs(no_box, rig), InputError);
  Rig one = rig;
  one.cameras.erase(one.cameras.begin() + 1);
  EXPECT_THROW(RegisterRigs(one, rig), InputError);
}

}  // namespace
}  // namespace flamerig
