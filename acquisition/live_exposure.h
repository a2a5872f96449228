// Which exposure and gain a streaming camera's frame was taken with, when they change while it
// streams (Camera::SetExposureGainLive). A driver that learns a frame's settings from the camera
// itself (GenICam chunk data) needs none of this; Aravis and V4L2 frames carry only their times,
// so the driver keeps the history of changes and asks it, for each frame, which settings were in
// force when that frame's exposure began: the newest change made before the exposure began. A
// frame exposed before a change and delivered after it (in flight, or waiting in a buffer) keeps
// the old settings; `flamerig run` fits each frame at the exposure it carries (frame_source.h), so
// a frame labelled with the other settings would be fitted at the wrong brightness.
//
// What is not known: when the camera applies a change (most GenICam cameras from the next exposure
// that starts after the register write; some one or two frames later), and, for a frame timed by
// its arrival, the readout between the exposure's end and the arrival (taken as 0: a frame that
// began exposing during the change's last readout time is labelled new).
//
// Thread safety: every member may be called from any thread.
#ifndef FLAMERIG_ACQUISITION_LIVE_EXPOSURE_H_
#define FLAMERIG_ACQUISITION_LIVE_EXPOSURE_H_

#include <cstdint>
#include <deque>
#include <mutex>

namespace flamerig {

struct ExposureSettings {
  double exposure_us = 0;
  double gain_db = 0;
};

class LiveExposure {
 public:
  // The settings every frame has until a change: at configure time (forgets earlier changes).
  void Reset(const ExposureSettings& settings);
  // A change that took effect at `at_ns` (the clock the frames' times are in).
  void Change(const ExposureSettings& settings, std::int64_t at_ns);
  // The settings now (what the next frame is exposed with).
  ExposureSettings Current() const;
  // The settings of a frame whose exposure began at `start_ns`: the newest change at or before it.
  ExposureSettings ForFrameStartingAt(std::int64_t start_ns) const;
  // The settings of a frame whose exposure ended at `end_ns` (or that arrived then): those under
  // which its exposure, counted back from `end_ns` by their exposure time, began while they were
  // in force; where two fit (an exposure shortened), the older; where none does (lengthened), the
  // ones in force at `end_ns`.
  ExposureSettings ForFrameEndingAt(std::int64_t end_ns) const;

  static constexpr std::size_t kHistory = 16;  // changes kept (frames in flight span a few)

 private:
  struct Entry {
    ExposureSettings settings;
    std::int64_t at_ns = 0;
  };
  mutable std::mutex mutex_;
  ExposureSettings first_;     // before the oldest change kept
  std::deque<Entry> changes_;  // oldest first
};

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_LIVE_EXPOSURE_H_
