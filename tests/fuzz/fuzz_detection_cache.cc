// The board-detection cache (calibration/calibrate.h): a damaged cache must never crash or poison a
// calibration; entries that do not fit the board are dropped.
#include <string>

#include "calibration/calibrate.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const flamerig::BoardSpec board = [] {
    flamerig::BoardSpec b;
    return b;
  }();
  std::map<std::string, flamerig::BoardDetection> entries;
  flamerig::ParseDetectionCache(std::string(reinterpret_cast<const char*>(data), size), board,
                                flamerig::DetectOptions(), &entries);
  for (const auto& [key, d] : entries) {
    if (d.corner_ids.size() != d.corners_px.size()) __builtin_trap();
    for (int id : d.corner_ids)
      if (id < 0 || id >= board.num_corners()) __builtin_trap();
    for (const auto& r : d.rejected)
      if (r.corner_id < 0 || r.corner_id >= board.num_corners() || !r.px.allFinite())
        __builtin_trap();
  }
  return 0;
}
