// The live view's server without a browser: histograms against counts made by hand, the API's
// answers against the daemon's own state, the token, and refusals (tools_live_view_test opens the
// page in Chromium).
#include <gtest/gtest.h>
#include <httplib.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <thread>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "acquisition/capture.h"
#include "acquisition/live_view.h"
#include "core/error.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

Frame MakeFrame(PixelFormat format, int width, int height, const std::vector<std::uint8_t>& bytes) {
  Frame f;
  f.info.pixel_format = format;
  f.info.width = width;
  f.info.height = height;
  f.data = std::make_shared<std::vector<std::uint8_t>>(bytes);
  return f;
}

TEST(LiveView, HistogramsCountWhatTheyShould) {
  // Mono8 4x2, every pixel: 0, 10, 10, 255 / 255, 255, 7, 10.
  const FrameHistogram m =
      HistogramOf(MakeFrame(PixelFormat::kMono8, 4, 2, {0, 10, 10, 255, 255, 255, 7, 10}), 1);
  EXPECT_EQ(m.sampled, 8u);
  EXPECT_EQ(m.bins[10], 3u);
  EXPECT_EQ(m.bins[255], 3u);
  EXPECT_EQ(m.clipped, 3u);
  EXPECT_DOUBLE_EQ(m.saturated_share(), 3.0 / 8);
  // Every second pixel of every second row: (0,0) and (2,0).
  const FrameHistogram sub =
      HistogramOf(MakeFrame(PixelFormat::kMono8, 4, 2, {0, 10, 10, 255, 255, 255, 7, 10}), 2);
  EXPECT_EQ(sub.sampled, 2u);
  EXPECT_EQ(sub.bins[0] + sub.bins[10], 2u);
  // Mono16: the top 8 bits; only 65535 is clipped (65280 is not).
  std::vector<std::uint8_t> wide(2 * 3);
  const std::uint16_t v[3] = {0x0102, 0xff00, 0xffff};
  std::memcpy(wide.data(), v, sizeof v);
  const FrameHistogram w = HistogramOf(MakeFrame(PixelFormat::kMono16, 3, 1, wide), 1);
  EXPECT_EQ(w.bins[1], 1u);
  EXPECT_EQ(w.bins[255], 2u);
  EXPECT_EQ(w.clipped, 1u);
  // RGB: every channel.
  const FrameHistogram rgb = HistogramOf(MakeFrame(PixelFormat::kRgb8, 1, 1, {255, 3, 3}), 1);
  EXPECT_EQ(rgb.sampled, 3u);
  EXPECT_EQ(rgb.bins[3], 2u);
  EXPECT_EQ(rgb.clipped, 1u);
}

