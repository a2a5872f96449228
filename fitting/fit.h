// Fitting temperature, density and exposure to images (DESIGN section 7): our fast fit, and the
// paper's Algorithms 1 and 2 as baselines, all minimising the same energy (objective.h) over the
// same active voxels, so that their error against run time can be compared.
//
// Active voxels: those whose tomography emission (luminance) exceeds `activity_threshold` times the
// brightest voxel's, the paper's "any RGB voxel value below a certain threshold is considered
// empty"; every other voxel is empty (density 0).
//
// Fast fit (FastFit):
//  1. Initialisation from the tomography emission: per voxel, the chromaticity of its emission
//     gives the temperature (the nearest point of the absorption-weighted Planck colour curve,
//     ThinEmissionTable, in the first view's camera response) and its brightness gives density times exposure (the exposure starts at
//     the tomography's and is moved, with every density, when the densities would leave their
//     bounds).
//  2. Refinement: L-BFGS (Ceres' GradientProblemSolver) on the Charbonnier-smoothed energy with
//     the adjoint gradient, bounds by reparametrisation (T = T_min + (T_max - T_min) sigmoid(u),
//     ln n and ln s likewise), directly on the requested grid. Coarse to fine (optional: the grid
//     halved down to `coarsest_resolution`, each level starting from the one below, temperature and
//     ln density resampled) is off by default: from the tomography's initialisation it only costs
//     time, because an iteration's cost is dominated by the pixels, not the voxels (a 32^3 level
//     costs half a 64^3 one), and a coarse grid cannot hold the fire that the fine tomography
//     already describes (64^3 candle, two views: initial Delta E 0.26 on the fine grid against 0.46
//     after a 40-iteration 32^3 level; 0.215 after 30 fine iterations in 9 s against 0.242 in 13 s).
//     It remains for starts far from the answer.
//  3. Warm start: a previous frame's result replaces step 1.
//
// Paper baselines (PaperFit): Algorithm 1 (per-voxel temperature and density, alternating) and
// Algorithm 2 (per-voxel temperature, density = the tomography's red channel normalised times one
// scale factor), by coordinate descent over clusters: two clusters from the halves of the
// yzx-ordered active voxels, doubling each iteration; `samples_per_cluster` Gaussian samples
// around the current value with a deviation that shrinks as 1 / iteration, kept only when they
// lower the energy (data term of the views plus the pairwise term of the cluster's voxels);
// uniform random start in [T_min, T_max] (and in log density for Algorithm 1); exposure (and
// density scale) by a log-spaced sweep at the start, then Gaussian samples in log space evaluated
// on the data term alone after each sweep over the clusters; a split cluster starts from the mean
// of its voxels. Ours departs from the paper only where DESIGN.md says (normalised pairwise
// units) and in evaluating a cluster's move with one render of all views, which is what the
// paper's dataTerm() does.
//
// Both report a trace of (time, exact energy, mean Delta E) so benchmarks can plot error against
// time, and call `progress` as they go (stage "fit", unit "iterations", values "energy",
// "mean_delta_e", "seconds"); a progress callback that answers kCancel stops the fit at that
// iteration with its current parameters (termination kCancelled). The result says why the fit
// stopped (FitTermination), in the manner of Ceres' Solver::Summary.
#ifndef FLAMERIG_FITTING_FIT_H_
#define FLAMERIG_FITTING_FIT_H_

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "core/error.h"
#include "core/progress.h"
#include "fitting/objective.h"
#include "fitting/uncertainty.h"
#include "tomography/volume.h"

namespace flamerig {

// Emission per unit density of a black body seen through the absorption model, in the renderer's
// linear sRGB (what a voxel of density 1 per m^3 emits per metre in the thin limit), per kelvin;
// with a camera response (camera_response.h), in its unit-gain channels (the response's output
// divided by its gains, as the tomography's frames are: frame_source.h), and the chromaticity
// below is then the channels' (c0, c1) / (c0 + c1 + c2).
class ThinEmissionTable {
 public:
  ThinEmissionTable(const AbsorptionModel& absorption, double t_min_k, double t_max_k,
                    std::shared_ptr<const ChannelResponse> response = nullptr);
  Eigen::Vector3d RgbPerDensity(double t_k) const;
  // The temperature in [t_min, t_max] whose emission has the chromaticity nearest `rgb`'s
  // (CIE xy); t_min for black or non-positive colours; the middle of the range for a mono
  // response, which has no colour.
  double TemperatureOf(const Eigen::Vector3d& rgb) const;
  double t_min() const { return t_min_; }
  double t_max() const { return t_max_; }

