#include "acquisition/capture.h"

#include "acquisition/aravis_camera.h"
#include "acquisition/camera_drivers.h"
#include "acquisition/thread_name.h"
#include "acquisition/v4l2_camera.h"
#include "core/config_reader.h"
#include "core/error.h"
#include "core/format.h"
#include "core/json_yaml.h"
#include "core/log.h"
#include "core/read_file.h"

#include <sys/statvfs.h>
#include <yaml-cpp/yaml.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <functional>
#include <mutex>
#include <set>

namespace flamerig {

namespace fs = std::filesystem;

const char* ToString(SyncMode mode) {
  switch (mode) {
    case SyncMode::kHardwareTrigger:
      return "hardware-trigger";
    case SyncMode::kSoftwareTrigger:
      return "software-trigger";
    case SyncMode::kFreeRun:
      return "free-run";
    case SyncMode::kPtp:
      return "ptp";
  }
  return "?";
}

SyncMode SyncModeFromName(const std::string& name) {
  for (SyncMode m :
       {SyncMode::kHardwareTrigger, SyncMode::kSoftwareTrigger, SyncMode::kFreeRun, SyncMode::kPtp})
    if (name == ToString(m)) return m;
  throw InputError("sync '" + name + "': use hardware-trigger, software-trigger, free-run or ptp");
}

namespace {

// A triggered camera's maximum rate leaves room for the trigger's timing jitter: a camera ignores
// a trigger that comes before it is ready. The config file and `ctl configure` hold to the same
// rule (configure accepted 5 Hz under a 30 Hz trigger, and the take missed 59 triggers).
void CheckTriggeredFrameRate(const CaptureConfig& c, const CameraSettings& s,
                             const std::string& where) {
  const bool triggered =
      c.sync == SyncMode::kHardwareTrigger || c.sync == SyncMode::kSoftwareTrigger;
  if (triggered && s.frame_rate_hz < 1.1 * c.trigger_rate_hz * (1 - 1e-12))  // 55 = 1.1 x 50
    throw InputError(where + ": frame_rate_hz " + FormatNumber(s.frame_rate_hz) +
                     " (the camera's maximum rate when triggered) must be at least 1.1 x "
                     "trigger_rate_hz (" +
                     FormatNumber(1.1 * c.trigger_rate_hz) + " Hz), or it will ignore triggers");
}

}  // namespace

CaptureConfig CaptureConfig::Load(const std::string& path) {
  std::string text;
  try {
    text = ReadFile(path);
  } catch (const IoError& e) {
    throw InputError("capture config " + std::string(e.what()));
  }
  return Parse(text, path);
}

CaptureConfig CaptureConfig::Parse(const std::string& text, const std::string& where) {
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw InputError(where + ": not valid YAML: " + e.what());
  }
  RejectDuplicateKeys(root, where);
  if (!root.IsMap()) throw InputError(where + ": expected a mapping of settings");
  CaptureConfig c;
  c.source_yaml = text;
  ConfigReader r(root, where);
  c.data_dir = r.Get<std::string>("data_dir", c.data_dir);
  c.sync = SyncModeFromName(r.Get<std::string>("sync", ToString(c.sync)));
  c.trigger_rate_hz = r.Range("trigger_rate_hz", c.trigger_rate_hz, 1e-3, 1e5);
  // Timestamp matching: about half a frame period by default (notes/aravis.md: the spread of host
  // receive times inside a set reaches a few ms, more on a loaded host).
  c.match_tolerance_ns = static_cast<std::int64_t>(
      r.Range("match_tolerance_ms", 400.0 / c.trigger_rate_hz, 1e-6, 1e6) * 1e6);
  c.set_timeout_ns = static_cast<std::int64_t>(r.Range("set_timeout_ms", 200, 1e-3, 1e6) * 1e6);
  c.buffers = r.Whole<int>("buffers", c.buffers, 1, 1024);
  c.pretrigger_seconds = r.Range("pretrigger_seconds", c.pretrigger_seconds, 0, 3600);
  c.pretrigger_max_bytes =
      static_cast<std::uint64_t>(r.Range("pretrigger_max_mb", 256, 0, 1e7) * (1 << 20));
  c.recorder.max_queued_bytes =
      static_cast<std::uint64_t>(r.Range("queue_mb", 512, 1e-3, 1e7) * (1 << 20));
  c.recorder.min_free_bytes =
      static_cast<std::uint64_t>(r.Range("min_free_mb", 64, 0, 1e9) * (1 << 20));
  c.recorder.sync_interval_s = r.NonNegative("sync_interval_s", c.recorder.sync_interval_s);
  c.recorder.max_bytes =
      static_cast<std::uint64_t>(r.Range("max_recording_mb", 0, 0, 1e12) * (1 << 20));
  if (const long long sets = r.Get<long long>("max_recording_sets", 0); sets >= 0)
    c.recorder.max_sets = static_cast<std::uint64_t>(sets);
  else
    throw InputError(where + ": 'max_recording_sets' must be a whole number >= 0 (0: no limit)");
  c.control = r.Get<std::string>("control", "");
  c.allow_remote = r.Get<bool>("allow_remote", false);
  c.live_view = r.Get<std::string>("live_view", "");
  c.live_view_allow_remote = r.Get<bool>("live_view_allow_remote", false);
  c.live_view_token = r.Get<std::string>("live_view_token", "");
  r.Seen("action");
  if (const YAML::Node action = root["action"]) {
    if (c.sync != SyncMode::kPtp)
      throw InputError(where + ": 'action' (GigE Vision action commands) needs sync: ptp");
    if (!action.IsMap()) throw InputError(where + ": 'action' must be a mapping");
    ConfigReader ar(action, where + ": action");
    ActionConfig& a = c.action;
    a.enabled = true;
    // Decimal or 0x hexadecimal, as camera manuals write keys and masks.
    auto key = [&](const char* name, std::uint32_t fallback) {
      const std::string text = ar.Get<std::string>(name, std::to_string(fallback));
      std::size_t used = 0;
      unsigned long long v = 0;
      try {
        if (text.empty() || text[0] == '-') throw InputError("negative");
        v = std::stoull(text, &used, 0);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used != text.size() || v > 0xffffffffULL)
        throw InputError(where + ": action: '" + name + "' (" + text +
                         ") must be an integer in [0, 2^32), decimal or 0x hex");
      return static_cast<std::uint32_t>(v);
    };
    a.device_key = key("device_key", a.device_key);
    a.group_key = key("group_key", a.group_key);
    a.group_mask = key("group_mask", a.group_mask);
    if (a.group_mask == 0)
      throw InputError(where + ": action: 'group_mask' 0 would fire no camera");
    a.lead_ms = ar.Range("lead_ms", a.lead_ms, 1e-3, 1e6);
    a.destination = ar.Get<std::string>("destination", a.destination);
    a.port = ar.Whole<int>("port", a.port, 1, 65535);
    ar.CheckKnown();
  }
  r.Seen("cameras");
  r.CheckKnown();
  const YAML::Node cams = root["cameras"];
  if (!cams || !cams.IsSequence() || cams.size() == 0)
    throw InputError(where + ": 'cameras' must list at least one camera");
  std::set<std::string> names;
  for (std::size_t i = 0; i < cams.size(); ++i) {
    const std::string at = where + ": cameras[" + std::to_string(i) + "]";
    if (!cams[i].IsMap()) throw InputError(at + ": expected a mapping");
    ConfigReader cr(cams[i], at);
    CaptureCameraConfig cc;
    cc.name = cr.Get<std::string>("name", "cam" + std::to_string(i));
    // The name becomes a file name (export's <camera>.png, a rig's camera): one path component.
    const bool safe_name = !cc.name.empty() && cc.name.size() <= 64 && cc.name[0] != '.' &&
                           cc.name[0] != '-' &&
                           std::all_of(cc.name.begin(), cc.name.end(), [](char ch) {
                             return std::isalnum(static_cast<unsigned char>(ch)) || ch == '_' ||
                                    ch == '-' || ch == '.';
                           });
    if (!safe_name)
      throw InputError(at + ": name '" + cc.name.substr(0, 64) +
                       "' must be 1 to 64 of A-Z a-z 0-9 _ - . (not starting with . or -): it "
                       "names the camera's files");
    if (!names.insert(cc.name).second)
      throw InputError(at + ": camera name '" + cc.name + "' is used twice");
    cc.driver = cr.Get<std::string>("driver", "sim");
    cc.required = cr.Get<bool>("required", true);
    const CameraDriver* found = nullptr;
    try {
      found = &FindCameraDriver(cc.driver);
    } catch (const InputError& e) {
      throw InputError(at + ": " + e.what());
    }
    const CameraDriver& driver = *found;
    cc.id = cr.Get<std::string>(
        "id", driver.default_id ? driver.default_id(static_cast<int>(i)) : std::string());
    if (cc.id.empty()) throw InputError(at + ": 'id' (serial, address or device) is required");
    for (std::size_t j = 0; j < c.cameras.size(); ++j)
      if (c.cameras[j].driver == cc.driver && c.cameras[j].id == cc.id)
        throw InputError(at + ": id '" + cc.id + "' is also cameras[" + std::to_string(j) + "] ('" +
                         c.cameras[j].name + "'): one camera cannot be opened twice");
    CameraSettings& s = cc.settings;
    // Absent: the camera's own size (aravis: its whole sensor; v4l2: its current format).
    const bool sim = cc.driver == "sim";
    s.width = cr.Whole<int>("width", sim ? s.width : 0, 0, 16384);
    s.height = cr.Whole<int>("height", sim ? s.height : 0, 0, 16384);
    s.offset_x = cr.Whole<int>("offset_x", 0, 0, 16384);
    s.offset_y = cr.Whole<int>("offset_y", 0, 0, 16384);
    cr.Seen("features");
    if (const YAML::Node f = cams[i]["features"]) {
      if (!f.IsMap())
        throw InputError(at +
                         ".features: a mapping of feature names (GenICam for aravis, v4l2-ctl's "
                         "control names for v4l2) to values");
      for (const auto& kv : f) {
        if (!kv.second.IsScalar())
          throw InputError(at + ".features." + kv.first.as<std::string>() + ": a single value");
        s.features.emplace_back(kv.first.as<std::string>(), kv.second.as<std::string>());
      }
    }
    try {
      s.SetPixelFormat(cr.Get<std::string>("pixel_format", "Mono8"));
    } catch (const InputError& e) {
      throw InputError(at + ": " + e.what());
    }
    // Free-run: the rate. Triggered: the camera's maximum rate, which must leave room for the
    // trigger's timing jitter (a camera ignores a trigger that comes before it is ready).
    const bool triggered =
        c.sync == SyncMode::kHardwareTrigger || c.sync == SyncMode::kSoftwareTrigger;
    s.frame_rate_hz =
        cr.Range("frame_rate_hz", triggered ? 2 * c.trigger_rate_hz : c.trigger_rate_hz, 1e-3, 1e6);
    CheckTriggeredFrameRate(c, s, at);
    s.exposure_us = cr.Range("exposure_us", s.exposure_us, 1e-3, 1e9);
    s.gain_db = cr.Range("gain_db", s.gain_db, -100, 100);
    s.trigger_source = cr.Get<std::string>("trigger_source", s.trigger_source);
    s.packet_size = cr.Whole<int>("packet_size", 0, 0, 65535);
    s.ptp = c.sync == SyncMode::kPtp;
    s.trigger = c.sync == SyncMode::kHardwareTrigger   ? TriggerMode::kHardware
                : c.sync == SyncMode::kSoftwareTrigger ? TriggerMode::kSoftware
                                                       : TriggerMode::kFreeRun;
    // Action commands reach GigE Vision cameras only; sim cameras stay free-run on the shared
    // clock.
    if (c.action.enabled && driver.capabilities.action_commands) {
      s.trigger = TriggerMode::kAction;
      s.action_device_key = c.action.device_key;
      s.action_group_key = c.action.group_key;
      s.action_group_mask = c.action.group_mask;
    }
    try {
      s.Validate();
    } catch (const InputError& e) {
      throw InputError(at + ": " + e.what());
    }
    // The driver's own keys: the map under its name (`sim:` for the sim driver); another
    // driver's map is a mistake.
    for (const CameraDriver& other : CameraDrivers()) {
      cr.Seen(other.name);
      if (other.name != cc.driver && cams[i][other.name])
        throw InputError(at + ": '" + other.name + "' is for driver " + other.name + " only");
    }
    cr.CheckKnown();
    const YAML::Node keys = cams[i][cc.driver];
    if (driver.read_keys)
      driver.read_keys(keys, at + "." + cc.driver, where, static_cast<int>(i), &cc);
    else if (keys)
      throw InputError(at + ": driver " + cc.driver + " has no keys of its own ('" + cc.driver +
                       "')");
    c.cameras.push_back(cc);
  }
  // Relative paths are relative to the config file (as a sim camera's replay is), not to the
  // directory the daemon or ctl happens to start in.
  const fs::path base = fs::path(where).parent_path();
  auto resolve = [&](const std::string& p) {
    return p.empty() || base.empty() || fs::path(p).is_absolute()
               ? p
               : (base / p).lexically_normal().string();
  };
  c.data_dir = resolve(c.data_dir);
  if (c.control.rfind("unix:", 0) == 0) c.control = "unix:" + resolve(c.control.substr(5));
  if (c.control.empty()) c.control = "unix:" + (fs::path(c.data_dir) / "control.sock").string();
  return c;
}

