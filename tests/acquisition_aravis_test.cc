// The aravis driver against Aravis' own fake GigE Vision cameras: the in-process ArvGvFakeCamera on
// loopback addresses (with image content we supply), and `arv-fake-gv-camera-0.8` processes (from
// Debian's aravis-tools; skipped when absent), including one that dies mid-stream.
#include <arv.h>
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <thread>
#include <vector>

#include "acquisition/aravis_camera.h"
#include "acquisition/camera_drivers.h"
#include "acquisition/capture.h"
#include "acquisition/netns.h"
#include "core/error.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

// Image content: byte i of a frame is (i * 7 + 3) mod 251, except the first 8 bytes, which hold the
// fill call's sequence number.
std::atomic<std::uint64_t> g_fills{0};
// `frames`: the fake's own count of the frames it made (an std::atomic<std::uint64_t>), or null.
void Fill(ArvBuffer* buffer, void* frames, guint32, guint32, ArvPixelFormat) {
  if (frames) ++*static_cast<std::atomic<std::uint64_t>*>(frames);
  size_t size = 0;
  auto* data = static_cast<std::uint8_t*>(const_cast<void*>(arv_buffer_get_data(buffer, &size)));
  const std::size_t n = std::size_t(arv_buffer_get_image_width(buffer)) *
                        arv_buffer_get_image_height(buffer);  // Mono8
  for (std::size_t i = 0; i < n; ++i) data[i] = static_cast<std::uint8_t>((i * 7 + 3) % 251);
  const std::uint64_t k = g_fills++;
  std::memcpy(data, &k, std::min<std::size_t>(8, n));
}

#define REQUIRE_LOOPBACK_ADDRESSES() \
  if (!InLoopbackNamespace())        \
  GTEST_SKIP() << "needs a private network namespace (unshare -rn) for 127.0.0.2..9"

class InProcessFake {
 public:
  // The fake looks for a software trigger `trigger_hz` times a second and makes one frame for
  // all it found (1000: a latency of 1..9 ms; below the trigger rate, it misses triggers as a
  // camera that is not ready does).
  InProcessFake(const std::string& address, const std::string& serial, double trigger_hz = 1000) {
    fake_ = arv_gv_fake_camera_new(address.c_str(), serial.c_str());
    ArvFakeCamera* fc = arv_gv_fake_camera_get_fake_camera(fake_);
    arv_fake_camera_set_fill_pattern(fc, Fill, &frames_);
    arv_fake_camera_set_trigger_frequency(fc, trigger_hz);
  }
  ~InProcessFake() { g_object_unref(fake_); }
  bool running() const { return arv_gv_fake_camera_is_running(fake_); }
  std::uint64_t frames() const { return frames_; }  // made so far

 private:
  ArvGvFakeCamera* fake_;
  std::atomic<std::uint64_t> frames_{0};
};

CameraSettings Settings(TriggerMode trigger, double rate) {
  CameraSettings s;
  s.width = 320;
  s.height = 240;
  s.pixel_format = PixelFormat::kMono8;
  s.frame_rate_hz = rate;
  s.exposure_us = 1000;
  s.trigger = trigger;
  return s;
}

void ExpectPattern(const Frame& f) {
  ASSERT_EQ(f.bytes(), 320u * 240u);
  for (std::size_t i = 8; i < f.bytes(); i += 997)
    ASSERT_EQ((*f.data)[i], (i * 7 + 3) % 251) << "byte " << i;
}

TEST(AravisCamera, StreamsFreeRunFramesFromTheInProcessFake) {
  REQUIRE_LOOPBACK_ADDRESSES();
  InProcessFake fake("127.0.0.2", "FLAMERIG-A");
  ASSERT_TRUE(fake.running());
  AravisCamera cam("127.0.0.2", 3);
  EXPECT_EQ(cam.description().driver, "aravis");
  EXPECT_EQ(cam.description().address, "127.0.0.2");
  cam.Configure(Settings(TriggerMode::kFreeRun, 50));
  EXPECT_EQ(cam.FeatureAsString("Width"), "320");
  cam.Start(8);
  std::vector<Frame> frames;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (frames.size() < 20 && std::chrono::steady_clock::now() < deadline)
    if (auto f = cam.Pop(200'000'000)) frames.push_back(*f);
  cam.Stop();
  ASSERT_EQ(frames.size(), 20u);
  for (std::size_t k = 0; k < frames.size(); ++k) {
    const FrameInfo& in = frames[k].info;
    EXPECT_EQ(in.camera, 3);
    EXPECT_EQ(in.status, FrameStatus::kOk);
    EXPECT_EQ(in.width, 320);
    EXPECT_EQ(in.pixel_format, PixelFormat::kMono8);
    ExpectPattern(frames[k]);
    if (k > 0) {
      EXPECT_EQ(in.frame_id, frames[k - 1].info.frame_id + 1);
      // 50 Hz: the device timestamps (ns) step by 20 ms, give or take the fake thread's timing;
      // when the fake overruns a slot it skips it with no frame-id gap (notes/aravis.md): the
      // driver must count those from the timestamps.
      EXPECT_GT(in.device_timestamp_ns, frames[k - 1].info.device_timestamp_ns);
      EXPECT_GT(in.host_monotonic_ns, frames[k - 1].info.host_monotonic_ns);
    }
  }
  // Slots the fake skipped, from the whole span: the driver's count from each gap must agree.
  const double span =
      double(frames.back().info.device_timestamp_ns - frames.front().info.device_timestamp_ns);
  const long long skipped = std::llround(span / 20e6) - 19;
  EXPECT_NEAR(double(cam.counters().missing_by_time), double(std::max(0LL, skipped)), 2.0);
  EXPECT_NEAR(span / (19 + double(cam.counters().missing_by_time)), 20e6, 4e6);
  EXPECT_EQ(cam.counters().delivered, 20u);
  EXPECT_EQ(cam.counters().missing_by_id, 0u);
}

