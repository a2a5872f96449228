// Reading images (core/image.h): what a damaged file says. A frame's image that a crash cut short,
// an empty or missing file, bytes that are no image: each a DataError naming the file and what is
// wrong (so that `run` fails that frame alone and says why), and libpng's own "libpng error" line
// no longer on stderr: a PNG cut short or with a damaged chunk is named before libpng reads it.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include "core/atomic_file.h"
#include "core/error.h"
#include "core/image.h"
#include "core/read_file.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

std::string ErrorReading(const std::string& path) {
  try {
    ReadImageU8(path);
  } catch (const DataError& e) {
    return e.what();
  }
  return "(no DataError)";
}

TEST(ReadImage, DamageIsADataErrorThatSaysWhat) {
  const fs::path dir = fs::temp_directory_path() / ("flamerig_image_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  // A noisy picture, so that the PNG is large enough to cut (random pixels do not compress).
  ImageU8 image(64, 48, 3);
  std::mt19937 random(3);
  for (auto& v : image.pixels) v = static_cast<std::uint8_t>(random() & 0xff);
  const std::string good = (dir / "good.png").string();
  WritePng(good, image);
  EXPECT_EQ(ReadImageU8(good).pixels, image.pixels);
  const std::string bytes = ReadFile(good);
  ASSERT_GT(bytes.size(), 9000u);

  // Cut short, as a crash during the write leaves it: named, and nothing from libpng on stderr.
  const std::string cut = (dir / "cut.png").string();
  WriteFileAtomically(cut, bytes.substr(0, bytes.size() / 2));
  testing::internal::CaptureStderr();
  const std::string cut_error = ErrorReading(cut);
  const std::string printed = testing::internal::GetCapturedStderr();
  EXPECT_EQ(cut_error, cut + ": a PNG cut short (" + std::to_string(bytes.size() / 2) +
                           " bytes, without its closing IEND chunk)");
  EXPECT_EQ(printed, "");
  // Its last 12 bytes only (the IEND chunk and its CRC) missing: the same.
  WriteFileAtomically(cut, bytes.substr(0, bytes.size() - 12));
  EXPECT_NE(ErrorReading(cut).find("a PNG cut short"), std::string::npos);

  // Bytes after the IEND chunk (some writers pad): read as before.
  const std::string padded = (dir / "padded.png").string();
  WriteFileAtomically(padded, bytes + std::string(16, '\0'));
  EXPECT_EQ(ReadImageU8(padded).pixels, image.pixels);

  // Damage inside: a flipped byte in the middle of the pixel data. The chunk that holds it is
  // named by its type and offset (an IDAT chunk that starts at most 8 KiB + 12 bytes before the
  // byte, libpng's chunk size), and libpng prints nothing.
  const std::size_t middle = bytes.size() / 2;
  std::string flipped = bytes;
  flipped[middle] = static_cast<char>(flipped[middle] ^ 0x5a);
  const std::string damaged = (dir / "damaged.png").string();
  WriteFileAtomically(damaged, flipped);
  testing::internal::CaptureStderr();
  const std::string damaged_error = ErrorReading(damaged);
  EXPECT_EQ(testing::internal::GetCapturedStderr(), "");
  const std::string prefix = damaged + ": a damaged PNG (" + std::to_string(bytes.size()) +
                             " bytes): its IDAT chunk at byte ";
  ASSERT_EQ(damaged_error.rfind(prefix, 0), 0u) << damaged_error;
  const std::size_t chunk_at = std::stoul(damaged_error.substr(prefix.size()));
  EXPECT_EQ(bytes.substr(chunk_at + 4, 4), "IDAT");
  EXPECT_LT(chunk_at, middle);
  EXPECT_LE(middle - chunk_at, 8192u + 12u);
  EXPECT_NE(damaged_error.find(" fails its CRC-32 check"), std::string::npos) << damaged_error;

  // The same chunk's length field overwritten: it would run past the end.
  std::string long_chunk = bytes;
  long_chunk.replace(chunk_at, 4, std::string("\x7f\xff\xff\xff", 4));
  WriteFileAtomically(damaged, long_chunk);
  EXPECT_NE(ErrorReading(damaged).find("its IDAT chunk at byte " + std::to_string(chunk_at) +
                                       " states a length of 2147483647 bytes, past the file's end"),
            std::string::npos)
      << ErrorReading(damaged);

  // The header chunk's type damaged (IHDR to iHDR, which alone would read as an ancillary chunk).
  std::string no_header = bytes;
  no_header[12] = 'i';
  WriteFileAtomically(damaged, no_header);
  EXPECT_EQ(ErrorReading(damaged),
            damaged + ": a damaged PNG (" + std::to_string(bytes.size()) +
                " bytes): its iHDR chunk at byte 8 comes first, where IHDR must");

  // No pixel data: the header followed by the closing chunk.
  WriteFileAtomically(damaged, bytes.substr(0, 33) + bytes.substr(bytes.size() - 12));
  EXPECT_EQ(ErrorReading(damaged), damaged +
                                       ": a damaged PNG (45 bytes): its IEND chunk at byte 33 "
                                       "ends it before any IDAT (pixel data)");

  // An ancillary chunk (a tEXt note after the 33 bytes of signature and IHDR) with a wrong CRC:
  // the pixels still read, as libpng reads them (it drops the chunk).
  const std::string text_chunk = std::string("\0\0\0\x04tEXtab\0c", 12) + std::string(4, '\x11');
  std::string with_note = bytes;
  with_note.insert(33, text_chunk);
  const std::string noted = (dir / "noted.png").string();
  WriteFileAtomically(noted, with_note);
  testing::internal::CaptureStderr();
  EXPECT_EQ(ReadImageU8(noted).pixels, image.pixels);
  testing::internal::GetCapturedStderr();

  const std::string empty = (dir / "empty.png").string();
  WriteFileAtomically(empty, "");
  EXPECT_EQ(ErrorReading(empty), empty + ": the image file is empty (0 bytes)");
  const std::string missing = (dir / "missing.png").string();
  EXPECT_EQ(ErrorReading(missing), missing + ": no such image file");
  const std::string text = (dir / "notes.png").string();
  WriteFileAtomically(text, "not an image at all\n");
  EXPECT_EQ(ErrorReading(text), text +
                                    ": not a known image format (it starts 6e 6f 74 20 61 6e 20 "
                                    "69, \"not an i\"); a camera's frames are read as PNG, JPEG, "
                                    "TIFF, BMP or PGM/PPM");
  EXPECT_NE(ErrorReading(dir.string()).find("it is a folder"), std::string::npos);

  // A 16-bit image where 8 bits are wanted.
  ImageU16 deep(8, 8, 1);
  const std::string deep_path = (dir / "deep.png").string();
  WritePng16(deep_path, deep);
  EXPECT_NE(ErrorReading(deep_path).find("expected an 8-bit image"), std::string::npos);
  ImageU8 as8;
  ImageU16 as16;
  EXPECT_EQ(ReadImage(deep_path, &as8, &as16), 16);
  EXPECT_EQ(as16.width, 8);
  fs::remove_all(dir);
}

// The formats a camera's frames come in read back (whatever the file is called: the bytes decide);
// any other format OpenCV decodes is refused before its decoder sees it, named by its magic. The
// OpenEXR file is the fuzzer's finding (tests/fuzz/regressions/image/): a damaged attribute size
// that OpenEXR's header reader allocated.
TEST(ReadImage, OnlyACamerasFrameFormatsReachOpenCV) {
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig_formats_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  ImageU8 image(16, 12, 3);
  for (std::size_t i = 0; i < image.pixels.size(); ++i)
    image.pixels[i] = static_cast<std::uint8_t>(i * 7);
  for (const char* extension : {".png", ".tif", ".bmp", ".ppm", ".jpg"}) {
    const std::string written = (dir / (std::string("frame") + extension)).string();
    WritePng(written, image);
    const std::string renamed = written + ".img";  // the magic decides, not the name
    fs::rename(written, renamed);
    const ImageU8 back = ReadImageU8(renamed, 3);
    ASSERT_EQ(back.pixels.size(), image.pixels.size()) << extension;
    if (std::string(extension) != ".jpg") {
      EXPECT_EQ(back.pixels, image.pixels) << extension;
    }
  }
  ImageU8 grey(16, 12, 1);
  WritePng((dir / "grey.pgm").string(), grey);
  EXPECT_EQ(ReadImageU8((dir / "grey.pgm").string()).channels, 1);

  // The fuzzer's finding itself (an OpenEXR header whose attribute states a huge size).
  const std::string exr =
      std::string(FLAMERIG_SOURCE_DIR) + "/tests/fuzz/regressions/image/openexr_attribute_size_oom";
  EXPECT_EQ(ErrorReading(exr), exr +
                                   ": an OpenEXR file (it starts 76 2f 31 01 02 00 00 00, "
                                   "\"v/1.....\"); a camera's frames are read as PNG, JPEG, TIFF, "
                                   "BMP or PGM/PPM");
  // A PNG whose signature a text-mode copy changed (\r\n to \n): named, and never handed to
  // OpenCV, whose GDAL decoder took such bytes before.
  WritePng((dir / "frame.png").string(), image);
  std::string mangled = ReadFile((dir / "frame.png").string());
  mangled.erase(4, 1);  // the \r
  const std::string text_copy = (dir / "text_copy.png").string();
  WriteFileAtomically(text_copy, mangled);
  testing::internal::CaptureStderr();
  EXPECT_NE(ErrorReading(text_copy).find(": a PNG with a damaged signature"), std::string::npos)
      << ErrorReading(text_copy);
  EXPECT_EQ(testing::internal::GetCapturedStderr(), "");
  const std::string hdr = (dir / "sky.hdr").string();
  WriteFileAtomically(hdr, "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n");
  EXPECT_NE(ErrorReading(hdr).find(": a Radiance HDR file (it starts 23 3f 52"), std::string::npos)
      << ErrorReading(hdr);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace flamerig