FrameSetOptions CaptureConfig::AssemblerOptions() const {
  FrameSetOptions o;
  o.cameras = static_cast<int>(cameras.size());
  const bool triggered = sync == SyncMode::kHardwareTrigger || sync == SyncMode::kSoftwareTrigger;
  // Only drivers whose frames carry the trigger's id (the sim driver) match triggered sets by id;
  // real cameras' frames carry none, so triggered sets are matched by receive time, within 40% of
  // the trigger period (every camera exposes on the same pulse; their receive times differ by
  // transfer jitter).
  const bool ids = std::all_of(cameras.begin(), cameras.end(), [](const CaptureCameraConfig& c) {
    return FindCameraDriver(c.driver).capabilities.trigger_ids;
  });
  o.match = triggered && ids ? MatchBy::kTriggerId : MatchBy::kTimestamp;
  // PTP cameras share a clock: match their own timestamps. Otherwise the cameras' clocks are
  // unrelated: match the host's receive times.
  o.timestamp = sync == SyncMode::kPtp ? TimestampSource::kDevice : TimestampSource::kHostMonotonic;
  o.tolerance_ns = match_tolerance_ns;
  if (triggered && !ids)
    o.tolerance_ns = std::max<std::int64_t>(o.tolerance_ns, std::llround(0.4e9 / trigger_rate_hz));
  o.timeout_ns = set_timeout_ns;
  return o;
}

