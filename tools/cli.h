// What every subcommand of `flamerig` shares: the command table's entry type, the context a
// command runs in (its log, its progress display, Ctrl-C), option validators, and exit statuses.
//
// A command is one file, tools/cmd_<name>.cc, with one function that declares its options on a
// CLI11 subcommand, bound to an options struct, and returns the code that runs it. The table of
// commands is in tools/main.cc. Options are declared once: `flamerig CMD --help` is made from them
// and a test checks the README's synopsis against it.
//
// Exit statuses: 0 done; 1 an error (bad input, a damaged file, a refused write, failed frames);
// 2 a command line that does not parse (usage); 130 stopped by Ctrl-C (SIGINT) or SIGTERM.
#ifndef FLAMERIG_TOOLS_CLI_H_
#define FLAMERIG_TOOLS_CLI_H_

#include <CLI/CLI.hpp>

#include <chrono>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "core/log.h"
#include "core/progress.h"
#include "fitting/fit.h"
#include "tomography/reconstruct.h"

namespace flamerig::cli {

constexpr int kExitOk = 0;
constexpr int kExitError = 1;
constexpr int kExitUsage = 2;
constexpr int kExitCancelled = 130;

// The run of one command.
class Context {
 public:
  Context(Verbosity verbosity, bool terminal) : verbosity_(verbosity), terminal_(terminal) {}

  // Ctrl-C (SIGINT), SIGTERM and SIGHUP (the terminal or the SSH session that started it gone)
  // raise cancel(): the command stops at its next safe point, so a recording is closed. A second
  // one ends the process at once.
  void StopOnSignals();
  const CancelFlag& cancel() const;

  // A progress callback that shows progress and answers kCancel once cancel() is raised. On a
  // terminal: a bar redrawn in place ("\r"), and each message as a log line above it. Otherwise
  // (a log file, a pipe): plain timestamped log lines: a stage's first, then at most one every
  // `period_s` seconds and its last when it ran that long (a stage that restarts, as each frame's
  // fit does, is not repeated), and every message. --quiet shows none of it.
  ProgressCallback Progress(double period_s = 10.0);

  Verbosity verbosity() const { return verbosity_; }
  bool terminal() const { return terminal_; }

