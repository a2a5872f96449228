// The reports' pictures and plots: gnuplot draws what was asked (sizes, labels, one style per
// series, a second axis, whole-number frame ticks, the data beside it), grids place each tile
// where its row and column say, and scale bars are round lengths of a readable size.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <string>

#include "core/image.h"
#include "pipeline/picture.h"
#include "pipeline/plot.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

fs::path TempDir() {
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_picture_" + std::to_string(::getpid()) + "_" +
                                   ::testing::UnitTest::GetInstance()->current_test_info()->name());
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

std::string Read(const fs::path& path) {
  std::ifstream in(path);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

PlotSpec FramesPlot(int series) {
  PlotSpec spec;
  spec.title = "Error over the frames";
  spec.x_label = "frame";
  spec.y_label = "mean Delta E";
  spec.y2_label = "temperature RMS error (K)";
  spec.integer_x = true;
  spec.width = 700;
  spec.height = 400;
  for (int s = 0; s < series; ++s) {
    PlotSeries p;
    p.name = "cam" + std::to_string(s) + "_view";  // an underscore: not a subscript
    for (int f = 0; f < 6; ++f) {
      p.x.push_back(f);
      p.y.push_back(s + 0.25 * f);
    }
    spec.series.push_back(p);
  }
  spec.series.back().right_axis = true;
  spec.series.front().y[2] = std::nan("");  // left out, not plotted as 0
  return spec;
}

TEST(Plot, GnuplotDrawsLabelledAxesOneStylePerSeriesAndKeepsItsData) {
  const fs::path dir = TempDir();
  std::string error;
  ASSERT_TRUE(WritePlot(FramesPlot(12), (dir / "errors").string(), &error)) << error;
  const ImageU8 png = ReadImageU8((dir / "errors.png").string(), 3);
  EXPECT_EQ(png.width, 700);
  EXPECT_EQ(png.height, 400);
  // The SVG's text is the plot's text.
  const std::string svg = Read(dir / "errors.svg");
  for (const char* text : {"Error over the frames", "frame", "mean Delta E",
                           "temperature RMS error (K)", "cam0_view", "cam11_view"})
    EXPECT_NE(svg.find(text), std::string::npos) << text;
  // Whole-number ticks only on the frame axis: 0..5, no 2.5.
  const std::string gp = Read(dir / "errors.gp");
  EXPECT_NE(gp.find("set xtics 1\n"), std::string::npos) << gp;
  EXPECT_NE(gp.find("axes x1y2"), std::string::npos);
  // Twelve series, twelve different (colour, dash) pairs.
  std::set<std::string> styles;
  std::istringstream lines(gp);
  for (std::string line; std::getline(lines, line);)
    if (line.rfind("set linetype", 0) == 0) styles.insert(line.substr(line.find(" lc ")));
  EXPECT_EQ(styles.size(), 12u) << gp;
  // The data beside it: twelve blocks, the NaN point left out.
  const std::string dat = Read(dir / "errors.dat");
  std::size_t blocks = 0, points = 0;
  std::istringstream rows(dat);
  for (std::string row; std::getline(rows, row);) {
    if (row.rfind("# ", 0) == 0) ++blocks;
    if (!row.empty() && row[0] != '#') ++points;
  }
  EXPECT_EQ(blocks, 12u);
  EXPECT_EQ(points, 12u * 6 - 1);
  EXPECT_EQ(dat.find("nan"), std::string::npos);
  // No temporary file left behind.
  for (const auto& e : fs::directory_iterator(dir))
    EXPECT_EQ(e.path().filename().string().find("tmp"), std::string::npos) << e.path();
  fs::remove_all(dir);
}

// Error bars and a dashed reference (a ring profile's fit and truth, fit_report.h): the bars'
// half-widths are the data's third column (a negative one drawn as none), the reference takes its
// series' colour dashed, and the next series its own colour.
TEST(Plot, ErrorBarsAndADashedReferenceInItsSeriesColour) {
  const fs::path dir = TempDir();
  PlotSpec spec;
  spec.title = "profile";
  spec.x_label = "radius (mm)";
  spec.y_label = "temperature (K)";
  spec.y_from_zero = false;
  PlotSeries fit("fit", {0, 1, 2}, {1800, 1700, 1500});
  fit.y_error = {50, -1, 80};
  PlotSeries truth("truth", {0, 1, 2}, {1750, 1650, 1400});
  truth.reference_of = 0;
  spec.series = {fit, truth, PlotSeries("other", {0, 1}, {1600, 1600})};
  std::string error;
  ASSERT_TRUE(WritePlot(spec, (dir / "p").string(), &error)) << error;
  EXPECT_FALSE(ReadImageU8((dir / "p.png").string(), 3).empty());
  const std::string dat = Read(dir / "p.dat");
  EXPECT_NE(dat.find("0 1800 50\n1 1700 0\n2 1500 80\n"), std::string::npos) << dat;
  EXPECT_NE(dat.find("0 1750\n"), std::string::npos) << dat;
  const std::string gp = Read(dir / "p.gp");
  EXPECT_NE(gp.find("index 0 using 1:2:3 with yerrorlines"), std::string::npos) << gp;
  EXPECT_NE(gp.find("index 1 using 1:2 with linespoints"), std::string::npos) << gp;
  std::vector<std::string> styles;
  std::istringstream lines(gp);
  for (std::string line; std::getline(lines, line);)
    if (line.rfind("set linetype", 0) == 0) styles.push_back(line);
  ASSERT_EQ(styles.size(), 3u) << gp;
  auto colour = [](const std::string& l) { return l.substr(l.find(" lc "), 18); };
  EXPECT_EQ(colour(styles[0]), colour(styles[1]));
  EXPECT_NE(colour(styles[2]), colour(styles[0]));
  EXPECT_NE(styles[0].find("dt 1"), std::string::npos);
  EXPECT_NE(styles[1].find("dt 2"), std::string::npos);
  EXPECT_NE(styles[2].find("dt 1"), std::string::npos);
  // A reference whose series draws nothing takes a colour of its own.
  spec.series[0].y.assign(3, std::nan(""));
  ASSERT_TRUE(WritePlot(spec, (dir / "q").string(), &error)) << error;
  const std::string orphan = Read(dir / "q.gp");
  std::vector<std::string> orphan_styles;
  std::istringstream orphan_lines(orphan);
  for (std::string line; std::getline(orphan_lines, line);)
    if (line.rfind("set linetype", 0) == 0) orphan_styles.push_back(line);
  ASSERT_EQ(orphan_styles.size(), 2u) << orphan;
  EXPECT_NE(colour(orphan_styles[0]), colour(orphan_styles[1]));
  fs::remove_all(dir);
}

TEST(Plot, WithoutGnuplotSaysWhatToInstallAndKeepsTheScript) {
  const fs::path dir = TempDir();
  const char* path = std::getenv("PATH");
  const std::string saved = path ? path : "";
  ::setenv("PATH", dir.c_str(), 1);
  std::string error;
  const bool drawn = WritePlot(FramesPlot(2), (dir / "p").string(), &error);
  ::setenv("PATH", saved.c_str(), 1);
  EXPECT_FALSE(drawn);
  EXPECT_NE(error.find("gnuplot-nox"), std::string::npos) << error;
  EXPECT_TRUE(fs::exists(dir / "p.gp"));
  EXPECT_TRUE(fs::exists(dir / "p.dat"));
  EXPECT_FALSE(fs::exists(dir / "p.png"));
  // An empty plot is drawn, saying so, rather than failing.
  PlotSpec empty;
  empty.title = "nothing yet";
  EXPECT_TRUE(WritePlot(empty, (dir / "empty").string(), &error)) << error;
  EXPECT_NE(Read(dir / "empty.svg").find("no data"), std::string::npos);
  // ... on a log axis too, where [0:1] would be no range at all.
  empty.log_x = true;
  EXPECT_TRUE(WritePlot(empty, (dir / "empty_log").string(), &error)) << error;
  fs::remove_all(dir);
}

TEST(Picture, GridPlacesEachTileInItsRowAndColumnWithItsBar) {
  // Two rows of three solid tiles, each a distinct colour, 40x30 drawn at height 60 (80x60).
  PictureGrid grid;
  grid.column_labels = {"a", "b", "c"};
  grid.row_labels = {"first", "second"};
  grid.tile_height = 60;
  for (int r = 0; r < 2; ++r) {
    grid.rows.emplace_back();
    for (int c = 0; c < 3; ++c)
      grid.rows.back().push_back(
          ImageU8(40, 30, 3, static_cast<std::uint8_t>(20 + 40 * (3 * r + c))));
  }
  grid.bars.push_back(
      {"K", "K", 300, 2300, [](double t) { return InfernoColour((t - 300) / 2000); }});
  const ImageU8 out = DrawPictureGrid(grid);
  // Layout (picture.cc): margin 8, label rows 22 px, gap 6, no title.
  const int top = 8 + 22;
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 3; ++c) {
      const int x = 8 + c * (80 + 6) + 40, y = top + r * (22 + 60 + 6) + 22 + 30;
      EXPECT_EQ(out.at(x, y, 0), 20 + 40 * (3 * r + c)) << r << "," << c;
    }
  // The bar right of the tiles: its top hotter (brighter) than its bottom.
  const int bar_x = 8 + 3 * 86 + 15;
  const int bar_top = top + 26 + 2, bar_bottom = top + 22 + 60 - 12;
  auto luminance = [&](int y) {
    return out.at(bar_x, y, 0) + out.at(bar_x, y, 1) + out.at(bar_x, y, 2);
  };
  EXPECT_GT(luminance(bar_top), luminance(bar_bottom) + 200);
  EXPECT_GE(out.width, 8 + 3 * 86 + 124);
  // A colour bar with no rows, or rows lower than a bar, still fits in the picture.
  PictureGrid bars_only;
  bars_only.bars = grid.bars;
  bars_only.tile_height = 20;
  const ImageU8 small = DrawPictureGrid(bars_only);
  EXPECT_GE(small.height, 60);
  bars_only.rows = {{ImageU8(4, 2, 3, 9)}};
  EXPECT_GE(DrawPictureGrid(bars_only).height, 60);
}