TEST(AravisCamera, SoftwareTriggerGivesOneFramePerTrigger) {
  REQUIRE_LOOPBACK_ADDRESSES();
  InProcessFake fake("127.0.0.3", "FLAMERIG-B");
  AravisCamera cam("127.0.0.3", 0);
  cam.Configure(Settings(TriggerMode::kSoftware, 200));
  cam.Start(4);
  EXPECT_FALSE(cam.Pop(150'000'000).has_value());  // no trigger, no frame
  int got = 0;
  for (int k = 0; k < 5; ++k) {
    cam.SoftwareTrigger(k);
    if (cam.Pop(500'000'000)) ++got;
  }
  EXPECT_EQ(got, 5);
  EXPECT_FALSE(cam.Pop(100'000'000).has_value());
  cam.Stop();
  EXPECT_TRUE(cam.connected());
}

TEST(AravisCamera, RefusedFeaturesAndMissingCamerasNameThemselves) {
  REQUIRE_LOOPBACK_ADDRESSES();
  InProcessFake fake("127.0.0.4", "FLAMERIG-C");
  AravisCamera cam("127.0.0.4", 0);
  CameraSettings s = Settings(TriggerMode::kFreeRun, 30);
  s.width = 8000;  // the fake's sensor is 2048 wide
  try {
    cam.Configure(s);
    FAIL() << "an 8000-pixel-wide image was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("127.0.0.4"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("Width/Height"), std::string::npos) << e.what();
  }
  try {
    AravisCamera none("127.0.0.99", 0);
    FAIL() << "opened a camera nobody runs";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("127.0.0.99"), std::string::npos) << e.what();
  }
}

// Wire formats. Pixel k of every frame holds WireValue(k, bits); the encoders below write the
// layouts from the GenICam PFNC and GigE Vision texts, bit by bit, independently of the driver's
// unpacking.
std::uint32_t WireValue(std::size_t k, int bits) { return (k * 37 + 11) % (1u << bits); }

void FillWire(ArvBuffer* buffer, void*, guint32, guint32, ArvPixelFormat format) {
  size_t size = 0;
  auto* data = static_cast<std::uint8_t*>(const_cast<void*>(arv_buffer_get_data(buffer, &size)));
  const std::size_t n =
      std::size_t(arv_buffer_get_image_width(buffer)) * arv_buffer_get_image_height(buffer);
  const WireFormat* w = WireFormatFromCode(format);
  if (!w) return;
  const int bits = w->bits;
  switch (w->packing) {
    case WirePacking::kWords16:  // little-endian words, the value in the low bits
      for (std::size_t k = 0; k < n; ++k) {
        data[2 * k] = WireValue(k, bits) & 0xff;
        data[2 * k + 1] = WireValue(k, bits) >> 8;
      }
      break;
    case WirePacking::kGigEPacked:  // [P0 high 8][P1 low | P0 low][P1 high 8]
      for (std::size_t k = 0; k + 1 < n; k += 2) {
        const std::uint32_t a = WireValue(k, bits), b = WireValue(k + 1, bits);
        const int low = bits - 8;
        data[3 * k / 2] = a >> low;
        data[3 * k / 2 + 1] = (a & ((1u << low) - 1)) | (b & ((1u << low) - 1)) << 4;
        data[3 * k / 2 + 2] = b >> low;
      }
      break;
    case WirePacking::kLsbBitStream:  // bit j of pixel k is bit k * bits + j of the stream
      std::memset(data, 0, (n * bits + 7) / 8);
      for (std::size_t k = 0; k < n; ++k)
        for (int j = 0; j < bits; ++j)
          if (WireValue(k, bits) >> j & 1) {
            const std::size_t at = k * bits + j;
            data[at / 8] |= 1u << (at % 8);
          }
      break;
  }
}

