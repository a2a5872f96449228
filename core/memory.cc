#include "core/memory.h"

#include <sys/mman.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

namespace flamerig {
namespace {

// A "Name:   1234 kB" line of a process's status file, in bytes; 0 when absent.
std::size_t StatusKilobytes(const char* name, const char* status = "/proc/self/status") {
  std::FILE* f = std::fopen(status, "r");
  if (!f) return 0;
  char line[256];
  std::size_t bytes = 0;
  const std::size_t n = std::strlen(name);
  while (std::fgets(line, sizeof line, f)) {
    if (std::strncmp(line, name, n) == 0 && line[n] == ':') {
      unsigned long long kb = 0;
      if (std::sscanf(line + n + 1, "%llu", &kb) == 1) bytes = static_cast<std::size_t>(kb) * 1024;
      break;
    }
  }
  std::fclose(f);
  return bytes;
}

}  // namespace

std::size_t PeakResidentBytes() {
  if (const std::size_t b = StatusKilobytes("VmHWM")) return b;
  struct rusage u {};
  if (::getrusage(RUSAGE_SELF, &u) == 0) return static_cast<std::size_t>(u.ru_maxrss) * 1024;
  return 0;
}

std::size_t PeakResidentBytesOf(int pid) {
  const std::string status = "/proc/" + std::to_string(pid) + "/status";
  return StatusKilobytes("VmHWM", status.c_str());
}

bool ResetPeakResident() {
  std::FILE* f = std::fopen("/proc/self/clear_refs", "w");
  if (!f) return false;
  const bool ok = std::fputs("5", f) >= 0;
  return std::fclose(f) == 0 && ok;
}

std::size_t ResidentBytes() { return StatusKilobytes("VmRSS"); }

std::size_t PhysicalMemoryBytes() {
  const long pages = ::sysconf(_SC_PHYS_PAGES);
  const long page_size = ::sysconf(_SC_PAGE_SIZE);
  if (pages <= 0 || page_size <= 0) return 0;
  return std::size_t(pages) * std::size_t(page_size);
}

void* AllocateHugePageBacked(std::size_t bytes) {
  constexpr std::size_t kHugePage = std::size_t(2) << 20;
  constexpr std::size_t kCacheLine = 64;
  if (bytes < kHugePage) {
    // A whole number of cache lines (at least one), as aligned_alloc wants.
    const std::size_t lines = std::max<std::size_t>(1, (bytes + kCacheLine - 1) / kCacheLine);
    return std::aligned_alloc(kCacheLine, lines * kCacheLine);
  }
  if (bytes > std::size_t(-1) - kHugePage) return nullptr;
  const std::size_t rounded = (bytes + kHugePage - 1) / kHugePage * kHugePage;
  void* p = std::aligned_alloc(kHugePage, rounded);
  if (!p) return nullptr;
#ifdef MADV_HUGEPAGE
  madvise(p, rounded, MADV_HUGEPAGE);  // advice only: ordinary pages when refused
#endif
  return p;
}

void FreeHugePageBacked(void* p) noexcept { std::free(p); }

}  // namespace flamerig
