#include "core/image.h"

#include <libdeflate.h>
#include <algorithm>
#include <cctype>
#include <filesystem>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <optional>
#include <random>
#include <stdexcept>
#include <string_view>
#include <vector>

#include "core/atomic_file.h"
#include "core/error.h"
#include "core/read_file.h"

namespace flamerig {

namespace {

template <typename T>
void WritePngImpl(const std::string& path, const Image<T>& image) {
  constexpr int depth = sizeof(T) == 1 ? CV_8U : CV_16U;
  if (image.channels != 1 && image.channels != 3) {
    throw InputError(path + ": cannot write an image with " + std::to_string(image.channels) +
                     " channels (need 1 or 3)");
  }
  cv::Mat view(image.height, image.width, CV_MAKETYPE(depth, image.channels),
               const_cast<T*>(image.pixels.data()));
  cv::Mat out;
  if (image.channels == 3) {
    cv::cvtColor(view, out, cv::COLOR_RGB2BGR);
  } else {
    out = view;
  }
  // Encoded in memory and written whole or not at all (core/atomic_file.h): cv::imwrite says
  // true when the disk fills under it, and an export onto a full disk left 125 empty PNGs of 200
  // with no name in any message (2026-12-02).
  std::string ext = std::filesystem::path(path).extension().string();
  if (ext.empty()) ext = ".png";
  std::vector<uchar> bytes;
  bool ok = false;
  try {
    ok = cv::imencode(ext, out, bytes);
  } catch (const cv::Exception& e) {
    throw IoError(path + ": cannot write image: " + e.what());
  }
  if (!ok) throw IoError(path + ": cannot write image (encoding " + ext + " failed)");
  WriteFileAtomically(path,
                      std::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size()));
}

template <typename T>
Image<T> FromMat(const std::string& path, const cv::Mat& in, int channels) {
  const int file_channels = in.channels();
  const int want = channels == 0 ? (file_channels == 1 ? 1 : 3) : channels;
  if (want != 1 && want != 3) throw InputError(path + ": can only read as 1 or 3 channels");
  cv::Mat rgb;
  if (want == 1) {
    if (file_channels == 1)
      rgb = in;
    else if (file_channels == 3)
      cv::cvtColor(in, rgb, cv::COLOR_BGR2GRAY);
    else
      cv::cvtColor(in, rgb, cv::COLOR_BGRA2GRAY);
  } else {
    if (file_channels == 1)
      cv::cvtColor(in, rgb, cv::COLOR_GRAY2RGB);
    else if (file_channels == 3)
      cv::cvtColor(in, rgb, cv::COLOR_BGR2RGB);
    else
      cv::cvtColor(in, rgb, cv::COLOR_BGRA2RGB);
  }
  Image<T> image(rgb.cols, rgb.rows, want);
  for (int y = 0; y < rgb.rows; ++y) {
    const T* row = rgb.ptr<T>(y);
    std::copy(row, row + static_cast<std::size_t>(rgb.cols) * want,
              image.pixels.begin() + static_cast<std::size_t>(y) * rgb.cols * want);
  }
  return image;
}

std::uint32_t BigEndian32(const std::string& bytes, std::size_t at) {
  return std::uint32_t(std::uint8_t(bytes[at])) << 24 |
         std::uint32_t(std::uint8_t(bytes[at + 1])) << 16 |
         std::uint32_t(std::uint8_t(bytes[at + 2])) << 8 |
         std::uint32_t(std::uint8_t(bytes[at + 3]));
}

// What is wrong with a PNG's chunks, or nullopt when they are whole (or the bytes are not a PNG:
// OpenCV then says what it can). Each chunk (length, type, data, CRC-32 over type and data) is
// walked up to the closing IEND:
// - a file that ends before IEND is "cut short", as a crash or a full disk leaves it;
// - a critical chunk (its type's first letter upper case: IHDR, PLTE, IDAT, IEND) whose CRC does
//   not match its bytes is damaged inside, and named with its byte offset. An ancillary chunk's
//   damage (text, timestamps) is left to libpng, which drops that chunk and reads the pixels;
// - a chunk whose stated length runs past the end of a file that does end in IEND has a damaged
//   length field;
// - a first chunk other than the image header (IHDR), or an IEND before any pixel data (IDAT), is
//   damage too.
// Found here, none of them reaches libpng, which would print "libpng error: ..." on stderr
// before OpenCV returned an empty image. Bytes after IEND (some writers pad) are allowed.
std::optional<std::string> PngDamage(const std::string& bytes) {
  static constexpr std::string_view kSignature("\x89PNG\r\n\x1a\n", 8);
  if (bytes.size() < kSignature.size() || bytes.compare(0, 8, kSignature) != 0) return std::nullopt;
  const std::string size = " (" + std::to_string(bytes.size()) + " bytes";
  std::size_t at = 8;
  bool seen_pixels = false;
  while (at + 8 <= bytes.size()) {
    const std::uint64_t length = BigEndian32(bytes, at);
    const std::string type = bytes.substr(at + 4, 4);
    const bool named = std::all_of(type.begin(), type.end(), [](char c) {
      return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z');
    });
    // The chunk's description, built only for a report.
    const auto damaged = [&](const std::string& what) {
      return "a damaged PNG" + size +
             "): " + (named ? "its " + type + " chunk" : "a chunk of damaged type") + " at byte " +
             std::to_string(at) + what;
    };
    if (at + 12 + length > bytes.size()) {
      const std::size_t tail = std::min<std::size_t>(bytes.size() - 8, 64);
      if (std::string_view(bytes).substr(bytes.size() - tail).find("IEND") ==
          std::string_view::npos)
        break;  // no IEND at the end either: cut short
      return damaged(" states a length of " + std::to_string(length) +
                     " bytes, past the file's end");
    }
    if (at == 8 && type != "IHDR") return damaged(" comes first, where IHDR must");
    const bool critical = named && type[0] >= 'A' && type[0] <= 'Z';
    if (critical || !named) {
      const std::uint32_t crc =
          libdeflate_crc32(0, bytes.data() + at + 4, static_cast<std::size_t>(length) + 4);
      if (crc != BigEndian32(bytes, at + 8 + length)) return damaged(" fails its CRC-32 check");
    }
    if (type == "IEND" && !seen_pixels) return damaged(" ends it before any IDAT (pixel data)");
    if (type == "IEND") return std::nullopt;
    seen_pixels = seen_pixels || type == "IDAT";
    at += 12 + length;
  }
  return "a PNG cut short" + size + ", without its closing IEND chunk)";
}

// The image formats a camera's frames come in (calibration/calibrate.cc's image extensions), by
// their leading bytes: PNG, JPEG, TIFF (either byte order; BigTIFF too), BMP and the PNM family
// (PBM, PGM, PPM, binary or text). Nothing else reaches OpenCV, whose other decoders (OpenEXR,
// Radiance HDR, JPEG 2000, WebP, ...) are no camera's frame format and trust their headers more
// than a frame's reader may: OpenEXR's allocates what a damaged attribute size states (a fuzzer's
// finding, tests/fuzz/regressions/image/). The signatures are whole, as OpenCV's own decoders
// check them, so that bytes let through are claimed by that decoder: a PNG's first 4 bytes alone
// let OpenCV try the rest on GDAL, through a temporary file. The format the bytes show is named
// when it is refused.
std::optional<std::string> NotAFrameFormat(std::string_view bytes) {
  using namespace std::string_view_literals;  // magic with NUL bytes in it
  const auto starts = [&](std::string_view magic) {
    return bytes.substr(0, magic.size()) == magic;
  };
  if (starts("\x89PNG\r\n\x1A\n"sv) || starts("\xFF\xD8\xFF"sv) || starts("II*\0"sv) ||
      starts("MM\0*"sv) || starts("II+\0"sv) || starts("MM\0+"sv) || starts("BM"sv))
    return std::nullopt;
  if (bytes.size() >= 3 && bytes[0] == 'P' && bytes[1] >= '1' && bytes[1] <= '6' &&
      std::isspace(static_cast<unsigned char>(bytes[2])))
    return std::nullopt;
  const std::string format =
      starts("\x89PNG"sv)   ? "a PNG with a damaged signature (a text-mode copy changes its line "
                              "ends)"
      : starts("v/1\x01"sv) ? "an OpenEXR file"
      : starts("#?RADIANCE"sv) || starts("#?RGBE"sv)             ? "a Radiance HDR file"
      : starts("RIFF"sv)                                         ? "a RIFF (WebP?) file"
      : starts("\0\0\0\x0CjP"sv) || starts("\xFF\x4F\xFF\x51"sv) ? "a JPEG 2000 file"
      : starts("version https://git-lfs"sv) ? "a Git LFS pointer, not the image (git lfs pull)"
                                            : "not a known image format";
  // The first bytes in hex and as text (a pointer or a note is legible).
  std::string hex, text;
  for (std::size_t i = 0; i < std::min<std::size_t>(bytes.size(), 8); ++i) {
    static const char* const kHex = "0123456789abcdef";
    const auto b = static_cast<unsigned char>(bytes[i]);
    hex += std::string(i ? " " : "") + kHex[b >> 4] + kHex[b & 15];
    text += b >= 0x20 && b < 0x7f ? static_cast<char>(b) : '.';
  }
  return format + " (it starts " + hex + ", \"" + text +
         "\"); a camera's frames are read as PNG, JPEG, TIFF, BMP or PGM/PPM";
}

// Damage is a DataError, the failure of the frame that holds the image (core/error.h), whether the
// file is missing, unreadable, empty, cut short or not an image.
cv::Mat Decode(const std::string& path) {
  std::optional<std::string> read;
  try {
    read = ReadFileIfPresent(path);
  } catch (const IoError& e) {
    throw DataError(e.what());
  }
  if (!read) throw DataError(path + ": no such image file");
  std::string& bytes = *read;  // non-const: cv::Mat wraps it (imdecode only reads)
  if (bytes.empty()) throw DataError(path + ": the image file is empty (0 bytes)");
  if (const auto other = NotAFrameFormat(bytes)) throw DataError(path + ": " + *other);
  if (const auto damage = PngDamage(bytes)) throw DataError(path + ": " + *damage);
  if (bytes.size() > static_cast<std::size_t>(std::numeric_limits<int>::max()))
    throw DataError(path + ": an image file of " + std::to_string(bytes.size()) +
                    " bytes is beyond what OpenCV decodes");
  cv::Mat in;
  try {
    in = cv::imdecode(cv::Mat(1, static_cast<int>(bytes.size()), CV_8U, bytes.data()),
                      cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception& e) {
    throw DataError(path + ": cannot decode: " + e.what());
  }
  if (in.empty())
    throw DataError(path + ": cannot be decoded (" + std::to_string(bytes.size()) +
                    " bytes): damaged, or not an image format OpenCV reads");
  return in;
}

}  // namespace

void WritePng(const std::string& path, const ImageU8& image) { WritePngImpl(path, image); }
void WritePng16(const std::string& path, const ImageU16& image) { WritePngImpl(path, image); }

ImageU8 ReadImageU8(const std::string& path, int channels) {
  cv::Mat in = Decode(path);
  if (in.depth() != CV_8U) {
    throw DataError(path + ": expected an 8-bit image, found another bit depth");
  }
  return FromMat<std::uint8_t>(path, in, channels);
}

int ReadImage(const std::string& path, ImageU8* image8, ImageU16* image16, int channels) {
  cv::Mat in = Decode(path);
  if (in.depth() == CV_8U) {
    *image8 = FromMat<std::uint8_t>(path, in, channels);
    *image16 = ImageU16();
    return 8;
  }
  if (in.depth() == CV_16U) {
    *image16 = FromMat<std::uint16_t>(path, in, channels);
    *image8 = ImageU8();
    return 16;
  }
  throw DataError(path + ": expected an 8-bit or 16-bit unsigned image");
}

ImageU8 ContactSheet(const std::vector<ImageU8>& tiles, int tile_height) {
  int total_w = 0;
  std::vector<int> widths;
  for (const auto& t : tiles) {
    int w = std::max(1, t.width * tile_height / std::max(1, t.height));
    widths.push_back(w);
    total_w += w + 4;
  }
  ImageU8 sheet(std::max(total_w, 1), tile_height, 3, 16);
  int x0 = 0;
  for (std::size_t n = 0; n < tiles.size(); ++n) {
    const ImageU8& t = tiles[n];
    for (int y = 0; y < tile_height; ++y)
      for (int x = 0; x < widths[n]; ++x) {
        int sx = std::min(t.width - 1, x * t.width / widths[n]);
        int sy = std::min(t.height - 1, y * t.height / tile_height);
        for (int c = 0; c < 3; ++c) sheet.at(x0 + x, y, c) = t.at(sx, sy, t.channels == 1 ? 0 : c);
      }
    x0 += widths[n] + 4;
  }
  return sheet;
}

void AddSensorNoise(ImageU8* image, double sigma_dn, std::uint64_t seed) {
  if (!(sigma_dn > 0)) return;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0.0, sigma_dn);
  for (auto& p : image->pixels)
    p = static_cast<std::uint8_t>(std::clamp(std::lround(p + noise(rng)), 0L, 255L));
}

}  // namespace flamerig
