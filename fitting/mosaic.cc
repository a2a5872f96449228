#include "fitting/mosaic.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <string>

#include "core/error.h"

namespace flamerig {

BayerLayout BayerLayoutOf(PixelFormat format) {
  const std::string cell = BayerCell(format);
  if (cell == "RGGB") return BayerLayout::kRggb;
  if (cell == "GRBG") return BayerLayout::kGrbg;
  if (cell == "GBRG") return BayerLayout::kGbrg;
  if (cell == "BGGR") return BayerLayout::kBggr;
  return BayerLayout::kNone;
}

const char* ToString(BayerLayout layout) {
  switch (layout) {
    case BayerLayout::kRggb:
      return "RGGB";
    case BayerLayout::kGrbg:
      return "GRBG";
    case BayerLayout::kGbrg:
      return "GBRG";
    case BayerLayout::kBggr:
      return "BGGR";
    case BayerLayout::kNone:
      break;
  }
  return "none";
}

int BayerColour(BayerLayout layout, int x, int y) {
  // The cell's colours in reading order: (0, 0), (1, 0), (0, 1), (1, 1).
  static constexpr int kCells[4][4] = {{0, 1, 1, 2}, {1, 0, 2, 1}, {1, 2, 0, 1}, {2, 1, 1, 0}};
  const int l = static_cast<int>(layout) - 1;
  return kCells[l][(x & 1) + 2 * (y & 1)];
}

namespace {

void CheckImage(const ImageF& image, BayerLayout layout, const char* what) {
  if (layout == BayerLayout::kNone) throw InputError(std::string(what) + ": no Bayer layout");
  if (image.channels != 3 || image.width < 3 || image.height < 3)
    throw InputError(std::string(what) + ": needs a 3-channel image of at least 3 x 3, not " +
                     std::to_string(image.width) + "x" + std::to_string(image.height) + "x" +
                     std::to_string(image.channels));
}

// The sites whose codes the demosaicing puts into one channel of an inner pixel, by the pixel's
// place in the 2 x 2 cell: the site itself for its own colour, else the sites of that colour among
// its 8 neighbours (two, or four), each with the same weight.
struct Taps {
  int count = 0;
  int dx[4] = {}, dy[4] = {};
  float weight = 0;
};
using TapTable = std::array<std::array<Taps, 3>, 4>;  // [(x & 1) + 2 (y & 1)][channel]

TapTable MakeTapTable(BayerLayout layout) {
  TapTable table;
  for (int phase = 0; phase < 4; ++phase) {
    const int x = 2 + (phase & 1), y = 2 + (phase >> 1);  // any inner site of that phase
    for (int ch = 0; ch < 3; ++ch) {
      Taps& t = table[phase][ch];
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const bool own = dx == 0 && dy == 0;
          const bool own_colour = BayerColour(layout, x, y) == ch;
          if (own != own_colour || BayerColour(layout, x + dx, y + dy) != ch) continue;
          t.dx[t.count] = dx;
          t.dy[t.count] = dy;
          ++t.count;
        }
      t.weight = 1.0f / static_cast<float>(t.count);
    }
  }
  return table;
}

const TapTable& TapsOf(BayerLayout layout) {
  static const std::array<TapTable, 4> tables = {
      MakeTapTable(BayerLayout::kRggb), MakeTapTable(BayerLayout::kGrbg),
      MakeTapTable(BayerLayout::kGbrg), MakeTapTable(BayerLayout::kBggr)};
  return tables[static_cast<int>(layout) - 1];
}

// Calls f(sx, sy, weight) for each site whose code the demosaicing puts into channel `ch` of pixel
// (x, y): border pixels are their inner neighbour's (columns first, then rows, as OpenCV copies
// them; both amount to clamping the pixel into the inner rectangle), inner ones take their taps.
template <typename F>
void ForEachTap(const TapTable& table, int width, int height, int x, int y, int ch, F&& f) {
  const int cx = std::clamp(x, 1, width - 2), cy = std::clamp(y, 1, height - 2);
  const Taps& t = table[(cx & 1) + 2 * (cy & 1)][ch];
  for (int i = 0; i < t.count; ++i) f(cx + t.dx[i], cy + t.dy[i], t.weight);
}

// f(y) for every row, rows in parallel.
template <typename F>
void ForEachRow(int height, F&& f) {
  tbb::parallel_for(tbb::blocked_range<int>(0, height, 8), [&](const tbb::blocked_range<int>& r) {
    for (int y = r.begin(); y < r.end(); ++y) f(y);
  });
}

// One code per site (1 channel) -> three interpolated codes per pixel.
ImageF Interpolate(const ImageF& mosaic, BayerLayout layout) {
  const TapTable& table = TapsOf(layout);
  ImageF out(mosaic.width, mosaic.height, 3, 0.0f);
  ForEachRow(mosaic.height, [&](int y) {
    for (int x = 0; x < mosaic.width; ++x)
      for (int ch = 0; ch < 3; ++ch) {
        float sum = 0;
        ForEachTap(table, mosaic.width, mosaic.height, x, y, ch,
                   [&](int sx, int sy, float w) { sum += w * mosaic.at(sx, sy); });
        out.at(x, y, ch) = sum;
      }
  });
  return out;
}

// The transpose of Interpolate: three values per pixel -> one per site.
ImageF InterpolateAdjoint(const ImageF& image, BayerLayout layout) {
  const TapTable& table = TapsOf(layout);
  ImageF out(image.width, image.height, 1, 0.0f);
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x)
      for (int ch = 0; ch < 3; ++ch) {
        const float g = image.at(x, y, ch);
        if (g == 0.0f) continue;
        ForEachTap(table, image.width, image.height, x, y, ch,
                   [&](int sx, int sy, float w) { out.at(sx, sy) += w * g; });
      }
  return out;
}

}  // namespace

