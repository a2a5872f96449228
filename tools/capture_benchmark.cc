#include <arv.h>
#include <fcntl.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <httplib.h>
#include <atomic>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <map>
#include <mutex>
#include <sstream>
#include <thread>

#include "acquisition/capture.h"
#include "acquisition/live_view.h"
#include "acquisition/netns.h"
#include "core/error.h"
#include "tools/benchmark.h"

namespace flamerig {

namespace fs = std::filesystem;

namespace {

double Now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

double CpuSeconds() {
  rusage u{};
  ::getrusage(RUSAGE_SELF, &u);
  return u.ru_utime.tv_sec + u.ru_utime.tv_usec * 1e-6 + u.ru_stime.tv_sec +
         u.ru_stime.tv_usec * 1e-6;
}

// Sequential write bandwidth of the disk under `dir`: 4 MiB writes, fdatasync at the end.
double DiskMegabytesPerSecond(const fs::path& dir, std::uint64_t bytes) {
  const fs::path file = dir / "disk_probe.bin";
  const int fd = ::open(file.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) throw IoError("benchmark capture: cannot write " + file.string());
  std::vector<char> chunk(4 << 20, 0x5a);
  const double t0 = Now();
  for (std::uint64_t done = 0; done < bytes; done += chunk.size()) {
    if (::write(fd, chunk.data(), chunk.size()) != static_cast<ssize_t>(chunk.size())) {
      ::close(fd);
      throw IoError("benchmark capture: writing " + file.string() + " failed");
    }
  }
  ::fdatasync(fd);
  const double t = Now() - t0;
  ::close(fd);
  fs::remove(file);
  return bytes / t / 1048576.0;
}

// A source that costs what a real driver costs (one copy of the image) and stamps camera and frame.
ImageSource CopySource(std::size_t bytes) {
  auto image = std::make_shared<std::vector<std::uint8_t>>(bytes);
  for (std::size_t i = 0; i < bytes; ++i) (*image)[i] = static_cast<std::uint8_t>(i * 7);
  return [image](const FrameInfo& info, std::vector<std::uint8_t>* out) {
    *out = *image;
    const std::uint64_t stamp[2] = {static_cast<std::uint64_t>(info.camera), info.frame_id};
    std::memcpy(out->data(), stamp, std::min<std::size_t>(16, out->size()));
  };
}

struct Scenario {
  std::string name;
  std::string rig;  // capture config text
};

struct Outcome {
  std::uint64_t sets = 0, complete = 0, recorded = 0, dropped = 0, incoming_dropped = 0;
  std::uint64_t frames_missing = 0;
  std::uint64_t camera_skipped = 0;  // slots the cameras never produced (timestamp gaps)
  double seconds = 0, cpu = 0, megabytes_per_s = 0, max_spread_ms = 0, backlog_peak_mb = 0;
  std::uint64_t page_requests = 0, page_failures = 0;  // with the live view open
  std::string page_first_failure;
};

// The live view's page, open in a browser, as an HTTP client that asks what the page asks once a
// second (acquisition/live_view.cc): the status, then each camera's half-size preview PNG and its
// histogram. Its own work (a few requests a second) is in the process' CPU with the server's.
class PagePoller {
 public:
  PagePoller(int port, int cameras) : cameras_(cameras), client_("127.0.0.1", port) {
    client_.set_connection_timeout(2);  // a server that hangs fails a request, not the run
    client_.set_read_timeout(5);
    thread_ = std::thread([this] { Loop(); });
  }
  ~PagePoller() {
    stop_ = true;
    thread_.join();
  }
  std::uint64_t requests() const { return requests_; }
  std::uint64_t failures() const { return failures_; }
  std::string first_failure() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return first_failure_;
  }

