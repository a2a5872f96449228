#include "acquisition/v4l2_camera.h"

#include <fcntl.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <stdexcept>

#include "acquisition/camera_drivers.h"
#include "core/error.h"

namespace flamerig {

namespace {

std::uint32_t FourccOf(PixelFormat f) {
  switch (f) {
    case PixelFormat::kMono8:
      return V4L2_PIX_FMT_GREY;
    case PixelFormat::kMono16:
      return V4L2_PIX_FMT_Y16;
    case PixelFormat::kRgb8:
      return V4L2_PIX_FMT_RGB24;
    case PixelFormat::kBayerRg8:
      return V4L2_PIX_FMT_SRGGB8;
    case PixelFormat::kBayerGr8:
      return V4L2_PIX_FMT_SGRBG8;
    case PixelFormat::kBayerGb8:
      return V4L2_PIX_FMT_SGBRG8;
    case PixelFormat::kBayerBg8:
      return V4L2_PIX_FMT_SBGGR8;
    case PixelFormat::kBayerRg16:
      return V4L2_PIX_FMT_SRGGB16;
    case PixelFormat::kBayerGr16:
      return V4L2_PIX_FMT_SGRBG16;
    case PixelFormat::kBayerGb16:
      return V4L2_PIX_FMT_SGBRG16;
    case PixelFormat::kBayerBg16:
      return V4L2_PIX_FMT_SBGGR16;
  }
  return V4L2_PIX_FMT_GREY;
}

std::string FourccName(std::uint32_t f) {
  std::string s(4, ' ');
  for (int i = 0; i < 4; ++i) s[i] = static_cast<char>((f >> (8 * i)) & 0xff);
  return s;
}

// ioctl, retried on EINTR.
int Xioctl(V4l2Device& d, unsigned long request, void* arg) {
  int r;
  do {
    r = d.Ioctl(request, arg);
  } while (r == -1 && errno == EINTR);
  return r;
}

}  // namespace

int SystemV4l2Device::Open(const std::string& path) {
  fd_ = ::open(path.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
  return fd_;
}
int SystemV4l2Device::Ioctl(unsigned long request, void* arg) { return ::ioctl(fd_, request, arg); }
void* SystemV4l2Device::Mmap(std::size_t length, off_t offset) {
  return ::mmap(nullptr, length, PROT_READ | PROT_WRITE, MAP_SHARED, fd_, offset);
}
int SystemV4l2Device::Munmap(void* address, std::size_t length) {
  return ::munmap(address, length);
}
int SystemV4l2Device::Poll(int timeout_ms) {
  pollfd p{fd_, POLLIN, 0};
  return ::poll(&p, 1, timeout_ms);
}
void SystemV4l2Device::Close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

std::vector<std::string> ListV4l2Devices() {
  std::vector<std::string> out;
  std::error_code ec;
  for (const auto& e : std::filesystem::directory_iterator("/dev", ec)) {
    const std::string name = e.path().filename().string();
    if (name.rfind("video", 0) != 0) continue;
    SystemV4l2Device d;
    if (d.Open(e.path().string()) < 0) continue;
    v4l2_capability cap{};
    if (d.Ioctl(VIDIOC_QUERYCAP, &cap) == 0 && (cap.device_caps & V4L2_CAP_VIDEO_CAPTURE) &&
        (cap.device_caps & V4L2_CAP_STREAMING))
      out.push_back(e.path().string());
  }
  return out;
}

V4l2Camera::V4l2Camera(const std::string& path, int camera_index,
                       std::unique_ptr<V4l2Device> device)
    : path_(path), camera_index_(camera_index), device_(std::move(device)) {
  if (!device_) device_ = std::make_unique<SystemV4l2Device>();
  if (device_->Open(path) < 0) Fail("cannot open", errno);
  v4l2_capability cap{};
  if (Xioctl(*device_, VIDIOC_QUERYCAP, &cap) != 0)
    Fail("VIDIOC_QUERYCAP (not a V4L2 device?)", errno);
  const std::uint32_t caps =
      (cap.capabilities & V4L2_CAP_DEVICE_CAPS) ? cap.device_caps : cap.capabilities;
  if (!(caps & V4L2_CAP_VIDEO_CAPTURE))
    throw InputError("v4l2 camera " + path + ": not a video capture device");
  if (!(caps & V4L2_CAP_STREAMING))
    throw InputError("v4l2 camera " + path + ": does not support streaming I/O");
  description_.driver = "v4l2";
  description_.id = path;
  description_.vendor = reinterpret_cast<const char*>(cap.driver);
  description_.model = reinterpret_cast<const char*>(cap.card);
  description_.address = reinterpret_cast<const char*>(cap.bus_info);
}

V4l2Camera::~V4l2Camera() {
  try {
    Stop();
  } catch (...) {
  }
  device_->Close();
}

void V4l2Camera::Fail(const std::string& what, int error) const {
  throw IoError("v4l2 camera " + path_ + ": " + what + ": " + std::strerror(error));
}

void V4l2Camera::Configure(const CameraSettings& s) {
  s.Validate();
  if (streaming_) throw std::logic_error("v4l2 camera " + path_ + ": Configure while streaming");
  if (!s.wire_format.empty())
    throw InputError("v4l2 camera " + path_ + ": pixel_format " + s.wire_format +
                     " is for aravis cameras only");
  if (s.trigger != TriggerMode::kFreeRun) {
    throw InputError("v4l2 camera " + path_ +
                     ": V4L2 has no trigger input; use sync: free-run (timestamp matching)");
  }
  if (s.ptp)
    throw InputError("v4l2 camera " + path_ +
                     ": V4L2 devices have no PTP clock; use sync: free-run");
  v4l2_format fmt{};
  fmt.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  CameraSettings asked = s;
  if (s.width == 0 || s.height == 0) {  // the device's current size
    if (Xioctl(*device_, VIDIOC_G_FMT, &fmt) != 0) Fail("VIDIOC_G_FMT", errno);
    if (asked.width == 0) asked.width = static_cast<int>(fmt.fmt.pix.width);
    if (asked.height == 0) asked.height = static_cast<int>(fmt.fmt.pix.height);
    fmt = v4l2_format{};
    fmt.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  }
  fmt.fmt.pix.width = static_cast<std::uint32_t>(asked.width);
  fmt.fmt.pix.height = static_cast<std::uint32_t>(asked.height);
  fmt.fmt.pix.pixelformat = FourccOf(s.pixel_format);
  fmt.fmt.pix.field = V4L2_FIELD_NONE;
  if (Xioctl(*device_, VIDIOC_S_FMT, &fmt) != 0) Fail("VIDIOC_S_FMT", errno);
  // The driver may adjust what it cannot do: that is a refusal here, not a silent change.
  if (fmt.fmt.pix.width != std::uint32_t(asked.width) ||
      fmt.fmt.pix.height != std::uint32_t(asked.height) ||
      fmt.fmt.pix.pixelformat != FourccOf(s.pixel_format)) {
    throw InputError("v4l2 camera " + path_ + ": asked for " + std::to_string(asked.width) + "x" +
                     std::to_string(asked.height) + " " + FourccName(FourccOf(s.pixel_format)) +
                     ", the driver offers " + std::to_string(fmt.fmt.pix.width) + "x" +
                     std::to_string(fmt.fmt.pix.height) + " " +
                     FourccName(fmt.fmt.pix.pixelformat));
  }
  bytes_per_line_ = fmt.fmt.pix.bytesperline;
  v4l2_streamparm parm{};
  parm.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  parm.parm.capture.timeperframe.numerator = 1000;
  parm.parm.capture.timeperframe.denominator =
      static_cast<std::uint32_t>(std::llround(s.frame_rate_hz * 1000));
  if (Xioctl(*device_, VIDIOC_S_PARM, &parm) != 0) Fail("VIDIOC_S_PARM (frame rate)", errno);
  if (s.exposure_us > 0) {
    v4l2_control manual{V4L2_CID_EXPOSURE_AUTO, V4L2_EXPOSURE_MANUAL};
    if (Xioctl(*device_, VIDIOC_S_CTRL, &manual) != 0) Fail("V4L2_CID_EXPOSURE_AUTO manual", errno);
    const auto units = static_cast<std::int32_t>(std::llround(s.exposure_us / 100.0));
    v4l2_control exposure{V4L2_CID_EXPOSURE_ABSOLUTE, units};
    if (Xioctl(*device_, VIDIOC_S_CTRL, &exposure) != 0)
      Fail("V4L2_CID_EXPOSURE_ABSOLUTE " + std::to_string(units) + " (100 us units)", errno);
    if (exposure.value != units)  // the control framework clamps to the range and says so
      throw InputError("v4l2 camera " + path_ + ": V4L2_CID_EXPOSURE_ABSOLUTE " +
                       std::to_string(units) +
                       " (100 us units) is outside its range (the device "
                       "took " +
                       std::to_string(exposure.value) + ")");
  }
  if (s.gain_db > 0) {
    v4l2_control gain{V4L2_CID_GAIN, static_cast<std::int32_t>(std::llround(s.gain_db))};
    if (Xioctl(*device_, VIDIOC_S_CTRL, &gain) != 0) Fail("V4L2_CID_GAIN", errno);
  }
  for (const auto& [name, value] : s.features) SetControl(name, value);
  settings_ = asked;
  // Frames carry what the device exposes: its 100 us units, read back after the features (which
  // may name the exposure control themselves).
  double exposure_us = asked.exposure_us;
  v4l2_control taken{V4L2_CID_EXPOSURE_ABSOLUTE, 0};
  if (s.exposure_us > 0 && Xioctl(*device_, VIDIOC_G_CTRL, &taken) == 0)
    exposure_us = taken.value * 100.0;
  live_.Reset({exposure_us, asked.gain_db});
}

CameraSettings V4l2Camera::settings() const {
  CameraSettings s = settings_;
  const ExposureSettings now = live_.Current();
  s.exposure_us = now.exposure_us;
  s.gain_db = now.gain_db;
  return s;
}

std::string V4l2Camera::ControlName(const std::string& name) {
  std::string out;
  bool gap = false;
  for (const char c : name) {
    if (std::isalnum(static_cast<unsigned char>(c))) {
      if (gap) out += '_';
      gap = false;
      out += static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    } else if (!out.empty()) {
      gap = true;
    }
  }
  return out;
}

std::vector<V4l2Camera::Control> V4l2Camera::Controls() const {
  std::vector<Control> out;
  v4l2_queryctrl q{};
  q.id = V4L2_CTRL_FLAG_NEXT_CTRL;
  for (int guard = 0; guard < 4096 && Xioctl(*device_, VIDIOC_QUERYCTRL, &q) == 0; ++guard) {
    const bool value = q.type == V4L2_CTRL_TYPE_INTEGER || q.type == V4L2_CTRL_TYPE_BOOLEAN ||
                       q.type == V4L2_CTRL_TYPE_MENU || q.type == V4L2_CTRL_TYPE_INTEGER_MENU;
    if (value && !(q.flags & V4L2_CTRL_FLAG_DISABLED)) {
      const std::string name(reinterpret_cast<const char*>(q.name),
                             strnlen(reinterpret_cast<const char*>(q.name), sizeof q.name));
      out.push_back({q.id, ControlName(name), q.type, q.minimum, q.maximum});
    }
    q.id |= V4L2_CTRL_FLAG_NEXT_CTRL;
  }
  return out;
}

void V4l2Camera::SetControl(const std::string& name, const std::string& value) {
  const std::vector<Control> controls = Controls();
  const auto c = std::find_if(controls.begin(), controls.end(),
                              [&](const Control& k) { return k.name == name; });
  if (c == controls.end()) {
    std::string names;
    for (const Control& k : controls) names += (names.empty() ? "" : ", ") + k.name;
    throw InputError("v4l2 camera " + path_ + ": feature '" + name +
                     "': no such control (it has: " + (names.empty() ? "none" : names) + ")");
  }
  long long v = 0;
  if (c->type == V4L2_CTRL_TYPE_BOOLEAN && (value == "true" || value == "false")) {
    v = value == "true";
  } else {
    std::size_t used = 0;
    try {
      v = std::stoll(value, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used == 0 || used != value.size())
      throw InputError("v4l2 camera " + path_ + ": feature '" + name + "': '" + value +
                       "' is not an integer" +
                       (c->type == V4L2_CTRL_TYPE_BOOLEAN ? " or true/false" : ""));
  }
  if (v < c->minimum || v > c->maximum)
    throw InputError("v4l2 camera " + path_ + ": feature '" + name + "': " + value +
                     " is outside [" + std::to_string(c->minimum) + ", " +
                     std::to_string(c->maximum) + "]");
  v4l2_control k{c->id, static_cast<std::int32_t>(v)};
  if (Xioctl(*device_, VIDIOC_S_CTRL, &k) != 0) Fail("feature '" + name + "' " + value, errno);
}

std::map<std::string, std::string> V4l2Camera::FeatureState() const {
  std::map<std::string, std::string> out;
  if (!connected_) return out;
  for (const Control& c : Controls()) {
    v4l2_control k{c.id, 0};
    if (Xioctl(*device_, VIDIOC_G_CTRL, &k) == 0) out[c.name] = std::to_string(k.value);
  }
  return out;
}

bool V4l2Camera::SetExposureGainLive(double exposure_us, double gain_db) {
  std::lock_guard<std::mutex> lock(control_mutex_);
  if (!connected_) return false;
  // The change's moment: before the writes (a UVC control write takes milliseconds, and a frame
  // whose exposure began after the first may be the new settings').
  const std::int64_t at_ns = SystemClock().MonotonicNs();
  v4l2_control exposure{V4L2_CID_EXPOSURE_ABSOLUTE,
                        static_cast<std::int32_t>(std::llround(exposure_us / 100.0))};
  if (Xioctl(*device_, VIDIOC_S_CTRL, &exposure) != 0) return false;  // busy while streaming
  ExposureSettings now = live_.Current();
  now.exposure_us = exposure.value * 100.0;  // what the device took, in its 100 us units
  bool took = true;
  if (std::llround(gain_db) != std::llround(now.gain_db)) {
    // A gain change (a camera without a gain control can still change its exposure live).
    v4l2_control gain{V4L2_CID_GAIN, static_cast<std::int32_t>(std::llround(gain_db))};
    took = Xioctl(*device_, VIDIOC_S_CTRL, &gain) == 0;
    if (took) now.gain_db = gain.value;
  }
  live_.Change(now, at_ns);
  return took;
}

void V4l2Camera::Start(int buffers) {
  if (streaming_) return;
  if (buffers < 2) throw InputError("v4l2 camera " + path_ + ": at least 2 buffers");
  pool_.Reserve(static_cast<std::size_t>(buffers), std::size_t(std::max(settings_.width, 0)) *
                                                       std::max(settings_.height, 0) *
                                                       BytesPerPixel(settings_.pixel_format));
  v4l2_requestbuffers req{};
  req.count = static_cast<std::uint32_t>(buffers);
  req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  req.memory = V4L2_MEMORY_MMAP;
  if (Xioctl(*device_, VIDIOC_REQBUFS, &req) != 0) Fail("VIDIOC_REQBUFS", errno);
  if (req.count < 2) {
    throw IoError("v4l2 camera " + path_ + ": the driver granted " + std::to_string(req.count) +
                  " buffers, at least 2 are needed");
  }
  for (std::uint32_t i = 0; i < req.count; ++i) {
    v4l2_buffer b{};
    b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    b.memory = V4L2_MEMORY_MMAP;
    b.index = i;
    if (Xioctl(*device_, VIDIOC_QUERYBUF, &b) != 0) Fail("VIDIOC_QUERYBUF", errno);
    void* p = device_->Mmap(b.length, static_cast<off_t>(b.m.offset));
    if (p == MAP_FAILED) Fail("mmap", errno);
    buffers_.push_back({p, b.length});
    if (Xioctl(*device_, VIDIOC_QBUF, &b) != 0) Fail("VIDIOC_QBUF", errno);
  }
  v4l2_buf_type type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (Xioctl(*device_, VIDIOC_STREAMON, &type) != 0) Fail("VIDIOC_STREAMON", errno);
  streaming_ = true;
}

void V4l2Camera::Stop() {
  if (buffers_.empty() && !streaming_) return;
  v4l2_buf_type type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (streaming_) Xioctl(*device_, VIDIOC_STREAMOFF, &type);  // returns every buffer to us
  streaming_ = false;
  for (const Mapped& m : buffers_) device_->Munmap(m.address, m.length);
  buffers_.clear();
  v4l2_requestbuffers req{};
  req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  req.memory = V4L2_MEMORY_MMAP;
  Xioctl(*device_, VIDIOC_REQBUFS, &req);  // count 0: free them
}

std::optional<Frame> V4l2Camera::Pop(std::int64_t timeout_ns) {
  if (!streaming_) throw std::logic_error("v4l2 camera " + path_ + ": Pop before Start");
  const int ready =
      device_->Poll(static_cast<int>(std::max<std::int64_t>(0, timeout_ns) / 1'000'000));
  if (ready <= 0) {
    ++counters_.timeouts;
    return std::nullopt;
  }
  v4l2_buffer b{};
  b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  b.memory = V4L2_MEMORY_MMAP;
  if (Xioctl(*device_, VIDIOC_DQBUF, &b) != 0) {
    if (errno == EAGAIN) {
      ++counters_.timeouts;
      return std::nullopt;
    }
    if (errno == ENODEV) connected_ = false;  // unplugged
    ++counters_.timeouts;
    return std::nullopt;
  }
  if (b.index >= buffers_.size()) Fail("VIDIOC_DQBUF returned an unknown buffer", EINVAL);
  const SystemClock clock;
  Frame f;
  f.info.camera = camera_index_;
  f.info.host_monotonic_ns = clock.MonotonicNs();
  f.info.host_realtime_ns = clock.RealtimeNs();
  f.info.device_frame_id = b.sequence;
  f.info.frame_id = unwrapper_.Next(b.sequence);
  f.info.device_timestamp_ns =
      std::int64_t(b.timestamp.tv_sec) * 1'000'000'000 + std::int64_t(b.timestamp.tv_usec) * 1000;
  // The settings it was exposed with: those in force when its exposure began, by the buffer's
  // timestamp where the driver stamps CLOCK_MONOTONIC (at the exposure's start, or its end) and
  // the stamp is within 10 s before now, else by when it was taken off the queue.
  {
    const std::int64_t stamp = f.info.device_timestamp_ns;
    const bool monotonic =
        (b.flags & V4L2_BUF_FLAG_TIMESTAMP_MASK) == V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC &&
        stamp <= f.info.host_monotonic_ns && f.info.host_monotonic_ns - stamp < 10'000'000'000;
    const bool at_start = (b.flags & V4L2_BUF_FLAG_TSTAMP_SRC_MASK) == V4L2_BUF_FLAG_TSTAMP_SRC_SOE;
    const ExposureSettings taken = !monotonic ? live_.ForFrameEndingAt(f.info.host_monotonic_ns)
                                   : at_start ? live_.ForFrameStartingAt(stamp)
                                              : live_.ForFrameEndingAt(stamp);
    f.info.exposure_us = taken.exposure_us;
    f.info.gain_db = taken.gain_db;
  }
  f.info.pixel_format = settings_.pixel_format;
  f.info.width = settings_.width;
  f.info.height = settings_.height;
  const std::size_t row = std::size_t(settings_.width) * BytesPerPixel(settings_.pixel_format);
  const std::size_t image = row * settings_.height;
  const std::size_t stride = std::max<std::size_t>(bytes_per_line_, row);
  auto bytes = pool_.Acquire(image);  // frame_pool.h: no allocation per frame
  const auto* src = static_cast<const std::uint8_t*>(buffers_[b.index].address);
  const bool whole = b.bytesused >= stride * (settings_.height - 1) + row &&
                     stride * (settings_.height - 1) + row <= buffers_[b.index].length;
  if (whole) {
    for (int y = 0; y < settings_.height; ++y)  // drop any row padding
      std::memcpy(bytes->data() + y * row, src + y * stride, row);
  } else {
    std::fill(bytes->begin(), bytes->end(), 0);  // a pooled buffer holds an older frame
  }
  f.info.status =
      (b.flags & V4L2_BUF_FLAG_ERROR) || !whole ? FrameStatus::kIncomplete : FrameStatus::kOk;
  f.data = std::move(bytes);
  if (Xioctl(*device_, VIDIOC_QBUF, &b) != 0) {
    if (errno == ENODEV) connected_ = false;
  }
  counters_.missing_by_id = unwrapper_.missing();
  counters_.buffers_allocated = pool_.stats().allocated;
  ++counters_.delivered;
  if (f.info.status != FrameStatus::kOk) ++counters_.incomplete;
  return f;
}

namespace {

// Every /dev/video* that is a streaming capture device.
std::vector<CameraDescription> DiscoverV4l2Cameras() {
  std::vector<CameraDescription> out;
  std::error_code ec;
  for (const auto& e : std::filesystem::directory_iterator("/dev", ec)) {
    const std::string path = e.path().string();
    if (e.path().filename().string().rfind("video", 0) != 0) continue;
    try {
      out.push_back(V4l2Camera(path, 0).description());
    } catch (const std::exception&) {
      // Not a capture device (metadata nodes are video* too), or busy.
    }
  }
  return out;
}

}  // namespace

CameraDriver V4l2CameraDriver() {
  CameraDriver d;
  d.name = "v4l2";
  d.description = "Video4Linux2 capture devices (USB and CSI cameras), mmap streaming";
  d.open = [](const CaptureCameraConfig& camera, int index,
              const DriverContext&) -> std::unique_ptr<Camera> {
    return std::make_unique<V4l2Camera>(camera.id, index);
  };
  d.discover = &DiscoverV4l2Cameras;
  return d;
}

}  // namespace flamerig
