// The `aravis` driver: GigE Vision and USB3 Vision cameras through libaravis 0.8 (DESIGN section 3,
// ../shared/notes/aravis.md).
//
// Discovery lists what Aravis sees. A camera is opened by its Aravis device id, its serial number,
// its user id (DeviceUserID), or, for GigE Vision, by its IPv4 address (opened directly with arv_gv_device_new, so that a host
// with several interfaces never picks the wrong one). Configure() writes the standard features:
// the region (OffsetX/OffsetY, Width/Height; a width or height of 0 takes the whole sensor less the
// offset), PixelFormat, AcquisitionFrameRate (free-run), exposure (ExposureTime, or
// ExposureTimeAbs on older GigE cameras), gain (Gain, or GainRaw), trigger (FrameStart trigger
// on the given line for hardware trigger, Software for software trigger, off for free-run) and the
// GigE packet size, then any feature the config names (`features: {Name: value}`); a refusal
// names the camera and the feature. With sync: ptp the camera's PTP clock is switched on and must
// report Slave or Master within 10 s. FeatureState() reads every feature of the device's GenICam
// tree, for the recording's metadata. Start() creates the stream with a
// fixed 4 MiB socket buffer and packet resend off (GigE), pushes the buffers and starts
// acquisition. Pop() returns a frame whose bytes are copied out of the Aravis buffer, which goes
// straight back to the stream; buffer statuses map to FrameStatus; the 16-bit GigE frame counter
// is unwrapped; the device timestamp and Aravis' system timestamp are kept. When the device stops
// answering (the `control-lost` signal, or frames stop arriving), connected() turns false.
//
// Thread safety: one thread calls Pop (the daemon's camera thread); SoftwareTrigger may be called
// from another (Aravis serialises device access).
#ifndef FLAMERIG_ACQUISITION_ARAVIS_CAMERA_H_
#define FLAMERIG_ACQUISITION_ARAVIS_CAMERA_H_

#include <atomic>
#include <memory>
#include <string>
#include <vector>

#include "acquisition/camera.h"
#include "acquisition/clock.h"
#include "acquisition/frame_pool.h"
#include "acquisition/live_exposure.h"

namespace flamerig {

// The cameras Aravis finds on every interface it is allowed to use.
std::vector<CameraDescription> DiscoverAravisCameras();

// Enables Aravis' in-process "Fake" interface (for tests and demos); off by default.
void EnableAravisFakeInterface();

class AravisCamera : public Camera {
 public:
  // Opens the camera; throws IoError naming `id` and Aravis' reason.
  AravisCamera(const std::string& id, int camera_index);
  ~AravisCamera() override;
  AravisCamera(const AravisCamera&) = delete;
  AravisCamera& operator=(const AravisCamera&) = delete;

  CameraDescription description() const override;
  void Configure(const CameraSettings& settings) override;
  CameraSettings settings() const override;
  // Writes ExposureTime(Abs) and Gain(Raw) while streaming; the frames popped after the write
  // returned carry the new values (without chunk data the exact frame is not known: a frame
  // exposed before the write but popped after it is labelled with the new values).
  bool SetExposureGainLive(double exposure_us, double gain_db) override;
  void Start(int buffers) override;
  void Stop() override;
  std::optional<Frame> Pop(std::int64_t timeout_ns) override;
  void SoftwareTrigger(std::int64_t trigger_id) override;
  bool connected() const override { return connected_; }
  // Reopens the camera by its id, reapplies the settings and restarts the stream.
  bool Reconnect() override;
  StreamCounters counters() const override;
  std::map<std::string, std::string> FeatureState() const override;

  // Reads a feature as text (for the recording's metadata); empty when the camera lacks it.
  std::string FeatureAsString(const std::string& name) const;
  // An enumeration feature's available values, ", "-separated; empty when it has none.
  std::string AvailableValues(const std::string& name) const;

 private:
  void Open();      // opens impl_->id; throws IoError
  void CheckPtp();  // sync: ptp: the clock on and locked, or an error naming the camera
  void Close();     // drops the stream and the device without talking to it
  struct Impl;
  std::unique_ptr<Impl> impl_;
  CameraSettings settings_;
  int camera_index_;
  std::atomic<bool> connected_{true};
  // The exposure and gain in force, and their changes while streaming, on the host's realtime
  // clock (Aravis' buffers' system timestamps): each frame's by when its exposure began.
  LiveExposure live_;
  FrameBufferPool pool_{0, 0};  // the frames' pixels (frame_pool.h)
};

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_ARAVIS_CAMERA_H_
