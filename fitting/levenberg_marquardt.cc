#include "fitting/levenberg_marquardt.h"

#include <Eigen/SparseCholesky>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>
#include <vector>

#include "core/error.h"

namespace flamerig {

namespace {
using Clock = std::chrono::steady_clock;
double Since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}
}  // namespace

void LevenbergMarquardtOptions::Validate() const {
  auto fail = [](const std::string& what) {
    throw InputError("Levenberg-Marquardt options: " + what);
  };
  if (max_iterations < 0) fail("max_iterations must be >= 0");
  if (!(stall_decrease >= 0 && stall_decrease < 1)) fail("stall_decrease must be in [0, 1)");
  if (!(initial_damping > 0) || !std::isfinite(initial_damping))
    fail("initial_damping must be finite and > 0");
  if (!(min_relative_diagonal > 0) || !(min_relative_diagonal < 1))
    fail("min_relative_diagonal must be in (0, 1)");
  if (stall_window < 1) fail("stall_window must be >= 1");
  if (!(max_step >= 0) || !std::isfinite(max_step)) fail("max_step must be finite and >= 0");
  if (!(time_limit_s >= 0)) fail("time_limit_s must be >= 0");
}

LevenbergMarquardtSummary SolveLevenbergMarquardt(LevenbergMarquardtProblem& problem, double* x,
                                                  const LevenbergMarquardtOptions& options,
                                                  const LevenbergMarquardtCallback& callback) {
  options.Validate();
  const auto start = Clock::now();
  const int np = problem.NumParameters();
  LevenbergMarquardtSummary summary;
  Eigen::Map<Eigen::VectorXd> xv(x, np);
  Eigen::VectorXd g(np), trial(np), trial_g(np);
  double cost = 0;
  ++summary.evaluations;
  if (!problem.Evaluate(x, &cost, g.data()) || !std::isfinite(cost) || !g.allFinite()) {
    summary.termination = LevenbergMarquardtTermination::kFailed;
    summary.message = "the energy is not defined at the start";
    return summary;
  }
  summary.initial_cost = summary.final_cost = cost;
  Eigen::SparseMatrix<double> h;
  auto curvature = [&]() {
    const auto t0 = Clock::now();
    h.resize(0, 0);
    problem.Curvature(x, &h);
    ++summary.curvatures;
    summary.seconds_in_curvature += Since(t0);
  };
  LevenbergMarquardtIteration it;
  it.damping = options.initial_damping;
  it.cost = cost;
  if (callback && !callback(it)) {
    summary.termination = LevenbergMarquardtTermination::kCancelled;
    summary.message = "the callback asked to stop";
    return summary;
  }
  if (g.lpNorm<Eigen::Infinity>() == 0) {
    summary.termination = LevenbergMarquardtTermination::kConverged;
    summary.message = "the gradient is zero at the start";
    return summary;
  }
  curvature();
  double lambda = options.initial_damping, nu = 2;
  std::vector<double> taken_costs = {cost};  // the energy after each step taken, from the start
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>, Eigen::Lower> solver;
  bool analysed = false;
  while (true) {
    if (summary.iterations >= options.max_iterations) {
      summary.termination = LevenbergMarquardtTermination::kIterationLimit;
      summary.message = std::to_string(options.max_iterations) + " steps tried";
      break;
    }
    if (options.time_limit_s > 0 && Since(start) > options.time_limit_s) {
      summary.termination = LevenbergMarquardtTermination::kTimeLimit;
      summary.message = "time limit of " + std::to_string(options.time_limit_s) + " s reached";
      break;
    }
    if (lambda > 1e16 * options.initial_damping) {
      summary.termination = LevenbergMarquardtTermination::kFailed;
      summary.message =
          "no step lowers the energy: the damping grew past 1e16 of its start (the model and the "
          "energy disagree, or the energy is flat to rounding here)";
      break;
    }
    ++summary.iterations;
    // D: H's diagonal, floored.
    Eigen::VectorXd d = h.diagonal();
    const double floor = options.min_relative_diagonal * std::max(d.maxCoeff(), 1e-300);
    for (int i = 0; i < np; ++i) d[i] = std::max(d[i], floor);
    Eigen::SparseMatrix<double> damped = h;
    for (int i = 0; i < np; ++i) damped.coeffRef(i, i) += lambda * d[i];
    const auto t0 = Clock::now();
    if (!analysed) {
      solver.analyzePattern(damped);
      analysed = true;
    }
    solver.factorize(damped);
    if (solver.info() != Eigen::Success) {  // the pattern changed, or not positive definite
      solver.analyzePattern(damped);
      solver.factorize(damped);
    }
    summary.seconds_in_factorisation += Since(t0);
    if (solver.info() != Eigen::Success) {
      lambda *= nu;
      nu *= 2;
      continue;
    }
    Eigen::VectorXd step = solver.solve(-g);
    // No parameter moves by more than max_step: a direction the model barely sees (a faint
    // node's, whose curvature is small beside the others') would otherwise take a step that
    // leaves the model's reach, and be refused again and again at growing damping.
    if (options.max_step > 0) step = step.cwiseMax(-options.max_step).cwiseMin(options.max_step);
    // The model's predicted fall: -(g.dx + dx^T H dx / 2).
    const double predicted =
        -(g.dot(step) + 0.5 * step.dot(h.selfadjointView<Eigen::Lower>() * step));
    if (!step.allFinite() || !(predicted > 0)) {
      lambda *= nu;
      nu *= 2;
      continue;
    }
    trial = xv + step;
    double trial_cost = 0;
    ++summary.evaluations;
    const bool defined = problem.Evaluate(trial.data(), &trial_cost, trial_g.data()) &&
                         std::isfinite(trial_cost) && trial_g.allFinite();
    if (!defined || !(trial_cost < cost)) {
      // A refused step whose predicted fall is at the energy's rounding: the minimum.
      if (defined && predicted <= 1e-12 * std::abs(cost)) {
        summary.termination = LevenbergMarquardtTermination::kConverged;
        summary.message =
            "the model's predicted fall is below 1e-12 of the energy: the minimum "
            "to rounding";
        break;
      }
      lambda *= nu;
      nu *= 2;
      continue;
    }
    const double fall = cost - trial_cost;
    const double rho = fall / predicted;
    lambda *= std::max(1.0 / 3.0, 1.0 - std::pow(2.0 * rho - 1.0, 3));
    nu = 2;
    xv = trial;
    g = trial_g;
    cost = trial_cost;
    ++summary.steps_taken;
    summary.final_cost = cost;
    it.iteration = summary.iterations;
    it.cost = cost;
    it.damping = lambda;
    it.gain_ratio = rho;
    it.seconds = Since(start);
    if (callback && !callback(it)) {
      summary.termination = LevenbergMarquardtTermination::kCancelled;
      summary.message = "the callback asked to stop";
      break;
    }
    taken_costs.push_back(cost);
    const double since_start = summary.initial_cost - cost;
    const int window = options.stall_window;
    const double recent = taken_costs.size() > std::size_t(window)
                              ? taken_costs[taken_costs.size() - 1 - window] - cost
                              : std::numeric_limits<double>::infinity();
    if (options.stall_decrease > 0 && recent < options.stall_decrease * since_start) {
      std::ostringstream m;
      m << "the last " << window << " steps taken lowered the energy by "
        << 100 * recent / since_start << "% of its fall since the start (stall "
        << 100 * options.stall_decrease << "%)";
      summary.termination = LevenbergMarquardtTermination::kConverged;
      summary.message = m.str();
      break;
    }
    if (g.lpNorm<Eigen::Infinity>() == 0) {
      summary.termination = LevenbergMarquardtTermination::kConverged;
      summary.message = "the gradient is zero";
      break;
    }
    curvature();
  }
  summary.final_cost = cost;
  return summary;
}

}  // namespace flamerig
