// The acquisition core: frame-id unwrapping, the frame-set assembler, and the simulated camera
// driver on a manual clock (deterministic), with the faults the daemon must survive.
#include <gtest/gtest.h>

#include <unistd.h>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>

#include "acquisition/capture.h"
#include "acquisition/clock.h"
#include "acquisition/frame_pool.h"
#include "acquisition/frame_set.h"
#include "acquisition/sim_camera.h"
#include "core/error.h"

namespace flamerig {
namespace {

TEST(FrameIdUnwrapper, SixteenBitCounterWrapsToOneLikeGigEVision) {
  // Aravis' fake camera: 16-bit ids starting at 65400, wrapping to 1 (0 is skipped).
  FrameIdUnwrapper u(16, 1);
  EXPECT_EQ(u.Next(65534), 65534u);
  EXPECT_EQ(u.Next(65535), 65535u);
  EXPECT_EQ(u.Next(1), 65536u);
  EXPECT_EQ(u.Next(2), 65537u);
  EXPECT_EQ(u.missing(), 0u);
  // A gap of two frames across the wrap: 65535 -> (1, 2 lost) -> 3.
  FrameIdUnwrapper g(16, 1);
  g.Next(65535);
  EXPECT_EQ(g.Next(3), 65538u);
  EXPECT_EQ(g.missing(), 2u);
  // A repeated or reordered id does not move the counter forward.
  EXPECT_EQ(g.Next(2), 65537u);
  EXPECT_EQ(g.out_of_order(), 1u);
  EXPECT_EQ(g.Next(4), 65539u);
  // Many wraps stay monotonic.
  FrameIdUnwrapper w(8, 1);
  std::uint64_t last = w.Next(250), device = 250;
  for (int i = 0; i < 2000; ++i) {
    device = device >= 255 ? 1 : device + 1;
    const std::uint64_t id = w.Next(device);
    ASSERT_EQ(id, last + 1);
    last = id;
  }
  EXPECT_THROW(FrameIdUnwrapper(0), InputError);
}

Frame MakeFrame(int camera, std::int64_t trigger, std::int64_t t_ns) {
  Frame f;
  f.info.camera = camera;
  f.info.trigger_id = trigger;
  f.info.device_timestamp_ns = t_ns;
  f.info.host_monotonic_ns = t_ns;
  return f;
}

// Packed pixel formats, unpacked against bytes written out by hand from the GenICam PFNC
// (Mono10p, Mono12p: an LSB-first bit stream) and GigE Vision (Mono10Packed, Mono12Packed) texts.
TEST(WireFormats, HandPackedBytesFromTheStandards) {
  auto unpack = [](const char* name, std::vector<std::uint8_t> bytes, int w) {
    const WireFormat* f = WireFormatFromName(name);
    EXPECT_TRUE(f) << name;
    const std::vector<std::uint8_t> out = UnpackTo16Bit(*f, bytes.data(), bytes.size(), w, 1);
    std::vector<std::uint32_t> v;
    for (std::size_t k = 0; k + 1 < out.size(); k += 2) v.push_back(out[k] | out[k + 1] << 8);
    return v;
  };
  using V = std::vector<std::uint32_t>;
  // 0xABC and 0x123 at 12 bits; the result holds the value in the high bits (x 16).
  EXPECT_EQ(unpack("Mono12", {0xBC, 0x0A, 0x23, 0x01}, 2), (V{0xABC0, 0x1230}));
  EXPECT_EQ(unpack("Mono12Packed", {0xAB, 0x3C, 0x12}, 2), (V{0xABC0, 0x1230}));
  EXPECT_EQ(unpack("Mono12p", {0xBC, 0x3A, 0x12}, 2), (V{0xABC0, 0x1230}));
  // 0x3FF, 0x001, 0x155, 0x2AA at 10 bits (x 64).
  EXPECT_EQ(unpack("Mono10p", {0xFF, 0x07, 0x50, 0x95, 0xAA}, 4),
            (V{0x3FF << 6, 0x001 << 6, 0x155 << 6, 0x2AA << 6}));
  EXPECT_EQ(unpack("Mono10Packed", {0xFF, 0x13, 0x00}, 2), (V{0x3FF << 6, 0x001 << 6}));
  EXPECT_EQ(unpack("Mono10", {0xFF, 0x03}, 1), (V{0xFFC0}));
  // An odd pixel count: the last GigE triple is half used; the bit stream rounds up to a byte.
  EXPECT_EQ(WireBytes(*WireFormatFromName("Mono12Packed"), 3, 1), 6u);
  EXPECT_EQ(WireBytes(*WireFormatFromName("Mono10p"), 3, 1), 4u);
  EXPECT_EQ(unpack("Mono12p", {0xBC, 0x3A, 0x12, 0xFF, 0x0F}, 3), (V{0xABC0, 0x1230, 0xFFF0}));
  // The wrong size is a DataError naming the format; other names are not wire formats.
  const WireFormat& m12 = *WireFormatFromName("Mono12p");
  const std::vector<std::uint8_t> two(2);
  try {
    UnpackTo16Bit(m12, two.data(), two.size(), 2, 1);
    ADD_FAILURE() << "a short frame unpacked";
  } catch (const DataError& e) {
    EXPECT_NE(std::string(e.what()).find("Mono12p frame 2x1: 2 bytes, expected 3"),
              std::string::npos)
        << e.what();
  }
  EXPECT_EQ(WireFormatFromName("Mono16"), nullptr);
  EXPECT_EQ(WireFormatFromCode(0x01080001u), nullptr);  // Mono8
  // A config's pixel_format: a wire format is stored as Mono16.
  CameraSettings s;
  s.SetPixelFormat("Mono12p");
  EXPECT_EQ(s.pixel_format, PixelFormat::kMono16);
  EXPECT_EQ(s.pixel_format_name(), "Mono12p");
  try {
    s.SetPixelFormat("Mono13");
    ADD_FAILURE() << "Mono13 accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("Mono12p"), std::string::npos) << e.what();
  }
}

// Bayer mosaics of 10 and 12 bits: each of the five packings in the four layouts unpacks into
// the layout's Bayer 16 (the PFNC codes are checked against Aravis' constants in
// acquisition_aravis_test), the same bytes as the mono format of its packing.
TEST(WireFormats, BayerMosaicsUnpackIntoTheirLayoutsSixteenBitFormat) {
  const std::pair<const char*, const char*> same_packing[] = {{"BayerRG12", "Mono12"},
                                                              {"BayerGR10", "Mono10"},
                                                              {"BayerGB12Packed", "Mono12Packed"},
                                                              {"BayerBG10Packed", "Mono10Packed"},
                                                              {"BayerRG12p", "Mono12p"},
                                                              {"BayerGB10p", "Mono10p"}};
  const std::vector<std::uint8_t> bytes = {0xBC, 0x3A, 0x12, 0xFF, 0x0F, 0x00, 0x5A, 0xA5};
  for (const auto& [bayer, mono] : same_packing) {
    const WireFormat* b = WireFormatFromName(bayer);
    const WireFormat* m = WireFormatFromName(mono);
    ASSERT_TRUE(b && m) << bayer;
    EXPECT_EQ(b->bits, m->bits) << bayer;
    EXPECT_EQ(b->packing, m->packing) << bayer;
    EXPECT_TRUE(IsBayer(b->stored)) << bayer;
    EXPECT_EQ(BytesPerPixel(b->stored), 2) << bayer;
    // The layout is the name's: BayerGB12Packed -> BayerGB16.
    EXPECT_EQ(std::string(ToString(b->stored)).substr(0, 7), std::string(bayer).substr(0, 7));
    EXPECT_EQ(WireFormatFromCode(b->pfnc), b) << bayer;
    const std::size_t n = WireBytes(*b, 4, 1);
    ASSERT_LE(n, bytes.size());
    EXPECT_EQ(UnpackTo16Bit(*b, bytes.data(), n, 4, 1), UnpackTo16Bit(*m, bytes.data(), n, 4, 1))
        << bayer;
  }
  // Every stored format by its name, both ways; the 16-bit mosaics take two bytes a site.
  for (PixelFormat f : kAllPixelFormats) EXPECT_EQ(PixelFormatFromName(ToString(f)), f);
  EXPECT_EQ(Bayer16Of(PixelFormat::kBayerBg8), PixelFormat::kBayerBg16);
  EXPECT_STREQ(BayerCell(PixelFormat::kBayerGr16), "GRBG");
  EXPECT_THROW(Bayer16Of(PixelFormat::kMono8), InputError);
  // A config's pixel_format: a Bayer wire format is stored as its layout's Bayer 16; settings
  // that pair it with another stored format are refused, naming both.
  CameraSettings s;
  s.SetPixelFormat("BayerGB12Packed");
  EXPECT_EQ(s.pixel_format, PixelFormat::kBayerGb16);
  EXPECT_EQ(s.pixel_format_name(), "BayerGB12Packed");
  s.Validate();
  s.pixel_format = PixelFormat::kMono16;
  try {
    s.Validate();
    ADD_FAILURE() << "BayerGB12Packed stored as Mono16 accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("BayerGB16, not Mono16"), std::string::npos) << e.what();
  }
}

// IEC 61966-2-1's sRGB curve, written out as the oracle for a replay's scaled light: a value in
// [0, 1] to linear light, and linear light (clipped at full scale) back.
double SrgbCurveDecode(double v) {
  return v <= 0.04045 ? v / 12.92 : std::pow((v + 0.055) / 1.055, 2.4);
}
double SrgbCurveEncode(double l) {
  l = std::min(1.0, l);
  return l <= 0.0031308 ? 12.92 * l : 1.055 * std::pow(l, 1 / 2.4) - 0.055;
}

// A sim camera replaying a dataset: a deeper camera's 16-bit PNGs of codes go out as they are
// (Bayer 16: each site's colour; Mono16: their luma), an 8-bit dataset's sRGB values x 257; 8-bit
// formats of a 16-bit dataset are refused, naming the file.
TEST(SimCamera, ReplaysADeeperCamerasCodesIntoSixteenBitFormats) {
  namespace fs = std::filesystem;
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_replay16_" + std::to_string(getpid()));
  fs::create_directories(dir / "deep" / "frames" / "frame_000000");
  fs::create_directories(dir / "sRGB" / "frames" / "frame_000000");
  ImageU16 codes(6, 4, 3);
  ImageU8 srgb(6, 4, 3);
  for (int y = 0; y < 4; ++y)
    for (int x = 0; x < 6; ++x)
      for (int c = 0; c < 3; ++c) {
        codes.at(x, y, c) = static_cast<std::uint16_t>(1000 * c + 100 * y + x);  // up to 2305
        srgb.at(x, y, c) = static_cast<std::uint8_t>(60 * c + 10 * y + x);
      }
  WritePng16((dir / "deep" / "frames" / "frame_000000" / "cam.png").string(), codes);
  WritePng((dir / "sRGB" / "frames" / "frame_000000" / "cam.png").string(), srgb);
  auto word = [](const std::vector<std::uint8_t>& b, std::size_t i) {
    std::uint16_t v;
    std::memcpy(&v, b.data() + 2 * i, 2);
    return v;
  };
  FrameInfo info;
  info.width = 6;
  info.height = 4;
  std::vector<std::uint8_t> bytes;
  const ImageSource deep = DatasetReplaySource((dir / "deep").string(), "cam");
  info.pixel_format = PixelFormat::kBayerGr16;  // G R / B G
  deep(info, &bytes);
  ASSERT_EQ(bytes.size(), 6u * 4 * 2);
  EXPECT_EQ(word(bytes, 0), codes.at(0, 0, 1));
  EXPECT_EQ(word(bytes, 1), codes.at(1, 0, 0));
  EXPECT_EQ(word(bytes, 6), codes.at(0, 1, 2));
  EXPECT_EQ(word(bytes, 6 * 3 + 5), codes.at(5, 3, 1));
  info.pixel_format = PixelFormat::kMono16;
  deep(info, &bytes);
  EXPECT_NEAR(word(bytes, 6 * 2 + 3),
              0.2126 * codes.at(3, 2, 0) + 0.7152 * codes.at(3, 2, 1) + 0.0722 * codes.at(3, 2, 2),
              0.51);
  for (PixelFormat narrow : {PixelFormat::kMono8, PixelFormat::kRgb8, PixelFormat::kBayerRg8}) {
    info.pixel_format = narrow;
    try {
      deep(info, &bytes);
      ADD_FAILURE() << ToString(narrow) << " of a 16-bit dataset accepted";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("cam.png"), std::string::npos) << e.what();
    }
  }
  // Sent as a wire format: the codes in its bits' place, as the driver unpacks them; a code the
  // format cannot hold is refused, naming the file.
  info.pixel_format = PixelFormat::kBayerGr16;
  info.sent_pfnc = WireFormatFromName("BayerGR12p")->pfnc;
  deep(info, &bytes);
  EXPECT_EQ(word(bytes, 1), codes.at(1, 0, 0) << 4);
  EXPECT_EQ(word(bytes, 6 * 3 + 5), codes.at(5, 3, 1) << 4);
  info.pixel_format = PixelFormat::kMono16;
  info.sent_pfnc = WireFormatFromName("Mono10p")->pfnc;  // codes up to 2305: not in 10 bits
  try {
    deep(info, &bytes);
    ADD_FAILURE() << "2305 sent in 10 bits";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("cam.png"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("Mono10p"), std::string::npos) << e.what();
  }
  info.sent_pfnc = 0;
  const ImageSource narrow = DatasetReplaySource((dir / "sRGB").string(), "cam");
  info.pixel_format = PixelFormat::kBayerBg16;  // B G / G R
  narrow(info, &bytes);
  EXPECT_EQ(word(bytes, 0), srgb.at(0, 0, 2) * 257);
  EXPECT_EQ(word(bytes, 6 + 1), srgb.at(1, 1, 0) * 257);
  info.pixel_format = PixelFormat::kBayerBg8;
  narrow(info, &bytes);
  ASSERT_EQ(bytes.size(), 6u * 4);
  EXPECT_EQ(bytes[6 + 1], srgb.at(1, 1, 0));
  fs::remove_all(dir);
}

// A replaying camera re-exposed while it streams (`ctl configure CAM exposure_us`, live): its
// 8-bit frames carry the dataset's light times its exposure x gain over the first frame's, as a
// real camera's image darkens and brightens (the oracle: IEC 61966-2-1's sRGB curve, written out
// here, on the dataset's values). The first frame's exposure is the dataset's; a deeper camera's
// codes stay as they are.
TEST(SimCamera, AReplayingCameraReExposedLiveScalesItsLight) {
  namespace fs = std::filesystem;
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_replay_exposure_" + std::to_string(getpid()));
  fs::create_directories(dir / "frames" / "frame_000000");
  ImageU8 srgb(16, 16, 3);
  for (std::size_t i = 0; i < srgb.pixels.size(); ++i)
    srgb.pixels[i] = static_cast<std::uint8_t>(i % 256);
  WritePng((dir / "frames" / "frame_000000" / "cam.png").string(), srgb);
  const ImageSource replay = DatasetReplaySource(dir.string(), "cam");
  FrameInfo info;
  info.width = info.height = 16;
  info.pixel_format = PixelFormat::kRgb8;
  std::vector<std::uint8_t> bytes;
  info.exposure_us = 10000;  // the first frame: the dataset as it is
  replay(info, &bytes);
  EXPECT_EQ(bytes, srgb.pixels);
  for (const auto& [exposure_us, gain_db] :
       {std::pair{5000.0, 0.0}, std::pair{10000.0, 6.0}, std::pair{2500.0, 12.0}}) {
    SCOPED_TRACE(exposure_us);
    info.exposure_us = exposure_us;
    info.gain_db = gain_db;
    replay(info, &bytes);
    const double factor = exposure_us / 10000 * std::pow(10.0, gain_db / 20);
    int saturated = 0;
    for (std::size_t i = 0; i < bytes.size(); ++i) {
      const double want = 255 * SrgbCurveEncode(factor * SrgbCurveDecode(srgb.pixels[i] / 255.0));
      ASSERT_NEAR(bytes[i], want, 0.5 + 1e-9) << i << " from " << int(srgb.pixels[i]);
      saturated += bytes[i] == 255;
    }
    if (factor > 1) {
      EXPECT_GT(saturated, 100);  // brighter: the top of the range clips
    }
  }
  // Mono8 is the luma of the scaled values.
  info.exposure_us = 5000;
  info.gain_db = 0;
  info.pixel_format = PixelFormat::kMono8;
  replay(info, &bytes);
  const auto half = [&](int v) {
    return std::lround(255 * SrgbCurveEncode(0.5 * SrgbCurveDecode(v / 255.0)));
  };
  const std::uint8_t* p = &srgb.pixels[3 * 20];
  EXPECT_NEAR(bytes[20], 0.2126 * half(p[0]) + 0.7152 * half(p[1]) + 0.0722 * half(p[2]), 0.51);

  // A camera's replay: the dataset as it is at the camera's configured settings, whatever frame
  // came first; a configure (stopped) at another exposure shows the dataset as it is again.
  SimCameraOptions o;
  o.replay_exposure = std::make_shared<ReplayExposure>();
  o.source = DatasetReplaySource(dir.string(), "cam", ReplayContent::kFire, o.replay_exposure);
  EXPECT_TRUE(o.replay_exposure->scalable);
  ManualClock clock(0);
  SimCamera cam(o, &clock, nullptr);
  CameraSettings settings;
  settings.width = settings.height = 16;
  settings.pixel_format = PixelFormat::kRgb8;
  settings.exposure_us = 4000;
  cam.Configure(settings);
  EXPECT_EQ(*o.replay_exposure->reference, 4000);
  info.pixel_format = PixelFormat::kRgb8;
  info.exposure_us = 2000;  // half the configured: darker, though it is the first frame here
  o.source(info, &bytes);
  EXPECT_NEAR(bytes[3 * 20], half(p[0]), 0.5 + 1e-9);
  settings.exposure_us = 2000;
  cam.Configure(settings);
  o.source(info, &bytes);
  EXPECT_EQ(bytes, srgb.pixels);
  EXPECT_TRUE(cam.SetExposureGainLive(1000, 0));
  fs::remove_all(dir);
}

// A deeper camera's codes cannot follow a live change (their black level is the rig's): its
// replaying camera refuses one, as a camera that must be stopped to be configured does.
TEST(SimCamera, ADeeperReplayRefusesALiveExposureChange) {
  namespace fs = std::filesystem;
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_replay_deep_" + std::to_string(getpid()));
  fs::create_directories(dir / "frames" / "frame_000000");
  WritePng16((dir / "frames" / "frame_000000" / "cam.png").string(), ImageU16(8, 8, 3, 300));
  SimCameraOptions o;
  o.replay_exposure = std::make_shared<ReplayExposure>();
  o.source = DatasetReplaySource(dir.string(), "cam", ReplayContent::kFire, o.replay_exposure);
  EXPECT_FALSE(o.replay_exposure->scalable);
  ManualClock clock(0);
  SimCamera cam(o, &clock, nullptr);
  CameraSettings settings;
  settings.width = settings.height = 8;
  settings.pixel_format = PixelFormat::kMono16;
  cam.Configure(settings);
  EXPECT_FALSE(cam.SetExposureGainLive(500, 0));
  EXPECT_EQ(cam.settings().exposure_us, settings.exposure_us);
  fs::remove_all(dir);
}

// Cameras of one capture config replaying the same dataset at different exposure times (a rig
// balanced per camera): the dataset is what the config's first replaying camera sees at its
// settings, and the second camera's 8-bit frames carry the light times its exposure over the
// first's (the oracle: IEC 61966-2-1's sRGB curve, written out here), whichever camera is
// configured first; another config's cameras do not share it. A deeper camera's codes replay at
// the first camera's settings only: a frame at others is an error naming both. A dataset that
// states its exposure in time (dataset.yaml's exposure x exposure_unit_us, as `flamerig simulate`
// writes) is shown at that instead, to every camera: at those settings as it is, at twice the
// time twice as bright, whatever the first camera's; a deeper one at those settings only; a unit
// that is not a time is an error naming the file and the key.
TEST(SimCamera, ReplayingCamerasConfiguredApartShowTheirOwnExposure) {
  namespace fs = std::filesystem;
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_replay_apart_" + std::to_string(getpid()));
  fs::create_directories(dir / "rgb" / "frames" / "frame_000000");
  fs::create_directories(dir / "deep" / "frames" / "frame_000000");
  ImageU8 srgb(16, 16, 3);
  for (std::size_t i = 0; i < srgb.pixels.size(); ++i)
    srgb.pixels[i] = static_cast<std::uint8_t>(i % 256);
  for (const char* cam : {"cam0", "cam1"}) {
    WritePng((dir / "rgb" / "frames" / "frame_000000" / (std::string(cam) + ".png")).string(),
             srgb);
    WritePng16((dir / "deep" / "frames" / "frame_000000" / (std::string(cam) + ".png")).string(),
               ImageU16(16, 16, 3, 300));
  }
  const auto yaml = [&](const char* dataset, const char* format, int cam1_exposure_us,
                        int cam0_exposure_us = 10000) {
    std::string y = "data_dir: rec\nsync: free-run\ncameras:\n";
    for (int c = 0; c < 2; ++c)
      y += "  - {name: cam" + std::to_string(c) +
           ", width: 16, height: 16, pixel_format: " + format +
           ", exposure_us: " + std::to_string(c == 0 ? cam0_exposure_us : cam1_exposure_us) +
           ", frame_rate_hz: 100, sim: {replay: " + (dir / dataset).string() + "}}\n";
    return y;
  };
  SystemClock clock;
  // The frame camera c sends once the cameras are configured in `order`.
  const auto frame_of = [&](const CaptureConfig& config, std::vector<int> order, int c) {
    auto cameras = MakeCameras(config, {&clock, nullptr});
    for (int k : order) cameras[k]->Configure(config.cameras[k].settings);
    cameras[c]->Start(2);
    std::optional<Frame> f = cameras[c]->Pop(2'000'000'000);
    cameras[c]->Stop();
    if (!f) throw std::runtime_error("no frame");
    return *f->data;
  };
  const CaptureConfig apart =
      CaptureConfig::Parse(yaml("rgb", "RGB8", 5000), (dir / "apart.yaml").string());
  for (const std::vector<int>& order : {std::vector<int>{0, 1}, std::vector<int>{1, 0}}) {
    SCOPED_TRACE(order[0]);
    EXPECT_EQ(frame_of(apart, order, 0), srgb.pixels);
    const std::vector<std::uint8_t> half = frame_of(apart, order, 1);
    ASSERT_EQ(half.size(), srgb.pixels.size());
    for (std::size_t i = 0; i < half.size(); ++i)
      ASSERT_NEAR(half[i], 255 * SrgbCurveEncode(0.5 * SrgbCurveDecode(srgb.pixels[i] / 255.0)),
                  0.5 + 1e-9)
          << i;
  }
  // The first camera's configured settings hold from the config's reading: before it is
  // configured, and when it never is (a deferred camera, not there at arming).
  const CaptureConfig late =
      CaptureConfig::Parse(yaml("rgb", "RGB8", 5000), (dir / "late.yaml").string());
  const auto scaled = [&](const std::vector<std::uint8_t>& got, double factor) {
    if (got.size() != srgb.pixels.size()) return false;
    for (std::size_t i = 0; i < got.size(); ++i) {
      const double light = std::min(1.0, factor * SrgbCurveDecode(srgb.pixels[i] / 255.0));
      if (std::abs(got[i] - 255 * SrgbCurveEncode(light)) > 0.5 + 1e-9) return false;
    }
    return true;
  };
  const auto halved = [&](const std::vector<std::uint8_t>& got) { return scaled(got, 0.5); };
  EXPECT_TRUE(halved(frame_of(late, {1}, 1)));
  // Another config's cameras (or the same file read again) do not share apart's reference: with
  // both cameras at 5000 us, the second shows the dataset as it is.
  const CaptureConfig other =
      CaptureConfig::Parse(yaml("rgb", "RGB8", 5000, 5000), (dir / "other.yaml").string());
  EXPECT_EQ(frame_of(other, {1}, 1), srgb.pixels);
  const CaptureConfig again =
      CaptureConfig::Parse(yaml("rgb", "RGB8", 5000, 5000), (dir / "apart.yaml").string());
  EXPECT_EQ(frame_of(again, {1}, 1), srgb.pixels);
  EXPECT_TRUE(halved(frame_of(apart, {1}, 1)));  // apart's cameras keep theirs
  // A deeper dataset: the same settings replay, others are refused.
  const CaptureConfig deep_same =
      CaptureConfig::Parse(yaml("deep", "Mono16", 10000), (dir / "deep_same.yaml").string());
  EXPECT_EQ(frame_of(deep_same, {0, 1}, 1).size(), 16u * 16 * 2);
  const CaptureConfig deep_apart =
      CaptureConfig::Parse(yaml("deep", "Mono16", 5000), (dir / "deep_apart.yaml").string());
  try {
    frame_of(deep_apart, {0, 1}, 1);
    ADD_FAILURE() << "a deeper replay at other settings than the reference's";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("holds a deeper camera's codes"), std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("10000"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("5000"), std::string::npos) << e.what();
  }
  // The dataset's own: 2 x 2500 us at 0 dB.
  for (const char* from : {"rgb", "deep"}) {
    const fs::path timed = dir / (std::string("timed_") + from);
    fs::create_directories(timed);
    fs::copy(dir / from / "frames", timed / "frames", fs::copy_options::recursive);
    std::ofstream(timed / "dataset.yaml") << "dataset:\n  exposure: 2\n  exposure_unit_us: 2500\n";
  }
  for (const std::vector<int>& order : {std::vector<int>{0, 1}, std::vector<int>{1, 0}}) {
    SCOPED_TRACE(order[0]);
    const CaptureConfig timed =
        CaptureConfig::Parse(yaml("timed_rgb", "RGB8", 5000, 10000), (dir / "timed.yaml").string());
    EXPECT_TRUE(scaled(frame_of(timed, order, 0), 2.0));
    EXPECT_EQ(frame_of(timed, order, 1), srgb.pixels);
  }
  EXPECT_TRUE(scaled(frame_of(CaptureConfig::Parse(yaml("timed_rgb", "RGB8", 10000, 10000),
                                                   (dir / "timed_alike.yaml").string()),
                              {0, 1}, 0),
                     2.0));
  EXPECT_EQ(frame_of(CaptureConfig::Parse(yaml("timed_deep", "Mono16", 5000, 5000),
                                          (dir / "timed_deep.yaml").string()),
                     {0, 1}, 1)
                .size(),
            16u * 16 * 2);
  try {
    frame_of(CaptureConfig::Parse(yaml("timed_deep", "Mono16", 10000, 10000),
                                  (dir / "timed_deep_apart.yaml").string()),
             {0, 1}, 0);
    ADD_FAILURE() << "a deeper replay at other settings than its dataset states";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(
                  "the exposure " + (dir / "timed_deep" / "dataset.yaml").string() + " states"),
              std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("5000"), std::string::npos) << e.what();
  }
  std::ofstream(dir / "timed_rgb" / "dataset.yaml")
      << "dataset:\n  exposure: 2\n  exposure_unit_us: -1\n";
  try {
    CaptureConfig::Parse(yaml("timed_rgb", "RGB8", 10000), (dir / "bad.yaml").string());
    ADD_FAILURE() << "a dataset whose exposure unit is not a time";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find((dir / "timed_rgb" / "dataset.yaml").string() +
                                         ": dataset.exposure_unit_us must be"),
              std::string::npos)
        << e.what();
  }
  // A unit with no exposure to give the time of (a hand-edited dataset.yaml): refused, naming it.
  std::ofstream(dir / "timed_rgb" / "dataset.yaml") << "dataset:\n  exposure_unit_us: 6000\n";
  try {
    CaptureConfig::Parse(yaml("timed_rgb", "RGB8", 10000), (dir / "bad_unit.yaml").string());
    ADD_FAILURE() << "a dataset with an exposure unit and no exposure";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find((dir / "timed_rgb" / "dataset.yaml").string() +
                                         ": dataset.exposure is missing"),
              std::string::npos)
        << e.what();
  }
  fs::remove_all(dir);
}

