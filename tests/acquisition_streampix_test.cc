// StreamPix .seq reading, on sequences written byte by byte here from the published layout
// (offsets spelled out below, independently of the reader's code). Version 5 files (StreamPix 6)
// keep 1024 in their header-size field but start their first image at byte 8192: so does
// sample_norpix6.seq of the pims project (6 frames of 36x32, 8 bit, timestamps 33 ms apart, read
// by our reader in a session; the file is not ours to ship), and so are the files written here.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <fstream>

#include "acquisition/streampix.h"
#include "core/error.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

struct SeqSpec {
  std::uint32_t version = 5, width = 6, height = 4, bit_depth = 8, format = 100;
  std::uint32_t compression = 0;
  int frames = 3;
  std::uint32_t padding = 8;  // after the timestamp
};

template <typename T>
void Put(std::vector<char>* b, std::size_t at, T v) {
  std::memcpy(b->data() + at, &v, sizeof v);
}

fs::path WriteSeq(const std::string& name, const SeqSpec& s) {
  const fs::path p = fs::temp_directory_path() / (name + std::to_string(::getpid()) + ".seq");
  const std::uint32_t image = s.width * s.height * s.bit_depth / 8;
  const std::uint32_t true_size = image + 8 + s.padding;
  std::vector<char> h(1024, 0);
  Put<std::uint32_t>(&h, 0, 0xFEED);
  const char16_t* title = u"Norpix seq\n";
  for (int i = 0; title[i]; ++i) Put<char16_t>(&h, 4 + 2 * i, title[i]);
  Put<std::int32_t>(&h, 28, static_cast<std::int32_t>(s.version));
  Put<std::int32_t>(&h, 32, 1024);
  const char16_t* text = u"candle, cam 1";
  for (int i = 0; text[i]; ++i) Put<char16_t>(&h, 36 + 2 * i, text[i]);
  Put<std::uint32_t>(&h, 548, s.width);
  Put<std::uint32_t>(&h, 552, s.height);
  Put<std::uint32_t>(&h, 556, s.bit_depth);
  Put<std::uint32_t>(&h, 560, s.bit_depth);
  Put<std::uint32_t>(&h, 564, image);
  Put<std::uint32_t>(&h, 568, s.format);
  Put<std::uint32_t>(&h, 572, static_cast<std::uint32_t>(s.frames));
  Put<std::uint32_t>(&h, 580, true_size);
  Put<double>(&h, 584, 500.0);
  Put<std::uint32_t>(&h, 620, s.compression);
  if (s.version >= 5) h.resize(8192, 0);  // the images of StreamPix 6 and later start at 8192
  std::ofstream out(p, std::ios::binary);
  out.write(h.data(), h.size());
  for (int f = 0; f < s.frames; ++f) {
    std::vector<char> frame(true_size, 0);
    for (std::uint32_t i = 0; i < image; ++i) frame[i] = static_cast<char>(10 * f + i);
    Put<std::int32_t>(&frame, image, 1'600'000'000 + f);                       // seconds
    Put<std::uint16_t>(&frame, image + 4, static_cast<std::uint16_t>(2 * f));  // ms
    Put<std::uint16_t>(&frame, image + 6, 7);                                  // us
    out.write(frame.data(), frame.size());
  }
  return p;
}

TEST(StreamPix, ReadsHeaderPixelsAndTimestamps) {
  const fs::path p = WriteSeq("mono", SeqSpec{});
  const StreamPixSequence seq(p.string());
  EXPECT_EQ(seq.header().version, 5u);
  EXPECT_EQ(seq.header().width, 6u);
  EXPECT_EQ(seq.header().frame_rate_hz, 500.0);
  EXPECT_EQ(seq.header().description, "candle, cam 1");
  ASSERT_EQ(seq.num_frames(), 3u);
  const Frame f = seq.ReadFrame(2, 4);
  EXPECT_EQ(f.info.camera, 4);
  EXPECT_EQ(f.info.pixel_format, PixelFormat::kMono8);
  ASSERT_EQ(f.bytes(), 24u);
  EXPECT_EQ((*f.data)[5], 25);
  EXPECT_EQ(f.info.device_timestamp_ns, (1'600'000'002LL * 1000 + 4) * 1'000'000 + 7'000);
  EXPECT_THROW(seq.ReadFrame(3), std::out_of_range);
  fs::remove(p);
}

TEST(StreamPix, BgrBecomesRgbAndOldVersionsHaveNoMicroseconds) {
  SeqSpec s;
  s.format = 200;
  s.bit_depth = 24;
  s.version = 4;
  const fs::path p = WriteSeq("bgr", s);
  const StreamPixSequence seq(p.string());
  const Frame f = seq.ReadFrame(1);
  EXPECT_EQ(f.info.pixel_format, PixelFormat::kRgb8);
  // Bytes 10, 11, 12 (B, G, R) -> R, G, B = 12, 11, 10.
  EXPECT_EQ((*f.data)[0], 12);
  EXPECT_EQ((*f.data)[1], 11);
  EXPECT_EQ((*f.data)[2], 10);
  EXPECT_EQ(f.info.device_timestamp_ns % 1'000'000, 0);
  fs::remove(p);
}

// Raw Bayer (image format 101) at 8 and 16 bits: the pattern the reader is given, in 8 or 16 bits.
TEST(StreamPix, RawBayerAtEightAndSixteenBits) {
  SeqSpec s;
  s.format = 101;
  const fs::path p8 = WriteSeq("bayer8", s);
  EXPECT_EQ(StreamPixSequence(p8.string(), PixelFormat::kBayerGr8).ReadFrame(0).info.pixel_format,
            PixelFormat::kBayerGr8);
  s.bit_depth = 16;
  const fs::path p16 = WriteSeq("bayer16", s);
  const Frame f = StreamPixSequence(p16.string(), PixelFormat::kBayerGr8).ReadFrame(1);
  EXPECT_EQ(f.info.pixel_format, PixelFormat::kBayerGr16);
  ASSERT_EQ(f.bytes(), 6u * 4u * 2u);
  EXPECT_EQ((*f.data)[7], 17);  // byte 7 of frame 1
  for (const auto& q : {p8, p16}) fs::remove(q);
}

TEST(StreamPix, CutShortCompressedAndForeignFilesAreClear) {
  const fs::path p = WriteSeq("cut", SeqSpec{});
  fs::resize_file(p, fs::file_size(p) - 20);  // the last frame is cut inside its pixels
  const StreamPixSequence cut(p.string());
  EXPECT_EQ(cut.num_frames(), 3u);  // the damaged frame is there, and reading it says so
  cut.ReadFrame(1, 0);
  try {
    cut.ReadFrame(2, 0);
    FAIL() << "a frame cut short was read";
  } catch (const DataError& e) {
    EXPECT_NE(std::string(e.what()).find("frame 2"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("cut short"), std::string::npos) << e.what();
  }
  // A header that states 20000 x 20000 pixels in a file of a few KiB: an error that says so
  // before a buffer of the stated 400 MB is made (a 65535 x 65535 header took 4.3 GB).
  SeqSpec huge;
  huge.width = huge.height = 20000;
  huge.frames = 0;
  const fs::path big = WriteSeq("huge", huge);
  std::ofstream(big, std::ios::binary | std::ios::app) << std::string(100, 'x');
  const StreamPixSequence claims(big.string());
  ASSERT_EQ(claims.num_frames(), 1u);
  try {
    claims.ReadFrame(0, 0);
    FAIL() << "a frame the file cannot hold was read";
  } catch (const DataError& e) {
    EXPECT_NE(std::string(e.what()).find("cut short (400000000 bytes"), std::string::npos)
        << e.what();
  }
  fs::remove(big);
  SeqSpec c;
  c.compression = 1;
  const fs::path q = WriteSeq("jpeg", c);
  try {
    StreamPixSequence seq(q.string());
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("compressed"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find(q.string()), std::string::npos);
  }
  SeqSpec y;
  y.format = 600;  // YUV422
  y.bit_depth = 16;
  const fs::path r = WriteSeq("yuv", y);
  EXPECT_THROW(StreamPixSequence(r.string()), std::runtime_error);
  std::ofstream(p, std::ios::binary | std::ios::trunc) << std::string(2000, 'x');
  try {
    StreamPixSequence seq(p.string());
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("0xFEED"), std::string::npos);
  }
  for (const auto& f : {p, q, r}) fs::remove(f);
}

}  // namespace
}  // namespace flamerig
