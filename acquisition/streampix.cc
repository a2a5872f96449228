#include "acquisition/streampix.h"

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <vector>

#include "core/error.h"

namespace flamerig {

namespace {

template <typename T>
T At(const std::vector<char>& b, std::size_t offset) {
  T v;
  std::memcpy(&v, b.data() + offset, sizeof v);
  return v;
}

}  // namespace

StreamPixSequence::StreamPixSequence(const std::string& path, PixelFormat bayer) : path_(path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw IoError("StreamPix sequence " + path + ": cannot be opened");
  std::vector<char> h(1024);
  in.read(h.data(), static_cast<std::streamsize>(h.size()));
  auto fail = [&](const std::string& why) {
    throw DataError("StreamPix sequence " + path + ": " + why);
  };
  if (in.gcount() < 1024) fail("shorter than its 1024-byte header");
  if (At<std::uint32_t>(h, 0) != 0xFEED) fail("not a .seq file (magic is not 0xFEED)");
  SeqHeader& s = header_;
  s.version = At<std::uint32_t>(h, 28);
  s.header_size = At<std::uint32_t>(h, 32);
  for (std::size_t i = 36; i + 1 < 548; i += 2) {  // UTF-16LE, ASCII kept
    const char c = h[i];
    if (c == 0 && h[i + 1] == 0) break;
    if (h[i + 1] == 0 && c >= 32 && c < 127) s.description += c;
  }
  s.width = At<std::uint32_t>(h, 548);
  s.height = At<std::uint32_t>(h, 552);
  s.bit_depth = At<std::uint32_t>(h, 556);
  s.bit_depth_real = At<std::uint32_t>(h, 560);
  s.image_size_bytes = At<std::uint32_t>(h, 564);
  s.image_format = At<std::uint32_t>(h, 568);
  s.allocated_frames = At<std::uint32_t>(h, 572);
  s.true_image_size = At<std::uint32_t>(h, 580);
  s.frame_rate_hz = At<double>(h, 584);
  s.compression_format = At<std::uint32_t>(h, 620);
  if (s.version < 3 || s.version > 6)
    fail("version " + std::to_string(s.version) + " (reads 3 to 6)");
  if (s.header_size < 1024 || s.header_size > (1u << 20))
    fail("header size " + std::to_string(s.header_size));
  if (s.compression_format != 0)
    fail("compressed sequence (compression format " + std::to_string(s.compression_format) +
         "); only uncompressed sequences are read");
  if (s.width == 0 || s.height == 0 || s.width > 65536 || s.height > 65536)
    fail("image size " + std::to_string(s.width) + "x" + std::to_string(s.height));
  if (s.image_format == 100 && s.bit_depth == 8)
    format_ = PixelFormat::kMono8;
  else if (s.image_format == 100 && s.bit_depth == 16)
    format_ = PixelFormat::kMono16;
  else if (s.image_format == 101 && s.bit_depth == 8)
    format_ = bayer;
  else if (s.image_format == 101 && s.bit_depth == 16)
    format_ = Bayer16Of(bayer);
  else if ((s.image_format == 200 || s.image_format == 400) && s.bit_depth == 24) {
    format_ = PixelFormat::kRgb8;
    bgr_ = s.image_format == 200;
  } else {
    fail("image format " + std::to_string(s.image_format) + " at " + std::to_string(s.bit_depth) +
         " bits (reads 100 mono 8/16, 101 Bayer 8/16, 200 BGR 24, 400 RGB 24)");
  }
  const std::uint64_t image = std::uint64_t(s.width) * s.height * BytesPerPixel(format_);
  if (s.image_size_bytes != image)
    fail("image size in bytes " + std::to_string(s.image_size_bytes) + " does not match " +
         std::to_string(s.width) + "x" + std::to_string(s.height) + " at " +
         std::to_string(s.bit_depth) + " bits (" + std::to_string(image) + ")");
  if (s.true_image_size < s.image_size_bytes + 8)
    fail("true image size " + std::to_string(s.true_image_size) +
         " leaves no room for the 8-byte timestamp");
  std::error_code ec;
  const std::uint64_t size = std::filesystem::file_size(path, ec);
  if (ec) fail("cannot read its size");
  // StreamPix 6 and later (version >= 5) write an 8192-byte header but keep 1024 in its size field
  // (the pims project's sample_norpix6.seq is laid out so, and its reader starts at 8192).
  first_image_ = s.version >= 5 ? std::max<std::uint64_t>(8192, s.header_size) : s.header_size;
  // A last frame that the file cuts short counts: reading it is an error that says so, rather
  // than a frame that silently is not there.
  frames_ =
      size > first_image_ ? (size - first_image_ + s.true_image_size - 1) / s.true_image_size : 0;
}

Frame StreamPixSequence::ReadFrame(std::size_t i, int camera) const {
  if (i >= frames_) {
    throw std::out_of_range("StreamPix sequence " + path_ + ": frame " + std::to_string(i) +
                            " of " + std::to_string(frames_));
  }
  std::ifstream in(path_, std::ios::binary);
  const std::uint64_t at = first_image_ + std::uint64_t(i) * header_.true_image_size;
  // Checked before the frame's buffer is made: a damaged header's 65536 x 65536 frame asked for
  // 4 GiB of a 1 KiB file.
  std::error_code ec;
  const std::uint64_t file_bytes = std::filesystem::file_size(path_, ec);
  if (ec || at + header_.image_size_bytes + 8 > file_bytes)
    throw DataError("StreamPix sequence " + path_ + ": frame " + std::to_string(i) + " at byte " +
                    std::to_string(at) + " cut short (" + std::to_string(header_.image_size_bytes) +
                    " bytes and an 8-byte timestamp; the file has " + std::to_string(file_bytes) +
                    ")");
  in.seekg(static_cast<std::streamoff>(at));
  auto bytes = std::make_shared<std::vector<std::uint8_t>>(header_.image_size_bytes);
  in.read(reinterpret_cast<char*>(bytes->data()), static_cast<std::streamsize>(bytes->size()));
  char stamp[8];
  in.read(stamp, 8);
  if (!in) {
    throw DataError("StreamPix sequence " + path_ + ": frame " + std::to_string(i) + " at byte " +
                    std::to_string(at) + " cut short");
  }
  if (bgr_)
    for (std::size_t p = 0; p + 2 < bytes->size(); p += 3) std::swap((*bytes)[p], (*bytes)[p + 2]);
  std::int32_t seconds;
  std::uint16_t ms, us;
  std::memcpy(&seconds, stamp, 4);
  std::memcpy(&ms, stamp + 4, 2);
  std::memcpy(&us, stamp + 6, 2);
  if (header_.version < 5) us = 0;
  Frame f;
  f.info.camera = camera;
  f.info.frame_id = i;
  f.info.device_frame_id = i;
  f.info.device_timestamp_ns = std::int64_t(seconds) * 1'000'000'000 +
                               std::int64_t(ms) * 1'000'000 + std::int64_t(us) * 1000;
  f.info.host_realtime_ns = f.info.device_timestamp_ns;
  f.info.pixel_format = format_;
  f.info.width = static_cast<int>(header_.width);
  f.info.height = static_cast<int>(header_.height);
  f.data = std::move(bytes);
  return f;
}

}  // namespace flamerig
