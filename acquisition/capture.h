// The capture daemon (DESIGN section 3): cameras -> per-camera threads -> the frame-set assembler ->
// the recorder, the pre-trigger ring and the live preview.
//
//   camera thread (one per camera)   Pop() with a timeout, so a dead camera never blocks anything;
//                                    pushes frames into a bounded incoming queue (full: the frame is
//                                    dropped and counted) and keeps that camera's live metrics; a
//                                    camera that lost its connection is reopened about once a second
//                                    (Camera::Reconnect) and the attempts are reported.
//   trigger thread                   software-trigger mode: broadcasts SoftwareTrigger(id) to every
//                                    camera at `trigger_rate_hz`; simulated hardware-trigger mode:
//                                    fires the simulated trigger line (the stand-in for a trigger
//                                    generator wired to the cameras).
//   assembler thread                 groups frames into sets (by trigger id, or by timestamp in
//                                    free-run and PTP modes), and hands every set to the recorder
//                                    when recording, to the pre-trigger ring, and to the preview
//                                    slot (a pointer swap: the preview never copies or waits).
//
// Recording names are single path components ([A-Za-z0-9._-], not "." or ".."): a recording is
// always created inside `data_dir`, whatever a control client asks. An event (ignition) starts a
// recording that begins with the ring's last `pretrigger_seconds` and goes on live until stopped.
//
// Configuration (YAML, `flamerig capture --config rig.yaml`), every key optional except cameras:
//   data_dir: recordings          # where recordings are created (relative paths here, in
//                                 # `control` and in a sim camera's `replay` are relative to
//                                 # the config file)
//   sync: software-trigger        # hardware-trigger | software-trigger | free-run | ptp
//   trigger_rate_hz: 30
//   match_tolerance_ms: 13        # timestamp matching; default 0.4 / trigger_rate_hz
//   set_timeout_ms: 200           # how long a frame set waits for a missing camera
//   buffers: 8                    # per camera stream
//   pretrigger_seconds: 2
//   pretrigger_max_mb: 256
//   queue_mb: 512                 # recorder queue bound (with a ring: at least pretrigger_max_mb + 64)
//   min_free_mb: 64
//   sync_interval_s: 1
//   max_recording_mb: 0           # a recording stops cleanly at this size; 0: no limit
//   max_recording_sets: 0         # ... after this many frame sets (`capture --frames`); 0: no limit
//   control: unix:recordings/control.sock   # or tcp:127.0.0.1:PORT (loopback unless `allow_remote`)
//   live_view: 127.0.0.1:8420     # the browser live view (acquisition/live_view.h); off when absent
//   live_view_allow_remote: false # true: any address, with a token (live_view_token, or random)
//   action:                       # sync: ptp only: trigger aravis cameras by scheduled GigE Vision
//     device_key: 0               # action commands, trigger_rate_hz times a second, each to fire
//     group_key: 1                # lead_ms ahead on the PTP clock (acquisition/gige_action.h);
//     group_mask: 0xffffffff      # without it, ptp is free-run matched by device timestamps
//     lead_ms: 20
//     destination: 255.255.255.255   # the cameras' broadcast address (or one camera's)
//     port: 3956
//   cameras:
//     - name: cam0                 # unique; A-Z a-z 0-9 _ - . (it names the camera's files)
//       driver: sim                # sim | aravis | v4l2 (acquisition/camera_drivers.h)
//       id: SIM0                   # serial, address or device path; one camera per id
//       required: true             # false: start without it when it cannot be opened, and take
//                                  # it in when it can (tried about once a second)
//       width: 640
//       height: 480
//       pixel_format: Mono8           # Mono8, Mono16, RGB8, BayerRG8/GR8/GB8/BG8,
//                                     # BayerRG16/GR16/GB16/BG16; aravis (and sim, which
//                                     # rehearses them) also Mono10, Mono12,
//                                     # Mono14, Mono10Packed, Mono12Packed, Mono10p, Mono12p,
//                                     # stored as Mono16, and BayerRG10, BayerRG12,
//                                     # BayerRG10Packed, BayerRG12Packed, BayerRG10p, BayerRG12p
//                                     # (and GR, GB, BG), stored as BayerRG16 (and GR16, ...),
//                                     # the value in the high bits (value << (16 - bits))
//       frame_rate_hz: 30
//       exposure_us: 10000
//       gain_db: 0
//       trigger_source: Line0
//       packet_size: 0
//       sim: {drop_probability: 0, miss_trigger_probability: 0, jitter_us: 0, drift_ppm: 0,
//             late_probability: 0,
//             incomplete_probability: 0, disconnect_at_s: -1, reconnect_at_s: -1, seed: 1,
//             outages: [[12, 14.5], [30, -1]],  # more outages: [down_s, up_s], -1 = for good
//             replay: DATASET,      # show a `flamerig simulate` dataset's images of this camera
//                                   # (name), path relative to this file; else a test pattern;
//                                   # as they are at the exposure time its dataset.yaml states
//                                   # (10000 us, 0 dB), or else at the settings of the config's
//                                   # first camera replaying DATASET; scaled at others
//                                   # (sim_camera.h)
//             replay_content: fire} # fire (its frames) or calibration (its board views)
#ifndef FLAMERIG_ACQUISITION_CAPTURE_H_
#define FLAMERIG_ACQUISITION_CAPTURE_H_

