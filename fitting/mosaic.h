// What a colour camera with a Bayer mosaic delivers of a rendered image, for fitting the frames
// it recorded as it recorded them.
//
// A colour machine-vision camera (BayerRG8, BayerRG12 and their kin) measures one colour at each
// pixel (its site's filter) and the host interpolates the other two from the neighbouring sites:
// flamerig's
// DecodeFrame (acquisition/frame.h) by OpenCV's bilinear demosaicing, in the frame's codes. At the
// flame's edges, where the brightness changes within a pixel or two, the interpolated colours are
// not the light's, and a fit that matches them as measured colours turns their fringes into
// temperature (BENCHMARKS.md, "Pixels that integrate, and a Bayer mosaic": about +7 K on the main
// job's average frame set). BayerRecord puts the same steps into the fit's forward model, so the
// rendered image is interpolated exactly as the recording was, and its adjoint takes the data
// term's gradient back to the one channel each site measured:
//
//   c_k(x, y)   = clamp(s I_k(x, y), 0, 1)         k = the site's colour, s the exposure
//   code(x, y)  = Encode(c_k(x, y))                 the camera's transfer (radiometry.h)
//   code'(x, y, ch) = sum over taps w * code(x', y')  bilinear, as OpenCV: the site's own code for
//                                                   its colour, else the mean of its 8-neighbours
//                                                   of colour ch (two, or four); the first and last
//                                                   columns copy their neighbours', then the first
//                                                   and last rows theirs
//   signal(x, y, ch) = Signal(code'(x, y, ch))      back to the linear signal, 0..1
//
// Frames of 8 or 16 bits (Bayer 16, and 10- or 12-bit mosaics unpacked into it) take the same
// steps in their own codes, decoded as the radiometry decodes such a frame (DecodingFor). OpenCV
// rounds the interpolated codes; the model does not (the fit sees the continuous value, as it
// does everywhere). Images must be at least 3 x 3.
#ifndef FLAMERIG_FITTING_MOSAIC_H_
#define FLAMERIG_FITTING_MOSAIC_H_

#include <memory>
#include <string>

#include "acquisition/frame.h"
#include "calibration/radiometry.h"
#include "core/image.h"

namespace flamerig {

// The colours of a Bayer mosaic's 2 x 2 cell, named by its first row and then its second, as
// GenICam names the formats (BayerRG8: R at (0, 0), G at (1, 0) and (0, 1), B at (1, 1)).
enum class BayerLayout { kNone, kRggb, kGrbg, kGbrg, kBggr };

// The layout of a frame of `format`; kNone for Mono, RGB and anything else not a mosaic.
BayerLayout BayerLayoutOf(PixelFormat format);
const char* ToString(BayerLayout layout);  // "RGGB", ...; "none"
// The colour the site at (x, y) records: 0 R, 1 G, 2 B. `layout` must not be kNone.
int BayerColour(BayerLayout layout, int x, int y);

// demosaic(mosaic(image)) of a 3-channel image, as DecodeFrame's OpenCV demosaicing makes it from
// the mosaic of the same values: the linear operator above without the transfer (for tests and
// pictures). Throws InputError for an image smaller than 3 x 3 or not 3 channels, or kNone.
ImageF BayerResample(const ImageF& image, BayerLayout layout);
// Its adjoint (transpose): <BayerResample(a), b> = <a, BayerResampleAdjoint(b)> for any a, b.
ImageF BayerResampleAdjoint(const ImageF& image, BayerLayout layout);

class BayerRecord {
 public:
  // A camera of `layout` (not kNone) whose frames are `frame_bits` (8 or 16) codes decoded by
  // `radiometry`. Throws InputError for kNone, a radiometry that refuses to decode such frames
  // (a 12-bit camera's in 8 bits), or a mono one.
  BayerRecord(BayerLayout layout, const CameraRadiometry& radiometry, int frame_bits = 8);

  BayerLayout layout() const { return layout_; }
  int frame_bits() const { return frame_bits_; }

  // The linear signal (3 channels, 0..1) that the host's demosaicing gives of the rendered linear
  // radiance `linear` (the renderer's output, 3 channels) at exposure s (> 0).
  // `codes`, when not null, receives the interpolated codes, which Adjoint can take back instead
  // of working them out again.
  ImageF Forward(const ImageF& linear, double s, ImageF* codes = nullptr) const;
  // Given dE/d(signal) for every pixel and channel of Forward(linear, s), dE/d(linear) (3
  // channels; at each site only its own colour is non-zero) and, if d_s is not null, adds dE/ds.
  // `codes`: Forward's for the same `linear` and s, or null to work them out.
  ImageF Adjoint(const ImageF& linear, double s, const ImageF& d_signal, double* d_s,
                 const ImageF* codes = nullptr) const;

 private:
  double Encode(double signal) const { return radiometry_.Encode(signal, decoding_); }
  double Signal(double code) const { return radiometry_.Signal(code, decoding_); }
  double EncodeSlope(double signal) const;  // d Encode / d signal at signal in [0, 1)
  double SignalSlope(double code) const;    // d Signal / d code
  ImageF SiteCodes(const ImageF& linear, double s) const;  // each site's code of its colour

  BayerLayout layout_;
  int frame_bits_;
  CameraRadiometry radiometry_;
  CameraRadiometry::Decoding decoding_;
};

// The model of a camera whose frames are of `layout` and `frame_bits` (recorded per frame set:
// SourceFrameSet::mosaic and ::bits); null for kNone, the frames of cameras that measure every
// channel. BayerRecord's errors name `camera` when it is given.
std::shared_ptr<const BayerRecord> MakeBayerRecord(BayerLayout layout,
                                                   const CameraRadiometry& radiometry,
                                                   const std::string& camera = "",
                                                   int frame_bits = 8);

}  // namespace flamerig

#endif  // FLAMERIG_FITTING_MOSAIC_H_