// The stock fake lists Mono8, Mono16, RGB8 and Bayer8 only: its own GenICam description with the
// 10- and 12-bit formats added (the fake stores any PixelFormat value and sizes its payload from
// the code's bits field, as a real camera does).
std::string WireFormatGenicam(const fs::path& dir) {
  ArvFakeCamera* stock = arv_fake_camera_new("STOCK");
  size_t size = 0;
  std::string xml(arv_fake_camera_get_genicam_xml(stock, &size));
  g_object_unref(stock);
  std::string entries;
  for (const char* name : {"Mono10", "Mono12", "Mono10Packed", "Mono12Packed", "Mono10p", "Mono12p",
                           "BayerBG12", "BayerGR10Packed", "BayerRG12p"})
    entries += "<EnumEntry Name=\"" + std::string(name) + "\" NameSpace=\"Standard\"><Value>" +
               std::to_string(WireFormatFromName(name)->pfnc) + "</Value></EnumEntry>\n";
  entries += "<EnumEntry Name=\"BayerGB16\" NameSpace=\"Standard\"><Value>" +
             std::to_string(ARV_PIXEL_FORMAT_BAYER_GB_16) + "</Value></EnumEntry>\n";
  const std::size_t at = xml.find("<pValue>PixelFormatRegister</pValue>");
  if (at == std::string::npos) return "";
  xml.insert(at, entries);
  const fs::path path = dir / "fake-wire-formats.xml";
  std::ofstream(path) << xml;
  return path.string();
}

// The wire formats' PFNC codes, against Aravis' own constants (no camera needed).
TEST(WireFormats, PfncCodesAreAravisOwn) {
  // The codes, against Aravis' own constants and (Mono10p, Mono12p, which Aravis 0.8 lacks)
  // the GenICam PFNC's table.
  EXPECT_EQ(WireFormatFromName("Mono10")->pfnc, ARV_PIXEL_FORMAT_MONO_10);
  EXPECT_EQ(WireFormatFromName("Mono12")->pfnc, ARV_PIXEL_FORMAT_MONO_12);
  EXPECT_EQ(WireFormatFromName("Mono14")->pfnc, ARV_PIXEL_FORMAT_MONO_14);
  EXPECT_EQ(WireFormatFromName("Mono10Packed")->pfnc, ARV_PIXEL_FORMAT_MONO_10_PACKED);
  EXPECT_EQ(WireFormatFromName("Mono12Packed")->pfnc, ARV_PIXEL_FORMAT_MONO_12_PACKED);
  EXPECT_EQ(WireFormatFromName("Mono10p")->pfnc, 0x010A0046u);
  EXPECT_EQ(WireFormatFromName("Mono12p")->pfnc, 0x010C0047u);
  const std::pair<const char*, ArvPixelFormat> bayer[] = {
      {"BayerRG10", ARV_PIXEL_FORMAT_BAYER_RG_10},
      {"BayerGR10", ARV_PIXEL_FORMAT_BAYER_GR_10},
      {"BayerGB10", ARV_PIXEL_FORMAT_BAYER_GB_10},
      {"BayerBG10", ARV_PIXEL_FORMAT_BAYER_BG_10},
      {"BayerRG12", ARV_PIXEL_FORMAT_BAYER_RG_12},
      {"BayerGR12", ARV_PIXEL_FORMAT_BAYER_GR_12},
      {"BayerGB12", ARV_PIXEL_FORMAT_BAYER_GB_12},
      {"BayerBG12", ARV_PIXEL_FORMAT_BAYER_BG_12},
      {"BayerRG10Packed", ARV_PIXEL_FORMAT_BAYER_RG_10_PACKED},
      {"BayerGR10Packed", ARV_PIXEL_FORMAT_BAYER_GR_10_PACKED},
      {"BayerGB10Packed", ARV_PIXEL_FORMAT_BAYER_GB_10_PACKED},
      {"BayerBG10Packed", ARV_PIXEL_FORMAT_BAYER_BG_10_PACKED},
      {"BayerRG12Packed", ARV_PIXEL_FORMAT_BAYER_RG_12_PACKED},
      {"BayerGR12Packed", ARV_PIXEL_FORMAT_BAYER_GR_12_PACKED},
      {"BayerGB12Packed", ARV_PIXEL_FORMAT_BAYER_GB_12_PACKED},
      {"BayerBG12Packed", ARV_PIXEL_FORMAT_BAYER_BG_12_PACKED},
      {"BayerRG10p", ARV_PIXEL_FORMAT_BAYER_RG_10P},
      {"BayerGR10p", ARV_PIXEL_FORMAT_BAYER_GR_10P},
      {"BayerGB10p", ARV_PIXEL_FORMAT_BAYER_GB_10P},
      {"BayerBG10p", ARV_PIXEL_FORMAT_BAYER_BG_10P},
      {"BayerRG12p", ARV_PIXEL_FORMAT_BAYER_RG_12P},
      {"BayerGR12p", ARV_PIXEL_FORMAT_BAYER_GR_12P},
      {"BayerGB12p", ARV_PIXEL_FORMAT_BAYER_GB_12P},
      {"BayerBG12p", ARV_PIXEL_FORMAT_BAYER_BG_12P}};
  for (const auto& [name, code] : bayer) {
    ASSERT_TRUE(WireFormatFromName(name)) << name;
    EXPECT_EQ(WireFormatFromName(name)->pfnc, code) << name;
  }
  // The stored formats' codes (frame.h's PfncOf, which the driver sets and reads formats by).
  const std::pair<PixelFormat, ArvPixelFormat> stored[] = {
      {PixelFormat::kMono8, ARV_PIXEL_FORMAT_MONO_8},
      {PixelFormat::kMono16, ARV_PIXEL_FORMAT_MONO_16},
      {PixelFormat::kRgb8, ARV_PIXEL_FORMAT_RGB_8_PACKED},
      {PixelFormat::kBayerRg8, ARV_PIXEL_FORMAT_BAYER_RG_8},
      {PixelFormat::kBayerGr8, ARV_PIXEL_FORMAT_BAYER_GR_8},
      {PixelFormat::kBayerGb8, ARV_PIXEL_FORMAT_BAYER_GB_8},
      {PixelFormat::kBayerBg8, ARV_PIXEL_FORMAT_BAYER_BG_8},
      {PixelFormat::kBayerRg16, ARV_PIXEL_FORMAT_BAYER_RG_16},
      {PixelFormat::kBayerGr16, ARV_PIXEL_FORMAT_BAYER_GR_16},
      {PixelFormat::kBayerGb16, ARV_PIXEL_FORMAT_BAYER_GB_16},
      {PixelFormat::kBayerBg16, ARV_PIXEL_FORMAT_BAYER_BG_16}};
  ASSERT_EQ(std::size(stored), std::size(kAllPixelFormats));
  for (const auto& [format, code] : stored) {
    EXPECT_EQ(PfncOf(format), code) << ToString(format);
    PixelFormat back = PixelFormat::kMono8;
    EXPECT_TRUE(PixelFormatFromPfnc(code, &back)) << ToString(format);
    EXPECT_EQ(back, format) << ToString(format);
  }
  PixelFormat unused;
  EXPECT_FALSE(PixelFormatFromPfnc(ARV_PIXEL_FORMAT_MONO_12, &unused));
  EXPECT_FALSE(PixelFormatFromPfnc(0, &unused));
}