TEST(Picture, ColourMapsAndScaleBars) {
  EXPECT_EQ(DivergingColour(0, 400), (Rgb{255, 255, 255}));
  EXPECT_EQ(DivergingColour(400, 400), (Rgb{255, 0, 0}));
  EXPECT_EQ(DivergingColour(-1e9, 400), (Rgb{0, 0, 255}));
  // Viridis runs dark to bright; inferno black to pale yellow.
  auto sum = [](const Rgb& c) { return c[0] + c[1] + c[2]; };
  EXPECT_LT(sum(ViridisColour(0)), sum(ViridisColour(1)));
  EXPECT_LT(sum(InfernoColour(0)), 30);
  // The ends of the published maps (matplotlib's viridis and inferno, 8-bit, to one level), a
  // value outside [0, 1] clamped, and a NaN drawn as the low end rather than undefined.
  auto near = [](const Rgb& c, int r, int g, int b) {
    return std::abs(c[0] - r) <= 1 && std::abs(c[1] - g) <= 1 && std::abs(c[2] - b) <= 1;
  };
  EXPECT_TRUE(near(ViridisColour(0), 68, 1, 84));
  EXPECT_TRUE(near(ViridisColour(1), 253, 231, 37));
  EXPECT_TRUE(near(InfernoColour(0), 0, 0, 4));
  EXPECT_TRUE(near(InfernoColour(1), 252, 255, 164));
  EXPECT_EQ(ViridisColour(7), ViridisColour(1));
  EXPECT_EQ(InfernoColour(-3), InfernoColour(0));
  EXPECT_EQ(InfernoColour(std::nan("")), InfernoColour(0));
  // A scale bar is 1, 2 or 5 times a power of ten metres, 40 to 100 pixels long.
  for (double ppm : {800.0, 3000.0, 9142.0, 20000.0, 1e5, 3.3e6}) {
    const double m = ScaleBarLength(ppm);
    const double mantissa = m / std::pow(10.0, std::floor(std::log10(m) + 1e-9));
    EXPECT_TRUE(std::abs(mantissa - 1) < 1e-9 || std::abs(mantissa - 2) < 1e-9 ||
                std::abs(mantissa - 5) < 1e-9)
        << ppm << " -> " << m;
    EXPECT_GE(m * ppm, 40 - 1e-9) << ppm;
    EXPECT_LE(m * ppm, 100 + 1e-9) << ppm;
  }
  // At 2000 px/m, 1 cm would be 20 px, too short to read: 2 cm, 40 px, drawn white from x = 8
  // in the bottom-left corner.
  ImageU8 image(200, 100, 3, 0);
  EXPECT_DOUBLE_EQ(ScaleBarLength(2000), 0.02);
  DrawScaleBar(&image, 2000, ScaleBarLength(2000));
  EXPECT_EQ(image.at(8 + 30, 100 - 10, 0), 255);
  EXPECT_EQ(image.at(8 + 60, 100 - 10, 0), 0);
}

}  // namespace
}  // namespace flamerig
