// `flamerig capture`: the capture daemon (acquisition/capture.h) and its control API.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <thread>

#include "acquisition/capture.h"
#include "acquisition/control.h"
#include "acquisition/live_view.h"
#include "core/error.h"
#include "core/folder_lock.h"
#include "tools/cli.h"

namespace flamerig::cli {

namespace {

// One line of the daemon's state: fps per camera, sets, recording.
std::string StatusLine(const CaptureStatus& s, double elapsed_s) {
  std::string fps;
  for (const auto& c : s.cameras) {
    char b[96];
    std::snprintf(b, sizeof b, " %s %.0f fps%s", c.name.c_str(), c.fps,
                  c.connected ? "" : " (gone)");
    fps += b;
  }
  char line[512];
  std::snprintf(line, sizeof line,
                "%.1f s:%s | sets %llu (%llu incomplete) | recorded %llu, dropped %llu, backlog "
                "%.0f MB",
                elapsed_s, fps.c_str(), (unsigned long long)s.sets.sets,
                (unsigned long long)s.sets.incomplete, (unsigned long long)s.recorder.sets_recorded,
                (unsigned long long)s.recorder.sets_dropped, s.recorder.queued_bytes / 1048576.0);
  return line;
}

}  // namespace

Runner AddCapture(CLI::App* command) {
  struct Options {
    std::string config, record, event, live_view;
    double duration = -1;
    long long frames = 0;
  };
  auto o = std::make_shared<Options>();
  command->footer(
      "Run the capture daemon: open the cameras of the config (see config/capture_sim.yaml),\n"
      "stream, assemble frame sets and serve the control API (`flamerig ctl`). --record starts\n"
      "recording into data_dir/NAME at once; --event saves the pre-trigger ring first;\n"
      "--duration stops after S seconds, --frames once the recording holds N frame sets (else:\n"
      "Ctrl-C or `flamerig ctl shutdown`); a recording of a set count is the same whichever\n"
      "moment the daemon starts, a timed one may hold a set more or less. Every state\n"
      "change and camera event is logged to stderr and to data_dir/capture.log. Exit status 1\n"
      "when a recording stopped before it was asked to (a full disk, a write error, min_free_mb;\n"
      "not max_recording_mb or max_recording_sets) or could not start, when a --frames take\n"
      "holds fewer than N sets, or a camera sent no frame at all; a camera\n"
      "silent for 5 periods (at least 2 s) is warned about as it happens.");
  command->add_option("--config", o->config, "Capture config")->required()->type_name("RIG.yaml");
  command->add_option("--record", o->record, "Record into data_dir/NAME at once")
      ->type_name("NAME");
  command
      ->add_option("--event", o->event, "Save the pre-trigger ring into data_dir/NAME, then live")
      ->type_name("NAME");
  command
      ->add_option("--live-view", o->live_view,
                   "Serve the live view in a browser here (0: any free port; the URL is logged)")
      ->type_name("HOST:PORT");
  command->add_option("--duration", o->duration, "Stop after S seconds")
      ->type_name("S")
      ->check(kPositive);
  command
      ->add_option("--frames", o->frames,
                   "Record N frame sets, then stop (with --record or --event; the pre-trigger "
                   "ring's sets count)")
      ->type_name("N")
      ->check(kPositive);
  return [o](Context& context) {
    if (!o->record.empty() && !o->event.empty()) throw UsageError("--record and --event: give one");
    if (o->frames > 0 && o->record.empty() && o->event.empty())
      throw UsageError("--frames counts a recording's frame sets: give --record or --event");
    CaptureConfig config = CaptureConfig::Load(o->config);
    if (o->frames > 0) config.recorder.max_sets = static_cast<std::uint64_t>(o->frames);
    // One daemon per data_dir: a second would mix recordings, sockets and logs.
    const FolderLock lock(config.data_dir, "flamerig capture --config " + o->config);
    // From here a signal stops the daemon at its next step, so a recording it starts is closed.
    context.StopOnSignals();
    const std::string log_file = (std::filesystem::path(config.data_dir) / "capture.log").string();
    AddLogFile(log_file);
    SystemClock clock;
    SimTriggerBus bus;
    CaptureDaemon daemon(config, MakeCameras(config, {&clock, &bus}), &clock, &bus);
    daemon.Start();
    auto server = std::make_unique<ControlServer>(&daemon, config.control, config.allow_remote);
    Log().info("capture: control at {}; log in {}", config.control, log_file);
    std::unique_ptr<LiveViewServer> live;
    const std::string listen = o->live_view.empty() ? config.live_view : o->live_view;
    if (!listen.empty()) {
      LiveViewOptions lv = LiveViewOptions::Parse(
          listen, o->live_view.empty() ? o->config + ": live_view" : "--live-view");
      lv.allow_remote = config.live_view_allow_remote;
      lv.token = config.live_view_token;
      live = std::make_unique<LiveViewServer>(&daemon, lv);
      Log().info("capture: live view at {}", live->url());
    }
    if (!o->event.empty() && config.pretrigger_seconds > 0)
      std::this_thread::sleep_for(std::chrono::duration<double>(config.pretrigger_seconds));
    // --duration counts from the recording's start: a timed take holds duration x rate sets,
    // give or take one (the frame sets in flight when it stops).
    const auto start = std::chrono::steady_clock::now();
    if (!o->record.empty()) daemon.StartRecording(o->record);
    if (!o->event.empty()) daemon.TriggerEvent(o->event);
    auto elapsed = [&] {
      return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    };
    // The status: redrawn in place each second on a terminal, a log line every 10 s otherwise.
    const double period = context.terminal() ? 1.0 : 10.0;
    double last_line = context.terminal() ? 0 : 1 - period;  // the first plain line after 1 s
    bool drawn = false;
    // A recording that stopped before it was asked to (a full disk, a write error, min_free_mb;
    // not max_recording_mb or max_recording_sets) makes the exit status 1.
    bool recording_failed = false;
    auto failed = [](const RecorderStatus& r) { return !r.error.empty() && !r.limit_reached; };
    // A camera that sends nothing (a hardware trigger with no pulses, a dead camera that still
    // reads as connected) is warned about after a few periods, once until it sends again; one
    // that sent nothing in the whole run makes the exit status 1.
    const double period_s = config.trigger_rate_hz > 0 ? 1 / config.trigger_rate_hz : 0.1;
    const double stall_s = std::max(2.0, 5 * period_s);
    std::vector<bool> warned(config.cameras.size(), false);
    auto watch = [&](const CaptureStatus& s) {
      for (std::size_t c = 0; c < s.cameras.size() && c < warned.size(); ++c) {
        const CameraLiveStatus& cam = s.cameras[c];
        const double silent_s = cam.last_frame_age_s < 0 ? s.armed_s : cam.last_frame_age_s;
        if (!s.running || silent_s < stall_s) {
          warned[c] = false;
          continue;
        }
        if (warned[c]) continue;
        warned[c] = true;
        const std::string hint =
            config.sync == SyncMode::kHardwareTrigger
                ? " (sync hardware-trigger: is the trigger generator running and wired to " +
                      config.cameras[c].settings.trigger_source + "?)"
                : "";
        if (cam.last_frame_age_s < 0)
          Log().warn("capture: camera {}: no frame in {:.1f} s since arming{}", cam.name, silent_s,
                     hint);
        else
          Log().warn("capture: camera {}: no frames for {:.1f} s{}", cam.name, silent_s, hint);
      }
    };
    // --frames: the daemon stops once its recording is closed, whatever closed it (its count,
    // another limit, a fault, `ctl stop`), and says below whether it holds the N sets asked for.
    bool frames_done = false;
    while (!context.cancel().raised() && !server->shutdown_requested() && !frames_done &&
           (o->duration < 0 || elapsed() < o->duration)) {
      // Every 100 ms, and at --duration's end (a 100 ms step overshot a 1 s take by 2 sets).
      const double step_s = o->duration < 0 ? 0.1 : std::clamp(o->duration - elapsed(), 0.0, 0.1);
      std::this_thread::sleep_for(std::chrono::duration<double>(step_s));
      if (o->duration >= 0 && elapsed() >= o->duration) break;
      const CaptureStatus s = daemon.status();
      watch(s);
      if (s.recorder.stopped && s.recording) {
        // A limit reached, a full disk or a write error: the recording stops cleanly, the
        // daemon goes on (or stops, after --frames).
        if (drawn) std::fputs("\n", stderr);
        drawn = false;
        if (failed(s.recorder)) Log().error("capture: recording stopped: {}", s.recorder.error);
        try {
          daemon.StopRecording();      // logs what it recorded and why it stopped
        } catch (const InputError&) {  // a control request stopped it meanwhile
        }
        // The closed recording's last word (a write that failed while it drained).
        recording_failed = failed(daemon.status().recorder) || recording_failed;
      }
      if (o->frames > 0 && !daemon.status().recording) {
        frames_done = true;
        if (drawn) std::fputs("\n", stderr);
        drawn = false;
        Log().info("capture: the recording is closed (--frames): stopping");
        continue;
      }
      if (elapsed() - last_line < period || context.verbosity() == Verbosity::kQuiet) continue;
      last_line = elapsed();
      if (context.terminal()) {
        std::fprintf(stderr, "\r%-120s", StatusLine(s, elapsed()).c_str());
        std::fflush(stderr);
        drawn = true;
      } else {
        Log().info("capture: {}", StatusLine(s, elapsed()));
      }
    }
    if (drawn) std::fputs("\n", stderr);
    if (context.cancel().raised()) Log().info("capture: stopping (signal)");
    live.reset();
    server.reset();  // no control request may log (or act) from here on
    if (daemon.status().recording) {
      try {
        const RecorderStatus last = daemon.StopRecording();
        if (failed(last)) {
          Log().error("capture: recording stopped: {}", last.error);
          recording_failed = true;
        }
      } catch (const InputError&) {  // stopped meanwhile by a control request
      }
    }
    // A recording that a control request closed after it had failed counts too.
    if (failed(daemon.status().recorder)) recording_failed = true;
    // --frames N: a recording that holds fewer (stopped early by a signal, `ctl stop`, --duration,
    // max_recording_mb or a fault) did not do what was asked.
    bool short_of_frames = false;
    if (o->frames > 0) {
      const RecorderStatus r = daemon.status().recorder;
      if (r.sets_recorded < static_cast<std::uint64_t>(o->frames)) {
        short_of_frames = true;
        Log().error("capture: the recording holds {} of the {} frame sets asked for (--frames){}{}",
                    r.sets_recorded, o->frames, r.error.empty() ? "" : ": ", r.error);
      }
    }
    // Each camera's story, for the log (and the soak test, which reads the disconnects).
    bool silent = false;
    for (const auto& c : daemon.status().cameras) {
      const bool optional = [&] {
        for (const auto& cc : config.cameras)
          if (cc.name == c.name) return !cc.required;
        return false;
      }();
      if (c.frames == 0 && optional) {
        Log().warn("capture: optional camera {} ({}) sent no frame", c.name, c.id);
      } else if (c.frames == 0) {
        Log().error("capture: camera {} ({}) sent no frame at all{}", c.name, c.id,
                    config.sync == SyncMode::kHardwareTrigger ? " (no trigger pulses?)" : "");
        silent = true;
      } else if (!optional && c.last_frame_age_s > stall_s) {
        // A required camera that went away and did not come back: the sets recorded after it
        // lack it (the exit status said 0 while 46 of 60 sets had no frame of it).
        Log().error(
            "capture: camera {} ({}) sent no frame in the last {:.1f} s of the run ({} frames, {} "
            "disconnects, {} reconnects{}{}): the sets recorded since lack it",
            c.name, c.id, c.last_frame_age_s, c.frames, c.disconnects, c.reconnects,
            c.error.empty() ? "" : "; last error: ", c.error);
        silent = true;
      }
      Log().info(
          "capture: {}: {} frames, {} missing by frame id, {} missed triggers, {} incomplete, {} "
          "disconnects, {} reconnects{}{}",
          c.name, c.frames, c.stream.missing_by_id, c.missed_triggers, c.stream.incomplete,
          c.disconnects, c.reconnects, c.error.empty() ? "" : "; last error: ", c.error);
    }
    daemon.Stop();
    RemoveLogFile(log_file);
    return recording_failed || silent || short_of_frames ? kExitError : kExitOk;
  };
}

}  // namespace flamerig::cli