TEST(FrameSetAssembler, GroupsByTriggerAndNeverWaitsForALostFrameItCanRuleOut) {
  FrameSetOptions o;
  o.cameras = 3;
  o.match = MatchBy::kTriggerId;
  o.timeout_ns = 1'000'000'000;
  FrameSetAssembler a(o);
  std::vector<FrameSet> out;
  // Trigger 0: all three cameras, interleaved.
  a.Add(MakeFrame(0, 0, 100), 100, &out);
  a.Add(MakeFrame(2, 0, 130), 130, &out);
  EXPECT_TRUE(out.empty());
  a.Add(MakeFrame(1, 0, 110), 140, &out);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_TRUE(out[0].complete());
  EXPECT_EQ(out[0].trigger_id, 0);
  EXPECT_EQ(out[0].spread_ns, 30);
  // Trigger 1: camera 1 loses its frame; once camera 1 delivers trigger 2, set 1 cannot complete and
  // goes out at once, incomplete, long before the timeout.
  a.Add(MakeFrame(0, 1, 200), 200, &out);
  a.Add(MakeFrame(2, 1, 201), 201, &out);
  a.Add(MakeFrame(1, 2, 300), 300, &out);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_FALSE(out[1].complete());
  EXPECT_EQ(out[1].present(), 2);
  EXPECT_EQ(a.counters().missing_per_camera[1], 1u);
  // The lost frame turning up afterwards is late, counted, not merged.
  EXPECT_FALSE(a.Add(MakeFrame(1, 1, 210), 310, &out));
  EXPECT_EQ(a.counters().late_frames, 1u);
  // A duplicate is refused.
  EXPECT_FALSE(a.Add(MakeFrame(1, 2, 300), 320, &out));
  EXPECT_EQ(a.counters().duplicate_frames, 1u);
  a.Add(MakeFrame(0, 2, 300), 330, &out);
  a.Add(MakeFrame(2, 2, 300), 340, &out);
  ASSERT_EQ(out.size(), 3u);
  EXPECT_TRUE(out[2].complete());
  EXPECT_EQ(out[2].index, 2u);
  EXPECT_EQ(a.counters().complete, 2u);
  EXPECT_EQ(a.counters().incomplete, 1u);
}