namespace {

// An optional camera (required: false) that could not be opened: it reads as disconnected, and
// each Reconnect() (the daemon calls it about once a second) tries to open it again; once open it
// is configured and started as the daemon last asked, and everything passes through to it.
class DeferredCamera : public Camera {
 public:
  using Opener = std::function<std::unique_ptr<Camera>()>;
  DeferredCamera(Opener open, CameraDescription description, CameraSettings settings, Clock* clock)
      : open_(std::move(open)),
        description_(std::move(description)),
        settings_(settings),
        clock_(clock) {}

  CameraDescription description() const override {
    std::lock_guard<std::mutex> lock(mutex_);
    return inner_ ? inner_->description() : description_;
  }
  void Configure(const CameraSettings& s) override {
    std::lock_guard<std::mutex> lock(mutex_);
    settings_ = s;
    if (inner_) inner_->Configure(s);
  }
  CameraSettings settings() const override {
    std::lock_guard<std::mutex> lock(mutex_);
    return inner_ ? inner_->settings() : settings_;
  }
  void Start(int buffers) override {
    std::lock_guard<std::mutex> lock(mutex_);
    buffers_ = buffers;
    started_ = true;
    if (inner_) inner_->Start(buffers);
  }
  void Stop() override {
    std::lock_guard<std::mutex> lock(mutex_);
    started_ = false;
    if (inner_) inner_->Stop();
  }
  std::optional<Frame> Pop(std::int64_t timeout_ns) override {
    std::shared_ptr<Camera> inner = Inner();
    if (inner) return inner->Pop(timeout_ns);
    clock_->SleepUntil(clock_->MonotonicNs() + std::min<std::int64_t>(timeout_ns, 100'000'000));
    return std::nullopt;
  }
  void SoftwareTrigger(std::int64_t trigger_id) override {
    if (std::shared_ptr<Camera> inner = Inner()) inner->SoftwareTrigger(trigger_id);
  }
  bool connected() const override {
    std::shared_ptr<Camera> inner = Inner();
    return inner && inner->connected();
  }
  bool Reconnect() override {
    if (std::shared_ptr<Camera> inner = Inner()) return inner->Reconnect();
    std::unique_ptr<Camera> opened;
    try {
      opened = open_();
    } catch (const std::exception&) {
      return false;  // still absent
    }
    std::lock_guard<std::mutex> lock(mutex_);
    try {
      opened->Configure(settings_);
      if (started_) opened->Start(buffers_);
    } catch (const std::exception& e) {
      // Here but refusing its settings: said once, and it stays out of the rig.
      if (refusal_ != e.what())
        Log().error("capture: camera {} ({}) is here but refuses its settings: {}", description_.id,
                    description_.driver, e.what());
      refusal_ = e.what();
      return false;
    }
    inner_ = std::move(opened);
    Log().info("capture: camera {} ({}) is here now", description_.id, description_.driver);
    return true;
  }
  bool SetExposureGainLive(double exposure_us, double gain_db) override {
    std::shared_ptr<Camera> inner = Inner();
    if (inner) return inner->SetExposureGainLive(exposure_us, gain_db);
    std::lock_guard<std::mutex> lock(mutex_);  // absent: taken when it arrives
    settings_.exposure_us = exposure_us;
    settings_.gain_db = gain_db;
    return true;
  }
  std::map<std::string, std::string> FeatureState() const override {
    std::shared_ptr<Camera> inner = Inner();
    return inner ? inner->FeatureState() : std::map<std::string, std::string>{};
  }
  StreamCounters counters() const override {
    std::shared_ptr<Camera> inner = Inner();
    return inner ? inner->counters() : StreamCounters{};
  }

 private:
  std::shared_ptr<Camera> Inner() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return inner_;
  }
  Opener open_;
  CameraDescription description_;
  mutable std::mutex mutex_;
  CameraSettings settings_;
  int buffers_ = 0;
  bool started_ = false;
  std::string refusal_;
  std::shared_ptr<Camera> inner_;
  Clock* clock_;
};

}  // namespace

std::vector<std::unique_ptr<Camera>> MakeCameras(const CaptureConfig& config,
                                                 const DriverContext& context) {
  std::vector<std::unique_ptr<Camera>> cameras;
  for (const auto& c : config.cameras) {
    const int index = static_cast<int>(cameras.size());
    const CameraDriver& driver = FindCameraDriver(c.driver);
    try {
      cameras.push_back(driver.open(c, index, context));
    } catch (const std::exception& e) {
      if (c.required || context.clock == nullptr)
        Rethrow(e, "camera '" + c.name + "': ", Error::Kind::kIo);
      Log().warn(
          "capture: camera '{}' ({}) is not here ({}); starting without it (required: "
          "false) and trying again every second",
          c.name, c.id, e.what());
      cameras.push_back(std::make_unique<DeferredCamera>(
          [&driver, c, index, context] { return driver.open(c, index, context); },
          CameraDescription{c.driver, c.id, "", "", "", ""}, c.settings, context.clock));
    }
  }
  return cameras;
}

namespace {

// Every field of the status, once: the JSON and the YAML are made from it.
nlohmann::json StatusJson(const CaptureStatus& s) {
  nlohmann::json j;
  j["running"] = s.running;
  j["recording"] = s.recording;
  j["recording_dir"] = s.recording_dir;
  j["armed_s"] = s.armed_s;
  j["recording_s"] = s.recording_s;
  for (const auto& c : s.cameras) {
    nlohmann::json k;
    k["name"] = c.name;
    k["id"] = c.id;
    k["connected"] = c.connected;
    k["fps"] = c.fps;
    k["megabytes_per_s"] = c.megabytes_per_s;
    k["frames"] = c.frames;
    k["incomplete"] = c.stream.incomplete;
    k["missing_by_frame_id"] = c.stream.missing_by_id;
    k["missing_by_timestamp"] = c.stream.missing_by_time;
    k["underruns"] = c.stream.underruns;
    k["buffers_allocated"] = c.stream.buffers_allocated;
    k["disconnects"] = c.disconnects;
    k["reconnect_attempts"] = c.reconnect_attempts;
    k["reconnects"] = c.reconnects;
    k["last_frame_age_s"] = c.last_frame_age_s;
    k["missed_triggers"] = c.missed_triggers;
    k["error"] = c.error;
    j["cameras"].push_back(k);
  }
  j["frame_sets"] = {{"total", s.sets.sets},
                     {"complete", s.sets.complete},
                     {"incomplete", s.sets.incomplete},
                     {"late_frames", s.sets.late_frames},
                     {"max_spread_ms", s.sets.max_spread_ns / 1e6}};
  j["recorder"] = {{"sets_recorded", s.recorder.sets_recorded},
                   {"sets_dropped", s.recorder.sets_dropped},
                   {"megabytes_written", s.recorder.bytes_written / 1048576.0},
                   {"disk_backlog_mb", s.recorder.queued_bytes / 1048576.0},
                   {"queue_fill", s.recorder.max_queued_bytes ? double(s.recorder.queued_bytes) /
                                                                    s.recorder.max_queued_bytes
                                                              : 0.0},
                   {"stopped", s.recorder.stopped},
                   {"limit_reached", s.recorder.limit_reached},
                   {"error", s.recorder.error}};
  j["incoming_queue"] = {s.incoming_queued, s.incoming_capacity};
  j["incoming_dropped"] = s.incoming_dropped;
  j["trigger_overruns"] = s.trigger_overruns;
  j["action_commands"] = s.action_commands;
  j["rejected_sets"] = s.rejected_sets;
  j["last_error"] = s.last_error;
  j["pretrigger_ring"] = {{"sets", s.ring_sets}, {"megabytes", s.ring_bytes / 1048576.0}};
  j["data_dir"] = s.data_dir;
  j["disk_free_mb"] = s.disk_free_bytes / 1048576.0;
  j["min_free_mb"] = s.min_free_bytes / 1048576.0;
  j["seconds_left"] = s.SecondsLeft();
  return j;
}

}  // namespace

