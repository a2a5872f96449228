// A recording directory (acquisition/recording.h), as the four files of a one-camera recording
// joined by kSeparator in the order of kFiles: opening and reading every set either works or throws
// RecordingError naming the file; torn tails are recovered, never trusted; what a frame says it was
// sent in is read without fault, whatever it says.
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>

#include "acquisition/recording.h"
#include "tests/fuzz/fuzz_util.h"

namespace {
const std::string kSeparator("\0FLAMERIG-FILE\0", 15);
const char* kFiles[] = {"metadata.yaml", "sets.index", "cam00.index", "cam00.data"};
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string input(reinterpret_cast<const char*>(data), size);
  const std::filesystem::path dir = flamerig_fuzz::Dir() / "recording";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  std::size_t at = 0;
  for (const char* name : kFiles) {
    const std::size_t end = std::min(input.find(kSeparator, at), input.size());
    const std::string part = input.substr(std::min(at, input.size()), end - std::min(at, end));
    std::ofstream((dir / name).string(), std::ios::binary) << part;
    at = end == input.size() ? end : end + kSeparator.size();
  }
  try {
    const flamerig::Recording rec = flamerig::Recording::Open(dir.string());
    for (std::size_t i = 0; i < std::min<std::size_t>(rec.num_sets(), 16); ++i) {
      const flamerig::FrameSet set = rec.ReadSet(i);
      for (std::size_t c = 0; c < set.frames.size() && c < rec.metadata().cameras.size(); ++c)
        if (set.frames[c])  // what a frame says it was sent in, whatever the bytes say
          flamerig::FullScaleValue(set.frames[c]->info,
                                   rec.metadata().cameras[c].settings.wire_format);
    }
    rec.MissingByFrameId();
  } catch (const flamerig::Error&) {  // every error of the hierarchy (core/error.h)
  } catch (const std::invalid_argument&) {
  }
  return 0;
}
