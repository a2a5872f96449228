// Progress and cancellation for every long operation (STYLE.md 5; after Ceres' IterationCallback
// and OpenVDB's NullInterrupter).
//
// A long operation (a render, a tomography solve, a fit, board detection, a run over frames) takes
// one ProgressCallback and calls it at safe points: places where stopping leaves nothing half
// done. The callback gets a Progress (what stage, how far, an optional line worth logging) and
// answers kContinue or kCancel. After kCancel the operation stops at that point: the fits return
// their current result with termination "cancelled" (fitting/fit.h), jobs without a partial
// result throw Cancelled (core/error.h), and `run` returns with the frames committed so far.
//
// Library code never prints: the CLI subscribes and draws progress bars (tools/cli.h), a test
// subscribes and counts, or asks to stop. A null callback means no progress and no cancellation.
//
// Thread safety: an operation never calls its callback concurrently (parallel work reports under
// a lock, so the call may come from a worker thread); CancelFlag may be raised from any thread or
// a signal handler.
#ifndef FLAMERIG_CORE_PROGRESS_H_
#define FLAMERIG_CORE_PROGRESS_H_

#include <atomic>
#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

namespace flamerig {

struct Progress {
  std::string stage;      // what is being done: "render", "detect", "frames", "fit", "solve"
  std::int64_t done = 0;  // units of work finished in this stage
  std::int64_t total = 0;  // units in the stage; 0 when unknown
  std::string unit;        // what a unit is: "frames", "samples", "iterations", "images"
  std::string message;     // a line worth logging now (a frame's summary); "" = none
  // Named figures of the work so far, units in the names: {"energy", 1.2e4},
  // {"mean_delta_e", 0.21}, {"residual_rms", 3e-3}.
  std::vector<std::pair<std::string, double>> values;
};

enum class ProgressAction { kContinue, kCancel };

using ProgressCallback = std::function<ProgressAction(const Progress&)>;

// Reports `p` through `callback` (null: nothing) and says whether the operation must stop.
inline bool ReportProgress(const ProgressCallback& callback, const Progress& p) {
  return callback && callback(p) == ProgressAction::kCancel;
}

// A callback that never cancels and only observes: adapts a void observer.
inline ProgressCallback Observe(std::function<void(const Progress&)> observer) {
  if (!observer) return nullptr;
  return [observer = std::move(observer)](const Progress& p) {
    observer(p);
    return ProgressAction::kContinue;
  };
}

// A stop request that any thread or a signal handler may raise (lock-free), and that a progress
// callback turns into kCancel. The CLI raises one on SIGINT and SIGTERM (tools/cli.h).
class CancelFlag {
 public:
  void Raise() { raised_.store(true, std::memory_order_relaxed); }
  void Clear() { raised_.store(false, std::memory_order_relaxed); }
  bool raised() const { return raised_.load(std::memory_order_relaxed); }

 private:
  std::atomic<bool> raised_{false};
  static_assert(std::atomic<bool>::is_always_lock_free, "raised from signal handlers");
};

// `callback` (may be null), made to answer kCancel once `flag` is raised.
inline ProgressCallback CancelledBy(const CancelFlag* flag, ProgressCallback callback) {
  return [flag, callback = std::move(callback)](const Progress& p) {
    const ProgressAction a = callback ? callback(p) : ProgressAction::kContinue;
    return flag && flag->raised() ? ProgressAction::kCancel : a;
  };
}

}  // namespace flamerig

#endif  // FLAMERIG_CORE_PROGRESS_H_