std::string CaptureStatus::ToJson() const {
  // Text that is not UTF-8 (a driver's error in another encoding) is replaced, not thrown on.
  return StatusJson(*this).dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";
}

std::string CaptureStatus::ToYaml() const { return JsonAsYaml(StatusJson(*this)); }

double CaptureStatus::SecondsLeft() const {
  double rate = 0;  // bytes per second, all cameras
  for (const auto& c : cameras) rate += c.megabytes_per_s * 1048576.0;
  if (!(rate > 0)) return -1;
  const double usable =
      disk_free_bytes > min_free_bytes ? double(disk_free_bytes - min_free_bytes) : 0.0;
  return usable / rate;
}

namespace {

// 1:02:03, 2:03 or 4.2 s.
std::string Elapsed(double s) {
  char b[32];
  const long t = static_cast<long>(s);
  if (s >= 3600)
    std::snprintf(b, sizeof b, "%ld:%02ld:%02ld", t / 3600, t / 60 % 60, t % 60);
  else if (s >= 60)
    std::snprintf(b, sizeof b, "%ld:%02ld", t / 60, t % 60);
  else
    std::snprintf(b, sizeof b, "%.1f s", s);
  return b;
}

// 1.2 GB, 340 MB, 12 kB.
std::string Bytes(double bytes) {
  char b[32];
  if (bytes >= 1e9)
    std::snprintf(b, sizeof b, "%.1f GB", bytes / 1e9);
  else if (bytes >= 1e6)
    std::snprintf(b, sizeof b, "%.0f MB", bytes / 1e6);
  else
    std::snprintf(b, sizeof b, "%.0f kB", bytes / 1e3);
  return b;
}

}  // namespace

std::string CaptureStatus::ToTable() const {
  std::string out;
  char line[512];
  auto add = [&](const char* label, const std::string& text) {
    std::snprintf(line, sizeof line, "%-10s %s\n", label, text.c_str());
    out += line;
  };
  add("state", !running ? std::string("disarmed")
                        : "armed for " + Elapsed(armed_s) +
                              (recording ? ", RECORDING " + Elapsed(recording_s) : ""));
  if (recording || !recording_dir.empty()) {
    std::snprintf(line, sizeof line,
                  "%s%s: %llu sets, %s written, %llu dropped, backlog %s (%.0f%%)",
                  recording ? "" : "last: ", recording_dir.c_str(),
                  static_cast<unsigned long long>(recorder.sets_recorded),
                  Bytes(double(recorder.bytes_written)).c_str(),
                  static_cast<unsigned long long>(recorder.sets_dropped),
                  Bytes(double(recorder.queued_bytes)).c_str(),
                  recorder.max_queued_bytes
                      ? 100.0 * double(recorder.queued_bytes) / recorder.max_queued_bytes
                      : 0.0);
    add("recording", line);
    if (!recorder.error.empty()) add("", "stopped: " + recorder.error);
  }
  const double left = SecondsLeft();
  add("disk",
      Bytes(double(disk_free_bytes)) + " free in " + data_dir +
          (left >= 0
               ? ", " + Elapsed(left) + " of recording left at " +
                     Bytes(left > 0 ? (double(disk_free_bytes) - min_free_bytes) / left : 0.0) +
                     "/s"
               : std::string()) +
          " (stops at min_free_mb: " + std::to_string(min_free_bytes >> 20) + " MiB)");
  std::snprintf(line, sizeof line,
                "%llu (%llu complete, %llu incomplete, %llu late frames), max spread %.2f ms",
                static_cast<unsigned long long>(sets.sets),
                static_cast<unsigned long long>(sets.complete),
                static_cast<unsigned long long>(sets.incomplete),
                static_cast<unsigned long long>(sets.late_frames), sets.max_spread_ns / 1e6);
  add("sets", line);
  if (incoming_dropped || trigger_overruns || rejected_sets) {
    std::snprintf(line, sizeof line,
                  "%llu frames dropped before assembly, %llu trigger overruns, %llu sets refused",
                  static_cast<unsigned long long>(incoming_dropped),
                  static_cast<unsigned long long>(trigger_overruns),
                  static_cast<unsigned long long>(rejected_sets));
    add("faults", line);
  }
  if (!last_error.empty()) add("error", last_error);
  std::snprintf(line, sizeof line, "\n%-12s %-16s %-20s %7s %7s %9s %10s %8s %11s\n", "camera",
                "id", "state", "fps", "MB/s", "frames", "incomplete", "missing", "disconnects");
  out += line;
  const double stale_s = std::max(1.0, 3 * period_s);
  for (const auto& c : cameras) {
    std::string state = c.connected ? "streaming" : "disconnected";
    if (running && c.last_frame_age_s < 0) state = "no frame yet";
    if (running && c.last_frame_age_s > stale_s) {
      char b[48];
      std::snprintf(b, sizeof b, "no frames for %.1f s", c.last_frame_age_s);
      state = b;
    }
    if (!running) state = c.connected ? "idle" : "disconnected";
    std::snprintf(line, sizeof line, "%-12s %-16s %-20s %7.2f %7.2f %9llu %10llu %8llu %11llu\n",
                  c.name.c_str(), c.id.c_str(), state.c_str(), c.fps, c.megabytes_per_s,
                  static_cast<unsigned long long>(c.frames),
                  static_cast<unsigned long long>(c.stream.incomplete),
                  static_cast<unsigned long long>(c.stream.missing_by_id +
                                                  c.stream.missing_by_time + c.missed_triggers),
                  static_cast<unsigned long long>(c.disconnects));
    out += line;
    if (!c.error.empty()) out += "             last error: " + c.error + "\n";
  }
  return out;
}

// ---------------------------------------------------------------------------------------------

