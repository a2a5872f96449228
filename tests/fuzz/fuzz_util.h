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

namespace flamerig_fuzz {

inline const std::filesystem::path& Dir() {
  static const std::filesystem::path dir = [] {
    const auto d =
        std::filesystem::temp_directory_path() / ("flamerig_fuzz_" + std::to_string(::getpid()));
    std::filesystem::create_directories(d);
    return d;
  }();
  return dir;
}

inline std::string WriteFile(const std::string& name, const std::uint8_t* data, std::size_t size) {
  const auto path = Dir() / name;
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  return path.string();
}

}  // namespace flamerig_fuzz

#endif  // FLAMERIG_TESTS_FUZZ_FUZZ_UTIL_H_
