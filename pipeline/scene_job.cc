#include "pipeline/scene_job.h"

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfOutputFile.h>
#include <tiny_obj_loader.h>
#include <yaml-cpp/yaml.h>

#include <filesystem>
#include <stdexcept>

#include "core/config_reader.h"
#include "core/error.h"
#include "fitting/renderer.h"
#include "pipeline/picture.h"
#include "pipeline/simulate.h"
#include "tomography/vdb_io.h"

namespace flamerig {

namespace fs = std::filesystem;

namespace {

Eigen::Vector3d Vec3(ConfigReader& r, const std::string& key, const Eigen::Vector3d& fallback) {
  const auto v = r.Get<std::vector<double>>(key, {fallback.x(), fallback.y(), fallback.z()});
  if (v.size() != 3 || !Eigen::Vector3d(v[0], v[1], v[2]).allFinite())
    throw InputError(r.where() + ": '" + key + "' must be three finite numbers");
  return Eigen::Vector3d(v[0], v[1], v[2]);
}

ConfigReader Map(const YAML::Node& node, const std::string& where) {
  if (!node.IsMap()) throw InputError(where + ": must be a map");
  return ConfigReader(node, where);
}

}  // namespace

void ReadObj(const std::string& path, std::vector<Eigen::Vector3f>* vertices,
             std::vector<Eigen::Vector3i>* triangles) {
  tinyobj::ObjReaderConfig config;
  config.triangulate = true;
  tinyobj::ObjReader reader;
  if (!reader.ParseFromFile(path, config))
    throw InputError(path + ": cannot read the mesh: " + reader.Error());
  const auto& v = reader.GetAttrib().vertices;
  vertices->clear();
  triangles->clear();
  for (std::size_t i = 0; i + 2 < v.size(); i += 3)
    vertices->emplace_back(v[i], v[i + 1], v[i + 2]);
  for (const auto& shape : reader.GetShapes()) {
    const auto& idx = shape.mesh.indices;
    for (std::size_t f = 0; f + 2 < idx.size(); f += 3) {
      const Eigen::Vector3i t(idx[f].vertex_index, idx[f + 1].vertex_index,
                              idx[f + 2].vertex_index);
      if ((t.array() < 0).any() || (t.array() >= static_cast<int>(vertices->size())).any())
        throw DataError(path + ": face " + std::to_string(f / 3) +
                        " refers to a vertex the file does not have");
      triangles->push_back(t);
    }
  }
  if (triangles->empty()) throw DataError(path + ": the mesh has no faces");
}

SceneJob SceneJob::Load(const std::string& path, const std::string& volume_override) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
    RejectDuplicateKeys(root, path);
  } catch (const YAML::Exception& e) {
    throw InputError(path + ": not a readable YAML file: " + e.what());
  }
  const fs::path base = fs::path(path).parent_path();
  auto resolve = [&](const std::string& file) {
    return fs::path(file).is_absolute() ? file : (base / file).string();
  };
  SceneJob job;
  ConfigReader top = Map(root, path);
  top.Seen("scene");
  top.Seen("render");
  top.Seen("display");
  top.CheckKnown();
  if (!root["scene"]) throw InputError(path + ": no 'scene' map");
  ConfigReader s = Map(root["scene"], path + ": scene");
  Scene& scene = job.scene;
  if (root["scene"]["camera"]) {
    ConfigReader c = Map(root["scene"]["camera"], path + ": scene.camera");
    scene.camera.position = Vec3(c, "position", scene.camera.position);
    scene.camera.look_at = Vec3(c, "look_at", scene.camera.look_at);
    scene.camera.up = Vec3(c, "up", scene.camera.up);
    scene.camera.vertical_fov_deg = c.Positive("fov_deg", scene.camera.vertical_fov_deg);
    scene.camera.width = c.Get<int>("width", scene.camera.width);
    scene.camera.height = c.Get<int>("height", scene.camera.height);
    c.CheckKnown();
    try {
      scene.camera.Validate();
    } catch (const InputError& e) {
      throw InputError(path + ": scene." + e.what());
    }
  }
  s.Seen("camera");
  scene.background = Vec3(s, "background", scene.background);
  // Materials by name.
  std::map<std::string, int> material_index;
  s.Seen("materials");
  if (root["scene"]["materials"]) {
    for (const auto& kv : root["scene"]["materials"]) {
      const std::string name = kv.first.as<std::string>();
      ConfigReader m = Map(kv.second, path + ": scene.materials." + name);
      SceneMaterial mat;
      mat.name = name;
      mat.albedo = Vec3(m, "albedo", mat.albedo);
      mat.specular = Vec3(m, "specular", mat.specular);
      mat.shininess = m.Positive("shininess", mat.shininess);
      m.CheckKnown();
      try {
        mat.Validate();
      } catch (const InputError& e) {
        throw InputError(path + ": scene.materials." + name + ": " + e.what());
      }
      material_index[name] = static_cast<int>(scene.materials.size());
      scene.materials.push_back(mat);
    }
  }
  s.Seen("objects");
  if (root["scene"]["objects"]) {
    int k = 0;
    for (const auto& node : root["scene"]["objects"]) {
      const std::string at = path + ": scene.objects[" + std::to_string(k++) + "]";
      ConfigReader o = Map(node, at);
      const std::string type = o.Get<std::string>("type", "");
      const std::string material = o.Get<std::string>("material", "");
      auto it = material_index.find(material);
      if (it == material_index.end())
        throw InputError(at + ": material '" + material + "' is not in scene.materials");
      if (type == "plane") {
        const Eigen::Vector3d n = Vec3(o, "normal", Eigen::Vector3d::UnitY());
        if (n.norm() < 1e-9) throw InputError(at + ": 'normal' must not be zero");
        const auto size = o.Get<std::vector<double>>("size", {1, 1});
        if (size.size() != 2 || !(size[0] > 0) || !(size[1] > 0))
          throw InputError(at + ": 'size' must be two positive numbers");
        scene.geometry.AddQuad(Vec3(o, "centre", Eigen::Vector3d::Zero()), n, {size[0], size[1]},
                               it->second);
      } else if (type == "box") {
        const Eigen::Vector3d lo = Vec3(o, "min", Eigen::Vector3d::Zero());
        const Eigen::Vector3d hi = Vec3(o, "max", Eigen::Vector3d::Ones());
        if (!(hi.array() > lo.array()).all())
          throw InputError(at + ": 'max' must exceed 'min' on every axis");
        scene.geometry.AddBox(lo, hi, it->second);
      } else if (type == "sphere") {
        SceneGeometry::Sphere sphere;
        sphere.centre = Vec3(o, "centre", Eigen::Vector3d::Zero());
        sphere.radius = o.Positive("radius", 0);
        sphere.material = it->second;
        scene.geometry.spheres.push_back(sphere);
      } else if (type == "mesh") {
        std::vector<Eigen::Vector3f> v;
        std::vector<Eigen::Vector3i> t;
        try {
          ReadObj(resolve(o.Get<std::string>("file", "")), &v, &t);
        } catch (const Error& e) {
          Rethrow(e, at + ": ", Error::Kind::kInput);
        }
        const double scale = o.Positive("scale", 1);
        const Eigen::Matrix3d r = Eigen::AngleAxisd(o.Get<double>("rotate_y_deg", 0) * M_PI / 180,
                                                    Eigen::Vector3d::UnitY())
                                      .toRotationMatrix();
        const Eigen::Vector3d translate = Vec3(o, "translate", Eigen::Vector3d::Zero());
        for (auto& p : v) p = (translate + scale * (r * p.cast<double>())).cast<float>();
        scene.geometry.AddMesh(v, t, it->second);
      } else {
        throw InputError(at + ": 'type' must be plane, box, sphere or mesh");
      }
      o.CheckKnown();
    }
  }
  s.Seen("fires");
  if (root["scene"]["fires"]) {
    int k = 0;
    for (const auto& node : root["scene"]["fires"]) {
      const std::string at = path + ": scene.fires[" + std::to_string(k++) + "]";
      ConfigReader f = Map(node, at);
      SceneFire fire;
      const std::string file = f.Get<std::string>("volume", "");
      if (file.empty() && volume_override.empty())
        throw InputError(at + ": 'volume' (a .vdb file) is required");
      // What was read: the scene's own file, or the --volume that replaces it.
      const std::string read = volume_override.empty() ? resolve(file) : volume_override;
      try {
        fire.volume = ReadVdb(read);
      } catch (const Error& e) {
        Rethrow(e, at + ": ", Error::Kind::kInput);
      }
      std::string absorption = f.Get<std::string>("absorption", "");
      if (absorption.empty()) {
        auto it = fire.volume.metadata_text.find("absorption_model");
        absorption = it != fire.volume.metadata_text.end() ? it->second : "soot";
      }
      try {
        fire.absorption = AbsorptionModel::FromName(absorption);
      } catch (const InputError& e) {
        throw InputError(at + ": " + e.what());
      }
      fire.scale = f.Positive("scale", 1);
      fire.rotate_y_deg = f.Get<double>("rotate_y_deg", 0);
      fire.translate = Vec3(f, "translate", Eigen::Vector3d::Zero());
      f.CheckKnown();
      if (fire.volume.temperature_k.empty() || fire.volume.density_per_m3.empty())
        throw InputError(
            at + ": " + read + (volume_override.empty() ? "" : " (given with --volume)") +
            " needs temperature and density grids to light a scene (it has " +
            (fire.volume.emission_rgb.empty() ? "neither" : "only an emission grid") + ")");
      scene.fires.push_back(std::move(fire));
    }
  }
  s.CheckKnown();
  if (scene.fires.empty()) throw InputError(path + ": scene.fires: no fire to light it");

  if (root["render"]) {
    ConfigReader r = Map(root["render"], path + ": render");
    job.render.samples_per_pixel = r.Get<int>("samples", job.render.samples_per_pixel);
    job.render.samples_per_pass = r.Get<int>("samples_per_pass", job.render.samples_per_pass);
    job.render.seed = r.Get<std::uint64_t>("seed", job.render.seed);
    const std::string lighting = r.Get<std::string>("lighting", "fire");
    if (lighting == "compare") {
      job.compare = true;
    } else {
      try {
        job.render.lighting = SceneLightingFromName(lighting);
      } catch (const InputError& e) {
        throw InputError(path + ": render.lighting: " + e.what() + " or compare");
      }
    }
    job.render.sphere_light_radius_m = r.NonNegative("sphere_radius_m", 0);
    r.CheckKnown();
    try {
      job.render.Validate();
    } catch (const InputError& e) {
      throw InputError(path + ": render: " + e.what());
    }
  }
  if (root["display"]) {
    ConfigReader d = Map(root["display"], path + ": display");
    job.display.exposure = d.Positive("exposure", job.display.exposure);
    job.display.key = d.Positive("key", job.display.key);
    job.display.white = d.NonNegative("white", job.display.white);
    d.CheckKnown();
    try {
      job.display.Validate();
    } catch (const InputError& e) {
      throw InputError(path + ": display: " + e.what());
    }
  }
  return job;
}

