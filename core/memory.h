// The process's memory as the operating system counts it, for summaries that must report what a
// run really needed (not what its big arrays add up to).
#ifndef FLAMERIG_CORE_MEMORY_H_
#define FLAMERIG_CORE_MEMORY_H_

#include <cstddef>
#include <new>

namespace flamerig {

// The peak resident set size of this process so far, bytes: VmHWM from /proc/self/status, else
// getrusage's ru_maxrss; 0 when neither is available.
std::size_t PeakResidentBytes();
// The peak resident set size of another running process (VmHWM of /proc/PID/status), bytes; 0
// when unavailable (it has exited, or is not ours to read).
std::size_t PeakResidentBytesOf(int pid);
// Starts the peak over: the next PeakResidentBytes() is the peak since this call (Linux's
// /proc/self/clear_refs); false when the kernel does not allow it.
bool ResetPeakResident();
// The resident set size now (VmRSS), bytes; 0 when unavailable.
std::size_t ResidentBytes();
// This machine's physical memory (sysconf), bytes; 0 when unavailable.
std::size_t PhysicalMemoryBytes();

// Memory for a large array read at random (a voxel grid that rays cross in every direction),
// backed by 2 MiB pages where the kernel allows it: a 128^3 grid of 16-byte records is 34 MB,
// 8,192 pages of 4 KiB, more than a core's TLB holds, so that a ray along z, whose every step
// reads a new slice, missed the TLB at nearly every step. Blocks of at least 2 MiB are aligned
// to 2 MiB and advised MADV_HUGEPAGE before their first use (transparent huge pages in the
// "madvise" mode, Debian's default); smaller blocks, and kernels that refuse, get ordinary pages.
// Smaller blocks are aligned to a cache line (64 bytes), so that loads of 32 bytes at multiples
// of 32 from the start never straddle two lines: malloc puts a block of 128 KiB or more 16 bytes
// past a page, and the renderer's kelvin table there (rows of 96 bytes read 32 at a time) made
// the soot view 8% slower (ratios to the fast path 1.55 to 1.59 against 1.42 to 1.51 aligned, on
// an AMD EPYC, 2026-11-28). Returns nullptr on failure.
void* AllocateHugePageBacked(std::size_t bytes);
void FreeHugePageBacked(void* p) noexcept;

// A std::allocator for AllocateHugePageBacked: std::vector<float, HugePageAllocator<float>>.
template <typename T>
struct HugePageAllocator {
  // Blocks under 2 MiB are aligned to 64 bytes, larger ones to 2 MiB.
  static_assert(alignof(T) <= 64);
  using value_type = T;
  HugePageAllocator() = default;
  template <typename U>
  HugePageAllocator(const HugePageAllocator<U>&) noexcept {}
  T* allocate(std::size_t n) {
    if (n > std::size_t(-1) / sizeof(T)) throw std::bad_array_new_length();
    void* p = AllocateHugePageBacked(n * sizeof(T));
    if (!p) throw std::bad_alloc();
    return static_cast<T*>(p);
  }
  void deallocate(T* p, std::size_t) noexcept { FreeHugePageBacked(p); }
  template <typename U>
  bool operator==(const HugePageAllocator<U>&) const noexcept {
    return true;
  }
};

}  // namespace flamerig

#endif  // FLAMERIG_CORE_MEMORY_H_
