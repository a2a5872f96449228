// Solvers for the tomography's A e = b (system_matrix.h), three colour channels at once, or one
// when the data are grey (a mono camera's frames: SolveProblem::channels).
//
// Each solver is one iteration behind one interface (IterativeSolver), found by name in a
// registry (TomographySolvers()); the driver, SolveTomography, owns everything else: validation,
// the warm start, pinned columns, the stopping rules, the held-out camera, cancellation and the
// summary. Adding a solver is a class in its own file and one entry in the registry (README,
// "Extending flamerig").
//
//  - "sart" (simultaneous algebraic reconstruction): e += lambda * C^-1 A^T R^-1 (b - A e), with R
//    and C the row and column sums, then projected onto e >= 0. Robust, non-negative at every
//    iterate. With ordered_subsets (the default) each iteration sweeps the cameras one at a time
//    (OS-SART), which converges about as many times faster per pass as there are cameras; the
//    residual reported for such an iteration is the one accumulated during the sweep.
//  - "cgls" (conjugate gradients on the normal equations): converges faster on well-posed problems;
//    non-negativity is applied to the result only (the amount clipped is reported).
//
//
// A smoothness prior (prior.h: "quadratic" or "tv"), for OS-EM only, turns the solve into a
// maximum a posteriori estimate: it maximises the Poisson log-likelihood of the data minus
// prior_weight * B * U(x), B the sum of the channel's data (the size of the likelihood) and U
// unit-free and independent of the grid's resolution (prior.h), so that one weight suits any
// exposure, image size or grid. It is applied one step late (Green's OSL-EM): each subset's update
// divides by its column sums plus its share of the weighted prior's gradient at the iterate before
// the sweep, the share being the subset's part of the voxel's column sum (so a sweep adds up to
// the full-data step, for a voxel that few cameras see as for one that all see); where the prior
// would move that divisor by more than a tenth of the column sum, the step is instead the minimum
// of the prior's separable quadratic majoriser (De Pierro), which cannot overshoot: the solve
// stays bounded at any weight (osem.cc). Codec noise and blocks then leave
// less ghost emission and grain (BENCHMARKS.md, "Tomography on real footage").
//
// Saturated pixels constrain only from below: their residual counts only where the model is darker
// than the pixel (SART); CGLS, which needs a linear problem, leaves them out.
//
// Stopping rules (the driver's, for every solver; choose by what is available, all optional):
//  - a stop camera: a callback scores each iterate on images the solve did not use; the best
//    iterate, the start included, is kept and the solve stops after `holdout_patience` iterations
//    without improvement (a camera that also reports the result's error would flatter it: the
//    reconstructor scores a held-out camera separately, reconstruct.h);
//  - the discrepancy principle: stop once the RMS residual is below discrepancy_tau * noise_sigma;
//  - stagnation: stop when an iteration improves the RMS residual by less than
//    stagnation_tolerance (from the second iteration on for a solver whose residual is the sweep's:
//    IterativeSolver::SweepsSubsets);
//  - the iteration limit; and a progress callback that asks to stop (SolveStop::kCancelled).
#ifndef FLAMERIG_TOMOGRAPHY_SOLVERS_H_
#define FLAMERIG_TOMOGRAPHY_SOLVERS_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "core/progress.h"
#include "tomography/system_matrix.h"

