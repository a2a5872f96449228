// Frames through a real video codec, as a camera rig that records compressed video delivers them:
// the test data and benchmarks of the tomography on real footage (issue 20) use it so that masks and
// solvers meet block artefacts, ringing, chroma subsampling and the specks a codec leaves on an
// exactly black background.
//
// The frames go to ffmpeg (Debian's, with libx264) as raw RGB, are encoded as one video with the
// given codec and quality, and are decoded back to RGB: the same colour conversion (BT.601,
// limited range, 4:2:0 by default) and quantisation a recording has. Frames of odd size are padded
// for 4:2:0 and cropped back.
#ifndef FLAMERIG_PIPELINE_VIDEO_CODEC_H_
#define FLAMERIG_PIPELINE_VIDEO_CODEC_H_

#include <string>
#include <vector>

#include "core/image.h"

namespace flamerig {

struct VideoCodecOptions {
  std::string codec = "libx264";  // an ffmpeg encoder: libx264, libx265, mpeg4, ...
  int crf = 30;                   // constant rate factor (libx264: 0 lossless .. 51; 23 default)
  std::string preset = "medium";  // libx264's speed preset
  std::string pixel_format = "yuv420p";
  void Validate() const;         // throws InputError naming the field
  std::string Describe() const;  // "libx264 crf 30 (medium, yuv420p)"
};

// `frames` (all RGB8 of one size) encoded as one video and decoded back, in order. Throws
// InputError for frames of mixed sizes or channels, IoError when ffmpeg cannot be run or fails
// (its message, and the package to install).
std::vector<ImageU8> ThroughVideoCodec(const std::vector<ImageU8>& frames,
                                       const VideoCodecOptions& options);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_VIDEO_CODEC_H_