TEST(LiveView, AWireFormatsFullScaleIsWhatItsBrightestPixelUnpacksTo) {
  EXPECT_EQ(FullScaleValue(PixelFormat::kMono8), 255);
  EXPECT_EQ(FullScaleValue(PixelFormat::kRgb8), 255);
  EXPECT_EQ(FullScaleValue(PixelFormat::kBayerRg8), 255);
  EXPECT_EQ(FullScaleValue(PixelFormat::kMono16), 65535);
  EXPECT_EQ(FullScaleValue(PixelFormat::kBayerGb16), 65535);
  // A name that is no wire format, or one unpacked into another format, is not the frame's.
  EXPECT_EQ(FullScaleValue(PixelFormat::kMono16, "Mono16"), 65535);
  EXPECT_EQ(FullScaleValue(PixelFormat::kMono16, "BayerRG12p"), 65535);
  EXPECT_EQ(FullScaleValue(PixelFormat::kMono8, "Mono12p"), 255);
  EXPECT_EQ(WireBitsOf(PixelFormat::kBayerRg16, "BayerRG12p"), 12);
  EXPECT_EQ(WireBitsOf(PixelFormat::kMono16, "Mono10Packed"), 10);
  EXPECT_EQ(WireBitsOf(PixelFormat::kMono16, "BayerRG12p"), 0);
  EXPECT_EQ(WireBitsOf(PixelFormat::kMono16, "Mono16"), 0);
  EXPECT_EQ(WireBitsOf(PixelFormat::kMono16, ""), 0);
  EXPECT_EQ(WireBitsOf(PixelFormat::kBayerRg8, "BayerRG12p"), 0);
  // A mirrored camera sends its wire format in another Bayer layout than its settings name.
  ASSERT_NE(WireFormatOfFrame(PixelFormat::kBayerGr16, "BayerRG12p"), nullptr);
  EXPECT_STREQ(WireFormatOfFrame(PixelFormat::kBayerGr16, "BayerRG12p")->name, "BayerGR12p");
  ASSERT_NE(WireFormatOfFrame(PixelFormat::kBayerGb16, "BayerRG10Packed"), nullptr);
  EXPECT_STREQ(WireFormatOfFrame(PixelFormat::kBayerGb16, "BayerRG10Packed")->name,
               "BayerGB10Packed");
  EXPECT_EQ(FullScaleValue(PixelFormat::kBayerBg16, "BayerRG12"), 0xfff0);
  EXPECT_EQ(WireFormatOfFrame(PixelFormat::kBayerRg16, "Mono12p"), nullptr);
  // A frame that says what it was sent in is taken at its word, whatever the settings name; one
  // that does not say, as the settings do.
  FrameInfo info;
  info.pixel_format = PixelFormat::kMono16;
  EXPECT_EQ(FullScaleValue(info, "Mono12p"), 0xfff0);  // sent_pfnc 0: the settings' rule
  info.sent_pfnc = WireFormatFromName("Mono10p")->pfnc;
  EXPECT_EQ(FullScaleValue(info, "Mono12p"), 0xffc0);
  EXPECT_EQ(WireBitsOf(info, ""), 10);
  EXPECT_STREQ(WireFormatOfFrame(info, "Mono12p")->name, "Mono10p");
  info.sent_pfnc = 0x7fff0001u;  // a code this flamerig does not know: as the settings say
  EXPECT_EQ(FullScaleValue(info, "Mono12p"), 0xfff0);
  info.sent_pfnc = PfncOf(PixelFormat::kMono16);  // a camera switched to Mono16 meanwhile
  EXPECT_EQ(FullScaleValue(info, "Mono12p"), 0xffff);
  EXPECT_EQ(WireFormatOfFrame(info, "Mono12p"), nullptr);
  info.sent_pfnc = WireFormatFromName("BayerRG12p")->pfnc;  // not what a Mono16 frame unpacks from
  EXPECT_EQ(WireBitsOf(info, "Mono12p"), 0);
  info.pixel_format = PixelFormat::kBayerRg16;
  EXPECT_EQ(WireBitsOf(info, ""), 12);
  info.pixel_format = PixelFormat::kRgb8;
  EXPECT_EQ(FullScaleValue(info, "BayerRG12p"), 255);
  // The oracle: every pixel of a frame sent at its wire format's highest value (all bits set),
  // unpacked as a camera's frames are.
  const std::pair<const char*, int> formats[] = {
      {"Mono10", 0xffc0},       {"Mono12", 0xfff0},         {"Mono14", 0xfffc},
      {"Mono10Packed", 0xffc0}, {"Mono12Packed", 0xfff0},   {"Mono10p", 0xffc0},
      {"Mono12p", 0xfff0},      {"BayerRG12p", 0xfff0},     {"BayerGB10Packed", 0xffc0},
      {"BayerBG10", 0xffc0},    {"BayerGR12Packed", 0xfff0}};
  for (const auto& [name, expected] : formats) {
    SCOPED_TRACE(name);
    const WireFormat* w = WireFormatFromName(name);
    ASSERT_NE(w, nullptr);
    const int width = 6, height = 2;
    std::vector<std::uint8_t> bytes(WireBytes(*w, width, height), 0xff);
    if (w->packing == WirePacking::kWords16)
      for (std::size_t i = 0; i + 1 < bytes.size(); i += 2) {
        const std::uint16_t top = static_cast<std::uint16_t>((1 << w->bits) - 1);
        std::memcpy(&bytes[i], &top, 2);
      }
    const std::vector<std::uint8_t> words =
        UnpackTo16Bit(*w, bytes.data(), bytes.size(), width, height);
    for (int i = 0; i < width * height; ++i) {
      std::uint16_t v;
      std::memcpy(&v, &words[2 * i], 2);
      ASSERT_EQ(v, FullScaleValue(w->stored, name)) << "pixel " << i;
    }
    EXPECT_EQ(FullScaleValue(w->stored, name), expected);
  }
}

