// Helpers for the fuzz targets: inputs become files in a private temporary folder (most of
// flamerig's parsers read files), and the exceptions a parser is allowed to throw on bad input are
// caught: anything else (a crash, a sanitizer report, an uncaught exception, a hang) is a finding.
#ifndef FLAMERIG_TESTS_FUZZ_FUZZ_UTIL_H_
#define FLAMERIG_TESTS_FUZZ_FUZZ_UTIL_H_

#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <system_error>

namespace flamerig_fuzz {

// This process's scratch folder, removed when the process exits normally (a crash keeps it, with
// the input that caused it).
inline const std::filesystem::path& Dir() {
  struct Scratch {
    std::filesystem::path path =
        std::filesystem::temp_directory_path() / ("flamerig_fuzz_" + std::to_string(::getpid()));
    Scratch() { std::filesystem::create_directories(path); }
    ~Scratch() {
      std::error_code ignored;
      std::filesystem::remove_all(path, ignored);
    }
  };
  static const Scratch dir;
  return dir.path;
}

inline std::string WriteFile(const std::string& name, const std::uint8_t* data, std::size_t size) {
  const auto path = Dir() / name;
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  return path.string();
}

}  // namespace flamerig_fuzz

#endif  // FLAMERIG_TESTS_FUZZ_FUZZ_UTIL_H_
