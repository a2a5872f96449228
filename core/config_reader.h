// Strict, typed access to one YAML map of a config file, shared by every config reader in flamerig.
//
// Errors name where the map is (a file and a key path, given by the caller) and the key, and say
// the rule broken; keys that no Get() asked for are errors (CheckKnown), so that a typo never
// falls back silently to a default. Throws InputError.
#ifndef FLAMERIG_CORE_CONFIG_READER_H_
#define FLAMERIG_CORE_CONFIG_READER_H_

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <filesystem>
#include <initializer_list>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>

#include "core/error.h"

namespace flamerig {

class ConfigReader {
 public:
  ConfigReader(const YAML::Node& node, std::string where) : node_(node), where_(std::move(where)) {}
  template <typename T>
  T Get(const std::string& key, T fallback) {
    seen_.insert(key);
    const YAML::Node v = node_[key];
    if (!v) return fallback;
    try {
      return v.as<T>();
    } catch (const YAML::Exception&) {
      throw InputError(where_ + ": '" + key + "' has a value of the wrong type");
    }
  }
  double Positive(const std::string& key, double fallback) {
    const double v = Get<double>(key, fallback);
    if (!(v > 0) || !std::isfinite(v))
      throw InputError(where_ + ": '" + key + "' must be a positive number");
    return v;
  }
  double NonNegative(const std::string& key, double fallback) {
    const double v = Get<double>(key, fallback);
    if (!(v >= 0) || !std::isfinite(v)) throw InputError(where_ + ": '" + key + "' must be >= 0");
    return v;
  }
  // A number in [lo, hi] (bounds that keep every later conversion to an integer type defined).
  double Range(const std::string& key, double fallback, double lo, double hi) {
    const double v = Get<double>(key, fallback);
    if (!(v >= lo) || !(v <= hi)) {
      std::ostringstream rule;
      rule << "must be in [" << lo << ", " << hi << "]";
      throw InputError(where_ + ": '" + key + "' " + rule.str());
    }
    return v;
  }
  // A whole number in [lo, hi] as an integer type (a count, a size, a port): 2.7 is an error, where
  // a cast would have taken 2 without a word.
  template <typename Int>
  Int Whole(const std::string& key, double fallback, double lo, double hi) {
    const double v = Range(key, fallback, lo, hi);
    if (v != std::floor(v)) throw InputError(where_ + ": '" + key + "' must be a whole number");
    return static_cast<Int>(v);
  }
  void Seen(const std::string& key) { seen_.insert(key); }
  // Unknown keys are errors: a typo must not silently fall back to a default. So is a key given
  // twice, of which YAML's reader keeps the first without a word (an edited config whose second
  // `trigger_rate_hz: 5` recorded at 30 Hz).
  void CheckKnown() const {
    std::set<std::string> keys;
    for (const auto& kv : node_) {
      const std::string k = kv.first.as<std::string>();
      if (!keys.insert(k).second)
        throw InputError(where_ + ": '" + k + "' is given twice (line " +
                         std::to_string(kv.first.Mark().line + 1) + ")");
      if (!seen_.count(k)) throw InputError(where_ + ": unknown key '" + k + "'");
    }
  }
  const std::string& where() const { return where_; }

 private:
  YAML::Node node_;
  std::string where_;
  std::set<std::string> seen_;
};

// A key given twice in any map of `node`, at any depth, is an error naming it and its line: YAML's
// reader keeps the first without a word. Throws InputError "<where>: 'k' is given twice (line L)".
inline void RejectDuplicateKeys(const YAML::Node& node, const std::string& where) {
  if (node.IsSequence()) {
    for (const auto& item : node) RejectDuplicateKeys(item, where);
  } else if (node.IsMap()) {
    std::set<std::string> keys;
    for (const auto& kv : node) {
      if (kv.first.IsScalar() && !keys.insert(kv.first.Scalar()).second)
        throw InputError(where + ": '" + kv.first.Scalar() + "' is given twice (line " +
                         std::to_string(kv.first.Mark().line + 1) + ")");
      RejectDuplicateKeys(kv.second, where);
    }
  }
}

// The YAML file at `path`, a `kind` of file ("config file", "rig file"), with no key given twice. Throws InputError
// naming the path: "a folder, not a <kind>", "cannot open <kind>", "not valid YAML: ...".
inline YAML::Node LoadYamlFile(const std::string& path, const std::string& kind) {
  if (std::filesystem::is_directory(path)) throw InputError(path + ": a folder, not a " + kind);
  try {
    const YAML::Node root = YAML::LoadFile(path);
    RejectDuplicateKeys(root, path);
    return root;
  } catch (const YAML::BadFile&) {
    throw InputError(path + ": cannot open " + kind);
  } catch (const YAML::Exception& e) {
    throw InputError(path + ": not valid YAML: " + e.what());
  }
}

// For readers that take values without a ConfigReader: `node` is a map whose keys are all in
// `known`. Throws InputError "<where>: must be a map" or "<where>: unknown key 'k'".
inline void CheckKeys(const YAML::Node& node, std::initializer_list<const char*> known,
                      const std::string& where) {
  if (!node.IsMap()) throw InputError(where + ": must be a map");
  ConfigReader r(node, where);
  for (const char* k : known) r.Seen(k);
  r.CheckKnown();
}

}  // namespace flamerig

#endif  // FLAMERIG_CORE_CONFIG_READER_H_