ImageF BayerResample(const ImageF& image, BayerLayout layout) {
  CheckImage(image, layout, "BayerResample");
  ImageF mosaic(image.width, image.height, 1);
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x)
      mosaic.at(x, y) = image.at(x, y, BayerColour(layout, x, y));
  return Interpolate(mosaic, layout);
}

ImageF BayerResampleAdjoint(const ImageF& image, BayerLayout layout) {
  CheckImage(image, layout, "BayerResampleAdjoint");
  const ImageF sites = InterpolateAdjoint(image, layout);
  ImageF out(image.width, image.height, 3, 0.0f);
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) out.at(x, y, BayerColour(layout, x, y)) = sites.at(x, y);
  return out;
}

BayerRecord::BayerRecord(BayerLayout layout, const CameraRadiometry& radiometry, int frame_bits)
    : layout_(layout), frame_bits_(frame_bits), radiometry_(radiometry) {
  if (layout == BayerLayout::kNone) throw InputError("a Bayer camera model needs a layout");
  if (radiometry.channels() != 3)
    throw InputError("a Bayer camera records colour; its radiometry describes a mono camera (" +
                     radiometry.spectral.Describe() + ")");
  decoding_ = radiometry.DecodingFor(frame_bits);
}

double BayerRecord::EncodeSlope(double signal) const {
  constexpr double h = 1e-7;
  const double lo = std::max(0.0, signal - h), hi = std::min(1.0, signal + h);
  return (Encode(hi) - Encode(lo)) / (hi - lo);
}

double BayerRecord::SignalSlope(double code) const {
  constexpr double h = 1e-3;
  if (code < decoding_.black || code > decoding_.saturation) return 0.0;
  const double lo = std::max(decoding_.black, code - h);
  const double hi = std::min(decoding_.saturation, code + h);
  return (Signal(hi) - Signal(lo)) / (hi - lo);
}

ImageF BayerRecord::SiteCodes(const ImageF& linear, double s) const {
  ImageF codes(linear.width, linear.height, 1);
  ForEachRow(linear.height, [&](int y) {
    for (int x = 0; x < linear.width; ++x) {
      const double c = std::clamp(s * linear.at(x, y, BayerColour(layout_, x, y)), 0.0, 1.0);
      codes.at(x, y) = static_cast<float>(Encode(c));
    }
  });
  return codes;
}

ImageF BayerRecord::Forward(const ImageF& linear, double s, ImageF* codes) const {
  CheckImage(linear, layout_, "BayerRecord::Forward");
  ImageF out = Interpolate(SiteCodes(linear, s), layout_);
  if (codes) *codes = out;
  ForEachRow(out.height, [&](int y) {
    float* row = &out.at(0, y);
    for (int i = 0; i < 3 * out.width; ++i) row[i] = static_cast<float>(Signal(row[i]));
  });
  return out;
}

ImageF BayerRecord::Adjoint(const ImageF& linear, double s, const ImageF& d_signal, double* d_s,
                            const ImageF* codes) const {
  CheckImage(linear, layout_, "BayerRecord::Adjoint");
  for (const ImageF* image : {&d_signal, codes})
    if (image &&
        (image->width != linear.width || image->height != linear.height || image->channels != 3))
      throw InputError("BayerRecord::Adjoint: the gradient or the codes are not the image's size");
  // The interpolated codes (Forward's, or worked out again), then dE/d(them).
  ImageF d_code = codes ? *codes : Interpolate(SiteCodes(linear, s), layout_);
  ForEachRow(d_code.height, [&](int y) {
    float* row = &d_code.at(0, y);
    const float* g = &d_signal.at(0, y);
    for (int i = 0; i < 3 * d_code.width; ++i)
      row[i] = g[i] == 0.0f ? 0.0f : static_cast<float>(g[i] * SignalSlope(row[i]));
  });
  const ImageF d_sites = InterpolateAdjoint(d_code, layout_);
  ImageF out(linear.width, linear.height, 3, 0.0f);
  double ds = 0;
  for (int y = 0; y < linear.height; ++y)
    for (int x = 0; x < linear.width; ++x) {
      const int k = BayerColour(layout_, x, y);
      const double v = s * linear.at(x, y, k);
      // Clamped: no derivative (as CameraLab); an unseen site: nothing to pass on.
      if (!(v > 0 && v < 1) || d_sites.at(x, y) == 0.0f) continue;
      const double d_c = d_sites.at(x, y) * EncodeSlope(v);
      out.at(x, y, k) = static_cast<float>(d_c * s);
      ds += d_c * linear.at(x, y, k);
    }
  if (d_s) *d_s += ds;
  return out;
}

std::shared_ptr<const BayerRecord> MakeBayerRecord(BayerLayout layout,
                                                   const CameraRadiometry& radiometry,
                                                   const std::string& camera, int frame_bits) {
  if (layout == BayerLayout::kNone) return nullptr;
  try {
    return std::make_shared<const BayerRecord>(layout, radiometry, frame_bits);
  } catch (const InputError& e) {
    if (camera.empty()) throw;
    throw InputError("camera '" + camera + "' (" + ToString(layout) + " mosaic): " + e.what());
  }
}

}  // namespace flamerig
