// The Levenberg-Marquardt solver (fitting/levenberg_marquardt.h) on problems whose minima are
// known in closed form: a sparse quadratic (its minimiser A^-1 b), Rosenbrock's valley as least
// squares (its minimum at (1, 1), zero), a model far flatter than the energy (the damping and the
// step limit must still bring it down), and the ways it stops.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <vector>

#include "core/error.h"
#include "fitting/levenberg_marquardt.h"

namespace flamerig {
namespace {

// E = x^T A x / 2 - b^T x with A tridiagonal, diagonally dominant; the model's curvature is A
// itself, scaled by `model_scale` (1: exact).
class Quadratic : public LevenbergMarquardtProblem {
 public:
  Quadratic(int n, double model_scale) : n_(n), model_scale_(model_scale), a_(n, n), b_(n) {
    std::vector<Eigen::Triplet<double>> t;
    for (int i = 0; i < n; ++i) {
      t.emplace_back(i, i, 4.0 + i % 3);
      if (i + 1 < n) {
        t.emplace_back(i + 1, i, -1.0);
        t.emplace_back(i, i + 1, -1.0);
      }
      b_[i] = std::sin(1.0 + i);
    }
    a_.setFromTriplets(t.begin(), t.end());
  }
  int NumParameters() const override { return n_; }
  bool Evaluate(const double* x, double* cost, double* gradient) override {
    ++evaluations;
    const Eigen::Map<const Eigen::VectorXd> v(x, n_);
    const Eigen::VectorXd av = a_ * v;
    *cost = 0.5 * v.dot(av) - b_.dot(v);
    if (gradient) Eigen::Map<Eigen::VectorXd>(gradient, n_) = av - b_;
    return true;
  }
  void Curvature(const double*, Eigen::SparseMatrix<double>* h) override {
    *h = (model_scale_ * a_).triangularView<Eigen::Lower>();
  }
  Eigen::VectorXd Minimiser() const { return Eigen::MatrixXd(a_).ldlt().solve(b_); }
  int evaluations = 0;

