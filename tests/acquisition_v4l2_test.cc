// The v4l2 driver against a fake device that follows the kernel's buffer rules (a buffer is
// either queued, done or dequeued; QBUF of a queued buffer is EINVAL; with no queued buffer a
// frame is dropped but the sequence counter still advances; STREAMOFF returns every buffer;
// ENODEV once unplugged). Tests that need a real /dev/video* skip themselves when none exists.
#include <gtest/gtest.h>
#include <linux/videodev2.h>
#include <sys/mman.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <ctime>
#include <deque>
#include <map>
#include <optional>
#include <vector>

#include "acquisition/v4l2_camera.h"
#include "core/error.h"

namespace flamerig {
namespace {

struct Ctrl {
  std::uint32_t id;
  const char* name;
  std::uint32_t type;
  std::int32_t min, max, value;
  std::uint32_t flags;
};

class FakeV4l2 : public V4l2Device {
 public:
  struct Shared {  // what the test inspects and steers after the camera owns the device
    int max_buffers = 4;
    int width_multiple = 16;
    std::uint32_t padding = 32;  // bytes at the end of every row
    std::uint32_t sequence = 0;
    bool unplugged = false;
    bool next_frame_error = false;
    int double_queue_errors = 0;
    std::uint32_t exposure = 0, gain = 0;
    // Stamp frames as a real driver does, CLOCK_MONOTONIC at the exposure's start (SOE), shifted
    // by this (a frame exposed that long ago); else by their sequence number from 0.
    bool stamp_now = false;
    std::int64_t stamp_shift_ns = 0;
    // Controls as uvcvideo names them, in id order: a class, a disabled one, an inactive one.
    std::vector<Ctrl> controls = {
        {V4L2_CID_USER_CLASS, "User Controls", V4L2_CTRL_TYPE_CTRL_CLASS, 0, 0, 0, 0},
        {V4L2_CID_BRIGHTNESS, "Brightness", V4L2_CTRL_TYPE_INTEGER, -64, 64, 0, 0},
        {V4L2_CID_HUE, "Hue", V4L2_CTRL_TYPE_INTEGER, -40, 40, 0, V4L2_CTRL_FLAG_DISABLED},
        {V4L2_CID_AUTO_WHITE_BALANCE, "White Balance, Automatic", V4L2_CTRL_TYPE_BOOLEAN, 0, 1, 1,
         0},
        {V4L2_CID_GAMMA, "Gamma", V4L2_CTRL_TYPE_INTEGER, 72, 500, 100, 0},
        {V4L2_CID_GAIN, "Gain", V4L2_CTRL_TYPE_INTEGER, 0, 100, 0, 0},
        {V4L2_CID_WHITE_BALANCE_TEMPERATURE, "White Balance Temperature", V4L2_CTRL_TYPE_INTEGER,
         2800, 6500, 4600, V4L2_CTRL_FLAG_INACTIVE},
        {V4L2_CID_EXPOSURE_AUTO, "Auto Exposure", V4L2_CTRL_TYPE_MENU, 0, 3, 3, 0},
        {V4L2_CID_EXPOSURE_ABSOLUTE, "Exposure Time, Absolute", V4L2_CTRL_TYPE_INTEGER, 1, 10000,
         156, 0},
    };
  };
  explicit FakeV4l2(Shared* shared) : s_(shared) {}

  int Open(const std::string& path) override {
    if (path != "/dev/fake0") return Err(ENOENT);
    return 3;
  }
  void Close() override {}
  int Poll(int) override {
    if (s_->unplugged) return 1;  // the kernel reports POLLERR
    if (done_.empty()) Produce();
    return done_.empty() ? 0 : 1;
  }
  void* Mmap(std::size_t length, off_t offset) override {
    const std::size_t i = static_cast<std::size_t>(offset) / kOffsetUnit;
    if (i >= buffers_.size() || length != buffers_[i].size()) {
      errno = EINVAL;
      return MAP_FAILED;
    }
    return buffers_[i].data();
  }
  int Munmap(void*, std::size_t) override { return 0; }

