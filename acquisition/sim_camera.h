// The simulated camera driver: deterministic stand-ins for a rig's cameras, used by the tests and
// by the built-in simulated rig (DESIGN section 3).
//
// Time comes from a Clock: the real one, or a ManualClock that a test (or a fast simulation)
// advances by hand, so that every frame's timing is reproducible. Cameras that share a
// SimTriggerBus receive the same trigger pulses (a hardware trigger line, or the daemon's software
// trigger broadcast); each responds after its own latency and jitter.
//
// Each camera models, from its seed: a free-run period with clock drift (ppm) and Gaussian jitter
// of its exposure start (the periods of cameras at one rate fall on one grid of the clock's time,
// multiples of the period, as those of a rig's cameras started by one command do: cameras started
// a few milliseconds apart, as a daemon starts them one by one, are in phase however slowly the
// host starts them; measured under ThreadSanitizer on a slow host, 7 ms a camera, which split
// every set of a 30 fps free run until 2026-11-30), a device clock offset, dropped frames
// (probability per frame: the frame id advances, no frame arrives), late frames (host receive
// delayed), incomplete frames, outages (disconnected from one time to another, or for good; as
// many as wanted), a device frame counter of a given width that wraps, and images from a
// pluggable source (a test pattern by default, or a callback). It sends its configured pixel format, or a 10- to 14-bit wire format (Mono12p,
// BayerRG12p, ...) as an Aravis camera's frames arrive from the driver: in the 16-bit format it
// unpacks into, only the words' high bits set, each frame saying what it was sent in
// (FrameInfo::sent_pfnc), so a 12-bit rig can be rehearsed end to end.
#ifndef FLAMERIG_ACQUISITION_SIM_CAMERA_H_
#define FLAMERIG_ACQUISITION_SIM_CAMERA_H_

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <random>
#include <string>
#include <vector>

#include "acquisition/camera.h"
#include "acquisition/clock.h"
#include "acquisition/frame_pool.h"

namespace flamerig {

// Trigger pulses shared by the cameras subscribed to it: pulse k at a time, with an id.
class SimTriggerBus : public TriggerLine {
 public:
  struct Pulse {
    std::int64_t trigger_id;
    std::int64_t monotonic_ns;
  };
  void Fire(std::int64_t trigger_id, std::int64_t monotonic_ns) override;
  // Pulses with index >= from (a subscriber keeps its own read position).
  std::vector<Pulse> Since(std::size_t from) const;
  std::size_t count() const;

