#include "tools/soak.h"

#include <dirent.h>
#include <fcntl.h>
#include <signal.h>
#include <sys/ptrace.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <future>
#include <random>
#include <sstream>
#include <thread>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "core/error.h"
#include "acquisition/control.h"
#include "acquisition/recording.h"
#include "acquisition/sim_camera.h"
#include "tools/benchmark.h"

namespace flamerig {

namespace fs = std::filesystem;

namespace {

using SteadyClock = std::chrono::steady_clock;

double ResidentMb(pid_t pid) {
  std::ifstream status("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(status, line))
    if (line.rfind("VmRSS:", 0) == 0) return std::atof(line.c_str() + 6) / 1024.0;
  return 0;
}

// A client that connects to the Unix socket and then misbehaves: `mode` 0 closes at once, 1 sends
// half a request and vanishes, 2 says nothing for 3 s.
void Misbehave(const std::string& socket_path, int mode) {
  const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return;
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  std::strncpy(addr.sun_path, socket_path.c_str(), sizeof(addr.sun_path) - 1);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0) {
    if (mode == 1) {
      const char half[] = "previ";
      (void)!::write(fd, half, sizeof half - 1);
    } else if (mode == 2) {
      std::this_thread::sleep_for(std::chrono::seconds(3));
    }
  }
  ::close(fd);
}

// The threads of process `pid` whose names (/proc/PID/task/TID/comm) start with one of `prefixes`.
std::vector<pid_t> ThreadsNamed(pid_t pid, const std::vector<std::string>& prefixes) {
  std::vector<pid_t> found;
  const std::string task = "/proc/" + std::to_string(pid) + "/task";
  DIR* d = ::opendir(task.c_str());
  if (!d) return found;
  while (const dirent* e = ::readdir(d)) {
    if (e->d_name[0] == '.') continue;
    std::ifstream comm(task + "/" + e->d_name + "/comm");
    std::string name;
    std::getline(comm, name);
    for (const auto& p : prefixes)
      if (name.rfind(p, 0) == 0) found.push_back(static_cast<pid_t>(std::atoi(e->d_name)));
  }
  ::closedir(d);
  return found;
}

// Stops the threads `tids` (ptrace: seize, interrupt, wait for the stop) for `ms`, then lets them
// go. The rest of their process runs on. Returns "" or why ptrace refused (nothing is left
// stopped either way). A thread that has exited meanwhile is skipped.
std::string StopThreadsFor(const std::vector<pid_t>& tids, int ms) {
  std::vector<pid_t> held;
  std::string refused;
  for (const pid_t tid : tids) {
    if (::ptrace(PTRACE_SEIZE, tid, nullptr, nullptr) != 0) {
      if (errno == EPERM || errno == EACCES)
        refused = std::string("ptrace: ") + std::strerror(errno);
      continue;  // ESRCH: gone
    }
    held.push_back(tid);
    int status = 0;
    if (::ptrace(PTRACE_INTERRUPT, tid, nullptr, nullptr) == 0)
      (void)::waitpid(tid, &status, __WALL);  // the thread is stopped (or has exited)
  }
  if (refused.empty()) std::this_thread::sleep_for(std::chrono::milliseconds(ms));
  for (const pid_t tid : held) (void)::ptrace(PTRACE_DETACH, tid, nullptr, nullptr);
  return refused;
}

// What one closed recording holds against what the daemon reported for it.
struct SegmentCheck {
  std::uint64_t readable = 0, frames = 0, wrong = 0, lost = 0;
};

// Reads every set of the recording at `path` back (checksums), compares every frame byte for byte
// with the pattern its camera produced, and counts as lost what the daemon reported as recorded
// but did not read back.
SegmentCheck CheckSegment(const fs::path& path, std::uint64_t reported) {
  SegmentCheck c;
  const Recording rec = Recording::Open(path.string());
  const ImageSource pattern = TestPatternSource();
  std::vector<std::uint8_t> expected;
  for (std::size_t i = 0; i < rec.num_sets(); ++i) {
    FrameSet set;
    try {
      set = rec.ReadSet(i);
    } catch (const RecordingError&) {
      continue;  // counted as lost below
    }
    ++c.readable;
    for (const auto& f : set.frames) {
      if (!f) continue;
      ++c.frames;
      pattern(f->info, &expected);
      if (!f->data || *f->data != expected) ++c.wrong;
    }
  }
  c.lost = reported > c.readable ? reported - c.readable : 0;
  return c;
}

// What the daemon reported for a closed recording: sets recorded and dropped, -1 when unknown.
struct Reported {
  long long recorded = -1, dropped = -1;
};

// From the "stop" reply's body, or from the recording's metadata.yaml (the recorder writes its
// final counters there when it closes).
Reported ParseReported(const YAML::Node& counters) {
  Reported r;
  try {
    r.recorded = counters["sets_recorded"].as<long long>();
    r.dropped = counters["sets_dropped"].as<long long>();
  } catch (const std::exception&) {
    r = Reported{};
  }
  return r;
}

}  // namespace

std::string SoakReport::Markdown() const {
  std::ostringstream md;
  md << "| seconds | recordings | frame sets reported recorded | read back, checksums and pixels "
        "exact | lost | "
        "dropped by the bounded queue (reported) | camera outages (disconnects the daemon saw) | "
        "daemon stalls (SIGSTOP) | one writer stopped | disk stalls (all writers stopped) | "
        "preview clients | vanishing clients | peak memory MB (bound) |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  const std::string refused =
      writer_stall_refused.empty() ? "" : " (refused: " + writer_stall_refused + ")";
  md << "| " << Fixed(seconds, 0) << " | " << segments << " | " << sets_reported << " | "
     << sets_readable << " (" << frames_checked << " frames, " << frames_wrong << " wrong) | "
     << lost << " | " << sets_dropped << " | " << outages << " (" << outages_seen << ") | "
     << stalls << " | " << writer_stalls << refused << " | " << disk_stalls << refused << " | "
     << preview_clients << " | " << vanishing_clients << " | " << Fixed(peak_rss_mb, 0) << " ("
     << Fixed(rss_bound_mb, 0) << ") |\n";
  return md.str();
}

SoakReport RunSoak(const SoakOptions& o, const std::function<void(const std::string&)>& log) {
  const fs::path dir = fs::absolute(o.directory);
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> uniform(0, 1);
  SoakReport report;
  // The config: cameras on a simulated trigger line, each with outages at random times: the first
  // 1 to 3 s in, each 0.3 to 2 s long, 1 to 8 s apart, none in the last second.
  const std::string socket_path = (dir / "control.sock").string();
  {
    std::ofstream y(dir / "soak.yaml");
    y << "data_dir: " << (dir / "rec").string()
      << "\nsync: hardware-trigger\ntrigger_rate_hz: " << o.rate_hz
      << "\npretrigger_seconds: 0\nqueue_mb: " << o.queue_mb
      << "\nset_timeout_ms: 300\nmin_free_mb: 16\ncontrol: unix:" << socket_path << "\ncameras:\n";
    for (int c = 0; c < o.cameras; ++c) {
      y << "  - {name: cam" << c << ", width: " << o.width << ", height: " << o.height
        << ", pixel_format: Mono8, sim: {seed: " << c + 1 << ", jitter_us: 100, outages: [";
      double down = 1 + 2 * uniform(rng);
      for (int k = 0;; ++k) {
        const double up = down + 0.3 + 1.7 * uniform(rng);
        if (up > o.seconds - 1) break;
        y << (k ? ", " : "") << "[" << down << ", " << up << "]";
        ++report.outages;
        down = up + 1 + 7 * uniform(rng);
      }
      y << "]}}\n";
    }
  }
  // The daemon, as its own process (so that it can be stopped, resumed and measured).
  const fs::path log_path = dir / "daemon.log";
  const pid_t pid = ::fork();
  if (pid < 0) throw IoError("soak: fork failed");
  if (pid == 0) {
    const int out = ::open(log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    ::dup2(out, 1);
    ::dup2(out, 2);
    const std::string config = (dir / "soak.yaml").string(), duration = std::to_string(o.seconds);
    ::execl(o.binary.c_str(), o.binary.c_str(), "capture", "--config", config.c_str(), "--record",
            "soak", "--duration", duration.c_str(), static_cast<char*>(nullptr));
    ::_exit(127);
  }
  const auto start = SteadyClock::now();
  auto elapsed = [&] { return std::chrono::duration<double>(SteadyClock::now() - start).count(); };
  std::atomic<bool> done{false};
  std::atomic<int> previews{0}, vanishing{0};
  // Control clients, at random.
  std::thread clients([&] {
    std::mt19937_64 r(o.seed * 7 + 1);
    while (!done) {
      std::this_thread::sleep_for(std::chrono::milliseconds(100 + r() % 400));
      if (done || !fs::exists(socket_path)) continue;
      const int what = static_cast<int>(r() % 4);
      if (what == 0) {
        try {
          ControlRequest("unix:" + socket_path,
                         "preview cam" + std::to_string(r() % o.cameras) + " 4", 5);
          ++previews;
        } catch (const std::exception&) {
        }
      } else {
        std::thread(Misbehave, socket_path, what - 1).detach();
        ++vanishing;
      }
    }
  });
  // Every closed segment is checked (then removed) while capture goes on.
  std::mutex checks_mutex;
  std::vector<std::future<void>> checks;
  auto check = [&](const fs::path& path, Reported reported) {
    const SegmentCheck c = CheckSegment(path, reported.recorded);
    if (!o.keep) fs::remove_all(path);
    std::lock_guard<std::mutex> lock(checks_mutex);
    report.sets_reported += reported.recorded;
    report.sets_dropped += reported.dropped;
    report.sets_readable += c.readable;
    report.frames_checked += c.frames;
    report.frames_wrong += c.wrong;
    report.lost += c.lost;
    ++report.segments;
  };
  // Rotation: "stop" (its reply: the recorder's final counters) and "start soak_K". A stop whose
  // reply was lost (the server busy with misbehaving clients past the timeout) is taken from the
  // recording's metadata.yaml, which the recorder wrote when it closed.
  std::string segment = "soak";
  int next_segment = 1;
  double next_rotation = o.segment_seconds > 0 ? o.segment_seconds : 1e300;
  auto rotate = [&] {
    const fs::path closed = dir / "rec" / segment;
    Reported reported;
    try {
      const ControlReply r = ControlRequest("unix:" + socket_path, "stop", 30);
      if (r.ok) reported = ParseReported(YAML::Load(r.body));
    } catch (const std::exception&) {
    }
    if (reported.recorded < 0) {
      try {
        reported = ParseReported(YAML::LoadFile((closed / "metadata.yaml").string())["counters"]);
      } catch (const std::exception&) {
      }
    }
    if (reported.recorded < 0) return;  // not closed yet: try again at the next turn
    checks.push_back(std::async(std::launch::async, check, closed, reported));
    segment = "soak_" + std::to_string(next_segment++);
    for (int attempt = 0; attempt < 3; ++attempt) {
      try {
        ControlRequest("unix:" + socket_path, "start " + segment, 30);
        break;
      } catch (const std::exception&) {  // unanswered: an answered refusal is not retried
      }
    }
  };
  // Stalls, and the memory samples.
  int status = 0;
  bool exited = false;
  double next_stall = 1.0 + uniform(rng) * 2;
  // The first three faults are one of each kind (one writer, the disk, the whole daemon), so that a
  // short soak meets every kind whatever the draws; after them the kind is drawn. A thread stall
  // that finds no such thread yet (a slow start, a rotation) is tried again shortly and not counted.
  int faults = 0;
  while (!exited) {
    report.peak_rss_mb = std::max(report.peak_rss_mb, ResidentMb(pid));
    if (::waitpid(pid, &status, WNOHANG) == pid) {
      exited = true;
      break;
    }
    if (elapsed() > next_rotation && elapsed() < o.seconds - 3) {
      rotate();
      next_rotation = elapsed() + o.segment_seconds;
    }
    // A stall ends before the next rotation is due, so that the recordings rotate on time.
    const bool rotation_due = next_rotation < o.seconds - 3;
    const double until_rotation_ms = (next_rotation - elapsed()) * 1000 - 100;
    if (elapsed() > next_stall && elapsed() < o.seconds - 1 &&
        !(rotation_due && until_rotation_ms < 50)) {
      // One fault at a time, so that a thread held by ptrace never meets a SIGSTOP; each ends a
      // second before the daemon does.
      const double drawn = uniform(rng), left_ms = (o.seconds - 1 - elapsed()) * 1000;
      const double kind = faults == 0 ? 0.5 : faults == 1 ? 0.8 : faults == 2 ? 0.0 : drawn;
      // A disk stall takes at most a fifth of the soak, leaving time for the other faults.
      auto cap = [&](double ms) {
        return static_cast<int>(
            std::min({ms, left_ms, o.seconds * 1000 / 5, rotation_due ? until_rotation_ms : ms}));
      };
      bool done = true;
      if (kind < 0.4 || !report.writer_stall_refused.empty()) {
        const int ms = cap(50 + 750 * uniform(rng));
        ::kill(pid, SIGSTOP);
        std::this_thread::sleep_for(std::chrono::milliseconds(ms));
        ::kill(pid, SIGCONT);
        ++report.stalls;
      } else if (kind < 0.7) {
        const int ms = cap(50 + 1950 * uniform(rng));
        const std::string writer = "fr-write" + std::to_string(rng() % o.cameras);
        const auto tids = ThreadsNamed(pid, {writer});
        done = !tids.empty();
        if (done) report.writer_stall_refused = StopThreadsFor(tids, ms);
        if (done && report.writer_stall_refused.empty()) ++report.writer_stalls;
      } else {
        const int ms = cap(50 + 7950 * uniform(rng));
        const auto tids = ThreadsNamed(pid, {"fr-write", "fr-commit"});
        done = !tids.empty();
        if (done) report.writer_stall_refused = StopThreadsFor(tids, ms);
        if (done && report.writer_stall_refused.empty()) ++report.disk_stalls;
      }
      faults += done;
      next_stall = elapsed() + (done ? 0.5 + 2.5 * uniform(rng) : 0.2);
    }
    if (elapsed() > o.seconds + 60) {  // a hung daemon is a failure, not a wait
      ::kill(pid, SIGKILL);
      ::waitpid(pid, &status, 0);
      exited = true;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  done = true;
  clients.join();
  std::this_thread::sleep_for(std::chrono::milliseconds(100));  // detached misbehavers
  report.preview_clients = previews;
  report.vanishing_clients = vanishing;
  report.seconds = elapsed();
  Reported last;  // the daemon's last line: its last recording
  {
    std::ifstream in(log_path);
    std::string line, all;
    while (std::getline(in, line)) {
      all += line + "\n";
      const auto gone = line.find(" disconnects, ");
      // Lines are "<date> <time> <level> capture: cam0: ... disconnects, ..." (core/log.h).
      if (line.find("capture: cam") != std::string::npos && gone != std::string::npos)
        report.outages_seen += std::stoi(line.substr(line.rfind(", ", gone) + 2));
      const auto at = line.find(" frame sets recorded, ");
      if (at != std::string::npos) {
        const auto colon = line.rfind(": ", at);
        last.recorded = std::stoll(line.substr(colon + 2));
        last.dropped = std::stoll(line.substr(at + 22));
      }
    }
    report.daemon_tail = all.size() > 2000 ? all.substr(all.size() - 2000) : all;
  }
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0)
    throw DataError("soak: the daemon did not exit cleanly:\n" + report.daemon_tail);
  if (log) log("soak: daemon done, reading the last recording back");
  if (last.recorded < 0)
    throw DataError("soak: the daemon did not report its last recording:\n" +
                             report.daemon_tail);
  check(dir / "rec" / segment, last);
  for (auto& c : checks)
    c.get();  // rethrows what a check threw (a recording that cannot be opened)
  // Memory: the recorder's queue bound plus the cameras' buffers and the process itself.
  const double frame_mb = o.width * double(o.height) / 1048576.0;
  report.rss_bound_mb = o.queue_mb + 64 * frame_mb * o.cameras + 200;
#if defined(__SANITIZE_ADDRESS__)
  // AddressSanitizer's quarantine (256 MB) and shadow memory come on top (a sanitizer build of the
  // daemon measured 441 MB where the plain one peaks near 105 MB).
  report.rss_bound_mb += 512;
#endif
  if (!o.keep) fs::remove_all(dir);
  return report;
}

std::string RunSoakBenchmark(const SoakOptions& options,
                             const std::function<void(const std::string&)>& log) {
  if (log) log("soak: " + Fixed(options.seconds, 0) + " s of capture with faults injected");
  const SoakReport r = RunSoak(options, log);
  std::ostringstream m;
  m << "## Capture soak (issue 9)\n\nMachine: " << MachineDescription() << ".\n\n"
    << "`flamerig capture` records " << options.cameras << " simulated cameras (" << options.width
    << "x" << options.height << " Mono8, " << options.rate_hz
    << " Hz hardware trigger) as its own process while faults are injected at random: every "
       "camera dies and comes back again and again (0.3 to 2 s, 1 to 8 s apart), the daemon "
       "is stopped and resumed (SIGSTOP/SIGCONT, 50 to 800 ms: a scheduler stall), one "
       "camera's writer thread is stopped while capture goes on (ptrace, 50 ms to 2 s), every "
       "writer thread and the set committer are stopped (a disk stall, 50 ms to 8 s: the "
       "longer ones fill the "
    << Fixed(options.queue_mb, 0)
    << " MB queue, and whole sets are dropped and reported), and control clients ask for "
       "previews, connect and vanish, send half a request or say nothing. Every "
    << (options.segment_seconds > 0 ? Fixed(options.segment_seconds, 0) +
                                          " s the recording is "
                                          "closed and another started through the control API, "
                                          "and the closed one is checked while capture goes on: "
                                    : std::string())
    << "every frame set is read back (checksums) and every frame compared byte for byte with "
       "the pattern its camera produced; lost counts sets the daemon reported as recorded that did "
       "not read "
       "back exactly. Memory is the daemon's peak resident set, sampled every 20 ms, against "
       "its queue bound plus the frames in flight.\n\n"
    << r.Markdown() << "\n"
    << (r.ok() ? "Verdict: nothing lost, memory bounded.\n" : "Verdict: FAILED.\n");
  if (!r.ok() && log) log(r.daemon_tail);
  return m.str();
}

}  // namespace flamerig
