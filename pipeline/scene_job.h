// `flamerig render --scene scene.yaml --out DIR`: fitted fires lighting a virtual scene
// (fitting/scene.h), written as a linear HDR image and display images.
//
// The scene file (YAML; every key is checked, unknown keys are errors naming the file and key; paths
// are relative to the scene file; see config/scene_candle.yaml):
//   scene:
//     camera: {position: [x, y, z], look_at: [x, y, z], up: [0, 1, 0], fov_deg: 40,
//              width: 960, height: 540}
//     background: [0, 0, 0]          # radiance of rays that hit nothing
//     materials:
//       floor: {albedo: [0.6, 0.6, 0.6]}                                  # diffuse
//       brass: {albedo: [0.3, 0.2, 0.1], specular: [0.5, 0.4, 0.2], shininess: 200}   # glossy
//     objects:
//       - {type: plane, centre: [0, 0, 0], normal: [0, 1, 0], size: [1, 1], material: floor}
//       - {type: box, min: [x, y, z], max: [x, y, z], material: floor}
//       - {type: sphere, centre: [x, y, z], radius: 0.02, material: brass}
//       - {type: mesh, file: bunny.obj, scale: 1, rotate_y_deg: 0, translate: [0, 0, 0],
//          material: floor}                                             # Wavefront OBJ
//     fires:
//       - {volume: run/frame_000000.vdb, absorption: soot, scale: 1, rotate_y_deg: 0,
//          translate: [0, 0, 0]}          # absorption default: the file's metadata, else soot
//   render:
//     samples: 64                     # light samples per pixel
//     samples_per_pass: 4
//     seed: 1
//     lighting: fire                  # fire | point | sphere | compare (all three, side by side)
//     sphere_radius_m: 0              # sphere light; 0 = the fire's RMS radius
//   display:
//     exposure: 1                     # linear multiplier before tone mapping
//     key: 0.18                       # Reinhard's key
//     white: 0                        # Reinhard's L_white; 0 = the image's brightest
//
// Outputs in DIR, for each lighting rendered (NAME = fire, point, sphere):
//   NAME.exr        linear scene-referred RGB (float, OpenEXR), the renderer's radiance units
//   NAME.png        Reinhard 2002 tone-mapped sRGB (the eye adapted to the flame)
//   NAME_linear.png the exposure only, clipped and sRGB-encoded (what a camera would record)
//   compare.png     with lighting: compare, the three tone-mapped images side by side, mapped with
//                   the fire-lit image's adaptation and white so that they compare
#ifndef FLAMERIG_PIPELINE_SCENE_JOB_H_
#define FLAMERIG_PIPELINE_SCENE_JOB_H_

#include <string>
#include <vector>

#include "fitting/scene.h"
#include "fitting/tonemap.h"

namespace flamerig {

struct SceneJob {
  Scene scene;
  SceneRenderOptions render;
  bool compare = false;  // render fire, point and sphere lighting
  ToneMapOptions display;
  // Reads a scene file (format above); `volume` (optional) replaces every fire's volume file (the
  // placement is kept). Throws InputError naming the file and the key,
  // IoError naming a volume or mesh file that cannot be read.
  static SceneJob Load(const std::string& path, const std::string& volume = "");
};

struct SceneJobResult {
  std::vector<std::string> files;  // what was written
  std::vector<SceneRenderSummary> renders;
};

SceneJobResult RunSceneJob(const SceneJob& job, const std::string& out_dir,
                           const ProgressCallback& progress = nullptr);

// Writes a 3-channel float image as an OpenEXR file of 32-bit float R, G, B channels. Throws
// InputError naming the path.
void WriteExr(const std::string& path, const ImageF& image);
// Reads one back (for tests).
ImageF ReadExr(const std::string& path);

// Reads a Wavefront OBJ mesh (triangulated) with tinyobjloader. Throws InputError naming
// the file and the loader's message.
void ReadObj(const std::string& path, std::vector<Eigen::Vector3f>* vertices,
             std::vector<Eigen::Vector3i>* triangles);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_SCENE_JOB_H_
