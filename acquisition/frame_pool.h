// Frame buffers that come back (DESIGN section 3: preallocated pools from the driver to the
// writer). A driver takes a buffer for every frame it delivers (Acquire), fills it and hands it on
// as Frame::data; when the last holder lets go of it (the recorder's writer once the pixels are on
// disk, the live preview, the pre-trigger ring), the buffer goes back to the pool instead of to the
// heap, so that capture allocates no pixel buffer per frame once the pool holds as many as are in
// flight. The pool keeps at most `keep` idle buffers (what a burst made beyond that is freed), and
// what is in flight is bounded by the daemon's bounded queues, which drop whole sets first.
//
// Thread safety: Acquire() may be called from any thread (the camera's own, normally); buffers come
// back from whichever thread drops the last reference. A buffer that comes back after its pool is
// gone is freed.
#ifndef FLAMERIG_ACQUISITION_FRAME_POOL_H_
#define FLAMERIG_ACQUISITION_FRAME_POOL_H_

#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

namespace flamerig {

class FrameBufferPool {
 public:
  // `preallocate` buffers of `bytes` bytes each made now; at most `keep` (>= preallocate) idle
  // buffers kept.
  FrameBufferPool(std::size_t preallocate, std::size_t bytes, std::size_t keep = 32);
  ~FrameBufferPool();
  FrameBufferPool(const FrameBufferPool&) = delete;
  FrameBufferPool& operator=(const FrameBufferPool&) = delete;

  // Makes idle buffers of `bytes` bytes until `count` are idle (a camera's Start: its buffers).
  void Reserve(std::size_t count, std::size_t bytes);

  // A buffer of exactly `bytes` bytes (its contents are whatever it held last: the caller fills
  // it), shared: it returns to the pool when the last copy of the pointer is gone.
  std::shared_ptr<std::vector<std::uint8_t>> Acquire(std::size_t bytes);

  struct Stats {
    std::uint64_t acquired = 0;   // buffers handed out
    std::uint64_t allocated = 0;  // of those, new or grown buffers (a heap allocation each)
    std::size_t idle = 0;         // buffers in the pool now
  };
  Stats stats() const;

 private:
  struct Shared;
  std::shared_ptr<Shared> shared_;
};

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_FRAME_POOL_H_
