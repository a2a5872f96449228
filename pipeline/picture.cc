#include "pipeline/picture.h"

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>

namespace flamerig {

namespace {

// ImageU8 (RGB or grey) <-> OpenCV BGR.
cv::Mat ToMat(const ImageU8& image) {
  cv::Mat m(image.height, image.width, CV_8UC3);
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x)
      for (int c = 0; c < 3; ++c)
        m.at<cv::Vec3b>(y, x)[2 - c] = image.at(x, y, image.channels == 1 ? 0 : c);
  return m;
}

ImageU8 FromMat(const cv::Mat& m) {
  ImageU8 image(m.cols, m.rows, 3);
  for (int y = 0; y < m.rows; ++y)
    for (int x = 0; x < m.cols; ++x)
      for (int c = 0; c < 3; ++c) image.at(x, y, c) = m.at<cv::Vec3b>(y, x)[2 - c];
  return image;
}

cv::Scalar Bgr(const Rgb& c) { return cv::Scalar(c[2], c[1], c[0]); }

// OpenCV's colour map as a 256-entry table, made once: applyColorMap builds the map's whole table
// on every call, which per pixel cost the run's pictures 20 s a frame.
std::array<Rgb, 256> ColourTable(cv::ColormapTypes map) {
  cv::Mat levels(1, 256, CV_8UC1);
  for (int i = 0; i < 256; ++i) levels.at<std::uint8_t>(0, i) = static_cast<std::uint8_t>(i);
  cv::Mat coloured;
  cv::applyColorMap(levels, coloured, map);
  std::array<Rgb, 256> table;
  for (int i = 0; i < 256; ++i) {
    const cv::Vec3b bgr = coloured.at<cv::Vec3b>(0, i);
    table[i] = {bgr[2], bgr[1], bgr[0]};
  }
  return table;
}

Rgb MapColour(double u, const std::array<Rgb, 256>& table) {
  const double v = std::isnan(u) ? 0.0 : std::clamp(u, 0.0, 1.0);
  return table[static_cast<std::size_t>(std::lround(255 * v))];
}

const cv::Scalar kBlack(0, 0, 0), kWhite(255, 255, 255);
constexpr int kFont = cv::FONT_HERSHEY_SIMPLEX;

// Writes `text` with its baseline at `at`, shrunk (down to 0.35) to fit `max_width` pixels.
void Text(cv::Mat* image, const std::string& text, cv::Point at, double size, int max_width,
          bool centred = false, const cv::Scalar& colour = kBlack) {
  int baseline = 0;
  cv::Size extent = cv::getTextSize(text, kFont, size, 1, &baseline);
  while (extent.width > max_width && size > 0.35) {
    size *= 0.9;
    extent = cv::getTextSize(text, kFont, size, 1, &baseline);
  }
  if (centred) at.x += std::max(0, (max_width - extent.width) / 2);
  cv::putText(*image, text, at, kFont, size, colour, 1, cv::LINE_AA);
}

cv::Mat Scaled(const ImageU8& tile, int height) {
  if (tile.empty()) return cv::Mat();
  const cv::Mat m = ToMat(tile);
  const int width = std::max(1, static_cast<int>(std::lround(double(m.cols) * height / m.rows)));
  cv::Mat out;
  cv::resize(m, out, cv::Size(width, height), 0, 0,
             height < m.rows ? cv::INTER_AREA : cv::INTER_NEAREST);
  return out;
}

std::string Number(double v, int decimals, bool signed_ticks) {
  char buf[48];
  std::snprintf(buf, sizeof buf, signed_ticks ? "%+.*f" : "%.*f", decimals, v);
  std::string s = buf;
  if (s == "-0" || s == "+0") s = "0";
  return s;
}

}  // namespace

Rgb InfernoColour(double u) {
  static const std::array<Rgb, 256> table = ColourTable(cv::COLORMAP_INFERNO);
  return MapColour(u, table);
}
Rgb ViridisColour(double u) {
  static const std::array<Rgb, 256> table = ColourTable(cv::COLORMAP_VIRIDIS);
  return MapColour(u, table);
}

