#include "acquisition/frame_pool.h"

#include <algorithm>
#include <mutex>

namespace flamerig {

// What the pool and its buffers' deleters share: the deleters hold it, so a buffer that outlives
// its pool still finds somewhere to go (and is freed there).
struct FrameBufferPool::Shared {
  std::mutex mutex;
  std::vector<std::unique_ptr<std::vector<std::uint8_t>>> idle;
  std::size_t keep = 0;
  bool open = true;
  std::uint64_t acquired = 0, allocated = 0;
};

FrameBufferPool::FrameBufferPool(std::size_t preallocate, std::size_t bytes, std::size_t keep)
    : shared_(std::make_shared<Shared>()) {
  shared_->keep = std::max(keep, preallocate);
  for (std::size_t i = 0; i < preallocate; ++i)
    shared_->idle.push_back(std::make_unique<std::vector<std::uint8_t>>(bytes));
}

FrameBufferPool::~FrameBufferPool() {
  std::lock_guard<std::mutex> lock(shared_->mutex);
  shared_->open = false;
  shared_->idle.clear();
}

void FrameBufferPool::Reserve(std::size_t count, std::size_t bytes) {
  std::lock_guard<std::mutex> lock(shared_->mutex);
  shared_->keep = std::max(shared_->keep, count);
  for (auto& b : shared_->idle)
    if (b->capacity() < bytes) b->reserve(bytes);
  while (shared_->idle.size() < count)
    shared_->idle.push_back(std::make_unique<std::vector<std::uint8_t>>(bytes));
}

std::shared_ptr<std::vector<std::uint8_t>> FrameBufferPool::Acquire(std::size_t bytes) {
  std::unique_ptr<std::vector<std::uint8_t>> buffer;
  bool fresh = false;
  {
    std::lock_guard<std::mutex> lock(shared_->mutex);
    ++shared_->acquired;
    // The idle buffer that needs no growing, if any (the last one first: the warmest in cache).
    for (std::size_t i = shared_->idle.size(); i-- > 0;) {
      if (shared_->idle[i]->capacity() >= bytes) {
        buffer = std::move(shared_->idle[i]);
        shared_->idle.erase(shared_->idle.begin() + static_cast<std::ptrdiff_t>(i));
        break;
      }
    }
    if (!buffer) {
      fresh = true;
      ++shared_->allocated;
    }
  }
  if (fresh) buffer = std::make_unique<std::vector<std::uint8_t>>();
  buffer->resize(bytes);  // within its capacity: no allocation for a pooled buffer
  std::shared_ptr<Shared> home = shared_;
  return std::shared_ptr<std::vector<std::uint8_t>>(
      buffer.release(), [home = std::move(home)](std::vector<std::uint8_t>* b) {
        std::unique_ptr<std::vector<std::uint8_t>> owned(b);
        std::lock_guard<std::mutex> lock(home->mutex);
        if (home->open && home->idle.size() < home->keep) home->idle.push_back(std::move(owned));
      });
}

FrameBufferPool::Stats FrameBufferPool::stats() const {
  std::lock_guard<std::mutex> lock(shared_->mutex);
  Stats s;
  s.acquired = shared_->acquired;
  s.allocated = shared_->allocated;
  s.idle = shared_->idle.size();
  return s;
}

}  // namespace flamerig