#include <atomic>
#include <condition_variable>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "acquisition/camera.h"
#include "acquisition/camera_drivers.h"
#include "acquisition/frame_set.h"
#include "acquisition/gige_action.h"
#include "acquisition/recording.h"
#include "acquisition/sim_camera.h"

namespace flamerig {

enum class SyncMode { kHardwareTrigger, kSoftwareTrigger, kFreeRun, kPtp };
const char* ToString(SyncMode mode);
SyncMode SyncModeFromName(const std::string& name);  // throws InputError

struct ActionConfig {
  bool enabled = false;
  std::uint32_t device_key = 0, group_key = 1, group_mask = 0xffffffff;
  double lead_ms = 20;  // how far ahead of now (PTP time) each action is scheduled
  std::string destination = "255.255.255.255";
  int port = 3956;
};

struct CaptureConfig {
  std::string data_dir = "recordings";
  SyncMode sync = SyncMode::kSoftwareTrigger;
  double trigger_rate_hz = 30;
  std::int64_t match_tolerance_ns = 13'333'333;  // 0.4 of a period at 30 Hz
  std::int64_t set_timeout_ns = 200'000'000;
  int buffers = 8;
  double pretrigger_seconds = 2;
  std::uint64_t pretrigger_max_bytes = 256ull << 20;
  RecorderOptions recorder;
  std::string control;  // empty: unix:<data_dir>/control.sock
  bool allow_remote = false;
  std::string
      live_view;  // HOST:PORT of the browser live view (acquisition/live_view.h); empty: off
  bool live_view_allow_remote = false;
  std::string live_view_token;  // required when remote (made at random when empty)
  ActionConfig action;
  std::vector<CaptureCameraConfig> cameras;
  std::string source_yaml;  // the text it was parsed from (kept in every recording)

