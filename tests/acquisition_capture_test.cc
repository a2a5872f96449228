// The capture daemon with simulated cameras in real time: configuration errors, recording every
// frame set bit-exact, a camera that dies, the pre-trigger ring, recording names that cannot escape
// the data directory, the control API over a Unix socket and loopback TCP, and Bayer decoding.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <regex>
#include <thread>

#include "acquisition/camera_drivers.h"
#include "acquisition/capture.h"
#include "acquisition/control.h"
#include "acquisition/sim_camera.h"
#include "core/error.h"
#include "core/image.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

struct TempDir {
  fs::path path = fs::temp_directory_path() /
                  ("flamerig_cap_" + std::to_string(::getpid()) + "_" + std::to_string(next++));
  TempDir() { fs::remove_all(path); }
  ~TempDir() { fs::remove_all(path); }
  static inline int next = 0;
};

void Sleep(double s) { std::this_thread::sleep_for(std::chrono::duration<double>(s)); }

std::string Config(const fs::path& data_dir, const std::string& sync, double rate,
                   const std::string& extra_camera = "", const std::string& extra = "") {
  std::string y = "data_dir: " + data_dir.string() + "\nsync: " + sync +
                  "\ntrigger_rate_hz: " + std::to_string(rate) + "\n" + extra + "cameras:\n";
  for (int c = 0; c < 3; ++c) {
    y += "  - name: cam" + std::to_string(c) + "\n    driver: sim\n    id: SIM" +
         std::to_string(c) + "\n    width: 96\n    height: 64\n";
    if (c == 2) y += extra_camera;
  }
  return y;
}

