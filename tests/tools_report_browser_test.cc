// The reports as a person sees them: each command's index.html (reconstruct, calibrate, fit,
// run) opened in headless Chromium (Debian's chromium) and its screenshot looked at: the page is
// not blank, its pictures loaded (fire tiles show their orange, the calibration's coverage maps
// their dark background), every picture it names is there. The screenshots are kept in
// build/testdata/report_screenshots/ for a person to look at too.
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <regex>
#include <sstream>
#include <string>

#include "core/image.h"
#include "tests/shell_util.h"

namespace {

namespace fs = std::filesystem;

using flamerig_test::Flamerig;
using flamerig_test::Result;
using flamerig_test::Shell;

// What a screenshot shows: the share of pixels that are not page white, that look like fire
// (orange), that are dark (black camera backgrounds, the slices' grey; text too), and that have
// the colour of the calibration coverage maps' covered cells (RGB 50, 60, 70).
struct Look {
  double ink = 0, fire = 0, dark = 0, covered = 0;
};

Look LookAt(const flamerig::ImageU8& shot) {
  Look look;
  const double n = double(shot.width) * shot.height;
  for (int y = 0; y < shot.height; ++y)
    for (int x = 0; x < shot.width; ++x) {
      const int r = shot.at(x, y, 0), g = shot.at(x, y, 1), b = shot.at(x, y, 2);
      if (r + g + b < 3 * 245) look.ink += 1 / n;
      if (r > 150 && g > 50 && g < 190 && b < 90 && r > g + 40) look.fire += 1 / n;
      if (r + g + b < 200) look.dark += 1 / n;
      if (std::abs(r - 50) <= 8 && std::abs(g - 60) <= 8 && std::abs(b - 70) <= 8)
        look.covered += 1 / n;
    }
  return look;
}

// Every <img src> and <a href> of the page that is a file beside it exists.
void ExpectLinkedFilesExist(const fs::path& page) {
  std::ifstream in(page);
  std::stringstream text;
  text << in.rdbuf();
  const std::string html = text.str();
  const std::regex link("(src|href)=\"([^\"]+)\"");
  int images = 0;
  for (auto it = std::sregex_iterator(html.begin(), html.end(), link); it != std::sregex_iterator();
       ++it) {
    const std::string target = (*it)[2];
    if ((*it)[1] == "src") ++images;
    EXPECT_TRUE(fs::exists(page.parent_path() / target)) << page << " names " << target;
  }
  EXPECT_GT(images, 0) << page;
}

flamerig::ImageU8 Screenshot(const fs::path& page, const std::string& name) {
  const fs::path dir = fs::path(FLAMERIG_TEST_DATA_DIR) / "report_screenshots";
  fs::create_directories(dir);
  const fs::path shot = dir / (name + ".png");
  fs::remove(shot);
  const fs::path profile = fs::temp_directory_path() / ("flamerig_chromium_" + name);
  fs::remove_all(profile);
  const Result r = Shell(
      "timeout 180 chromium --headless --no-sandbox --disable-gpu --disable-quic --no-first-run "
      "--disable-background-networking --disable-component-update --disable-sync "
      "--hide-scrollbars --window-size=1280,2400 --user-data-dir=" +
      profile.string() + " --screenshot=" + shot.string() + " file://" + page.string());
  fs::remove_all(profile);
  EXPECT_TRUE(fs::exists(shot)) << "chromium (install it: scripts/install-deps.sh) said:\n"
                                << r.output;
  if (!fs::exists(shot)) return flamerig::ImageU8();
  return flamerig::ReadImageU8(shot.string(), 3);
}

TEST(ReportBrowser, EveryReportRendersWithItsPicturesInChromium) {
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_report_browser_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::ofstream((dir / "sim.yaml").string())
      << "simulate:\n  frames: 2\n  grid_resolution: 20\n  rig: {cameras: 3, azimuths_deg: [0, "
         "90, 45], width: 160, height: 120}\n  absorption: grey\n";
  const Result sim = Flamerig("simulate --config " + (dir / "sim.yaml").string() + " --out " +
                              (dir / "data").string());
  ASSERT_EQ(sim.status, 0) << sim.output;
  const std::string rig = (dir / "data" / "rig.yaml").string();
  const std::string frame = (dir / "data" / "frames" / "frame_000000").string();
  const std::string truth = (dir / "data" / "truth" / "frame_000000.vdb").string();
  const Result reconstruct = Flamerig(
      "reconstruct --rig " + rig + " --images " + frame + " --out " + (dir / "e.vdb").string() +
      " --resolution 20 --truth " + truth + " --report " + (dir / "reconstruct").string());
  ASSERT_EQ(reconstruct.status, 0) << reconstruct.output;
  const Result calibrate =
      Flamerig("calibrate --images " + (dir / "data" / "calibration").string() + " --out " +
               (dir / "calibrate").string());
  ASSERT_EQ(calibrate.status, 0) << calibrate.output;
  const Result fit =
      Flamerig("fit --rig " + rig + " --images " + frame + " --out " +
               (dir / "fit" / "f.vdb").string() + " --holdout cam2 --resolution 20 --truth " +
               truth + " --report " + (dir / "fit" / "report").string());
  ASSERT_EQ(fit.status, 0) << fit.output;
  // The same fit axisymmetric: its page has the radial profile too.
  const Result rings =
      Flamerig("fit --rig " + rig + " --images " + frame + " --out " +
               (dir / "rings" / "f.vdb").string() + " --holdout cam2 --resolution 20 --truth " +
               truth + " --report " + (dir / "rings" / "report").string() + " --axisymmetric");
  ASSERT_EQ(rings.status, 0) << rings.output;
  ASSERT_TRUE(fs::exists(dir / "rings" / "report" / "profile.png"));
  const Result run =
      Flamerig("run --images " + (dir / "data" / "frames").string() + " --rig " + rig +
               " --resolution 20 --truth " + (dir / "data" / "truth").string() + " --out " +
               (dir / "run").string());
  ASSERT_EQ(run.status, 0) << run.output;

  struct Page {
    std::string name;
    fs::path path;
    bool fire;  // shows fire images
  };
  for (const Page& page : {Page{"reconstruct", dir / "reconstruct" / "index.html", true},
                           Page{"calibrate", dir / "calibrate" / "index.html", false},
                           Page{"fit", dir / "fit" / "report" / "index.html", true},
                           Page{"axisymmetric_fit", dir / "rings" / "report" / "index.html", true},
                           Page{"run", dir / "run" / "report" / "index.html", true}}) {
    SCOPED_TRACE(page.name);
    ASSERT_TRUE(fs::exists(page.path));
    ExpectLinkedFilesExist(page.path);
    const flamerig::ImageU8 shot = Screenshot(page.path, page.name);
    ASSERT_FALSE(shot.empty());
    EXPECT_EQ(shot.width, 1280);
    const Look look = LookAt(shot);
    std::printf("%s: %.1f%% ink, %.2f%% fire, %.1f%% dark, %.2f%% coverage cells\n",
                page.name.c_str(), 100 * look.ink, 100 * look.fire, 100 * look.dark,
                100 * look.covered);
    EXPECT_GT(look.ink, 0.05) << "a blank page";
    // Whether its pictures loaded: the pictures' own colours, which text and Chromium's broken
    // image icons do not have (measured: a calibration page whose pictures were missing had no
    // coverage-cell pixel and 1.8% dark ones; the pages here have 2.5 to 26% dark).
    if (page.fire) {
      EXPECT_GT(look.dark, 0.10) << "its camera views did not load";
      EXPECT_GT(look.fire, 0.001) << "no fire in its pictures";
    } else {
      EXPECT_GT(look.covered, 0.002) << "its coverage maps did not load";
    }
  }
  fs::remove_all(dir);
}

}  // namespace
