#include "acquisition/live_exposure.h"

#include <cmath>

namespace flamerig {

void LiveExposure::Reset(const ExposureSettings& settings) {
  std::lock_guard<std::mutex> lock(mutex_);
  first_ = settings;
  changes_.clear();
}

void LiveExposure::Change(const ExposureSettings& settings, std::int64_t at_ns) {
  std::lock_guard<std::mutex> lock(mutex_);
  // Times go forward; a change stamped before the last one (a clock step) takes the last's time.
  if (!changes_.empty() && at_ns < changes_.back().at_ns) at_ns = changes_.back().at_ns;
  changes_.push_back({settings, at_ns});
  if (changes_.size() > kHistory) {
    first_ = changes_.front().settings;
    changes_.pop_front();
  }
}

ExposureSettings LiveExposure::Current() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return changes_.empty() ? first_ : changes_.back().settings;
}

ExposureSettings LiveExposure::ForFrameStartingAt(std::int64_t start_ns) const {
  std::lock_guard<std::mutex> lock(mutex_);
  for (auto it = changes_.rbegin(); it != changes_.rend(); ++it)
    if (it->at_ns <= start_ns) return it->settings;
  return first_;
}

ExposureSettings LiveExposure::ForFrameEndingAt(std::int64_t end_ns) const {
  std::lock_guard<std::mutex> lock(mutex_);
  for (auto it = changes_.rbegin(); it != changes_.rend(); ++it) {
    const double exposure_ns =
        std::isfinite(it->settings.exposure_us) && it->settings.exposure_us > 0
            ? it->settings.exposure_us * 1e3
            : 0.0;
    if (double(end_ns) - exposure_ns >= double(it->at_ns)) return it->settings;
  }
  return first_;
}

}  // namespace flamerig
