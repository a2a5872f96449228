// The capture daemon's YAML config (acquisition/capture.h): errors are flamerig::InputError (core/error.h).
#include <string>

#include "acquisition/capture.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  try {
    flamerig::CaptureConfig::Parse(std::string(reinterpret_cast<const char*>(data), size), "fuzz");
  } catch (const std::invalid_argument&) {
  } catch (const std::runtime_error&) {
  }
  return 0;
}