TEST(FrameSetAssembler, ADeadCameraDelaysSetsByTheTimeoutOnly) {
  FrameSetOptions o;
  o.cameras = 2;
  o.timeout_ns = 50;
  FrameSetAssembler a(o);
  std::vector<FrameSet> out;
  for (int k = 0; k < 10; ++k) a.Add(MakeFrame(0, k, 100 * k), 100 * k, &out);
  // Camera 1 never delivers: every set leaves incomplete once it has waited 50 ns.
  a.Poll(100 * 9 + 50, &out);
  ASSERT_EQ(out.size(), 10u);
  for (int k = 0; k < 10; ++k) {
    EXPECT_EQ(out[k].trigger_id, k);
    EXPECT_FALSE(out[k].complete());
  }
  EXPECT_EQ(a.counters().missing_per_camera[1], 10u);
  EXPECT_EQ(a.open_sets(), 0u);
}

TEST(FrameSetAssembler, MatchesTimestampsWithinTheToleranceAndBoundsMemory) {
  FrameSetOptions o;
  o.cameras = 2;
  o.match = MatchBy::kTimestamp;
  o.tolerance_ns = 1000;
  o.max_open_sets = 4;
  FrameSetAssembler a(o);
  std::vector<FrameSet> out;
  // Period 10000 ns, the second camera 700 ns behind.
  for (int k = 0; k < 5; ++k) {
    a.Add(MakeFrame(0, -1, 10000 * k), 10000 * k, &out);
    a.Add(MakeFrame(1, -1, 10000 * k + 700), 10000 * k + 800, &out);
  }
  ASSERT_EQ(out.size(), 5u);
  for (const auto& s : out) {
    EXPECT_TRUE(s.complete());
    EXPECT_EQ(s.spread_ns, 700);
  }
  // Camera 1 stops: no more than max_open_sets sets wait.
  for (int k = 5; k < 20; ++k) a.Add(MakeFrame(0, -1, 10000 * k), 10000 * k, &out);
  EXPECT_LE(a.open_sets(), 4u);
  a.Flush(&out);
  EXPECT_EQ(out.size(), 20u);
  EXPECT_EQ(a.counters().incomplete, 15u);
  EXPECT_THROW(a.Add(MakeFrame(7, -1, 0), 0, &out), InputError);
}

