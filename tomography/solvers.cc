#include "tomography/solvers.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "core/error.h"

namespace flamerig {

const char* ToString(TomographySolver solver) {
  return solver == TomographySolver::kSart ? "sart" : "cgls";
}

TomographySolver TomographySolverFromName(const std::string& name) {
  if (name == "sart") return TomographySolver::kSart;
  if (name == "cgls") return TomographySolver::kCgls;
  throw InputError("solver '" + name + "' is unknown; use 'sart' or 'cgls'");
}

const char* ToString(SolveStop stop) {
  switch (stop) {
    case SolveStop::kMaxIterations:
      return "max iterations";
    case SolveStop::kDiscrepancy:
      return "discrepancy principle (residual at the noise level)";
    case SolveStop::kHoldout:
      return "held-out camera error stopped improving";
    case SolveStop::kStagnation:
      return "residual stagnated";
    case SolveStop::kNoData:
      return "no data (empty system)";
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
  if (!(stagnation_tolerance >= 0)) fail("stagnation_tolerance must be >= 0");
  if (holdout_patience < 1) fail("holdout_patience must be >= 1");
}

std::string SolveSummary::BriefReport() const {
  std::ostringstream s;
  s.precision(4);
  s << ToString(solver) << ": " << iterations << " iterations, stopped by " << ToString(stop)
    << ", residual RMS " << initial_residual_rms << " -> " << final_residual_rms << " ("
    << (data_rms > 0 ? 100 * final_residual_rms / data_rms : 0)
    << "% of the data RMS), best iterate " << best_iteration;
  if (!holdout_error.empty())
    s << ", held-out error " << holdout_error[std::max(0, best_iteration - 1)];
  if (clipped_fraction > 0) s << ", " << clipped_fraction * 100 << "% of the mass clipped to >= 0";
  s << ", " << time_ms << " ms";
  return s.str();
}

namespace {

constexpr int kChannels = 3;

// r = b - A x with the lower-bound rule; returns the RMS of r.
double Residual(const SystemMatrix& a, const std::vector<float>& b,
                const std::vector<std::uint8_t>& lower, const std::vector<float>& x,
                std::vector<float>* ax, std::vector<float>* r, bool drop_lower) {
  a.Multiply(x.data(), ax->data(), kChannels);
  double sum = 0;
  for (std::size_t i = 0; i < a.rows(); ++i) {
    const bool is_lower = !lower.empty() && lower[i];
    for (int c = 0; c < kChannels; ++c) {
      const std::size_t k = i * kChannels + c;
      float v = b[k] - (*ax)[k];
      if (is_lower && (drop_lower || v < 0)) v = 0;
      (*r)[k] = v;
      sum += double(v) * v;
    }
  }
  return a.rows() ? std::sqrt(sum / (a.rows() * kChannels)) : 0.0;
}

}  // namespace

SolveSummary SolveTomography(const SolveProblem& problem, std::vector<float>* x,
                             const SolveOptions& options, const HoldoutScorer& holdout,
                             const SolveProgress& progress) {
  const auto start = std::chrono::steady_clock::now();
  options.Validate();
  if (problem.a == nullptr) throw InputError("SolveTomography: no system matrix");
  const SystemMatrix& a = *problem.a;
  const std::vector<float>& b = problem.b;
  const std::vector<std::uint8_t>& lower_bound_rows = problem.lower_bound_rows;
  const std::vector<std::uint8_t>& active = problem.active_cols;
  if (!active.empty() && active.size() != a.cols()) {
    throw InputError("SolveTomography: active_cols needs one value per column");
  }
  auto pin = [&](std::vector<float>* v) {
    if (active.empty()) return;
    for (std::size_t j = 0; j < active.size(); ++j)
      if (!active[j])
        for (int c = 0; c < 3; ++c) (*v)[j * 3 + c] = 0.0f;
  };
  const std::size_t m = a.rows(), n = a.cols();
  if (b.size() != m * kChannels)
    throw InputError("SolveTomography: b needs rows * 3 values");
  if (!lower_bound_rows.empty() && lower_bound_rows.size() != m) {
    throw InputError("SolveTomography: lower_bound_rows needs one value per row");
  }
  if (x->size() != n * kChannels) x->assign(n * kChannels, 0.0f);
  for (float& v : *x) {
    if (!std::isfinite(v)) v = 0.0f;  // a broken warm start never poisons the solve
    if (options.non_negative && v < 0) v = 0.0f;
  }
  pin(x);
  SolveSummary summary;
  summary.solver = options.solver;
  if (m == 0 || n == 0) {
    summary.stop = SolveStop::kNoData;
    return summary;
  }
  double data_sum = 0;
  for (float v : b) {
    if (!std::isfinite(v))
      throw InputError("SolveTomography: the data contain NaN or Inf");
    data_sum += double(v) * v;
  }
  summary.data_rms = std::sqrt(data_sum / b.size());

  std::vector<float> ax(m * kChannels), r(m * kChannels), g(n * kChannels);
  const bool cgls = options.solver == TomographySolver::kCgls;
  double residual = Residual(a, b, lower_bound_rows, *x, &ax, &r, cgls);
  summary.initial_residual_rms = residual;
  std::vector<float> best = *x;
  double best_holdout = holdout ? holdout(*x) : 0.0;
  int since_best = 0;
  const auto& row_sums = a.row_sums();
  const auto& col_sums = a.col_sums();

  // CGLS state.
  std::vector<float> p, q;
  double gamma[kChannels] = {0, 0, 0};
  if (cgls) {
    a.MultiplyTransposed(r.data(), g.data(), kChannels);
    pin(&g);
    p = g;
    q.assign(m * kChannels, 0.0f);
    for (std::size_t j = 0; j < n; ++j)
      for (int c = 0; c < kChannels; ++c)
        gamma[c] += double(g[j * kChannels + c]) * g[j * kChannels + c];
  }

  for (int it = 1; it <= options.max_iterations; ++it) {
    const auto& ranges = a.camera_row_ranges();
    if (!cgls && options.ordered_subsets && ranges.size() > 1) {
      // OS-SART: one camera's rows at a time; the residual is accumulated during the sweep.
      const float lambda = static_cast<float>(options.relaxation);
      double sum = 0;
      for (const auto& [first, last] : ranges) {
        a.MultiplyRows(first, last, x->data(), ax.data(), kChannels);
        for (std::size_t i = first; i < last; ++i) {
          const bool is_lower = !lower_bound_rows.empty() && lower_bound_rows[i];
          const float w = row_sums[i] > 0 ? 1.0f / row_sums[i] : 0.0f;
          for (int c = 0; c < kChannels; ++c) {
            const std::size_t k = i * kChannels + c;
            float v = b[k] - ax[k];
            if (is_lower && v < 0) v = 0;
            sum += double(v) * v;
            r[k] = v * w;
          }
        }
        // Backprojection, update, non-negativity and pinning in one pass over the columns.
        float* xs = x->data();
        const bool non_negative = options.non_negative;
        a.BackprojectRows(first, last, r.data(), kChannels,
                          [&](std::size_t j, const float* gj, float col_sum) {
                            if (!(col_sum > 0)) return;
                            if (!active.empty() && !active[j]) {
                              for (int c = 0; c < kChannels; ++c) xs[j * kChannels + c] = 0.0f;
                              return;
                            }
                            const float w = lambda / col_sum;
                            for (int c = 0; c < kChannels; ++c) {
                              const float v = xs[j * kChannels + c] + w * gj[c];
                              xs[j * kChannels + c] = non_negative && v < 0 ? 0.0f : v;
                            }
                          });
      }
      residual = std::sqrt(sum / (m * kChannels));
    } else if (!cgls) {
      for (std::size_t i = 0; i < m; ++i) {
        const float w = row_sums[i] > 0 ? 1.0f / row_sums[i] : 0.0f;
        for (int c = 0; c < kChannels; ++c) r[i * kChannels + c] *= w;
      }
      a.MultiplyTransposed(r.data(), g.data(), kChannels);
      const float lambda = static_cast<float>(options.relaxation);
      for (std::size_t j = 0; j < n; ++j) {
        const float w = col_sums[j] > 0 ? lambda / col_sums[j] : 0.0f;
        for (int c = 0; c < kChannels; ++c) {
          float& v = (*x)[j * kChannels + c];
          v += w * g[j * kChannels + c];
          if (options.non_negative && v < 0) v = 0;
        }
      }
      pin(x);
      residual = Residual(a, b, lower_bound_rows, *x, &ax, &r, false);
    } else {
      pin(&p);
      a.Multiply(p.data(), q.data(), kChannels);
      // Saturated rows are not part of the CGLS problem.
      if (!lower_bound_rows.empty()) {
        for (std::size_t i = 0; i < m; ++i)
          if (lower_bound_rows[i])
            for (int c = 0; c < kChannels; ++c) q[i * kChannels + c] = 0;
      }
      double qq[kChannels] = {0, 0, 0};
      for (std::size_t i = 0; i < m; ++i)
        for (int c = 0; c < kChannels; ++c)
          qq[c] += double(q[i * kChannels + c]) * q[i * kChannels + c];
      float alpha[kChannels];
      for (int c = 0; c < kChannels; ++c)
        alpha[c] = qq[c] > 0 ? static_cast<float>(gamma[c] / qq[c]) : 0.0f;
      for (std::size_t j = 0; j < n; ++j)
        for (int c = 0; c < kChannels; ++c)
          (*x)[j * kChannels + c] += alpha[c] * p[j * kChannels + c];
      double sum = 0;
      for (std::size_t i = 0; i < m; ++i)
        for (int c = 0; c < kChannels; ++c) {
          float& v = r[i * kChannels + c];
          v -= alpha[c] * q[i * kChannels + c];
          sum += double(v) * v;
        }
      residual = std::sqrt(sum / (m * kChannels));
      a.MultiplyTransposed(r.data(), g.data(), kChannels);
      pin(&g);
      double gamma_new[kChannels] = {0, 0, 0};
      for (std::size_t j = 0; j < n; ++j)
        for (int c = 0; c < kChannels; ++c)
          gamma_new[c] += double(g[j * kChannels + c]) * g[j * kChannels + c];
      for (int c = 0; c < kChannels; ++c) {
        const float beta = gamma[c] > 0 ? static_cast<float>(gamma_new[c] / gamma[c]) : 0.0f;
        gamma[c] = gamma_new[c];
        for (std::size_t j = 0; j < n; ++j)
          p[j * kChannels + c] = g[j * kChannels + c] + beta * p[j * kChannels + c];
      }
    }
    const double previous =
        summary.residual_rms.empty() ? summary.initial_residual_rms : summary.residual_rms.back();
    summary.residual_rms.push_back(residual);
    summary.iterations = it;
    if (progress) progress(it, residual);

    if (holdout) {
      std::vector<float> candidate = *x;
      if (cgls && options.non_negative)
        for (float& v : candidate) v = std::max(v, 0.0f);
      const double e = holdout(candidate);
      summary.holdout_error.push_back(e);
      if (e < best_holdout || it == 1) {
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
    if (options.noise_sigma > 0 && residual <= options.discrepancy_tau * options.noise_sigma) {
      summary.stop = SolveStop::kDiscrepancy;
      break;
    }
    if (options.stagnation_tolerance > 0 && previous > 0 &&
        std::abs(previous - residual) <= options.stagnation_tolerance * previous) {
      summary.stop = SolveStop::kStagnation;
      break;
    }
  }
  if (holdout) *x = best;
  if (cgls && options.non_negative) {
    double total = 0, clipped = 0;
    for (float& v : *x) {
      total += std::abs(v);
      if (v < 0) {
        clipped -= v;
        v = 0;
      }
    }
    summary.clipped_fraction = total > 0 ? clipped / total : 0.0;
  }
  summary.final_residual_rms = Residual(a, b, lower_bound_rows, *x, &ax, &r, false);
  summary.time_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

}  // namespace flamerig
