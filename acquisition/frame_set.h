// The frame-set assembler: groups the frames of a rig's cameras into frame sets, one frame per
// camera taken at the same instant (DESIGN section 3).
//
// Matching, by the sync mode in force:
//  - by trigger id (hardware or software trigger, action commands): frames with the same trigger id
//    form a set;
//  - by timestamp (free-run, PTP): a frame joins the open set whose reference time (its first
//    frame's timestamp) is within `tolerance_ns` of its own, else opens a new set. The timestamp
//    used is the device timestamp (PTP-synchronised cameras share a clock) or the host receive time
//    (TimestampSource).
//
// A set is emitted complete as soon as every camera has a frame in it, or incomplete once it has
// waited `timeout_ns` (measured on the caller's clock, passed to Add and Poll) since it opened: a dead
// camera delays its sets by at most the timeout, never blocks the others. A frame for a set already
// emitted is "late": it is counted and returned to the caller, not merged. Sets are emitted in order
// of their reference time. Memory is bounded: at most `max_open_sets` sets wait; beyond that the
// oldest is emitted incomplete.
#ifndef FLAMERIG_ACQUISITION_FRAME_SET_H_
#define FLAMERIG_ACQUISITION_FRAME_SET_H_

#include <cstdint>
#include <deque>
#include <optional>
#include <vector>

#include "acquisition/frame.h"

namespace flamerig {

enum class MatchBy { kTriggerId, kTimestamp };
enum class TimestampSource { kDevice, kHostMonotonic };

struct FrameSetOptions {
  int cameras = 0;  // frames carry camera indices 0..cameras-1; >= 1
  MatchBy match = MatchBy::kTriggerId;
  TimestampSource timestamp = TimestampSource::kDevice;
  std::int64_t tolerance_ns = 2'000'000;  // timestamp matching: about half a frame period
  std::int64_t timeout_ns = 200'000'000;  // how long a set waits for its missing cameras
  int max_open_sets = 64;
  void Validate() const;  // throws InputError naming the field
};

struct FrameSet {
  std::uint64_t index = 0;                   // 0, 1, 2, ... in emission order
  std::int64_t trigger_id = -1;              // when matched by trigger
  std::int64_t reference_ns = 0;             // the timestamp the set was opened with
  std::vector<std::optional<Frame>> frames;  // one slot per camera
  bool complete() const;
  int present() const;
  // max - min of the present frames' timestamps (the chosen source): how well the cameras agreed.
  std::int64_t spread_ns = 0;
};

struct FrameSetCounters {
  std::uint64_t sets = 0, complete = 0, incomplete = 0;
  std::uint64_t late_frames = 0;       // arrived after their set was emitted
  std::uint64_t duplicate_frames = 0;  // a second frame of one camera for one set (the first kept)
  std::vector<std::uint64_t> missing_per_camera;  // sets emitted without that camera
  std::int64_t max_spread_ns = 0;
};

class FrameSetAssembler {
 public:
  explicit FrameSetAssembler(const FrameSetOptions& options);

  // Adds a frame received at `now_ns`; appends the sets that became ready to *ready (complete ones,
  // and timed-out ones). Returns false (and counts) when the frame was late or a duplicate. A frame
  // with a camera index outside the rig throws InputError.
  bool Add(Frame frame, std::int64_t now_ns, std::vector<FrameSet>* ready);
  // Emits the sets that have waited longer than the timeout at `now_ns`.
  void Poll(std::int64_t now_ns, std::vector<FrameSet>* ready);
  // Emits everything still open (at the end of a recording).
  void Flush(std::vector<FrameSet>* ready);

  const FrameSetCounters& counters() const { return counters_; }
  std::size_t open_sets() const { return open_.size(); }

 private:
  struct Open {
    FrameSet set;
    std::int64_t opened_ns = 0;  // caller's clock
  };
  std::int64_t Stamp(const Frame& f) const;
  void Emit(std::size_t i, std::vector<FrameSet>* ready);
  // Emits, in order, every open set up to and including the ones that must go.
  void EmitReady(std::int64_t now_ns, std::vector<FrameSet>* ready);

  FrameSetOptions options_;
  std::deque<Open> open_;  // ordered by reference time
  FrameSetCounters counters_;
  std::uint64_t next_index_ = 0;
  bool emitted_any_ = false;
  std::int64_t last_emitted_reference_ = 0;  // sets at or before it are closed
  std::int64_t last_emitted_trigger_ = -1;
};

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_FRAME_SET_H_