 private:
  Verbosity verbosity_;
  bool terminal_;
};

// Declares a subcommand's options and returns the code that runs it; the code returns the exit
// status. Called once, before parsing.
using Runner = std::function<int(Context&)>;
struct Command {
  const char* name;
  const char* summary;
  Runner (*add)(CLI::App* command);
};

// Validators that CLI11 lacks: a finite number > 0 (CLI11's PositiveNumber lets NaN through), a
// finite number >= 0, and a whole number of frames.
extern const CLI::Validator kPositive;
extern const CLI::Validator kNonNegative;
// A whole number in [min, max] ("2.5", "nan" and "1e30" are refused, naming the range).
CLI::Validator Whole(std::int64_t min, std::int64_t max);
// A finite number in [min, max] ("nan" and "1e300" are refused, naming the range).
CLI::Validator Between(double min, double max);
// A known exposure (--exposure): a finite number in [1e-6, 1e6], wide enough for any camera's
// and narrow enough that the rendering's arithmetic stays finite; or, with `or_auto`, "auto".
CLI::Validator ExposureRange(bool or_auto = false);
// Put on every option that takes a value: a value that is itself an option ("--out --resolution")
// is a forgotten value, not a file named "--resolution".
extern const CLI::Validator kNotAnOption;

// The tomography's options, shared by reconstruct, fit and run: --tomography-config T.yaml
// (pipeline/tomography_config.h), then each option given on the command line over it.
struct TomographyFlags {
  std::string config;
  std::optional<std::string> input_transfer, solver, cache, prior;
  std::optional<int> resolution, max_iterations, dilation_px, min_views, min_speck_px, bin;
  std::optional<double> threshold_sigmas, noise, stagnation, prior_weight, prior_edge;
  std::optional<bool> coarse_to_fine;
};
// Declares --tomography, --resolution, --bin, --input-transfer and the --mask-* options; with
// `solve_options` also --solver, --solve-iterations, --stagnation, --prior, --prior-weight,
// --prior-edge, --coarse-to-fine / --no-coarse-to-fine and --cache.
void AddTomographyFlags(CLI::App* command, TomographyFlags* flags, bool solve_options);
// Loads the config into *options and *input_transfer (when one was given), then the options given
// over it. Throws InputError naming the config file and key (a bad input transfer is the job's to
// refuse).
void ApplyTomographyFlags(const TomographyFlags& flags, ReconstructOptions* options,
                          std::string* input_transfer);

// The tied fit's flags, shared by fit and run: --axisymmetric (FitOptions::axisymmetric, its help
// `what` as the command says it) and --axisymmetric-interpolate, which needs it; `prefix` starts
// the latter's help ("Fast fit, with --axisymmetric" in `fit`, whose other methods do not tie).
void AddTieFlags(CLI::App* command, FitOptions* fit, const std::string& what,
                 const std::string& prefix);

// The fit's neighbour term by direction, shared by fit and run: --w-sm-along-y F and
// --w-sm-across-y F (ObjectiveOptions::along_y, across_y: the factors on the weight of the
// neighbour pairs along the grid's vertical axis and of every other pair). A factor given is the
// fit's, tied to rings or not, as --w-sm's weight is; a factor not given keeps each fit's default
// (untied 1 and 1, the paper's term; tied FitOptions::axisymmetric_along_y and _across_y).
struct DirectionFlags {
  std::optional<double> along_y, across_y;
};
// `defaults` are the options the help describes.
void AddDirectionFlags(CLI::App* command, DirectionFlags* flags, const FitOptions& defaults);
// Applies --w-sm's weight (`w_sm`, unset when not given) and the factors to the fit that runs:
// the untied fit's objective, and with fit->axisymmetric the tied fit's weight too (an untied
// fit's weight leaves the tied one alone; until 2026-12-03 it set it, and a weight above 2.5e10
// was refused with the tied fit's message). Throws UsageError naming the flags when the fit that
// runs would weigh its pairs above ObjectiveOptions::kMaxWeight (the weight x either factor).
void ApplyNeighbourFlags(std::optional<double> w_sm, const DirectionFlags& flags, FitOptions* fit);

// The fast fit's stop rule, shared by fit and run: --fit-stall F (FitOptions::stall_decrease and
// axisymmetric_stall_decrease, the share of the energy's fall since the start under which a fall
// over the last stall_window iterations stops the fit; a share given is the fit's, tied or not;
// 0: no such rule, only the iteration cap, the time limit and Ceres' own tolerances stop it).
// Unset (negative) keeps each fit's default. Under the untied fit's 0.5% the tied fit stopped
// while its faint rings still cooled and its soot still grew, hence its own 0.1%; run on past
// about 150 iterations its temperatures got worse and only its soot gained (BENCHMARKS.md, "When
// the tied fit stops"). A user who wants the soot sets it to 0 with a cap (--fit-iterations).
void AddStallFlag(CLI::App* command, double* stall, const FitOptions& defaults);
void ApplyStallFlag(double stall, FitOptions* fit);

// The tied fit's solver, shared by fit and run: --fit-solver lbfgs|lm
// (FitOptions::axisymmetric_solver; lm: Levenberg-Marquardt on the rings' nodes). Empty keeps the
// default. Given without --axisymmetric it is a usage error: the untied fit is L-BFGS always.
void AddSolverFlag(CLI::App* command, std::string* solver, const FitOptions& defaults);
void ApplySolverFlag(const std::string& solver, FitOptions* fit);

// "a,b,,c" -> {"a", "b", "c"}.
std::vector<std::string> SplitList(const std::string& text);

// SIGPIPE (stderr piped into a `tee` or `head` that has ended) and SIGXFSZ (`ulimit -f` reached)
// are ignored, for every command, from main(): their writes fail with EPIPE and EFBIG instead,
// which the log skips and the recorder reports and closes on. Either signal ended a capture
// mid-take with its recording open and its queued frame sets lost (until 2026-12-02).
void IgnoreWriteSignals();

// Frame indices and counts go up to 2^48.
constexpr std::int64_t kMaxFrames = std::int64_t(1) << 48;

// The commands, each in tools/cmd_<name>.cc.
Runner AddSimulate(CLI::App* command);
Runner AddRender(CLI::App* command);
Runner AddReconstruct(CLI::App* command);
Runner AddFit(CLI::App* command);
Runner AddRun(CLI::App* command);
Runner AddCapture(CLI::App* command);
Runner AddCtl(CLI::App* command);
Runner AddCameras(CLI::App* command);
Runner AddCalibrate(CLI::App* command);
Runner AddCalibrateRadiometry(CLI::App* command);
Runner AddExport(CLI::App* command);
Runner AddRecover(CLI::App* command);
Runner AddExportVolume(CLI::App* command);
Runner AddBenchmark(CLI::App* command);

// The process's arguments, for commands that run themselves again (in a network namespace) or
// hand the command line to another process (MPI).
struct ProcessArgs {
  int* argc = nullptr;
  char*** argv = nullptr;
};
ProcessArgs& Args();

}  // namespace flamerig::cli

#endif  // FLAMERIG_TOOLS_CLI_H_