struct CaptureDaemon::CameraState {
  mutable std::mutex mutex;
  CameraLiveStatus live;
  std::deque<std::pair<std::int64_t, std::uint64_t>> recent;  // (receive time, bytes), last 1 s
  std::int64_t last_frame_ns = -1;                            // receive time of the last frame
  // Frames since the arm: receive times while they may still answer a recent trigger, then only
  // counted (the missed-trigger count compares them with the triggers sent).
  std::deque<std::int64_t> recent_frames;
  std::uint64_t old_frames = 0;
  std::map<std::string, std::string> features;  // its feature state at the last arm or reconnect
  double exposure_us = 0;                       // what it exposes now (for the trigger grace)
};

CaptureDaemon::CaptureDaemon(const CaptureConfig& config,
                             std::vector<std::unique_ptr<Camera>> cameras, Clock* clock,
                             TriggerLine* trigger_line)
    : config_(config),
      cameras_(std::move(cameras)),
      clock_(clock),
      trigger_line_(trigger_line),
      assembler_(config.AssemblerOptions()) {
  if (cameras_.size() != config_.cameras.size())
    throw InputError("capture: the config lists " + std::to_string(config_.cameras.size()) +
                     " cameras, " + std::to_string(cameras_.size()) + " were given");
  for (std::size_t c = 0; c < cameras_.size(); ++c) {
    auto s = std::make_unique<CameraState>();
    s->live.name = config_.cameras[c].name;
    s->live.id = config_.cameras[c].id;
    camera_state_.push_back(std::move(s));
  }
  incoming_capacity_ = std::max<std::size_t>(64, 4 * cameras_.size() * config_.buffers);
  // The ring is flushed into a new recording at once: its queue must hold it. Without a ring the
  // queue is what the config says (found by the soak: a 64 MB queue had silently become 320 MB).
  if (config_.pretrigger_seconds > 0)
    config_.recorder.max_queued_bytes =
        std::max<std::uint64_t>(config_.recorder.max_queued_bytes,
                                config_.pretrigger_max_bytes + (std::uint64_t(64) << 20));
}

CaptureDaemon::~CaptureDaemon() {
  try {
    Stop();
  } catch (...) {
  }
}

void CaptureDaemon::Start() {
  std::lock_guard<std::recursive_mutex> command(command_mutex_);
  if (running_) return;
  armed_ns_ = clock_->MonotonicNs();
  for (auto& st : camera_state_) {
    std::lock_guard<std::mutex> lock(st->mutex);
    st->recent_frames.clear();
    st->old_frames = 0;
  }
  {
    std::lock_guard<std::mutex> lock(trigger_mutex_);
    old_triggers_ = 0;
    recent_triggers_.clear();
  }
  {
    // A fresh assembler at every arm.
    std::lock_guard<std::mutex> lock(state_mutex_);
    assembler_ = FrameSetAssembler(config_.AssemblerOptions());
    set_counters_ = assembler_.counters();
  }
  {
    std::lock_guard<std::mutex> lock(incoming_mutex_);
    incoming_.clear();  // frames from before a disarm
  }
  // Configure every camera first (a refusal costs nothing), then start each stream together with
  // the thread that drains it: a stream started long before its reader fills its buffers and
  // drops frames (measured: 21 frames lost by the first of four Aravis cameras).
  std::size_t c = 0;
  try {
    for (c = 0; c < cameras_.size(); ++c) {
      cameras_[c]->Configure(config_.cameras[c].settings);
      // The whole feature state, read now (it takes a register read per feature), kept for the
      // metadata of every recording of this arm.
      std::map<std::string, std::string> state = cameras_[c]->FeatureState();
      std::lock_guard<std::mutex> lock(camera_state_[c]->mutex);
      camera_state_[c]->features = std::move(state);
      camera_state_[c]->exposure_us = config_.cameras[c].settings.exposure_us;
    }
    running_ = true;
    threads_.emplace_back([this] {
      NameThisThread("fr-assemble");
      AssemblerLoop();
    });
    for (c = 0; c < cameras_.size(); ++c) {
      cameras_[c]->Start(config_.buffers);
      threads_.emplace_back([this, c] {
        NameThisThread("fr-cam" + std::to_string(c));
        CameraLoop(static_cast<int>(c));
      });
    }
  } catch (const std::exception& e) {
    running_ = false;
    incoming_cv_.notify_all();
    for (auto& t : threads_) t.join();
    threads_.clear();
    for (std::size_t k = 0; k < c && k < cameras_.size(); ++k) cameras_[k]->Stop();
    Rethrow(e,
            "capture: camera '" + config_.cameras[c].name + "' (" + config_.cameras[c].id + "): ",
            Error::Kind::kIo);
  }
  if (config_.sync == SyncMode::kPtp && config_.action.enabled) {
    try {
      action_sender_ = std::make_unique<ActionCommandSender>(
          config_.action.destination, static_cast<std::uint16_t>(config_.action.port));
    } catch (const std::exception& e) {
      Stop();
      Rethrow(e, "capture: action commands: ", Error::Kind::kIo);
    }
  }
  if (config_.sync == SyncMode::kSoftwareTrigger ||
      (config_.sync == SyncMode::kHardwareTrigger && trigger_line_ != nullptr) || action_sender_)
    threads_.emplace_back([this] {
      NameThisThread("fr-trigger");
      TriggerLoop();
    });
  Log().info("capture: armed: {} camera(s) streaming, sync {}", cameras_.size(),
             ToString(config_.sync));
}

void CaptureDaemon::Stop() {
  std::lock_guard<std::recursive_mutex> command(command_mutex_);
  if (!running_.exchange(false)) return;
  Log().info("capture: disarming: cameras stop");
  incoming_cv_.notify_all();
  for (auto& t : threads_) t.join();
  threads_.clear();
  for (auto& c : cameras_) c->Stop();
  std::lock_guard<std::mutex> lock(state_mutex_);
  std::vector<FrameSet> ready;
  assembler_.Flush(&ready);
  Deliver(&ready);
  if (recorder_) {
    last_recorder_status_ = recorder_->Close(RecordingCounters(totals_at_recording_start_));
    recorder_.reset();
    LogClosed(recording_dir_, last_recorder_status_);
  }
}

void CaptureDaemon::LogClosed(const std::string& dir, const RecorderStatus& r) {
  if (r.limit_reached && r.sets_dropped == 0)
    Log().info("capture: {}: {} frame sets recorded: {}", dir, r.sets_recorded, r.error);
  else if (r.limit_reached)
    Log().warn("capture: {}: {} frame sets recorded, {} dropped (the disk fell behind): {}", dir,
               r.sets_recorded, r.sets_dropped, r.error);
  else if (r.error.empty())
    Log().info("capture: {}: {} frame sets recorded, {} dropped", dir, r.sets_recorded,
               r.sets_dropped);
  else
    Log().error("capture: {}: {} frame sets recorded, {} dropped; {}", dir, r.sets_recorded,
                r.sets_dropped, r.error);
}

