// Images as the rest of flamerig sees them: a width x height raster of interleaved channels.
//
// Pixel (x, y) is column x, row y; the centre of the top-left pixel is (0, 0), as in OpenCV and
// mrcal. Channels are interleaved (RGBRGB...) in row-major order: element (x, y, c) is at
// ((y * width) + x) * channels + c. Colour images are RGB, never BGR; conversion to OpenCV's BGR
// happens only inside the file I/O functions below.
//
// Thread safety: an Image is a value; concurrent reads are safe, writes need external locking.
#ifndef FLAMERIG_CORE_IMAGE_H_
#define FLAMERIG_CORE_IMAGE_H_

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace flamerig {

template <typename T>
struct Image {
  int width = 0;
  int height = 0;
  int channels = 0;
  std::vector<T> pixels;  // width * height * channels values, interleaved, row-major

  Image() = default;
  Image(int width_px, int height_px, int num_channels, T fill = T{})
      : width(width_px),
        height(height_px),
        channels(num_channels),
        pixels(static_cast<std::size_t>(width_px) * height_px * num_channels, fill) {}

  bool empty() const { return pixels.empty(); }
  std::size_t num_pixels() const { return static_cast<std::size_t>(width) * height; }
  T& at(int x, int y, int c = 0) {
    return pixels[(static_cast<std::size_t>(y) * width + x) * channels + c];
  }
  const T& at(int x, int y, int c = 0) const {
    return pixels[(static_cast<std::size_t>(y) * width + x) * channels + c];
  }
};

using ImageU8 = Image<std::uint8_t>;
using ImageU16 = Image<std::uint16_t>;
using ImageF = Image<float>;

// Writes an 8-bit image (1 or 3 channels, RGB order) as PNG (or the format of the path's
// extension, which OpenCV knows), whole or not at all (core/atomic_file.h). Throws IoError naming
// the path and the system's reason when the file cannot be written (a full disk, say).
void WritePng(const std::string& path, const ImageU8& image);
// The same for 16-bit images (PNG stores 16 bits per channel).
void WritePng16(const std::string& path, const ImageU16& image);

// Reads an 8-bit PNG (or JPEG, TIFF, BMP, PBM/PGM/PPM: the formats a camera's frames come in,
// known by their leading bytes, whatever the file is called) as 1 or 3 channels (RGB order);
// `channels` 0 keeps the file's channel count (alpha dropped). Throws DataError naming the path and
// what is wrong when the file is missing, unreadable, empty, of another format (OpenEXR, Radiance
// HDR, ...: named, and never handed to OpenCV's decoder for it), a PNG cut short (no closing IEND chunk), a
// PNG with a damaged chunk (a critical chunk failing its CRC-32, a length past the file's end, a
// first chunk that is not IHDR, an IEND before any IDAT: the chunk's type and byte offset named),
// cannot be decoded, or is not 8-bit. A PNG's damage is found before libpng reads it, so libpng
// prints no error of its own (only its warning for a damaged ancillary chunk, which it drops).
ImageU8 ReadImageU8(const std::string& path, int channels = 0);
// Reads an 8-bit or 16-bit image into *image8 or *image16 (the other is left empty) and returns
// the bit depth, 8 or 16. Same channel rules and errors as ReadImageU8.
int ReadImage(const std::string& path, ImageU8* image8, ImageU16* image16, int channels = 0);

// Tiles side by side, scaled to a common height (grey promoted to RGB), 4 px apart on a dark grey
// background: a picture to look at.
ImageU8 ContactSheet(const std::vector<ImageU8>& tiles, int tile_height);

// Adds Gaussian noise of `sigma_dn` 8-bit units to every channel, rounded and clamped to [0, 255],
// deterministically from `seed` (std::mt19937_64).
void AddSensorNoise(ImageU8* image, double sigma_dn, std::uint64_t seed);

}  // namespace flamerig

#endif  // FLAMERIG_CORE_IMAGE_H_
