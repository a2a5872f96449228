// Time for the acquisition code: the host's clocks (SystemClock), or a ManualClock that a test (or
// a fast simulation) advances by hand so that every frame's timing is reproducible. Times are int64
// nanoseconds: monotonic (steady_clock, CLOCK_MONOTONIC) and realtime (system_clock).
#ifndef FLAMERIG_ACQUISITION_CLOCK_H_
#define FLAMERIG_ACQUISITION_CLOCK_H_

#include <atomic>
#include <cstdint>

namespace flamerig {

class Clock {
 public:
  virtual ~Clock() = default;
  virtual std::int64_t MonotonicNs() const = 0;
  virtual std::int64_t RealtimeNs() const = 0;
  // Blocks (or, for a manual clock, advances) until MonotonicNs() >= t.
  virtual void SleepUntil(std::int64_t monotonic_ns) = 0;
};

class SystemClock : public Clock {
 public:
  std::int64_t MonotonicNs() const override;
  std::int64_t RealtimeNs() const override;
  void SleepUntil(std::int64_t monotonic_ns) override;
};

// Time that moves only when told: SleepUntil jumps to the target. Realtime = monotonic + offset.
class ManualClock : public Clock {
 public:
  explicit ManualClock(std::int64_t start_ns = 0, std::int64_t realtime_offset_ns = 0)
      : now_(start_ns), offset_(realtime_offset_ns) {}
  std::int64_t MonotonicNs() const override { return now_.load(); }
  std::int64_t RealtimeNs() const override { return now_.load() + offset_; }
  void SleepUntil(std::int64_t t) override;
  void Advance(std::int64_t ns) { now_ += ns; }

 private:
  std::atomic<std::int64_t> now_;
  std::int64_t offset_;
};

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_CLOCK_H_