 private:
  int n_;
  double model_scale_;
  Eigen::SparseMatrix<double> a_;
  Eigen::VectorXd b_;
};

// Rosenbrock as residuals r = (10 (y - x^2), 1 - x), E = |r|^2 / 2, the model J^T J.
class Rosenbrock : public LevenbergMarquardtProblem {
 public:
  int NumParameters() const override { return 2; }
  bool Evaluate(const double* p, double* cost, double* gradient) override {
    const double x = p[0], y = p[1];
    const double r0 = 10 * (y - x * x), r1 = 1 - x;
    *cost = 0.5 * (r0 * r0 + r1 * r1);
    if (gradient) {
      gradient[0] = r0 * (-20 * x) - r1;
      gradient[1] = r0 * 10;
    }
    return true;
  }
  void Curvature(const double* p, Eigen::SparseMatrix<double>* h) override {
    Eigen::Matrix2d j;
    j << -20 * p[0], 10, -1, 0;
    const Eigen::Matrix2d jtj = j.transpose() * j;
    h->resize(2, 2);
    std::vector<Eigen::Triplet<double>> t = {
        {0, 0, jtj(0, 0)}, {1, 0, jtj(1, 0)}, {1, 1, jtj(1, 1)}};
    h->setFromTriplets(t.begin(), t.end());
  }
};

TEST(LevenbergMarquardt, AQuadraticWithItsExactCurvatureInAFewSteps) {
  Quadratic q(200, 1.0);
  std::vector<double> x(200, 0.0);
  LevenbergMarquardtOptions o;
  o.max_step = 0;  // no limit: the model is exact
  o.stall_decrease = 1e-12;
  const LevenbergMarquardtSummary s = SolveLevenbergMarquardt(q, x.data(), o);
  const Eigen::VectorXd truth = q.Minimiser();
  for (int i = 0; i < 200; ++i) EXPECT_NEAR(x[i], truth[i], 1e-7) << i;
  EXPECT_LE(s.steps_taken, 8) << s.message;
  EXPECT_EQ(s.termination, LevenbergMarquardtTermination::kConverged) << s.message;
  EXPECT_LT(s.final_cost, s.initial_cost);
  EXPECT_EQ(s.evaluations, q.evaluations);
}

TEST(LevenbergMarquardt, RosenbrocksValley) {
  Rosenbrock r;
  double x[2] = {-1.2, 1.0};
  LevenbergMarquardtOptions o;
  o.stall_decrease = 0;  // only the zero gradient or the cap stops it
  o.max_iterations = 200;
  const LevenbergMarquardtSummary s = SolveLevenbergMarquardt(r, x, o);
  EXPECT_NEAR(x[0], 1.0, 1e-6) << s.message;
  EXPECT_NEAR(x[1], 1.0, 1e-6) << s.message;
  EXPECT_LT(s.final_cost, 1e-12);
}

// A model 1e4 times flatter than the energy proposes steps 1e4 times too long: they are refused,
// the damping grows until they fall inside the energy's reach, and the energy still reaches its
// minimum; the step limit keeps every proposal within `max_step`.
TEST(LevenbergMarquardt, AModelFarFlatterThanTheEnergyIsDampedDown) {
  Quadratic q(50, 1e-4);
  std::vector<double> x(50, 0.0);
  LevenbergMarquardtOptions o;
  o.stall_decrease = 1e-10;
  o.max_iterations = 500;
  const LevenbergMarquardtSummary s = SolveLevenbergMarquardt(q, x.data(), o);
  const Eigen::VectorXd truth = q.Minimiser();
  for (int i = 0; i < 50; ++i) EXPECT_NEAR(x[i], truth[i], 1e-4) << i << ": " << s.message;
  EXPECT_GT(s.iterations, s.steps_taken);  // some steps were refused
}

TEST(LevenbergMarquardt, SaysWhyItStopped) {
  Quadratic q(10, 1.0);
  LevenbergMarquardtOptions o;
  // No steps asked for: x as it was.
  o.max_iterations = 0;
  std::vector<double> x(10, 0.5);
  LevenbergMarquardtSummary s = SolveLevenbergMarquardt(q, x.data(), o);
  EXPECT_EQ(s.termination, LevenbergMarquardtTermination::kIterationLimit);
  for (double v : x) EXPECT_EQ(v, 0.5);
  // The callback stops it after the first step taken.
  o.max_iterations = 50;
  int calls = 0;
  s = SolveLevenbergMarquardt(q, x.data(), o, [&](const LevenbergMarquardtIteration& it) {
    ++calls;
    return it.iteration == 0;
  });
  EXPECT_EQ(s.termination, LevenbergMarquardtTermination::kCancelled);
  EXPECT_EQ(calls, 2);
  EXPECT_EQ(s.steps_taken, 1);
  // An energy that is not defined at the start fails, naming it.
  class Undefined : public Quadratic {
   public:
    Undefined() : Quadratic(3, 1.0) {}
    bool Evaluate(const double*, double*, double*) override { return false; }
  } undefined;
  std::vector<double> y(3, 0.0);
  s = SolveLevenbergMarquardt(undefined, y.data(), o);
  EXPECT_EQ(s.termination, LevenbergMarquardtTermination::kFailed);
  EXPECT_NE(s.message.find("not defined"), std::string::npos) << s.message;
  // At the minimum already: the gradient is zero.
  const Eigen::VectorXd m = q.Minimiser();
  std::vector<double> at(m.data(), m.data() + m.size());
  Quadratic exact(10, 1.0);
  // (the minimiser to rounding: a zero gradient or a stall, either is convergence)
  s = SolveLevenbergMarquardt(exact, at.data(), o);
  EXPECT_EQ(s.termination, LevenbergMarquardtTermination::kConverged) << s.message;
  // Bad options are refused, naming the field.
  for (auto change : std::vector<void (*)(LevenbergMarquardtOptions*)>{
           [](LevenbergMarquardtOptions* b) { b->max_iterations = -1; },
           [](LevenbergMarquardtOptions* b) { b->stall_decrease = 1; },
           [](LevenbergMarquardtOptions* b) { b->stall_window = 0; },
           [](LevenbergMarquardtOptions* b) { b->initial_damping = 0; },
           [](LevenbergMarquardtOptions* b) { b->min_relative_diagonal = 0; },
           [](LevenbergMarquardtOptions* b) { b->max_step = std::nan(""); },
           [](LevenbergMarquardtOptions* b) { b->time_limit_s = -1; }}) {
    LevenbergMarquardtOptions bad;
    change(&bad);
    EXPECT_THROW(bad.Validate(), InputError);
  }
}

}  // namespace
}  // namespace flamerig