void CaptureDaemon::CameraLoop(int camera) {
  Camera& cam = *cameras_[camera];
  CameraState& st = *camera_state_[camera];
  const std::int64_t timeout = 100'000'000;  // wake up at least 10 times a second to see Stop
  std::int64_t last_attempt = 0;
  bool was_connected = true;
  while (running_) {
    const bool connected = cam.connected();
    if (!connected && was_connected) {
      Log().warn("capture: camera {} ({}) disconnected", st.live.name, st.live.id);
      std::lock_guard<std::mutex> lock(st.mutex);
      ++st.live.disconnects;
    }
    if (connected && !was_connected)
      Log().info("capture: camera {} ({}) reconnected", st.live.name, st.live.id);
    was_connected = connected;
    if (!connected) {
      // A lost camera: try to bring it back about once a second; the others go on meanwhile.
      const std::int64_t t = clock_->MonotonicNs();
      if (t - last_attempt >= 1'000'000'000) {
        last_attempt = t;
        bool back = false;
        try {
          back = cam.Reconnect();
        } catch (const std::exception& e) {  // never out of this thread: the rig goes on
          Log().warn("capture: camera {} ({}): reconnecting: {}", st.live.name, st.live.id,
                     e.what());
        }
        // Back (or an optional camera here for the first time): its feature state, for the
        // metadata of the recordings from now on.
        std::map<std::string, std::string> state;
        if (back) {
          try {
            state = cam.FeatureState();
          } catch (const std::exception& e) {
            Log().warn("capture: camera {}: reading its features: {}", st.live.name, e.what());
          }
        }
        std::lock_guard<std::mutex> lock(st.mutex);
        ++st.live.reconnect_attempts;
        if (back) ++st.live.reconnects;
        if (!state.empty()) st.features = std::move(state);
      }
    }
    std::optional<Frame> f;
    try {
      f = cam.Pop(timeout);
    } catch (const std::exception& e) {
      // A driver or image-source failure: reported, and this camera keeps trying; the others
      // are not affected.
      bool changed;
      {
        std::lock_guard<std::mutex> lock(st.mutex);
        changed = st.live.error != e.what();
        st.live.error = e.what();
      }
      if (changed) Log().warn("capture: camera {}: {}", st.live.name, e.what());
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
      continue;
    }
    const std::int64_t now = clock_->MonotonicNs();
    {
      std::lock_guard<std::mutex> lock(st.mutex);
      st.live.connected = cam.connected();
      st.live.stream = cam.counters();
      if (f) {
        ++st.live.frames;
        st.recent.emplace_back(now, f->bytes());
        st.last_frame_ns = now;
        st.recent_frames.push_back(now);
        while (st.recent_frames.front() < now - 2 * TriggerGraceNs()) {
          st.recent_frames.pop_front();
          ++st.old_frames;
        }
      }
      while (!st.recent.empty() && st.recent.front().first < now - 1'000'000'000)
        st.recent.pop_front();
    }
    if (!f) continue;
    f->info.camera = camera;
    std::lock_guard<std::mutex> lock(incoming_mutex_);
    if (incoming_.size() >= incoming_capacity_) {
      ++incoming_dropped_;  // the assembler is behind: drop, count, never wait
      continue;
    }
    incoming_.push_back(std::move(*f));
    incoming_cv_.notify_one();
  }
}

std::int64_t CaptureDaemon::TriggerGraceNs() const {
  const auto period = static_cast<std::int64_t>(1e9 / config_.trigger_rate_hz);
  return std::max<std::int64_t>(3 * period, config_.set_timeout_ns + 100'000'000);
}

std::vector<std::uint64_t> CaptureDaemon::MissedTriggers(std::int64_t now) const {
  std::uint64_t due = 0;
  {
    std::lock_guard<std::mutex> lock(trigger_mutex_);
    due = old_triggers_;
    for (const std::int64_t t : recent_triggers_) due += t <= now - TriggerGraceNs();
  }
  // A trigger's frame comes after the exposure and the transfer: frames received up to that much
  // after the last counted trigger answer counted triggers.
  std::vector<std::uint64_t> missed;
  for (std::size_t c = 0; c < camera_state_.size(); ++c) {
    const CameraState& st = *camera_state_[c];
    std::lock_guard<std::mutex> lock(st.mutex);
    const std::int64_t latency = std::min<std::int64_t>(
        TriggerGraceNs() / 2, static_cast<std::int64_t>(st.exposure_us * 1e3) + 50'000'000);
    std::uint64_t got = st.old_frames;
    for (const std::int64_t t : st.recent_frames) got += t <= now - TriggerGraceNs() + latency;
    missed.push_back(due > got ? due - got : 0);
  }
  return missed;
}

void CaptureDaemon::TriggerLoop() {
  const auto period = static_cast<std::int64_t>(1e9 / config_.trigger_rate_hz);
  // A trigger sent at time t: kept timed while its frames may still come, then only counted.
  auto CountTrigger = [this](std::int64_t t) {
    std::lock_guard<std::mutex> lock(trigger_mutex_);
    recent_triggers_.push_back(t);
    while (!recent_triggers_.empty() && recent_triggers_.front() < t - 2 * TriggerGraceNs()) {
      recent_triggers_.pop_front();
      ++old_triggers_;
    }
  };
  std::int64_t next = clock_->MonotonicNs() + period;
  // Ids go on increasing across arms, so a frame left over from before can never match a new set.
  for (std::int64_t id = ++last_trigger_id_; running_; id = ++last_trigger_id_) {
    // Sleep in short steps so that Stop is seen quickly.
    while (running_ && clock_->MonotonicNs() < next)
      clock_->SleepUntil(std::min(next, clock_->MonotonicNs() + 50'000'000));
    if (!running_) break;
    const std::int64_t now = clock_->MonotonicNs();
    if (action_sender_) {
      // Scheduled on the PTP clock, lead_ms ahead, so that every camera fires at the same instant
      // however late the datagram reaches each of them.
      ActionCommand command;
      command.device_key = config_.action.device_key;
      command.group_key = config_.action.group_key;
      command.group_mask = config_.action.group_mask;
      command.action_time_ns =
          PtpNowNs() + static_cast<std::uint64_t>(config_.action.lead_ms * 1e6);
      try {
        action_sender_->Send(command);
        ++action_commands_;
      } catch (const std::exception& e) {
        std::lock_guard<std::mutex> lock(state_mutex_);
        last_error_ = e.what();
      }
    } else if (config_.sync == SyncMode::kHardwareTrigger && trigger_line_) {
      // The simulated trigger line stands for a hardware trigger generator, which never runs
      // late: a pulse carries its scheduled time even when this thread wakes late (the cameras
      // expose then and the frames wait in their buffers), and no slot is skipped.
      trigger_line_->Fire(id, next);
      CountTrigger(next);
      next += period;
      continue;
    } else {
      for (auto& c : cameras_) c->SoftwareTrigger(id);
    }
    CountTrigger(now);
    // Never two triggers closer than 3/4 of a period: after a late one (this thread was not
    // scheduled in time), the schedule restarts from it, and the lost slot is counted. A camera
    // would ignore a trigger that comes before it is ready, and its set would be lost.
    next += period;
    if (next - now < 3 * period / 4) {
      next = now + period;
      ++trigger_overruns_;
    }
  }
}

void CaptureDaemon::AssemblerLoop() {
  std::vector<Frame> batch;
  while (running_) {
    {
      std::unique_lock<std::mutex> lock(incoming_mutex_);
      incoming_cv_.wait_for(lock, std::chrono::milliseconds(20),
                            [&] { return !incoming_.empty() || !running_; });
      batch.assign(std::make_move_iterator(incoming_.begin()),
                   std::make_move_iterator(incoming_.end()));
      incoming_.clear();
    }
    std::vector<FrameSet> ready;
    const std::int64_t now = clock_->MonotonicNs();
    std::lock_guard<std::mutex> lock(state_mutex_);
    for (Frame& f : batch) assembler_.Add(std::move(f), now, &ready);
    batch.clear();
    assembler_.Poll(now, &ready);
    Deliver(&ready);
  }
}

void CaptureDaemon::Deliver(std::vector<FrameSet>* ready) {
  set_counters_ = assembler_.counters();
  for (FrameSet& set : *ready) {
    if (recorder_) {
      try {
        recorder_->Submit(set);
      } catch (const std::exception& e) {  // a malformed frame from a driver: never fatal
        ++rejected_sets_;
        last_error_ = e.what();
      }
    }
    std::uint64_t bytes = 0;
    for (const auto& f : set.frames)
      if (f) bytes += f->bytes();
    auto shared = std::make_shared<const FrameSet>(set);
    latest_ = shared;
    if (config_.pretrigger_seconds > 0) {
      ring_.push_back(std::move(set));
      ring_bytes_ += bytes;
      const std::int64_t window = static_cast<std::int64_t>(config_.pretrigger_seconds * 1e9);
      while (!ring_.empty() && (ring_bytes_ > config_.pretrigger_max_bytes ||
                                ring_.back().reference_ns - ring_.front().reference_ns > window)) {
        for (const auto& f : ring_.front().frames)
          if (f) ring_bytes_ -= f->bytes();
        ring_.pop_front();
      }
    }
  }
  ready->clear();
}

CaptureDaemon::TriggerTotals CaptureDaemon::CountTotals() const {
  TriggerTotals t;
  {
    std::lock_guard<std::mutex> lock(trigger_mutex_);
    t.triggers = old_triggers_ + recent_triggers_.size();
  }
  for (const auto& st : camera_state_) {
    std::lock_guard<std::mutex> lock(st->mutex);
    t.frames.push_back(st->old_frames + st->recent_frames.size());
  }
  return t;
}

std::map<std::string, std::string> CaptureDaemon::RecordingCounters(
    const TriggerTotals& at_start) const {
  std::map<std::string, std::string> out;
  if (config_.sync != SyncMode::kSoftwareTrigger && config_.sync != SyncMode::kHardwareTrigger &&
      !action_sender_)
    return out;
  const TriggerTotals now = CountTotals();
  const std::uint64_t sent = now.triggers - std::min(now.triggers, at_start.triggers);
  for (std::size_t c = 0; c < now.frames.size(); ++c) {
    const std::uint64_t before = c < at_start.frames.size() ? at_start.frames[c] : 0;
    const std::uint64_t got = now.frames[c] - std::min(now.frames[c], before);
    out["missed_triggers_" + config_.cameras[c].name] = std::to_string(sent > got ? sent - got : 0);
  }
  return out;
}

RecordingMetadata CaptureDaemon::Metadata() const {
  RecordingMetadata m;
  m.sync_mode = ToString(config_.sync);
  m.config_yaml = config_.source_yaml;
  m.started_realtime_ns = clock_->RealtimeNs();
  m.trigger_rate_hz = config_.sync == SyncMode::kFreeRun ? 0.0 : config_.trigger_rate_hz;
  for (std::size_t c = 0; c < cameras_.size(); ++c) {
    RecordingCamera rc;
    rc.name = config_.cameras[c].name;
    rc.description = cameras_[c]->description();
    rc.settings = cameras_[c]->settings();
    m.cameras.push_back(rc);
    std::lock_guard<std::mutex> lock(camera_state_[c]->mutex);
    for (const auto& [name, value] : camera_state_[c]->features)
      m.features[rc.name + "." + name] = value;
  }
  return m;
}

std::string CaptureDaemon::RecordingPath(const std::string& name) const {
  const bool safe =
      !name.empty() && name.size() <= 128 && name != "." && name != ".." &&
      std::all_of(name.begin(), name.end(), [](char ch) {
        return std::isalnum(static_cast<unsigned char>(ch)) || ch == '_' || ch == '-' || ch == '.';
      });
  if (!safe) {
    throw InputError("recording name '" + name.substr(0, 64) +
                     "': use letters, digits, '_', '-' and '.' only (at most 128), not "
                     "'.' or '..'");
  }
  return (fs::path(config_.data_dir) / name).string();
}

std::string CaptureDaemon::StartRecording(const std::string& name) {
  return BeginRecording(name, false);
}

std::string CaptureDaemon::TriggerEvent(const std::string& name) {
  return BeginRecording(name, true);
}

std::string CaptureDaemon::BeginRecording(const std::string& name, bool with_ring) {
  std::lock_guard<std::recursive_mutex> command(command_mutex_);
  const std::string dir = RecordingPath(name);
  if (!running_) throw InputError("capture: arm the cameras before recording");
  std::lock_guard<std::mutex> lock(state_mutex_);
  if (recorder_) throw InputError("capture: already recording into " + recording_dir_);
  RecordingMetadata metadata = Metadata();
  if (with_ring) {  // the trigger's moment, and where the ring ends and live sets begin
    metadata.event_name = name;
    metadata.event_realtime_ns = clock_->RealtimeNs();
    if (!ring_.empty())
      metadata.event_last_ring_set = static_cast<std::int64_t>(ring_.back().index);
  }
  recorder_ = std::make_unique<Recorder>(dir, metadata, config_.recorder);
  totals_at_recording_start_ = CountTotals();
  recording_dir_ = dir;
  recording_started_ns_ = clock_->MonotonicNs();
  // The ring is bounded by pretrigger_max_bytes and the queue was sized to hold it. A recording
  // of max_sets sets that the ring alone would fill takes the ring's newest: those next to the
  // event.
  if (!with_ring) {
    Log().info("capture: recording into {}", dir);
    return dir;
  }
  const std::size_t max_sets = config_.recorder.max_sets;
  const std::size_t skip = max_sets > 0 && ring_.size() > max_sets ? ring_.size() - max_sets : 0;
  for (std::size_t i = skip; i < ring_.size(); ++i) recorder_->Submit(ring_[i]);
  if (skip > 0)
    Log().info(
        "capture: event: recording into {}: the pre-trigger ring's newest {} sets make the {} the "
        "recording is limited to (max_recording_sets, --frames); its {} older sets are left out",
        dir, ring_.size() - skip, max_sets, skip);
  else
    Log().info("capture: event: recording into {}, starting with the pre-trigger ring ({} sets)",
               dir, ring_.size());
  return dir;
}

RecorderStatus CaptureDaemon::StopRecording() {
  std::lock_guard<std::recursive_mutex> command(command_mutex_);
  std::unique_ptr<Recorder> r;
  TriggerTotals baseline;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    if (!recorder_) throw InputError("capture: not recording");
    r = std::move(recorder_);
    baseline = totals_at_recording_start_;
  }
  const RecorderStatus st = r->Close(RecordingCounters(baseline));  // capture goes on meanwhile
  std::lock_guard<std::mutex> lock(state_mutex_);
  last_recorder_status_ = st;
  LogClosed(recording_dir_, st);
  return st;
}