std::string ParseError(const std::string& yaml) {
  try {
    CaptureConfig::Parse(yaml, "rig.yaml");
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

TEST(CaptureConfig, ParsesAndNamesTheKeyOfEveryMistake) {
  const CaptureConfig c = CaptureConfig::Parse(Config("/tmp/x", "free-run", 25), "rig.yaml");
  ASSERT_EQ(c.cameras.size(), 3u);
  EXPECT_EQ(c.sync, SyncMode::kFreeRun);
  EXPECT_EQ(c.cameras[1].id, "SIM1");
  EXPECT_EQ(c.cameras[1].settings.width, 96);
  EXPECT_EQ(c.cameras[1].settings.trigger, TriggerMode::kFreeRun);
  EXPECT_EQ(c.cameras[1].settings.frame_rate_hz, 25);
  EXPECT_EQ(CaptureConfig::Parse(Config("/tmp/x", "software-trigger", 25), "t")
                .cameras[0]
                .settings.frame_rate_hz,
            50);  // room for trigger jitter
  EXPECT_NE(ParseError("sync: hardware-trigger\ntrigger_rate_hz: 30\ncameras: [{name: a, "
                       "frame_rate_hz: 30}]")
                .find("1.1 x trigger_rate_hz"),
            std::string::npos);
  EXPECT_EQ(c.control, "unix:/tmp/x/control.sock");
  EXPECT_EQ(c.AssemblerOptions().match, MatchBy::kTimestamp);

  EXPECT_NE(ParseError("sync: free-run\ncameras: [{name: a, wdth: 3}]")
                .find("rig.yaml: cameras[0]: unknown key 'wdth'"),
            std::string::npos);
  // A key given twice, at the top or in a camera: YAML's reader kept the first without a word.
  EXPECT_NE(ParseError("sync: free-run\ntrigger_rate_hz: 30\ncameras: [{name: a}]\n"
                       "trigger_rate_hz: 5\n")
                .find("rig.yaml: 'trigger_rate_hz' is given twice (line 4)"),
            std::string::npos);
  EXPECT_NE(ParseError("sync: free-run\ncameras:\n  - {name: a, exposure_us: 2000, "
                       "exposure_us: 100000}\n")
                .find("'exposure_us' is given twice (line 3)"),
            std::string::npos);
  EXPECT_NE(ParseError("synk: free-run\ncameras: [{name: a}]").find("unknown key 'synk'"),
            std::string::npos);
  EXPECT_NE(ParseError("sync: sometimes\ncameras: [{name: a}]").find("sync 'sometimes'"),
            std::string::npos);
  EXPECT_NE(ParseError("cameras: []").find("at least one camera"), std::string::npos);
  EXPECT_NE(ParseError("cameras: [{name: a}, {name: a}]").find("'a' is used twice"),
            std::string::npos);
  // A name becomes a file name: one path component, never a way out of an export's folder.
  for (const char* bad : {"../../escaped", "a/b", ".hidden", "''", "-rf", "caméra"})
    EXPECT_NE(ParseError(std::string("cameras: [{name: ") + bad + "}]").find("cameras[0]: name '"),
              std::string::npos)
        << bad;
  EXPECT_NO_THROW(CaptureConfig::Parse("cameras: [{name: Cam_0-left.1}]", "rig.yaml"));
  // One camera cannot be two cameras of a rig.
  EXPECT_NE(ParseError("cameras: [{name: a, id: S1}, {name: b, id: S2}, {name: c, id: S1}]")
                .find("cameras[2]: id 'S1' is also cameras[0] ('a')"),
            std::string::npos);
  // Relative paths are relative to the config file, wherever the daemon starts.
  const CaptureConfig rel = CaptureConfig::Parse("data_dir: ../takes\ncameras: [{name: a}]",
                                                 "/home/op/rig/config/capture.yaml");
  EXPECT_EQ(rel.data_dir, "/home/op/rig/takes");
  EXPECT_EQ(rel.control, "unix:/home/op/rig/takes/control.sock");
  EXPECT_EQ(
      CaptureConfig::Parse("control: unix:ctl.sock\ncameras: [{name: a}]", "/etc/r.yaml").control,
      "unix:/etc/ctl.sock");
  EXPECT_EQ(CaptureConfig::Parse("data_dir: /abs\ncameras: [{name: a}]", "/etc/r.yaml").data_dir,
            "/abs");
  EXPECT_NE(
      ParseError("cameras: [{name: a, width: wide}]").find("'width' has a value of the wrong type"),
      std::string::npos);
  EXPECT_NE(ParseError("cameras: [{name: a, width: -4}]").find("'width' must be in [0, 16384]"),
            std::string::npos);
  // Found by fuzzing: numbers far out of range were converted to int (undefined behaviour).
  EXPECT_NE(ParseError("buffers: 6666666666666668\ncameras: [{name: a}]")
                .find("'buffers' must be in [1, 1024]"),
            std::string::npos);
  EXPECT_NE(ParseError("cameras: [{name: a, width: 1e300}]").find("'width' must be in"),
            std::string::npos);
  // A size given as a fraction: an error, not truncated.
  EXPECT_NE(ParseError("cameras: [{name: a, width: 640.5}]").find("'width' must be a whole number"),
            std::string::npos);
  // A recording's set count: a whole number, 0 for none.
  EXPECT_EQ(CaptureConfig::Parse("max_recording_sets: 90\ncameras: [{name: a}]", "r.yaml")
                .recorder.max_sets,
            90u);
  EXPECT_EQ(c.recorder.max_sets, 0u);
  for (const char* bad : {"-1", "2.5", "many"})
    EXPECT_NE(ParseError(std::string("max_recording_sets: ") + bad + "\ncameras: [{name: a}]")
                  .find("rig.yaml: 'max_recording_sets'"),
              std::string::npos)
        << bad;
  EXPECT_NE(ParseError("trigger_rate_hz: 1e-300\ncameras: [{name: a}]").find("trigger_rate_hz"),
            std::string::npos);
  EXPECT_NE(ParseError("cameras: [{name: a, pixel_format: YUV}]").find("cameras[0]"),
            std::string::npos);
  EXPECT_NE(ParseError("cameras: [{name: a, driver: aravis}]").find("'id'"), std::string::npos);
  EXPECT_NE(ParseError("cameras: [{name: a, sim: {drop_probability: 2}}]").find("[0, 1]"),
            std::string::npos);
  // Outages: one by disconnect_at_s/reconnect_at_s, more by a list; in order, not overlapping.
  const CaptureConfig outages = CaptureConfig::Parse(
      "cameras: [{name: a, sim: {disconnect_at_s: 1, reconnect_at_s: 2, outages: [[3, 4.5], [6, "
      "-1]]}}]",
      "rig.yaml");
  ASSERT_EQ(outages.cameras[0].Options<SimCameraOptions>().outages.size(), 3u);
  EXPECT_EQ(outages.cameras[0].Options<SimCameraOptions>().outages[1].down_ns, 3'000'000'000);
  EXPECT_EQ(outages.cameras[0].Options<SimCameraOptions>().outages[1].up_ns, 4'500'000'000);
  EXPECT_EQ(outages.cameras[0].Options<SimCameraOptions>().outages[2].up_ns, -1);
  EXPECT_NE(ParseError("cameras: [{name: a, sim: {outages: [[3, 4], [3.5, 5]]}}]")
                .find("cameras[0].sim: outages must be in order and not overlap"),
            std::string::npos);
  EXPECT_NE(ParseError("cameras: [{name: a, sim: {outages: [[3, 2]]}}]")
                .find("cameras[0].sim.outages[0]: must be [down_s, up_s]"),
            std::string::npos);
  EXPECT_NE(ParseError("cameras: [{name: a, sim: {outages: [[3, .nan]]}}]").find("outages[0]"),
            std::string::npos);
  EXPECT_NE(ParseError("cameras: [{name: a, sim: {reconnect_at_s: 3}}]").find("disconnect_at_s"),
            std::string::npos);
  EXPECT_NE(ParseError("cameras: [{name: a\n").find("not valid YAML"), std::string::npos);
  EXPECT_NE(ParseError("- just\n- a list\n").find("expected a mapping"), std::string::npos);
}

// Runs a daemon from `yaml` for `seconds` while recording into `name`; returns the recording.
Recording RecordFor(const std::string& yaml, double seconds, const std::string& name,
                    CaptureStatus* final_status = nullptr) {
  const CaptureConfig config = CaptureConfig::Parse(yaml, "test");
  SystemClock clock;
  SimTriggerBus bus;
  CaptureDaemon daemon(config, MakeCameras(config, {&clock, &bus}), &clock, &bus);
  daemon.Start();
  const std::string dir = daemon.StartRecording(name);
  Sleep(seconds);
  const RecorderStatus rs = daemon.StopRecording();
  EXPECT_FALSE(rs.stopped) << rs.error;
  if (final_status) *final_status = daemon.status();
  daemon.Stop();
  return Recording::Open(dir);
}

void ExpectTestPattern(const Frame& f) {
  std::vector<std::uint8_t> want;
  TestPatternSource()(f.info, &want);
  ASSERT_TRUE(*f.data == want) << "camera " << f.info.camera << " frame " << f.info.frame_id;
}

// The drivers are found by name in one registry and the daemon decides by their capabilities:
// frames with trigger ids (sim) are matched by id, a rig with any camera without them by receive
// time; a driver's keys belong to it alone.
TEST(CameraDrivers, TheRegistryNamesTheDriversAndTheirCapabilities) {
  std::vector<std::string> names;
  for (const CameraDriver& d : CameraDrivers()) names.push_back(d.name);
  EXPECT_EQ(names, (std::vector<std::string>{"sim", "aravis", "v4l2"}));
  EXPECT_TRUE(FindCameraDriver("sim").capabilities.trigger_ids);
  EXPECT_FALSE(FindCameraDriver("aravis").capabilities.trigger_ids);
  EXPECT_TRUE(FindCameraDriver("aravis").capabilities.action_commands);
  EXPECT_FALSE(FindCameraDriver("v4l2").capabilities.action_commands);
  try {
    FindCameraDriver("gentl");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("use sim, aravis, v4l2"), std::string::npos) << e.what();
  }
  const CaptureConfig sims =
      CaptureConfig::Parse("sync: hardware-trigger\ncameras: [{name: a}, {name: b}]", "rig.yaml");
  EXPECT_EQ(sims.AssemblerOptions().match, MatchBy::kTriggerId);
  EXPECT_EQ(sims.cameras[1].id, "SIM1");
  EXPECT_EQ(sims.cameras[1].Options<SimCameraOptions>().camera_index, 1);
  const CaptureConfig mixed = CaptureConfig::Parse(
      "sync: hardware-trigger\ncameras: [{name: a}, {name: b, driver: v4l2, id: /dev/video9}]",
      "rig.yaml");
  EXPECT_EQ(mixed.AssemblerOptions().match, MatchBy::kTimestamp);
  EXPECT_THROW(mixed.cameras[1].Options<SimCameraOptions>(), std::logic_error);
  auto error = [](const std::string& yaml) {
    try {
      CaptureConfig::Parse(yaml, "rig.yaml");
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("(no error)");
  };
  EXPECT_NE(error("cameras: [{name: a, driver: aravis, id: X, sim: {seed: 2}}]")
                .find("cameras[0]: 'sim' is for driver sim only"),
            std::string::npos);
  EXPECT_NE(error("cameras: [{name: a, driver: v4l2, id: /dev/video0, v4l2: {}}]")
                .find("driver v4l2 has no keys of its own"),
            std::string::npos);
  EXPECT_NE(error("cameras: [{name: a, driver: gentl, id: X}]").find("cameras[0]: driver 'gentl'"),
            std::string::npos);
}

TEST(CaptureDaemon, RecordsEverySoftwareTriggeredSetBitExact) {
  TempDir dir;
  CaptureStatus status;
  const Recording r = RecordFor(Config(dir.path, "software-trigger", 50), 1.0, "take1", &status);
  // 50 Hz for 1 s, minus the sets in flight at start and stop.
  EXPECT_GE(r.num_sets(), 40u);
  EXPECT_LE(r.num_sets(), 52u);
  std::int64_t last_trigger = -1;
  for (std::size_t i = 0; i < r.num_sets(); ++i) {
    const FrameSet s = r.ReadSet(i);
    ASSERT_TRUE(s.complete()) << "set " << i;
    if (last_trigger >= 0) {
      EXPECT_EQ(s.trigger_id, last_trigger + 1);  // none lost
    }
    last_trigger = s.trigger_id;
    for (const auto& f : s.frames) {
      EXPECT_EQ(f->info.trigger_id, s.trigger_id);
      ExpectTestPattern(*f);
    }
  }
  EXPECT_EQ(r.metadata().sync_mode, "software-trigger");
  EXPECT_EQ(r.metadata().cameras[2].description.id, "SIM2");
  EXPECT_NE(r.metadata().config_yaml.find("trigger_rate_hz"), std::string::npos);
  for (auto m : r.MissingByFrameId()) EXPECT_EQ(m, 0u);
  ASSERT_EQ(status.cameras.size(), 3u);
  EXPECT_NEAR(status.cameras[0].fps, 50, 8);
  EXPECT_EQ(status.incoming_dropped, 0u);
}

// A frame that arrives after status() has read the clock is 0 s old, not "none yet": the
// silent-camera watch (`flamerig capture`) once warned that a camera sending 20 frames a second had
// sent nothing since arming, when its last frame landed between the two reads. Reproduced
// exactly by a clock stepped back after the frames: every frame then lies after status()'s now.
TEST(CaptureDaemon, AFrameNewerThanTheStatusClockIsNotNoneYet) {
  TempDir dir;
  struct SteppedClock : Clock {
    SystemClock system;
    std::atomic<std::int64_t> back{0};
    std::int64_t MonotonicNs() const override { return system.MonotonicNs() - back.load(); }
    std::int64_t RealtimeNs() const override { return system.RealtimeNs(); }
    void SleepUntil(std::int64_t t) override { system.SleepUntil(t + back.load()); }
  } clock;
  const CaptureConfig config =
      CaptureConfig::Parse(Config(dir.path, "software-trigger", 50), "test");
  SimTriggerBus bus;
  CaptureDaemon daemon(config, MakeCameras(config, {&clock, &bus}), &clock, &bus);
  daemon.Start();
  for (int i = 0; i < 200 && daemon.status().cameras[0].last_frame_age_s < 0; ++i) Sleep(0.01);
  ASSERT_GE(daemon.status().cameras[0].last_frame_age_s, 0) << "no frame in 2 s";
  clock.back = 1'000'000'000;
  const CaptureStatus s = daemon.status();
  clock.back = 0;
  daemon.Stop();
  for (const CameraLiveStatus& c : s.cameras) EXPECT_EQ(c.last_frame_age_s, 0.0) << c.name;
}

// The recorder's queue is what the config says; only a pre-trigger ring (flushed into the queue at
// once) raises it to pretrigger_max_mb + 64 MB. Found by the soak: a 64 MB queue had become 320 MB.
TEST(CaptureDaemon, TheQueueBoundIsTheConfigsUnlessARingNeedsMore) {
  TempDir dir;
  auto bound_mb = [&](const std::string& extra, const std::string& name) {
    const CaptureConfig config =
        CaptureConfig::Parse(Config(dir.path, "software-trigger", 20, "", extra), "test");
    SystemClock clock;
    SimTriggerBus bus;
    CaptureDaemon daemon(config, MakeCameras(config, {&clock, &bus}), &clock, &bus);
    daemon.Start();
    daemon.StartRecording(name);
    const double mb = daemon.status().recorder.max_queued_bytes / double(1 << 20);
    daemon.StopRecording();
    daemon.Stop();
    return mb;
  };
  EXPECT_EQ(bound_mb("queue_mb: 2\npretrigger_seconds: 0\n", "a"), 2);
  EXPECT_EQ(bound_mb("queue_mb: 2\npretrigger_seconds: 1\npretrigger_max_mb: 8\n", "b"), 72);
}

TEST(CaptureDaemon, ADeadCameraNeverStallsTheOthers) {
  TempDir dir;
  // Camera 2 disappears after 0.3 s of a 1.2 s take; hardware trigger on the simulated line.
  CaptureStatus status;
  const Recording r =
      RecordFor(Config(dir.path, "hardware-trigger", 40, "    sim: {disconnect_at_s: 0.3}\n",
                       "set_timeout_ms: 100\n"),
                1.2, "take2", &status);
  ASSERT_EQ(status.cameras.size(), 3u);
  EXPECT_EQ(status.cameras[2].disconnects, 1u);
  EXPECT_FALSE(status.cameras[2].connected);
  EXPECT_EQ(status.cameras[0].disconnects, 0u);
  ASSERT_GE(r.num_sets(), 35u);
  std::size_t complete = 0, without_2 = 0;
  for (std::size_t i = 0; i < r.num_sets(); ++i) {
    const FrameSet s = r.ReadSet(i);
    ASSERT_TRUE(s.frames[0] && s.frames[1]) << "set " << i;
    if (s.frames[2])
      ++complete;
    else
      ++without_2;
  }
  EXPECT_GE(complete, 8u);
  EXPECT_GE(without_2, 25u);  // the others went on at full rate
}

TEST(CaptureDaemon, FreeRunMatchesByTimestamp) {
  TempDir dir;
  // The default tolerance: 0.4 of the 33 ms period.
  const Recording r = RecordFor(Config(dir.path, "free-run", 30), 1.0, "take3");
  EXPECT_GE(r.num_sets(), 24u);
  std::size_t complete = 0;
  for (std::size_t i = 0; i < r.num_sets(); ++i) {
    const FrameSet s = r.ReadSet(i);
    if (s.complete()) ++complete;
    EXPECT_LE(s.spread_ns, 13'333'334);
  }
  // Host receive times carry the camera threads' wake-up jitter: on a loaded two-core host an
  // occasional frame lands outside the tolerance and its set splits in two.
  EXPECT_GE(complete, r.num_sets() * 85 / 100);
}

// A camera that misses triggers without a gap in its frame ids (a lost trigger, not a lost
// packet): the daemon counts it against the triggers it sent, live and in the recording's
// metadata. Oracle: the sets the assembler (matching by trigger id) emitted without that camera.
TEST(CaptureDaemon, MissedTriggersAreCountedAgainstTheSchedule) {
  TempDir dir;
  const CaptureConfig config = CaptureConfig::Parse(
      Config(dir.path, "software-trigger", 50, "    sim: {miss_trigger_probability: 0.2}\n"),
      "test");
  SystemClock clock;
  std::vector<std::unique_ptr<Camera>> cameras = MakeCameras(config, {&clock, nullptr});
  // The oracle: the triggers each simulated camera itself chose to ignore (cam2 loses 20% on the
  // way; all three ignore a trigger that comes too early, after a late trigger thread).
  std::vector<const SimCamera*> sims;
  for (const auto& c : cameras) sims.push_back(dynamic_cast<const SimCamera*>(c.get()));
  ASSERT_TRUE(sims[0] && sims[1] && sims[2]);
  const auto Ignored = [&] {
    std::vector<double> n;
    for (const SimCamera* s : sims) n.push_back(double(s->triggers_ignored()));
    return n;
  };
  CaptureDaemon daemon(config, std::move(cameras), &clock, nullptr);
  daemon.Start();
  Sleep(0.3);
  // The take's own window lies between these: outer before the start and after the stop, inner
  // after the start returned and before the stop was asked (the recorder's fsyncs lie between).
  const std::vector<double> outer_start = Ignored();
  const std::string take = daemon.StartRecording("take");
  const std::vector<double> inner_start = Ignored();
  Sleep(2.5);
  const std::vector<double> inner_stop = Ignored();
  daemon.StopRecording();
  const std::vector<double> at_stop = Ignored();
  // The live count leaves out the triggers of the last grace time (300 ms here): wait it out.
  Sleep(0.5);
  const CaptureStatus live = daemon.status();
  const std::vector<double> at_status = Ignored();
  daemon.Stop();
  ASSERT_EQ(live.cameras.size(), 3u);
  EXPECT_GE(inner_stop[2] - inner_start[2], 10);        // about 0.2 x 125 triggers
  EXPECT_EQ(live.cameras[2].stream.missing_by_id, 0u);  // the frame ids say nothing
  // The live count: at least every trigger ignored up to 500 ms ago (its cut-off is 300 ms ago),
  // less the frames of up to 4 later triggers (received within the latency allowance, 10 ms
  // exposure + 50 ms); at most those ignored until now, plus 2 frames a loaded machine may hold up
  // for more than 50 ms.
  for (std::size_t c = 0; c < 3; ++c) {
    const double counted = double(live.cameras[c].missed_triggers);
    EXPECT_GE(counted, at_stop[c] - 4) << c << "\n" << live.ToTable();
    EXPECT_LE(counted, at_status[c] + 2) << c << "\n" << live.ToTable();
  }
  // In the recording: the take's own count, triggers sent minus frames received while it
  // recorded, between the ignored triggers of the inner and the outer window, give or take a
  // frame in flight at its start or stop.
  const Recording r = Recording::Open(take);
  for (std::size_t c = 0; c < 3; ++c) {
    const std::string key = "missed_triggers_cam" + std::to_string(c);
    ASSERT_TRUE(r.final_counters().count(key)) << key;
    const double counted = std::stod(r.final_counters().at(key));
    EXPECT_GE(counted, inner_stop[c] - inner_start[c] - 1) << key;
    EXPECT_LE(counted, at_stop[c] - outer_start[c] + 1) << key;
  }
  EXPECT_EQ(r.metadata().trigger_rate_hz, 50);
}

// Exposure and gain change while streaming and recording: no disarm, no set lost, and every
// recorded frame carries the exposure it was taken with (the old value, then the new one from one
// frame on). Other settings still need a disarm.
TEST(CaptureDaemon, ExposureChangesWhileRecording) {
  TempDir dir;
  const CaptureConfig config =
      CaptureConfig::Parse(Config(dir.path, "software-trigger", 50, "", ""), "test");
  SystemClock clock;
  CaptureDaemon daemon(config, MakeCameras(config, {&clock, nullptr}), &clock, nullptr);
  daemon.Start();
  const std::string take = daemon.StartRecording("take");
  Sleep(0.5);
  daemon.SetCameraSetting("cam0", "gain_db", "6");  // first: a frame at 500 us has gain 6
  daemon.SetCameraSetting("cam0", "exposure_us", "500");
  Sleep(0.5);
  EXPECT_THROW(daemon.SetCameraSetting("cam0", "width", "32"), InputError);
  EXPECT_TRUE(daemon.running());
  daemon.StopRecording();
  daemon.Stop();
  const Recording r = Recording::Open(take);
  ASSERT_GE(r.num_sets(), 30u);
  std::size_t before = 0, after = 0;
  for (std::size_t i = 0; i < r.num_sets(); ++i) {
    const FrameSet s = r.ReadSet(i);
    if (i > 0) {
      EXPECT_EQ(s.trigger_id, r.SetHeader(i - 1).trigger_id + 1) << i;  // none lost
    }
    ASSERT_TRUE(s.frames[0] && s.frames[1]);
    const double e = s.frames[0]->info.exposure_us;
    if (e == 500) {
      ++after;
      EXPECT_EQ(s.frames[0]->info.gain_db, 6) << i;
    } else {
      EXPECT_EQ(after, 0u) << "the old exposure after the new one, set " << i;
      EXPECT_EQ(e, config.cameras[0].settings.exposure_us);
      ++before;
    }
    EXPECT_EQ(s.frames[1]->info.exposure_us, config.cameras[1].settings.exposure_us);
  }
  EXPECT_GE(before, 15u);
  EXPECT_GE(after, 15u);
  EXPECT_EQ(r.metadata().cameras[0].settings.exposure_us, config.cameras[0].settings.exposure_us);
}

// `ctl configure` holds a triggered camera's frame rate to the config file's rule, at least 1.1 x
// the trigger rate: it took 5 Hz under a 30 Hz trigger, and the take missed 59 triggers.
TEST(CaptureDaemon, ConfigureRefusesAFrameRateThatMissesTriggers) {
  TempDir dir;
  const CaptureConfig config =
      CaptureConfig::Parse(Config(dir.path, "software-trigger", 50, "", ""), "test");
  SystemClock clock;
  CaptureDaemon daemon(config, MakeCameras(config, {&clock, nullptr}), &clock, nullptr);
  try {
    daemon.SetCameraSetting("cam0", "frame_rate_hz", "50");
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("camera 'cam0': frame_rate_hz '50'"), std::string::npos) << what;
    EXPECT_NE(what.find("at least 1.1 x trigger_rate_hz (55 Hz)"), std::string::npos) << what;
  }
  EXPECT_EQ(daemon.config().cameras[0].settings.frame_rate_hz,
            config.cameras[0].settings.frame_rate_hz);  // unchanged
  EXPECT_NO_THROW(daemon.SetCameraSetting("cam0", "frame_rate_hz", "55"));
}

TEST(CaptureDaemon, AnEventSavesThePreTriggerRing) {
  TempDir dir;
  const CaptureConfig config = CaptureConfig::Parse(
      Config(dir.path, "software-trigger", 50, "", "pretrigger_seconds: 0.5\n"), "test");
  SystemClock clock;
  CaptureDaemon daemon(config, MakeCameras(config, {&clock, nullptr}), &clock, nullptr);
  daemon.Start();
  Sleep(1.0);
  const std::int64_t event_ns = clock.MonotonicNs();
  const std::int64_t event_wall_ns = clock.RealtimeNs();
  const std::string d = daemon.TriggerEvent("ignition");
  const std::int64_t after_wall_ns = clock.RealtimeNs();
  Sleep(0.3);
  daemon.StopRecording();
  daemon.Stop();
  const Recording r = Recording::Open(d);
  const FrameSet first = r.ReadSet(0);
  const double before_s = (event_ns - first.frames[0]->info.host_monotonic_ns) / 1e9;
  EXPECT_NEAR(before_s, 0.5, 0.1);         // the ring's half second before the event
  EXPECT_NEAR(r.num_sets(), 0.8 * 50, 6);  // and 0.3 s after it
  for (std::size_t i = 1; i < r.num_sets(); ++i)
    EXPECT_EQ(r.ReadSet(i).trigger_id, r.ReadSet(i - 1).trigger_id + 1);
  // The trigger's moment is in the metadata, and where the ring ends: every ring set was received
  // before it.
  const RecordingMetadata& m = r.metadata();
  EXPECT_EQ(m.event_name, "ignition");
  EXPECT_GE(m.event_realtime_ns, event_wall_ns);
  EXPECT_LE(m.event_realtime_ns, after_wall_ns);
  std::size_t ring = 0;
  for (std::size_t i = 0; i < r.num_sets(); ++i) {
    const FrameSet s = r.ReadSet(i);
    if (static_cast<std::int64_t>(s.index) > m.event_last_ring_set) continue;
    ++ring;
    for (const auto& f : s.frames) {
      if (f) {
        EXPECT_LE(f->info.host_monotonic_ns, event_ns + 2'000'000) << i;
      }
    }
  }
  EXPECT_NEAR(double(ring), 0.5 * 50, 5);
}

// An event limited to fewer sets than its ring holds (max_recording_sets, `capture --event
// --frames`) records the ring's newest: the ten sets just before the event, in order, none after.
TEST(CaptureDaemon, AnEventOfFewerSetsThanItsRingKeepsTheNewest) {
  TempDir dir;
  const CaptureConfig config =
      CaptureConfig::Parse(Config(dir.path, "software-trigger", 50, "",
                                  "pretrigger_seconds: 0.5\nmax_recording_sets: 10\n"),
                           "test");
  SystemClock clock;
  CaptureDaemon daemon(config, MakeCameras(config, {&clock, nullptr}), &clock, nullptr);
  daemon.Start();
  Sleep(1.0);
  const std::string d = daemon.TriggerEvent("ignition");
  Sleep(0.3);
  daemon.StopRecording();
  daemon.Stop();
  const Recording r = Recording::Open(d);
  ASSERT_EQ(r.num_sets(), 10u);
  const RecordingMetadata& m = r.metadata();
  ASSERT_GE(m.event_last_ring_set, 20);  // the ring held about 25 sets
  for (std::size_t i = 0; i < 10; ++i)
    EXPECT_EQ(static_cast<std::int64_t>(r.ReadSet(i).index), m.event_last_ring_set - 9 + long(i))
        << i;
  EXPECT_EQ(r.final_counters().at("sets_dropped"), "0");
}

// Sim cameras replaying a `flamerig simulate` dataset: the recorded Mono8 frames are the luma of
// the dataset's images; a camera set to another size reports the error and the others go on.
TEST(CaptureDaemon, SimCamerasReplayADataset) {
  TempDir dir;
  for (int k = 0; k < 2; ++k) {
    const fs::path f = dir.path / "data" / "frames" / ("frame_00000" + std::to_string(k));
    fs::create_directories(f);
    ImageU8 img(96, 64, 3);
    for (int y = 0; y < 64; ++y)
      for (int x = 0; x < 96; ++x) {
        img.at(x, y, 0) = static_cast<std::uint8_t>(x + 100 * k);
        img.at(x, y, 1) = static_cast<std::uint8_t>(y);
        img.at(x, y, 2) = 40;
      }
    WritePng((f / "cam0.png").string(), img);
    WritePng((f / "cam1.png").string(), img);
    WritePng((f / "cam2.png").string(), img);
  }
  std::string yaml = Config(dir.path, "software-trigger", 50);
  // Every camera replays; camera 2 is set to the wrong size.
  for (const std::string cam : {"cam0", "cam1"}) {
    const std::string key = "name: " + cam + "\n    driver: sim\n";
    yaml.replace(yaml.find(key), key.size(), key + "    sim: {replay: data}\n");
  }
  const std::string key2 = "name: cam2\n    driver: sim\n";
  yaml.replace(yaml.find(key2), key2.size(), key2 + "    sim: {replay: data}\n");
  yaml.replace(yaml.rfind("width: 96"), 9, "width: 80");
  std::ofstream(dir.path / "rig.yaml") << yaml;
  const CaptureConfig config = CaptureConfig::Load((dir.path / "rig.yaml").string());
  SystemClock clock;
  CaptureDaemon daemon(config, MakeCameras(config, {&clock, nullptr}), &clock, nullptr);
  daemon.Start();
  const std::string rec = daemon.StartRecording("replay");
  Sleep(0.6);
  daemon.StopRecording();
  const CaptureStatus st = daemon.status();
  daemon.Stop();
  EXPECT_NE(st.cameras[2].error.find("images are 96x64, the camera is set to 80x64"),
            std::string::npos)
      << st.cameras[2].error;
  const Recording r = Recording::Open(rec);
  ASSERT_GE(r.num_sets(), 10u);
  const FrameSet s = r.ReadSet(3);
  ASSERT_TRUE(s.frames[0].has_value());
  EXPECT_FALSE(s.frames[2].has_value());
  const Frame& f = *s.frames[0];
  const int k = static_cast<int>(f.info.frame_id % 2);
  for (int x : {0, 17, 95}) {
    const double luma = 0.2126 * (x + 100 * k) + 0.7152 * 10 + 0.0722 * 40;
    EXPECT_NEAR((*f.data)[10 * 96 + x], luma, 0.51) << "x " << x;
  }
}

// A 12-bit rig rehearsed with sim cameras: replaying a deeper camera's dataset (16-bit PNGs of
// 12-bit codes) as BayerRG12p and Mono12p, the take holds each code in the words' high bits, says
// so per frame and in its settings, and its full scale is the 12-bit one; a camera set to Mono10p
// cannot send those codes and says so, naming the file, while the others record.
TEST(CaptureDaemon, SimCamerasRehearseATwelveBitRig) {
  TempDir dir;
  const fs::path f = dir.path / "data" / "frames" / "frame_000000";
  fs::create_directories(f);
  ImageU16 codes(96, 64, 3);
  for (int y = 0; y < 64; ++y)
    for (int x = 0; x < 96; ++x)
      for (int c = 0; c < 3; ++c)
        codes.at(x, y, c) = static_cast<std::uint16_t>(25 * x + 3 * y + 600 * c);  // to 3764
  for (const char* cam : {"cam0", "cam1", "cam2"})
    WritePng16((f / (std::string(cam) + ".png")).string(), codes);
  std::string yaml = Config(dir.path, "software-trigger", 50);
  const char* formats[] = {"BayerRG12p", "Mono12p", "Mono10p"};
  for (int c = 0; c < 3; ++c) {
    const std::string key = "name: cam" + std::to_string(c) + "\n    driver: sim\n";
    yaml.replace(yaml.find(key), key.size(),
                 key + "    pixel_format: " + formats[c] + "\n    sim: {replay: data}\n");
  }
  std::ofstream(dir.path / "rig.yaml") << yaml;
  const CaptureConfig config = CaptureConfig::Load((dir.path / "rig.yaml").string());
  SystemClock clock;
  CaptureDaemon daemon(config, MakeCameras(config, {&clock, nullptr}), &clock, nullptr);
  daemon.Start();
  const std::string rec = daemon.StartRecording("twelve");
  Sleep(0.4);
  daemon.StopRecording();
  const CaptureStatus st = daemon.status();
  daemon.Stop();
  EXPECT_NE(st.cameras[2].error.find("cam2.png"), std::string::npos) << st.cameras[2].error;
  EXPECT_NE(st.cameras[2].error.find("Mono10p"), std::string::npos) << st.cameras[2].error;
  const Recording r = Recording::Open(rec);
  ASSERT_GE(r.num_sets(), 3u);
  EXPECT_EQ(r.metadata().cameras[0].settings.wire_format, "BayerRG12p");
  EXPECT_EQ(r.metadata().cameras[1].settings.wire_format, "Mono12p");
  const FrameSet s = r.ReadSet(1);
  ASSERT_TRUE(s.frames[0].has_value());
  ASSERT_TRUE(s.frames[1].has_value());
  EXPECT_FALSE(s.frames[2].has_value());
  const Frame& bayer = *s.frames[0];
  const Frame& mono = *s.frames[1];
  EXPECT_EQ(bayer.info.pixel_format, PixelFormat::kBayerRg16);
  EXPECT_EQ(bayer.info.sent_pfnc, WireFormatFromName("BayerRG12p")->pfnc);
  EXPECT_EQ(mono.info.pixel_format, PixelFormat::kMono16);
  EXPECT_EQ(mono.info.sent_pfnc, WireFormatFromName("Mono12p")->pfnc);
  EXPECT_EQ(FullScaleValue(bayer.info, r.metadata().cameras[0].settings.wire_format), 0xfff0);
  auto word = [](const Frame& fr, int x, int y) {
    std::uint16_t v;
    std::memcpy(&v, fr.data->data() + 2 * (std::size_t(y) * 96 + x), 2);
    return v;
  };
  // RGGB: R at (0, 0), G at (1, 0), B at (1, 1).
  for (int x : {0, 2, 60}) EXPECT_EQ(word(bayer, x, 10), codes.at(x, 10, 0) << 4) << x;
  EXPECT_EQ(word(bayer, 1, 10), codes.at(1, 10, 1) << 4);
  EXPECT_EQ(word(bayer, 5, 11), codes.at(5, 11, 2) << 4);
  for (int x : {0, 17, 95}) {
    const double luma =
        0.2126 * codes.at(x, 20, 0) + 0.7152 * codes.at(x, 20, 1) + 0.0722 * codes.at(x, 20, 2);
    EXPECT_EQ(word(mono, x, 20), std::lround(luma) << 4) << x;
  }
}

TEST(CaptureDaemon, RecordingNamesCannotLeaveTheDataDirectory) {
  TempDir dir;
  const CaptureConfig config = CaptureConfig::Parse(Config(dir.path / "data", "free-run", 30), "t");
  SystemClock clock;
  CaptureDaemon daemon(config, MakeCameras(config, {&clock, nullptr}), &clock, nullptr);
  for (const std::string bad : {"../escape", "a/b", "", "..", ".", "/abs", "x\ny", "a b"})
    EXPECT_THROW(daemon.StartRecording(bad), InputError) << bad;
  EXPECT_FALSE(fs::exists(dir.path / "escape"));
  EXPECT_THROW(daemon.StopRecording(), InputError);
}

// The status for people: a camera that has stopped sending shows it, whatever its driver says of
// the connection (a killed GigE camera stays "connected" until its heartbeat times out); the time
// left on the disk is what min_free_mb leaves at the cameras' current rate.
TEST(CaptureStatus, TheTableShowsStalledCamerasAndTheTimeLeft) {
  CaptureStatus s;
  s.running = true;
  s.armed_s = 125;
  s.recording = true;
  s.recording_s = 65;
  s.recording_dir = "/data/take1";
  s.data_dir = "/data";
  s.period_s = 1.0 / 30;
  s.disk_free_bytes = 64ull << 30;
  s.min_free_bytes = 64ull << 20;
  for (const char* name : {"cam0", "cam1"}) {
    CameraLiveStatus c;
    c.name = name;
    c.id = std::string("SIM") + name[3];
    c.connected = true;
    c.fps = 30;
    c.megabytes_per_s = 9;
    c.frames = 1234;
    c.last_frame_age_s = 0.02;
    s.cameras.push_back(c);
  }
  s.cameras[1].last_frame_age_s = 4.25;  // killed 4 s ago, still "connected"
  s.cameras[1].fps = 0;
  s.cameras[1].megabytes_per_s = 0;
  const std::string t = s.ToTable();
  EXPECT_NE(t.find("armed for 2:05, RECORDING 1:05"), std::string::npos) << t;
  EXPECT_TRUE(std::regex_search(t, std::regex("\\ncam0 +SIM0 +streaming +30\\.00 +9\\.00 +1234")))
      << t;
  EXPECT_TRUE(std::regex_search(t, std::regex("\\ncam1 +SIM1 +no frames for 4\\.2 s"))) << t;
  // (64 GiB - 64 MiB) at 9 MiB/s: 7274.7 s.
  EXPECT_NEAR(s.SecondsLeft(), ((64.0 * 1024) - 64) / 9, 1e-6);
  EXPECT_NE(t.find("2:01:14 of recording left"), std::string::npos) << t;
  EXPECT_NE(t.find("(stops at min_free_mb: 64 MiB)"), std::string::npos) << t;
  s.cameras[0].megabytes_per_s = 0;
  EXPECT_EQ(s.SecondsLeft(), -1);
}

TEST(ControlApi, StatusRecordingAndPreviewOverAUnixSocket) {
  TempDir dir;
  const CaptureConfig config =
      CaptureConfig::Parse(Config(dir.path, "software-trigger", 50), "test");
  fs::create_directories(dir.path);
  SystemClock clock;
  CaptureDaemon daemon(config, MakeCameras(config, {&clock, nullptr}), &clock, nullptr);
  daemon.Start();
  ControlServer server(&daemon, config.control, false);
  const std::string socket_path = config.control.substr(5);
  struct stat st;
  ASSERT_EQ(::stat(socket_path.c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);  // owner only
  Sleep(0.3);
  ControlReply r = ControlRequest(config.control, "status");
  ASSERT_TRUE(r.ok) << r.body;
  EXPECT_NE(r.body.find("running: true"), std::string::npos) << r.body;
  EXPECT_NE(r.body.find("name: \"cam2\""), std::string::npos) << r.body;
  r = ControlRequest(config.control, "start run1");
  ASSERT_TRUE(r.ok) << r.body;
  EXPECT_EQ(r.body, (dir.path / "run1").string() + "\n");
  r = ControlRequest(config.control, "start run2");
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.body.find("already recording"), std::string::npos);
  Sleep(0.4);
  r = ControlRequest(config.control, "preview cam1 2");
  ASSERT_TRUE(r.ok) << r.body;
  const cv::Mat png =
      cv::imdecode(std::vector<std::uint8_t>(r.body.begin(), r.body.end()), cv::IMREAD_UNCHANGED);
  EXPECT_EQ(png.cols, 48);
  EXPECT_EQ(png.rows, 32);
  r = ControlRequest(config.control, "stop");
  ASSERT_TRUE(r.ok) << r.body;
  EXPECT_NE(r.body.find("sets_recorded: "), std::string::npos);
  EXPECT_GE(Recording::Open((dir.path / "run1").string()).num_sets(), 10u);
  // Bad requests: an error that says why, and capture goes on.
  r = ControlRequest(config.control, "start ../../etc");
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.body.find("recording name"), std::string::npos);
  r = ControlRequest(config.control, "format c:");
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.body.find("unknown request"), std::string::npos);
  r = ControlRequest(config.control, std::string(5000, 'a'));
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.body.find("refused"), std::string::npos);
  r = ControlRequest(config.control, "preview cam9");
  EXPECT_FALSE(r.ok);
  const std::uint64_t before = daemon.status().sets.sets;
  Sleep(0.2);
  EXPECT_GT(daemon.status().sets.sets, before);
  // Exposure changes live; a size needs a disarm, configure, arm again.
  r = ControlRequest(config.control, "configure cam1 exposure_us 1500");
  EXPECT_TRUE(r.ok) << r.body;
  EXPECT_NE(r.body.find("live"), std::string::npos) << r.body;
  r = ControlRequest(config.control, "configure cam1 width 64");
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.body.find("disarm"), std::string::npos) << r.body;
  ASSERT_TRUE(ControlRequest(config.control, "disarm").ok);
  EXPECT_FALSE(ControlRequest(config.control, "start nothing").ok);  // not armed
  r = ControlRequest(config.control, "configure cam1 exposure_us 2000");
  ASSERT_TRUE(r.ok) << r.body;
  r = ControlRequest(config.control, "configure cam1 exposure_us -5");
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.body.find("camera 'cam1': exposure_us '-5'"), std::string::npos) << r.body;
  // Found by fuzzing: a width of 66 digits was converted to int (undefined behaviour).
  r = ControlRequest(config.control, "configure cam1 width 2222222222222222222222222222222222");
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.body.find("must be a whole number in [0, 16384]"), std::string::npos) << r.body;
  // The ranges are the config file's: a gain a config refuses is refused here too, and a width
  // the config takes (17000 is over its 16384) is not.
  r = ControlRequest(config.control, "configure cam1 gain_db 1e9");
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.body.find("gain_db must be in [-100, 100]"), std::string::npos) << r.body;
  r = ControlRequest(config.control, "configure cam1 width 17000");
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.body.find("[0, 16384]"), std::string::npos) << r.body;
  r = ControlRequest(config.control, "configure cam1 focus 3");
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.body.find("unknown key"), std::string::npos) << r.body;
  ASSERT_TRUE(ControlRequest(config.control, "arm").ok);
  EXPECT_NE(ControlRequest(config.control, "cameras").body.find("exposure_us: 2000"),
            std::string::npos);
  const std::uint64_t rearmed = daemon.status().sets.sets;
  Sleep(0.3);
  EXPECT_GT(daemon.status().sets.sets, rearmed + 5);  // sets flow again at once
  r = ControlRequest(config.control, "shutdown");
  EXPECT_TRUE(r.ok);
  EXPECT_TRUE(server.shutdown_requested());
}

