// The capture soak test (issue 9): `flamerig capture` records simulated cameras for a while as a
// separate process, while faults are injected at random (seeded):
//   - cameras dying and coming back, again and again (each camera's outages at random times, for
//     random whiles, set in the simulated cameras' config);
//   - the whole daemon stopped and resumed (SIGSTOP / SIGCONT, 50 to 800 ms): a scheduler stall,
//     during which nothing runs and the cameras' frames pile up;
//   - the writer alone stopped and resumed while capture goes on: one camera's writer thread, or
//     every writer thread and the set committer (a disk stall: 50 ms to 8 s, long enough to fill
//     the queue). SIGSTOP stops a whole process (POSIX), so threads are stopped with ptrace
//     (PTRACE_SEIZE + PTRACE_INTERRUPT, then PTRACE_DETACH), found by their names
//     (acquisition/thread_name.h). Where ptrace is refused (a container's seccomp, Yama's
//     ptrace_scope 3) these are skipped and `writer_stall_refused` says why;
//   - control clients that ask for a preview, that connect and vanish, that send half a request
//     and vanish, and that connect and say nothing (the server cuts them after 2 s).
// Every frame set of each recording is read back and every frame compared byte for byte with what
// the simulated camera produced (its test pattern is a function of camera and frame id), the number
// of sets the daemon reported as recorded is compared with the number readable, and the daemon's
// peak resident memory (sampled from /proc) is compared with its queue bounds. Long soaks close
// the recording every `segment_seconds` and start another through the control API, and check and
// remove the closed one while capture goes on: an hour at 4 x 320x240 x 50 Hz is 55 GB otherwise.
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
  // Every this many seconds the recording is closed ("stop") and a new one started ("start"), and
  // the closed one is checked and removed while capture goes on (so that hours fit on a disk);
  // 0 = one recording.
  double segment_seconds = 0;
  std::uint64_t seed = 1;
  bool keep = false;
};

struct SoakReport {
  double seconds = 0;
  int segments = 0;                 // recordings checked
  std::uint64_t sets_reported = 0;  // by "stop" replies and the daemon's last line
  std::uint64_t sets_readable = 0;  // in the recording, every frame's checksum verified
  std::uint64_t frames_checked = 0, frames_wrong = 0;  // bytes against the test pattern
  std::uint64_t sets_dropped = 0;    // refused by the bounded queue (reported, not lost)
  std::uint64_t lost = 0;            // reported as recorded but not read back exactly: must be 0
  int outages = 0;                   // scheduled in the cameras' config
  int outages_seen = 0;              // disconnects the daemon reported at its end
  int stalls = 0;                    // the whole daemon: SIGSTOP / SIGCONT
  int writer_stalls = 0;             // one camera's writer thread stopped (ptrace)
  int disk_stalls = 0;               // every writer thread and the committer stopped (ptrace)
  std::string writer_stall_refused;  // why ptrace could not stop threads here; empty if it could
  int preview_clients = 0, vanishing_clients = 0;
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
