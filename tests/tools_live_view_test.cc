// The capture daemon's live view in a real browser (Debian's chromium, headless): the page shows
// every camera's image, and a click on its Start button starts a recording. The screenshot is kept
// in build/testdata/live_view/ for a person to look at.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>
#include <string>

#include "core/image.h"
#include "tests/shell_util.h"

namespace {

namespace fs = std::filesystem;

using flamerig_test::Result;
using flamerig_test::Shell;

// Chromium, headless, with its own profile; `what` is --dump-dom or --screenshot=FILE.
Result Chromium(const std::string& what, const std::string& url, const fs::path& profile) {
  return Shell(
      "timeout 120 chromium --headless --no-sandbox --disable-gpu --disable-quic "
      "--no-first-run --window-size=1200,900 --virtual-time-budget=6000 --user-data-dir=" +
      profile.string() + " " + what + " '" + url + "'");
}

TEST(LiveViewBrowser, ThePageShowsEveryCameraAndAClickStartsARecording) {
  if (Shell("command -v chromium").status != 0)
    GTEST_SKIP() << "no chromium (scripts/install-deps.sh installs it)";
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_lv_browser_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::ofstream(dir / "rig.yaml") << "data_dir: rec\nsync: software-trigger\ntrigger_rate_hz: 20\n"
                                     "cameras:\n"
                                     "  - {name: left, width: 160, height: 120}\n"
                                     "  - {name: right, width: 160, height: 120, pixel_format: "
                                     "BayerRG8}\n"
                                     "  - {name: deep, width: 160, height: 120, pixel_format: "
                                     "Mono16}\n";
  const std::string config = (dir / "rig.yaml").string();
  FILE* daemon = popen((std::string(FLAMERIG_BINARY) + " capture --config " + config +
                        " --live-view 127.0.0.1:0 --duration 60 2>&1")
                           .c_str(),
                       "r");
  ASSERT_NE(daemon, nullptr);
  std::string log, url;
  std::array<char, 4096> line;
  const std::regex at(R"(live view at (http://\S+))");
  while (url.empty() && fgets(line.data(), line.size(), daemon)) {
    log += line.data();
    std::smatch m;
    const std::string text = line.data();
    if (std::regex_search(text, m, at)) url = m[1];
  }
  ASSERT_FALSE(url.empty()) << log;
  usleep(500'000);  // frames from every camera

  // Every camera's image loaded (the page counts its images' load events), and a screenshot.
  const Result dom = Chromium("--dump-dom", url, dir / "profile1");
  EXPECT_NE(dom.output.find("cameras shown: deep,left,right"), std::string::npos) << dom.output;
  const fs::path shots = fs::path(FLAMERIG_TEST_DATA_DIR) / "live_view";
  fs::create_directories(shots);
  const fs::path shot = shots / "live_view.png";
  fs::remove(shot);
  const Result screenshot = Chromium("--screenshot=" + shot.string(), url, dir / "profile2");
  ASSERT_TRUE(fs::exists(shot)) << screenshot.output;
  const flamerig::ImageU8 image = flamerig::ReadImageU8(shot.string());
  // The dark page with three camera images of the test pattern (white and grey ramps) on it, and
  // their clipped pixels in red.
  double bright = 0, dark = 0, red = 0;
  const double n = double(image.width) * image.height;
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) {
      const int r = image.at(x, y, 0), g = image.at(x, y, 1), b = image.at(x, y, 2);
      bright += (r > 200 && g > 200 && b > 200) / n;
      dark += (r + g + b < 150) / n;
      red += (r > 200 && g < 60 && b < 60) / n;
    }
  EXPECT_GT(bright, 0.03) << shot;
  EXPECT_GT(dark, 0.4) << shot;
  EXPECT_GT(red, 0.0005) << shot;

  // A click on Start (the page presses its own button when asked by ?click=start).
  const std::string click =
      url + (url.find('?') == std::string::npos ? "?" : "&") + "click=start&name=from_browser";
  Chromium("--dump-dom", click, dir / "profile3");
  const Result status =
      Shell(std::string(FLAMERIG_BINARY) + " ctl --config " + config + " status yaml");
  EXPECT_NE(status.output.find("recording: true"), std::string::npos) << status.output;
  EXPECT_NE(status.output.find("from_browser"), std::string::npos) << status.output;
  Shell(std::string(FLAMERIG_BINARY) + " ctl --config " + config + " shutdown");
  while (fgets(line.data(), line.size(), daemon)) log += line.data();
  const int exit = pclose(daemon);
  EXPECT_TRUE(WIFEXITED(exit) && WEXITSTATUS(exit) == 0) << log;
  EXPECT_TRUE(fs::exists(dir / "rec" / "from_browser" / "metadata.yaml")) << log;
  fs::remove_all(dir);
}

}  // namespace