namespace flamerig {

enum class SolveStop { kMaxIterations, kDiscrepancy, kHoldout, kStagnation, kNoData, kCancelled };
const char* ToString(SolveStop stop);

struct SolveOptions {
  std::string solver = "osem";  // a name in TomographySolvers(): "osem" | "sart" | "cgls"
  int max_iterations = 100;     // [1, 100000]
  double relaxation = 1.5;      // SART lambda, (0, 2); 1.5 reaches a given error in fewer passes
                                // than 1 on our fires (BENCHMARKS.md)
  bool ordered_subsets = true;  // SART: one subset of rows per camera (OS-SART)
  bool non_negative = true;
  double noise_sigma = 0.0;  // per-pixel noise, radiance units; > 0 enables the discrepancy stop
  double discrepancy_tau = 1.0;  // > 0
  // Relative improvement of the residual per iteration below which the solve stops; 0 never;
  // -1 = the solver's own (TomographySolverEntry: osem 1e-3, whose tail improves slowly but
  // steadily; sart and cgls 5e-3).
  double stagnation_tolerance = -1;
  int holdout_patience = 10;   // >= 1
  std::string prior = "none";  // "none" | "quadratic" | "tv" (prior.h); needs solver "osem"
  // The prior's weight (above), [0, 10]; 0 = none; -1 = the prior's own (DefaultPriorWeight: tv
  // 3e-4, quadratic 1e-5, chosen on `benchmark footage` and a noisy Shepp-Logan phantom).
  double prior_weight = -1;
  double prior_edge = 1;  // TV: gradients below this (prior.h's g) are smoothed quadratically; > 0
  void Validate() const;  // throws InputError naming the field (an unknown solver too)
};

struct SolveSummary {
  std::string solver;
  std::string prior;        // "" without one (SolveOptions::prior)
  int channels = 3;         // solved: 3, or 1 for grey data (SolveProblem::channels)
  double prior_weight = 0;  // the weight in effect
  int iterations = 0;
  SolveStop stop = SolveStop::kMaxIterations;
  // Each iteration's RMS residual (radiance units): after it, or for a solver that sweeps
  // subsets of rows (IterativeSolver::SweepsSubsets: OS-EM, OS-SART) accumulated during its sweep,
  // each subset's rows measured before that subset's update. final_residual_rms is the returned
  // iterate's, measured after the solve.
  std::vector<double> residual_rms;
  std::vector<double> holdout_error;  // after each iteration, when a stop camera's scorer was given
  double initial_holdout_error = -1;  // the start's, likewise
  int best_iteration = 0;             // the iterate returned (0: the start)
  double data_rms = 0;                // RMS of b, for relative residuals
  double initial_residual_rms = 0;
  double final_residual_rms = 0;
  double clipped_fraction = 0;  // CGLS: share of the solution's mass removed by clipping to >= 0
  double time_ms = 0;
  std::string BriefReport() const;
};

// Scores an iterate (cols * channels values) on data the solve does not use; lower is better.
using HoldoutScorer = std::function<double(const std::vector<float>& x)>;

// What a solve works on besides A: the data and which rows and columns take part.
struct SolveProblem {
  const SystemMatrix* a = nullptr;
  // Interleaved channels of b and x: 3 (RGB), or 1 for grey data (every channel equal), which
  // then costs a third of the arithmetic and memory of the vectors.
  int channels = 3;
  std::vector<float> b;                        // rows * channels values (radiance)
  std::vector<std::uint8_t> lower_bound_rows;  // optional, per row: saturated pixel
  std::vector<std::uint8_t> active_cols;       // optional, per column: 0 pins the column at zero
  const GridGeometry* grid = nullptr;          // the grid of a's columns; needed by a prior only
};

// One solver's iteration. The driver calls Start once with the cleaned, pinned initial guess, then
// Iterate until a stopping rule holds, then Finish. A solver keeps whatever state it needs
// between calls; it is used for one solve.
class IterativeSolver {
 public:
  virtual ~IterativeSolver() = default;
  // The RMS of the residual b - A x at the start (with the lower-bound rule for saturated rows).
  virtual double Start(const SolveProblem& problem, const SolveOptions& options,
                       std::vector<float>* x) = 0;
  // One iteration: updates *x and returns the RMS residual of the iteration: after it, or, for a
  // solver that sweeps subsets of rows (SweepsSubsets), accumulated during the sweep.
  virtual double Iterate(const SolveProblem& problem, const SolveOptions& options,
                         std::vector<float>* x) = 0;
  // True when Iterate's residual is accumulated during the sweep, each subset's rows measured before
  // that subset's update (OS-EM; OS-SART): the first iteration's figure is then mostly the start's
  // own, so the driver's stagnation test begins at the second iteration. Until 2026-12-03 it began
  // at the first, and a good start (a coarse level's result upsampled, the previous frame) on two
  // cameras stopped after one sweep as "stagnated" while that sweep had halved the residual.
  virtual bool SweepsSubsets(const SolveProblem& problem, const SolveOptions& options) const {
    return false;
  }
  // The iterate as a result (e.g. clipped to >= 0); returns the share of the mass removed.
  virtual double Result(const SolveOptions& options, std::vector<float>* x) const { return 0.0; }
};

struct TomographySolverEntry {
  std::string name;
  std::string description;
  std::unique_ptr<IterativeSolver> (*make)(int channels);  // 1 or 3
  double stagnation_tolerance;  // its default stopping tolerance (SolveOptions)
};
// The weight of options.prior in effect (0 without one): prior_weight, or the prior's own default.
double PriorWeight(const SolveOptions& options);

// Every solver, in the order the CLI lists them.
const std::vector<TomographySolverEntry>& TomographySolvers();
// The entry named `name`; throws InputError listing the names when there is none.
const TomographySolverEntry& FindTomographySolver(const std::string& name);

// Solves for x (cols * channels, interleaved; its input is the initial guess, e.g. a warm start).
// Progress: stage "solve", unit "iterations", value "residual_rms" after each iteration; a cancel
// stops at that iteration with SolveStop::kCancelled (the best iterate so far is returned).
// Throws InputError for mis-sized inputs or non-finite data.
SolveSummary SolveTomography(const SolveProblem& problem, std::vector<float>* x,
                             const SolveOptions& options, const HoldoutScorer& holdout = nullptr,
                             const ProgressCallback& progress = nullptr);

}  // namespace flamerig

#endif  // FLAMERIG_TOMOGRAPHY_SOLVERS_H_