 private:
  mutable std::mutex mutex_;
  std::vector<Pulse> pulses_;
};

// Fills a frame's bytes from its description: sets their size and every byte (the vector is a
// pooled buffer that may hold an earlier frame, frame_pool.h).
using ImageSource = std::function<void(const FrameInfo& info, std::vector<std::uint8_t>* bytes)>;
// A moving gradient with the camera index and frame id encoded in the first bytes (so a test can
// tell frames apart and check them bit-exact after recording; a camera sending a wire format
// keeps only each word's high bits of it, WireBitsOf).
ImageSource TestPatternSource();
// Replays a `flamerig simulate` dataset: frame k of the camera shows
// dataset_dir/frames/frame_NNNNNN/<camera>.png with N = k mod the number of frames (loaded once,
// here), converted to the frame's pixel format (Mono8/Mono16: Rec. 709 luma of the 8-bit sRGB
// values; RGB8 as is; Bayer: the matching colour of each site; 16-bit formats hold 8-bit values
// x 257). A deeper camera's dataset (16-bit PNGs of its codes, `simulate`'s radiometry with
// bit_depth > 8) replays its codes as they are, into Mono16 or a Bayer 16 format only (any
// other is an InputError naming the file); for a frame sent in a wire format (FrameInfo::sent_pfnc
// Mono12p, BayerRG12p, ...) in the words' high bits, as the driver unpacks them (a code deeper
// than the format is an InputError naming the file). Throws DataError naming
// the file when a frame is missing or unreadable; a frame asked for at another size than the
// images gets an error naming both sizes.
// The frames are what the camera sees at the replay's reference exposure x gain (ReplayExposure
// below: the one the dataset states; or else, in a capture config, the configured settings of
// the first camera replaying the same dataset; without one, the first frame's). `exposure`, when
// given, is a fresh object (its reference is replaced here, before any frame). A frame at other
// settings (a camera configured at another exposure time, or `ctl configure CAM exposure_us`,
// live) shows an 8-bit
// dataset's light times the factor, through its sRGB values and clipped at full scale, as a real
// camera's image darkens or brightens. A deeper camera's codes replay as they are, at the
// reference's settings only: a frame at others is an InputError naming the camera and both (and
// SimCamera::Configure refuses such settings).
// With ReplayContent::kCalibration frame k shows the k-th board view instead
// (dataset_dir/calibration/view_NNN/<camera>.png, k mod the number of views), and a dark frame
// where the camera did not see that view: a board waved in front of the rig.
enum class ReplayContent { kFire, kCalibration };
// Shared by a replaying sim camera and its source: the exposure x gain the dataset's frames show
// (`reference`, 0: the first frame's), and whether the replay's light can follow another (an
// 8-bit dataset's; false for a deeper camera's codes, whose black level the camera does not know:
// such a camera refuses a live change, and its Configure refuses settings other than the
// reference's). The reference is shared by the cameras of a capture config that replay the same
// dataset, and the first of them sets it (`sets_reference`): to its configured settings when the
// config is read, and again at its Configure. So a rig whose cameras are configured at different
// exposure times records each one's light at its own against the first camera's, which is what
// `flamerig run` takes the take's exposure to be (pipeline/frame_source.h's
// StartExposureOfCamera: the recording's first camera's; a rig whose first camera is not a
// replay of the dataset has its reference elsewhere).
// A dataset that states its exposure in time (its dataset.yaml's `dataset: {exposure,
// exposure_unit_us}`, as `flamerig simulate` writes: pipeline/simulate.h's SimExposureUnitUs)
// has a reference of its own for its fire frames, exposure x exposure_unit_us microseconds at
// 0 dB, which no camera sets: every camera records its light at its own settings against that,
// as a real camera records a fire, so that a rig that knows its exposure unit (a radiometric
// calibration's) fits the take at the exposure its cameras' settings give. Board views
// (kCalibration) keep the first camera's: their light is not the fire's. A dataset.yaml whose
// exposure or unit is not a finite number > 0 is an InputError naming it.
struct ReplayExposure {
  std::shared_ptr<std::atomic<double>> reference = std::make_shared<std::atomic<double>>(0.0);
  bool sets_reference = true;
  bool dataset_reference = false;  // the dataset's own, stated in its dataset.yaml
  std::string dataset_dir;         // the dataset replayed (DatasetReplaySource sets it)
  std::atomic<bool> scalable{true};
};
// What a `flamerig simulate` dataset's DATASET/dataset.yaml states about the exposure of its fire
// frames, the one reader of it (the replay above; pipeline/run.h's ResolveExposure): `exposure`,
// the fit's exposure of its images (0 when it states none), and `unit_us`, `exposure_unit_us`, the
// exposure time at 0 dB that exposure 1 stands for (0 when it states none). `path` names the file.
// A missing file, or one without a `dataset` map, states nothing; a key that is absent or empty
// states nothing. InputError naming the file (and the key) when the file is not YAML, `dataset`
// is not a map, a stated value is not a finite number > 0, a unit comes without an exposure, or
// their product (the frames' exposure time) overflows.
struct DatasetExposureStatement {
  std::string path;
  double exposure = 0;
  double unit_us = 0;
  // exposure x unit_us microseconds at 0 dB: the replay's reference (ReplayExposure); 0 when
  // the dataset states no unit.
  double reference_us() const { return unit_us > 0 ? exposure * unit_us : 0.0; }
};
DatasetExposureStatement ReadDatasetExposure(const std::string& dataset_dir);

ImageSource DatasetReplaySource(const std::string& dataset_dir, const std::string& camera,
                                ReplayContent content = ReplayContent::kFire,
                                std::shared_ptr<ReplayExposure> exposure = nullptr);

// The camera is gone (no frames, connected() false) from down_ns until up_ns; up_ns = -1: for good.
struct SimOutage {
  std::int64_t down_ns = 0;
  std::int64_t up_ns = -1;
};

// The index of the first outage that starts before 0, ends before it starts, or starts before the
// previous one ends (or after one that lasts for good); -1 when the list is valid.
int FirstInvalidOutage(const std::vector<SimOutage>& outages);

struct SimCameraOptions {
  std::string id = "sim0";
  int camera_index = 0;  // written into FrameInfo::camera
  std::uint64_t seed = 1;
  double drift_ppm = 0;                      // device clock rate error
  std::int64_t device_offset_ns = 0;         // device clock minus host clock at 0
  std::int64_t jitter_ns = 0;                // standard deviation of each exposure start
  std::int64_t trigger_latency_ns = 50'000;  // from a pulse to the exposure start
  std::int64_t transfer_ns = 2'000'000;      // from exposure end to host receive
  double drop_probability = 0;               // frame produced but never delivered
  double miss_trigger_probability = 0;       // a trigger ignored: no exposure, no frame id
  std::string plugged;  // a file standing for the cable: the camera opens only while it exists
  double late_probability = 0;  // delivered `late_ns` later than normal
  std::int64_t late_ns = 100'000'000;
  double incomplete_probability = 0;  // delivered with status incomplete
  std::vector<SimOutage> outages;     // monotonic times, in order, not overlapping
  int frame_id_bits = 16;             // device counter width (GigE Vision: 16)
  std::uint64_t first_frame_id = 1;
  ImageSource source;  // empty = TestPatternSource()
  // A dataset replay's (DatasetReplaySource's): Configure sets its reference; a live change is
  // refused where its light cannot follow. Null for other sources.
  std::shared_ptr<ReplayExposure> replay_exposure;
};

class SimCamera : public Camera {
 public:
  // `bus` may be null (free-run only). The clock and bus must outlive the camera.
  SimCamera(const SimCameraOptions& options, Clock* clock, SimTriggerBus* bus);