  // Throws InputError naming the file, the key and what is wrong.
  static CaptureConfig Load(const std::string& path);
  static CaptureConfig Parse(const std::string& yaml_text, const std::string& where);
  FrameSetOptions AssemblerOptions() const;
};

// The cameras of a config, each opened by its driver (camera_drivers.h): sim cameras share the
// context's clock and simulated trigger line; aravis and v4l2 cameras are opened by id. Throws
// IoError naming the camera that cannot be opened.
std::vector<std::unique_ptr<Camera>> MakeCameras(const CaptureConfig& config,
                                                 const DriverContext& context);

struct CameraLiveStatus {
  std::string name, id;
  bool connected = false;
  double fps = 0;  // over the last second
  double megabytes_per_s = 0;
  std::uint64_t frames = 0;
  std::uint64_t disconnects = 0;  // times it was seen gone after being connected
  std::uint64_t reconnect_attempts = 0, reconnects = 0;  // by the daemon (a camera may also come
                                                         // back by itself)
  std::string error;             // the last error of its driver or image source, if any
  StreamCounters stream;         // the driver's counters
  double last_frame_age_s = -1;  // since its last frame arrived; -1: none yet
  // Triggers (software, the simulated line, action commands) sent since the arm whose frame has
  // not come: triggers older than the grace time (3 periods, at least set_timeout_ms + 100 ms)
  // minus frames received. A lower bound (frames of later triggers count too), and 0 in free-run.
  std::uint64_t missed_triggers = 0;
};

struct CaptureStatus {
  bool running = false;
  bool recording = false;
  std::string recording_dir;
  std::vector<CameraLiveStatus> cameras;
  FrameSetCounters sets;
  RecorderStatus recorder;  // of the current (or last) recording
  std::size_t incoming_queued = 0, incoming_capacity = 0;
  std::uint64_t incoming_dropped = 0;  // frames the assembler could not take in time
  std::uint64_t trigger_overruns = 0;  // trigger slots skipped because the trigger thread was late
  std::uint64_t action_commands = 0;   // GigE Vision action commands sent (sync: ptp, action)
  std::uint64_t rejected_sets = 0;     // sets the recorder refused as malformed (see last_error)
  std::string last_error;
  std::size_t ring_sets = 0;
  std::uint64_t ring_bytes = 0;
  double armed_s = 0;      // since the cameras were armed (0 when not)
  double recording_s = 0;  // since the current recording started (0 when not recording)
  std::string data_dir;
  std::uint64_t disk_free_bytes = 0;  // on data_dir's filesystem, for a user (f_bavail)
  std::uint64_t min_free_bytes = 0;   // min_free_mb: a recording stops there
  double period_s = 0;                // of the trigger (0 in free-run without a rate)

  // Every field, for scripts: `ctl status yaml` (the old form) and `ctl --json status`.
  std::string ToYaml() const;
  std::string ToJson() const;
  // For people (`ctl status`): the state with its elapsed time, the disk with the time left at
  // the cameras' current rate, the frame sets, and a table of cameras with units; a camera whose
  // last frame is more than 3 periods (at least 1 s) old shows "no frames for N s" whatever its
  // driver says of its connection.
  std::string ToTable() const;
  // Seconds of recording left at the cameras' current data rate before min_free_mb stops it;
  // -1 when no camera is sending.
  double SecondsLeft() const;
};

class CaptureDaemon {
 public:
  // `clock` and `bus` (may be null) must outlive the daemon; they are the ones the cameras use.
  CaptureDaemon(const CaptureConfig& config, std::vector<std::unique_ptr<Camera>> cameras,
                Clock* clock, TriggerLine* trigger_line);
  ~CaptureDaemon();  // Stop()

  // Configures every camera (a refusal names the camera), starts the streams and the threads.
  void Start();
  // Stops a recording in progress (closing it cleanly), then the threads and the streams.
  void Stop();

  // Starts recording every frame set into data_dir/name. Throws InputError for a name
  // that is not a single safe path component, when not armed or already recording, and
  // RecordingError when it exists. Returns the recording's directory. Logged (core/log.h), as
  // are arming, disarming, the end of a recording, settings and camera disconnects.
  std::string StartRecording(const std::string& name);
  // Closes the recording; its final status (the counters written into its metadata). Throws
  // InputError when not recording.
  RecorderStatus StopRecording();
  // An event (ignition): a recording that starts with the pre-trigger ring and continues live.
  std::string TriggerEvent(const std::string& name);

  bool running() const { return running_; }
  // Changes one setting of one camera (by name or index). Disarmed: any of width, height,
  // pixel_format, frame_rate_hz, exposure_us, gain_db, applied at the next Start. Armed (even
  // recording): exposure_us and gain_db, from the next frame the camera exposes, when its driver
  // can (Camera::SetExposureGainLive; every frame records the values it was taken with). Throws
  // InputError naming the camera, key and value.
  void SetCameraSetting(const std::string& camera, const std::string& key,
                        const std::string& value);