TEST(AravisCamera, TenAndTwelveBitFormatsAreUnpackedIntoSixteenBitOnes) {
  REQUIRE_LOOPBACK_ADDRESSES();
  const fs::path dir = fs::temp_directory_path() / ("flamerig_wire_" + std::to_string(getpid()));
  fs::create_directories(dir);
  const std::string genicam = WireFormatGenicam(dir);
  ASSERT_FALSE(genicam.empty()) << "the stock fake's GenICam has no PixelFormatRegister";
  ArvGvFakeCamera* fake = arv_gv_fake_camera_new_full("127.0.0.9", "FLAMERIG-W", genicam.c_str());
  ArvFakeCamera* fc = arv_gv_fake_camera_get_fake_camera(fake);
  arv_fake_camera_set_fill_pattern(fc, FillWire, nullptr);
  ASSERT_TRUE(arv_gv_fake_camera_is_running(fake));
  {
    AravisCamera cam("127.0.0.9", 0);
    EXPECT_NE(cam.AvailableValues("PixelFormat").find("Mono12p"), std::string::npos);
    for (const char* name : {"Mono12", "Mono10", "Mono12Packed", "Mono10Packed", "Mono12p",
                             "Mono10p", "BayerBG12", "BayerGR10Packed", "BayerRG12p"}) {
      SCOPED_TRACE(name);
      CameraSettings s = Settings(TriggerMode::kFreeRun, 50);
      s.SetPixelFormat(name);
      ASSERT_EQ(s.pixel_format, WireFormatFromName(name)->stored);
      cam.Configure(s);
      EXPECT_EQ(cam.FeatureAsString("PixelFormat"), name);
      EXPECT_EQ(cam.settings().wire_format, name);
      cam.Start(4);
      std::optional<Frame> f;
      for (int i = 0; i < 20 && !f; ++i) f = cam.Pop(200'000'000);
      cam.Stop();
      ASSERT_TRUE(f);
      EXPECT_EQ(f->info.status, FrameStatus::kOk);
      ASSERT_EQ(f->info.pixel_format, WireFormatFromName(name)->stored);
      EXPECT_EQ(f->info.sent_pfnc, WireFormatFromName(name)->pfnc);  // as the buffer said
      ASSERT_EQ(f->bytes(), 320u * 240u * 2);
      const int bits = WireFormatFromName(name)->bits;
      for (std::size_t k = 0; k < 320u * 240u; k += 331) {
        const std::uint32_t v = (*f->data)[2 * k] | (*f->data)[2 * k + 1] << 8;
        ASSERT_EQ(v, WireValue(k, bits) << (16 - bits)) << "pixel " << k;
      }
    }
    {  // A 16-bit mosaic as the camera sends it: stored as it is, its layout named.
      CameraSettings s = Settings(TriggerMode::kFreeRun, 50);
      s.SetPixelFormat("BayerGB16");
      cam.Configure(s);
      EXPECT_EQ(cam.FeatureAsString("PixelFormat"), "BayerGB16");
      cam.Start(4);
      std::optional<Frame> f;
      for (int i = 0; i < 20 && !f; ++i) f = cam.Pop(200'000'000);
      cam.Stop();
      ASSERT_TRUE(f);
      EXPECT_EQ(f->info.pixel_format, PixelFormat::kBayerGb16);
      EXPECT_EQ(f->info.sent_pfnc, ARV_PIXEL_FORMAT_BAYER_GB_16);
      EXPECT_EQ(WireBitsOf(f->info, "BayerGB12p"), 0);  // at its own scale, whatever was set
      EXPECT_EQ(f->bytes(), 320u * 240u * 2);
    }
    // A wire format the camera does not list is refused by name.
    CameraSettings s = Settings(TriggerMode::kFreeRun, 50);
    s.SetPixelFormat("Mono14");
    try {
      cam.Configure(s);
      ADD_FAILURE() << "Mono14 accepted";
    } catch (const IoError& e) {  // as every feature value the camera refuses
      EXPECT_NE(std::string(e.what()).find("Mono14"), std::string::npos) << e.what();
    }
  }
  g_object_unref(fake);
  fs::remove_all(dir);
}

