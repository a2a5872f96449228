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
  // Oldest first: the first settings under which the frame's exposure, counted back from its end,
  // began while they were in force. A frame that fits both sides of a change (an exposure
  // shortened at t: ending between t + the new time and t + the old, it began before t at the old
  // or after t at the new) is taken as the old settings', as it was exposed first.
  const auto exposure_ns = [](const ExposureSettings& s) {
    return std::isfinite(s.exposure_us) && s.exposure_us > 0 ? s.exposure_us * 1e3 : 0.0;
  };
  const double end = double(end_ns);
  for (std::size_t k = 0; k <= changes_.size(); ++k) {
    const ExposureSettings& s = k == 0 ? first_ : changes_[k - 1].settings;
    const double from = k == 0 ? -HUGE_VAL : double(changes_[k - 1].at_ns);
    const double until = k == changes_.size() ? HUGE_VAL : double(changes_[k].at_ns);
    const double began = end - exposure_ns(s);
    if (began >= from && began < until) return s;
  }
  // None fits (an exposure lengthened at t, the frame ending between t + the old time and t + the
  // new: under the old it began after t, under the new before): the settings in force at its end,
  // which the camera had taken when it began.
  for (auto it = changes_.rbegin(); it != changes_.rend(); ++it)
    if (it->at_ns <= end_ns) return it->settings;
  return first_;
}

}  // namespace flamerig