 private:
  void Get(const std::string& path) {
    ++requests_;
    const auto r = client_.Get(path);
    if (r && r->status == 200) return;
    ++failures_;
    std::lock_guard<std::mutex> lock(mutex_);
    if (first_failure_.empty())
      first_failure_ = path + ": " + (r ? std::to_string(r->status) + " " + r->body : "no answer");
    while (!first_failure_.empty() && first_failure_.back() == '\n') first_failure_.pop_back();
  }
  void Loop() {
    while (!stop_) {
      const auto next = std::chrono::steady_clock::now() + std::chrono::seconds(1);
      Get("/api/status");
      for (int c = 0; c < cameras_; ++c) {
        Get("/api/preview?camera=" + std::to_string(c) + "&k=2");
        Get("/api/histogram?camera=" + std::to_string(c));
      }
      while (!stop_ && std::chrono::steady_clock::now() < next)
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
  }
  int cameras_;
  httplib::Client client_;
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> requests_{0}, failures_{0};
  mutable std::mutex mutex_;
  std::string first_failure_;
  std::thread thread_;
};

Outcome Run(const std::string& yaml, double seconds, const fs::path& dir, bool sim_copy_source,
            std::size_t frame_bytes, bool live_view) {
  CaptureConfig config = CaptureConfig::Parse(yaml, "benchmark");
  config.data_dir = dir.string();
  if (sim_copy_source)
    for (auto& c : config.cameras) c.Options<SimCameraOptions>().source = CopySource(frame_bytes);
  SystemClock clock;
  SimTriggerBus bus;
  CaptureDaemon daemon(config, MakeCameras(config, {&clock, &bus}), &clock, &bus);
  daemon.Start();
  std::unique_ptr<LiveViewServer> server;
  if (live_view) server = std::make_unique<LiveViewServer>(&daemon, LiveViewOptions{});
  std::this_thread::sleep_for(std::chrono::milliseconds(300));  // streams settle
  // Opened once every camera has a frame, as the page asks for a camera's image only then.
  std::unique_ptr<PagePoller> page;
  if (server) {
    const double until = Now() + 10;
    auto all_seen = [&] {
      for (const auto& c : daemon.status().cameras)
        if (c.frames == 0) return false;
      return true;
    };
    while (!all_seen() && Now() < until) std::this_thread::sleep_for(std::chrono::milliseconds(20));
    page = std::make_unique<PagePoller>(server->port(), int(config.cameras.size()));
  }
  const double cpu0 = CpuSeconds(), t0 = Now();
  daemon.StartRecording("take");
  double peak_backlog = 0;
  while (Now() - t0 < seconds) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    peak_backlog = std::max(peak_backlog, daemon.status().recorder.queued_bytes / 1048576.0);
  }
  const RecorderStatus r = daemon.StopRecording();  // includes flushing to disk
  Outcome o;
  o.seconds = Now() - t0;
  o.cpu = (CpuSeconds() - cpu0) / o.seconds;
  if (page) {
    o.page_requests = page->requests();
    o.page_failures = page->failures();
    o.page_first_failure = page->first_failure();
  }
  page.reset();
  server.reset();
  const CaptureStatus s = daemon.status();
  daemon.Stop();
  o.recorded = r.sets_recorded;
  o.dropped = r.sets_dropped;
  o.incoming_dropped = s.incoming_dropped;
  for (const auto& c : s.cameras) o.camera_skipped += c.stream.missing_by_time;
  o.megabytes_per_s = r.bytes_written / o.seconds / 1048576.0;
  o.backlog_peak_mb = std::max(peak_backlog, r.peak_queued_bytes / 1048576.0);
  const Recording rec = Recording::Open((dir / "take").string());
  o.sets = rec.num_sets();
  std::int64_t spread = 0;
  for (std::size_t i = 0; i < rec.num_sets(); ++i) {
    const FrameSet set = rec.ReadSet(i);  // reads every byte back and checks its CRC
    o.complete += set.complete();
    spread = std::max(spread, set.spread_ns);
  }
  for (auto m : rec.MissingByFrameId()) o.frames_missing += m;
  o.max_spread_ms = spread / 1e6;
  fs::remove_all(dir / "take");
  return o;
}

std::string Rig(const std::string& sync, double rate, int cameras, int w, int h,
                const std::string& driver, int first_address = 2) {
  std::ostringstream y;
  y << "sync: " << sync << "\ntrigger_rate_hz: " << rate << "\nbuffers: 16\ncameras:\n";
  for (int c = 0; c < cameras; ++c) {
    y << "  - {name: cam" << c << ", driver: " << driver << ", id: "
      << (driver == "sim" ? "SIM" + std::to_string(c)
                          : "127.0.0." + std::to_string(first_address + c))
      << ", width: " << w << ", height: " << h << ", exposure_us: 1000}\n";
  }
  return y.str();
}

// `arv-fake-gv-camera-0.8` processes, one per address, killed (SIGKILL) and reaped when this goes
// out of scope whatever happened. Ready() waits until every one answers on its address.
class FakeCameraProcesses {
 public:
  explicit FakeCameraProcesses(const std::vector<std::string>& addresses) {
    for (std::size_t c = 0; c < addresses.size(); ++c) {
      const pid_t pid = ::fork();
      if (pid == 0) {
        const int null = ::open("/dev/null", O_RDWR);
        ::dup2(null, 1);
        ::dup2(null, 2);
        const std::string serial = "BENCHX" + std::to_string(c);
        ::execl(kExe, kExe, "-i", addresses[c].c_str(), "-s", serial.c_str(),
                static_cast<char*>(nullptr));
        ::_exit(127);
      }
      if (pid > 0) pids_.push_back(pid);
    }
    addresses_ = addresses;
  }
  ~FakeCameraProcesses() {
    for (pid_t pid : pids_) ::kill(pid, SIGKILL);
    for (pid_t pid : pids_) ::waitpid(pid, nullptr, 0);
  }
  static bool Installed() { return fs::exists(kExe); }
  bool Ready(double timeout_s) const {
    const double end = Now() + timeout_s;
    for (const auto& a : addresses_) {
      for (;;) {
        GError* error = nullptr;
        ArvCamera* camera = arv_camera_new(a.c_str(), &error);
        if (camera) {
          g_object_unref(camera);
          break;
        }
        if (error) g_error_free(error);
        if (Now() > end) return false;
        std::this_thread::sleep_for(std::chrono::milliseconds(200));
      }
    }
    return pids_.size() == addresses_.size();
  }