void WriteExr(const std::string& path, const ImageF& image) {
  if (image.channels != 3) throw InputError("WriteExr: needs a 3-channel image");
  try {
    Imf::Header header(image.width, image.height);
    for (const char* c : {"R", "G", "B"}) header.channels().insert(c, Imf::Channel(Imf::FLOAT));
    Imf::OutputFile file(path.c_str(), header);
    Imf::FrameBuffer fb;
    const std::size_t px = 3 * sizeof(float), row = px * image.width;
    char* base = reinterpret_cast<char*>(const_cast<float*>(image.pixels.data()));
    fb.insert("R", Imf::Slice(Imf::FLOAT, base, px, row));
    fb.insert("G", Imf::Slice(Imf::FLOAT, base + sizeof(float), px, row));
    fb.insert("B", Imf::Slice(Imf::FLOAT, base + 2 * sizeof(float), px, row));
    file.setFrameBuffer(fb);
    file.writePixels(image.height);
  } catch (const std::exception& e) {
    throw IoError(path + ": cannot write OpenEXR: " + e.what());
  }
}

ImageF ReadExr(const std::string& path) {
  try {
    Imf::InputFile file(path.c_str());
    const Imath::Box2i dw = file.header().dataWindow();
    const int w = dw.max.x - dw.min.x + 1, h = dw.max.y - dw.min.y + 1;
    ImageF image(w, h, 3, 0.0f);
    Imf::FrameBuffer fb;
    const std::size_t px = 3 * sizeof(float), row = px * w;
    char* base = reinterpret_cast<char*>(image.pixels.data()) -
                 (static_cast<std::ptrdiff_t>(dw.min.x) * px + dw.min.y * row);
    fb.insert("R", Imf::Slice(Imf::FLOAT, base, px, row));
    fb.insert("G", Imf::Slice(Imf::FLOAT, base + sizeof(float), px, row));
    fb.insert("B", Imf::Slice(Imf::FLOAT, base + 2 * sizeof(float), px, row));
    file.setFrameBuffer(fb);
    file.readPixels(dw.min.y, dw.max.y);
    return image;
  } catch (const std::exception& e) {
    throw DataError(path + ": cannot read OpenEXR: " + e.what());
  }
}

