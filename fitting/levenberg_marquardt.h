// Levenberg-Marquardt for an energy whose exact gradient is cheap (an adjoint) and whose curvature
// a Gauss-Newton model gives (J^T J over the problem's own parameters, plus a prior's): the tied
// fit's solver (fitting/fit.cc, FitOptions::axisymmetric_solver), where a few thousand ring
// parameters stand for tens of thousands of voxels, so that J^T J is small and sparse while J is
// not.
//
// Each iteration solves (H + lambda D) dx = -g by a sparse Cholesky factorisation (Eigen's
// SimplicialLDLT), H the model's curvature at x, g the exact gradient, D the diagonal of H floored
// at min_relative_diagonal of its largest entry (Marquardt's scaling, so that the damping is alike
// in every parameter's own units), clips dx so that no parameter moves by more than max_step (a
// parameter the model barely sees cannot run away), and tries x + dx. The step is taken when the
// energy falls; the gain ratio rho (the fall over the fall the quadratic model predicts) moves
// lambda as Nielsen's rule does (x max(1/3, 1 - (2 rho - 1)^3) on a taken step, x nu then nu x 2
// on a refused one). Because the gradient is exact and a step is taken only when the energy
// falls, the model's curvature may be approximate (a Bayer camera's, an iteratively reweighted
// robust term's): it sets how far and which way to step, not where the minimum is.
//
// It stops (LevenbergMarquardtSummary::termination) when the last `stall_window` steps taken
// lowered the energy by less than `stall_decrease` of its fall since the start (converged; the
// stall rule of FitOptions, over steps taken rather than iterations), when a refused step's
// predicted fall was below 1e-12 of the energy (converged: the minimum to rounding), when the
// gradient is zero, after `max_iterations` steps tried (taken or not), when lambda has grown past
// 1e16 of its start without a step that lowers the energy (failed: the model and the energy
// disagree), at the time limit, or when the callback asks.
#ifndef FLAMERIG_FITTING_LEVENBERG_MARQUARDT_H_
#define FLAMERIG_FITTING_LEVENBERG_MARQUARDT_H_

#include <Eigen/Sparse>
#include <functional>
#include <string>

namespace flamerig {

class LevenbergMarquardtProblem {
 public:
  virtual ~LevenbergMarquardtProblem() = default;
  virtual int NumParameters() const = 0;
  // The energy at x (NumParameters values), and its gradient when `gradient` is not null. False
  // where the energy is not defined: a trial step there is refused (at the start: failed).
  virtual bool Evaluate(const double* x, double* cost, double* gradient) = 0;
  // The model's curvature at x: symmetric positive semi-definite, NumParameters square; only the
  // lower triangle is read (the upper may be left empty).
  virtual void Curvature(const double* x, Eigen::SparseMatrix<double>* h) = 0;
};

struct LevenbergMarquardtOptions {
  int max_iterations = 50;  // steps tried, taken or refused; >= 0
  // The stall rule: the fall over the last `stall_window` steps taken, under stall_decrease of
  // the fall since the start. A window of several steps, since a step taken under heavy damping
  // (after refused ones) can be short while the minimum is still far.
  double stall_decrease = 1e-4;         // [0, 1), 0: no such rule
  int stall_window = 3;                 // steps taken, >= 1
  double initial_damping = 1e-3;        // lambda at the start, in units of D; > 0
  double min_relative_diagonal = 1e-9;  // D's floor, of H's largest diagonal entry; > 0
  // The largest change of any one parameter in a step: a component beyond it is clipped to it
  // (the predicted fall is the clipped step's); 0: no limit.
  double max_step = 2;
  double time_limit_s = 0;  // 0 = none
  void Validate() const;    // throws InputError naming the field
};

enum class LevenbergMarquardtTermination {
  kConverged,       // the stall rule, or a zero gradient (message says which)
  kIterationLimit,  // max_iterations steps tried
  kTimeLimit,
  kCancelled,  // the callback returned false
  kFailed,     // no step lowers the energy (message says why)
};

// What the callback sees after the start (iteration 0) and after every step taken.
struct LevenbergMarquardtIteration {
  int iteration = 0;      // steps tried so far
  double cost = 0;        // the energy at the current point
  double damping = 0;     // lambda for the next step
  double gain_ratio = 0;  // the taken step's rho (0 at the start)
  double seconds = 0;
};
// Returns false to stop (cancelled).
using LevenbergMarquardtCallback = std::function<bool(const LevenbergMarquardtIteration&)>;

struct LevenbergMarquardtSummary {
  int iterations = 0;  // steps tried
  int steps_taken = 0;
  int evaluations = 0;  // Evaluate calls
  int curvatures = 0;   // Curvature calls (one at the start and one after every step taken)
  double initial_cost = 0, final_cost = 0;
  double seconds_in_curvature = 0, seconds_in_factorisation = 0;
  LevenbergMarquardtTermination termination = LevenbergMarquardtTermination::kIterationLimit;
  std::string message;
};

// Minimises the problem's energy from x (NumParameters values), leaving the best point in x.
LevenbergMarquardtSummary SolveLevenbergMarquardt(
    LevenbergMarquardtProblem& problem, double* x, const LevenbergMarquardtOptions& options,
    const LevenbergMarquardtCallback& callback = nullptr);

}  // namespace flamerig

#endif  // FLAMERIG_FITTING_LEVENBERG_MARQUARDT_H_
