// `flamerig reconstruct`: algebraic tomography of one frame set (pipeline/reconstruct_job.h).
#include <cstdio>
#include <memory>

#include "pipeline/reconstruct_job.h"
#include "tools/cli.h"

namespace flamerig::cli {

Runner AddReconstruct(CLI::App* command) {
  auto job = std::make_shared<ReconstructJob>();
  auto holdout = std::make_shared<std::string>();
  auto flags = std::make_shared<TomographyFlags>();
  command->footer(
      "Algebraic tomography of one frame set (DIR/<camera>.png for every rig camera) into an RGB\n"
      "emission volume. The exposure defaults to the one in dataset.yaml beside the rig, else an\n"
      "export's recorded settings over the rig's exposure unit (calibrate-radiometry), else 1.\n"
      "With --truth, report the error against a ground-truth volume's emission.");
  command->add_option("--rig", job->rig_path, "Rig file")->required()->type_name("RIG.yaml");
  command->add_option("--images", job->images_dir, "Folder of one image per camera")
      ->required()
      ->type_name("DIR");
  command->add_option("--out", job->out_path, "Emission volume to write")
      ->required()
      ->type_name("E.vdb");
  command->add_option("--exposure", job->exposure, "Exposure the images were taken with")
      ->type_name("S")
      ->check(ExposureRange());
  command
      ->add_option("--holdout", *holdout,
                   "Camera to leave out and score the result on (it does not stop the solve)")
      ->type_name("CAMERA");
  command
      ->add_option("--stop-camera", job->reconstruct.stop_camera,
                   "Camera to leave out and stop the solve on (its best iterate is kept)")
      ->type_name("CAMERA");
  command
      ->add_option("--masks", job->masks_dir,
                   "Write each camera's fire mask (CAMERA.png) and masks.png into DIR")
      ->type_name("DIR");
  AddTomographyFlags(command, flags.get(), /*solve_options=*/true);
  command->add_option("--truth", job->truth_path, "Ground-truth volume with an emission grid")
      ->type_name("T.vdb");
  command
      ->add_option("--preview", job->preview_path,
                   "Picture: input, reconstruction rendered back, 4x difference per camera")
      ->type_name("P.png");
  command
      ->add_option("--report", job->report_dir,
                   "Report folder: index.html with the summary, the views and the score")
      ->type_name("DIR");
  return [job, holdout, flags](Context& context) {
    context.StopOnSignals();
    ApplyTomographyFlags(*flags, &job->reconstruct, &job->input_transfer);
    job->reconstruct.holdout_camera = *holdout;
    const ReconstructJobResult r = RunReconstructJob(*job, context.Progress());
    for (const auto& note : r.notes) Log().warn("reconstruct: {}", note);
    if (!job->preview_path.empty())
      std::printf("  preview (input, reconstruction rendered back, 4x difference per camera): %s\n",
                  job->preview_path.c_str());
    std::printf("reconstruct: wrote %s (exposure %.6g from %s)\n  %s\n", job->out_path.c_str(),
                r.exposure, r.exposure_source.c_str(), r.summary.BriefReport().c_str());
    if (r.truth_error >= 0)
      std::printf("  volume error against %s: relative L2 %.4f\n", job->truth_path.c_str(),
                  r.truth_error);
    if (!job->masks_dir.empty())
      std::printf("  masks: %s (one PNG per camera, masks.png)\n", job->masks_dir.c_str());
    if (!job->report_dir.empty()) std::printf("  report: %s/index.html\n", job->report_dir.c_str());
    return kExitOk;
  };
}

}  // namespace flamerig::cli
