#include "fitting/tonemap.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "core/error.h"
#include "core/srgb.h"

namespace flamerig {

namespace {

double Luminance(const float* rgb) {
  const double l = 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2];
  return std::isfinite(l) && l > 0 ? l : 0.0;
}

}  // namespace

void ToneMapOptions::Validate() const {
  if (!(exposure > 0) || !std::isfinite(exposure))
    throw InputError("ToneMapOptions.exposure must be finite and > 0");
  if (!(key > 0) || !(key <= 1))
    throw InputError("ToneMapOptions.key must be in (0, 1]");
  if (!(white >= 0) || !std::isfinite(white))
    throw InputError("ToneMapOptions.white must be finite and >= 0 (0 = automatic)");
  if (!(delta > 0)) throw InputError("ToneMapOptions.delta must be > 0");
  if (!(log_average >= 0) || !std::isfinite(log_average))
    throw InputError("ToneMapOptions.log_average must be finite and >= 0 (0 = own)");
}

double ReinhardDisplayLuminance(double l, double white) {
  if (!(l > 0)) return 0;
  const double w2 = white > 0 ? white * white : std::numeric_limits<double>::infinity();
  return l * (1 + l / w2) / (1 + l);
}

ImageU8 ToneMapReinhard(const ImageF& linear, const ToneMapOptions& options,
                        ToneMapSummary* summary) {
  options.Validate();
  if (linear.channels != 3) throw InputError("ToneMapReinhard: needs 3 channels");
  const std::size_t n = linear.num_pixels();
  double log_sum = 0;
  for (std::size_t p = 0; p < n; ++p)
    log_sum += std::log(options.delta + options.exposure * Luminance(&linear.pixels[3 * p]));
  const double average =
      options.log_average > 0 ? options.log_average : (n ? std::exp(log_sum / n) : 1.0);
  const double scale = options.key / average;
  double white = options.white;
  if (white == 0) {
    for (std::size_t p = 0; p < n; ++p)
      white = std::max(white, scale * options.exposure * Luminance(&linear.pixels[3 * p]));
  }
  ImageU8 out(linear.width, linear.height, 3, 0);
  for (std::size_t p = 0; p < n; ++p) {
    const double lw = options.exposure * Luminance(&linear.pixels[3 * p]);
    if (!(lw > 0)) continue;
    const double ld = ReinhardDisplayLuminance(scale * lw, white);
    for (int c = 0; c < 3; ++c) {
      const double v = options.exposure * linear.pixels[3 * p + c];
      const double mapped = std::isfinite(v) && v > 0 ? v * ld / lw : 0.0;
      out.pixels[3 * p + c] = QuantizeU8(SrgbEncode(std::clamp(mapped, 0.0, 1.0)));
    }
  }
  if (summary) {
    summary->log_average = average;
    summary->white = white;
  }
  return out;
}

}  // namespace flamerig
