// The `v4l2` driver: USB and other cameras through Video4Linux2 memory-mapped streaming (DESIGN
// section 3), behind a seam so that it is tested without a kernel device.
//
// V4l2Device is the seam: open, ioctl, mmap, munmap, poll, close. SystemV4l2Device is the real one
// (the syscalls on /dev/videoN). V4l2Camera drives any V4l2Device:
//   Configure: VIDIOC_QUERYCAP (must capture and stream), VIDIOC_S_FMT (GREY -> Mono8, Y16 ->
//     Mono16, RGB3 -> RGB8, RGGB/GRBG/GBRG/BA81 -> Bayer 8-bit, RG16/GR16/GB16/BYR2 -> Bayer
//     16-bit; a driver that adjusts the size or
//     format is an error naming both), VIDIOC_S_PARM (frame interval), exposure (V4L2_CID_EXPOSURE_
//     AUTO manual, V4L2_CID_EXPOSURE_ABSOLUTE in 100 us units) and gain (V4L2_CID_GAIN) when
//     exposure_us / gain_db are set (> 0), then `features` as V4L2 controls by v4l2-ctl's names
//     (VIDIOC_QUERYCTRL's name in lower case, every run of other characters one '_': "White
//     Balance, Automatic" is white_balance_automatic; integers, booleans as 0/1/true/false, menus
//     by index; outside the control's range is refused naming it). V4L2 has no trigger: trigger
//     modes are refused. No region of interest (width/height are the driver's formats).
//   FeatureState: every enabled integer, boolean and menu control's value (VIDIOC_G_CTRL) by that
//     name, saved with a take (64-bit, string and bitmask controls are left out).
//   SetExposureGainLive: VIDIOC_S_CTRL while streaming (gain only when it changes); frames
//     dequeued from then on carry the values the device took (it clamps to the control's range),
//     so buffers already filled before the change carry the new values too.
//   Start: VIDIOC_REQBUFS (the driver may grant fewer, at least 2), VIDIOC_QUERYBUF + mmap each,
//     VIDIOC_QBUF all, VIDIOC_STREAMON.
//   Pop: poll, VIDIOC_DQBUF, copy `bytesused`, VIDIOC_QBUF the buffer straight back. Frame ids are
//     the driver's 32-bit `sequence` (gaps are drops), timestamps its monotonic `timestamp`;
//     V4L2_BUF_FLAG_ERROR marks a frame incomplete. ENODEV (unplugged) -> connected() false.
//   Stop: VIDIOC_STREAMOFF, munmap, VIDIOC_REQBUFS 0.
#ifndef FLAMERIG_ACQUISITION_V4L2_CAMERA_H_
#define FLAMERIG_ACQUISITION_V4L2_CAMERA_H_

#include <sys/types.h>

#include <atomic>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "acquisition/camera.h"
#include "acquisition/clock.h"
#include "acquisition/frame_pool.h"
#include "acquisition/live_exposure.h"

namespace flamerig {

class V4l2Device {
 public:
  virtual ~V4l2Device() = default;
  // Each returns what the syscall returns; on failure -1 with errno set.
  virtual int Open(const std::string& path) = 0;
  virtual int Ioctl(unsigned long request, void* arg) = 0;
  virtual void* Mmap(std::size_t length, off_t offset) = 0;  // MAP_FAILED on failure
  virtual int Munmap(void* address, std::size_t length) = 0;
  virtual int Poll(int timeout_ms) = 0;  // > 0 when a buffer can be dequeued
  virtual void Close() = 0;
};

class SystemV4l2Device : public V4l2Device {
 public:
  ~SystemV4l2Device() override { Close(); }
  int Open(const std::string& path) override;
  int Ioctl(unsigned long request, void* arg) override;
  void* Mmap(std::size_t length, off_t offset) override;
  int Munmap(void* address, std::size_t length) override;
  int Poll(int timeout_ms) override;
  void Close() override;

 private:
  int fd_ = -1;
};

// /dev/video* devices that can capture (for discovery); empty when there are none.
std::vector<std::string> ListV4l2Devices();

class V4l2Camera : public Camera {
 public:
  // Opens `path` through `device` (a SystemV4l2Device when null). Throws InputError
  // naming the path and the reason.
  V4l2Camera(const std::string& path, int camera_index,
             std::unique_ptr<V4l2Device> device = nullptr);
  ~V4l2Camera() override;

  CameraDescription description() const override { return description_; }
  void Configure(const CameraSettings& settings) override;
  CameraSettings settings() const override;  // with exposure and gain as changed live
  void Start(int buffers) override;
  void Stop() override;
  std::optional<Frame> Pop(std::int64_t timeout_ns) override;
  void SoftwareTrigger(std::int64_t) override {}  // never configured: Configure refuses triggers
  bool connected() const override { return connected_; }
  StreamCounters counters() const override { return counters_; }
  bool SetExposureGainLive(double exposure_us, double gain_db) override;
  std::map<std::string, std::string> FeatureState() const override;

  struct Control {
    std::uint32_t id = 0;
    std::string name;  // v4l2-ctl's
    std::uint32_t type = 0;
    std::int32_t minimum = 0, maximum = 0;
  };
  std::vector<Control> Controls() const;  // VIDIOC_QUERYCTRL, enabled value controls only
  // v4l2-ctl's variable name of a control's name: "White Balance, Automatic" ->
  // "white_balance_automatic".
  static std::string ControlName(const std::string& name);

 private:
  void SetControl(const std::string& name, const std::string& value);
  [[noreturn]] void Fail(const std::string& what, int error) const;
  struct Mapped {
    void* address = nullptr;
    std::size_t length = 0;
  };
  std::string path_;
  int camera_index_;
  std::unique_ptr<V4l2Device> device_;
  CameraDescription description_;
  CameraSettings settings_;
  std::vector<Mapped> buffers_;
  FrameBufferPool pool_{0, 0};  // the frames' pixels (frame_pool.h)
  bool streaming_ = false;
  std::atomic<bool> connected_{true};  // written by Pop, read by any thread
  // The exposure and gain in force, and their changes while streaming, on CLOCK_MONOTONIC (the
  // buffers' timestamps): each frame's by when its exposure began (live_exposure.h).
  LiveExposure live_;
  std::mutex control_mutex_;  // live changes one at a time
  std::uint32_t bytes_per_line_ = 0;
  FrameIdUnwrapper unwrapper_{32, 0};
  StreamCounters counters_;
};

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_V4L2_CAMERA_H_
