// The camera driver interface (DESIGN section 3), layered after Aravis: discovery -> camera (its
// controls) -> stream (a preallocated buffer pool) -> frames (frame.h).
//
// A Camera is configured, started with a number of buffers, and then delivers frames through Pop()
// in the order the device produced them. Drivers (camera_drivers.h): `sim` (sim_camera.h,
// deterministic, for tests and the simulated rig), `aravis` (GigE Vision and USB3 Vision) and
// `v4l2`. A camera is used from one thread at a time
// (the daemon gives each camera its own thread) except SoftwareTrigger(), which any thread may call.
#ifndef FLAMERIG_ACQUISITION_CAMERA_H_
#define FLAMERIG_ACQUISITION_CAMERA_H_

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "acquisition/frame.h"

namespace flamerig {

struct CameraDescription {
  std::string driver;  // "sim", "aravis", "v4l2"
  std::string id;      // serial number or device path: what a config names the camera by
  std::string vendor, model, address;
  std::string serial;  // the device's serial number, when it has one
};

// kAction: a GigE Vision action command (acquisition/gige_action.h), scheduled on the PTP clock.
enum class TriggerMode { kFreeRun, kSoftware, kHardware, kAction };
const char* ToString(TriggerMode mode);
// "free-run" | "software" | "hardware" | "action"
TriggerMode TriggerModeFromName(const std::string& name);

struct CameraSettings {
  // 0: the sensor's full size less the offset (aravis), the device's current size (v4l2), 640x480
  // (sim). Configure() turns 0 into the size the camera took; settings() reports that.
  int width = 640, height = 480;
  int offset_x = 0, offset_y = 0;                  // the region of interest's corner on the sensor
  PixelFormat pixel_format = PixelFormat::kMono8;  // as stored
  // The camera's own format when it sends one of the WireFormats (frame.h): then pixel_format is
  // what it unpacks into (Mono16, or the layout's Bayer 16) and the driver unpacks every frame.
  // "" = it sends pixel_format. Aravis cameras, and sim ones rehearsing them (sim_camera.h);
  // V4L2 refuses one.
  std::string wire_format;
  double frame_rate_hz = 30;  // free-run rate; the maximum rate when triggered
  double exposure_us = 10000;
  double gain_db = 0;
  TriggerMode trigger = TriggerMode::kFreeRun;
  std::string trigger_source = "Line0";  // hardware trigger input
  int packet_size = 0;                   // GigE Vision packet size, 0 = the device's
  // kAction: the camera fires on action commands carrying these (SFNC ActionDeviceKey,
  // ActionGroupKey, ActionGroupMask).
  std::uint32_t action_device_key = 0, action_group_key = 1, action_group_mask = 0xffffffff;
  // sync: ptp. The camera's PTP clock must be on and locked (slave or master) before it streams:
  // its timestamps are what frame sets are matched by. Drivers without PTP refuse it, except the
  // sim driver, whose cameras share one clock.
  bool ptp = false;
  // Any other camera feature by name, written in this order after the ones above (`features:
  // {Name: value}` in a capture config): a GenICam feature (aravis) or a V4L2 control by v4l2-ctl's
  // name (v4l2, e.g. gamma, white_balance_automatic). The sim driver refuses them.
  std::vector<std::pair<std::string, std::string>> features;
  void Validate() const;  // throws InputError naming the field
  // A `pixel_format` from a config: a stored format, or a wire format (stored as Mono16). Throws
  // InputError listing both.
  void SetPixelFormat(const std::string& name);
  std::string pixel_format_name() const;  // the wire format if any, else the stored one
};

struct StreamCounters {
  std::uint64_t delivered = 0;        // frames returned by Pop
  std::uint64_t incomplete = 0;       // of those, with status other than ok
  std::uint64_t missing_by_id = 0;    // frame-id gaps (wrap-aware)
  std::uint64_t missing_by_time = 0;  // gaps of more than 1.5 periods between timestamps (free-run)
  std::uint64_t underruns = 0;        // frames the device had no free buffer for
  std::uint64_t timeouts = 0;         // Pop calls that returned nothing
  // Pixel buffers the driver had to allocate for frames (frame_pool.h): its buffers at the start,
  // then none while its frames come back to it as fast as they arrive.
  std::uint64_t buffers_allocated = 0;
};

class Camera {
 public:
  virtual ~Camera() = default;
  virtual CameraDescription description() const = 0;
  // Applies settings while stopped; throws InputError naming the camera and the feature
  // the device refuses.
  virtual void Configure(const CameraSettings& settings) = 0;
  virtual CameraSettings settings() const = 0;
  virtual void Start(int buffers) = 0;
  virtual void Stop() = 0;
  // The next frame, waiting at most timeout_ns on the camera's clock; nullopt on timeout or when
  // the camera is gone (then connected() is false).
  virtual std::optional<Frame> Pop(std::int64_t timeout_ns) = 0;
  virtual void SoftwareTrigger(std::int64_t trigger_id) = 0;
  virtual bool connected() const = 0;
  // After connected() turned false: tries once to open the device again and restore its settings
  // and stream; true when it is back. The daemon calls it about once a second.
  virtual bool Reconnect() { return connected(); }
  virtual StreamCounters counters() const = 0;
  // Changes exposure and gain while streaming, from the next frame the camera exposes (each
  // frame's FrameInfo carries the values it was taken with); callable from any thread. False when
  // this camera cannot (then it must be stopped to be configured). Aravis takes a frame's values
  // from its chunk data where the camera sends them (ChunkExposureTime, ChunkGain), else Aravis
  // and V4L2 from the values in force when its exposure began, by its timestamp (live_exposure.h):
  // a frame exposed before the change and delivered after it keeps the old values; a camera that
  // applies a change a frame or two late is labelled early by as much.
  virtual bool SetExposureGainLive(double exposure_us, double gain_db) { return false; }
  // Every readable feature of the device and its value as text (GenICam cameras), for the
  // recording's metadata; empty for cameras without such a tree.
  virtual std::map<std::string, std::string> FeatureState() const { return {}; }
};

// A trigger generator that the daemon drives in hardware-trigger mode: a pulse on the line wired
// to every camera's trigger input at the given time. The simulated rig's line is SimTriggerBus
// (sim_camera.h); a real generator (a microcontroller, a camera's output line) is another.
// Fire may be called from the daemon's trigger thread while cameras read the line.
class TriggerLine {
 public:
  virtual ~TriggerLine() = default;
  virtual void Fire(std::int64_t trigger_id, std::int64_t monotonic_ns) = 0;
};

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_CAMERA_H_
