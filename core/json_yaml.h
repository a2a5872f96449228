// JSON values written as YAML, types kept: one list of fields serves both formats (a run's
// per-frame summaries, the capture daemon's status).
//
// Strings are double-quoted, so a name that looks like a number or a boolean reads back as text;
// NaN and infinities stay numbers (.nan, .inf), which JSON text cannot hold.
#ifndef FLAMERIG_CORE_JSON_YAML_H_
#define FLAMERIG_CORE_JSON_YAML_H_

#include <yaml-cpp/yaml.h>

#include <nlohmann/json.hpp>
#include <string>

namespace flamerig {

// Emits `j` into `e` (objects as maps in the JSON value's key order, arrays as sequences).
void EmitJsonAsYaml(YAML::Emitter& e, const nlohmann::json& j);

// The YAML document of `j`, doubles with 17 significant digits, ending in a newline.
std::string JsonAsYaml(const nlohmann::json& j);

}  // namespace flamerig

#endif  // FLAMERIG_CORE_JSON_YAML_H_
