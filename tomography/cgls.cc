// CGLS (solvers.h): conjugate gradients on the normal equations, per channel; saturated rows are
// left out (a linear problem); non-negativity applied to the result only.
#include <algorithm>
#include <cmath>
#include <string>

#include "core/error.h"
#include "tomography/solver_kernels.h"

namespace flamerig::solver_kernels {
namespace {

template <int kChannels>
class Cgls : public IterativeSolver {
 public:
  double Start(const SolveProblem& problem, const SolveOptions& options,
               std::vector<float>* x) override {
    const SystemMatrix& a = *problem.a;
    const std::size_t m = a.rows(), n = a.cols();
    ax_.assign(m * kChannels, 0.0f);
    r_.assign(m * kChannels, 0.0f);
    g_.assign(n * kChannels, 0.0f);
    const double residual = Residual(problem, *x, &ax_, &r_, true);
    a.MultiplyTransposed(r_.data(), g_.data(), kChannels);
    Pin(problem, &g_);
    p_ = g_;
    q_.assign(m * kChannels, 0.0f);
    for (int c = 0; c < kChannels; ++c) gamma_[c] = 0;
    for (std::size_t j = 0; j < n; ++j)
      for (int c = 0; c < kChannels; ++c)
        gamma_[c] += double(g_[j * kChannels + c]) * g_[j * kChannels + c];
    return residual;
  }

  double Iterate(const SolveProblem& problem, const SolveOptions& options,
                 std::vector<float>* x) override {
    const SystemMatrix& a = *problem.a;
    const std::size_t m = a.rows(), n = a.cols();
    Pin(problem, &p_);
    a.Multiply(p_.data(), q_.data(), kChannels);
    // Saturated rows are not part of the CGLS problem.
    if (!problem.lower_bound_rows.empty()) {
      for (std::size_t i = 0; i < m; ++i)
        if (problem.lower_bound_rows[i])
          for (int c = 0; c < kChannels; ++c) q_[i * kChannels + c] = 0;
    }
    double qq[kChannels] = {};
    for (std::size_t i = 0; i < m; ++i)
      for (int c = 0; c < kChannels; ++c)
        qq[c] += double(q_[i * kChannels + c]) * q_[i * kChannels + c];
    float alpha[kChannels];
    for (int c = 0; c < kChannels; ++c)
      alpha[c] = qq[c] > 0 ? static_cast<float>(gamma_[c] / qq[c]) : 0.0f;
    for (std::size_t j = 0; j < n; ++j)
      for (int c = 0; c < kChannels; ++c) (*x)[j * kChannels + c] += alpha[c] * p_[j * kChannels + c];
    double sum = 0;
    for (std::size_t i = 0; i < m; ++i)
      for (int c = 0; c < kChannels; ++c) {
        float& v = r_[i * kChannels + c];
        v -= alpha[c] * q_[i * kChannels + c];
        sum += double(v) * v;
      }
    a.MultiplyTransposed(r_.data(), g_.data(), kChannels);
    Pin(problem, &g_);
    double gamma_new[kChannels] = {};
    for (std::size_t j = 0; j < n; ++j)
      for (int c = 0; c < kChannels; ++c)
        gamma_new[c] += double(g_[j * kChannels + c]) * g_[j * kChannels + c];
    for (int c = 0; c < kChannels; ++c) {
      const float beta = gamma_[c] > 0 ? static_cast<float>(gamma_new[c] / gamma_[c]) : 0.0f;
      gamma_[c] = gamma_new[c];
      for (std::size_t j = 0; j < n; ++j)
        p_[j * kChannels + c] = g_[j * kChannels + c] + beta * p_[j * kChannels + c];
    }
    return std::sqrt(sum / (m * kChannels));
  }

  // The held-out camera and the result see the iterate clipped to >= 0.
  double Result(const SolveOptions& options, std::vector<float>* x) const override {
    if (!options.non_negative) return 0.0;
    double total = 0, clipped = 0;
    for (float& v : *x) {
      total += std::abs(v);
      if (v < 0) {
        clipped -= v;
        v = 0;
      }
    }
    return total > 0 ? clipped / total : 0.0;
  }

 private:
  std::vector<float> ax_, r_, g_, p_, q_;
  double gamma_[kChannels] = {};
};

}  // namespace

std::unique_ptr<IterativeSolver> MakeCgls(int channels) {
  if (channels == 1) return std::make_unique<Cgls<1>>();
  if (channels == 3) return std::make_unique<Cgls<3>>();
  throw InputError("cgls: 1 or 3 channels, not " + std::to_string(channels));
}

}  // namespace flamerig::solver_kernels