// Exposure changed while streaming: the fake fills each frame with the exposure it took it with
// (its first 4 bytes), the camera's own record. Every frame must carry the exposure it was taken
// with, the old one until the change and the new one from the frame where it took effect.
void FillExposure(ArvBuffer* buffer, void*, guint32 exposure_us, guint32, ArvPixelFormat) {
  size_t size = 0;
  auto* data = static_cast<std::uint8_t*>(const_cast<void*>(arv_buffer_get_data(buffer, &size)));
  std::memcpy(data, &exposure_us, 4);
}

TEST(AravisCamera, ExposureChangedWhileStreamingIsRecordedFromTheFrameItTookEffect) {
  REQUIRE_LOOPBACK_ADDRESSES();
  ArvGvFakeCamera* fake = arv_gv_fake_camera_new("127.0.0.9", "FLAMERIG-E");
  ArvFakeCamera* fc = arv_gv_fake_camera_get_fake_camera(fake);
  arv_fake_camera_set_fill_pattern(fc, FillExposure, nullptr);
  arv_fake_camera_set_trigger_frequency(fc, 1000);
  {
    // Software-triggered, as a flame rig runs: no frame is on its way when the change is made.
    // Each frame is labelled with the settings in force when its exposure began, counted back from
    // its arrival by its exposure time (live_exposure.h). The fake sends a frame without spending
    // its exposure time, where a camera's arrives at least that long after its trigger: the test
    // waits 4 ms (more than the new 3 ms) after the change before the next trigger, so that the
    // fake's frame arrives no sooner than a camera's could (without the wait, 1 run in 20 put
    // frame 10 within 3 ms of the change, labelled old).
    //
    // Free-running, a frame in flight during the change keeps the old settings: camera.h.
    AravisCamera cam("127.0.0.9", 0);
    cam.Configure(Settings(TriggerMode::kSoftware, 200));  // 1000 us
    cam.Start(8);
    std::vector<Frame> frames;
    for (int k = 0; k < 20; ++k) {
      if (k == 10) {
        ASSERT_TRUE(cam.SetExposureGainLive(3000, 0));  // the fake allows it
        std::this_thread::sleep_for(std::chrono::milliseconds(4));
      }
      cam.SoftwareTrigger(k);
      if (auto f = cam.Pop(500'000'000)) frames.push_back(*f);
    }
    cam.Stop();
    ASSERT_EQ(frames.size(), 20u);
    for (std::size_t k = 0; k < frames.size(); ++k) {
      std::uint32_t taken = 0;
      std::memcpy(&taken, frames[k].data->data(), 4);
      EXPECT_EQ(taken, k < 10 ? 1000u : 3000u) << "frame " << k;  // the fake's own record
      EXPECT_EQ(frames[k].info.exposure_us, double(taken)) << "frame " << k;
    }
  }
  g_object_unref(fake);
}

// Two Aravis cameras a and b at 320x240, software-triggered at 20 Hz, recording into `dir`; `b_extra`
// is appended to b's entry.
CaptureConfig TwoFakeRig(const fs::path& dir, const std::string& a, const std::string& b,
                         const std::string& b_extra = "") {
  return CaptureConfig::Parse("data_dir: " + dir.string() +
                                  "\nsync: software-trigger\ntrigger_rate_hz: 20\ncameras:\n"
                                  "  - {name: a, driver: aravis, id: " +
                                  a +
                                  ", width: 320, height: 240, exposure_us: 1000}\n"
                                  "  - {name: b, driver: aravis, id: " +
                                  b + ", width: 320, height: 240, exposure_us: 1000" + b_extra +
                                  "}\n",
                              "test");
}