CaptureStatus CaptureDaemon::status() const {
  CaptureStatus s;
  s.running = running_;
  const std::int64_t now = clock_->MonotonicNs();
  if (s.running) s.armed_s = (now - armed_ns_.load()) / 1e9;
  s.data_dir = config_.data_dir;
  s.min_free_bytes = config_.recorder.min_free_bytes;
  s.period_s = config_.trigger_rate_hz > 0 ? 1.0 / config_.trigger_rate_hz : 0.0;
  struct statvfs v;
  if (::statvfs(config_.data_dir.c_str(), &v) == 0)
    s.disk_free_bytes = static_cast<std::uint64_t>(v.f_bavail) * v.f_frsize;
  const std::vector<std::uint64_t> missed = MissedTriggers(now);
  for (const auto& st : camera_state_) {
    std::lock_guard<std::mutex> lock(st->mutex);
    CameraLiveStatus live = st->live;
    // A frame that arrived after `now` was read is 0 s old, not -1 (none yet): the silent-camera
    // watch took a negative age for a camera sending 20 frames a second as one that sent none.
    if (st->last_frame_ns >= 0)
      live.last_frame_age_s = std::max(0.0, (now - st->last_frame_ns) / 1e9);
    if (s.running) live.missed_triggers = missed[s.cameras.size()];
    if (st->recent.size() >= 2) {
      const double span = (st->recent.back().first - st->recent.front().first) / 1e9;
      std::uint64_t bytes = 0;
      for (const auto& r : st->recent) bytes += r.second;
      if (span > 0) {
        live.fps = (st->recent.size() - 1) / span;
        live.megabytes_per_s = bytes / span / 1048576.0;
      }
    }
    s.cameras.push_back(live);
  }
  {
    std::lock_guard<std::mutex> lock(incoming_mutex_);
    s.incoming_queued = incoming_.size();
    s.incoming_capacity = incoming_capacity_;
    s.incoming_dropped = incoming_dropped_;
  }
  std::lock_guard<std::mutex> lock(state_mutex_);
  s.sets = set_counters_;
  s.recording = recorder_ != nullptr;
  s.recording_dir = recording_dir_;
  if (s.recording) s.recording_s = (now - recording_started_ns_) / 1e9;
  s.recorder = recorder_ ? recorder_->status() : last_recorder_status_;
  s.ring_sets = ring_.size();
  s.trigger_overruns = trigger_overruns_;
  s.action_commands = action_commands_;
  s.rejected_sets = rejected_sets_;
  s.last_error = last_error_;
  s.ring_bytes = ring_bytes_;
  return s;
}

