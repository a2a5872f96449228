#include "tools/cli.h"

#include <fmt/format.h>
#include <signal.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <sstream>

#include "core/format.h"
#include "pipeline/tomography_config.h"

namespace flamerig::cli {

namespace {

CancelFlag g_cancel;

void OnSignal(int) { g_cancel.Raise(); }  // lock-free (core/progress.h)

std::string Number(double v) {
  char b[32];
  if (std::abs(v) >= 1e5 || (v != 0 && std::abs(v) < 1e-3))
    std::snprintf(b, sizeof b, "%.3g", v);
  else
    std::snprintf(b, sizeof b, "%.4g", v);
  return b;
}

std::string Duration(double s) {
  char b[32];
  if (s < 120)
    std::snprintf(b, sizeof b, "%.0f s", s);
  else if (s < 7200)
    std::snprintf(b, sizeof b, "%.1f min", s / 60);
  else
    std::snprintf(b, sizeof b, "%.1f h", s / 3600);
  return b;
}

// What one stage's progress says: "frames 3/12 (25%), 4.1 frames/min, 2.2 min left".
std::string Describe(const Progress& p, double elapsed_s) {
  std::ostringstream s;
  s << p.stage << " " << p.done;
  if (p.total > 0) {
    s << "/" << p.total;
    if (!p.unit.empty()) s << " " << p.unit;
    s << " (" << static_cast<int>(100.0 * p.done / p.total) << "%)";
    if (p.done > 0 && elapsed_s > 1 && p.done < p.total)
      s << ", " << Duration(elapsed_s / p.done * (p.total - p.done)) << " left";
  } else if (!p.unit.empty()) {
    s << " " << p.unit;
  }
  for (const auto& [name, value] : p.values) s << ", " << name << " " << Number(value);
  return s.str();
}

class Display {
 public:
  Display(Verbosity verbosity, bool terminal, double period_s)
      : verbosity_(verbosity), terminal_(terminal), period_s_(period_s) {}
  ~Display() { EndBar(); }

  void Show(const Progress& p) {
    if (verbosity_ == Verbosity::kQuiet) return;
    const auto now = std::chrono::steady_clock::now();
    Stage& st = stages_[p.stage];
    if (!st.seen || p.done < st.last_done) {
      st.seen = true;
      st.start = now;
    }
    st.last_done = p.done;
    const double elapsed = std::chrono::duration<double>(now - st.start).count();
    if (!p.message.empty()) {
      EndBar();
      Log().info("{}", p.message);
    }
    const bool finished = p.total > 0 && p.done >= p.total;
    if (terminal_) {
      // Redraw the bar in place, at most ten times a second.
      if (!finished && now - last_draw_ < std::chrono::milliseconds(100)) return;
      last_draw_ = now;
      const int width = 24;
      const int filled =
          p.total > 0 ? static_cast<int>(width * std::min<double>(1, double(p.done) / p.total)) : 0;
      std::string line = "[" + std::string(filled, '#') + std::string(width - filled, '.') + "] " +
                         Describe(p, elapsed);
      if (line.size() > 110) line.resize(110);
      std::fprintf(stderr, "\r%-110s", line.c_str());
      std::fflush(stderr);
      bar_shown_ = true;
      if (finished) EndBar();
      return;
    }
    // Plain lines: a stage's first, one every period, and its last when it ran long enough to
    // have had periodic ones (a stage that restarts, as each frame's fit does, is not repeated).
    const bool first = st.lines == 0;
    const double since = std::chrono::duration<double>(now - st.last_line).count();
    if (first || since >= period_s_ || (finished && elapsed >= period_s_)) {
      st.last_line = now;
      ++st.lines;
      Log().info("{}", Describe(p, elapsed));
    }
  }

