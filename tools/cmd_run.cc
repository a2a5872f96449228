// `flamerig run`: every frame set of a recording through tomography and the fit
// (pipeline/run.h), over MPI ranks when started by mpirun (pipeline/distributed.h).
#include <fmt/format.h>
#include <cstdio>
#include <memory>

#include "core/error.h"
#include "fitting/objective.h"
#include "pipeline/distributed.h"
#include "tools/cli.h"

namespace flamerig::cli {

Runner AddRun(CLI::App* command) {
  struct Options {
    RunOptions run;
    std::string seq, names, calibrate_config, board;
    std::int64_t first = -1, count = -1;
    int fit_iterations = -1;
    double w_sm = -1, fit_stall = -1;
    std::string fit_solver;  // --fit-solver
    bool no_skip_unchanged = false, no_blender = false, cold = false, no_sigma = false;
    std::size_t threads = 0;
    TomographyFlags tomography;
    DirectionFlags directions;
  };
  auto o = std::make_shared<Options>();
  RunOptions& run = o->run;
  AddTomographyFlags(command, &o->tomography, /*solve_options=*/false);
  command->footer(
      "The daily job: every frame set of a recording through tomography and the fit (warm\n"
      "started from the previous frame) into OUT/frame_NNNNNN.vdb, a Blender-ready sequence in\n"
      "OUT/blender/, a summary line per frame and OUT/report/index.html. A damaged frame fails\n"
      "alone; the exit status is then 1. Stopped runs (Ctrl-C, a kill) resume at the first frame\n"
      "without a complete output. Under `mpirun -n N` the frames are split into contiguous runs\n"
      "per rank. --truth: ground-truth volumes of a simulated recording. --axisymmetric: each\n"
      "frame's radial profile in OUT/frames/frame_NNNNNN_profile.csv.");
  command->add_option("--recording", run.source.recording_dir, "A flamerig recording")
      ->type_name("DIR");
  command->add_option("--seq", o->seq, "StreamPix sequences, one per camera")
      ->type_name("A.seq,B.seq");
  command->add_option("--names", o->names, "Camera names of the sequences (default: file stems)")
      ->type_name("CAM,CAM");
  command->add_option("--images", run.source.images_dir, "Folders DIR/frame_NNNNNN/<camera>.png")
      ->type_name("DIR");
  CLI::Option* rig = command->add_option("--rig", run.rig_path, "Rig file")->type_name("RIG.yaml");
  command
      ->add_option("--calibration-recording", run.calibration.recording_dir,
                   "Calibrate first from this recording of a board (instead of --rig; an "
                   "OUT/calibrated/rig.yaml already there is used as it is)")
      ->type_name("DIR")
      ->excludes(rig);
  command
      ->add_option("--calibration-images", run.calibration.images_dir,
                   "Calibrate first from these board views (instead of --rig; likewise)")
      ->type_name("DIR")
      ->excludes(rig);
  command->add_option("--board", o->board, "The calibration board")->type_name("B.yaml");
  command->add_option("--calibrate-config", o->calibrate_config, "Calibration config")
      ->type_name("C.yaml");
  command->add_option("--out", run.out_dir, "Output folder")->required()->type_name("OUT");
  command->add_option("--first", o->first, "First frame set")
      ->type_name("N")
      ->check(Whole(0, kMaxFrames));
  command->add_option("--count", o->count, "How many frame sets")
      ->type_name("N")
      ->check(Whole(1, kMaxFrames));
  command->add_option("--exposure", run.exposure, "Exposure the images were taken with")
      ->type_name("S")
      ->check(ExposureRange());
  command->add_option("--absorption", run.absorption, "Absorption model (default: dataset.yaml's)")
      ->check(CLI::IsMember({"soot", "grey"}));
  const FitOptions defaults = run.fit;  // the help states the defaults it describes
  command
      ->add_option("--fit-iterations", o->fit_iterations,
                   fmt::format("Cap on the L-BFGS iterations of each frame's fit (it stops "
                               "earlier once its energy falls over {} iterations by less than "
                               "{:g}% of its fall since the start, {:g}% with --axisymmetric: "
                               "--fit-stall)",
                               defaults.stall_window, 100 * defaults.stall_decrease,
                               100 * defaults.axisymmetric_stall_decrease))
      ->type_name("N")
      ->check(Whole(0, 1000000));
  AddStallFlag(command, &o->fit_stall, defaults);
  AddSolverFlag(command, &o->fit_solver, defaults);
  command
      ->add_option(
          "--w-sm", o->w_sm,
          fmt::format("Weight of the fit's neighbour term (default {:g}, with "
                      "--axisymmetric {:g} and with --fit-solver lm {:g}, its pairs along the "
                      "axis x {:g} and across x {:g}) "
                      "at {} voxels, x ({} / resolution)^2 on other grids; each frame's volume "
                      "records the weight applied (metadata w_sm)",
                      defaults.objective.w_sm, defaults.axisymmetric_w_sm,
                      defaults.axisymmetric_lm_w_sm, defaults.axisymmetric_along_y,
                      defaults.axisymmetric_across_y, defaults.neighbour_weight_resolution,
                      defaults.neighbour_weight_resolution))
      ->type_name("W")
      ->check(Between(0, ObjectiveOptions::kMaxWeight));
  AddDirectionFlags(command, &o->directions, defaults);
  command->add_option("--holdout", run.holdout_camera, "Camera to score but not fit")
      ->type_name("CAMERA");
  command
      ->add_option("--stop-camera", run.reconstruct.stop_camera,
                   "Camera the tomography leaves out and stops its solve on (its best iterate is "
                   "kept; the fit still uses the camera)")
      ->type_name("CAMERA");
  CLI::Option* truth =
      command->add_option("--truth", run.truth_dir, "Ground-truth volumes DIR/frame_NNNNNN.vdb")
          ->type_name("DIR");
  command
      ->add_option("--truth-rig", run.truth_rig,
                   "The rig the truth was simulated in (its dataset's rig.yaml), when --rig is a "
                   "calibration: the truth is moved into --rig's frame before it is scored")
      ->type_name("RIG")
      ->needs(truth);
  command->add_flag("--no-skip-unchanged", o->no_skip_unchanged,
                    "Compute frames whose images did not change too");
  command->add_flag("--no-blender", o->no_blender, "Do not write OUT/blender/");
  command->add_flag("--cold", o->cold,
                    "Start every frame from its own images alone: a cold tomography, the fit from "
                    "it");
  command->add_flag(
      "--no-sigma", o->no_sigma,
      "Do not write the per-voxel sigma grids (saves about 50 ms a frame at 64^3, two views)");
  AddTieFlags(command, &run.fit,
              "Fit one temperature and density per ring about the flame's vertical axis (an "
              "axisymmetric flame, as Abel inversion assumes; every frame then starts from its own "
              "tomography)",
              "With --axisymmetric");
  command->add_flag("--fit-exposure", run.fit_exposure,
                    "Fit a free exposure on every frame (the paper's s), even a known one");
  command
      ->add_option("--threads", o->threads,
                   "Threads per process (default: all cores, shared among a node's ranks)")
      ->type_name("N")
      ->check(Whole(1, 4096));
  return [o](Context& context) {
    RunOptions run = o->run;
    // Mistakes of the command line itself are usage errors (status 2), found before any work.
    if (int(!run.source.recording_dir.empty()) + int(!o->seq.empty()) +
            int(!run.source.images_dir.empty()) !=
        1)
      throw UsageError("give one frame source: --images, --recording or --seq");
    if (run.rig_path.empty() && run.calibration.images_dir.empty() &&
        run.calibration.recording_dir.empty())
      throw UsageError(
          "give a rig (--rig), or a calibration to make one (--calibration-images or "
          "--calibration-recording)");
    ApplyTomographyFlags(o->tomography, &run.reconstruct, &run.input_transfer);
    run.source.seq_files = SplitList(o->seq);
    run.source.seq_names = SplitList(o->names);
    if (!o->calibrate_config.empty()) run.calibrate = CalibrateConfig::Load(o->calibrate_config);
    if (!o->board.empty()) run.calibrate.board = LoadBoardSpec(o->board);
    if (o->first >= 0) run.first = static_cast<std::size_t>(o->first);
    if (o->count >= 0) run.count = static_cast<std::size_t>(o->count);
    if (o->fit_iterations >= 0) run.fit.iterations_finest = o->fit_iterations;
    ApplyStallFlag(o->fit_stall, &run.fit);
    ApplySolverFlag(o->fit_solver, &run.fit);
    // A weight given is the fit's, tied to rings or not (ApplyNeighbourFlags, as in `fit`).
    ApplyNeighbourFlags(o->w_sm >= 0 ? std::optional<double>(o->w_sm) : std::nullopt, o->directions,
                        &run.fit);
    run.skip_unchanged = !o->no_skip_unchanged;
    run.blender = !o->no_blender;
    run.sigma = !o->no_sigma;
    run.warm_start = !o->cold;
    // Under mpirun every rank runs this; a failing rank stops the others.
    std::unique_ptr<MpiSession> mpi;
    try {
      mpi = std::make_unique<MpiSession>(Args().argc, Args().argv);
      run.Validate();
      context.StopOnSignals();
      DistributedOptions distributed;
      distributed.threads = o->threads;
      // Under mpirun: rank 0 shows progress, every rank's frame lines carry its rank.
      ProgressCallback progress = context.Progress();
      if (mpi->size() > 1) {
        const std::string who = "[rank " + std::to_string(mpi->rank()) + "] ";
        const bool show = mpi->rank() == 0;
        progress = [progress, who, show, &context](const Progress& p) {
          Progress q = p;
          if (!q.message.empty()) q.message = who + q.message;
          if (show || !q.message.empty()) return progress(q);
          return context.cancel().raised() ? ProgressAction::kCancel : ProgressAction::kContinue;
        };
      }
      const DistributedRun r = RunDistributed(run, distributed, *mpi, progress);
      std::printf("%srun: %s\n",
                  mpi->size() > 1 ? ("[rank " + std::to_string(mpi->rank()) + "] ").c_str() : "",
                  r.mine.BriefReport().c_str());
      std::fflush(stdout);
      if (mpi->rank() != 0) return r.cancelled ? kExitCancelled : kExitOk;
      std::printf("run: report %s\n", r.report.c_str());
      if (r.cancelled) {
        Log().warn("flamerig run: stopped; run the same command again to go on");
        return kExitCancelled;
      }
      if (r.failed) {
        // The other frames are written; a script must still see that this run is not complete.
        Log().error("flamerig run: {} of {} frame(s) failed (their lines above, OUT/frames)",
                    r.failed, r.frames.size());
        return kExitError;
      }
      return kExitOk;
    } catch (const std::exception& e) {
      if (mpi && mpi->size() > 1) {
        // A failing (or stopped) rank stops the others, which would wait at the next barrier.
        const bool usage = dynamic_cast<const UsageError*>(&e) != nullptr;
        const bool cancelled = dynamic_cast<const Cancelled*>(&e) != nullptr;
        Log().error("flamerig run: {}: {}", cancelled ? "stopped" : "error", e.what());
        mpi->Abort(cancelled ? kExitCancelled : usage ? kExitUsage : kExitError);
      }
      throw;
    }
  };
}

}  // namespace flamerig::cli
