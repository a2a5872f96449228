// Reading Norpix StreamPix `.seq` sequences, the format the paper's capture used (one file per
// camera, hardware-triggered, so frame i of every file is one frame set).
//
// Layout (little-endian): a header of `header_size` bytes (1024; versions 5 and later, written by
// StreamPix 6 and later, have an 8192-byte header although the field still says 1024: their first
// image is at byte 8192, as in the pims project's sample file), then fixed-size frames of
// `true_image_size` bytes: the image (`image_size_bytes`), an 8-byte timestamp (int32 seconds
// since 1970, uint16 milliseconds, uint16 microseconds; version 5 and later, earlier versions
// leave the microseconds 0), padding. Header fields, by byte offset: 0 magic 0xFEED, 28 version,
// 32 header size, 36 description (UTF-16, 512 bytes), 548 width, 552 height, 556 bit depth, 560
// real bit depth, 564 image size in bytes, 568 image format, 572 allocated frames, 580 true image
// size, 584 frame rate (double), 620 compression format.
//
// Variants read: versions 3 to 6, uncompressed (compression format 0), image formats 100 (mono,
// 8 or 16 bit), 101 (raw Bayer, 8 or 16 bit; pattern as given to the reader, BayerRG8 for
// BayerRG16 and so on), 200 (BGR, 24 bit) and 400
// (RGB, 24 bit). Compressed sequences (JPEG, H.264; they need a separate index file) and the
// packed/YUV formats are refused with an error that names the file and the variant.
#ifndef FLAMERIG_ACQUISITION_STREAMPIX_H_
#define FLAMERIG_ACQUISITION_STREAMPIX_H_

#include <cstdint>
#include <string>

#include "acquisition/frame.h"

namespace flamerig {

struct SeqHeader {
  std::uint32_t version = 0, header_size = 0;
  std::uint32_t width = 0, height = 0, bit_depth = 0, bit_depth_real = 0;
  std::uint32_t image_size_bytes = 0, image_format = 0, allocated_frames = 0, true_image_size = 0;
  double frame_rate_hz = 0;
  std::uint32_t compression_format = 0;
  std::string description;  // ASCII part of the UTF-16 description
};

class StreamPixSequence {
 public:
  // Reads and checks the header; throws IoError when the file cannot be opened, DataError naming
  // the file and the field when it is not a sequence we read.
  // `bayer` is the pattern of image format 101 files (the header does not always say).
  explicit StreamPixSequence(const std::string& path, PixelFormat bayer = PixelFormat::kBayerRg8);
  const SeqHeader& header() const { return header_; }
  // Frames present in the file, whole or not: a sequence cut short by a crash ends in a frame
  // that ReadFrame refuses (and may have fewer frames than the header allocated).
  std::size_t num_frames() const { return frames_; }
  // Frame i: pixels (BGR converted to RGB), its index as frame id, its timestamp as the device
  // timestamp (ns since 1970); `camera` goes into the frame's info. Throws DataError naming the
  // file, the frame and the byte offset when the file cuts the frame short.
  Frame ReadFrame(std::size_t i, int camera = 0) const;

 private:
  std::string path_;
  SeqHeader header_;
  PixelFormat format_ = PixelFormat::kMono8;
  bool bgr_ = false;
  std::size_t frames_ = 0;
  std::uint64_t first_image_ = 0;  // byte offset of frame 0
};

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_STREAMPIX_H_
