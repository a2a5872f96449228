// Fire that lights the scene (the paper's section 5): fitted fire volumes placed in a virtual scene
// of simple geometry, the fire itself seen through a camera with the fit's physics, and the
// surfaces lit by the fire's own emission, with soft shadows and no hand-placed light.
//
// The scene frame: metres, y up (the rig's convention). A fire is placed by a similarity transform
// scene_from_rig (rotation about y, scale, translation); its emission and absorption scale with it
// (a fire scaled by 2 is the same fire seen from twice as far, not a brighter one: emission per
// unit length is divided by the scale, absorption likewise).
//
// Radiometry (renderer units: linear sRGB radiance, luminance-normalised W m^-2 sr^-1 nm^-1, as in
// renderer.h; the light of deep-red fire has a slightly negative blue, outside the sRGB gamut,
// which display images clip). A voxel j of a fire emits j_rgb = n_j * E(T_j) per metre per steradian (E: the
// thin-limit emission per unit density, ThinEmissionTable), isotropically, so it is a light of
// intensity I_j = j_rgb * V_j. A surface point p with normal N receives from it the irradiance
//     E(p) = sum_j integral over voxel j of  j_rgb Tr(x -> p) V(x, p) cos(theta_p) / |x - p|^2 dx,
// Tr the transmittance through the fires between x and p (per channel: kappa at 610, 550 and
// 465 nm for R, G, B; exact for grey soot, an approximation of the spectrum for Rayleigh soot),
// V the visibility through the scene's geometry. It is estimated by Monte Carlo: a brick of 4^3
// voxels chosen with probability proportional to its emitted power over its squared distance from
// p (never nearer than the brick's own radius, so every brick keeps a chance: unbiased), then a
// voxel of it by power (luminance of I_j), a point uniform in the voxel, one shadow ray; the brick
// choice is stratified over a pixel's samples. Against choosing voxels by power alone this cut the
// variance about five times on a candle beside a table (surfaces near an extended light see 1/d^2
// vary across it). Surfaces reflect with a
// Lambertian term (albedo / pi) plus, for glossy materials, a normalised Blinn-Phong lobe
// ((shininess + 8) / (8 pi) specular cos^shininess of the half angle). Only direct light: the fire
// lights the scene, the scene does not light the scene again (no interreflection), and the fire
// does not scatter.
//
// The camera ray: the fires are marched with FireRenderer (the fit's discretisation and spectral
// path) up to the first surface (Embree), and the surface's radiance arrives attenuated by the
// fires' transmittance in front of it.
//
// Comparison lighting (the usual practice the paper argues against): the fire's light replaced by
// a point light, or a sphere light of radius r, at the fire's power-weighted centroid, of the same
// total intensity, coloured like the hottest visible voxel (its chromaticity, the fire's total
// luminance). The fire is still seen through the camera. Hard shadows (point) or soft ones of the
// wrong size and place (sphere).
//
// Determinism: every pixel's random numbers come from (seed, pixel, pass), so an image does not
// depend on the number of threads or their scheduling. Progressive: passes of
// `samples_per_pass` light samples per pixel, accumulated; a callback after each pass.
//
// Thread safety: Render() uses TBB inside and must be called from one thread at a time per
// SceneRenderer.
#ifndef FLAMERIG_FITTING_SCENE_H_
#define FLAMERIG_FITTING_SCENE_H_

#include <Eigen/Core>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "core/progress.h"
#include "core/image.h"
#include "fitting/absorption.h"
#include "fitting/renderer.h"
#include "tomography/volume.h"