Rgb DivergingColour(double e, double range) {
  const double u = std::clamp(e / std::max(1e-9, range), -1.0, 1.0);
  const auto fade = static_cast<std::uint8_t>(std::lround(255 * (1 - std::abs(u))));
  return u >= 0 ? Rgb{255, fade, fade} : Rgb{fade, fade, 255};
}

ImageU8 ColourBar(const ColourScale& scale, int height) {
  height = std::max(height, 60);
  cv::Mat bar(height, 120, CV_8UC3, kWhite);
  const int top = 26, bottom = height - 10;
  Text(&bar, scale.title, cv::Point(4, 16), 0.45, 114);
  for (int y = top; y <= bottom; ++y) {
    const double v = scale.hi - (scale.hi - scale.lo) * (y - top) / double(bottom - top);
    cv::line(bar, cv::Point(5, y), cv::Point(30, y), Bgr(scale.colour(v)));
  }
  cv::rectangle(bar, cv::Point(5, top), cv::Point(30, bottom), kBlack);
  for (int k = 0; k <= 4; ++k) {
    const double v = scale.lo + (scale.hi - scale.lo) * k / 4.0;
    const int y = bottom - (bottom - top) * k / 4;
    cv::line(bar, cv::Point(30, y), cv::Point(36, y), kBlack);
    Text(&bar,
         Number(v, scale.decimals, scale.signed_ticks) +
             (scale.unit.empty() ? "" : " " + scale.unit),
         cv::Point(40, y + 5), 0.45, 78);
  }
  return FromMat(bar);
}

ImageU8 DrawPictureGrid(const PictureGrid& grid) {
  constexpr int kMargin = 8, kGap = 6, kLabel = 22, kTitle = 30;
  const int h = std::max(8, grid.tile_height);
  std::vector<std::vector<cv::Mat>> tiles;
  std::size_t columns = grid.column_labels.size();
  for (const auto& row : grid.rows) {
    tiles.emplace_back();
    for (const auto& t : row) tiles.back().push_back(Scaled(t, h));
    columns = std::max(columns, row.size());
  }
  std::vector<int> widths(columns, 0);
  for (const auto& row : tiles)
    for (std::size_t c = 0; c < row.size(); ++c) widths[c] = std::max(widths[c], row[c].cols);
  for (auto& w : widths) w = std::max(w, 4 * h / 3 / 2);
  const bool have_columns = !grid.column_labels.empty();
  const bool have_rows = !grid.row_labels.empty();
  int width = kMargin;
  for (int w : widths) width += w + kGap;
  const int bars_x = width;
  width += static_cast<int>(grid.bars.size()) * 124 + kMargin;
  const int row_height = (have_rows ? kLabel : 0) + h + kGap;
  const int grid_top = kMargin + (grid.title.empty() ? 0 : kTitle) + (have_columns ? kLabel : 0);
  // Tall enough for the colour bars too (at least 60 px each, picture.h) when rows are few or low.
  const int height =
      std::max(grid_top + static_cast<int>(tiles.size()) * row_height + kMargin,
               grid.bars.empty() ? 0 : grid_top + std::max(60, h + kLabel) + kMargin);
  cv::Mat out(std::max(height, 1), std::max(width, 1), CV_8UC3, kWhite);
  if (!grid.title.empty()) Text(&out, grid.title, cv::Point(kMargin, kMargin + 20), 0.6, width);
  int x = kMargin;
  for (std::size_t c = 0; c < columns; ++c) {
    if (c < grid.column_labels.size())
      Text(&out, grid.column_labels[c], cv::Point(x, grid_top - 6), 0.5, widths[c], true);
    x += widths[c] + kGap;
  }
  for (std::size_t r = 0; r < tiles.size(); ++r) {
    int y = grid_top + static_cast<int>(r) * row_height;
    if (have_rows) {
      if (r < grid.row_labels.size())
        Text(&out, grid.row_labels[r], cv::Point(kMargin, y + 16), 0.5, bars_x - kMargin);
      y += kLabel;
    }
    x = kMargin;
    for (std::size_t c = 0; c < columns; ++c) {
      if (c < tiles[r].size() && !tiles[r][c].empty())
        tiles[r][c].copyTo(out(cv::Rect(x, y, tiles[r][c].cols, tiles[r][c].rows)));
      x += widths[c] + kGap;
    }
  }
  for (std::size_t b = 0; b < grid.bars.size(); ++b) {
    const cv::Mat bar = ToMat(ColourBar(grid.bars[b], h + (have_rows ? kLabel : 0)));
    bar.copyTo(out(cv::Rect(bars_x + static_cast<int>(b) * 124, grid_top, bar.cols, bar.rows)));
  }
  return FromMat(out);
}

