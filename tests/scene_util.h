// Scenes shared by the scene renderer's tests and the scene job's: a uniform cube of fire, a
// floor, and a floor and a sphere lit by a small candle-like fire.
#ifndef FLAMERIG_TESTS_SCENE_UTIL_H_
#define FLAMERIG_TESTS_SCENE_UTIL_H_

#include <cmath>

#include "fitting/scene.h"

namespace flamerig {

// A cube of `n` voxels a side, `size_m` across, uniform temperature and density, its min corner at
// the origin of its rig frame.
inline FireVolume UniformCube(int n, double size_m, double temperature_k, double density) {
  FireVolume v;
  v.geometry.dims = Eigen::Vector3i::Constant(n);
  v.geometry.voxel_size_m = Eigen::Vector3d::Constant(size_m / n);
  v.temperature_k.assign(v.geometry.num_voxels(), static_cast<float>(temperature_k));
  v.density_per_m3.assign(v.geometry.num_voxels(), static_cast<float>(density));
  return v;
}

inline double Luminance(const Eigen::Vector3d& rgb) {
  return 0.2126 * rgb.x() + 0.7152 * rgb.y() + 0.0722 * rgb.z();
}

inline Scene FloorScene() {
  Scene s;
  SceneMaterial white;
  white.name = "white";
  white.albedo = Eigen::Vector3d::Constant(1.0);
  s.materials.push_back(white);
  s.geometry.AddQuad(Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitY(), {10, 10}, 0);
  s.camera.position = Eigen::Vector3d(0, 1.5, 2.5);
  s.camera.look_at = Eigen::Vector3d(0, 0.2, 0);
  s.camera.width = 64;
  s.camera.height = 48;
  return s;
}

// A floor and a sphere lit by a small candle-like fire.
inline Scene LitScene(int width, int height) {
  Scene scene = FloorScene();
  scene.camera.width = width;
  scene.camera.height = height;
  scene.camera.position = Eigen::Vector3d(0, 0.25, 0.6);
  scene.camera.look_at = Eigen::Vector3d(0, 0.03, 0);
  SceneMaterial glossy;
  glossy.name = "glossy";
  glossy.albedo = Eigen::Vector3d::Constant(0.2);
  glossy.specular = Eigen::Vector3d::Constant(0.5);
  glossy.shininess = 100;
  scene.materials.push_back(glossy);
  scene.geometry.spheres.push_back({Eigen::Vector3d(0.05, 0.02, 0.02), 0.02, 1});
  SceneFire fire;
  FireVolume v = UniformCube(16, 0.02, 300, 0);
  for (int k = 0; k < 16; ++k)
    for (int j = 0; j < 16; ++j)
      for (int i = 0; i < 16; ++i) {
        const double r = std::hypot(i - 7.5, k - 7.5) / 8, h = j / 16.0;
        if (r < 1 - h) {
          v.temperature_k[v.geometry.Flat(i, j, k)] = static_cast<float>(1500 + 600 * (1 - r));
          v.density_per_m3[v.geometry.Flat(i, j, k)] = 3e16f;
        }
      }
  fire.volume = v;
  fire.translate = Eigen::Vector3d(-0.01, 0.02, -0.01);  // a flame above a wick, off the floor
  scene.fires.push_back(fire);
  return scene;
}

}  // namespace flamerig

#endif  // FLAMERIG_TESTS_SCENE_UTIL_H_
