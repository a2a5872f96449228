// The calibration tests' ring: 4 cameras 90 degrees apart at 640x480, boards shared by
// neighbours only, close-ups per camera, rendered once into the build tree and shared by the
// calibration tests and the calibrate job's tests.
#ifndef FLAMERIG_TESTS_CALIBRATION_RING_H_
#define FLAMERIG_TESTS_CALIBRATION_RING_H_

#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/file.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <array>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <string>

#include "calibration/calibrate.h"
#include "calibration/synthetic_rig.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;
constexpr double kRadToDeg = 180.0 / 3.14159265358979323846;

fs::path TempDir(const std::string& what) {
  fs::path d =
      fs::temp_directory_path() / ("flamerig_calib_" + what + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

// Rendered once for the whole suite (a few seconds).
class Ring : public ::testing::Test {
 protected:
  // Each test runs in its own process under ctest, so the rendered ring is kept in the build tree
  // (made once, under a lock, by whichever test gets there first). The environment variable
  // FLAMERIG_TEST_DATA_DIR points elsewhere: the sanitizer pass reuses the ring that the plain
  // build rendered (rendering it under ASan and UBSan takes 5.5 minutes; the renderer itself is
  // covered under the sanitizers by smaller tests).
  static void SetUpTestSuite() {
    const char* data_dir = std::getenv("FLAMERIG_TEST_DATA_DIR");
    const fs::path root = fs::path(data_dir && *data_dir ? data_dir : FLAMERIG_TEST_DATA_DIR);
    fs::create_directories(root);
    dir_ = new fs::path(root / "calibration_ring_v2");
    const int lock = ::open((root / "calibration_ring.lock").c_str(), O_CREAT | O_RDWR, 0644);
    ASSERT_GE(lock, 0);
    ASSERT_EQ(::flock(lock, LOCK_EX), 0);
    if (!fs::exists(*dir_ / "done")) {
      const fs::path tmp = root / ("calibration_ring_tmp_" + std::to_string(::getpid()));
      fs::remove_all(tmp);
      // What `flamerig simulate` writes for its calibration (seed 21, noise 0.5 DN), made here by
      // the calibration layer's own generator.
      const Box3 box{Eigen::Vector3d(-0.015, 0.0, -0.015), Eigen::Vector3d(0.015, 0.07, 0.015)};
      synthetic::RingOptions ring;
      ring.cameras = 4;
      ring.width = 640;
      ring.height = 480;
      ring.fill = 0.45;  // a wider field than the flame needs, as on a real rig (f about 780 px)
      const Rig rig = synthetic::MakeRingRig(box, ring, "sim");
      fs::create_directories(tmp);
      rig.Save((tmp / "rig.yaml").string());
      BoardSpec board;
      board.square_m = 0.012;
      board.marker_m = 0.009;
      synthetic::WriteCalibrationViews(rig, board, 21, 24, 24, 0.5, (tmp / "calibration").string());
      std::ofstream(tmp / "done") << "complete\n";
      fs::remove_all(*dir_);
      fs::rename(tmp, *dir_);
    }
    ::close(lock);  // releases the lock
    truth_ = new Rig(Rig::Load((*dir_ / "rig.yaml").string()));
  }
  static void TearDownTestSuite() {
    delete dir_;
    delete truth_;
  }
  static CalibrationData Detect(const std::string& cache = "") {
    return DetectViewsInFolder((*dir_ / "calibration").string(),
                               LoadBoardSpec((*dir_ / "calibration" / "board.yaml").string()), {},
                               cache);
  }
  static fs::path* dir_;
  static Rig* truth_;
};
fs::path* Ring::dir_ = nullptr;
Rig* Ring::truth_ = nullptr;

// The corners of each observation where the truth projects them (the views' true poses are in
// the board.yaml beside the images, `views`).
inline CalibrationData ExactCorners(CalibrationData data, const fs::path& views, const Rig& truth) {
  const auto corners = data.board.InnerCornersInBoard();
  std::map<std::string, Rigid3> pose;
  for (const auto& v : YAML::LoadFile((views / "board.yaml").string())["views"]) {
    std::array<double, 6> rt;
    for (int i = 0; i < 6; ++i) rt[i] = v["rt_rig_from_board"][i].as<double>();
    pose[v["name"].as<std::string>()] = Rigid3::FromRt(rt);
  }
  for (auto& o : data.observations) {
    const CameraModel& cam = truth.cameras[truth.FindCamera(data.camera_names[o.camera])].model;
    for (std::size_t k = 0; k < o.detection.corner_ids.size(); ++k)
      o.detection.corners_px[k] =
          cam.Project(pose.at(data.view_names[o.view]) * corners[o.detection.corner_ids[k]]);
  }
  return data;
}

// ---- Bad input: each error names the camera (or file) and the reason.

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const std::exception& e) {
    return e.what();
  }
  return "(no error)";
}

}  // namespace
}  // namespace flamerig

#endif  // FLAMERIG_TESTS_CALIBRATION_RING_H_
