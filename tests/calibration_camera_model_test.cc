// Camera models through libmrcal, checked against mrcal's own Python tools.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <random>
#include <sstream>
#include <string>

#include "calibration/camera_model.h"
#include "core/error.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

fs::path TempDir() {
  fs::path dir =
      fs::temp_directory_path() / ("flamerig_camera_test_" + std::to_string(::getpid()) + "_" +
                                   ::testing::UnitTest::GetInstance()->current_test_info()->name());
  fs::create_directories(dir);
  return dir;
}

// Runs a command and returns its standard output; fails the test on a non-zero status.
std::string RunCommand(const std::string& command) {
  std::array<char, 4096> buffer;
  std::string out;
  std::unique_ptr<FILE, int (*)(FILE*)> pipe(popen(command.c_str(), "r"), pclose);
  if (!pipe) return "";
  while (fgets(buffer.data(), buffer.size(), pipe.get())) out += buffer.data();
  int status = pclose(pipe.release());
  EXPECT_EQ(status, 0) << command << "\n" << out;
  return out;
}

CameraModel Opencv8Camera() {
  Rigid3 cam_from_rig = Rigid3::FromRt({0.1, -2.9, 0.3, 0.05, -0.02, 0.41});
  return CameraModel(
      "LENSMODEL_OPENCV8",
      {812.5, 809.25, 319.7, 241.3, -0.12, 0.031, 4e-4, -3e-4, 0.002, 0.01, -0.005, 0.001},
      cam_from_rig, 640, 480);
}

std::vector<Eigen::Vector3d> TestPoints(const CameraModel& camera) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-0.1, 0.1);
  std::vector<Eigen::Vector3d> points;
  Rigid3 rig_from_cam = camera.cam_from_rig().Inverse();
  for (int i = 0; i < 50; ++i)
    points.push_back(rig_from_cam * Eigen::Vector3d(u(rng), u(rng), 0.5 + u(rng)));
  return points;
}

TEST(Pose, RtRoundTripIncludingNearPi) {
  for (double angle : {0.0, 1e-9, 0.3, 2.0, 3.14159, 3.14159265358979 - 1e-7, 3.14159265358979}) {
    Eigen::Vector3d axis = Eigen::Vector3d(0.3, -0.5, 0.8).normalized();
    Rigid3 pose(Eigen::Quaterniond(Eigen::AngleAxisd(angle, axis)), Eigen::Vector3d(1, 2, 3));
    Rigid3 back = Rigid3::FromRt(pose.ToRt());
    EXPECT_TRUE(back.RotationMatrix().isApprox(pose.RotationMatrix(), 1e-12)) << angle;
    Eigen::Vector3d r(pose.ToRt()[0], pose.ToRt()[1], pose.ToRt()[2]);
    EXPECT_NEAR(r.norm(), angle, 1e-9) << angle;
  }
}

TEST(Pose, LookAtPointsTheOpticalAxis) {
  Rigid3 cam_from_rig = LookAt(Eigen::Vector3d(1, 0.5, 2), Eigen::Vector3d(0, 0.5, 0));
  Eigen::Vector3d target = cam_from_rig * Eigen::Vector3d(0, 0.5, 0);
  EXPECT_NEAR(target.x(), 0, 1e-12);
  EXPECT_NEAR(target.y(), 0, 1e-12);
  EXPECT_GT(target.z(), 0);
  // Rig up (+y) is image up (-y in the camera).
  Eigen::Vector3d up = cam_from_rig.rotation * Eigen::Vector3d::UnitY();
  EXPECT_LT(up.y(), -0.99);
  EXPECT_THROW(LookAt(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0, 0, 0)), InputError);
  EXPECT_THROW(LookAt(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0, 1, 0)), InputError);
}

TEST(CameraModel, PinholeProjectsByTheBook) {
  Rigid3 identity;
  CameraModel cam = CameraModel::Pinhole(500, 400, 320, 240, identity, 640, 480);
  Eigen::Vector2d q = cam.Project(Eigen::Vector3d(0.1, -0.2, 2.0));
  EXPECT_NEAR(q.x(), 320 + 500 * 0.05, 1e-12);
  EXPECT_NEAR(q.y(), 240 - 400 * 0.1, 1e-12);
}

TEST(CameraModel, UnprojectInvertsProject) {
  CameraModel cam = Opencv8Camera();
  for (const Eigen::Vector3d& p : TestPoints(cam)) {
    Eigen::Vector2d q = cam.Project(p);
    Ray ray = cam.Unproject(q);
    ASSERT_TRUE(ray.valid);
    Eigen::Vector3d to_point = (p - ray.origin_in_rig).normalized();
    EXPECT_NEAR((to_point - ray.direction_in_rig).norm(), 0.0, 1e-8);
  }
  std::vector<Ray> all = cam.UnprojectAllPixels();
  ASSERT_EQ(all.size(), 640u * 480u);
  Ray single = cam.Unproject(Eigen::Vector2d(17, 33));
  EXPECT_NEAR((all[33 * 640 + 17].direction_in_rig - single.direction_in_rig).norm(), 0.0, 1e-12);
}

