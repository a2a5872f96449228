#include "pipeline/subprocess.h"

#include <fcntl.h>
#include <spawn.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <thread>

#include "core/error.h"
#include "core/memory.h"
#include "core/read_file.h"

namespace flamerig {

namespace fs = std::filesystem;

ProgramResult RunProgram(const std::vector<std::string>& args, const std::string& dir) {
  ProgramResult result;
  if (args.empty()) {
    result.error = "no program given";
    return result;
  }
  static std::atomic<int> counter{0};
  const fs::path log = fs::temp_directory_path() / ("flamerig-" + std::to_string(::getpid()) + "-" +
                                                    std::to_string(counter++) + ".stderr");
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  if (!dir.empty()) posix_spawn_file_actions_addchdir_np(&actions, dir.c_str());
  posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&actions, 1, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_addopen(&actions, 2, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0600);
  std::vector<std::string> copies = args;
  std::vector<char*> argv;
  for (std::string& a : copies) argv.push_back(a.data());
  argv.push_back(nullptr);
  pid_t pid = -1;
  const auto start = std::chrono::steady_clock::now();
  const int spawned = posix_spawnp(&pid, argv[0], &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  std::error_code ignored;
  if (spawned != 0) {
    fs::remove(log, ignored);
    result.error = "cannot run " + args[0] + " (" + std::strerror(spawned) + ")";
    return result;
  }
  // The child's peak is read from its own /proc status while it runs: wait4's ru_maxrss would
  // include this process's peak at the spawn, because Linux carries the high-water mark of the
  // memory a process had before exec into its rusage (after a spawn from a 600 MB benchmark, a
  // 400 MB child reported 619 MB). VmHWM is a high-water mark, so the last reading before the
  // exit misses at most the last few milliseconds' growth.
  int status = 0;
  struct rusage usage {};
  std::size_t polled_peak = 0;
  for (;;) {
    const pid_t done = ::wait4(pid, &status, WNOHANG, &usage);
    if (done == pid) break;
    if (done < 0 && errno != EINTR) break;
    polled_peak = std::max(polled_peak, PeakResidentBytesOf(pid));
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  result.peak_resident_bytes =
      polled_peak > 0 ? polled_peak : static_cast<std::size_t>(usage.ru_maxrss) * 1024;
  try {
    result.error = ReadFileIfPresent(log.string()).value_or("").substr(0, 2000);
  } catch (const IoError& e) {
    result.error = e.what();
  }
  fs::remove(log, ignored);
  result.exit_status = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  // posix_spawnp reports a program missing from PATH as exit status 127 of the child.
  result.started = result.exit_status != 127;
  if (!result.started) result.error = "cannot run " + args[0] + " (not found)";
  return result;
}

}  // namespace flamerig