TEST(LiveView, ATwelveBitTakeClipsAndShowsAtItsOwnFullScale) {
  // Mono16 words from a Mono12p camera: 0xFFF0 is its clipped value, which 65535 never reaches.
  std::vector<std::uint8_t> wide(2 * 3);
  const std::uint16_t v[3] = {0xfff0, 0x3ffc, 0xffe0};
  std::memcpy(wide.data(), v, sizeof v);
  const Frame f = MakeFrame(PixelFormat::kMono16, 3, 1, wide);
  EXPECT_EQ(HistogramOf(f, 1).clipped, 0u);
  const int full = FullScaleValue(PixelFormat::kMono16, "Mono12p");
  const FrameHistogram h = HistogramOf(f, 1, full);
  EXPECT_EQ(h.clipped, 1u);
  EXPECT_EQ(h.bins[255], 2u);
  // The picture: 16-bit values scaled so that the full scale is white: 0x3ffc * 255 / 0xfff0 =
  // 63.75 -> 64, 0xffe0 -> 254.6 -> 255; grey without the clipped pixels marked.
  const cv::Mat grey = PreviewImage(f, 1, full);
  ASSERT_EQ(grey.type(), CV_8UC1);
  EXPECT_EQ(grey.at<std::uint8_t>(0, 0), 255);
  EXPECT_EQ(grey.at<std::uint8_t>(0, 1), 64);
  EXPECT_EQ(grey.at<std::uint8_t>(0, 2), 255);
  const cv::Mat marked = PreviewImage(f, 1, full, /*mark_clipped=*/true);
  ASSERT_EQ(marked.type(), CV_8UC3);
  EXPECT_EQ(marked.at<cv::Vec3b>(0, 0), cv::Vec3b(0, 0, 255));  // red, in BGR
  EXPECT_EQ(marked.at<cv::Vec3b>(0, 1), cv::Vec3b(64, 64, 64));
  EXPECT_EQ(marked.at<cv::Vec3b>(0, 2), cv::Vec3b(255, 255, 255));  // bright, not clipped
  // Read as a full-scale 16-bit camera's, nothing is clipped.
  EXPECT_EQ(PreviewImage(f, 1, 0, true).at<cv::Vec3b>(0, 0), cv::Vec3b(255, 255, 255));
  // An RGB frame is turned into OpenCV's BGR; k shrinks it by area.
  const cv::Mat rgb = PreviewImage(
      MakeFrame(PixelFormat::kRgb8, 2, 2, {255, 0, 0, 255, 0, 0, 0, 0, 0, 0, 0, 0}), 2);
  ASSERT_EQ(rgb.size(), cv::Size(1, 1));
  EXPECT_EQ(rgb.at<cv::Vec3b>(0, 0), cv::Vec3b(0, 0, 128));
}

std::string Config(const fs::path& dir) {
  return "data_dir: " + dir.string() +
         "\nsync: software-trigger\ntrigger_rate_hz: 20\ncameras:\n"
         "  - {name: a, width: 64, height: 48}\n"
         "  - {name: b, width: 64, height: 48, pixel_format: Mono16}\n"
         "  - {name: c, width: 160, height: 60, pixel_format: Mono12p}\n";
}

