// Internal to the tomography's solvers (solvers.h): the solvers' factories, named in the registry
// (solvers.cc), and what more than one of them needs.
#ifndef FLAMERIG_TOMOGRAPHY_SOLVER_KERNELS_H_
#define FLAMERIG_TOMOGRAPHY_SOLVER_KERNELS_H_

#include <memory>
#include <vector>

#include "tomography/solvers.h"

namespace flamerig::solver_kernels {

// r = b - A x (problem.channels interleaved channels) with the lower-bound rule (a saturated row's
// residual counts only where the model is darker; `drop_lower`: not at all); *ax = A x. Returns
// the RMS of r.
double Residual(const SolveProblem& problem, const std::vector<float>& x, std::vector<float>* ax,
                std::vector<float>* r, bool drop_lower);

// Sets the channels of the columns that problem.active_cols pins to zero.
void Pin(const SolveProblem& problem, std::vector<float>* v);

// Each for 1 or 3 interleaved channels (SolveProblem::channels).
std::unique_ptr<IterativeSolver> MakeSart(int channels);  // sart.cc
std::unique_ptr<IterativeSolver> MakeCgls(int channels);  // cgls.cc
std::unique_ptr<IterativeSolver> MakeOsem(int channels);  // osem.cc

}  // namespace flamerig::solver_kernels

#endif  // FLAMERIG_TOMOGRAPHY_SOLVER_KERNELS_H_
