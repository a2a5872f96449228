// The scene job (`flamerig render --scene`): scene files with meshes, an OpenEXR of the linear
// render, shadows where the mesh puts them, and scene-file errors that name the file and key.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "core/error.h"
#include "pipeline/scene_job.h"
#include "tests/scene_util.h"
#include "tomography/vdb_io.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

fs::path TempDir() {
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_scene_test_" + std::to_string(::getpid()) + "_" +
                                   ::testing::UnitTest::GetInstance()->current_test_info()->name());
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

TEST(SceneJob, ReadsScenesMeshesAndWritesExr) {
  const fs::path dir = TempDir();
  const Scene lit = LitScene(32, 24);
  WriteVdb((dir / "fire.vdb").string(), lit.fires[0].volume);
  // A mesh: one triangle standing between the fire and the floor to its right.
  std::ofstream(dir / "wall.obj") << "v 0.03 0 -0.05\nv 0.03 0 0.05\nv 0.03 0.08 0\nf 1 2 3\n";
  const std::string yaml =
      "scene:\n"
      "  camera: {position: [0, 0.25, 0.6], look_at: [0, 0.03, 0], fov_deg: 40, width: 32, "
      "height: 24}\n"
      "  materials:\n    white: {albedo: [1, 1, 1]}\n"
      "  objects:\n"
      "    - {type: plane, centre: [0, 0, 0], normal: [0, 1, 0], size: [2, 2], material: white}\n"
      "    - {type: mesh, file: wall.obj, material: white}\n"
      "  fires:\n    - {volume: fire.vdb, translate: [-0.01, 0, -0.01]}\n"
      "render: {samples: 8, lighting: compare}\n";
  std::ofstream(dir / "scene.yaml") << yaml;
  const SceneJob job = SceneJob::Load((dir / "scene.yaml").string());
  EXPECT_EQ(job.scene.geometry.triangles.size(), 3u);  // the plane's two and the mesh's one
  EXPECT_TRUE(job.compare);
  const SceneJobResult r = RunSceneJob(job, (dir / "out").string());
  EXPECT_EQ(r.renders.size(), 3u);
  for (const auto& f : r.files) EXPECT_TRUE(fs::exists(f)) << f;
  // The EXR holds the linear render: the same numbers back, and the floor right of the mesh is
  // in its shadow (darker than the mirror point on the left).
  SceneJob fire_only = job;
  fire_only.compare = false;
  const SceneRenderer renderer(fire_only.scene);
  ImageF linear;
  renderer.Render(fire_only.render, &linear);
  const ImageF back = ReadExr((dir / "out" / "fire.exr").string());
  EXPECT_TRUE(back.pixels == linear.pixels);
  const Eigen::Vector3d left = renderer.Irradiance({-0.08, 0, 0}, Eigen::Vector3d::UnitY(),
                                                   SceneLighting::kFireVolume, 1024, 1);
  const Eigen::Vector3d right = renderer.Irradiance({0.08, 0, 0}, Eigen::Vector3d::UnitY(),
                                                    SceneLighting::kFireVolume, 1024, 1);
  EXPECT_LT(Luminance(right), 0.5 * Luminance(left));

  // Mistakes name the file and the key.
  auto expect_error = [&](const std::string& text, const std::string& words) {
    std::ofstream(dir / "bad.yaml") << text;
    try {
      SceneJob::Load((dir / "bad.yaml").string());
      ADD_FAILURE() << "accepted: " << text;
    } catch (const std::exception& e) {
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("bad.yaml"), std::string::npos) << e.what();
    }
  };
  expect_error("scene:\n  fires: [{volume: fire.vdb}]\n  colour: red\n", "unknown key 'colour'");
  expect_error(
      "scene:\n  materials: {a: {albedo: [1, 1, 1]}}\n  objects: [{type: sphere, centre: [0, 0, "
      "0], radius: 1, material: b}]\n  fires: [{volume: fire.vdb}]\n",
      "material 'b'");
  expect_error("scene:\n  materials: {a: {albedo: [2, 1, 1]}}\n  fires: [{volume: fire.vdb}]\n",
               "albedo");
  expect_error("scene:\n  objects: []\n", "no fire");
  expect_error("scene:\n  fires: [{volume: missing.vdb}]\n", "missing.vdb");
  // A --volume with only emission (a reconstruction) is named, not the scene's own volume.
  FireVolume emission_only;
  emission_only.geometry = lit.fires[0].volume.geometry;
  emission_only.emission_rgb.assign(3 * emission_only.geometry.num_voxels(), 0.5f);
  WriteVdb((dir / "reconstruction.vdb").string(), emission_only);
  try {
    SceneJob::Load((dir / "scene.yaml").string(), (dir / "reconstruction.vdb").string());
    ADD_FAILURE() << "lit a scene with an emission-only volume";
  } catch (const InputError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("reconstruction.vdb (given with --volume)"), std::string::npos) << what;
    EXPECT_NE(what.find("only an emission grid"), std::string::npos) << what;
    EXPECT_EQ(what.find("fire.vdb"), std::string::npos) << what;
  }
  std::ofstream(dir / "broken.obj") << "v 0 0 0\nf 1 2 3\n";
  expect_error(
      "scene:\n  materials: {a: {albedo: [1, 1, 1]}}\n  objects: [{type: mesh, file: broken.obj, "
      "material: a}]\n  fires: [{volume: fire.vdb}]\n",
      "broken.obj");
  fs::remove_all(dir);
}

}  // namespace
}  // namespace flamerig