CameraSettings CaptureDaemon::camera_settings(int camera) const {
  std::lock_guard<std::mutex> lock(config_mutex_);
  return config_.cameras.at(static_cast<std::size_t>(camera)).settings;
}

void CaptureDaemon::SetCameraSetting(const std::string& camera, const std::string& key,
                                     const std::string& value) {
  std::lock_guard<std::recursive_mutex> command(command_mutex_);
  std::lock_guard<std::mutex> config_lock(config_mutex_);
  const bool live = running_;
  if (live && key != "exposure_us" && key != "gain_db")
    throw InputError("capture: disarm before changing " + key +
                     " (exposure_us and gain_db change while streaming)");
  int index = -1;
  for (std::size_t c = 0; c < config_.cameras.size(); ++c)
    if (config_.cameras[c].name == camera || std::to_string(c) == camera)
      index = static_cast<int>(c);
  if (index < 0) throw InputError("capture: no camera '" + camera + "'");
  CameraSettings s = config_.cameras[index].settings;
  const std::string where =
      "camera '" + config_.cameras[index].name + "': " + key + " '" + value + "'";
  auto number = [&] {
    char* end = nullptr;
    const double v = std::strtod(value.c_str(), &end);
    if (value.empty() || *end != '\0' || !std::isfinite(v))
      throw InputError(where + ": not a number");
    return v;
  };
  try {
    // Sizes in range before they become ints (a conversion out of range is undefined); the
    // range is the config file's (0: the sensor's size).
    auto size = [&] {
      const double v = number();
      if (!(v >= 0 && v <= 16384) || v != std::floor(v))
        throw InputError(where + ": must be a whole number in [0, 16384] (0: the sensor's size)");
      return static_cast<int>(v);
    };
    if (key == "width")
      s.width = size();
    else if (key == "height")
      s.height = size();
    else if (key == "pixel_format")
      s.SetPixelFormat(value);
    else if (key == "frame_rate_hz")
      s.frame_rate_hz = std::clamp(number(), 0.0, 2e6);  // Validate() below names the range
    else if (key == "exposure_us")
      s.exposure_us = number();
    else if (key == "gain_db")
      s.gain_db = number();
    else
      throw InputError(
          "unknown key (width, height, pixel_format, frame_rate_hz, "
          "exposure_us, gain_db)");
    s.Validate();
    CheckTriggeredFrameRate(config_, s, where);
  } catch (const InputError& e) {
    const std::string m = e.what();
    throw InputError(m.rfind(where, 0) == 0 ? m : where + ": " + m);
  }
  if (live) {
    // While streaming: from the next frame the camera exposes; each frame records its own values.
    if (!cameras_[index]->SetExposureGainLive(s.exposure_us, s.gain_db))
      throw InputError(where + ": this camera does not take it while streaming; disarm first");
    {
      std::lock_guard<std::mutex> lock(camera_state_[index]->mutex);
      camera_state_[index]->exposure_us = s.exposure_us;
    }
    config_.cameras[index].settings.exposure_us = s.exposure_us;
    config_.cameras[index].settings.gain_db = s.gain_db;
    Log().info("capture: camera {}: {} = {} (live, from the next frame; recorded per frame)",
               config_.cameras[index].name, key, value);
    return;
  }
  config_.cameras[index].settings = s;
  Log().info("capture: camera {}: {} = {} (applied when armed)", config_.cameras[index].name, key,
             value);
}

std::string CaptureDaemon::ApplyCameraSetting(const std::string& camera, const std::string& key,
                                              const std::string& value) {
  std::lock_guard<std::recursive_mutex> command(command_mutex_);
  try {
    SetCameraSetting(camera, key, value);
    return running_ ? "live, from the next frame" : "applied when armed";
  } catch (const InputError&) {
    if (!running_) throw;
    if (status().recording)
      throw InputError("capture: camera '" + camera + "': " + key +
                       " needs a re-arm, not done while recording (the take would lose frames)");
  }
  Stop();
  std::string outcome = "re-armed";
  try {
    SetCameraSetting(camera, key, value);
  } catch (...) {
    Start();
    throw;
  }
  Start();
  return outcome;
}

std::shared_ptr<const FrameSet> CaptureDaemon::LatestSet() const {
  std::lock_guard<std::mutex> lock(state_mutex_);
  return latest_;
}

}  // namespace flamerig