CameraSettings Settings(double fps, TriggerMode mode = TriggerMode::kFreeRun) {
  CameraSettings s;
  s.width = 32;
  s.height = 24;
  s.frame_rate_hz = fps;
  s.exposure_us = 1000;
  s.trigger = mode;
  return s;
}

// A sim camera set to a wire format sends what an Aravis camera's driver delivers: the 16-bit
// format it unpacks into with only the wire format's bits (the words' high bits), each frame
// saying what it was sent in; the same camera set to Mono16 sends the same image in full.
TEST(SimCamera, AWireFormatArrivesAsTheDriverUnpacksIt) {
  for (const char* name : {"Mono12p", "Mono10Packed", "BayerGR12p"}) {
    SCOPED_TRACE(name);
    const WireFormat& wire = *WireFormatFromName(name);
    ManualClock clock(0);
    SimCameraOptions o;
    o.id = "SIMW";
    SimCamera sent(o, &clock, nullptr), full(o, &clock, nullptr);
    CameraSettings s = Settings(100);
    s.SetPixelFormat(name);
    sent.Configure(s);
    EXPECT_EQ(sent.settings().wire_format, name);
    s.SetPixelFormat(ToString(wire.stored));
    full.Configure(s);
    sent.Start(4);
    full.Start(4);
    std::optional<Frame> a, b;
    while (!a) a = sent.Pop(50'000'000);
    while (!b) b = full.Pop(50'000'000);
    ASSERT_EQ(a->info.frame_id, b->info.frame_id);
    EXPECT_EQ(a->info.pixel_format, wire.stored);
    EXPECT_EQ(a->info.sent_pfnc, wire.pfnc);
    EXPECT_EQ(b->info.sent_pfnc, PfncOf(wire.stored));
    EXPECT_EQ(WireBitsOf(a->info, ""), wire.bits);
    ASSERT_EQ(a->bytes(), b->bytes());
    const std::uint16_t keep = static_cast<std::uint16_t>(0xffffu << (16 - wire.bits));
    int differ = 0;
    for (std::size_t i = 0; i + 1 < a->bytes(); i += 2) {
      std::uint16_t va, vb;
      std::memcpy(&va, a->data->data() + i, 2);
      std::memcpy(&vb, b->data->data() + i, 2);
      ASSERT_EQ(va, vb & keep) << "word " << i / 2;
      differ += va != vb;
    }
    EXPECT_GT(differ, 0);  // the pattern has low bits to lose
  }
}

