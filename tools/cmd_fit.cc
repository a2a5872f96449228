// `flamerig fit`: temperature, density and exposure from one frame set (pipeline/fit_job.h).
#include <fmt/format.h>
#include <algorithm>
#include <cstdio>
#include <memory>
#include <vector>

#include "core/error.h"
#include "fitting/objective.h"
#include "pipeline/fit_job.h"
#include "tools/cli.h"

namespace flamerig::cli {

Runner AddFit(CLI::App* command) {
  struct Options {
    FitJob job;
    std::string views, method = "fast";
    int iterations = -1;
    double stall = -1;
    std::string solver;  // --fit-solver
    std::int64_t seed = -1;
    TomographyFlags tomography;
    DirectionFlags directions;
  };
  auto o = std::make_shared<Options>();
  FitJob& job = o->job;
  AddTomographyFlags(command, &o->tomography, /*solve_options=*/false);
  command->footer(
      "Fit temperature, density and exposure so that rendering reproduces the images: the fast\n"
      "fit (default) or the paper's Algorithm 1 or 2. The tomography is reconstructed from the\n"
      "fitted views unless given. Writes F.vdb (temperature, density; exposure and why the fit\n"
      "stopped in its metadata) and a report (input, rendered and Delta E images per view and\n"
      "held-out view, error against time). Ctrl-C during the fit stops it and writes what it has\n"
      "(termination \"cancelled\"); during its tomography, it writes nothing.");
  command->add_option("--rig", job.rig_path, "Rig file")->required()->type_name("RIG.yaml");
  command->add_option("--images", job.images_dir, "Folder of one image per camera")
      ->required()
      ->type_name("DIR");
  command->add_option("--out", job.out_path, "Fitted volume to write")
      ->required()
      ->type_name("F.vdb");
  command->add_option("--views", o->views, "Cameras to fit (default: every camera with an image)")
      ->type_name("CAM,CAM");
  command->add_option("--holdout", job.holdout, "Camera to score but not fit")->type_name("CAMERA");
  command
      ->add_option("--tomography", job.tomography_path,
                   "Emission volume to start from (default: reconstructed here)")
      ->type_name("E.vdb");
  command->add_option("--method", o->method, "fast (default), or the paper's Algorithm 1 or 2")
      ->check(CLI::IsMember({"fast", "alg1", "alg2"}));
  command->add_option("--absorption", job.absorption, "Absorption model (default: dataset.yaml's)")
      ->check(CLI::IsMember({"soot", "grey"}));
  command->add_option("--exposure", job.exposure, "Exposure the images were taken with")
      ->type_name("S")
      ->check(ExposureRange());
  command->add_flag("--fit-exposure", job.fit_exposure,
                    "Fast fit: fit a free exposure (the paper's s), even a known one");
  AddTieFlags(command, &job.fit,
              "Fast fit: one temperature and density per ring about the flame's vertical axis "
              "(an axisymmetric flame, as Abel inversion assumes)",
              "Fast fit, with --axisymmetric");
  command->add_flag(
      "--no-sigma", [&job](std::int64_t) { job.uncertainty = false; },
      "Fast fit: do not write the per-voxel sigma grids");
  const FitOptions defaults = job.fit;  // the help states the defaults it describes
  CLI::Option* w_sm =
      command
          ->add_option(
              "--w-sm", job.fit.objective.w_sm,
              fmt::format("Weight of the neighbour term (fast: {:g}, with --axisymmetric "
                          "{:g} and with --fit-solver lm {:g}, its pairs along the axis x "
                          "{:g} and across x {:g}, at {} "
                          "voxels, x ({} / resolution)^2 on other grids; alg1/alg2: the "
                          "paper's {:g})",
                          defaults.objective.w_sm, defaults.axisymmetric_w_sm,
                          defaults.axisymmetric_lm_w_sm, defaults.axisymmetric_along_y,
                          defaults.axisymmetric_across_y, defaults.neighbour_weight_resolution,
                          defaults.neighbour_weight_resolution, PaperFitOptions().w_sm))
          ->type_name("W")
          ->check(Between(0, ObjectiveOptions::kMaxWeight));
  AddDirectionFlags(command, &o->directions, defaults);
  command
      ->add_option("--fit-iterations", o->iterations,
                   fmt::format("Fast fit: cap on the L-BFGS iterations per grid level (it stops "
                               "earlier once its energy falls over {} iterations by less than "
                               "{:g}% of its fall since the level's start, {:g}% with "
                               "--axisymmetric: --fit-stall); alg1/alg2: sweeps",
                               defaults.stall_window, 100 * defaults.stall_decrease,
                               100 * defaults.axisymmetric_stall_decrease))
      ->type_name("N")
      ->check(Whole(0, 1000000));
  AddStallFlag(command, &o->stall, defaults);
  AddSolverFlag(command, &o->solver, defaults);
  command->add_option("--time-limit", job.fit.time_limit_s, "Stop the fit after S seconds")
      ->type_name("S")
      ->check(kNonNegative);
  command->add_option("--seed", o->seed, "alg1/alg2: random seed (default 1)")
      ->type_name("N")
      ->check(Whole(0, std::int64_t(1) << 53));
  command->add_option("--report", job.report_dir, "Report folder (default: beside F.vdb)")
      ->type_name("DIR");
  CLI::Option* truth =
      command->add_option("--truth", job.truth_path, "Ground-truth volume: score the temperature")
          ->type_name("T.vdb");
  command
      ->add_option("--truth-rig", job.truth_rig,
                   "The rig the truth was simulated in (its dataset's rig.yaml), when --rig is a "
                   "calibration: the truth is moved into --rig's frame before it is scored")
      ->type_name("RIG")
      ->needs(truth);
  command->add_flag("--coarse-to-fine,!--no-coarse-to-fine", job.fit.coarse_to_fine,
                    "Fast fit: start at 32^3 and double (default off)");
  return [o, w_sm](Context& context) {
    context.StopOnSignals();
    FitJob job = o->job;
    ApplyTomographyFlags(o->tomography, &job.reconstruct, &job.input_transfer);
    job.views = SplitList(o->views);
    job.method = o->method == "alg1"   ? FitMethod::kAlgorithm1
                 : o->method == "alg2" ? FitMethod::kAlgorithm2
                                       : FitMethod::kFast;
    // The paper's algorithms minimise the paper's energy (w_sm 10) unless told otherwise.
    // A weight given is the fit's, tied to rings or not (ApplyNeighbourFlags).
    if (w_sm->count() > 0) job.paper.w_sm = job.fit.objective.w_sm;
    ApplyNeighbourFlags(
        w_sm->count() > 0 ? std::optional<double>(job.fit.objective.w_sm) : std::nullopt,
        o->directions, &job.fit);
    job.paper.time_limit_s = job.fit.time_limit_s;
    if (o->iterations >= 0) {
      if (o->iterations == 0 && job.method != FitMethod::kFast)
        throw UsageError("--fit-iterations 0: alg1 and alg2 need at least one sweep");
      job.fit.iterations_finest = job.fit.iterations_per_level = o->iterations;
      job.paper.iterations = o->iterations;
    }
    if (o->stall >= 0 && job.method != FitMethod::kFast)
      throw UsageError("--fit-stall: the fast fit's stop rule (alg1 and alg2 run their sweeps)");
    ApplyStallFlag(o->stall, &job.fit);
    if (!o->solver.empty() && job.method != FitMethod::kFast)
      throw UsageError("--fit-solver: the fast fit's tied solver (alg1 and alg2 run their sweeps)");
    ApplySolverFlag(o->solver, &job.fit);
    if (o->seed >= 0) job.paper.seed = static_cast<std::uint64_t>(o->seed);
    const FitJobResult r = RunFitJob(job, context.Progress(2.0));
    Log().info("fit: tomography {}", r.tomography);
    std::printf("fit: wrote %s\n  %s\n", job.out_path.c_str(), r.result.BriefReport().c_str());
    for (const auto& sc : r.scores)
      std::printf(
          "  %s (%s): mean Delta E %.3f over all pixels, %.3f over fire pixels (95th "
          "percentile %.2f)\n",
          sc.name.c_str(), sc.held_out ? "held out" : "fitted", sc.mean_delta_e, sc.fire_delta_e,
          sc.p95_delta_e);
    std::printf("  report: %s/report.md\n", r.report_dir.c_str());
    const auto& numbers = r.result.volume.metadata_numbers;
    if (numbers.count("soot_volume_fraction_peak")) {
      // The peak is one voxel's, often one that two views cannot place along its rays: the 99th
      // percentile of the voxels with soot beside it says whether it stands alone.
      std::vector<float> fractions;
      for (float f : r.result.volume.soot_volume_fraction)
        if (f > 0) fractions.push_back(f);
      double p99 = 0;
      if (!fractions.empty()) {
        auto at = fractions.begin() + std::ptrdiff_t(0.99 * double(fractions.size() - 1));
        std::nth_element(fractions.begin(), at, fractions.end());
        p99 = *at;
      }
      std::printf(
          "  soot: peak volume fraction %.3g (%.3g ppm; 99%% of the %zu voxels with soot at or "
          "below %.3g ppm), %.4g mm^3 of soot in the volume (the density grid counts particles "
          "of %.0f nm radius; the volume fraction holds whatever the radius)\n",
          numbers.at("soot_volume_fraction_peak"), 1e6 * numbers.at("soot_volume_fraction_peak"),
          fractions.size(), 1e6 * p99, 1e9 * numbers.at("soot_volume_m3"),
          1e9 * numbers.at("soot_particle_radius_m"));
    }
    if (r.have_truth) {
      if (!job.truth_rig.empty())
        std::printf("  truth's rig %s moved into the rig's frame: %s\n", job.truth_rig.c_str(),
                    r.truth_frame.Describe().c_str());
      if (!r.truth.compared)
        std::printf("  truth: %s not compared: %s\n", job.truth_path.c_str(),
                    r.truth.why_not.c_str());
      else if (r.truth.counted)
        std::printf(
            "  temperature against %s on the %zu of %zu visible voxels (>= 1300 K, >= 1%% of the "
            "peak emission) with medium: RMS %.1f K, mean %+.1f K\n",
            job.truth_path.c_str(), r.truth.counted, r.truth.visible, r.truth.rms_k,
            r.truth.mean_k);
      if (r.truth.compared && r.truth.truth_soot > 0)
        std::printf(
            "  soot particles: %.3f of the truth's (a volume ratio where both assume one "
            "particle size)\n",
            r.truth.fit_soot / r.truth.truth_soot);
      if (r.truth.compared && r.truth.truth_visible_soot > 0)
        std::printf(
            "  in the truth's visible voxels: %.3f of the truth's soot there (%.3f of its "
            "total)\n",
            r.truth.fit_visible_soot / r.truth.truth_visible_soot,
            r.truth.truth_visible_soot / r.truth.truth_soot);
      if (r.limit.compared && r.limit.counted && r.limit.truth_visible_soot > 0)
        std::printf(
            "  its limit, the truth's light given exactly to each fitted %s: RMS %.1f K, mean "
            "%+.1f K, %.3f of the truth's soot in its visible voxels\n",
            r.result.ring_profile.empty()      ? "voxel"
            : job.fit.axisymmetric_interpolate ? "ring (the rings' limit, which a tie linear in "
                                                 "the radius can pass)"
                                               : "ring",
            r.limit.rms_k, r.limit.mean_k, r.limit.fit_visible_soot / r.limit.truth_visible_soot);
      if (r.truth.have_sigma)
        std::printf(
            "  its sigma: %.0f%% of those voxels within one sigma, %.0f%% within two (calibrated: "
            "68%%, 95%%); median sigma %.0f K; %.0f%% determined by the images\n",
            100 * r.truth.within_1_sigma, 100 * r.truth.within_2_sigma, r.truth.median_sigma_k,
            100 * r.truth.determined_share);
      if (r.truth.have_determined) {
        // What a researcher who quotes only the determined voxels can expect.
        auto rms = [](double k) { return k >= 0 ? fmt::format("{:.1f} K", k) : std::string("-"); };
        std::printf("  temperature RMS on the determined voxels %s, on the rest %s\n",
                    rms(r.truth.determined_rms_k).c_str(), rms(r.truth.undetermined_rms_k).c_str());
      }
    }
    if (!r.result.uncertainty.temperature_sigma_k.empty())
      std::printf(
          "  sigma grids: %zu of %zu active voxels determined by the images, noise %.2f "
          "per Lab residual (the residuals' level %.2f), exact curvature in %.1f s\n",
          r.result.uncertainty.determined_count, r.result.active_voxels,
          r.result.uncertainty.sigma_lab, r.result.uncertainty.residual_lab,
          r.result.uncertainty.seconds);
    return r.result.termination == FitTermination::kCancelled ? kExitCancelled : kExitOk;
  };
}

}  // namespace flamerig::cli