  int Ioctl(unsigned long request, void* arg) override {
    if (s_->unplugged) return Err(ENODEV);
    switch (request) {
      case VIDIOC_QUERYCAP: {
        auto* c = static_cast<v4l2_capability*>(arg);
        std::memset(c, 0, sizeof *c);
        std::strcpy(reinterpret_cast<char*>(c->driver), "fake");
        std::strcpy(reinterpret_cast<char*>(c->card), "Fake camera");
        std::strcpy(reinterpret_cast<char*>(c->bus_info), "platform:fake");
        c->device_caps = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING;
        c->capabilities = c->device_caps | V4L2_CAP_DEVICE_CAPS;
        return 0;
      }
      case VIDIOC_S_FMT: {
        if (streaming_ || !buffers_.empty()) return Err(EBUSY);
        auto* f = static_cast<v4l2_format*>(arg);
        auto& p = f->fmt.pix;
        int bpp = 1;
        if (p.pixelformat == V4L2_PIX_FMT_Y16 || p.pixelformat == V4L2_PIX_FMT_SRGGB16)
          bpp = 2;
        else if (p.pixelformat == V4L2_PIX_FMT_RGB24)
          bpp = 3;
        else if (p.pixelformat != V4L2_PIX_FMT_GREY && p.pixelformat != V4L2_PIX_FMT_SRGGB8)
          p.pixelformat = V4L2_PIX_FMT_GREY;  // drivers substitute what they have
        p.width = std::min<std::uint32_t>(1920, p.width / s_->width_multiple * s_->width_multiple);
        p.height = std::min<std::uint32_t>(1080, p.height);
        p.bytesperline = p.width * bpp + s_->padding;
        p.sizeimage = p.bytesperline * p.height;
        format_ = p;
        return 0;
      }
      case VIDIOC_S_PARM:
        return 0;
      case VIDIOC_QUERYCTRL: {  // with V4L2_CTRL_FLAG_NEXT_CTRL: the next id up
        auto* q = static_cast<v4l2_queryctrl*>(arg);
        const std::uint32_t after =
            q->id & ~(V4L2_CTRL_FLAG_NEXT_CTRL | V4L2_CTRL_FLAG_NEXT_COMPOUND);
        const bool next = q->id & V4L2_CTRL_FLAG_NEXT_CTRL;
        for (const Ctrl& c : s_->controls) {  // in id order
          if (next ? c.id <= after : c.id != after) continue;
          std::memset(q, 0, sizeof *q);
          q->id = c.id;
          q->type = c.type;
          std::strncpy(reinterpret_cast<char*>(q->name), c.name, sizeof q->name - 1);
          q->minimum = c.min;
          q->maximum = c.max;
          q->step = 1;
          q->flags = c.flags;
          return 0;
        }
        return Err(EINVAL);
      }
      case VIDIOC_G_CTRL:
      case VIDIOC_S_CTRL: {
        auto* k = static_cast<v4l2_control*>(arg);
        for (Ctrl& c : s_->controls) {
          if (c.id != k->id || c.type == V4L2_CTRL_TYPE_CTRL_CLASS ||
              (c.flags & V4L2_CTRL_FLAG_DISABLED))
            continue;
          if (request == VIDIOC_G_CTRL) {
            k->value = c.value;
            return 0;
          }
          // The control framework clamps integers to the range and writes back what it took;
          // booleans and menus out of range are ERANGE.
          if (c.type == V4L2_CTRL_TYPE_INTEGER)
            k->value = std::clamp(k->value, c.min, c.max);
          else if (k->value < c.min || k->value > c.max)
            return Err(ERANGE);
          c.value = k->value;
          if (c.id == V4L2_CID_EXPOSURE_ABSOLUTE)
            s_->exposure = static_cast<std::uint32_t>(k->value);
          if (c.id == V4L2_CID_GAIN) s_->gain = static_cast<std::uint32_t>(k->value);
          return 0;
        }
        return Err(EINVAL);
      }
      case VIDIOC_REQBUFS: {
        auto* r = static_cast<v4l2_requestbuffers*>(arg);
        if (streaming_) return Err(EBUSY);
        buffers_.clear();
        state_.clear();
        done_.clear();
        const int n = std::min<int>(static_cast<int>(r->count), s_->max_buffers);
        for (int i = 0; i < n; ++i) {
          buffers_.emplace_back(format_.sizeimage);
          state_.push_back(kDequeued);
        }
        r->count = static_cast<std::uint32_t>(n);
        return 0;
      }
      case VIDIOC_QUERYBUF: {
        auto* b = static_cast<v4l2_buffer*>(arg);
        if (b->index >= buffers_.size()) return Err(EINVAL);
        b->length = static_cast<std::uint32_t>(buffers_[b->index].size());
        b->m.offset = b->index * kOffsetUnit;
        return 0;
      }
      case VIDIOC_QBUF: {
        auto* b = static_cast<v4l2_buffer*>(arg);
        if (b->index >= buffers_.size()) return Err(EINVAL);
        if (state_[b->index] != kDequeued) {
          ++s_->double_queue_errors;
          return Err(EINVAL);
        }
        state_[b->index] = kQueued;
        queued_.push_back(b->index);
        return 0;
      }
      case VIDIOC_DQBUF: {
        auto* b = static_cast<v4l2_buffer*>(arg);
        if (!streaming_ || done_.empty()) return Err(EAGAIN);
        *b = done_.front();
        done_.pop_front();
        state_[b->index] = kDequeued;
        return 0;
      }
      case VIDIOC_STREAMON:
        streaming_ = true;
        return 0;
      case VIDIOC_STREAMOFF:
        streaming_ = false;
        for (auto& st : state_) st = kDequeued;
        queued_.clear();
        done_.clear();
        return 0;
    }
    return Err(ENOTTY);
  }

