// `flamerig benchmark`: run time against error, written to BENCHMARKS.md (tools/benchmark.h).
#include <cstdio>
#include <filesystem>
#include <memory>

#include "acquisition/netns.h"
#include "core/error.h"
#include "tools/benchmark.h"
#include "tools/cli.h"
#include "tools/soak.h"

namespace flamerig::cli {

Runner AddBenchmark(CLI::App* command) {
  struct Options {
    std::string target, out = "BENCHMARKS.md", figures;
    bool quick = false;
    double seconds = 0, segment_seconds = 300;
  };
  auto o = std::make_shared<Options>();
  command->footer(
      "Time the forward renderer, the tomography (also on compressed footage) or the fit (ours "
      "against the paper's\n"
      "Algorithm 2) against its error, the fit's temperatures from cameras that are not the\n"
      "sRGB observer before and after radiometric calibration, sustained recording from\n"
      "simulated and Aravis fake cameras, the calibration of a simulated ring against\n"
      "mrcal-calibrate-cameras, the daily job, a fire-lit scene, or a capture soak with faults\n"
      "injected, and write the figures to BENCHMARKS.md (--quick: a small smoke run).");
  command->add_option("target", o->target, "What to measure")
      ->required()
      ->check(CLI::IsMember({"render", "tomography", "footage", "fit", "accuracy", "cameras",
                             "capture", "calibration", "run", "scene", "soak"}));
  command->add_option("--out", o->out, "The Markdown file to write the section into")
      ->type_name("BENCHMARKS.md");
  command->add_flag("--quick", o->quick, "A small smoke run");
  command->add_option("--figures", o->figures, "fit: plots into DIR (default benchmarks/)")
      ->type_name("DIR");
  command->add_option("--seconds", o->seconds, "capture, soak: how long")
      ->type_name("S")
      ->check(kPositive);
  command
      ->add_option("--segment-seconds", o->segment_seconds,
                   "soak: a new recording every S seconds (default 300)")
      ->type_name("S")
      ->check(kPositive);
  return [o](Context&) {
    auto log = [](const std::string& line) { Log().info("{}", line); };
    std::string md;
    const std::string& target = o->target;
    if (target == "render") {
      RenderBenchmarkOptions options;
      options.quick = o->quick;
      md = RunRenderBenchmark(options, log);
    } else if (target == "tomography") {
      TomographyBenchmarkOptions options;
      options.quick = o->quick;
      md = RunTomographyBenchmark(options, log);
    } else if (target == "footage") {
      FootageBenchmarkOptions options;
      options.quick = o->quick;
      options.binary = std::filesystem::read_symlink("/proc/self/exe").string();
      md = RunFootageBenchmark(options, log);
    } else if (target == "fit") {
      FitBenchmarkOptions options;
      options.quick = o->quick;
      if (!o->figures.empty()) options.figure_dir = o->figures;
      md = RunFitBenchmark(options, log);
    } else if (target == "capture") {
      CaptureBenchmarkOptions options;
      options.quick = o->quick;
      if (o->seconds > 0) options.seconds = o->seconds;
      // The Aravis scenario needs 127.0.0.2..5: run this command again in a private network
      // namespace.
      std::vector<std::string> again = {std::filesystem::read_symlink("/proc/self/exe").string()};
      for (int i = 1; i < *Args().argc; ++i) again.push_back((*Args().argv)[i]);
      RerunInLoopbackNamespace(again);
      md = RunCaptureBenchmark(options, log);
    } else if (target == "soak") {
      SoakOptions options;
      options.binary = std::filesystem::read_symlink("/proc/self/exe").string();
      options.directory = ".flamerig_soak";
      options.seconds = o->seconds > 0 ? o->seconds : (o->quick ? 10 : 600);
      options.segment_seconds = o->segment_seconds;
      md = RunSoakBenchmark(options, log);
    } else if (target == "accuracy") {
      AccuracyBenchmarkOptions options;
      options.quick = o->quick;
      md = RunAccuracyBenchmark(options, log);
    } else if (target == "cameras") {
      CameraBenchmarkOptions options;
      options.quick = o->quick;
      md = RunCameraBenchmark(options, log);
    } else if (target == "scene") {
      SceneBenchmarkOptions options;
      options.quick = o->quick;
      md = RunSceneBenchmark(options, log);
    } else if (target == "run") {
      RunBenchmarkOptions options;
      options.quick = o->quick;
      md = RunRunBenchmark(options, log);
    } else {
      CalibrationBenchmarkOptions options;
      options.quick = o->quick;
      md = RunCalibrationBenchmark(options, log);
    }
    WriteBenchmarkSection(o->out, target, md);
    std::printf("%s\nwritten to %s\n", md.c_str(), o->out.c_str());
    return kExitOk;
  };
}

}  // namespace flamerig::cli
