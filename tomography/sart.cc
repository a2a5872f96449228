// SART and OS-SART (solvers.h): e += lambda * C^-1 A^T R^-1 (b - A e), projected onto e >= 0.
#include <cmath>
#include <string>

#include "core/error.h"
#include "tomography/solver_kernels.h"

namespace flamerig::solver_kernels {
namespace {

template <int kChannels>
class Sart : public IterativeSolver {
 public:
  double Start(const SolveProblem& problem, const SolveOptions& options,
               std::vector<float>* x) override {
    const SystemMatrix& a = *problem.a;
    ax_.assign(a.rows() * kChannels, 0.0f);
    r_.assign(a.rows() * kChannels, 0.0f);
    g_.assign(a.cols() * kChannels, 0.0f);
    return Residual(problem, *x, &ax_, &r_, false);
  }

  bool SweepsSubsets(const SolveProblem& problem, const SolveOptions& options) const override {
    return options.ordered_subsets && problem.a->camera_row_ranges().size() > 1;
  }

  double Iterate(const SolveProblem& problem, const SolveOptions& options,
                 std::vector<float>* x) override {
    const SystemMatrix& a = *problem.a;
    const auto& ranges = a.camera_row_ranges();
    if (options.ordered_subsets && ranges.size() > 1) return OrderedSubsets(problem, options, x);
    // Plain SART: the residual of the last iterate is in r_.
    const auto& row_sums = a.row_sums();
    const auto& col_sums = a.col_sums();
    const std::size_t m = a.rows(), n = a.cols();
    for (std::size_t i = 0; i < m; ++i) {
      const float w = row_sums[i] > 0 ? 1.0f / row_sums[i] : 0.0f;
      for (int c = 0; c < kChannels; ++c) r_[i * kChannels + c] *= w;
    }
    a.MultiplyTransposed(r_.data(), g_.data(), kChannels);
    const float lambda = static_cast<float>(options.relaxation);
    for (std::size_t j = 0; j < n; ++j) {
      const float w = col_sums[j] > 0 ? lambda / col_sums[j] : 0.0f;
      for (int c = 0; c < kChannels; ++c) {
        float& v = (*x)[j * kChannels + c];
        v += w * g_[j * kChannels + c];
        if (options.non_negative && v < 0) v = 0;
      }
    }
    Pin(problem, x);
    return Residual(problem, *x, &ax_, &r_, false);
  }

 private:
  // OS-SART: one camera's rows at a time; the residual is accumulated during the sweep.
  double OrderedSubsets(const SolveProblem& problem, const SolveOptions& options,
                        std::vector<float>* x) {
    const SystemMatrix& a = *problem.a;
    const auto& row_sums = a.row_sums();
    const std::vector<float>& b = problem.b;
    const std::vector<std::uint8_t>& lower = problem.lower_bound_rows;
    const std::vector<std::uint8_t>& active = problem.active_cols;
    const float lambda = static_cast<float>(options.relaxation);
    double sum = 0;
    for (const auto& [first, last] : a.camera_row_ranges()) {
      a.MultiplyRows(first, last, x->data(), ax_.data(), kChannels);
      for (std::size_t i = first; i < last; ++i) {
        const bool is_lower = !lower.empty() && lower[i];
        const float w = row_sums[i] > 0 ? 1.0f / row_sums[i] : 0.0f;
        for (int c = 0; c < kChannels; ++c) {
          const std::size_t k = i * kChannels + c;
          float v = b[k] - ax_[k];
          if (is_lower && v < 0) v = 0;
          sum += double(v) * v;
          r_[k] = v * w;
        }
      }
      // Backprojection, update, non-negativity and pinning in one pass over the columns.
      float* xs = x->data();
      const bool non_negative = options.non_negative;
      a.BackprojectRows(
          first, last, r_.data(), kChannels,
          [&](std::size_t j, const float* gj, float col_sum) {
            if (!(col_sum > 0)) return;
            const float w = lambda / col_sum;
            for (int c = 0; c < kChannels; ++c) {
              const float v = xs[j * kChannels + c] + w * gj[c];
              xs[j * kChannels + c] = non_negative && v < 0 ? 0.0f : v;
            }
          },
          // Columns outside the hull stay at zero (Pin): their work is skipped.
          active.empty() ? nullptr : active.data());
    }
    return std::sqrt(sum / (a.rows() * kChannels));
  }

  std::vector<float> ax_, r_, g_;
};

}  // namespace

std::unique_ptr<IterativeSolver> MakeSart(int channels) {
  if (channels == 1) return std::make_unique<Sart<1>>();
  if (channels == 3) return std::make_unique<Sart<3>>();
  throw InputError("sart: 1 or 3 channels, not " + std::to_string(channels));
}

}  // namespace flamerig::solver_kernels
