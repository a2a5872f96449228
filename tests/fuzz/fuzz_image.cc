// A camera's image file (core/image.h's ReadImage, which every frame of a folder, `simulate`'s
// datasets and the calibration views go through): OpenCV decodes it, flamerig checks it (a PNG
// cut short) and converts its channels. Errors are DataError (a std::runtime_error) naming the
// file.
#include <cstdlib>
#include <stdexcept>

#include "core/image.h"
#include "tests/fuzz/fuzz_util.h"

// OpenCV refuses images over OPENCV_IO_MAX_IMAGE_PIXELS (its default 2^30) before it allocates
// them; a header that states a gigapixel would otherwise be a gigabyte-sized allocation, which the
// fuzzer's malloc limit reports. Here 2^24 (a 16-megapixel image), so that the limit is met.
extern "C" int LLVMFuzzerInitialize(int*, char***) {
  ::setenv("OPENCV_IO_MAX_IMAGE_PIXELS", "16777216", 1);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string path = flamerig_fuzz::WriteFile("in.png", data, size);
  for (int channels : {0, 1, 3}) {
    try {
      flamerig::ImageU8 u8;
      flamerig::ImageU16 u16;
      flamerig::ReadImage(path, &u8, &u16, channels);
    } catch (const std::runtime_error&) {
    }
  }
  return 0;
}
