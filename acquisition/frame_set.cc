#include "acquisition/frame_set.h"

#include <algorithm>
#include <stdexcept>
#include <string>

#include "core/error.h"

namespace flamerig {

void FrameSetOptions::Validate() const {
  auto fail = [](const std::string& what) {
    throw InputError("frame set options: " + what);
  };
  if (cameras < 1) fail("cameras must be >= 1");
  if (tolerance_ns < 0) fail("tolerance_ns must be >= 0");
  if (timeout_ns <= 0) fail("timeout_ns must be > 0");
  if (max_open_sets < 1) fail("max_open_sets must be >= 1");
}

bool FrameSet::complete() const {
  for (const auto& f : frames)
    if (!f) return false;
  return true;
}

int FrameSet::present() const {
  int n = 0;
  for (const auto& f : frames) n += f.has_value();
  return n;
}

FrameSetAssembler::FrameSetAssembler(const FrameSetOptions& options) : options_(options) {
  options_.Validate();
  counters_.missing_per_camera.assign(options_.cameras, 0);
}

std::int64_t FrameSetAssembler::Stamp(const Frame& f) const {
  return options_.timestamp == TimestampSource::kDevice ? f.info.device_timestamp_ns
                                                        : f.info.host_monotonic_ns;
}

bool FrameSetAssembler::Add(Frame frame, std::int64_t now_ns, std::vector<FrameSet>* ready) {
  const int c = frame.info.camera;
  if (c < 0 || c >= options_.cameras) {
    throw InputError("frame set: camera index " + std::to_string(c) + " outside 0.." +
                                std::to_string(options_.cameras - 1));
  }
  const bool by_trigger = options_.match == MatchBy::kTriggerId;
  const std::int64_t key = by_trigger ? frame.info.trigger_id : Stamp(frame);
  // The open set it belongs to.
  std::size_t match = open_.size();
  std::int64_t best = options_.tolerance_ns + 1;
  for (std::size_t i = 0; i < open_.size(); ++i) {
    if (by_trigger) {
      if (open_[i].set.trigger_id == key) {
        match = i;
        break;
      }
    } else {
      const std::int64_t d = std::abs(open_[i].set.reference_ns - key);
      if (d <= options_.tolerance_ns && d < best) {
        best = d;
        match = i;
      }
    }
  }
  bool accepted = true;
  if (match == open_.size()) {
    const bool closed =
        emitted_any_ && (by_trigger ? key <= last_emitted_trigger_
                                    : key <= last_emitted_reference_ + options_.tolerance_ns);
    if (closed) {
      ++counters_.late_frames;
      accepted = false;
    } else {
      Open o;
      o.set.frames.assign(options_.cameras, std::nullopt);
      o.set.trigger_id = by_trigger ? key : frame.info.trigger_id;
      o.set.reference_ns = Stamp(frame);
      o.opened_ns = now_ns;
      // Keep the open sets ordered by their key.
      auto before = [&](const Open& x) {
        return by_trigger ? x.set.trigger_id < key : x.set.reference_ns < key;
      };
      auto it = std::find_if_not(open_.begin(), open_.end(), before);
      match = static_cast<std::size_t>(it - open_.begin());
      open_.insert(it, std::move(o));
    }
  }
  if (accepted) {
    auto& slot = open_[match].set.frames[c];
    if (slot) {
      ++counters_.duplicate_frames;
      accepted = false;
    } else {
      slot = std::move(frame);
    }
  }
  EmitReady(now_ns, ready);
  return accepted;
}

void FrameSetAssembler::Poll(std::int64_t now_ns, std::vector<FrameSet>* ready) {
  EmitReady(now_ns, ready);
}

void FrameSetAssembler::Flush(std::vector<FrameSet>* ready) {
  while (!open_.empty()) Emit(0, ready);
}

void FrameSetAssembler::EmitReady(std::int64_t now_ns, std::vector<FrameSet>* ready) {
  while (!open_.empty()) {
    const Open& front = open_.front();
    bool go = front.set.complete() || now_ns - front.opened_ns >= options_.timeout_ns ||
              open_.size() > static_cast<std::size_t>(options_.max_open_sets);
    if (!go) {
      // Cameras deliver in order: a camera missing here that has already delivered a frame to a
      // later set will not deliver this one.
      go = true;
      for (int c = 0; c < options_.cameras && go; ++c) {
        if (front.set.frames[c]) continue;
        bool later = false;
        for (std::size_t i = 1; i < open_.size() && !later; ++i)
          later = open_[i].set.frames[c].has_value();
        go = later;
      }
    }
    if (!go) return;
    Emit(0, ready);
  }
}

void FrameSetAssembler::Emit(std::size_t i, std::vector<FrameSet>* ready) {
  Open o = std::move(open_[i]);
  open_.erase(open_.begin() + static_cast<std::ptrdiff_t>(i));
  FrameSet& s = o.set;
  s.index = next_index_++;
  std::int64_t lo = 0, hi = 0;
  bool first = true;
  for (int c = 0; c < options_.cameras; ++c) {
    if (!s.frames[c]) {
      ++counters_.missing_per_camera[c];
      continue;
    }
    const std::int64_t t = Stamp(*s.frames[c]);
    lo = first ? t : std::min(lo, t);
    hi = first ? t : std::max(hi, t);
    first = false;
  }
  s.spread_ns = hi - lo;
  counters_.max_spread_ns = std::max(counters_.max_spread_ns, s.spread_ns);
  ++counters_.sets;
  if (s.complete())
    ++counters_.complete;
  else
    ++counters_.incomplete;
  last_emitted_reference_ =
      emitted_any_ ? std::max(last_emitted_reference_, s.reference_ns) : s.reference_ns;
  last_emitted_trigger_ =
      emitted_any_ ? std::max(last_emitted_trigger_, s.trigger_id) : s.trigger_id;
  emitted_any_ = true;
  ready->push_back(std::move(s));
}

}  // namespace flamerig
