#include "calibration/rig.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>
#include <stdexcept>

#include "core/atomic_file.h"
#include "core/config_reader.h"
#include "core/error.h"
#include "core/format.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

[[noreturn]] void Fail(const std::string& path, const std::string& field, const std::string& rule) {
  throw InputError(path + ": field '" + field + "': " + rule);
}

Eigen::Vector3d ReadVector3(const YAML::Node& node, const std::string& path,
                            const std::string& field) {
  if (!node || !node.IsSequence() || node.size() != 3)
    Fail(path, field, "must be a list of 3 numbers");
  Eigen::Vector3d v;
  for (int i = 0; i < 3; ++i) {
    try {
      v[i] = node[i].as<double>();
    } catch (const YAML::Exception&) {
      Fail(path, field, "element " + std::to_string(i) + " is not a number");
    }
    if (!std::isfinite(v[i])) Fail(path, field, "element " + std::to_string(i) + " is not finite");
  }
  return v;
}

Rig ReadRig(const YAML::Node& r, const std::string& yaml_path);  // the `rig:` map; below

}  // namespace

int Rig::FindCamera(const std::string& camera_name) const {
  for (std::size_t i = 0; i < cameras.size(); ++i) {
    if (cameras[i].name == camera_name) return static_cast<int>(i);
  }
  return -1;
}

Rig Rig::Load(const std::string& yaml_path) {
  const YAML::Node root = LoadYamlFile(yaml_path, "rig file");
  YAML::Node r = root.IsMap() ? root["rig"] : YAML::Node();
  if (!r || !r.IsMap()) Fail(yaml_path, "rig", "missing; a rig file has a top-level 'rig' map");
  try {
    return ReadRig(r, yaml_path);
  } catch (const YAML::Exception& e) {  // a value of the wrong shape
    throw InputError(yaml_path + ": " + e.what());
  } catch (const InputError& e) {  // CheckKeys: an unknown key, or not a map
    throw InputError(e.what());
  }
}

namespace {

Rig ReadRig(const YAML::Node& r, const std::string& yaml_path) {
  CheckKeys(r, {"name", "up", "box", "exposure_unit_us", "cameras"}, yaml_path + ": rig");
  Rig rig;
  if (r["name"]) rig.name = r["name"].as<std::string>();
  if (r["exposure_unit_us"]) {
    rig.exposure_unit_us = r["exposure_unit_us"].as<double>();
    if (!(rig.exposure_unit_us > 0) || !std::isfinite(rig.exposure_unit_us))
      Fail(yaml_path, "rig.exposure_unit_us",
           "must be a finite time > 0 in microseconds, got " + r["exposure_unit_us"].Scalar());
  }
  if (r["up"]) {
    rig.up_in_rig = ReadVector3(r["up"], yaml_path, "rig.up");
    if (rig.up_in_rig.norm() < 1e-12) Fail(yaml_path, "rig.up", "must not be the zero vector");
    rig.up_in_rig.normalize();
  }
  YAML::Node box = r["box"];
  if (!box || !box.IsMap())
    Fail(yaml_path, "rig.box", "missing; give min and max corners in metres");
  CheckKeys(box, {"min", "max"}, yaml_path + ": rig.box");
  rig.box.min_in_rig = ReadVector3(box["min"], yaml_path, "rig.box.min");
  rig.box.max_in_rig = ReadVector3(box["max"], yaml_path, "rig.box.max");
  if (!rig.box.IsValid()) Fail(yaml_path, "rig.box", "max must exceed min on every axis");

  YAML::Node cams = r["cameras"];
  if (!cams || !cams.IsSequence() || cams.size() == 0) {
    Fail(yaml_path, "rig.cameras", "must be a non-empty list");
  }
  fs::path base = fs::path(yaml_path).parent_path();
  std::set<std::string> names;
  for (std::size_t i = 0; i < cams.size(); ++i) {
    std::string field = "rig.cameras[" + std::to_string(i) + "]";
    YAML::Node c = cams[i];
    CheckKeys(c, {"name", "model", "radiometry"}, yaml_path + ": " + field);
    if (!c["name"] || !c["model"]) Fail(yaml_path, field, "needs 'name' and 'model'");
    std::string name = c["name"].as<std::string>();
    if (name.empty()) Fail(yaml_path, field + ".name", "must not be empty");
    if (!names.insert(name).second)
      Fail(yaml_path, field + ".name", "duplicate camera name '" + name + "'");
    std::string model_path = c["model"].as<std::string>();
    fs::path full = fs::path(model_path).is_absolute() ? fs::path(model_path) : base / model_path;
    try {
      rig.cameras.push_back(RigCamera{name, model_path, CameraModel::Load(full.string()), {}});
    } catch (const std::exception& e) {
      Fail(yaml_path, field + ".model", e.what());
    }
    if (c["radiometry"])
      rig.cameras.back().radiometry = CameraRadiometry::FromYaml(
          c["radiometry"], base.string(), yaml_path + ": " + field + ".radiometry");
  }
  return rig;
}

}  // namespace

void Rig::Save(const std::string& yaml_path) const {
  fs::path base = fs::path(yaml_path).parent_path();
  if (!base.empty()) fs::create_directories(base);
  YAML::Emitter out;
  out << YAML::BeginMap << YAML::Key << "rig" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "name" << YAML::Value << name;
  // + 0.0: a negated axis is written [0, -1, 0], not [-0, -1, -0].
  out << YAML::Key << "up" << YAML::Value << YAML::Flow
      << std::vector<double>{up_in_rig.x() + 0.0, up_in_rig.y() + 0.0, up_in_rig.z() + 0.0};
  out << YAML::Key << "box" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "min" << YAML::Value << YAML::Flow
      << std::vector<double>{box.min_in_rig.x(), box.min_in_rig.y(), box.min_in_rig.z()};
  out << YAML::Key << "max" << YAML::Value << YAML::Flow
      << std::vector<double>{box.max_in_rig.x(), box.max_in_rig.y(), box.max_in_rig.z()};
  out << YAML::EndMap;
  if (exposure_unit_us > 0)  // exactly: a run's exposure is the settings over it
    out << YAML::Key << "exposure_unit_us" << YAML::Value << FormatNumber(exposure_unit_us, 17);
  out << YAML::Key << "cameras" << YAML::Value << YAML::BeginSeq;
  for (const RigCamera& c : cameras) {
    std::string model_path =
        c.model_path.empty() ? "cameras/" + c.name + ".cameramodel" : c.model_path;
    fs::path full = fs::path(model_path).is_absolute() ? fs::path(model_path) : base / model_path;
    fs::create_directories(full.parent_path());
    c.model.Save(full.string(), "flamerig camera '" + c.name + "' of rig '" + name + "'");
    out << YAML::BeginMap << YAML::Key << "name" << YAML::Value << c.name << YAML::Key << "model"
        << YAML::Value << model_path;
    if (!c.radiometry.is_default()) {
      out << YAML::Key << "radiometry" << YAML::Value;
      c.radiometry.ToYaml(&out);
    }
    out << YAML::EndMap;
  }
  out << YAML::EndSeq << YAML::EndMap << YAML::EndMap;
  WriteFileAtomically(yaml_path, std::string(out.c_str()) + "\n");
}

}  // namespace flamerig