 private:
  static constexpr const char* kExe = "/usr/bin/arv-fake-gv-camera-0.8";
  std::vector<pid_t> pids_;
  std::vector<std::string> addresses_;
};

}  // namespace

std::string RunCaptureBenchmark(const CaptureBenchmarkOptions& options,
                                const std::function<void(const std::string&)>& log) {
  const double seconds = options.quick ? 1.0 : options.seconds;
  const fs::path dir = options.directory;
  fs::remove_all(dir);
  fs::create_directories(dir);
  const double disk = DiskMegabytesPerSecond(dir, options.quick ? (64ull << 20) : (1024ull << 20));
  if (log) log("disk: " + Fixed(disk, 0) + " MB/s sequential write");
  std::ostringstream md;
  md << "## Capture (issue 5)\n\n";
  md << "Machine: " << MachineDescription() << ". Disk under `" << dir.string()
     << "`: " << Fixed(disk, 0)
     << " MB/s sequential write (4 MiB writes then fdatasync, measured at the start of this "
        "run).\n\n";
  md << "The daemon records every frame set for " << Fixed(seconds, 0)
     << " s; afterwards every set is read back and its checksums verified. CPU is the whole "
        "process (cameras, assembler, writers) in cores; sim cameras copy one image per frame, as "
        "a driver copies out of its DMA buffer. Dropped = sets refused by the recorder's bounded "
        "queue + frames the assembler could not take + frame-id gaps in the recording.\n\n";
  md << "| scenario | data rate, MB/s | seconds | frame sets recorded | complete | dropped | "
        "frames the cameras skipped | write MB/s (share of disk) | CPU, cores | peak disk "
        "backlog, MB | max timestamp spread in a set, ms |\n|---|---|---|---|---|---|---|---|---|"
        "---|---|\n";
  struct S {
    std::string name, yaml;
    bool sim;
    std::size_t bytes;
    double data_rate;
    bool live_view = false;
  };
  std::vector<S> scenarios;
  const int n8 = options.quick ? 2 : 8, n4 = options.quick ? 2 : 4;
  scenarios.push_back({std::to_string(n8) + " sim x 640x480 Mono8 at 100 fps, hardware trigger",
                       Rig("hardware-trigger", 100, n8, 640, 480, "sim"), true, 640 * 480,
                       n8 * 640 * 480 * 100 / 1048576.0});
  scenarios.push_back({std::to_string(n4) + " sim x 1920x1080 Mono8 at 30 fps, hardware trigger",
                       Rig("hardware-trigger", 30, n4, 1920, 1080, "sim"), true, 1920 * 1080,
                       n4 * 1920 * 1080 * 30 / 1048576.0});
  // The same two with the live view open (issue 21): it must not cost a set.
  for (std::size_t k = 0; k < 2; ++k) {
    S open = scenarios[k];
    open.name += ", live view open";
    open.live_view = true;
    scenarios.push_back(open);
  }
  const bool have_addresses = InLoopbackNamespace();
  if (options.aravis && have_addresses) {
    // The fakes tick in phase with the host's wall clock, but have no PTP clock (sync: ptp refuses
    // them since the PTP check): free-run, matched by the host's receive times.
    scenarios.push_back({std::to_string(n4) +
                             " Aravis fake GigE x 640x480 at 100 fps, free-run matched by receive "
                             "time, loopback, fakes in the same process",
                         Rig("free-run", 100, n4, 640, 480, "aravis"), false, 640 * 480,
                         n4 * 640 * 480 * 100 / 1048576.0});
  }
  const bool external = options.aravis && have_addresses && FakeCameraProcesses::Installed();
  if (external) {
    scenarios.push_back({std::to_string(n4) +
                             " Aravis fake GigE x 640x480 at 100 fps, free-run matched by receive "
                             "time, loopback, fakes as separate processes "
                             "(`arv-fake-gv-camera-0.8`)",
                         Rig("free-run", 100, n4, 640, 480, "aravis", 6), false, 640 * 480,
                         n4 * 640 * 480 * 100 / 1048576.0});
  }
  // A warm-up take of the first rig, not reported: the first recording in a fresh process paid
  // a one-off cost (0.62 to 0.64 cores where the same rig measured 0.47 to 0.53 later in the run).
  if (!scenarios.empty() && scenarios.front().sim) {
    try {
      Run(scenarios.front().yaml, std::min(seconds, 3.0), dir, true, scenarios.front().bytes,
          false);
    } catch (const std::exception&) {
      // The scenario itself will say why it cannot run.
    }
    fs::remove_all(dir / "take");
  }
  std::vector<ArvGvFakeCamera*> fakes;
  std::unique_ptr<FakeCameraProcesses> processes;
  std::ostringstream page_notes;
  std::map<std::string, double> cpu_without;  // each rig's CPU without the live view
  for (const S& sc : scenarios) {
    if (sc.name.find("separate processes") != std::string::npos) {
      for (auto* f : fakes) g_object_unref(f);  // the in-process ones are done
      fakes.clear();
      std::vector<std::string> addresses;
      for (int c = 0; c < n4; ++c) addresses.push_back("127.0.0." + std::to_string(6 + c));
      processes = std::make_unique<FakeCameraProcesses>(addresses);
      if (!processes->Ready(10)) {
        md << "| " << sc.name << " | the fake processes did not answer within 10 s |\n";
        continue;
      }
    } else if (!sc.sim) {
      for (int c = 0; c < n4; ++c)
        fakes.push_back(arv_gv_fake_camera_new(("127.0.0." + std::to_string(2 + c)).c_str(),
                                               ("BENCH" + std::to_string(c)).c_str()));
    }
    if (log) log("capture: " + sc.name + " ...");
    Outcome o;
    try {
      o = Run(sc.yaml, seconds, dir, sc.sim, sc.bytes, sc.live_view);
    } catch (const std::exception& e) {  // a scenario that cannot run says why; the others go on
      md << "| " << sc.name << " | could not run: " << e.what() << " |\n";
      if (log) log("  could not run: " + std::string(e.what()));
      fs::remove_all(dir / "take");
      continue;
    }
    if (!sc.live_view) cpu_without[sc.name] = o.cpu;
    if (sc.live_view) {
      const std::string base =
          sc.name.substr(0, sc.name.size() - std::string(", live view open").size());
      const auto without = cpu_without.find(base);
      page_notes << "- " << sc.name << ": "
                 << (without == cpu_without.end()
                         ? std::string()
                         : "the page cost " + Fixed(o.cpu - without->second, 2) + " cores; ")
                 << o.page_requests << " requests, " << o.page_failures << " failed"
                 << (o.page_first_failure.empty() ? ""
                                                  : " (the first: " + o.page_first_failure + ")")
                 << ".\n";
    }
    const std::uint64_t dropped = o.dropped + o.incoming_dropped + o.frames_missing;
    md << "| " << sc.name << " | " << Fixed(sc.data_rate, 0) << " | " << Fixed(o.seconds, 1)
       << " | " << o.sets << " | " << o.complete << " | " << dropped << " | " << o.camera_skipped
       << " | " << Fixed(o.megabytes_per_s, 0) << " (" << Fixed(100 * o.megabytes_per_s / disk, 0)
       << "%) | " << Fixed(o.cpu, 2) << " | " << Fixed(o.backlog_peak_mb, 1) << " | "
       << Fixed(o.max_spread_ms, 2) << " |\n";
    if (log) {
      log("  " + std::to_string(o.sets) + " sets, " + std::to_string(dropped) + " dropped, " +
          Fixed(o.megabytes_per_s, 0) + " MB/s, " + Fixed(o.cpu, 2) + " cores");
    }
  }
  for (auto* f : fakes) g_object_unref(f);
  processes.reset();
  md << "\n'Live view open': the daemon serves its live view (`capture --live-view`) and a client "
        "asks "
        "what the page in a browser asks once a second: the status, every camera's half-size "
        "preview PNG and its histogram. Compare each with the same rig's row without it: the CPU "
        "column's difference is the page's cost (server and client, both in this process).\n"
     << page_notes.str();
  if (options.aravis && have_addresses) {
    md << "\nThe Aravis fakes share the machine's two cores with the daemon (in its process, or as "
          "processes of their own, whose CPU is not in the CPU column); when starved they skip "
          "frame slots (free-run, no frame-id gap: counted from timestamp gaps, column 'frames the "
          "cameras skipped'), and each skipped slot leaves its set incomplete. Dropped counts what "
          "the daemon lost itself. The fakes have no PTP clock, so `sync: ptp` refuses them (its "
          "check before arming): their frames are matched by the host's receive times within 0.4 "
          "of a period (4 ms at 100 fps). On two loaded cores the four 300 kB frames of one slot "
          "sometimes arrive further apart than that, and the slot splits into incomplete sets "
          "without losing a frame; how often varies from run to run with the load (the rows "
          "before the PTP check, 2026-11-23, matched the fakes' own timestamps).\n";
  }
  fs::remove_all(dir);
  return md.str();
}

}  // namespace flamerig