 private:
  struct Stage {
    bool seen = false;
    std::int64_t last_done = 0;
    int lines = 0;
    std::chrono::steady_clock::time_point start, last_line;
  };
  void EndBar() {
    if (!bar_shown_) return;
    std::fprintf(stderr, "\r%-110s\r", "");
    std::fflush(stderr);
    bar_shown_ = false;
  }
  Verbosity verbosity_;
  bool terminal_;
  double period_s_;
  bool bar_shown_ = false;
  std::chrono::steady_clock::time_point last_draw_;
  std::map<std::string, Stage> stages_;
};

bool Finite(const std::string& text, double* v) {
  try {
    std::size_t used = 0;
    *v = std::stod(text, &used);
    return used == text.size() && std::isfinite(*v);
  } catch (const std::exception&) {
    return false;
  }
}

}  // namespace

const CLI::Validator kPositive(
    [](std::string& text) -> std::string {
      double v;
      if (!Finite(text, &v) || !(v > 0)) return "'" + text + "' must be a finite number > 0";
      return "";
    },
    "POSITIVE");

const CLI::Validator kNonNegative(
    [](std::string& text) -> std::string {
      double v;
      if (!Finite(text, &v) || !(v >= 0)) return "'" + text + "' must be a finite number >= 0";
      return "";
    },
    "NONNEGATIVE");

CLI::Validator Whole(std::int64_t min, std::int64_t max) {
  return CLI::Validator(
      [min, max](std::string& text) -> std::string {
        double v;
        if (!Finite(text, &v) || v != std::floor(v) || v < double(min) || v > double(max))
          return "'" + text + "' must be a whole number in [" + std::to_string(min) + ", " +
                 std::to_string(max) + "]";
        return "";
      },
      std::to_string(min) + ".." +
          (max >= (std::int64_t(1) << 40) ? "2^" + std::to_string(int(std::log2(max)))
                                          : std::to_string(max)));
}

CLI::Validator Between(double min, double max) {
  const std::string range = "[" + FormatNumber(min) + ", " + FormatNumber(max) + "]";
  return CLI::Validator(
      [min, max, range](std::string& text) -> std::string {
        double v;
        if (!Finite(text, &v) || !(v >= min && v <= max))
          return "'" + text + "' must be a finite number in " + range;
        return "";
      },
      range);
}

CLI::Validator ExposureRange(bool or_auto) {
  const CLI::Validator range = Between(1e-6, 1e6);
  return CLI::Validator(
      [range, or_auto](std::string& text) -> std::string {
        if (or_auto && text == "auto") return "";
        std::string error = range(text);
        return error.empty() || !or_auto ? error : error + ", or auto";
      },
      or_auto ? "[1e-06, 1e+06]|auto" : "[1e-06, 1e+06]");
}

const CLI::Validator kNotAnOption(
    [](std::string& text) -> std::string {
      if (text.rfind("--", 0) == 0) return "needs a value, got the option " + text;
      return "";
    },
    "");

void AddTomographyFlags(CLI::App* command, TomographyFlags* f, bool solve_options) {
  const std::string group = "Tomography";
  command
      ->add_option("--tomography-config", f->config, "Tomography settings (config/tomography.yaml)")
      ->type_name("T.yaml")
      ->group(group);
  command
      ->add_option("--resolution", f->resolution,
                   "Voxels along the box's longest side (default 64, or the tomography config's)")
      ->type_name("N")
      ->check(Whole(1, 1024))
      ->group(group);
  command
      ->add_option("--bin", f->bin,
                   "Average the images over N x N pixel blocks before the tomography (default 1: "
                   "N^2 times fewer rays, less memory and time, for detail finer than a block)")
      ->type_name("N")
      ->check(Whole(1, 16))
      ->group(group);
  command
      ->add_option("--input-transfer", f->input_transfer,
                   "How 8-bit images encode light: srgb, linear (machine-vision raw) or gamma=G")
      ->type_name("T")
      ->group(group);
  command
      ->add_option("--mask-threshold", f->threshold_sigmas,
                   "Fire where brighter than this many noise sigmas (default 5)")
      ->type_name("SIGMAS")
      ->check(kPositive)
      ->group(group);
  command
      ->add_option("--mask-noise", f->noise,
                   "Image noise sigma, radiance units (default: estimated, at least one step)")
      ->type_name("SIGMA")
      ->check(kNonNegative)
      ->group(group);
  command->add_option("--mask-dilation", f->dilation_px, "Extra dilation of fire masks (default 2)")
      ->type_name("PX")
      ->check(Whole(0, 64))
      ->group(group);
  command
      ->add_option("--mask-min-views", f->min_views,
                   "Cameras that must see fire at a voxel (default 2)")
      ->type_name("N")
      ->check(Whole(1, 1000))
      ->group(group);
  command
      ->add_option("--mask-min-speck", f->min_speck_px,
                   "Fire regions of fewer pixels are specks (default -1: half a voxel's image)")
      ->type_name("PX")
      ->check(Whole(-1, 1000000))
      ->group(group);
  if (!solve_options) return;
  std::vector<std::string> solvers;
  for (const auto& s : TomographySolvers()) solvers.push_back(s.name);
  command->add_option("--solver", f->solver, "Tomography solver (default osem)")
      ->check(CLI::IsMember(solvers))
      ->group(group);
  command
      ->add_option(
          "--solve-iterations", f->max_iterations,
          "At most this many solver iterations (default 100; it stops earlier on its own rules)")
      ->type_name("N")
      ->check(Whole(1, 100000))
      ->group(group);
  command
      ->add_option("--stagnation", f->stagnation,
                   "Stop when an iteration improves the residual by less (0 never; default: the "
                   "solver's own, osem 0.001, sart and cgls 0.005)")
      ->type_name("R")
      ->check(kNonNegative & CLI::Range(0.0, 1.0))
      ->group(group);
  command
      ->add_option("--prior", f->prior,
                   "Smoothness prior of the osem solve: none (default), quadratic or tv (total "
                   "variation: smooths codec blocks and noise, keeps edges)")
      ->check(CLI::IsMember({"none", "quadratic", "tv"}))
      ->group(group);
  command
      ->add_option("--prior-weight", f->prior_weight,
                   "The prior's weight, unit-free (default: tv 3e-4, quadratic 1e-5)")
      ->type_name("W")
      ->check(kNonNegative & CLI::Range(0.0, 10.0))
      ->group(group);
  command
      ->add_option("--prior-edge", f->prior_edge,
                   "TV: gradients below this (the mean emission's change across the grid) are "
                   "smoothed quadratically (default 1)")
      ->type_name("E")
      ->check(kPositive)
      ->group(group);
  command
      ->add_flag_callback(
          "--coarse-to-fine", [f] { f->coarse_to_fine = true; },
          "Solve a half-resolution grid first (the default)")
      ->group(group);
  command
      ->add_flag_callback(
          "--no-coarse-to-fine", [f] { f->coarse_to_fine = false; }, "Solve the full grid only")
      ->group(group);
  command->add_option("--cache", f->cache, "Keep system matrices in DIR")
      ->type_name("DIR")
      ->group(group);
}

void ApplyTomographyFlags(const TomographyFlags& f, ReconstructOptions* o,
                          std::string* input_transfer) {
  if (!f.config.empty()) LoadTomographyConfig(f.config, o, input_transfer);
  if (f.input_transfer) *input_transfer = *f.input_transfer;
  if (f.resolution) o->resolution = *f.resolution;
  if (f.bin) o->bin = *f.bin;
  if (f.solver) o->solve.solver = *f.solver;
  if (f.max_iterations) o->solve.max_iterations = *f.max_iterations;
  if (f.stagnation) o->solve.stagnation_tolerance = *f.stagnation;
  if (f.prior) o->solve.prior = *f.prior;
  if (f.prior_weight) o->solve.prior_weight = *f.prior_weight;
  if (f.prior_edge) o->solve.prior_edge = *f.prior_edge;
  if (f.coarse_to_fine) o->coarse_to_fine = *f.coarse_to_fine;
  if (f.cache) o->cache_dir = *f.cache;
  if (f.threshold_sigmas) o->hull.threshold_sigmas = *f.threshold_sigmas;
  if (f.noise) o->hull.noise_sigma = *f.noise;
  if (f.dilation_px) o->hull.dilation_px = *f.dilation_px;
  if (f.min_views) o->hull.min_views = *f.min_views;
  if (f.min_speck_px) o->hull.min_speck_px = *f.min_speck_px;
  // A bad --input-transfer is refused by the job before any work (WithInputTransfer, run's
  // Validate).
}

void AddTieFlags(CLI::App* command, FitOptions* fit, const std::string& what,
                 const std::string& prefix) {
  CLI::Option* axisymmetric = command->add_flag("--axisymmetric", fit->axisymmetric, what);
  command
      ->add_flag("--axisymmetric-interpolate", fit->axisymmetric_interpolate,
                 prefix +
                     ": a field linear in the radius between whole radii (in the fit's "
                     "parameters) instead of constant over each ring (measured, not the default: "
                     "BENCHMARKS.md, \"A tied field linear in the radius\")")
      ->needs(axisymmetric);
}

void AddDirectionFlags(CLI::App* command, DirectionFlags* flags, const FitOptions& defaults) {
  command
      ->add_option(
          "--w-sm-along-y", flags->along_y,
          fmt::format("Factor on the neighbour weight of the pairs along the grid's "
                      "vertical axis, the flame's (default {:g}, with --axisymmetric {:g})",
                      defaults.objective.along_y, defaults.axisymmetric_along_y))
      ->type_name("F")
      ->check(Between(0, ObjectiveOptions::kMaxDirectionFactor));
  command
      ->add_option("--w-sm-across-y", flags->across_y,
                   fmt::format("Factor on the neighbour weight of every other pair (default {:g}, "
                               "with --axisymmetric {:g})",
                               defaults.objective.across_y, defaults.axisymmetric_across_y))
      ->type_name("F")
      ->check(Between(0, ObjectiveOptions::kMaxDirectionFactor));
}

void AddStallFlag(CLI::App* command, double* stall, const FitOptions& defaults) {
  command
      ->add_option("--fit-stall", *stall,
                   fmt::format("Fast fit: stop once the energy falls over {} iterations by less "
                               "than this share, in [0, 0.5], of its fall since the start (default "
                               "{:g}, with --axisymmetric {:g}; 0: no such rule, and only "
                               "--fit-iterations, --time-limit or Ceres' own tolerances stop it)",
                               defaults.stall_window, defaults.stall_decrease,
                               defaults.axisymmetric_stall_decrease))
      ->type_name("F")
      ->check(Between(0, 0.5));
}

void ApplyStallFlag(double stall, FitOptions* fit) {
  if (stall < 0) return;
  fit->stall_decrease = fit->axisymmetric_stall_decrease = fit->axisymmetric_lm_stall_decrease =
      stall;
  if (stall == 0) fit->stall_window = 0;
}

void AddSolverFlag(CLI::App* command, std::string* solver, const FitOptions& defaults) {
  command
      ->add_option(
          "--fit-solver", *solver,
          fmt::format("With --axisymmetric: the tied fit's solver, lbfgs (L-BFGS on the "
                      "voxels, the gradient projected onto the rings) or lm "
                      "(Levenberg-Marquardt on the rings' own parameters, stopped once a "
                      "step lowers the energy by under {:g}% of its fall since the start; "
                      "--fit-stall sets that share too); default {}",
                      100 * defaults.axisymmetric_lm_stall_decrease,
                      defaults.axisymmetric_solver == FitOptions::TiedSolver::kLevenbergMarquardt
                          ? "lm"
                          : "lbfgs"))
      ->type_name("S")
      ->check(CLI::IsMember({"lbfgs", "lm"}));
}

void ApplySolverFlag(const std::string& solver, FitOptions* fit) {
  if (solver.empty()) return;
  if (!fit->axisymmetric)
    throw UsageError("--fit-solver " + solver +
                     ": the solver of a tied fit (--axisymmetric); the untied fit is L-BFGS");
  fit->axisymmetric_solver =
      solver == "lm" ? FitOptions::TiedSolver::kLevenbergMarquardt : FitOptions::TiedSolver::kLbfgs;
}

void ApplyNeighbourFlags(std::optional<double> w_sm, const DirectionFlags& flags, FitOptions* fit) {
  if (w_sm) fit->objective.w_sm = *w_sm;
  if (w_sm && fit->axisymmetric) fit->axisymmetric_w_sm = fit->axisymmetric_lm_w_sm = *w_sm;
  if (flags.along_y) fit->objective.along_y = fit->axisymmetric_along_y = *flags.along_y;
  if (flags.across_y) fit->objective.across_y = fit->axisymmetric_across_y = *flags.across_y;
  const ObjectiveOptions used = fit->axisymmetric ? fit->TiedObjective() : fit->objective;
  const double strongest = used.w_sm * std::max(used.along_y, used.across_y);
  if (!(strongest <= ObjectiveOptions::kMaxWeight))
    throw UsageError(fmt::format(
        "--w-sm {:g} x its factor {:g} (--w-sm-along-y or --w-sm-across-y{}) weighs the "
        "neighbour pairs {:g}, above {:g}",
        used.w_sm, std::max(used.along_y, used.across_y),
        fit->axisymmetric ? ", with --axisymmetric" : "", strongest, ObjectiveOptions::kMaxWeight));
}

void Context::StopOnSignals() {
  struct sigaction action {};
  action.sa_handler = OnSignal;
  action.sa_flags = SA_RESETHAND;  // a second Ctrl-C ends the process at once
  sigemptyset(&action.sa_mask);
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);
  sigaction(SIGHUP, &action, nullptr);
}

void IgnoreWriteSignals() {
  struct sigaction ignore {};
  ignore.sa_handler = SIG_IGN;
  sigemptyset(&ignore.sa_mask);
  sigaction(SIGPIPE, &ignore, nullptr);
  sigaction(SIGXFSZ, &ignore, nullptr);
}

const CancelFlag& Context::cancel() const { return g_cancel; }

ProgressCallback Context::Progress(double period_s) {
  auto display = std::make_shared<Display>(verbosity_, terminal_, period_s);
  return CancelledBy(&g_cancel, [display](const flamerig::Progress& p) {
    display->Show(p);
    return ProgressAction::kContinue;
  });
}

std::vector<std::string> SplitList(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ','))
    if (!item.empty()) out.push_back(item);
  return out;
}

ProcessArgs& Args() {
  static ProcessArgs args;
  return args;
}

}  // namespace flamerig::cli
