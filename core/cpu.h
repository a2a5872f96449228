// What the CPU running flamerig can do, for the kernels that have a build for wider vector
// instructions (the renderer's ray march and its adjoint; the tomography's matrix products were
// measured with one and gained nothing: they are bound by the work per column).
//
// Those kernels are compiled twice in one binary: for the baseline x86-64 (SSE2) that Debian's
// packages target, and for AVX2 with FMA (a function with GCC's target attribute into which the
// kernel is inlined whole). UseWideKernels() picks between them at run time, so one build runs
// on any x86-64 machine and at full width on the machines that have it. Setting the environment
// variable FLAMERIG_ISA=baseline forces the baseline build (for benchmarks that compare the two
// in one run, and for tests of the baseline path on a wide machine).
//
// Thread safety: safe to call from any thread; decided once per process.
#ifndef FLAMERIG_CORE_CPU_H_
#define FLAMERIG_CORE_CPU_H_

#include <string>

namespace flamerig {

// True when the CPU has AVX2 and FMA (x86-64 with GCC or Clang) and FLAMERIG_ISA is not
// "baseline".
bool UseWideKernels();

// "AVX2 + FMA" or "baseline (SSE2)", for reports.
std::string KernelIsaName();

}  // namespace flamerig

#endif  // FLAMERIG_CORE_CPU_H_