// The region of interest, the sensor-size default, features by name and the feature state saved
// with a take, and a camera opened by its serial number; against the fake's own GenICam values
// (SensorWidth 2048, read back with Aravis' feature reads).
TEST(AravisCamera, RegionFeaturesAndSerial) {
  REQUIRE_LOOPBACK_ADDRESSES();
  InProcessFake fake("127.0.0.8", "FLAMERIG-F");
  AravisCamera cam("127.0.0.8", 0);
  EXPECT_EQ(cam.description().serial, "FLAMERIG-F");
  EXPECT_EQ(cam.description().address, "127.0.0.8");
  const int sensor = std::stoi(cam.FeatureAsString("SensorWidth"));
  // No size given: the whole sensor, less the offset.
  CameraSettings s = Settings(TriggerMode::kFreeRun, 20);
  s.width = 0;
  s.height = 0;
  s.offset_x = 64;
  cam.Configure(s);
  EXPECT_EQ(cam.settings().width, sensor - 64);
  EXPECT_EQ(cam.settings().height, std::stoi(cam.FeatureAsString("SensorHeight")));
  EXPECT_EQ(cam.FeatureAsString("OffsetX"), "64");
  // A region, and a feature by name (the fake's TestRegister), read back from the camera.
  s.width = 128;
  s.height = 96;
  s.offset_x = 32;
  s.offset_y = 16;
  s.features = {{"TestRegister", "4242"}};
  cam.Configure(s);
  EXPECT_EQ(cam.FeatureAsString("Width"), "128");
  EXPECT_EQ(cam.FeatureAsString("OffsetY"), "16");
  EXPECT_EQ(cam.FeatureAsString("TestRegister"), "4242");
  cam.Start(4);
  std::optional<Frame> f;
  for (int i = 0; i < 50 && !f; ++i) f = cam.Pop(100'000'000);
  cam.Stop();
  ASSERT_TRUE(f);
  EXPECT_EQ(f->info.width, 128);
  EXPECT_EQ(f->info.height, 96);
  // The whole feature state, as a take saves it.
  const std::map<std::string, std::string> state = cam.FeatureState();
  EXPECT_EQ(state.at("Width"), "128");
  EXPECT_EQ(state.at("TestRegister"), "4242");
  EXPECT_EQ(state.at("PixelFormat"), "Mono8");
  EXPECT_EQ(state.count("AcquisitionStart"), 0u);  // commands are not state
  // Refusals name the camera and the feature: an unknown feature, a region off the sensor.
  s.features = {{"NoSuchFeature", "1"}};
  try {
    cam.Configure(s);
    FAIL() << "an unknown feature was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("has no feature 'NoSuchFeature'"), std::string::npos)
        << e.what();
  }
  s.features.clear();
  s.offset_x = sensor - 64;
  try {
    cam.Configure(s);
    FAIL() << "a region off the sensor was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("does not fit the sensor, " + std::to_string(sensor)),
              std::string::npos)
        << e.what();
  }
  // sync: ptp with a camera that has no PTP clock (the fake has none) is refused, naming it.
  s.offset_x = 0;
  s.ptp = true;
  try {
    cam.Configure(s);
    FAIL() << "a camera without PTP was accepted for sync: ptp";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("sync: ptp, but it has no PTP clock"), std::string::npos)
        << e.what();
  }
  // By serial number, as a config names it.
  {
    AravisCamera by_serial("FLAMERIG-F", 1);
    EXPECT_EQ(by_serial.description().serial, "FLAMERIG-F");
  }
  // What `flamerig cameras --details` shows: discovered (in this network namespace) with its
  // serial and address, then opened for its sensor, formats and current region.
  const CameraDriver& driver = FindCameraDriver("aravis");
  bool listed = false;
  for (const CameraDescription& d : driver.discover()) {
    if (d.serial != "FLAMERIG-F") continue;
    listed = true;
    EXPECT_EQ(d.address, "127.0.0.8");
    std::map<std::string, std::string> details;
    for (const auto& [label, value] : driver.details(d)) details[label] = value;
    EXPECT_EQ(details["sensor"],
              std::to_string(sensor) + "x" + cam.FeatureAsString("SensorHeight"));
    EXPECT_EQ(details["region"], "128x96+32+16");  // the refused region was never written
    EXPECT_NE(details["formats"].find("Mono16"), std::string::npos) << details["formats"];
    EXPECT_EQ(details["pixel format"], "Mono8");
  }
  EXPECT_TRUE(listed);
}

// Records for a second, and on until every camera connected by then has sent `per_camera` frames
// more than before the recording (at most 20 s): a loaded host (CI runs two tests at a time) may
// deliver fewer than a second's worth in the first second, and a test that counts frames must
// not depend on that. A camera never connected (an absent optional one) is not waited for.
// Returns the recording's folder.
std::string RecordAtLeast(CaptureDaemon& daemon, const std::string& name,
                          std::uint64_t per_camera) {
  const CaptureStatus before = daemon.status();
  const std::string dir = daemon.StartRecording(name);
  const auto start = std::chrono::steady_clock::now();
  std::this_thread::sleep_for(std::chrono::milliseconds(1000));
  auto enough = [&] {
    const CaptureStatus now = daemon.status();
    for (std::size_t c = 0; c < now.cameras.size(); ++c) {
      const std::uint64_t base = c < before.cameras.size() ? before.cameras[c].frames : 0;
      if (now.cameras[c].connected && now.cameras[c].frames < base + per_camera) return false;
    }
    return true;
  };
  while (!enough() && std::chrono::steady_clock::now() - start < std::chrono::seconds(20))
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  daemon.StopRecording();
  return dir;
}