TEST(ControlApi, TcpOnlyOnLoopbackUnlessAsked) {
  TempDir dir;
  const CaptureConfig config = CaptureConfig::Parse(Config(dir.path, "free-run", 30), "test");
  SystemClock clock;
  CaptureDaemon daemon(config, MakeCameras(config, {&clock, nullptr}), &clock, nullptr);
  try {
    ControlServer open(&daemon, "tcp:0.0.0.0:0", false);
    FAIL() << "bound to every interface without allow_remote";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("allow_remote"), std::string::npos);
  }
  ControlServer server(&daemon, "tcp:127.0.0.1:0", false);
  ASSERT_GT(server.port(), 0);
  const ControlReply r =
      ControlRequest("tcp:127.0.0.1:" + std::to_string(server.port()), "cameras");
  ASSERT_TRUE(r.ok) << r.body;
  EXPECT_NE(r.body.find("id: SIM1"), std::string::npos) << r.body;
  // A host name is resolved (the rig's computer by name), and one that does not resolve is said
  // so, where it was tried as 0.0.0.0 and said "Connection refused".
  EXPECT_TRUE(ControlRequest("tcp:localhost:" + std::to_string(server.port()), "cameras").ok);
  try {
    ControlRequest("tcp:no-such-host.invalid:7000", "status");
    ADD_FAILURE() << "reached a host that does not exist";
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find("no such host 'no-such-host.invalid'"), std::string::npos)
        << e.what();
  }
  EXPECT_THROW(ControlRequest("unix:" + (dir.path / "nobody.sock").string(), "status"),
               std::runtime_error);
}

