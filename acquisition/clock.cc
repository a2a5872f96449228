#include "acquisition/clock.h"

#include <chrono>
#include <thread>

namespace flamerig {

std::int64_t SystemClock::MonotonicNs() const {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

std::int64_t SystemClock::RealtimeNs() const {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

void SystemClock::SleepUntil(std::int64_t t) {
  const std::int64_t now = MonotonicNs();
  if (t > now) std::this_thread::sleep_for(std::chrono::nanoseconds(t - now));
}

void ManualClock::SleepUntil(std::int64_t t) {
  std::int64_t now = now_.load();
  while (now < t && !now_.compare_exchange_weak(now, t)) {
  }
}

}  // namespace flamerig
