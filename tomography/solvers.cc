#include "tomography/solvers.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "core/error.h"
#include "core/log.h"
#include "tomography/prior.h"
#include "tomography/solver_kernels.h"

namespace flamerig {

const std::vector<TomographySolverEntry>& TomographySolvers() {
  // The registry: add a solver here (and its file to CMakeLists.txt).
  static const std::vector<TomographySolverEntry> solvers = {
      {"osem",
       "OS-EM: multiplicative, non-negative, drives the emission on dark rays to zero (default)",
       &solver_kernels::MakeOsem, 1e-3},
      {"sart", "OS-SART: additive, non-negative at every iterate", &solver_kernels::MakeSart, 5e-3},
      {"cgls", "conjugate gradients on the normal equations, clipped to >= 0 at the end",
       &solver_kernels::MakeCgls, 5e-3},
  };
  return solvers;
}

const TomographySolverEntry& FindTomographySolver(const std::string& name) {
  std::string names;
  for (const auto& s : TomographySolvers()) {
    if (s.name == name) return s;
    names += (names.empty() ? "" : ", ") + s.name;
  }
  throw InputError("solver '" + name + "' is unknown; use one of " + names);
}

const char* ToString(SolveStop stop) {
  switch (stop) {
    case SolveStop::kMaxIterations:
      return "max iterations";
    case SolveStop::kDiscrepancy:
      return "discrepancy principle (residual at the noise level)";
    case SolveStop::kHoldout:
      return "the stop camera's error stopped improving";
    case SolveStop::kStagnation:
      return "residual stagnated";
    case SolveStop::kNoData:
      return "no data (empty system)";
    case SolveStop::kCancelled:
      return "cancelled";
  }
  return "?";
}

void SolveOptions::Validate() const {
  auto fail = [](const std::string& what) { throw InputError("SolveOptions." + what); };
  if (max_iterations < 1 || max_iterations > 100000) fail("max_iterations must be in [1, 100000]");
  if (!(relaxation > 0) || !(relaxation < 2)) fail("relaxation must be in (0, 2)");
  if (!(noise_sigma >= 0) || !std::isfinite(noise_sigma))
    fail("noise_sigma must be finite and >= 0");
  if (!(discrepancy_tau > 0)) fail("discrepancy_tau must be > 0");
  if (!(stagnation_tolerance >= 0) && stagnation_tolerance != -1)
    fail("stagnation_tolerance must be >= 0, or -1 for the solver's own");
  if (holdout_patience < 1) fail("holdout_patience must be >= 1");
  FindTomographySolver(solver);
  PriorKind kind;
  try {
    kind = ParsePriorKind(prior);
  } catch (const InputError& e) {
    fail(e.what());
  }
  if (kind != PriorKind::kNone && solver != "osem")
    fail("prior '" + prior + "' needs solver osem, not " + solver);
  if (!(prior_weight >= 0 && prior_weight <= 10) && prior_weight != -1)
    fail("prior_weight must be in [0, 10], or -1 for the prior's own");
  if (!(prior_edge > 0) || !std::isfinite(prior_edge)) fail("prior_edge must be finite and > 0");
}

std::string SolveSummary::BriefReport() const {
  std::ostringstream s;
  s.precision(4);
  s << solver;
  if (!prior.empty()) s << " with the " << prior << " prior (weight " << prior_weight << ")";
  if (channels == 1) s << ", one channel (grey data)";
  s << ": " << iterations << " iterations, stopped by " << ToString(stop) << ", residual RMS "
    << initial_residual_rms << " -> " << final_residual_rms << " ("
    << (data_rms > 0 ? 100 * final_residual_rms / data_rms : 0)
    << "% of the data RMS), best iterate " << best_iteration;
  if (!holdout_error.empty())
    s << ", stop camera's error "
      << (best_iteration > 0 ? holdout_error[best_iteration - 1] : initial_holdout_error)
      << (best_iteration == 0 ? " (the start was best)" : "");
  if (clipped_fraction > 0) s << ", " << clipped_fraction * 100 << "% of the mass clipped to >= 0";
  s << ", " << time_ms << " ms";
  return s.str();
}

double PriorWeight(const SolveOptions& options) {
  const PriorKind kind = ParsePriorKind(options.prior);
  if (kind == PriorKind::kNone) return 0.0;
  return options.prior_weight >= 0 ? options.prior_weight : DefaultPriorWeight(kind);
}

namespace solver_kernels {

double Residual(const SolveProblem& problem, const std::vector<float>& x, std::vector<float>* ax,
                std::vector<float>* r, bool drop_lower) {
  const SystemMatrix& a = *problem.a;
  const int channels = problem.channels;
  const std::vector<std::uint8_t>& lower = problem.lower_bound_rows;
  a.Multiply(x.data(), ax->data(), channels);
  double sum = 0;
  for (std::size_t i = 0; i < a.rows(); ++i) {
    const bool is_lower = !lower.empty() && lower[i];
    for (int c = 0; c < channels; ++c) {
      const std::size_t k = i * channels + c;
      float v = problem.b[k] - (*ax)[k];
      if (is_lower && (drop_lower || v < 0)) v = 0;
      (*r)[k] = v;
      sum += double(v) * v;
    }
  }
  return a.rows() ? std::sqrt(sum / (a.rows() * channels)) : 0.0;
}

void Pin(const SolveProblem& problem, std::vector<float>* v) {
  const std::vector<std::uint8_t>& active = problem.active_cols;
  const int channels = problem.channels;
  for (std::size_t j = 0; j < active.size(); ++j)
    if (!active[j])
      for (int c = 0; c < channels; ++c) (*v)[j * channels + c] = 0.0f;
}

}  // namespace solver_kernels

SolveSummary SolveTomography(const SolveProblem& problem, std::vector<float>* x,
                             const SolveOptions& options, const HoldoutScorer& holdout,
                             const ProgressCallback& progress) {
  const auto start = std::chrono::steady_clock::now();
  options.Validate();
  if (problem.a == nullptr) throw InputError("SolveTomography: no system matrix");
  const SystemMatrix& a = *problem.a;
  const std::size_t m = a.rows(), n = a.cols();
  if (!problem.active_cols.empty() && problem.active_cols.size() != n)
    throw InputError("SolveTomography: active_cols needs one value per column");
  const int channels = problem.channels;
  if (channels != 1 && channels != 3)
    throw InputError("SolveTomography: channels must be 1 or 3, not " + std::to_string(channels));
  if (problem.b.size() != m * channels)
    throw InputError("SolveTomography: b needs rows * channels values");
  if (!problem.lower_bound_rows.empty() && problem.lower_bound_rows.size() != m)
    throw InputError("SolveTomography: lower_bound_rows needs one value per row");
  if (x->size() != n * channels) x->assign(n * channels, 0.0f);
  for (float& v : *x) {
    if (!std::isfinite(v)) v = 0.0f;  // a broken warm start never poisons the solve
    if (options.non_negative && v < 0) v = 0.0f;
  }
  solver_kernels::Pin(problem, x);
  SolveSummary summary;
  summary.solver = options.solver;
  summary.channels = channels;
  if (const double w = PriorWeight(options); w > 0) {
    summary.prior = options.prior;
    summary.prior_weight = w;
  }
  if (m == 0 || n == 0) {
    summary.stop = SolveStop::kNoData;
    return summary;
  }
  double data_sum = 0;
  for (float v : problem.b) {
    if (!std::isfinite(v)) throw InputError("SolveTomography: the data contain NaN or Inf");
    data_sum += double(v) * v;
  }
  summary.data_rms = std::sqrt(data_sum / problem.b.size());

  const TomographySolverEntry& entry = FindTomographySolver(options.solver);
  std::unique_ptr<IterativeSolver> solver = entry.make(channels);
  const double stagnation =
      options.stagnation_tolerance >= 0 ? options.stagnation_tolerance : entry.stagnation_tolerance;
  const bool sweeps_subsets = solver->SweepsSubsets(problem, options);
  summary.initial_residual_rms = solver->Start(problem, options, x);
  auto as_result = [&](const std::vector<float>& iterate) {
    std::vector<float> r = iterate;
    solver->Result(options, &r);
    return r;
  };
  // The start (a warm start, or the coarse stage's result upsampled) competes too: a fine stage
  // that never beats it on the held-out data gives it back.
  std::vector<float> best = holdout ? as_result(*x) : std::vector<float>();
  double best_holdout = holdout ? holdout(best) : 0.0;
  summary.initial_holdout_error = holdout ? best_holdout : -1.0;
  int since_best = 0;
  for (int it = 1; it <= options.max_iterations; ++it) {
    const double residual = solver->Iterate(problem, options, x);
    const double previous =
        summary.residual_rms.empty() ? summary.initial_residual_rms : summary.residual_rms.back();
    summary.residual_rms.push_back(residual);
    summary.iterations = it;
    if (holdout) {
      std::vector<float> candidate = as_result(*x);
      const double e = holdout(candidate);
      summary.holdout_error.push_back(e);
      if (e < best_holdout) {
        best_holdout = e;
        best = std::move(candidate);
        summary.best_iteration = it;
        since_best = 0;
      } else if (++since_best >= options.holdout_patience) {
        summary.stop = SolveStop::kHoldout;
        break;
      }
    } else {
      summary.best_iteration = it;
    }
    Log().debug("tomography: iteration {}: residual rms {:.6g}{}", it, residual,
                holdout ? ", held-out error " + std::to_string(summary.holdout_error.back()) : "");
    Progress p;
    p.stage = "solve";
    p.unit = "iterations";
    p.done = it;
    p.total = options.max_iterations;
    p.values = {{"residual_rms", residual}};
    if (ReportProgress(progress, p)) {
      summary.stop = SolveStop::kCancelled;
      break;
    }
    if (options.noise_sigma > 0 && residual <= options.discrepancy_tau * options.noise_sigma) {
      summary.stop = SolveStop::kDiscrepancy;
      break;
    }
    if (stagnation > 0 && previous > 0 && !(sweeps_subsets && it == 1) &&
        std::abs(previous - residual) <= stagnation * previous) {
      summary.stop = SolveStop::kStagnation;
      break;
    }
  }
  if (holdout) *x = best;
  summary.clipped_fraction = solver->Result(options, x);
  std::vector<float> ax(m * channels), r(m * channels);
  summary.final_residual_rms = solver_kernels::Residual(problem, *x, &ax, &r, false);
  summary.time_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

}  // namespace flamerig