 private:
  static constexpr std::uint32_t kOffsetUnit = 1 << 24;
  enum State { kDequeued, kQueued, kDone };
  int Err(int e) {
    errno = e;
    return -1;
  }
  // One frame: into the oldest queued buffer, or dropped when none is queued.
  void Produce() {
    if (!streaming_) return;
    const std::uint32_t seq = s_->sequence++;
    if (queued_.empty()) return;
    const std::uint32_t i = queued_.front();
    queued_.pop_front();
    auto& buf = buffers_[i];
    const std::uint32_t row = format_.bytesperline - s_->padding;
    for (std::uint32_t y = 0; y < format_.height; ++y) {
      for (std::uint32_t x = 0; x < row; ++x)
        buf[y * format_.bytesperline + x] = static_cast<std::uint8_t>(x + 3 * y + 5 * seq);
      for (std::uint32_t x = row; x < format_.bytesperline; ++x)
        buf[y * format_.bytesperline + x] = 0xEE;  // padding the driver must not pass on
    }
    v4l2_buffer b{};
    b.index = i;
    b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    b.memory = V4L2_MEMORY_MMAP;
    b.sequence = seq;
    b.bytesused = format_.sizeimage;
    b.timestamp.tv_sec = seq / 30;
    b.timestamp.tv_usec = (seq % 30) * 33333;
    b.flags = V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC | (s_->next_frame_error ? V4L2_BUF_FLAG_ERROR : 0);
    if (s_->stamp_now) {
      timespec now{};
      clock_gettime(CLOCK_MONOTONIC, &now);
      const std::int64_t ns =
          std::int64_t(now.tv_sec) * 1'000'000'000 + now.tv_nsec + s_->stamp_shift_ns;
      b.timestamp.tv_sec = ns / 1'000'000'000;
      b.timestamp.tv_usec = (ns % 1'000'000'000) / 1000;
      b.flags |= V4L2_BUF_FLAG_TSTAMP_SRC_SOE;
    }
    s_->next_frame_error = false;
    state_[i] = kDone;
    done_.push_back(b);
  }

  Shared* s_;
  v4l2_pix_format format_{};
  bool streaming_ = false;
  std::vector<std::vector<std::uint8_t>> buffers_;
  std::vector<State> state_;
  std::deque<std::uint32_t> queued_;
  std::deque<v4l2_buffer> done_;
};

CameraSettings Mono(int w, int h) {
  CameraSettings s;
  s.width = w;
  s.height = h;
  s.pixel_format = PixelFormat::kMono8;
  s.frame_rate_hz = 30;
  s.exposure_us = 5000;
  return s;
}

TEST(V4l2Camera, StreamsFramesWithoutRowPaddingAndRequeuesEveryBuffer) {
  FakeV4l2::Shared shared;
  V4l2Camera cam("/dev/fake0", 2, std::make_unique<FakeV4l2>(&shared));
  EXPECT_EQ(cam.description().model, "Fake camera");
  cam.Configure(Mono(64, 48));
  EXPECT_EQ(shared.exposure, 50u);  // 5000 us in 100 us units
  cam.Start(8);                     // the fake grants 4
  for (std::uint32_t k = 0; k < 25; ++k) {
    const auto f = cam.Pop(100'000'000);
    ASSERT_TRUE(f.has_value()) << k;
    EXPECT_EQ(f->info.camera, 2);
    EXPECT_EQ(f->info.frame_id, k);
    EXPECT_EQ(f->info.status, FrameStatus::kOk);
    EXPECT_EQ(f->info.device_timestamp_ns,
              std::int64_t(k / 30) * 1'000'000'000 + std::int64_t(k % 30) * 33'333'000);
    ASSERT_EQ(f->bytes(), 64u * 48u);
    for (int y = 0; y < 48; y += 7)
      for (int x = 0; x < 64; x += 5)
        ASSERT_EQ((*f->data)[y * 64 + x], static_cast<std::uint8_t>(x + 3 * y + 5 * k));
  }
  EXPECT_EQ(shared.double_queue_errors, 0);
  EXPECT_EQ(cam.counters().missing_by_id, 0u);
  cam.Stop();
  // Restart after stop: the buffers come back.
  cam.Start(4);
  EXPECT_TRUE(cam.Pop(100'000'000).has_value());
}

// A 16-bit Bayer mosaic (RG16): two bytes a site, the rows' padding left out.
TEST(V4l2Camera, StreamsSixteenBitBayerMosaics) {
  FakeV4l2::Shared shared;
  V4l2Camera cam("/dev/fake0", 0, std::make_unique<FakeV4l2>(&shared));
  CameraSettings s = Mono(64, 48);
  s.pixel_format = PixelFormat::kBayerRg16;
  cam.Configure(s);
  cam.Start(4);
  const auto f = cam.Pop(100'000'000);
  ASSERT_TRUE(f.has_value());
  EXPECT_EQ(f->info.pixel_format, PixelFormat::kBayerRg16);
  ASSERT_EQ(f->bytes(), 64u * 48u * 2);
  for (int y = 0; y < 48; y += 7)
    for (int x = 0; x < 128; x += 5)
      ASSERT_EQ((*f->data)[y * 128 + x], static_cast<std::uint8_t>(x + 3 * y));
  cam.Stop();
}

TEST(V4l2Camera, DropsFromSequenceGapsAndErrorFlags) {
  FakeV4l2::Shared shared;
  V4l2Camera cam("/dev/fake0", 0, std::make_unique<FakeV4l2>(&shared));
  cam.Configure(Mono(32, 16));
  cam.Start(4);
  ASSERT_TRUE(cam.Pop(0).has_value());
  shared.sequence += 3;  // three frames the driver produced while no buffer was free
  shared.next_frame_error = true;
  const auto f = cam.Pop(0);
  ASSERT_TRUE(f.has_value());
  EXPECT_EQ(f->info.frame_id, 4u);
  EXPECT_EQ(f->info.status, FrameStatus::kIncomplete);
  EXPECT_EQ(cam.counters().missing_by_id, 3u);
  EXPECT_EQ(cam.counters().incomplete, 1u);
}

TEST(V4l2Camera, RefusalsNameWhatAndWhere) {
  FakeV4l2::Shared shared;
  EXPECT_THROW(V4l2Camera("/dev/none", 0, std::make_unique<FakeV4l2>(&shared)), std::runtime_error);
  V4l2Camera cam("/dev/fake0", 0, std::make_unique<FakeV4l2>(&shared));
  try {
    cam.Configure(Mono(100, 48));  // the fake wants multiples of 16
    FAIL() << "an adjusted size was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("asked for 100x48 GREY, the driver offers 96x48 GREY"),
              std::string::npos)
        << e.what();
  }
  CameraSettings bayer = Mono(64, 48);
  bayer.pixel_format = PixelFormat::kBayerGb8;  // the fake offers RGGB only
  EXPECT_THROW(cam.Configure(bayer), std::runtime_error);
  CameraSettings trig = Mono(64, 48);
  trig.trigger = TriggerMode::kHardware;
  try {
    cam.Configure(trig);
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("no trigger"), std::string::npos);
  }
  CameraSettings longer = Mono(64, 48);
  longer.frame_rate_hz = 0.1;
  longer.exposure_us = 5e6;  // 50000 units, beyond the control's range
  try {
    cam.Configure(longer);
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("V4L2_CID_EXPOSURE_ABSOLUTE"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("/dev/fake0"), std::string::npos);
  }
  shared.max_buffers = 1;
  cam.Configure(Mono(64, 48));
  EXPECT_THROW(cam.Start(4), std::runtime_error);  // granted 1 buffer
}

// v4l2-ctl's names for the kernel's control names (v4l2-ctl -l lists them so).
TEST(V4l2Camera, ControlNamesAreV4l2CtlsNames) {
  EXPECT_EQ(V4l2Camera::ControlName("White Balance, Automatic"), "white_balance_automatic");
  EXPECT_EQ(V4l2Camera::ControlName("  Exposure Time, Absolute "), "exposure_time_absolute");
  EXPECT_EQ(V4l2Camera::ControlName("Gain (dB)"), "gain_db");
  EXPECT_EQ(V4l2Camera::ControlName("Power Line Frequency"), "power_line_frequency");
}

// `features` are V4L2 controls by those names: set, range-checked, and every enabled control's
// value is the feature state saved with a take; exposure and gain change while streaming.
TEST(V4l2Camera, ControlsByNameFeatureStateAndLiveExposure) {
  FakeV4l2::Shared shared;
  V4l2Camera cam("/dev/fake0", 0, std::make_unique<FakeV4l2>(&shared));
  auto value = [&](std::uint32_t id) {
    for (const Ctrl& c : shared.controls)
      if (c.id == id) return c.value;
    return -999;
  };
  CameraSettings s = Mono(64, 48);
  s.features = {{"gamma", "220"}, {"white_balance_automatic", "false"}, {"brightness", "-10"}};
  cam.Configure(s);
  EXPECT_EQ(value(V4L2_CID_GAMMA), 220);
  EXPECT_EQ(value(V4L2_CID_AUTO_WHITE_BALANCE), 0);
  EXPECT_EQ(value(V4L2_CID_BRIGHTNESS), -10);
  EXPECT_EQ(value(V4L2_CID_EXPOSURE_AUTO), V4L2_EXPOSURE_MANUAL);  // exposure_us is set
  const std::map<std::string, std::string> state = cam.FeatureState();
  EXPECT_EQ(state.at("gamma"), "220");
  EXPECT_EQ(state.at("white_balance_automatic"), "0");
  EXPECT_EQ(state.at("brightness"), "-10");
  EXPECT_EQ(state.at("auto_exposure"), "1");
  EXPECT_EQ(state.at("exposure_time_absolute"), std::to_string(shared.exposure));
  EXPECT_EQ(state.at("white_balance_temperature"), "4600");  // inactive, but its value is there
  EXPECT_EQ(state.count("hue"), 0u);                         // disabled
  EXPECT_EQ(state.count("user_controls"), 0u);               // a class, not a value
  EXPECT_EQ(state.size(), 7u);
  auto refused = [&](const std::string& name, const std::string& v) -> std::string {
    CameraSettings bad = Mono(64, 48);
    bad.features = {{name, v}};
    try {
      cam.Configure(bad);
    } catch (const InputError& e) {
      return e.what();
    }
    return "accepted";
  };
  const std::string unknown = refused("gama", "100");
  EXPECT_NE(unknown.find("/dev/fake0: feature 'gama': no such control (it has: brightness, "
                         "white_balance_automatic, gamma, gain"),
            std::string::npos)
      << unknown;
  EXPECT_NE(refused("gamma", "9999").find("9999 is outside [72, 500]"), std::string::npos);
  EXPECT_NE(refused("gamma", "1.5").find("'1.5' is not an integer"), std::string::npos);
  EXPECT_NE(refused("white_balance_automatic", "maybe").find("or true/false"), std::string::npos);
  EXPECT_EQ(value(V4L2_CID_GAMMA), 220);  // nothing refused was written

  // Live: the next frames carry what the device took (exposure in its 100 us units), each frame
  // the settings in force when its exposure began (its timestamp, stamped at the start here).
  shared.stamp_now = true;
  cam.Configure(Mono(64, 48));
  cam.Start(4);
  ASSERT_TRUE(cam.Pop(100'000'000));
  EXPECT_EQ(cam.Pop(100'000'000)->info.exposure_us, Mono(64, 48).exposure_us);
  ASSERT_TRUE(cam.SetExposureGainLive(2540, 7));
  EXPECT_EQ(shared.exposure, 25u);
  EXPECT_EQ(shared.gain, 7u);
  // A frame whose exposure began 50 ms before the change, delivered after it: the old settings.
  shared.stamp_shift_ns = -50'000'000;
  const std::optional<Frame> in_flight = cam.Pop(100'000'000);
  ASSERT_TRUE(in_flight);
  EXPECT_EQ(in_flight->info.exposure_us, Mono(64, 48).exposure_us);
  EXPECT_EQ(in_flight->info.gain_db, 0);
  shared.stamp_shift_ns = 0;
  const std::optional<Frame> f = cam.Pop(100'000'000);
  ASSERT_TRUE(f);
  EXPECT_EQ(f->info.exposure_us, 2500);
  EXPECT_EQ(f->info.gain_db, 7);
  EXPECT_EQ(cam.settings().exposure_us, 2500);  // what a take's metadata says from now on
  EXPECT_EQ(cam.settings().gain_db, 7);
  // Beyond the control's range: the device clamps, and frames carry what it took.
  ASSERT_TRUE(cam.SetExposureGainLive(5e6, 7));
  EXPECT_EQ(shared.exposure, 10000u);
  EXPECT_EQ(cam.Pop(100'000'000)->info.exposure_us, 1e6);
  cam.Stop();
  // Configure labels frames with what the device took (a value it would clamp is refused:
  // RefusalsNameWhatAndWhere).
  CameraSettings odd = Mono(64, 48);
  odd.exposure_us = 5050;  // 50.5 units: the device takes 51 (rounded here) = 5100 us
  cam.Configure(odd);
  cam.Start(4);
  EXPECT_EQ(cam.Pop(100'000'000)->info.exposure_us, 5100);
  cam.Stop();
}

TEST(V4l2Camera, UnpluggedMeansDisconnected) {
  FakeV4l2::Shared shared;
  V4l2Camera cam("/dev/fake0", 0, std::make_unique<FakeV4l2>(&shared));
  cam.Configure(Mono(32, 16));
  cam.Start(4);
  ASSERT_TRUE(cam.Pop(0).has_value());
  shared.unplugged = true;
  EXPECT_FALSE(cam.Pop(10'000'000).has_value());
  EXPECT_FALSE(cam.connected());
}

TEST(V4l2Camera, RealDevicesWhenPresent) {
  const auto devices = ListV4l2Devices();
  if (devices.empty()) GTEST_SKIP() << "no /dev/video* capture device on this machine";
  V4l2Camera cam(devices.front(), 0);
  EXPECT_EQ(cam.description().driver, "v4l2");
}

}  // namespace
}  // namespace flamerig