// Two in-process fakes in the capture daemon, software-triggered: sets matched by receive time.
TEST(AravisCamera, TheDaemonRecordsTwoFakeCameras) {
  REQUIRE_LOOPBACK_ADDRESSES();
  InProcessFake a("127.0.0.5", "FLAMERIG-D"), b("127.0.0.6", "FLAMERIG-E");
  const fs::path dir = fs::temp_directory_path() / ("flamerig_arv_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  const CaptureConfig config = TwoFakeRig(dir, "127.0.0.5", "127.0.0.6");
  EXPECT_EQ(config.AssemblerOptions().match, MatchBy::kTimestamp);
  SystemClock clock;
  CaptureDaemon daemon(config, MakeCameras(config, {&clock, nullptr}), &clock, nullptr);
  daemon.Start();
  const std::string rec_dir = RecordAtLeast(daemon, "take", 30);
  const CaptureStatus st = daemon.status();
  daemon.Stop();
  const Recording r = Recording::Open(rec_dir);
  ASSERT_GE(r.num_sets(), 20u);
  std::size_t complete = 0;
  for (std::size_t i = 0; i < r.num_sets(); ++i) {
    const FrameSet s = r.ReadSet(i);
    if (s.complete()) ++complete;
    for (const auto& f : s.frames)
      if (f) ExpectPattern(*f);
  }
  // Matched by receive time within 0.4 of the period; on a loaded two-core host (the tests run
  // two at a time) an occasional pair arrives further apart and splits into two sets.
  EXPECT_GE(complete, r.num_sets() * 8 / 10);
  EXPECT_GE(r.frames(0).size(), 25u);
  EXPECT_GE(r.frames(1).size(), 25u);
  EXPECT_EQ(r.metadata().cameras[0].description.driver, "aravis");
  // The cameras' whole feature state went into the take, read back from each device.
  EXPECT_EQ(r.metadata().cameras[1].description.serial, "FLAMERIG-E");
  EXPECT_EQ(r.metadata().features.at("a.Width"), "320");
  EXPECT_EQ(r.metadata().features.at("b.DeviceID"), "FLAMERIG-E");
  EXPECT_EQ(r.metadata().features.count("a.AcquisitionStart"), 0u);
  EXPECT_NEAR(st.cameras[0].fps, 20, 4);
  fs::remove_all(dir);
}

// Missed software triggers: fake b looks for a trigger only 8 times a second while the daemon
// triggers at 20 Hz, so it misses about 12 a second, and a answers every one. The oracle is the
// fakes' own frame counts: b missed what a made and b did not.
TEST(AravisCamera, MissedSoftwareTriggersAreCounted) {
  REQUIRE_LOOPBACK_ADDRESSES();
  InProcessFake a("127.0.0.7", "FLAMERIG-M1"), b("127.0.0.8", "FLAMERIG-M2", 8);
  const fs::path dir = fs::temp_directory_path() / ("flamerig_arvm_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  const CaptureConfig config = TwoFakeRig(dir, "127.0.0.7", "127.0.0.8");
  SystemClock clock;
  CaptureDaemon daemon(config, MakeCameras(config, {&clock, nullptr}), &clock, nullptr);
  daemon.Start();
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  const double a0 = double(a.frames()), b0 = double(b.frames());
  const std::string rec_dir = daemon.StartRecording("take");
  std::this_thread::sleep_for(std::chrono::milliseconds(2500));
  daemon.StopRecording();
  const double made_a = double(a.frames()) - a0, made_b = double(b.frames()) - b0;
  daemon.Stop();
  const Recording r = Recording::Open(rec_dir);
  const double missed_a = std::stod(r.final_counters().at("missed_triggers_a"));
  const double missed_b = std::stod(r.final_counters().at("missed_triggers_b"));
  EXPECT_GE(made_a, 40);  // 20 Hz for 2.5 s
  EXPECT_LE(made_b, 0.7 * made_a);
  // The healthy camera misses a trigger only when the host falls behind (3 of about 50 once on two
  // loaded cores under ASan): a tenth of its frames, well below b's share of at least 0.3.
  EXPECT_LE(missed_a, 0.1 * made_a);
  EXPECT_NEAR(missed_b, made_a - made_b, 4) << "a made " << made_a << ", b " << made_b;
  fs::remove_all(dir);
}

// An optional camera (required: false) that is not on the network when the daemon arms: the rig
// records without it, and takes it in when it appears (looked for about once a second).
TEST(AravisCamera, AnOptionalCameraIsTakenInWhenItAppears) {
  REQUIRE_LOOPBACK_ADDRESSES();
  InProcessFake a("127.0.0.2", "FLAMERIG-O1");
  const fs::path dir = fs::temp_directory_path() / ("flamerig_arvo_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  const CaptureConfig config = TwoFakeRig(dir, "127.0.0.2", "127.0.0.3", ", required: false");
  SystemClock clock;
  CaptureDaemon daemon(config, MakeCameras(config, {&clock, nullptr}), &clock, nullptr);
  daemon.Start();
  const std::string without = RecordAtLeast(daemon, "without", 12);
  EXPECT_FALSE(daemon.status().cameras[1].connected);
  {
    InProcessFake b("127.0.0.3", "FLAMERIG-O2");
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    while (daemon.status().cameras[1].frames == 0 && std::chrono::steady_clock::now() < until)
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    ASSERT_GT(daemon.status().cameras[1].frames, 0u) << daemon.status().ToTable();
    const std::string with = RecordAtLeast(daemon, "with", 12);
    daemon.Stop();
    const Recording r1 = Recording::Open(without), r2 = Recording::Open(with);
    EXPECT_GE(r1.frames(0).size(), 10u);
    EXPECT_EQ(r1.frames(1).size(), 0u);
    EXPECT_GE(r2.frames(0).size(), 10u);
    EXPECT_GE(r2.frames(1).size(), 10u);
    // A frame the stream flagged (the camera that just appeared may deliver a buffer Aravis marks
    // failed, kept with its status as incomplete: it failed this check once in CI on 2026-12-03)
    // holds no pattern; every complete one does.
    std::size_t complete = 0;
    for (std::size_t i = 0; i < r2.num_sets(); ++i) {
      const FrameSet s = r2.ReadSet(i);
      if (!s.frames[1] || s.frames[1]->info.status != FrameStatus::kOk) continue;
      ExpectPattern(*s.frames[1]);
      ++complete;
    }
    EXPECT_GE(complete, 5u);
    EXPECT_EQ(r2.metadata().features.at("b.DeviceID"), "FLAMERIG-O2");
  }
  fs::remove_all(dir);
}

// A child process running the external fake on `address`; killed when the guard goes, whatever
// the test's outcome (a fake left running would hold the test's output pipe open).
class FakeProcess {
 public:
  FakeProcess(const char* exe, const char* address) {
    pid_ = ::fork();
    if (pid_ == 0) {
      const int null = ::open("/dev/null", O_RDWR);
      ::dup2(null, 0);
      ::dup2(null, 1);
      ::dup2(null, 2);
      ::execl(exe, exe, "-i", address, "-s", "FLAMERIG-X", static_cast<char*>(nullptr));
      ::_exit(127);
    }
  }
  ~FakeProcess() { Kill(); }
  void Kill() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
    pid_ = -1;
  }
  bool started() const { return pid_ > 0; }

 private:
  pid_t pid_ = -1;
};

// `arv-fake-gv-camera-0.8`, a separate process, as a camera on the network would be; then killed.
TEST(AravisCamera, ExternalFakeProcessAndItsDeath) {
  REQUIRE_LOOPBACK_ADDRESSES();
  const char* exe = "/usr/bin/arv-fake-gv-camera-0.8";
  if (!fs::exists(exe)) GTEST_SKIP() << exe << " not installed (Debian package aravis-tools)";
  FakeProcess fake(exe, "127.0.0.7");
  ASSERT_TRUE(fake.started());
  std::unique_ptr<AravisCamera> cam;
  for (int tries = 0; tries < 4 && !cam; ++tries) {  // until the fake answers
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    try {
      cam = std::make_unique<AravisCamera>("127.0.0.7", 0);
    } catch (const std::runtime_error&) {
    }
  }
  ASSERT_TRUE(cam) << "the external fake never answered";
  cam->Configure(Settings(TriggerMode::kFreeRun, 50));  // it keeps settings between clients
  cam->Start(8);
  int frames = 0;
  for (int k = 0; k < 40 && frames < 10; ++k)
    if (auto f = cam->Pop(200'000'000)) frames += f->info.status == FrameStatus::kOk;
  EXPECT_EQ(frames, 10);
  fake.Kill();
  // Frames stop at once; Aravis declares the control lost after its heartbeat timeout.
  const auto t0 = std::chrono::steady_clock::now();
  int after = 0;
  while (cam->connected() && std::chrono::steady_clock::now() - t0 < std::chrono::seconds(15)) {
    if (auto f = cam->Pop(100'000'000)) ++after;
  }
  EXPECT_FALSE(cam->connected());
  EXPECT_LE(after, 8);             // at most the buffers in flight
  EXPECT_FALSE(cam->Reconnect());  // nobody there yet
  // The camera comes back (a new process on the same address): reconnect restores the stream.
  FakeProcess again(exe, "127.0.0.7");
  bool back = false;
  for (int tries = 0; tries < 10 && !back; ++tries) {
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    back = cam->Reconnect();
  }
  EXPECT_TRUE(back);
  int restored = 0;
  for (int k = 0; k < 40 && restored < 5; ++k)
    if (auto f = cam->Pop(200'000'000)) restored += f->info.status == FrameStatus::kOk;
  EXPECT_EQ(restored, 5);
  cam.reset();
}

}  // namespace
}  // namespace flamerig

// Each fake camera needs its own address (they all bind UDP 3956). The loopback interface of the
// host has only 127.0.0.1, so the test re-runs itself in a private network namespace
// (`unshare -rn`, no root needed) where it adds 127.0.0.2..9 to lo. Where user namespaces are not
// allowed, the tests that need those addresses skip themselves and say why.
int main(int argc, char** argv) {
  flamerig::RerunInLoopbackNamespace(std::vector<std::string>(argv, argv + argc));
  ::testing::InitGoogleTest(&argc, argv);
  const int r = RUN_ALL_TESTS();
  arv_shutdown();
  return r;
}