// A binned camera sees a point where the original's pixel block holding it is: pixel q of the
// original lies at (q + 0.5) / k - 0.5 of the k x k binned imager. Checked through mrcal for a
// polynomial lens and a splined one (whose spline acts before the core, so scaling the core is
// exact for it too).
TEST(CameraModel, BinnedProjectsToTheBlockThatHoldsThePixel) {
  const CameraModel opencv = Opencv8Camera();
  const std::string splined = "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=8_Ny=6_fov_x_deg=100";
  std::vector<double> spline = {500, 505, 319.5, 239.5};
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-0.02, 0.02);
  for (int i = 0; i < 2 * 8 * 6; ++i) spline.push_back(u(rng));
  const CameraModel spline_camera(splined, spline, opencv.cam_from_rig(), 640, 480);
  for (const CameraModel* camera : {&opencv, &spline_camera}) {
    SCOPED_TRACE(camera->lensmodel());
    for (int k : {2, 3}) {
      const CameraModel binned = camera->Binned(k);
      EXPECT_EQ(binned.width(), 640 / k);
      EXPECT_EQ(binned.height(), 480 / k);
      EXPECT_EQ(binned.lensmodel(), camera->lensmodel());
      for (const Eigen::Vector3d& p : TestPoints(*camera)) {
        const Eigen::Vector2d want = (camera->Project(p).array() + 0.5) / k - 0.5;
        EXPECT_NEAR((binned.Project(p) - want).norm(), 0.0, 1e-9);
      }
    }
  }
  EXPECT_EQ(opencv.Binned(1).intrinsics(), opencv.intrinsics());
  EXPECT_THROW(opencv.Binned(0), InputError);
  EXPECT_THROW(opencv.Binned(481), InputError);
}

TEST(CameraModel, SaveLoadIsExact) {
  fs::path dir = TempDir();
  CameraModel cam = Opencv8Camera();
  cam.Save((dir / "a.cameramodel").string(), "test");
  CameraModel back = CameraModel::Load((dir / "a.cameramodel").string());
  EXPECT_EQ(back.lensmodel(), cam.lensmodel());
  EXPECT_EQ(back.intrinsics(), cam.intrinsics());  // bit-exact with %.17g
  EXPECT_EQ(back.width(), 640);
  EXPECT_EQ(back.height(), 480);
  for (const Eigen::Vector3d& p : TestPoints(cam))
    EXPECT_NEAR((back.Project(p) - cam.Project(p)).norm(), 0, 1e-10);
  fs::remove_all(dir);
}

// Files we write load in mrcal's Python tools and project to the same pixels.
TEST(CameraModel, MrcalPythonReadsOurFiles) {
  fs::path dir = TempDir();
  CameraModel cam = Opencv8Camera();
  const std::string path = (dir / "ours.cameramodel").string();
  cam.Save(path);
  std::vector<Eigen::Vector3d> points = TestPoints(cam);
  std::ostringstream script;
  script.precision(17);
  script << "import mrcal, numpy as np\n"
         << "m = mrcal.cameramodel('" << path << "')\n"
         << "p = np.array([";
  for (const auto& p : points) script << "[" << p.x() << "," << p.y() << "," << p.z() << "],";
  script << "])\n"
         << "pc = mrcal.transform_point_rt(m.extrinsics_rt_fromref(), p)\n"
         << "q = mrcal.project(pc, *m.intrinsics())\n"
         << "for r in q: print('%.17g %.17g' % (r[0], r[1]))\n";
  std::ofstream((dir / "check.py").string()) << script.str();
  std::istringstream out(RunCommand("/usr/bin/python3 " + (dir / "check.py").string()));
  for (const auto& p : points) {
    double x, y;
    ASSERT_TRUE(out >> x >> y);
    Eigen::Vector2d q = cam.Project(p);
    EXPECT_NEAR(q.x(), x, 1e-9);
    EXPECT_NEAR(q.y(), y, 1e-9);
  }
  fs::remove_all(dir);
}

