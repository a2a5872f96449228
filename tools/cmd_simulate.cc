// `flamerig simulate`: a synthetic dataset (pipeline/simulate.h).
#include <cstdio>
#include <memory>

#include "pipeline/simulate.h"
#include "tools/cli.h"

namespace flamerig::cli {

Runner AddSimulate(CLI::App* command) {
  struct Options {
    std::string config, out;
  };
  auto o = std::make_shared<Options>();
  command->footer(
      "Write a synthetic dataset (rig, camera models, fire images, calibration board images,\n"
      "ground-truth .vdb) from a simulation config such as config/sim_rig.yaml.");
  command->add_option("--config", o->config, "Simulation config (YAML)")
      ->required()
      ->type_name("FILE");
  command->add_option("--out", o->out, "Output folder")->required()->type_name("DIR");
  return [o](Context& context) {
    context.StopOnSignals();
    const SimulateConfig config = SimulateConfig::Load(o->config);
    const SimulateSummary s = Simulate(config, o->out, context.Progress());
    std::printf("simulate: wrote %s\n", o->out.c_str());
    std::printf(
        "  %d camera(s), %d frame(s) of a %s fire, grid %d along the longest axis, %s absorption\n",
        s.cameras, s.frames, synthetic::ToString(config.fire.kind), config.grid_resolution,
        config.absorption.c_str());
    std::printf("  exposure %.6g (%s); %.2f%% of fire pixels saturated at frame 0\n", s.exposure,
                s.exposure_source.c_str(), 100 * s.saturated_pixel_fraction);
    std::printf("  calibration: %d board views, %d images\n", s.calibration_views,
                s.calibration_images);
    if (s.radiometric_shots > 0)
      std::printf(
          "  radiometric calibration: %d images of a black body, %s/radiometry/shots.yaml\n",
          s.radiometric_shots, o->out.c_str());
    if (config.pixel_samples > 1)
      std::printf("  last render (one of the %d rays a pixel, %d x %d): %s\n",
                  config.pixel_samples * config.pixel_samples, config.pixel_samples,
                  config.pixel_samples, s.last_render.BriefReport().c_str());
    else
      std::printf("  last render: %s\n", s.last_render.BriefReport().c_str());
    std::printf("  preview: %s/preview.png; %.2f s in all\n", o->out.c_str(), s.time_s);
    return kExitOk;
  };
}

}  // namespace flamerig::cli
