// A StreamPix .seq file (acquisition/streampix.h): errors are std::runtime_error naming the file.
#include <algorithm>

#include "acquisition/frame.h"
#include "acquisition/streampix.h"
#include "tests/fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string path = flamerig_fuzz::WriteFile("in.seq", data, size);
  try {
    const flamerig::StreamPixSequence seq(path);
    for (std::size_t i = 0; i < std::min<std::size_t>(seq.num_frames(), 8); ++i) {
      const flamerig::Frame f = seq.ReadFrame(i);
      flamerig::ImageU8 u8;
      flamerig::ImageU16 u16;
      flamerig::DecodeFrame(f, &u8, &u16);
    }
  } catch (const std::runtime_error&) {
  } catch (const std::invalid_argument&) {
  } catch (const std::out_of_range&) {
  }
  return 0;
}