  // What the live view's Apply does: SetCameraSetting, live when it can; otherwise, armed and not
  // recording, disarm, configure and arm again as one command. Returns what happened ("live, from
  // the next frame", "applied when armed", "re-armed"); InputError when refused.
  std::string ApplyCameraSetting(const std::string& camera, const std::string& key,
                                 const std::string& value);

  CaptureStatus status() const;
  // The latest frame set (shared pixels, no copy); empty before the first.
  std::shared_ptr<const FrameSet> LatestSet() const;
  const CaptureConfig& config() const { return config_; }
  // Camera `camera`'s settings as configured now: a copy taken under the lock SetCameraSetting
  // writes under, for readers on other threads (the live view, `ctl preview`). std::out_of_range
  // for a camera the rig does not have.
  CameraSettings camera_settings(int camera) const;

 private:
  struct CameraState;
  void CameraLoop(int camera);
  void TriggerLoop();
  void AssemblerLoop();
  void Deliver(std::vector<FrameSet>* ready);  // holds state_mutex_
  RecordingMetadata Metadata() const;
  // Triggers sent and each camera's frames received since the arm, exact running totals.
  struct TriggerTotals {
    std::uint64_t triggers = 0;
    std::vector<std::uint64_t> frames;  // per camera
  };
  TriggerTotals CountTotals() const;
  // Written into a closing recording's metadata: each camera's missed triggers while it recorded,
  // the triggers sent minus the frames received between the start and now. Frames on their way
  // at the start (answering earlier triggers) and at the stop (not counted) cancel, so the count
  // is off by at most the frames in flight at one moment, with no lag.
  std::map<std::string, std::string> RecordingCounters(const TriggerTotals& at_start) const;
  std::string BeginRecording(const std::string& name, bool with_ring);
  std::string RecordingPath(const std::string& name) const;

  CaptureConfig config_;
  std::vector<std::unique_ptr<Camera>> cameras_;
  Clock* clock_;
  TriggerLine* trigger_line_;
  static void LogClosed(const std::string& dir, const RecorderStatus& r);
  std::vector<std::unique_ptr<CameraState>> camera_state_;
  std::atomic<bool> running_{false};
  std::atomic<std::int64_t> armed_ns_{0};  // clock_'s monotonic time of the last Start()
  std::int64_t recording_started_ns_ = 0;  // guarded by state_mutex_
  std::atomic<std::uint64_t> trigger_overruns_{0};
  std::atomic<std::uint64_t> action_commands_{0};
  std::unique_ptr<ActionCommandSender> action_sender_;  // sync: ptp with action commands
  std::int64_t last_trigger_id_ = 0;                    // used by the trigger thread only
  // Triggers sent since the arm: those older than the grace time counted, the recent ones timed.
  mutable std::mutex trigger_mutex_;
  mutable std::mutex config_mutex_;  // SetCameraSetting's writes to config_
  // Commands (arm, disarm, start, stop, event, configure) one at a time: the control socket and
  // the live view's server threads may send them at once.
  std::recursive_mutex command_mutex_;
  std::uint64_t old_triggers_ = 0;
  std::deque<std::int64_t> recent_triggers_;
  std::int64_t TriggerGraceNs() const;
  std::vector<std::uint64_t> MissedTriggers(std::int64_t now) const;  // per camera
  TriggerTotals totals_at_recording_start_;                           // guarded by state_mutex_

  // camera threads -> assembler
  mutable std::mutex incoming_mutex_;
  std::condition_variable incoming_cv_;
  std::deque<Frame> incoming_;
  std::size_t incoming_capacity_ = 0;
  std::uint64_t incoming_dropped_ = 0;

  // assembler, recorder, ring, preview
  mutable std::mutex state_mutex_;
  FrameSetAssembler assembler_;
  FrameSetCounters set_counters_;
  std::unique_ptr<Recorder> recorder_;
  std::string recording_dir_;
  RecorderStatus last_recorder_status_;
  std::deque<FrameSet> ring_;
  std::uint64_t ring_bytes_ = 0;
  std::shared_ptr<const FrameSet> latest_;
  std::uint64_t rejected_sets_ = 0;
  std::string last_error_;

  std::vector<std::thread> threads_;
};

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_CAPTURE_H_
