#include "core/atomic_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <system_error>

#include "core/error.h"

namespace flamerig {

namespace fs = std::filesystem;

namespace {

std::string Errno(int e) { return std::strerror(e); }

void SyncFolderOf(const fs::path& path) {
  fs::path dir = path.parent_path();
  if (dir.empty()) dir = ".";
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd >= 0) {
    ::fsync(fd);
    ::close(fd);
  }
}

void RenameInto(const std::string& temp, const std::string& path) {
  std::error_code ec;
  fs::rename(temp, path, ec);
  if (ec) {
    const std::string why = ec.message();  // before remove() sets ec again (it said "Success")
    fs::remove(temp, ec);
    throw IoError(path + ": cannot move the written file into place: " + why);
  }
  SyncFolderOf(path);
}

// A name beside `path` that no other writer uses: ".tmp-<pid>-<n>" before the extension (some
// writers choose the format by it), so that two writers of one path (two processes, two threads)
// never write into each other's file.
std::string TempName(const std::string& path, bool keep_extension) {
  static std::atomic<unsigned long> counter{0};
  const std::string tag =
      ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(counter.fetch_add(1));
  const fs::path p(path);
  const std::string ext = p.extension().string();
  if (!keep_extension || ext.empty()) return path + tag;
  return (p.parent_path() / (p.stem().string() + tag + ext)).string();
}

}  // namespace

void WriteFileAtomically(const std::string& path, std::string_view bytes) {
  const std::string temp = TempName(path, false);
  const int fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) throw IoError(path + ": cannot write: " + Errno(errno));
  std::size_t done = 0;
  int error = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      error = n < 0 ? errno : ENOSPC;
      break;
    }
    done += static_cast<std::size_t>(n);
  }
  if (!error && ::fdatasync(fd) != 0) error = errno;
  ::close(fd);
  if (error) {
    std::error_code ec;
    fs::remove(temp, ec);
    throw IoError(path + ": write failed: " + Errno(error));
  }
  RenameInto(temp, path);
}

void SyncFile(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd >= 0) {
    ::fdatasync(fd);
    ::close(fd);
  }
  SyncFolderOf(path);
}

void CopyFileAtomically(const std::string& from, const std::string& to) {
  const std::string temp = TempName(to, false);
  std::error_code ec;
  fs::copy_file(from, temp, fs::copy_options::overwrite_existing, ec);
  if (ec) {
    fs::remove(temp, ec);
    throw IoError(to + ": cannot copy " + from + " there: " + ec.message());
  }
  SyncFile(temp);
  RenameInto(temp, to);
}

AtomicFile::AtomicFile(std::string path) : path_(std::move(path)), temp_(TempName(path_, true)) {}

AtomicFile::~AtomicFile() {
  if (!committed_) {
    std::error_code ec;
    fs::remove(temp_, ec);
  }
}

void AtomicFile::Commit() {
  if (!fs::exists(temp_)) throw IoError(path_ + ": nothing was written to " + temp_);
  SyncFile(temp_);
  RenameInto(temp_, path_);
  committed_ = true;
}

}  // namespace flamerig