// Files mrcal's Python tools write load in ours and project to the pixels mrcal computes.
TEST(CameraModel, WeReadMrcalPythonFiles) {
  fs::path dir = TempDir();
  const std::string path = (dir / "theirs.cameramodel").string();
  std::ostringstream script;
  script << "import mrcal, numpy as np\n"
         << "m = mrcal.cameramodel(intrinsics=('LENSMODEL_OPENCV8', np.array([700.1, 702.3, 330.2, "
            "250.7, -0.2, "
            "0.05, 1e-3, -2e-3, 0.01, 0.002, 0.003, -0.001])),\n"
         << "    extrinsics_rt_fromref=np.array([0.2, 0.1, -0.3, 0.01, 0.02, 0.5]), "
            "imagersize=(640, 480))\n"
         << "m.write('" << path << "')\n"
         << "p = np.array([[0.01, 0.02, 0.3], [-0.1, 0.05, 0.2], [0.05, -0.08, 0.4]])\n"
         << "q = mrcal.project(mrcal.transform_point_rt(m.extrinsics_rt_fromref(), p), "
            "*m.intrinsics())\n"
         << "for r in q: print('%.17g %.17g' % (r[0], r[1]))\n";
  std::ofstream((dir / "write.py").string()) << script.str();
  std::istringstream out(RunCommand("/usr/bin/python3 " + (dir / "write.py").string()));
  CameraModel cam = CameraModel::Load(path);
  EXPECT_EQ(cam.lensmodel(), "LENSMODEL_OPENCV8");
  for (const Eigen::Vector3d& p :
       {Eigen::Vector3d(0.01, 0.02, 0.3), Eigen::Vector3d(-0.1, 0.05, 0.2),
        Eigen::Vector3d(0.05, -0.08, 0.4)}) {
    double x, y;
    ASSERT_TRUE(out >> x >> y);
    EXPECT_NEAR(cam.Project(p).x(), x, 1e-9);
    EXPECT_NEAR(cam.Project(p).y(), y, 1e-9);
  }
  fs::remove_all(dir);
}

TEST(CameraModel, BadInputGivesClearErrors) {
  Rigid3 identity;
  EXPECT_THROW(CameraModel("LENSMODEL_NONSENSE", {1, 2, 3, 4}, identity, 10, 10), InputError);
  EXPECT_THROW(CameraModel("LENSMODEL_OPENCV8", {1, 2, 3, 4}, identity, 10, 10), InputError);
  EXPECT_THROW(CameraModel("LENSMODEL_PINHOLE", {1, 2, NAN, 4}, identity, 10, 10), InputError);
  EXPECT_THROW(CameraModel("LENSMODEL_PINHOLE", {1, 2, 3, 4}, identity, 0, 10), InputError);
  EXPECT_THROW(CameraModel("LENSMODEL_PINHOLE", {0, 2, 3, 4}, identity, 10, 10), InputError);
  EXPECT_THROW(CameraModel("LENSMODEL_PINHOLE", {1, -2, 3, 4}, identity, 10, 10), InputError);
  // Rotation vectors: any angle up to Rigid3::kMaxRotationAngle is a rotation (7 rad is 7 - 2 pi
  // about the same axis); beyond it, or not finite, an error (1e300 made NaN rotations that
  // crashed the tomography's matrix build).
  const Rigid3 seven = Rigid3::FromRt(std::array<double, 6>{7, 0, 0, 0, 0, 0});
  EXPECT_NEAR(seven.ToRt()[0], 7 - 2 * M_PI, 1e-12);
  for (const double r : {1e300, 1e160, 1e20, 1001.0, double(NAN), double(INFINITY)})
    EXPECT_THROW(Rigid3::FromRt(std::array<double, 6>{0, r, 0, 0, 0, 0.3}), InputError) << r;
  EXPECT_THROW(Rigid3::FromRt(std::array<double, 6>{0, 0, 0, 0, NAN, 0.3}), InputError);
  fs::path dir = TempDir();
  {
    // A .cameramodel file with such a rotation: the error names the file.
    CameraModel::Pinhole(100, 100, 5, 5, identity, 10, 10)
        .Save((dir / "huge.cameramodel").string());
    std::ifstream in(dir / "huge.cameramodel");
    std::string text((std::istreambuf_iterator<char>(in)), {});
    const std::size_t at = text.find("'extrinsics': [");
    ASSERT_NE(at, std::string::npos);
    const std::size_t end = text.find(']', at);
    text.replace(at, end - at, "'extrinsics': [ 1e300, 0, 0, 0, 0, 0.3 ");
    std::ofstream(dir / "huge.cameramodel") << text;
    try {
      CameraModel::Load((dir / "huge.cameramodel").string());
      FAIL() << "no error";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("huge.cameramodel"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("rotation"), std::string::npos) << e.what();
    }
  }
  try {
    CameraModel::Load((dir / "missing.cameramodel").string());
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("missing.cameramodel"), std::string::npos);
  }
  std::ofstream((dir / "garbage.cameramodel").string())
      << "{ 'lensmodel': 'LENSMODEL_PINHOLE', 'intrinsics': [1, 2";
  try {
    CameraModel::Load((dir / "garbage.cameramodel").string());
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("garbage.cameramodel"), std::string::npos);
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace flamerig
