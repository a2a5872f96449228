#include "core/cpu.h"

#include <cstdlib>
#include <string>

namespace flamerig {

bool UseWideKernels() {
#if defined(__x86_64__) && defined(__GNUC__)
  static const bool wide = [] {
    const char* isa = std::getenv("FLAMERIG_ISA");
    if (isa && std::string(isa) == "baseline") return false;
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  }();
  return wide;
#else
  return false;
#endif
}

std::string KernelIsaName() { return UseWideKernels() ? "AVX2 + FMA" : "baseline (SSE2)"; }

}  // namespace flamerig
