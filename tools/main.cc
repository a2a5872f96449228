// flamerig: one binary, subcommands. `flamerig --help` lists them, `flamerig CMD --help` gives a
// command's options; tools/cli.h says how a command is written.
#include <CLI/CLI.hpp>

#include <cstdio>
#include <cstring>
#include <map>
#include <string>
#include <vector>

#include "core/error.h"
#include "core/log.h"
#include "flamerig_version.h"
#include "tools/cli.h"

using namespace flamerig;

namespace {

// The command table: every subcommand, in the order `flamerig --help` lists them.
const std::vector<cli::Command>& Commands() {
  static const std::vector<cli::Command> commands = {
      {"simulate", "Write a synthetic dataset: rig, fire images, board images, ground truth",
       &cli::AddSimulate},
      {"render", "Render a volume through a rig's cameras, or fires lighting a scene",
       &cli::AddRender},
      {"reconstruct", "Algebraic tomography of one frame set into an emission volume",
       &cli::AddReconstruct},
      {"fit", "Fit temperature, density and exposure to one frame set", &cli::AddFit},
      {"run", "Every frame set of a recording through tomography and the fit", &cli::AddRun},
      {"capture", "Run the capture daemon on a rig of cameras", &cli::AddCapture},
      {"ctl", "Talk to a running capture daemon", &cli::AddCtl},
      {"cameras", "List the cameras each driver can see", &cli::AddCameras},
      {"calibrate", "Calibrate the rig from views of a board (mrcal)", &cli::AddCalibrate},
      {"calibrate-radiometry", "Calibrate the cameras' gains from images of a black body",
       &cli::AddCalibrateRadiometry},
      {"export", "Write a recording's frame sets as PNG images", &cli::AddExport},
      {"recover", "Rebuild a damaged or interrupted recording's indexes from its data files",
       &cli::AddRecover},
      {"export-volume", "Write a volume as a table: CSV, NumPy or HDF5, coordinates in metres",
       &cli::AddExportVolume},
      {"benchmark", "Measure run time against error; write BENCHMARKS.md", &cli::AddBenchmark},
  };
  return commands;
}

}  // namespace

int main(int argc, char** argv) {
  cli::Args() = {&argc, &argv};
  cli::IgnoreWriteSignals();
  CLI::App app("flamerig: fire reconstruction from a calibrated multi-camera rig", "flamerig");
  app.set_version_flag("--version", FLAMERIG_VERSION);
  app.require_subcommand(0, 1);
  app.fallthrough();  // --quiet and --verbose after the command too
  bool quiet = false, verbose = false;
  app.add_flag("-q,--quiet", quiet, "Show warnings and errors only (no progress)");
  app.add_flag("-v,--verbose", verbose, "Show debug lines too");
  app.footer(
      "Errors name the file, the field and the rule. Exit status: 0 done, 1 an error, 2 a usage "
      "error, 130 stopped by Ctrl-C.");
  std::map<CLI::App*, cli::Runner> runners;
  for (const cli::Command& c : Commands()) {
    CLI::App* sub = app.add_subcommand(c.name, c.summary);
    runners[sub] = c.add(sub);
    for (CLI::Option* option : sub->get_options())
      if (option->get_items_expected_min() > 0 && option->nonpositional())
        option->check(cli::kNotAnOption);
  }
  // `flamerig help [CMD]` is `flamerig [CMD] --help`.
  std::vector<std::string> args(argv + 1, argv + argc);
  if (!args.empty() && args[0] == "help") {
    args.erase(args.begin());
    if (args.size() > 1) args.resize(1);
    args.push_back("--help");
  }
  if (!args.empty() && args[0].rfind("-", 0) != 0) {
    bool known = false;
    for (const cli::Command& c : Commands()) known = known || args[0] == c.name;
    if (!known) {
      std::fprintf(stderr, "flamerig: unknown command '%s'\n\n%s", args[0].c_str(),
                   app.help().c_str());
      return cli::kExitUsage;
    }
  }
  std::vector<std::string> reversed(args.rbegin(), args.rend());  // CLI11 takes them reversed
  try {
    app.parse(reversed);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);  // prints the help, the version, or the error
    return code == 0 ? cli::kExitOk : cli::kExitUsage;
  }
  std::vector<CLI::App*> chosen = app.get_subcommands();
  if (chosen.empty()) {
    std::fputs(app.help().c_str(), stderr);
    return cli::kExitUsage;
  }
  CLI::App* command = chosen.front();
  const Verbosity verbosity =
      quiet ? Verbosity::kQuiet : (verbose ? Verbosity::kVerbose : Verbosity::kNormal);
  LogOptions log;
  log.verbosity = verbosity;
  ConfigureLog(log);
  cli::Context context(verbosity, StderrIsTerminal());
  const std::string name = command->get_name();
  try {
    return runners.at(command)(context);
  } catch (const UsageError& e) {
    // As CLI11's own parse errors: a plain line, no timestamp (README, "Usage errors").
    std::fprintf(stderr, "flamerig %s: %s (see flamerig %s --help)\n", name.c_str(), e.what(),
                 name.c_str());
    return cli::kExitUsage;
  } catch (const Cancelled& e) {
    Log().warn("flamerig {}: stopped: {}", name, e.what());
    return cli::kExitCancelled;
  } catch (const std::exception& e) {
    Log().error("flamerig {}: error: {}", name, e.what());
    return cli::kExitError;
  }
}
