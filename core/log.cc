#include "core/log.h"

#include <spdlog/sinks/basic_file_sink.h>
#include <spdlog/sinks/stdout_sinks.h>
#include <unistd.h>

#include <filesystem>
#include <map>
#include <mutex>

#include "core/error.h"

namespace flamerig {

namespace {

constexpr const char* kPattern = "%Y-%m-%d %H:%M:%S.%e %-7l %v";

struct LogState {
  std::mutex mutex;
  std::shared_ptr<spdlog::logger> logger;
  spdlog::sink_ptr stderr_sink;
  std::map<std::string, spdlog::sink_ptr> files;

  LogState() {
    logger = std::make_shared<spdlog::logger>("flamerig");
    logger->set_level(spdlog::level::info);
    logger->flush_on(spdlog::level::trace);  // every line reaches the file at once (crash-safe)
  }

  void Rebuild() {
    std::vector<spdlog::sink_ptr> sinks;
    if (stderr_sink) sinks.push_back(stderr_sink);
    for (const auto& [path, sink] : files) sinks.push_back(sink);
    logger->sinks() = sinks;
  }
};

LogState& State() {
  static LogState* state = new LogState;  // never destroyed: threads may log during exit
  return *state;
}

}  // namespace

spdlog::logger& Log() { return *State().logger; }

void ConfigureLog(const LogOptions& options) {
  LogState& s = State();
  std::lock_guard<std::mutex> lock(s.mutex);
  s.stderr_sink.reset();
  if (options.to_stderr) {
    s.stderr_sink = std::make_shared<spdlog::sinks::stderr_sink_mt>();
    s.stderr_sink->set_pattern(kPattern);
  }
  switch (options.verbosity) {
    case Verbosity::kQuiet: s.logger->set_level(spdlog::level::warn); break;
    case Verbosity::kNormal: s.logger->set_level(spdlog::level::info); break;
    case Verbosity::kVerbose: s.logger->set_level(spdlog::level::debug); break;
  }
  s.Rebuild();
}

void AddLogFile(const std::string& path) {
  LogState& s = State();
  std::lock_guard<std::mutex> lock(s.mutex);
  if (s.files.count(path)) return;
  try {
    const std::filesystem::path parent = std::filesystem::path(path).parent_path();
    if (!parent.empty()) std::filesystem::create_directories(parent);
    auto sink = std::make_shared<spdlog::sinks::basic_file_sink_mt>(path, false);
    sink->set_pattern(kPattern);
    s.files[path] = sink;
  } catch (const std::exception& e) {
    throw IoError(path + ": cannot open the log file: " + e.what());
  }
  s.Rebuild();
}

void RemoveLogFile(const std::string& path) {
  LogState& s = State();
  std::lock_guard<std::mutex> lock(s.mutex);
  s.files.erase(path);
  s.Rebuild();
}

void ResetLog() {
  LogState& s = State();
  std::lock_guard<std::mutex> lock(s.mutex);
  s.stderr_sink.reset();
  s.files.clear();
  s.Rebuild();
  s.logger->set_level(spdlog::level::info);
}

bool StderrIsTerminal() { return ::isatty(STDERR_FILENO) == 1; }

}  // namespace flamerig