TEST(LiveView, TheApiAnswersFromTheDaemonAndATokenGuardsIt) {
  const fs::path dir = fs::temp_directory_path() / ("flamerig_lv_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const CaptureConfig config = CaptureConfig::Parse(Config(dir), "test");
  SystemClock clock;
  CaptureDaemon daemon(config, MakeCameras(config, {&clock, nullptr}), &clock, nullptr);
  daemon.Start();
  LiveViewOptions o;
  o.allow_remote = true;  // on loopback still: the token is what is tested
  o.token = "s3cret";
  LiveViewServer server(&daemon, o);
  EXPECT_EQ(server.url(), "http://127.0.0.1:" + std::to_string(server.port()) + "/?token=s3cret");
  httplib::Client client("127.0.0.1", server.port());
  std::this_thread::sleep_for(std::chrono::milliseconds(400));
  EXPECT_EQ(client.Get("/api/status")->status, 403);
  EXPECT_EQ(client.Get("/api/status?token=wrong")->status, 403);
  auto status = client.Get("/api/status?token=s3cret");
  ASSERT_TRUE(status);
  ASSERT_EQ(status->status, 200);
  const nlohmann::json j = nlohmann::json::parse(status->body);
  EXPECT_TRUE(j.at("running").get<bool>());
  EXPECT_EQ(j.at("cameras")[1].at("name"), "b");
  // The preview is the camera's image at 1/k size, a PNG.
  auto png = client.Get("/api/preview?camera=b&k=2&token=s3cret");
  ASSERT_EQ(png->status, 200) << png->body;
  const cv::Mat image =
      cv::imdecode(std::vector<std::uint8_t>(png->body.begin(), png->body.end()), cv::IMREAD_COLOR);
  EXPECT_EQ(image.cols, 32);
  EXPECT_EQ(image.rows, 24);
  // A camera sending Mono12p (its test pattern's words reach 0xFFF8 but keep 12 bits: 0xFFF0,
  // on some pixel of every frame at this size) shows those pixels clipped in red, at its own
  // full scale; the Mono16 camera's never reach 65535.
  auto red_pixels = [&](const std::string& camera) {
    auto r = client.Get("/api/preview?camera=" + camera + "&k=1&token=s3cret");
    EXPECT_EQ(r->status, 200) << r->body;
    const cv::Mat bgr =
        cv::imdecode(std::vector<std::uint8_t>(r->body.begin(), r->body.end()), cv::IMREAD_COLOR);
    int red = 0;
    for (int y = 0; y < bgr.rows; ++y)
      for (int x = 0; x < bgr.cols; ++x) {
        const cv::Vec3b p = bgr.at<cv::Vec3b>(y, x);
        red += p[2] > 200 && p[1] < 60 && p[0] < 60;
      }
    return red;
  };
  EXPECT_GT(red_pixels("c"), 0);
  EXPECT_EQ(red_pixels("b"), 0);
  auto hist = client.Get("/api/histogram?camera=0&token=s3cret");
  ASSERT_EQ(hist->status, 200);
  const nlohmann::json h = nlohmann::json::parse(hist->body);
  EXPECT_EQ(h.at("bins").size(), 256u);
  EXPECT_EQ(h.at("sampled").get<std::uint64_t>(), 32u * 24u);
  // Controls: a recording started and stopped from the page; shutdown is not offered.
  httplib::Headers token = {{"X-Flamerig-Token", "s3cret"}};
  auto start = client.Post("/api/control", token, "start web", "text/plain");
  ASSERT_EQ(start->status, 200) << start->body;
  EXPECT_TRUE(daemon.status().recording);
  // Exposure changes live, the recording going on; a size needs a re-arm, refused mid-take.
  auto live = client.Post("/api/control", token, "apply a exposure_us 500", "text/plain");
  EXPECT_EQ(live->status, 200) << live->body;
  EXPECT_NE(live->body.find("live"), std::string::npos) << live->body;
  EXPECT_TRUE(daemon.status().recording);
  auto size = client.Post("/api/control", token, "apply a width 32", "text/plain");
  EXPECT_EQ(size->status, 400) << size->body;
  EXPECT_NE(size->body.find("not done while recording"), std::string::npos) << size->body;
  EXPECT_EQ(client.Post("/api/control", token, "stop", "text/plain")->status, 200);
  auto apply = client.Post("/api/control", token, "apply a width 32", "text/plain");
  EXPECT_EQ(apply->status, 200) << apply->body;
  EXPECT_NE(apply->body.find("re-armed"), std::string::npos) << apply->body;
  EXPECT_TRUE(daemon.running());
  EXPECT_EQ(daemon.config().cameras[0].settings.width, 32);
  EXPECT_EQ(daemon.config().cameras[0].settings.exposure_us, 500);
  EXPECT_EQ(client.Post("/api/control", token, "shutdown", "text/plain")->status, 400);
  EXPECT_EQ(client.Get("/api/preview?camera=z&token=s3cret")->status, 400);
  EXPECT_TRUE(fs::exists(dir / "web"));
  // A public address without allow_remote is refused.
  LiveViewOptions open;
  open.host = "0.0.0.0";
  EXPECT_THROW(LiveViewServer(&daemon, open), InputError);
  daemon.Stop();
  fs::remove_all(dir);
}

}  // namespace
}  // namespace flamerig
