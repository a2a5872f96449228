#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>

#include "calibration/rig.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

fs::path TempDir(const std::string& name) {
  fs::path dir =
      fs::temp_directory_path() / ("flamerig_rig_test_" + std::to_string(::getpid()) + "_" + name);
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

Rig TwoCameraRig() {
  Rig rig;
  rig.name = "test";
  rig.box = Box3{Eigen::Vector3d(-0.1, 0, -0.1), Eigen::Vector3d(0.1, 0.3, 0.1)};
  for (int i = 0; i < 2; ++i) {
    Rigid3 pose = LookAt(Eigen::Vector3d(i ? 1.0 : 0.0, 0.15, i ? 0.0 : 1.0), rig.box.center());
    rig.cameras.push_back(
        RigCamera{"cam" + std::to_string(i),
                  "",
                  CameraModel::Pinhole(300 + i, 300, 159.5, 119.5, pose, 320, 240),
                  {}});
  }
  return rig;
}

TEST(Rig, SaveLoadRoundTrip) {
  fs::path dir = TempDir("roundtrip");
  Rig rig = TwoCameraRig();
  rig.up_in_rig = -Eigen::Vector3d::UnitY();  // a calibrated first camera's frame: (-0, -1, -0)
  rig.Save((dir / "rig.yaml").string());
  {
    std::ifstream in(dir / "rig.yaml");
    const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_NE(text.find("up: [0, -1, 0]"), std::string::npos) << text;
  }
  Rig back = Rig::Load((dir / "rig.yaml").string());
  EXPECT_EQ(back.up_in_rig, Eigen::Vector3d(0, -1, 0));
  EXPECT_EQ(back.name, "test");
  ASSERT_EQ(back.cameras.size(), 2u);
  EXPECT_EQ(back.FindCamera("cam1"), 1);
  EXPECT_EQ(back.FindCamera("nope"), -1);
  EXPECT_EQ(back.box.min_in_rig, rig.box.min_in_rig);
  EXPECT_EQ(back.box.max_in_rig, rig.box.max_in_rig);
  EXPECT_EQ(back.cameras[1].model.intrinsics(), rig.cameras[1].model.intrinsics());
  Eigen::Vector3d p(0.01, 0.2, -0.03);
  EXPECT_NEAR((back.cameras[0].model.Project(p) - rig.cameras[0].model.Project(p)).norm(), 0,
              1e-10);
  fs::remove_all(dir);
}

void ExpectLoadError(const std::string& yaml, const std::string& expected_fragment) {
  fs::path dir = TempDir("bad");
  TwoCameraRig().Save((dir / "good.yaml").string());
  std::ofstream((dir / "rig.yaml").string()) << yaml;
  try {
    Rig::Load((dir / "rig.yaml").string());
    FAIL() << "no error for:\n" << yaml;
  } catch (const std::runtime_error& e) {
    std::string what = e.what();
    EXPECT_NE(what.find("rig.yaml"), std::string::npos) << what;
    EXPECT_NE(what.find(expected_fragment), std::string::npos) << what;
  }
  fs::remove_all(dir);
}

TEST(Rig, MalformedFilesNameTheField) {
  ExpectLoadError("rig: [1, 2", "not valid YAML");
  ExpectLoadError("cameras: []", "'rig'");
  ExpectLoadError("rig:\n  cameras:\n    - {name: a, model: cameras/cam0.cameramodel}\n",
                  "rig.box");
  ExpectLoadError(
      "rig:\n  box: {min: [0, 0, 0], max: [1, 1]}\n  cameras:\n    - {name: a, model: x}\n",
      "rig.box.max");
  ExpectLoadError(
      "rig:\n  box: {min: [0, 0, 0], max: [1, -1, 1]}\n  cameras:\n    - {name: a, model: x}\n",
      "max must exceed min");
  ExpectLoadError("rig:\n  box: {min: [0, 0, 0], max: [1, 1, 1]}\n  cameras: []\n", "rig.cameras");
  ExpectLoadError(
      "rig:\n  box: {min: [0, 0, 0], max: [1, 1, 1]}\n  cameras:\n    - {name: a, model: "
      "nowhere.cameramodel}\n",
      "rig.cameras[0].model");
  ExpectLoadError(
      "rig:\n  box: {min: [0, 0, 0], max: [1, 1, 1]}\n  cameras:\n    - {name: a, model: "
      "cameras/cam0.cameramodel}\n"
      "    - {name: a, model: cameras/cam1.cameramodel}\n",
      "duplicate camera name");
  ExpectLoadError(
      "rig:\n  up: [0, 0, 0]\n  box: {min: [0, 0, 0], max: [1, 1, 1]}\n  cameras:\n    - {name: a, "
      "model: x}\n",
      "rig.up");
  // A misspelt key would silently be ignored; a value of the wrong shape names the file.
  ExpectLoadError(
      "rig:\n  upp: [0, 1, 0]\n  box: {min: [0, 0, 0], max: [1, 1, 1]}\n  cameras:\n    - {name: "
      "a, model: x}\n",
      "rig: unknown key 'upp'");
  ExpectLoadError(
      "rig:\n  box: {min: [0, 0, 0], max: [1, 1, 1], maxx: 2}\n  cameras:\n    - {name: a, model: "
      "x}\n",
      "rig.box: unknown key 'maxx'");
  ExpectLoadError(
      "rig:\n  box: {min: [0, 0, 0], max: [1, 1, 1]}\n  cameras:\n    - {name: a, modle: x}\n",
      "rig.cameras[0]: unknown key 'modle'");
  ExpectLoadError(
      "rig:\n  name: [a, b]\n  box: {min: [0, 0, 0], max: [1, 1, 1]}\n  cameras:\n    - {name: "
      "a, model: x}\n",
      "bad conversion");
  ExpectLoadError("just a line\n", "'rig'");
}

}  // namespace
}  // namespace flamerig