  CameraDescription description() const override;
  void Configure(const CameraSettings& settings) override;
  CameraSettings settings() const override;
  bool SetExposureGainLive(double exposure_us, double gain_db) override;
  void Start(int buffers) override;
  void Stop() override;
  std::optional<Frame> Pop(std::int64_t timeout_ns) override;
  void SoftwareTrigger(std::int64_t trigger_id) override;
  bool connected() const override;
  StreamCounters counters() const override { return counters_; }
  // Ground truth for tests: triggers this camera took no exposure for (lost on the way, or before
  // the sensor was ready), since it was made. Counted when the camera looks at its triggers (in
  // Pop), so it lags a pulse by at most one Pop timeout.
  std::uint64_t triggers_ignored() const { return triggers_ignored_; }

 private:
  struct Pending {
    FrameInfo info;
    std::int64_t deliver_ns;  // host receive time
    bool dropped;
  };
  // Produces the frames whose exposure started by `until_ns` into pending_ (ordered by delivery).
  void Produce(std::int64_t until_ns);
  void AddExposure(std::int64_t start_ns, std::int64_t trigger_id);
  bool Gone(std::int64_t monotonic_ns) const;  // inside an outage

  SimCameraOptions options_;
  Clock* clock_;
  SimTriggerBus* bus_;
  // The bytes of one frame at the configured size and format.
  std::size_t FrameBytes() const {
    return std::size_t(std::max(settings_.width, 0)) * std::max(settings_.height, 0) *
           BytesPerPixel(settings_.pixel_format);
  }
  CameraSettings settings_;
  // A wire format the settings name (Mono12p, ...): its PFNC code and depth; 0 for none.
  std::uint32_t wire_pfnc_ = 0;
  int wire_bits_ = 0;
  std::atomic<double> live_exposure_us_{0}, live_gain_db_{0};  // what the next exposure uses
  bool running_ = false;
  std::mt19937_64 rng_;
  std::int64_t started_ns_ = 0;
  std::int64_t free_run_first_ns_ = 0;  // the first free-run exposure: on the period's grid
  std::uint64_t produced_ = 0;          // exposures so far
  std::atomic<std::uint64_t> triggers_ignored_{0};
  std::size_t bus_position_ = 0;
  std::uint64_t device_counter_ = 0;
  std::int64_t last_exposure_ns_ = 0;
  std::deque<Pending> pending_;
  std::deque<std::int64_t> software_triggers_;  // ids queued by SoftwareTrigger
  std::mutex trigger_mutex_;
  FrameIdUnwrapper unwrapper_;
  std::int64_t last_timestamp_ns_ = -1;
  StreamCounters counters_;
  ImageSource source_;
  FrameBufferPool pool_{0, 0};
};

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_SIM_CAMERA_H_