 private:
  double t_min_, t_max_;
  bool xyz_chromaticity_ = true;      // the sRGB observer (any gains, basis_is_xyz()): CIE xy
  bool mono_ = false;                 // one channel: TemperatureOf gives the range's middle
  std::vector<Eigen::Vector3d> rgb_;  // per kelvin from t_min
  std::vector<Eigen::Vector2d> xy_;
};

struct FitTracePoint {
  double seconds = 0;
  double energy = 0;  // exact energy (objective.h)
  double mean_delta_e = 0;
  int level = 0;  // coarse-to-fine level (fast fit), 0 = coarsest; iteration for the paper's fits
  std::string stage;
};

// Why a fit stopped (after Ceres' TerminationType).
enum class FitTermination {
  kConverged,       // a convergence criterion held (FitResult::message says which)
  kIterationLimit,  // the iteration (or sweep) budget was spent
  kTimeLimit,       // FitOptions::time_limit_s or PaperFitOptions::time_limit_s
  kCancelled,       // the progress callback asked to stop
  kFailed,          // the solver gave up (a line search that found no descent, say)
};
// "converged", "iteration limit", "time limit", "cancelled", "failed"
const char* ToString(FitTermination termination);

// The fit's unknowns that may change (the exposure is selected by FitOptions::known_exposure).
struct FitSelection {
  bool temperature = true;
  bool density = true;
};

struct FitOptions {
  // Weights and bounds: the paper's, but for the neighbour weight, w_sm = 1 where the paper has 10.
  // `flamerig benchmark accuracy` (BENCHMARKS.md, issue 19) chose it: on the 2-view candle and the
  // 8-view licks, both at 30 iterations with the exposure known, w_sm 10 / 1 gave temperature RMS
  // 155 / 145 K and 95 / 83 K (3 at 300 iterations: 148 and 82 K); 0 overfits the noise (234 K,
  // 131 K at 300 iterations). In our normalised units (objective.h) 10 flattens the field: its
  // spread 57 K against the truth's 142 K. The paper's algorithms are run with the paper's 10 (ObjectiveOptions'
  // default; PaperFitOptions::w_sm).
  ObjectiveOptions objective = [] {
    ObjectiveOptions o;
    o.w_sm = 1;
    return o;
  }();
  // The grid size at which objective.w_sm (and axisymmetric_w_sm) hold as given: voxels along the
  // grid's longest side. A grid of N voxels uses w_sm x (neighbour_weight_resolution / N)^2,
  // because the pairwise sum over a field grows as N^2 (N^3 pairs, differences ~1/N) while the
  // data term (a sum over pixels) does not; the weights above were chosen at 64. 0 = as given on
  // every grid. Measured (BENCHMARKS.md, issue 19, "The tied fit and where the grid lies"): the
  // main job's two views tied at 128 scored 125 to 131 K with 0.3 unscaled, 82 to 91 K with 0.075;
  // the eight-view licks untied at 128, 70 K with 1 and 66 K with 0.25. Each level of a
  // coarse-to-fine fit gets its own grid's weight. The paper's algorithms (PaperFit) never scale.
  int neighbour_weight_resolution = 64;
  // The forward model's discretisation. Spectral bins of 20 nm: against a 1 nm reference they
  // differ by Delta E 0.06 on a candle's fire pixels (10 nm: 0.017), below the 8-bit floor
  // (about 0.19), at 60% of the 10 nm cost. Steps of one voxel (the renderer's default is half):
  // `flamerig benchmark render` puts the difference in Delta E at a few hundredths, and the fit's
  // temperatures on the run benchmark's 12 frames moved by under 0.1 K while its fit took 23%
  // less time, and the 8-view licks (config/sim_licks.yaml, truth 96, fit 64) scored 81.8 K RMS,
  // bias +20.9 K, in 6.0 s against 82.0 K, +21.6 K, in 7.5 s (2026-11-26).
  RenderOptions render = [] {
    RenderOptions r;
    r.spectral_step_nm = 20;
    r.step_voxels = 1.0;
    return r;
  }();
  double activity_threshold = 1e-3;  // of the brightest voxel's emission luminance; [0, 1)
  double exposure_min = 0.01, exposure_max = 1000;  // the paper's range
  // Fast fit.
  int init_colour_radius_voxels = 1;  // temperature from the colour of (2r+1)^3 voxels; [0, 8]
  // In that cube, a neighbour brighter than the voxel counts at the voxel's own brightness (its
  // emission scaled down to the voxel's R + G + B, its colour kept): a plain sum is weighted by
  // brightness, so a dim voxel next to a hot core took the core's temperature. The start is the
  // cooler of that colour's temperature and the plain sum's: where brightness grows steeply with
  // temperature, capping the bright neighbours should cool a voxel, and where it heats one, the
  // dim neighbours' noise left in the pool is the likelier cause (two views' OS-SART: a dim red
  // voxel whose pool turned magenta started at the 2300 K bound, and five such voxels over
  // `benchmark run`'s take stayed there; a thin hot voxel beside a dense cooler one keeps the
  // plain pool's temperature, the cost of this rule). Measured with `flamerig benchmark
  // accuracy`'s finer-grid scene (licks, 8 views, truth 192, exposure known, 2026-11-27),
  // temperature RMS / bias / emission-weighted RMS after the fit, capped against plain: fit 64:
  // 66 / +5 / 38 K against 76 / +12 / 43 K; fit 128: 61 / +5 / 32 K against 66 / +7 / 34 K (the
  // cooler of the two, as now: 66 / +5 / 39 K and 60 / +5 / 31 K). The rest with the cap alone,
  // before the minimum: from the truth's own emission box-filtered onto the 128 grid (a perfect
  // tomography) 50 K capped, 66 K plain, 40 K from each voxel's colour alone (radius 0, which from
  // the real tomography's noisier colour gives 79 K). The benchmark's own tables (truth 96, fit
  // 64): licks 83 -> 71 K; the 2-view candle's RMS unchanged (147 K), its bias +71 -> +66 K, but
  // its emission-weighted RMS worse (79 -> 88 K). Other pools measured at 128 (fitted): the six
  // face neighbours 61 K, 18 neighbours 60 K, neighbours at half weight 62 K, every neighbour at
  // the voxel's brightness 72 K, the colour of a 64 or 96 tomography resampled 69 / 63 K.
  // false: the plain sum.
  bool init_colour_cap_brightness = true;
  // The same for a two-colour start (BandTomography), [0, 8], or -1: chosen on a cold start
  // among 1, 2, 3, 5 and 8 by the data term of each start (at its first level; finer levels pool
  // over the same distance; 3 for a warm start's new voxels). A
  // band's tomography is noisy voxel by voxel and the temperature follows the log of the bands'
  // ratio, and the best pooling depends on the scene: four mono cameras in two bands (650/40 and
  // 550/40 nm; candle, truth 48, fit 32) from radius 0/1/2/3/4 gave temperature RMS
  // 537/209/157/146/145 K after the fit (the truth's spread 139 K), eight there 126 K from 1 and
  // 148 K from 3; eight around licks (fit 64) 347 K from 1, 192 K from 3, 136 K from 5.
  int init_band_radius_voxels = -1;
  int coarsest_resolution = 32;   // coarse-to-fine stops halving here; >= 4
  bool coarse_to_fine = false;    // see step 2 above
  int iterations_per_level = 40;  // L-BFGS iterations at each coarse level
  int iterations_finest = 100;    // at the finest level: a cap, see stall_window
  // The convergence criterion (EnergyStalled): a level stops when its energy fell over the last
  // stall_window iterations by less than stall_decrease (a fraction) of what it has fallen since
  // the level began (window 0: no such criterion, only the iteration cap and Ceres' own
  // tolerances). FitResult::message says which stopped it. Measured against the energy's own
  // size until 2026-11-29 (issue 24: the 2-view candle stopped after 15 to 19 iterations, the
  // 8-view licks after 31): the part of the energy no fit removes (noise, pixels the model
  // cannot explain) then set the tolerance, and a raw 12-bit linear camera, whose noise near
  // black is a large energy in Lab, stopped after 5 to 32 iterations with the main job's tied
  // fit up to 66 K too hot (BENCHMARKS.md, "Raw 12-bit Bayer cameras and when the fit stops").
  int stall_window = 5;
  double stall_decrease = 0.005;
  double smooth_delta_e = 0.5;  // Charbonnier epsilons (the fast fit's smooth energy)
  double smooth_neighbour = 0.01;
  double time_limit_s = 0;  // 0 = none
  // Pairwise term on the per-voxel densities too. Off by default: the energy is then the one of
  // the paper's Algorithm 2 (pairwise on temperature), which the paper used for all its results;
  // with it, at 128^3 the density term outweighs the data and the fitted views' Delta E rises
  // (0.30 -> 0.50 measured).
  bool density_pairwise = false;
  // Warm start from another frame: the previous temperatures carry over, and each voxel's density
  // is what this frame's tomography brightness implies at that temperature (true), or the previous
  // density carries over too (false). The fire moves between frames; its temperature field
  // changes less than where the soot is.
  bool warm_start_density_from_emission = true;
  // An axisymmetric flame (the assumption of Abel inversion, usual for laminar flames filmed from
  // one or two directions): every active voxel is tied to its ring about the flame's axis, and the
  // fit has one temperature and one density per ring. The axis is vertical (y, up in the rig frame)
  // and passes, in each layer of the grid, through the centroid of that layer's tomography emission
  // (luminance-weighted), so a flame that sways or leans keeps its rings centred; rings are one
  // voxel wide (the distance to the axis rounded to whole voxels). The start is each ring's mean
  // (temperature, and log density); the gradient is projected onto ring-constant fields (each
  // ring's mean), so every L-BFGS step stays tied; the neighbour weight is axisymmetric_w_sm, on
  // the pairs along the axis only (axisymmetric_along_y, across_y below). Fast fit only. Measured
  // by `flamerig benchmark accuracy` (BENCHMARKS.md, issue 19): on the two-view candle, which sways
  // and has 10% turbulence in its radius, the temperature RMS falls from 148 to 84 K (the truth's
  // spread 142 K), the emission-weighted RMS from 82 to 52 K and the held-out camera's Delta E from
  // 20.7 to 7.8, while the fitted views' rises from 1.3 to 2.7 (they show what rings cannot hold).
  // The eight-view licks, not axisymmetric, are the control: 69 -> 94 K, and the held-out camera
  // says so (1.72 -> 5.93), as it will for a user's own fire. The sigma is the ring's
  // (uncertainty.h's groups: the ring's voxels' curvature pooled): on the main job's 13 frame sets
  // (two views, truth 96, fit 64, calibrated rig, each frame from its own tomography, pixels that
  // integrate over their area, Bayer cameras fitted through their mosaic) 71 to 77% of the visible
  // voxels lie within one sigma and 92 to 95% within two (69 to 73% with the neighbour term alike
  // in every direction), where the untied fit's per-voxel sigma holds 69 to 77% within one
  // (`benchmark run`'s candle, truth and fit both 64, point-sampled RGB frames: 45 to 63% tied, 62
  // to 68% untied).
  bool axisymmetric = false;
  // The neighbour weight of an axisymmetric fit, in place of objective.w_sm (which is the untied
  // fit's). The rings already average away the noise the neighbour term holds down in an untied
  // fit, so at w_sm 1 what is left of the term is its bias: alike in every direction (as below,
  // until axisymmetric_along_y), it pulls the cool rings at the flame's edge towards the hot core
  // (+57 K on the two-view candle). The measurements below are of that term. 0.3 was chosen on
  // 2026-11-28 by `flamerig benchmark accuracy`'s two-view candle over four seeds of its
  // turbulence, as the weight whose temperature RMS is never far from the best (RMS at 1 / 0.3 /
  // 0.1 / 0.03: 119 / 99 / 89 / 88 K, seed 7; 137 / 87 / 94 / 103, seed 3; 124 / 108 / 98 / 100,
  // seed 5; 123 / 81 / 123 / 136, seed 9; the truth's spread 142 K), under the stop rule of that
  // time, which measured the energy's fall against its own size and stopped the two-view candle
  // after 15 to 19 iterations. Since the stop rule of 2026-11-29 the tied fit runs 50 to 60, and
  // the same criterion picks 0.2 (BENCHMARKS.md, issue 19, "The tied fit run to convergence"; RMS /
  // bias / emission-weighted K at 0.3 against 0.2): `simulate`'s candle through the true rig, seeds
  // 3, 5, 7, 9, three frames each, 92 / +28 / 54 -> 90 / +22 / 56, 91 / +33 / 52 -> 88 / +27 / 52,
  // 97 / +42 / 52 -> 94 / +39 / 51, 90 / +28 / 53 -> 90 / +24 / 56 (0.15 and 0.1 are no better on
  // RMS, 0.05 worse); the main job's 13 sets 86.5 / +22.1 / 58.3 -> 86.1 / +17.9 / 59.4 (0.1: 88.0
  // / +12.6 / 61.6). A weaker term is cooler and closer in soot, but its emission-weighted error
  // rises. Run to convergence (400 iterations) the term's bias shows plainly: the main job's take
  // at +46, +19, +3.5 and -6.5 K with 0.3, 0.1, 0.03 and 0, and the RMS 108, 88, 94 and 128 K. The
  // held-out camera does not choose (its Delta E moves by under 0.1).
  double axisymmetric_w_sm = 0.2;
  // The tied fit's neighbour term by direction (ObjectiveOptions::along_y, across_y): the pairs
  // along the flame's axis (y) weigh axisymmetric_w_sm x 40, the pairs across it nothing. A
  // laminar flame's radial profile changes little from one layer to the next but sharply from
  // the axis outwards (the main job's truth: a core at 1550 K, a shell at 1950 K two to three
  // voxels out, an edge at 1550 to 1800 K); a term alike in every direction fills the cool core
  // and the edge towards the shell, while one along the axis averages the noise of neighbouring
  // layers and leaves the profile's contrast alone. Measured on 2026-12-03 (BENCHMARKS.md, issue
  // 19, "The tied fit's neighbour term along the axis only") at weight 0.2 under the stop rule,
  // against the term alike in every direction (1, 1; until then), as T RMS / bias / emission-
  // weighted RMS K, means over the sets: the main job's 13 sets 86.0 / +18.1 (10 sets within
  // 20 K) / 59.2 -> 81.6 / +12.2 (all 13) / 58.5; `simulate`'s candle seeds 3, 5, 7, 9, three
  // frames each, 90.2 / +27.8 (2 of 12) / 53.3 -> 85.5 / +23.1 (6) / 53.3. Along the axis only,
  // x 9, 20, 40, 80 and 160: the main job's RMS 87.8, 85.0, 81.6, 79.8, 80.4 K and bias +10.9,
  // +10.3, +12.2, +15.0, +19.0 K; the seeds' RMS 90.0, 88.1, 85.5, 84.9 K and bias +18.0, +19.2,
  // +23.1, +26.1 K. 40 is the weight never far from the best RMS whose bias keeps every set of
  // the take within 20 K.
  double axisymmetric_along_y = 40, axisymmetric_across_y = 0;
  // The tied fit's field between whole radii: constant over each ring, a voxel taking the node at
  // its radius rounded (false, the default); or linear in the radius, each voxel interpolating
  // the nodes at the whole radii either side of its own (true; `--axisymmetric-interpolate`; linear
  // in the fit's parameters, the logit of T's place in its search range and likewise of ln n's, so
  // nearly linear in T and ln n between two nodes a whole voxel apart), so
  // that the radial profile is not a staircase whose steps fall where the grid happens to cut the
  // flame. Measured on 2026-12-03 (BENCHMARKS.md, issue 19, "A tied field linear in the radius"),
  // T RMS / bias / emission-weighted RMS K, soot over the truth's, share within one sigma: the main
  // job's 13 sets 81.7 / +12.3 / 58.5, 0.71 to 0.83, 71 to 77% -> 79.0 / +5.1 / 58.8, 0.76 to
  // 0.99, 58 to 75% (its two worst sets 80 -> 91 K: neighbouring nodes trade against each other),
  // and with a weak term across the axis too (axisymmetric_across_y 0.5) 76.0 / +11.6 / 54.8, 0.74
  // to 0.91, 61 to 76%; `simulate`'s candle seeds 3, 5, 7, 9, three frames each, 85.6 / +23.2 /
  // 53.4, 66 to 81% -> 79.3 / +22.4 / 46.2, 76 to 85% (with 0.5 across: 80.5 / +28.1 / 45.2, 75 to
  // 86%). The sigma there was the bound sum_k w_k sigma_k; from the nodes' covariance (since
  // 2026-12-03 16:40 UTC, uncertainty.h) the main job holds 51 to 66% (55 to 67% with 0.5 across)
  // and the seeds 69 to 81% (65 to 81%). Not the default until the benchmarks are re-run with it.
  bool axisymmetric_interpolate = false;
  // The tied fit's stop rule: stall_decrease for a tied fit (the window and the iteration cap are
  // the untied fit's). Its few parameters walk on long after the untied fit's 0.5% stops them:
  // the faint rings cool and the soot grows along a flat valley of the energy (BENCHMARKS.md,
  // "When the tied fit stops"). Measured on 2026-12-05, T RMS / bias / emission-weighted RMS K,
  // soot over the truth's, iterations (cap 400), the main job's 13 sets: at 0.5% 81.2 / +11.4 /
  // 58.4, 0.71 to 0.80, 50 to 64; at 0.2% 79.1 / +9.8 / 57.8, 0.73 to 0.82, 66 to 87; at 0.1%
  // 77.1 / +8.0 / 58.7, 0.75 to 0.84, 93 to 107; `simulate`'s candle seeds 3, 5, 7, 9, three
  // frames each, 0.5% -> 0.1%: 81.9 / +9.3 / 57.0, 0.77 -> 81.1 / +1.8 / 58.0, 0.79, 47 to 60 ->
  // 91 to 115 iterations. Run on to 400 iterations (no rule) the fit is no better in temperature
  // (83.4 K and 87.1 K RMS) and its soot scatters (0.75 to 1.38 on the seeds).
  double axisymmetric_stall_decrease = 0.001;
  // The tied fit's solver. kLbfgs: L-BFGS (Ceres) on every voxel's parameters with the gradient
  // projected onto the tied fields, stopped by axisymmetric_stall_decrease. kLevenbergMarquardt
  // (`--fit-solver lm`): Levenberg-Marquardt on the nodes' parameters themselves
  // (levenberg_marquardt.h), the energy's exact gradient with a Gauss-Newton model of its
  // curvature built ray by ray over the nodes (FitObjective::DataGaussNewton and
  // PairwiseGaussNewton), stopped when a step taken lowers the energy by less than
  // axisymmetric_lm_stall_decrease of its fall since the start, or after iterations_finest steps
  // tried: a second-order method on the small problem that the tie makes of the fit, which
  // converges where L-BFGS walks a flat valley (BENCHMARKS.md, "When the tied fit stops"). Untied
  // fits are L-BFGS always (their J^T J couples every voxel along every ray).
  enum class TiedSolver { kLbfgs, kLevenbergMarquardt };
  TiedSolver axisymmetric_solver = TiedSolver::kLbfgs;
  double axisymmetric_lm_stall_decrease = 1e-4;
  // The tied fit's neighbour weight under kLevenbergMarquardt, in place of axisymmetric_w_sm
  // (which was chosen for L-BFGS as its stop rule ends it). Measured on 2026-12-07 on converged
  // fits (BENCHMARKS.md, issue 19, "The tied fit converged"), the main job's 13 sets, T RMS /
  // bias / emission-weighted RMS K, visible soot within 10% of the truth's: 0.03: 89.8 / +5.9 /
  // 61.4, 4 sets; 0.05: 85.4 / +8.3 / 57.8, 6; 0.08: 83.5 / +11.0 / 55.7, 11; 0.12: 83.3 / +14.5
  // / 54.0, 13; 0.2: 84.8 / +18.2 / 52.8, 13 (bias within 20 K on 7 sets); `simulate`'s candle
  // seeds 3, 5, 7, 9 at 0.05 / 0.08 / 0.12 / 0.2: 90.4 / 83.3 / 81.0 / 81.1 K RMS, +7.0 / +9.4 /
  // +12.2 / +18.9 K. 0.12: every set of the main job within 20 K and its soot within 10%.
  double axisymmetric_lm_w_sm = 0.12;
  // The cameras' exposure when it is known (the recording's exposure time x gain, in the
  // renderer's units, as the tomography takes it): > 0 holds the fit's exposure there, so that
  // densities come out absolute and comparable across frames; 0 = unknown, fitted (the paper's
  // free exposure s). Must lie in [exposure_min, exposure_max].
  double known_exposure = 0;
  // What the fit may change; a parameter not selected keeps its start (mrcal's problem
  // selections). The accuracy benchmark's oracle runs hold the truth's densities, say.
  FitSelection vary;
  // Per-voxel confidence (uncertainty.h) at the finest level's result: the sigma and determined
  // grids in the volume. Off by default (it costs a render and a curvature pass per view);
  // `fit` and `run` turn it on.
  bool estimate_uncertainty = false;
  UncertaintyOptions uncertainty;
  void Validate() const;  // throws InputError naming the field
  // The energy's options an axisymmetric fit minimises: `objective` with the tied fit's neighbour
  // weight and direction factors (axisymmetric_w_sm, axisymmetric_along_y, axisymmetric_across_y)
  // in place of the untied fit's (FastFit uses it; Validate checks it, so the rules are
  // ObjectiveOptions::Validate's alone).
  ObjectiveOptions TiedObjective() const;
  // The stop rule's share for the fit that runs: axisymmetric_stall_decrease when tied, else
  // stall_decrease.
  double StallDecrease() const {
    return axisymmetric ? axisymmetric_stall_decrease : stall_decrease;
  }
  // Every field of these options, and of the structs it holds, as one line ("w_am 1, w_sm 1,
  // ..."; numbers to 17 digits, so a line read back means the same doubles): two fits whose keys
  // are equal were given the same options. `run` stores it with each frame and refuses to resume
  // a run fitted with other ones. tests/fitting_fit_test.cc counts the fields of each struct, so
  // a field added without a place here fails the test rather than a resume.
  std::string Key() const;
};

// "l-bfgs", "levenberg-marquardt"
const char* ToString(FitOptions::TiedSolver solver);

// One ring of an axisymmetric fit (FitOptions::axisymmetric) at one height: a point of the radial
// profile T(r, h) that an Abel inversion gives and combustion papers quote, in the rig frame's
// metres. A ring holds the active voxels of one grid layer whose distance to the layer's axis,
// rounded to whole voxels (of the grid's x size), is the ring's radius.
struct RingProfilePoint {
  int layer = 0;  // the grid layer (y index)
  // The layer's height along the rig's up (Rig::up_in_rig), in metres from the rig's origin:
  // up . (axis_x_m, axis_y_m, axis_z_m), so that it grows up the flame. The fit, which is not
  // told the rig's up, gives axis_y_m (an up of +y); MeasureRingHeights measures it along another
  // (a rig calibrated in its first camera's frame has an up of about -y).
  double height_m = 0;
  // Where the flame's axis crosses the layer, in the rig frame (axis_y_m: the layer's voxel
  // centres).
  double axis_x_m = 0, axis_y_m = 0, axis_z_m = 0;
  int radius_voxels = 0;           // the ring's radius in whole voxels
  double radius_m = 0;             // the same in metres (its voxels lie within half a voxel)
  std::size_t voxels = 0;          // the ring's voxels (their values are the ring's, or with
                                   // axisymmetric_interpolate, the values below are their means)
  double temperature_k = 0;        // the ring's temperature
  double temperature_sigma_k = 0;  // its one-sigma uncertainty (0 when not estimated)
  double density_per_m3 = 0;       // the ring's soot density
  double log_density_sigma = 0;    // sigma of ln(density): 0.1 is about 10% (0: none)
  // The soot's volume fraction (density x particle volume; absorption.h's StampAbsorption), 0 for
  // a grey model.
  double soot_volume_fraction = 0;
};

// Sets each point's height_m to its axis point's height along `up_in_rig` (normalised; the
// rig's up, Rig::up_in_rig). Throws InputError when `up_in_rig` is zero or not finite.
void MeasureRingHeights(const Eigen::Vector3d& up_in_rig, std::vector<RingProfilePoint>* profile);

struct FitResult {
  // Temperature (K) and density (1/m^3) on the fitted grid; voxels outside the medium (density 0)
  // hold the lowest temperature of the search range (ambient). Metadata: exposure, density_scale,
  // mean_delta_e, energy, active_voxels, method, and the absorption model's (StampAbsorption:
  // with soot, the soot's volume fraction per voxel too).
  FireVolume volume;
  double exposure = 1;
  double density_scale = 1;  // Algorithm 2's factor (1 for per-voxel densities)
  EnergyTerms final_terms;   // exact, at the returned parameters
  std::vector<FitTracePoint> trace;
  std::size_t active_voxels = 0;
  // Active voxels the fit left at the upper bound of its search range, temperature
  // (ObjectiveOptions::t_max_k) and density (FitObjective::n_max()): within 1% of the range of it
  // (of ln n's for density; the sigmoid never reaches it). The bound holds such a voxel, not the
  // images: a fire cooler and thinner than the bounds puts none there (issue 19's "no voxel
  // pinned at a bound that the truth does not reach"). Also in the volume's metadata.
  std::size_t voxels_at_temperature_bound = 0, voxels_at_density_bound = 0;
  int evaluations = 0;  // energy (and gradient) evaluations
  int iterations = 0;   // solver iterations (L-BFGS steps; sweeps of the paper's algorithms)
  // Why it stopped, and the solver's own words ("Function tolerance reached. |cost_change|/cost:
  // 8.1e-08 <= 1.0e-07"); a cancelled or timed-out fit returns its best parameters so far.
  FitTermination termination = FitTermination::kIterationLimit;
  std::string message;
  double initial_energy = 0;    // exact energy at the start (the initialisation or warm start)
  int band_radius_voxels = -1;  // a two-colour start's neighbourhood radius (-1: none)
  std::size_t rings = 0;  // FitOptions::axisymmetric: the rings of the finest level (0: untied)
  // FitOptions::axisymmetric: one point per ring of the finest level, by layer and then radius
  // (empty when untied).
  std::vector<RingProfilePoint> ring_profile;
  VoxelUncertainty uncertainty;  // FitOptions::estimate_uncertainty; empty otherwise
  double seconds = 0;
  std::string method;
  std::string BriefReport() const;
};

// The convergence criterion of FitOptions: whether the energies of a level's iterations so far
// (costs[0] at its start, costs.back() now) fell over the last `window` iterations by less than
// `decrease` times their fall since costs[0]. False while there are at most `window` iterations,
// with window 0, or for energies that are not finite. Adding a constant to every energy (a noise
// floor) does not change it.
bool EnergyStalled(const std::vector<double>& costs, int window, double decrease);

// Two-colour (multi-band) pyrometry's start (issue 19, item 6). A mono camera records no colour,
// so the fit cannot start a mono rig's temperatures from the tomography's colour; a rig of mono
// cameras behind different band-pass filters (the combustion lab's two-colour set-up) has instead
// one tomography per band, each from that band's cameras alone, in their unit-gain signal: per
// voxel the band's emission e_b = n K_b(T) (K_b: the band's ThinEmissionTable, soot absorption
// times Planck through the filtered sensor). The start's temperature is the one whose band ratios
// match the measured ones (least squares on log e_b - log K_b(T) over the bands, each e_b summed
// over a cube around the voxel: FitOptions::init_band_radius_voxels), its density the bands'
// summed emission over their summed K_b(T). This is what a two-colour pyrometer does per pixel, here per voxel. The fit then
// refines every voxel against each view in its own band as before.
struct BandTomography {
  std::shared_ptr<const ChannelResponse> response;  // the band's cameras' (one channel)
  FireVolume tomography;  // emission_rgb from this band's cameras only (grey: channel 0 is read)
};

// The views to match at full resolution: shared by every level. `tomography` is an emission
// volume (tomography/reconstruct.h: `emission_rgb`, metadata "exposure" optional) on any grid;
// the fit runs on `grid`. `warm_start` (optional): a previous FitResult on any grid. `bands`
// (optional, two or more, each on any grid): the start's temperatures from the bands' ratios
// instead of the tomography's colour (BandTomography), and the active voxels where any band has
// light (each band's emission over its peak, summed); `tomography` is then not read (the first
// band's exposure is the start's).
// Throws InputError for a band without a one-channel response or emission.
FitResult FastFit(const GridGeometry& grid, const FireVolume& tomography,
                  const std::vector<FitView>& views, const AbsorptionModel& absorption,
                  const FitOptions& options, const FitResult* warm_start = nullptr,
                  const ProgressCallback& progress = nullptr,
                  const std::vector<BandTomography>& bands = {});

// What FastFit and PaperFit throw when their inputs hold nothing to fit: no voxel of the
// tomography (with bands: of any band) is active. A DataError, so that a caller that does not
// tell it apart fails as before; `flamerig run` writes the frame as one without fire
// (NoFireResult, below).
class NoActiveVoxelsError : public DataError {
 public:
  explicit NoActiveVoxelsError(const std::string& message) : DataError(message) {}
};

// The result for images that hold no fire (a take filmed before ignition or after the flame is
// out, a frame set with the fire outside every camera's view): no active voxel, every voxel at the
// ambient temperature (ObjectiveOptions::t_min_k) with no soot, `exposure` as given (a placeholder
// where the take's is not known yet: a reader needs one > 0), 0 iterations, method "no fire" and
// termination "converged" with the message "the images show no fire: nothing to fit", metadata
// no_fire 1. The keys every reader of a fitted volume needs (exposure, energy, active_voxels, the
// absorption's), so that a take's sequence of volumes has no gap; no neighbour weights and no
// sigma grids: nothing was fitted or estimated.
FitResult NoFireResult(const GridGeometry& grid, const AbsorptionModel& absorption,
                       const FitOptions& options, double exposure);

enum class PaperAlgorithm { kPerVoxelDensity = 1, kDensityScale = 2 };

struct PaperFitOptions {
  PaperAlgorithm algorithm = PaperAlgorithm::kDensityScale;
  int iterations = 12;             // sweeps over the clusters (each doubles them)
  int samples_per_cluster = 8;     // Gaussian samples per cluster per sweep
  double initial_sigma_t_k = 400;  // deviation at iteration 1 (then / iteration)
  double initial_sigma_log_n = 2;  // natural-log units, Algorithm 1
  int exposure_sweep = 25;         // log-spaced exposures tried at the start
  int exposure_samples = 8;        // per sweep, after the first
  double time_limit_s = 0;         // 0 = none
  std::uint64_t seed = 1;
  // The neighbour weight: the paper's 10, whatever FitOptions::objective says (the fast fit's
  // default differs, FitOptions above).
  double w_sm = ObjectiveOptions().w_sm;
};

FitResult PaperFit(const GridGeometry& grid, const FireVolume& tomography,
                   const std::vector<FitView>& views, const AbsorptionModel& absorption,
                   const FitOptions& options, const PaperFitOptions& paper,
                   const ProgressCallback& progress = nullptr);

// Active voxels of `grid` from an emission volume (resampled onto it when its grid differs).
std::vector<std::uint32_t> ActiveVoxels(const GridGeometry& grid, const FireVolume& tomography,
                                        double threshold, std::vector<float>* emission_on_grid);

}  // namespace flamerig

#endif  // FLAMERIG_FITTING_FIT_H_