namespace flamerig {

struct SceneMaterial {
  std::string name;
  Eigen::Vector3d albedo =
      Eigen::Vector3d::Constant(0.5);                  // diffuse reflectance per channel, [0, 1]
  Eigen::Vector3d specular = Eigen::Vector3d::Zero();  // glossy reflectance, [0, 1]
  double shininess = 50;  // Blinn-Phong exponent of the glossy lobe, [1, 1e5]
  void Validate() const;  // throws InputError naming the material and field
};

// Triangles (planes, boxes and meshes become triangles) and spheres, in the scene frame.
struct SceneGeometry {
  std::vector<Eigen::Vector3f> vertices;
  std::vector<Eigen::Vector3i> triangles;
  std::vector<int> triangle_material;  // per triangle: index into Scene::materials
  struct Sphere {
    Eigen::Vector3d centre;
    double radius = 0;
    int material = 0;
  };
  std::vector<Sphere> spheres;
  // Helpers that append a shape (triangles wound so that normals point outward / along `normal`).
  void AddQuad(const Eigen::Vector3d& centre, const Eigen::Vector3d& normal,
               const Eigen::Vector2d& size, int material);
  void AddBox(const Eigen::Vector3d& min, const Eigen::Vector3d& max, int material);
  void AddMesh(const std::vector<Eigen::Vector3f>& vertices,
               const std::vector<Eigen::Vector3i>& triangles, int material);
};

struct SceneFire {
  FireVolume volume;  // temperature (K) and density (1/m^3), rig frame
  AbsorptionModel absorption = AbsorptionModel::DefaultSoot();
  double scale = 1;  // scene_from_rig: scale, rotation about y (degrees), translation
  double rotate_y_deg = 0;
  Eigen::Vector3d translate = Eigen::Vector3d::Zero();
};

struct SceneCamera {
  Eigen::Vector3d position = Eigen::Vector3d(0, 0.1, 0.5);
  Eigen::Vector3d look_at = Eigen::Vector3d::Zero();
  Eigen::Vector3d up = Eigen::Vector3d::UnitY();
  double vertical_fov_deg = 40;  // (0, 170)
  int width = 960, height = 540;
  void Validate() const;  // throws InputError naming the field
};

enum class SceneLighting { kFireVolume, kPointLight, kSphereLight };
const char* ToString(SceneLighting lighting);
SceneLighting SceneLightingFromName(const std::string& name);  // "fire" | "point" | "sphere"

struct Scene {
  SceneCamera camera;
  std::vector<SceneMaterial> materials;
  SceneGeometry geometry;
  std::vector<SceneFire> fires;
  Eigen::Vector3d background = Eigen::Vector3d::Zero();  // radiance of rays that hit nothing
};

struct SceneRenderOptions {
  int samples_per_pixel = 64;  // light samples per pixel; >= 1
  int samples_per_pass = 4;    // >= 1
  std::uint64_t seed = 1;
  SceneLighting lighting = SceneLighting::kFireVolume;
  double sphere_light_radius_m = 0;  // kSphereLight; 0 = the fire's RMS radius about its centroid
  RenderOptions fire;                // how the camera rays march the fires
  void Validate() const;             // throws InputError naming the field
};

struct SceneLight {  // what the comparison lighting uses, and what the fire amounts to
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();       // power-weighted, scene frame
  Eigen::Vector3d intensity_rgb = Eigen::Vector3d::Zero();  // sum of the voxels' I_j
  Eigen::Vector3d hottest_rgb = Eigen::Vector3d::Zero();    // chromaticity of the hottest voxel
  double hottest_k = 0;
  double rms_radius_m = 0;
  std::size_t emitting_voxels = 0;
};

struct SceneRenderSummary {
  SceneLight light;
  SceneLighting lighting = SceneLighting::kFireVolume;
  int samples_per_pixel = 0;
  std::int64_t surface_pixels = 0;  // pixels whose camera ray hit geometry
  std::int64_t shadow_rays = 0;
  double fire_ms = 0, lighting_ms = 0, total_ms = 0;
  std::string BriefReport() const;
};

class SceneRenderer {
 public:
  // Builds the Embree scene and the fires' light tables. Throws InputError for a scene
  // that cannot be rendered (a triangle or sphere naming a missing material, a fire without
  // temperature or density, a non-positive scale), naming what is wrong.
  explicit SceneRenderer(const Scene& scene);
  ~SceneRenderer();
  SceneRenderer(const SceneRenderer&) = delete;
  SceneRenderer& operator=(const SceneRenderer&) = delete;

  // Renders the linear image (3 channels, camera size). Deterministic for a seed. Progress after
  // each pass: stage "render", unit "samples" (per pixel); a cancel throws Cancelled.
  SceneRenderSummary Render(const SceneRenderOptions& options, ImageF* linear_rgb,
                            const ProgressCallback& progress = nullptr) const;

  // The irradiance (per channel) at a point with a normal, from `lighting`, estimated with
  // `samples` light samples (seeded): what a surface receives. Exposed for tests and energy checks.
  Eigen::Vector3d Irradiance(const Eigen::Vector3d& point, const Eigen::Vector3d& normal,
                             SceneLighting lighting, int samples, std::uint64_t seed,
                             double sphere_radius_m = 0) const;

  const SceneLight& light() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace flamerig

#endif  // FLAMERIG_FITTING_SCENE_H_
