// The process's memory as the operating system counts it, for summaries that must report what a
// run really needed (not what its big arrays add up to).
#ifndef FLAMERIG_CORE_MEMORY_H_
#define FLAMERIG_CORE_MEMORY_H_

#include <cstddef>

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

}  // namespace flamerig

#endif  // FLAMERIG_CORE_MEMORY_H_
