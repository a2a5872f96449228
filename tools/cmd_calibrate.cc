// `flamerig calibrate`: the rig from views of a board (pipeline/calibrate_job.h).
#include <cstdio>
#include <memory>

#include "core/error.h"
#include "pipeline/calibrate_job.h"
#include "tools/cli.h"

namespace flamerig::cli {

Runner AddCalibrate(CLI::App* command) {
  struct Options {
    std::string images, recording, out, config, board;
  };
  auto o = std::make_shared<Options>();
  command->footer(
      "Calibrate the rig from views of a board (DIR/<view>/<camera>.png, as `simulate` writes\n"
      "calibration/ and `export` writes frame sets, or a recording): board detection (cached),\n"
      "one joint mrcal solve, the rig (OUT/rig.yaml + cameras/*.cameramodel), and a report\n"
      "(OUT/report.md with coverage and rig pictures). Config: config/calibrate_sim.yaml.");
  command->add_option("--images", o->images, "Board views DIR/<view>/<camera>.png")
      ->type_name("DIR");
  command->add_option("--recording", o->recording, "A recording of the board")->type_name("DIR");
  command->add_option("--out", o->out, "Output folder")->required()->type_name("DIR");
  command->add_option("--config", o->config, "Calibration config")->type_name("C.yaml");
  command
      ->add_option("--board", o->board,
                   "The board (default: the config's, or board.yaml "
                   "beside the images)")
      ->type_name("B.yaml");
  return [o](Context& context) {
    if (o->images.empty() == o->recording.empty())
      throw UsageError("give the board views: --images or --recording (one of them)");
    context.StopOnSignals();
    CalibrateConfig config;
    if (!o->config.empty()) config = CalibrateConfig::Load(o->config);
    if (!o->board.empty()) config.board = LoadBoardSpec(o->board);
    const CalibrationSummary s =
        RunCalibration(config, CalibrateInput{o->images, o->recording}, o->out, context.Progress());
    std::fprintf(stderr, "%s", s.BriefReport().c_str());
    for (const auto& note : s.notes)
      if (note.rfind("WARNING: ", 0) == 0) Log().warn("calibrate: {}", note.substr(9));
    Log().info("calibrate: wrote {}/rig.yaml, {}/report.md", o->out, o->out);
    return kExitOk;
  };
}

}  // namespace flamerig::cli
