#include "core/json_yaml.h"

namespace flamerig {

void EmitJsonAsYaml(YAML::Emitter& e, const nlohmann::json& j) {
  if (j.is_object()) {
    e << YAML::BeginMap;
    for (const auto& [key, value] : j.items()) {
      e << YAML::Key << key << YAML::Value;
      EmitJsonAsYaml(e, value);
    }
    e << YAML::EndMap;
  } else if (j.is_array()) {
    e << YAML::BeginSeq;
    for (const auto& value : j) EmitJsonAsYaml(e, value);
    e << YAML::EndSeq;
  } else if (j.is_boolean()) {
    e << j.get<bool>();
  } else if (j.is_number_integer()) {
    e << j.get<long long>();
  } else if (j.is_number()) {
    e << j.get<double>();
  } else if (j.is_string()) {
    e << YAML::DoubleQuoted << j.get<std::string>();
  } else {
    e << YAML::Null;
  }
}

std::string JsonAsYaml(const nlohmann::json& j) {
  YAML::Emitter e;
  e.SetDoublePrecision(17);
  EmitJsonAsYaml(e, j);
  return std::string(e.c_str()) + "\n";
}

}  // namespace flamerig
