// flamerig's log: timestamped lines through spdlog, one logger for the whole program.
//
// Library code that has something to tell an operator while it runs (the capture daemon's state
// changes and camera events, a recording recovered on open) logs through Log(); it never writes to
// stdout or stderr itself. By default the logger has no sink, so a library used on its own (a
// test, a program of the user's) prints nothing. The CLI attaches the sinks (ConfigureLog): stderr,
// and for the capture daemon a file in its data directory (AddLogFile).
//
// Every line reads "2026-11-23 19:44:01.123 info    capture: recording into ...": local date and
// time to the millisecond, the level (debug, info, warning, error), the message. Plain lines only: a log never holds "\r" or
// terminal escapes, whether it goes to a terminal or a file.
//
// Levels: debug (--verbose), info (default), warn, error; --quiet shows warnings and errors only.
//
// Thread safety: Log() and its logger are safe from any thread; ConfigureLog, AddLogFile and
// RemoveLogFile are for the main thread, before or after the threads that log.
#ifndef FLAMERIG_CORE_LOG_H_
#define FLAMERIG_CORE_LOG_H_

#include <spdlog/spdlog.h>

#include <memory>
#include <string>

namespace flamerig {

// The program's logger ("flamerig"); never null.
spdlog::logger& Log();

enum class Verbosity { kQuiet, kNormal, kVerbose };

struct LogOptions {
  Verbosity verbosity = Verbosity::kNormal;
  bool to_stderr = true;  // a sink on stderr
};

// Replaces the logger's sinks by the ones `options` asks for (file sinks added with AddLogFile are
// kept) and sets its level.
void ConfigureLog(const LogOptions& options);

// Also writes every line to `path` (appended; created with its folder). Throws IoError naming the
// path when it cannot be opened.
void AddLogFile(const std::string& path);
void RemoveLogFile(const std::string& path);

// Removes every sink (tests).
void ResetLog();

// True when stderr is a terminal: the only case where the CLI draws progress bars with "\r".
bool StderrIsTerminal();

}  // namespace flamerig

#endif  // FLAMERIG_CORE_LOG_H_
