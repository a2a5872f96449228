// Which exposure a frame was taken with when it changes while the camera streams
// (acquisition/live_exposure.h): the oracle is the timeline itself, a frame's exposure window
// against the moments of the changes, worked out by hand for each case.
#include "acquisition/live_exposure.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <string>
#include <thread>
#include <vector>

namespace flamerig {
namespace {

constexpr std::int64_t kMs = 1'000'000;

TEST(LiveExposure, AFrameKeepsTheSettingsItsExposureBeganWith) {
  LiveExposure live;
  live.Reset({10000, 0});  // 10 ms
  EXPECT_EQ(live.Current().exposure_us, 10000);
  // Nothing changed yet: every frame is at the configured settings.
  EXPECT_EQ(live.ForFrameEndingAt(5 * kMs).exposure_us, 10000);
  // At t = 100 ms the exposure becomes 5 ms and the gain 6 dB.
  live.Change({5000, 6}, 100 * kMs);
  EXPECT_EQ(live.Current().exposure_us, 5000);
  EXPECT_EQ(live.Current().gain_db, 6);
  // A frame that arrived before the change, or waited in a buffer: the old settings.
  EXPECT_EQ(live.ForFrameEndingAt(99 * kMs).exposure_us, 10000);
  // One that arrived 3 ms after it: at the new 5 ms its exposure would have begun 2 ms before the
  // change, so it was exposed at the old settings (in flight).
  EXPECT_EQ(live.ForFrameEndingAt(103 * kMs).exposure_us, 10000);
  EXPECT_EQ(live.ForFrameEndingAt(103 * kMs).gain_db, 0);
  // One that arrived between 5 and 10 ms after it could have begun at the change under the new
  // 5 ms or before it under the old 10 ms: taken as the old (exposed first).
  EXPECT_EQ(live.ForFrameEndingAt(105 * kMs).exposure_us, 10000);
  EXPECT_EQ(live.ForFrameEndingAt(109 * kMs).exposure_us, 10000);
  // From 10 ms after the change on, only the new settings fit.
  EXPECT_EQ(live.ForFrameEndingAt(110 * kMs).exposure_us, 5000);
  EXPECT_EQ(live.ForFrameEndingAt(130 * kMs).gain_db, 6);
  // Timed by its exposure's start instead (a V4L2 driver stamping the start of exposure).
  EXPECT_EQ(live.ForFrameStartingAt(99 * kMs).exposure_us, 10000);
  EXPECT_EQ(live.ForFrameStartingAt(100 * kMs).exposure_us, 5000);
  // A second change at 120 ms, lengthening to 20 ms. A frame arriving at 124 ms began at 119 ms
  // under the 5 ms settings, before that change: 5 ms. One arriving at 130 ms fits neither (at
  // 5 ms it began at 125, after the change; at 20 ms at 110, before it): the settings in force at
  // its end, 20 ms. From 140 ms on, 20 ms fits.
  live.Change({20000, 0}, 120 * kMs);
  EXPECT_EQ(live.ForFrameEndingAt(124 * kMs).exposure_us, 5000);
  EXPECT_EQ(live.ForFrameEndingAt(130 * kMs).exposure_us, 20000);
  EXPECT_EQ(live.ForFrameEndingAt(140 * kMs).exposure_us, 20000);
  EXPECT_EQ(live.ForFrameEndingAt(102 * kMs).exposure_us, 10000);
  // Reset (a new configure) forgets the history.
  live.Reset({8000, 1});
  EXPECT_EQ(live.ForFrameEndingAt(125 * kMs).exposure_us, 8000);
}

TEST(LiveExposure, TheHistoryIsBoundedAndTimesOnlyGoForward) {
  LiveExposure live;
  live.Reset({1000, 0});
  for (int k = 1; k <= 40; ++k) live.Change({1000.0 + k, 0}, k * 10 * kMs);
  // The oldest changes fold into the starting settings: a frame from long ago gets the oldest
  // change kept, not a made-up value.
  EXPECT_EQ(live.ForFrameStartingAt(0).exposure_us, 1000.0 + 40 - double(LiveExposure::kHistory));
  EXPECT_EQ(live.ForFrameStartingAt(400 * kMs).exposure_us, 1040);
  // A change stamped before the last one (a clock stepped back) is taken at the last one's time.
  live.Change({7, 0}, 5 * kMs);
  EXPECT_EQ(live.ForFrameStartingAt(400 * kMs).exposure_us, 7);
  EXPECT_EQ(live.ForFrameStartingAt(399 * kMs).exposure_us, 1039);
}

// A change from the control thread while the camera thread labels frames. Whatever has been
// added so far, a frame that began at k ms has a change made at k ms or before (exposure 10000 +
// at most k), or, when changes after k have pushed it out of the bounded history, the oldest one
// kept (10000 + at most n - kHistory for n changes made): never a change newer than both. The
// lookups check against the count of changes made, read after each (the changer counts after
// its change, so one more may be in). A failure is kept and reported after the join (an ASSERT
// here, with the changer running, aborted the test: seen in CI once).
TEST(LiveExposure, ChangesAndLookupsFromTwoThreads) {
  LiveExposure live;
  live.Reset({10000, 0});
  std::atomic<int> made{0};
  std::thread changer([&] {
    for (int k = 1; k <= 2000; ++k) {
      live.Change({10000.0 + k, 0}, k * kMs);
      made.store(k, std::memory_order_release);
    }
  });
  std::string wrong;
  for (int k = 0; k < 2000 && wrong.empty(); ++k) {
    const double e = live.ForFrameStartingAt(std::int64_t(k) * kMs).exposure_us;
    const int n = made.load(std::memory_order_acquire) + 1;
    const double newest = 10000.0 + std::max(k, n - int(LiveExposure::kHistory));
    if (!(e >= 10000 && e <= newest))
      wrong = "frame at " + std::to_string(k) + " ms: " + std::to_string(e) + " after about " +
              std::to_string(n) + " changes";
  }
  changer.join();
  EXPECT_TRUE(wrong.empty()) << wrong;
  EXPECT_EQ(live.Current().exposure_us, 12000);
  EXPECT_EQ(live.ForFrameStartingAt(1995 * kMs).exposure_us, 11995);  // within the history kept
}

}  // namespace
}  // namespace flamerig
