// Display images from linear HDR renders: an exposure, the photographic tone reproduction of
// Reinhard, Stark, Shirley and Ferwerda (SIGGRAPH 2002) to model the eye adapting to a bright flame,
// and the sRGB encoding.
//
// Reinhard 2002, global operator, on luminance L_w = 0.2126 R + 0.7152 G + 0.0722 B (linear sRGB):
//   L_avg = exp(mean over pixels of ln(delta + L_w))        the log-average ("adaptation") luminance
//   L     = key / L_avg * L_w                               key a: 0.18 for a middle-grey scene
//   L_d   = L (1 + L / L_white^2) / (1 + L)                 L_white: the smallest L mapped to white
// and each pixel's colour is scaled by L_d / L_w (hue and saturation kept), then clamped to [0, 1]
// and sRGB-encoded. By default L_white is the largest L of the image (Reinhard's choice: nothing
// burns out), so the brightest flame voxel is just white.
#ifndef FLAMERIG_FITTING_TONEMAP_H_
#define FLAMERIG_FITTING_TONEMAP_H_

#include "core/image.h"

namespace flamerig {

struct ToneMapOptions {
  double exposure = 1;  // multiplies the linear image before anything else; (0, inf)
  double key = 0.18;    // a; (0, 1]
  double white = 0;     // L_white in scaled luminance units; 0 = the image's largest L
  double delta = 1e-6;  // keeps ln finite on black pixels; > 0
  // L_avg to use instead of the image's own (after the exposure); 0 = the image's. Images mapped
  // with one adaptation and white compare with each other.
  double log_average = 0;
  void Validate() const;  // throws InputError naming the field
};

struct ToneMapSummary {
  double log_average = 0;  // L_avg, after the exposure
  double white = 0;        // the L_white used
};

// Reinhard-mapped 8-bit sRGB image of a 3-channel linear image. NaN or negative pixels count as
// black.
ImageU8 ToneMapReinhard(const ImageF& linear_rgb, const ToneMapOptions& options,
                        ToneMapSummary* summary = nullptr);

// The operator on one luminance, for tests and plots: L_d for a scaled luminance L.
double ReinhardDisplayLuminance(double scaled_luminance, double white);

}  // namespace flamerig

#endif  // FLAMERIG_FITTING_TONEMAP_H_