ImageU8 Labelled(const ImageU8& image, const std::string& label) {
  std::vector<std::string> lines;
  std::size_t from = 0;
  for (std::size_t at; (at = label.find('\n', from)) != std::string::npos; from = at + 1)
    lines.push_back(label.substr(from, at - from));
  lines.push_back(label.substr(from));
  const int head = 24 + 20 * (static_cast<int>(lines.size()) - 1);
  // As wide as the image, or as its label at a legible size.
  int width = std::max(image.width, 10);
  for (const auto& line : lines) {
    int baseline = 0;
    width = std::max(width, cv::getTextSize(line, kFont, 0.45, 1, &baseline).width + 6);
  }
  cv::Mat out(image.height + head, width, CV_8UC3, kWhite);
  if (!image.empty()) ToMat(image).copyTo(out(cv::Rect(0, head, image.width, image.height)));
  for (std::size_t k = 0; k < lines.size(); ++k)
    Text(&out, lines[k], cv::Point(2, 17 + 20 * static_cast<int>(k)), 0.5, width - 4);
  return FromMat(out);
}

ImageU8 Beside(const std::vector<ImageU8>& images, int gap) {
  int width = 0, height = 1;
  for (const auto& p : images) {
    width += p.width + gap;
    height = std::max(height, p.height);
  }
  cv::Mat out(height, std::max(1, width), CV_8UC3, kWhite);
  int x = 0;
  for (const auto& p : images) {
    if (!p.empty()) ToMat(p).copyTo(out(cv::Rect(x, 0, p.width, p.height)));
    x += p.width + gap;
  }
  return FromMat(out);
}

ImageU8 Stacked(const std::vector<ImageU8>& images, int gap) {
  int width = 1, height = 0;
  for (const auto& p : images) {
    width = std::max(width, p.width);
    height += p.height + gap;
  }
  cv::Mat out(std::max(1, height), width, CV_8UC3, kWhite);
  int y = 0;
  for (const auto& p : images) {
    if (!p.empty()) ToMat(p).copyTo(out(cv::Rect(0, y, p.width, p.height)));
    y += p.height + gap;
  }
  return FromMat(out);
}

double ScaleBarLength(double pixels_per_m) {
  if (!(pixels_per_m > 0) || !std::isfinite(pixels_per_m)) return 0;
  const double target = 60 / pixels_per_m;  // metres for about 60 px
  const double decade = std::pow(10.0, std::floor(std::log10(target)));
  for (double m : {1.0, 2.0, 5.0, 10.0})
    if (m * decade * pixels_per_m >= 40) return m * decade;
  return 10 * decade;
}

void DrawScaleBar(ImageU8* image, double pixels_per_m, double length_m) {
  const int length = static_cast<int>(std::lround(length_m * pixels_per_m));
  if (length < 2 || length + 16 > image->width || image->height < 24) return;
  cv::Mat m = ToMat(*image);
  const int y = m.rows - 10;
  cv::rectangle(m, cv::Point(7, y - 3), cv::Point(9 + length, y + 3), kBlack, cv::FILLED);
  cv::rectangle(m, cv::Point(8, y - 2), cv::Point(8 + length, y + 2), kWhite, cv::FILLED);
  char text[32];
  if (length_m >= 0.01)
    std::snprintf(text, sizeof text, "%g cm", length_m * 100);
  else
    std::snprintf(text, sizeof text, "%g mm", length_m * 1000);
  cv::putText(m, text, cv::Point(8, y - 8), kFont, 0.4, kBlack, 3, cv::LINE_AA);
  cv::putText(m, text, cv::Point(8, y - 8), kFont, 0.4, kWhite, 1, cv::LINE_AA);
  *image = FromMat(m);
}

}  // namespace flamerig
