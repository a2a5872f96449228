#include "core/read_file.h"

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <system_error>

#include "core/error.h"

namespace flamerig {

namespace fs = std::filesystem;

std::string ReadFile(const std::string& path) {
  std::error_code ec;
  if (fs::is_directory(path, ec)) throw IoError(path + ": cannot be read: it is a folder");
  errno = 0;
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    const int e = errno;
    throw IoError(path + ": cannot be read" +
                  (e != 0 ? std::string(": ") + std::strerror(e) : std::string()));
  }
  std::ostringstream all;
  // An empty file extracts nothing, which sets failbit on `all`; only a failed read is an error.
  if (in.peek() != std::ifstream::traits_type::eof()) all << in.rdbuf();
  if (in.bad() || all.bad()) throw IoError(path + ": the read failed part way");
  return all.str();
}

std::optional<std::string> ReadFileIfPresent(const std::string& path) {
  std::error_code ec;
  if (!fs::exists(fs::symlink_status(path, ec))) return std::nullopt;
  return ReadFile(path);
}

}  // namespace flamerig