TEST(SimCamera, FreeRunsAtItsRateWithDriftJitterAndAWrappingCounter) {
  ManualClock clock(1'000'000'000);
  SimCameraOptions o;
  o.drift_ppm = 50;
  o.jitter_ns = 20'000;
  o.first_frame_id = 65530;
  SimCamera cam(o, &clock, nullptr);
  cam.Configure(Settings(100));
  cam.Start(8);
  std::vector<Frame> frames;
  while (clock.MonotonicNs() < 2'000'000'000) {
    auto f = cam.Pop(50'000'000);
    if (f) frames.push_back(*f);
  }
  // One second at 100 fps.
  EXPECT_NEAR(static_cast<double>(frames.size()), 100.0, 1.0);
  for (std::size_t i = 1; i < frames.size(); ++i) {
    EXPECT_EQ(frames[i].info.frame_id, frames[i - 1].info.frame_id + 1);  // across the wrap
    const double dt =
        double(frames[i].info.device_timestamp_ns - frames[i - 1].info.device_timestamp_ns);
    EXPECT_NEAR(dt, 1e7, 6 * 20'000 * 1.5);  // period +- jitter
    EXPECT_GE(frames[i].info.host_monotonic_ns, frames[i - 1].info.host_monotonic_ns);
  }
  EXPECT_LT(frames.back().info.device_frame_id, 100u);  // it wrapped
  // Drift: over the run the device clock gains 50 ppm on the host's.
  const auto& a = frames.front().info;
  const auto& b = frames.back().info;
  const double host_span = double(b.device_timestamp_ns - a.device_timestamp_ns) / (1 + 50e-6);
  EXPECT_NEAR(double(b.device_timestamp_ns - a.device_timestamp_ns) - host_span, host_span * 50e-6,
              1000);
  // The bytes: the test pattern carries the camera and frame id.
  ASSERT_EQ(frames[3].bytes(), 32u * 24u);
  std::uint64_t id = 0;
  for (int i = 0; i < 8; ++i) id |= std::uint64_t((*frames[3].data)[8 + i]) << (8 * i);
  EXPECT_EQ(id, frames[3].info.frame_id);
  EXPECT_EQ(cam.counters().missing_by_id, 0u);
}

// Free-running cameras at one rate started a few milliseconds apart, as a daemon starts them one
// by one, expose in phase: their periods fall on one grid of the clock's time (multiples of the
// period), so a set matched by timestamp holds all of them however slowly the host started them
// (7 ms a camera under ThreadSanitizer on a slow host split every set of a 30 fps free run).
TEST(SimCamera, FreeRunningCamerasStartedApartExposeInPhase) {
  ManualClock clock(5'000'000'123);
  SimCameraOptions o;  // no jitter, no drift
  SimCamera first(o, &clock, nullptr), second(o, &clock, nullptr);
  first.Configure(Settings(30));
  second.Configure(Settings(30));
  first.Start(4);
  clock.Advance(7'000'000);
  second.Start(4);
  std::optional<Frame> a, b;
  while (!a) a = first.Pop(50'000'000);
  while (!b) b = second.Pop(50'000'000);
  const std::int64_t period = 33'333'333;  // 1e9 / 30, rounded
  EXPECT_EQ(a->info.device_timestamp_ns, b->info.device_timestamp_ns);
  EXPECT_EQ(a->info.device_timestamp_ns % period, 0);
  EXPECT_GE(a->info.device_timestamp_ns, 5'000'000'123);
  EXPECT_LT(a->info.device_timestamp_ns, 5'000'000'123 + period);
}

// Frame buffers come back to their pool (frame_pool.h): released frames are reused without a new
// allocation, a buffer outlives its pool, the pool keeps no more idle buffers than asked, and a
// camera that delivers frames as they are released allocates nothing after its start (the counter
// the daemon reports), and no more than the frames held at once beyond its buffers when they pile
// up; a reused buffer shows the new frame, not the old.
TEST(FrameBufferPool, BuffersComeBackAndOutliveThePool) {
  {
    FrameBufferPool pool(2, 100, 3);
    auto a = pool.Acquire(100), b = pool.Acquire(100), c = pool.Acquire(80);
    EXPECT_EQ(pool.stats().allocated, 1u);  // two were made up front
    EXPECT_EQ(c->size(), 80u);
    const auto* kept = a.get();
    a.reset();
    EXPECT_EQ(pool.stats().idle, 1u);
    auto d = pool.Acquire(100);
    EXPECT_EQ(d.get(), kept);  // the same buffer, no allocation
    EXPECT_EQ(pool.stats().allocated, 1u);
    auto e = pool.Acquire(1000);  // larger than any idle buffer: a new one
    EXPECT_EQ(pool.stats().allocated, 2u);
    b.reset();
    c.reset();
    d.reset();
    e.reset();
    EXPECT_EQ(pool.stats().idle, 3u);  // `keep`: the fourth was freed
    EXPECT_EQ(pool.stats().acquired, 5u);
  }
  std::shared_ptr<std::vector<std::uint8_t>> survivor;
  {
    FrameBufferPool pool(1, 10);
    survivor = pool.Acquire(10);
  }
  (*survivor)[0] = 1;  // still valid after its pool is gone; freed when dropped
  survivor.reset();
}

TEST(SimCamera, DeliversFramesInPooledBuffers) {
  ManualClock clock(0);
  SimCameraOptions o;
  SimCamera cam(o, &clock, nullptr);
  cam.Configure(Settings(100));
  cam.Start(4);
  int popped = 0;
  while (popped < 50) {
    auto f = cam.Pop(50'000'000);
    if (!f) continue;
    ++popped;
    std::uint64_t id = 0;  // the test pattern's frame id: this frame's, not a reused buffer's
    for (int i = 0; i < 8; ++i) id |= std::uint64_t((*f->data)[8 + i]) << (8 * i);
    EXPECT_EQ(id, f->info.frame_id);
  }
  EXPECT_EQ(cam.counters().buffers_allocated, 0u);
  std::vector<Frame> held;  // ten frames held at once: six beyond the camera's four buffers
  while (held.size() < 10)
    if (auto f = cam.Pop(50'000'000)) held.push_back(*f);
  EXPECT_EQ(cam.counters().buffers_allocated, 6u);
  held.clear();
  for (int n = 0; n < 30;)
    if (cam.Pop(50'000'000)) ++n;
  EXPECT_EQ(cam.counters().buffers_allocated, 6u);
}

TEST(SimCamera, RepeatedOutagesComeAndGoAtTheirTimes) {
  ManualClock clock(0);
  SimCameraOptions o;
  // Gone in [1, 2) s and [3, 4) s at 100 fps: frames only in [0, 1), [2, 3) and [4, 5).
  o.outages = {{1'000'000'000, 2'000'000'000}, {3'000'000'000, 4'000'000'000}};
  SimCamera cam(o, &clock, nullptr);
  cam.Configure(Settings(100));
  cam.Start(4);
  int got = 0, got_while_gone = 0;
  std::vector<std::pair<double, bool>> seen;  // (time, connected) at a few moments
  while (clock.MonotonicNs() < 5'000'000'000) {
    const std::int64_t now = clock.MonotonicNs();
    if (now % 500'000'000 < 10'000'000) seen.emplace_back(now * 1e-9, cam.connected());
    if (auto f = cam.Pop(10'000'000)) {
      ++got;
      // Received an exposure and a transfer (a few ms) after its exposure started.
      const double t = f->info.host_monotonic_ns * 1e-9;
      if ((t >= 1.05 && t < 2) || (t >= 3.05 && t < 4)) ++got_while_gone;
    }
  }
  EXPECT_EQ(got_while_gone, 0);
  EXPECT_NEAR(got, 300, 3);  // three connected seconds at 100 fps
  for (const auto& [t, connected] : seen) {
    const bool want = !((t >= 1 && t < 2) || (t >= 3 && t < 4));
    EXPECT_EQ(connected, want) << "at " << t << " s";
  }
  SimCameraOptions bad;
  bad.outages = {{2'000'000'000, -1}, {3'000'000'000, 4'000'000'000}};  // after "for good"
  EXPECT_THROW(SimCamera(bad, &clock, nullptr), InputError);
}

TEST(SimCamera, FirstInvalidOutageNamesTheFirstOneOutOfOrder) {
  EXPECT_EQ(FirstInvalidOutage({}), -1);
  EXPECT_EQ(FirstInvalidOutage({{0, 1}, {1, 2}, {5, -1}}), -1);  // touching is allowed
  EXPECT_EQ(FirstInvalidOutage({{-1, 5}}), 0);                   // before the start
  EXPECT_EQ(FirstInvalidOutage({{0, 1}, {3, 3}}), 1);            // ends as it starts
  EXPECT_EQ(FirstInvalidOutage({{0, 4}, {3, 6}, {2, 1}}), 1);    // overlaps the one before
  EXPECT_EQ(FirstInvalidOutage({{0, 1}, {2, -1}, {9, 10}}), 2);  // after one for good
}

TEST(SimCamera, DropsAreSeenInFrameIdsAndTimestampsAndDisconnectStopsFrames) {
  ManualClock clock(0);
  SimCameraOptions o;
  o.drop_probability = 0.1;
  o.outages = {{3'000'000'000, -1}};
  o.seed = 5;
  SimCamera cam(o, &clock, nullptr);
  cam.Configure(Settings(200));
  cam.Start(4);
  int got = 0;
  while (clock.MonotonicNs() < 4'000'000'000) {
    if (cam.Pop(10'000'000)) ++got;
  }
  const StreamCounters c = cam.counters();
  // About 600 exposures before the disconnect, 10% dropped; both detectors see every drop.
  EXPECT_EQ(static_cast<std::uint64_t>(got) + c.missing_by_id, 600u);
  EXPECT_NEAR(double(c.missing_by_id), 60.0, 25.0);
  EXPECT_EQ(c.missing_by_time, c.missing_by_id);
  EXPECT_FALSE(cam.connected());
  EXPECT_FALSE(cam.Pop(100'000'000).has_value());
}

TEST(SimCamera, HardwareTriggerBusDrivesAllCamerasIntoCompleteSets) {
  ManualClock clock(0);
  SimTriggerBus bus;
  std::vector<std::unique_ptr<SimCamera>> cams;
  for (int c = 0; c < 3; ++c) {
    SimCameraOptions o;
    o.id = "sim" + std::to_string(c);
    o.camera_index = c;
    o.seed = 10 + c;
    o.jitter_ns = 5000;
    o.device_offset_ns = 1000 * c;
    cams.push_back(std::make_unique<SimCamera>(o, &clock, &bus));
    cams.back()->Configure(Settings(100, TriggerMode::kHardware));
    cams.back()->Start(4);
  }
  for (int k = 0; k < 50; ++k) bus.Fire(k, 1'000'000 + 20'000'000LL * k);
  FrameSetOptions fo;
  fo.cameras = 3;
  FrameSetAssembler assembler(fo);
  std::vector<FrameSet> sets;
  for (int round = 0; round < 600; ++round)  // 3 ms of clock per round at most
    for (auto& cam : cams)
      if (auto f = cam->Pop(1'000'000)) assembler.Add(*f, clock.MonotonicNs(), &sets);
  assembler.Flush(&sets);
  ASSERT_EQ(sets.size(), 50u);
  for (int k = 0; k < 50; ++k) {
    EXPECT_EQ(sets[k].trigger_id, k);
    EXPECT_TRUE(sets[k].complete());
    EXPECT_LT(sets[k].spread_ns, 2000 + 6 * 5000);  // offsets plus jitter
  }
  // A camera without a bus cannot be put on a hardware trigger.
  SimCamera lone(SimCameraOptions{}, &clock, nullptr);
  EXPECT_THROW(lone.Configure(Settings(100, TriggerMode::kHardware)), InputError);
}

TEST(SimCamera, SoftwareTriggerAndBadSettings) {
  ManualClock clock(0);
  SimCamera cam(SimCameraOptions{}, &clock, nullptr);
  cam.Configure(Settings(50, TriggerMode::kSoftware));
  cam.Start(2);
  EXPECT_FALSE(cam.Pop(100'000'000).has_value());  // no trigger, no frame
  cam.SoftwareTrigger(7);
  auto f = cam.Pop(100'000'000);
  ASSERT_TRUE(f.has_value());
  EXPECT_EQ(f->info.trigger_id, 7);
  // Triggers faster than the maximum rate are ignored, as a real sensor would.
  clock.Advance(50'000'000);
  cam.SoftwareTrigger(8);
  cam.SoftwareTrigger(9);
  int frames = 0;
  while (cam.Pop(50'000'000)) ++frames;
  EXPECT_EQ(frames, 1);
  cam.Stop();
  CameraSettings bad = Settings(100);
  bad.exposure_us = 20000;  // longer than the 10 ms period
  EXPECT_THROW(cam.Configure(bad), InputError);
  bad = Settings(0);
  EXPECT_THROW(cam.Configure(bad), InputError);
  SimCameraOptions wrong;
  wrong.drop_probability = 2;
  EXPECT_THROW(SimCamera(wrong, &clock, nullptr), InputError);
}

// The pattern is the formula its header states, byte by byte (a test decodes frames with it), in
// a pooled buffer that held a larger frame of another format before.
TEST(SimCamera, TestPatternIsTheStatedGradientWithItsStamp) {
  const ImageSource pattern = TestPatternSource();
  std::vector<std::uint8_t> bytes(5000000, 0xAB);
  for (PixelFormat format : {PixelFormat::kRgb8, PixelFormat::kMono8, PixelFormat::kMono16}) {
    FrameInfo info;
    info.pixel_format = format;
    info.width = 601;  // longer than the 256-step period, and odd
    info.height = 37;
    info.camera = 5;
    info.frame_id = 1234567;
    pattern(info, &bytes);
    const int bpp = BytesPerPixel(format);
    ASSERT_EQ(bytes.size(), std::size_t(601) * 37 * bpp);
    int wrong = 0;
    for (int y = 0; y < 37; ++y)
      for (int x = 0; x < 601; ++x)
        for (int b = 0; b < bpp; ++b) {
          const std::size_t i = (std::size_t(y) * 601 + x) * bpp + b;
          if (i < 16) continue;
          const long long v = x + 2LL * y + 3LL * 1234567 + 50 * 5 + 7 * b;
          wrong += bytes[i] != static_cast<std::uint8_t>(v % 256);
        }
    EXPECT_EQ(wrong, 0) << ToString(format);
    EXPECT_EQ(bytes[0], 5);
    EXPECT_EQ(bytes[8], 1234567 & 0xFF);
    EXPECT_EQ(bytes[9], (1234567 >> 8) & 0xFF);
  }
}

}  // namespace
}  // namespace flamerig