SceneJobResult RunSceneJob(const SceneJob& job, const std::string& out_dir,
                           const ProgressCallback& progress) {
  fs::create_directories(out_dir);
  const SceneRenderer renderer(job.scene);
  std::vector<SceneLighting> lightings = {job.render.lighting};
  if (job.compare)
    lightings = {SceneLighting::kFireVolume, SceneLighting::kPointLight,
                 SceneLighting::kSphereLight};
  SceneJobResult result;
  ToneMapOptions shared = job.display;  // the first (fire-lit) image's adaptation, for compare
  std::vector<ImageU8> mapped;
  for (std::size_t k = 0; k < lightings.size(); ++k) {
    SceneRenderOptions o = job.render;
    o.lighting = lightings[k];
    ImageF linear;
    result.renders.push_back(renderer.Render(o, &linear, progress));
    const std::string name = ToString(lightings[k]);
    const fs::path exr = fs::path(out_dir) / (name + ".exr");
    WriteExr(exr.string(), linear);
    ToneMapSummary tm;
    const ImageU8 display = ToneMapReinhard(linear, job.display, &tm);
    WritePng((fs::path(out_dir) / (name + ".png")).string(), display);
    WritePng((fs::path(out_dir) / (name + "_linear.png")).string(),
             ApplyCameraResponse(linear, job.display.exposure));
    result.files.push_back(exr.string());
    result.files.push_back((fs::path(out_dir) / (name + ".png")).string());
    result.files.push_back((fs::path(out_dir) / (name + "_linear.png")).string());
    if (k == 0) {
      shared.log_average = tm.log_average;
      shared.white = tm.white;
    }
    if (job.compare) mapped.push_back(ToneMapReinhard(linear, shared));
  }
  if (job.compare) {
    const fs::path sheet = fs::path(out_dir) / "compare.png";
    PictureGrid grid;
    grid.title = "the same scene lit by the fitted fire and by stand-in lights, one tone mapping";
    for (const auto& l : lightings)
      grid.column_labels.push_back(std::string("lit by ") + ToString(l));
    grid.rows.push_back(mapped);
    grid.tile_height = job.scene.camera.height;
    WritePng(sheet.string(), DrawPictureGrid(grid));
    result.files.push_back(sheet.string());
  }
  return result;
}

}  // namespace flamerig
