// The capture soak test (issue 9): `flamerig capture` records simulated cameras for a while as a
// separate process, while faults are injected at random (seeded):
//   - cameras dying and coming back (each camera's outage at a random time, for a random while);
//   - the whole daemon stopped and resumed (SIGSTOP / SIGCONT, 50 to 800 ms): a disk or scheduler
//     stall, during which nothing is written and the cameras' frames pile up;
//   - control clients that ask for a preview, that connect and vanish, that send half a request
//     and vanish, and that connect and say nothing (the server cuts them after 2 s).
// Afterwards every frame set of the recording is read back and every frame compared byte for byte
// with what the simulated camera produced (its test pattern is a function of camera and frame id),
// the number of sets the daemon reported as recorded is compared with the number readable, and the
// daemon's peak resident memory (sampled from /proc) is compared with its queue bounds.
#ifndef FLAMERIG_TOOLS_SOAK_H_
#define FLAMERIG_TOOLS_SOAK_H_

#include <cstdint>
#include <functional>
#include <string>

namespace flamerig {

struct SoakOptions {
  std::string binary;     // the flamerig executable to run as the daemon
  std::string directory;  // scratch folder (created, removed after unless keep)
  double seconds = 20;    // how long the daemon records
  int cameras = 4;
  int width = 320, height = 240;
  double rate_hz = 50;
  double queue_mb = 64;  // the recorder's queue bound
  std::uint64_t seed = 1;
  bool keep = false;
};

struct SoakReport {
  double seconds = 0;
  std::uint64_t sets_reported = 0;  // "N frame sets recorded" in the daemon's last line
  std::uint64_t sets_readable = 0;  // in the recording, every frame's checksum verified
  std::uint64_t frames_checked = 0, frames_wrong = 0;  // bytes against the test pattern
  std::uint64_t sets_dropped = 0;  // refused by the bounded queue (reported, not lost)
  std::uint64_t lost = 0;          // reported as recorded but not read back exactly: must be 0
  int outages = 0, stalls = 0, preview_clients = 0, vanishing_clients = 0;
  double peak_rss_mb = 0, rss_bound_mb = 0;
  std::string daemon_tail;  // the daemon's last lines, for a failure message
  bool ok() const { return lost == 0 && frames_wrong == 0 && peak_rss_mb <= rss_bound_mb; }
  std::string Markdown() const;
};

// Runs the soak. Throws std::runtime_error when the daemon cannot be started or its recording
// cannot be opened at all.
SoakReport RunSoak(const SoakOptions& options,
                   const std::function<void(const std::string&)>& log = nullptr);

// `flamerig benchmark soak`: RunSoak, and its BENCHMARKS.md section (the daemon's last lines go
// to `log` when it failed).
std::string RunSoakBenchmark(const SoakOptions& options,
                             const std::function<void(const std::string&)>& log);

}  // namespace flamerig

#endif  // FLAMERIG_TOOLS_SOAK_H_