// GenICam Bayer names give the colour at (0,0) first. A red scene, mosaicked in each of the four
// layouts, must decode to red.
TEST(DecodeFrame, BayerLayoutsDecodeARedSceneAsRed) {
  const struct {
    PixelFormat f;
    int red_x, red_y;  // where R sits in the 2x2 tile
  } layouts[] = {{PixelFormat::kBayerRg8, 0, 0},
                 {PixelFormat::kBayerGr8, 1, 0},
                 {PixelFormat::kBayerGb8, 0, 1},
                 {PixelFormat::kBayerBg8, 1, 1}};
  for (const auto& l : layouts) {
    Frame f;
    f.info.width = 16;
    f.info.height = 12;
    f.info.pixel_format = l.f;
    auto b = std::make_shared<std::vector<std::uint8_t>>(16 * 12, 0);
    for (int y = 0; y < 12; ++y)
      for (int x = 0; x < 16; ++x)
        if (x % 2 == l.red_x && y % 2 == l.red_y) (*b)[y * 16 + x] = 200;
    f.data = b;
    ImageU8 u8;
    ImageU16 u16;
    ASSERT_EQ(DecodeFrame(f, &u8, &u16), 8);
    ASSERT_EQ(u8.channels, 3);
    EXPECT_NEAR(u8.at(7, 5, 0), 200, 1) << ToString(l.f);
    EXPECT_EQ(u8.at(7, 5, 1), 0) << ToString(l.f);
    EXPECT_EQ(u8.at(7, 5, 2), 0) << ToString(l.f);
  }
  Frame mono;
  mono.info.width = 4;
  mono.info.height = 2;
  mono.info.pixel_format = PixelFormat::kMono16;
  mono.data = std::make_shared<std::vector<std::uint8_t>>(16, 1);
  ImageU8 u8;
  ImageU16 u16;
  ASSERT_EQ(DecodeFrame(mono, &u8, &u16), 16);
  EXPECT_EQ(u16.at(3, 1), 257);
  mono.data = std::make_shared<std::vector<std::uint8_t>>(15, 1);
  EXPECT_THROW(DecodeFrame(mono, &u8, &u16), DataError);
}

}  // namespace
}  // namespace flamerig
