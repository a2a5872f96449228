// `flamerig benchmark accuracy` (issue 19): what limits the fitted temperature, found by oracle
// runs on a synthetic truth finer than the fit's grid. See tools/benchmark.h.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <utility>

#include "calibration/synthetic_rig.h"
#include "core/error.h"
#include "core/image.h"
#include "fitting/fit.h"
#include "fitting/objective.h"
#include "fitting/renderer.h"
#include "fitting/synthetic_fire.h"
#include "pipeline/fit_report.h"
#include "pipeline/simulate.h"
#include "pipeline/truth.h"
#include "tomography/reconstruct.h"
#include "tools/benchmark.h"

namespace flamerig {

namespace {

using Clock = std::chrono::steady_clock;

double Since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

// "share% / RMS / RMS": the scored voxels the fit calls determined, the temperature RMS over
// them and over the rest ("-" where there are none, or no determined grid).
std::string DeterminedCell(const TruthError& t) {
  if (!t.have_determined) return "-";
  auto rms = [](double k) { return k >= 0 ? Fixed(k, 0) : std::string("-"); };
  return Fixed(100 * t.determined_share, 0) + "% / " + rms(t.determined_rms_k) + " / " +
         rms(t.undetermined_rms_k);
}

// A scene: a truth on a fine grid, the cameras that film it (the last one held out), their 8-bit
// images, the exposure they were taken with, and the tomography of the fitted views on the fit's
// grid.
struct Scene {
  std::string name;
  Rig rig;
  std::vector<std::unique_ptr<CameraRays>> rays;
  FireVolume truth;
  GridGeometry fit_grid;
  double exposure = 1;
  std::vector<ImageU8> images;  // per camera
  FireVolume tomography;
  AbsorptionModel absorption = AbsorptionModel::DefaultSoot();
};

struct SceneSpec {
  std::string name;
  synthetic::FireKind kind = synthetic::FireKind::kCandle;
  std::uint64_t seed = 7;
  double peak_k = 2000, soot = 1e-6;
  Box3 box;
  std::vector<double> azimuths_deg;  // fitted views, then the held-out one
  double distance_m = 0.3, elevation_deg = 0, fill = 0.6;
  int width = 320, height = 240;
  int truth_resolution = 96, fit_resolution = 64;
  double noise_dn = 0.5;
  double exposure_scale = 1;  // 1: the brightest 0.5% of fire pixels saturate (as simulate does)
};

// Renders the truth through every camera and makes the 8-bit images as `flamerig simulate` does:
// the exposure puts the 99.5th percentile of fire pixels at full scale (times exposure_scale),
// sensor noise added.
void Film(const SceneSpec& spec, Scene* s) {
  FireRenderer renderer(s->absorption);
  renderer.SetVolume(s->truth.geometry, s->truth.temperature_k, s->truth.density_per_m3);
  std::vector<ImageF> linear(s->rays.size());
  for (std::size_t c = 0; c < s->rays.size(); ++c) renderer.Render(*s->rays[c], &linear[c]);
  const double automatic = AutoExposure(linear);
  if (!(automatic > 0)) throw DataError("accuracy benchmark: " + spec.name + ": no fire in view");
  s->exposure = spec.exposure_scale * automatic;
  s->images.clear();
  for (std::size_t c = 0; c < linear.size(); ++c) {
    s->images.push_back(ApplyCameraResponse(linear[c], s->exposure));
    AddSensorNoise(&s->images.back(), spec.noise_dn, 1000 * spec.seed + c);
  }
}

// Sets the scene's fit grid (`resolution` along the box's longest side) and the tomography of its
// fitted views on it, with the exposure the images were taken with.
void Reconstruct(const Box3& box, int resolution, Scene* s) {
  s->fit_grid = GridGeometry::FromBox(box, resolution);
  Rig fitted = s->rig;
  fitted.cameras.pop_back();
  ReconstructOptions ro;
  ro.resolution = resolution;
  ro.exposure = s->exposure;
  Reconstructor rec(fitted, ro);
  std::vector<ImageU8> used(s->images.begin(), s->images.end() - 1);
  s->tomography = rec.Reconstruct(used, nullptr);
}

Scene MakeScene(const SceneSpec& spec) {
  Scene s;
  s.name = spec.name;
  synthetic::RingOptions ring;
  ring.cameras = static_cast<int>(spec.azimuths_deg.size());
  ring.azimuths_deg = spec.azimuths_deg;
  ring.distance_m = spec.distance_m;
  ring.elevation_deg = spec.elevation_deg;
  ring.fill = spec.fill;
  ring.width = spec.width;
  ring.height = spec.height;
  s.rig = synthetic::MakeRingRig(spec.box, ring);
  s.rig.cameras.back().name = "holdout";
  for (const auto& c : s.rig.cameras) s.rays.push_back(std::make_unique<CameraRays>(c.model));
  synthetic::FireOptions fo;
  fo.kind = spec.kind;
  fo.seed = spec.seed;
  fo.peak_temperature_k = spec.peak_k;
  fo.peak_soot_volume_fraction = spec.soot;
  const GridGeometry truth_grid = GridGeometry::FromBox(spec.box, spec.truth_resolution);
  s.truth = synthetic::MakeFire(truth_grid, fo, s.absorption);
  s.truth.emission_rgb = synthetic::ThinEmissionRgb(s.truth, s.absorption);
  Film(spec, &s);
  Reconstruct(spec.box, spec.fit_resolution, &s);
  return s;
}

// The truth box-filtered onto the fit's grid: each fit voxel gets the density-weighted mean
// temperature and the mean density of the truth voxels whose centres it holds.
FireVolume TruthOnGrid(const FireVolume& truth, const GridGeometry& grid) {
  const std::size_t n = grid.num_voxels();
  std::vector<double> nt(n, 0), dn(n, 0), count(n, 0);
  const GridGeometry& tg = truth.geometry;
  for (int k = 0; k < tg.dims.z(); ++k)
    for (int j = 0; j < tg.dims.y(); ++j)
      for (int i = 0; i < tg.dims.x(); ++i) {
        std::size_t f;
        if (!grid.VoxelHolding(tg.VoxelCenter(i, j, k), &f)) continue;
        const std::size_t v = tg.Flat(i, j, k);
        nt[f] += double(truth.density_per_m3[v]) * truth.temperature_k[v];
        dn[f] += truth.density_per_m3[v];
        count[f] += 1;
      }
  FireVolume out;
  out.geometry = grid;
  out.temperature_k.assign(n, 300.0f);
  out.density_per_m3.assign(n, 0.0f);
  for (std::size_t f = 0; f < n; ++f) {
    if (!(dn[f] > 0)) continue;
    out.temperature_k[f] = static_cast<float>(nt[f] / dn[f]);
    out.density_per_m3[f] = static_cast<float>(dn[f] / count[f]);
  }
  return out;
}

std::vector<FitView> Views(const Scene& s, bool held_out) {
  std::vector<FitView> v;
  const std::size_t n = s.rig.cameras.size();
  for (std::size_t c = held_out ? n - 1 : 0; c < (held_out ? n : n - 1); ++c) {
    FitView f;
    f.name = s.rig.cameras[c].name;
    f.rays = s.rays[c].get();
    f.image = s.images[c];
    v.push_back(f);
  }
  return v;
}

// Mean Delta E over the fire pixels (fit_report.h) of the fitted views and of the held-out ones,
// each pooled over their pixels.
std::pair<double, double> FireDeltaE(const FitResult& r, const std::vector<FitView>& fitted,
                                     const std::vector<FitView>& held,
                                     const AbsorptionModel& absorption) {
  double sum[2] = {0, 0}, pixels[2] = {0, 0};
  for (const ViewScore& v : WriteFitReport("", r, fitted, held, absorption, RenderOptions(), "")) {
    sum[v.held_out] += v.fire_delta_e * v.fire_pixels;
    pixels[v.held_out] += v.fire_pixels;
  }
  return {pixels[0] > 0 ? sum[0] / pixels[0] : 0.0, pixels[1] > 0 ? sum[1] / pixels[1] : 0.0};
}

// Where the fit's temperature error lies on a scene's fit grid (issue 19's eight-view target):
// the error in bands of the truth's emission for the fit as `run` fits (`run_fit`, done by the
// caller), its start, the grid's limit (the image-equivalent truth), and two oracle starts: the
// image-equivalent truth, and the run's start with only its faint voxels (the tomography below
// 10% of its brightest) taken from it. Returns the section's Markdown table rows.
std::string ErrorByEmissionRows(const Scene& scene, const std::vector<FitView>& fitted,
                                const std::vector<FitView>& held, const FitOptions& run_options,
                                const FitResult& run_fit, double run_seconds,
                                const std::function<void(const std::string&)>& log) {
  const FireVolume equivalent = LightEquivalentTruth(scene.truth, scene.fit_grid, scene.absorption);
  FitOptions frozen = run_options;  // no iteration: a start scored as it is
  frozen.iterations_finest = 0;
  FitOptions from_volume = run_options;  // a warm start's temperature and density both kept
  from_volume.warm_start_density_from_emission = false;
  auto warm = [&](const FireVolume& volume) {
    FitResult w;
    w.volume = volume;
    w.exposure = scene.exposure;
    return w;
  };
  // The run's start, and the same with its faint voxels from the image-equivalent truth.
  const FitResult start =
      FastFit(scene.fit_grid, scene.tomography, fitted, scene.absorption, frozen);
  FireVolume faint_from_truth = start.volume;
  {
    const std::vector<float>& e = scene.tomography.emission_rgb;
    if (e.size() != 3 * faint_from_truth.geometry.num_voxels() ||
        !faint_from_truth.geometry.SameVoxels(equivalent.geometry))
      throw std::logic_error(
          "accuracy benchmark: the start, the tomography and the truth on the "
          "fit's grid must share its voxels");
    float peak = 0;
    for (std::size_t v = 0; v < e.size() / 3; ++v) peak = std::max(peak, e[3 * v + 1]);
    for (std::size_t v = 0; v < e.size() / 3; ++v) {
      if (!(faint_from_truth.density_per_m3[v] > 0) || !(equivalent.density_per_m3[v] > 0) ||
          !(e[3 * v + 1] < 0.1f * peak))
        continue;
      faint_from_truth.temperature_k[v] = equivalent.temperature_k[v];
      faint_from_truth.density_per_m3[v] = equivalent.density_per_m3[v];
    }
    StampAbsorption(scene.absorption, &faint_from_truth);  // the fraction of the new densities
  }
  struct Case {
    std::string name;
    FitResult result;
    double seconds = 0;
  };
  std::vector<Case> cases;
  cases.push_back({"the fit as `run` fits", run_fit, run_seconds});
  cases.push_back({"its start (the tomography's colour), no iteration", start, 0});
  {
    const FitResult w = warm(equivalent);
    FitOptions kept = frozen;  // its densities too, not the tomography's brightness at its T
    kept.warm_start_density_from_emission = false;
    cases.push_back({"the grid's limit: the image-equivalent truth, no iteration",
                     FastFit(scene.fit_grid, scene.tomography, fitted, scene.absorption, kept, &w),
                     0});
  }
  for (const auto& [name, volume] :
       {std::pair<std::string, const FireVolume*>{"started at the image-equivalent truth",
                                                  &equivalent},
        {"started as `run` starts but its faint voxels (tomography below 10% of its peak) at the "
         "image-equivalent truth",
         &faint_from_truth}}) {
    const FitResult w = warm(*volume);
    const auto t0 = Clock::now();
    FitResult r =
        FastFit(scene.fit_grid, scene.tomography, fitted, scene.absorption, from_volume, &w);
    cases.push_back({name, std::move(r), Since(t0)});
  }
  std::ostringstream md;
  for (const Case& c : cases) {
    const TruthError t = CompareWithTruth(scene.truth, c.result.volume);
    const std::vector<EmissionBandError> bands =
        TemperatureErrorByEmission(scene.truth, c.result.volume);
    const auto delta_e = FireDeltaE(c.result, fitted, held, scene.absorption);
    md << "| " << c.name << " | " << Fixed(c.seconds, 1) << " | " << c.result.iterations << " | "
       << Fixed(delta_e.first, 2) << " | " << Fixed(delta_e.second, 2) << " | " << Fixed(t.rms_k, 0)
       << " | " << Fixed(t.mean_k, 0);
    for (const EmissionBandError& b : bands)
      md << " | " << Fixed(b.rms_k, 0) << " / " << Fixed(b.mean_k, 0) << " ("
         << Fixed(100 * b.share, 0) << "%)";
    md << " |\n";
    if (log)
      log("accuracy: by emission: " + c.name + ": T RMS " + Fixed(t.rms_k, 0) + " K, held out " +
          Fixed(delta_e.second, 2));
  }
  return md.str();
}

// Finer fit grids (issue 19's eight-view target): the licks filmed (once per image size) from a
// truth of 1.5 times the finest fit's resolution, fitted as `run` fits (exposure known, until the
// energy stalls) on grids of 1, 1.5 and 2 times the scene's fit resolution, with the neighbour
// weight scaled by (resolution / scene's)^-2 (the pairwise sum of |v_j - v_i| over a field grows
// as the resolution squared while the data term, a sum over pixels, does not), the finest grid
// also from images of twice the size (four times the pixels: a prior four times weaker relative
// to the data, not compensated). Each row against the grid's own limit (the image-equivalent
// truth).
std::string FinerGridSection(const SceneSpec& base,
                             const std::function<void(const std::string&)>& log) {
  std::ostringstream md;
  const int r0 = base.fit_resolution;
  const int truth = 3 * r0;  // 1.5 times the finest fit grid's resolution
  md << "### Finer fit grids: " << base.name << ", truth " << truth << "\n\n";
  md << "The same fire filmed from a truth of " << truth
     << " (once for each image size), fitted as `run` fits (exposure known, "
        "until the energy stalls) on finer grids. The neighbour weight is scaled by ("
     << r0
     << " / resolution)^2, as `fit` and `run` scale it (FitOptions::neighbour_weight_resolution): "
        "the pairwise sum of |v_j - v_i| over a field grows as the "
        "resolution squared while the data term does not (roughly: the fit smooths |x| below "
        "about 20 K, where the sum grows more slowly). The data term sums over pixels, so images "
        "of twice the size also weaken the prior four times relative to it; the weight is not "
        "scaled for that. 'Grid limit' is the image-equivalent truth on that grid (the best a fit "
        "there can return, as in the tables above). The errors are over the truth's visible "
        "voxels where the fit has medium (last column), so the truth's spread differs a little "
        "between rows. Targets (issue 19, eight views): RMS at most 50 K, emission-weighted at "
        "most 35 K, bias within 10 K.\n\n";
  md << "| fit grid | images | w_sm | seconds | iterations | stopped by | Delta E fitted | Delta E "
        "held out | T RMS K | bias K | emission-weighted RMS K | correlation | grid limit RMS K "
        "| truth's spread K | visible voxels with medium | determined: share / T RMS / the rest's "
        "K |\n";
  md << "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  struct Row {
    int resolution, width;
  };
  const std::vector<Row> rows = {
      {r0, base.width}, {r0 * 3 / 2, base.width}, {2 * r0, base.width}, {2 * r0, 2 * base.width}};
  // Rows of one image size share their filming (truth and images); each grid gets its tomography.
  Scene scene;
  int filmed_width = 0;
  std::string by_emission, by_emission_grid;  // ErrorByEmissionRows on the finest grid
  for (const Row& row : rows) {
    SceneSpec spec = base;
    spec.truth_resolution = truth;
    spec.fit_resolution = row.resolution;
    spec.width = row.width;
    spec.height = base.height * row.width / base.width;
    const auto t0 = Clock::now();
    if (row.width != filmed_width) {
      scene = MakeScene(spec);
      filmed_width = row.width;
    } else {
      Reconstruct(spec.box, row.resolution, &scene);
    }
    if (log)
      log("accuracy: finer grids: " + std::to_string(row.resolution) + " from " +
          std::to_string(spec.width) + "x" + std::to_string(spec.height) + " ready in " +
          Fixed(Since(t0), 1) + " s");
    const std::vector<FitView> fitted = Views(scene, false), held = Views(scene, true);
    FitOptions o;
    o.known_exposure = scene.exposure;
    o.neighbour_weight_resolution = r0;  // the weight as `run` scales it: x (r0 / resolution)^2
    o.estimate_uncertainty = true;       // as `run` fits
    const auto start = Clock::now();
    const FitResult r = FastFit(scene.fit_grid, scene.tomography, fitted, scene.absorption, o);
    const double seconds = Since(start);
    const TruthError t = CompareWithTruth(scene.truth, r.volume);
    const TruthError limit = CompareWithTruth(
        scene.truth, LightEquivalentTruth(scene.truth, scene.fit_grid, scene.absorption));
    const auto delta_e = FireDeltaE(r, fitted, held, scene.absorption);
    md << "| " << row.resolution << " | " << spec.width << "x" << spec.height << " | "
       << Fixed(r.volume.metadata_numbers.at("w_sm"), 3) << " | " << Fixed(seconds, 1) << " | "
       << r.iterations << " | " << ToString(r.termination) << " | " << Fixed(delta_e.first, 2)
       << " | " << Fixed(delta_e.second, 2) << " | " << Fixed(t.rms_k, 0) << " | "
       << Fixed(t.mean_k, 0) << " | " << Fixed(t.weighted_rms_k, 0) << " | "
       << Fixed(t.correlation, 2) << " | " << Fixed(limit.rms_k, 0) << " | "
       << Fixed(t.truth_spread_k, 0) << " | " << t.counted << " / " << t.visible << " | "
       << DeterminedCell(t) << " |\n";
    if (log)
      log("accuracy: finer grids: " + std::to_string(row.resolution) + ": " + Fixed(seconds, 1) +
          " s, T RMS " + Fixed(t.rms_k, 0) + " K, bias " + Fixed(t.mean_k, 0) + " K");
    if (row.resolution == 2 * r0 && row.width == base.width) {
      by_emission = ErrorByEmissionRows(scene, fitted, held, o, r, seconds, log);
      by_emission_grid = std::to_string(row.resolution) + " from " + std::to_string(spec.width) +
                         "x" + std::to_string(spec.height);
    }
  }
  md << "\n";
  md << "Where the error lies (fit " << by_emission_grid
     << "): the temperature error in bands of the truth's emission (its green channel over its "
        "brightest voxel's), each as RMS / bias K (the band's share of the summed squared "
        "error), for the fit as `run` fits, its start, the grid's limit, and two oracle starts: "
        "the image-equivalent truth, and `run`'s start with only its faint voxels (where the "
        "tomography is below 10% of its brightest) taken from it. Delta E held out is the "
        "held-out camera's.\n\n";
  md << "| fit | seconds | iterations | Delta E fitted | Delta E held out | T RMS K | bias K "
        "| 1-3% of the peak | 3-10% | 10-30% | 30-100% |\n";
  md << "|---|---|---|---|---|---|---|---|---|---|---|\n";
  md << by_emission << "\n";
  return md.str();
}

struct Variant {
  std::string name;
  FitOptions options;
  bool start_at_truth = false;  // warm start from the truth on the fit's grid
  // Warm start from the image-equivalent truth (pipeline/truth.h's LightEquivalentTruth) instead.
  bool start_at_image_equivalent = false;
};

}  // namespace

std::string RunAccuracyBenchmark(const AccuracyBenchmarkOptions& options,
                                 const std::function<void(const std::string&)>& log) {
  const bool quick = options.quick;
  std::vector<SceneSpec> specs;
  {
    SceneSpec candle;
    candle.name = "candle, 2 views (the paper's set-up)";
    candle.box = Box3{Eigen::Vector3d(-0.015, 0.0, -0.015), Eigen::Vector3d(0.015, 0.07, 0.015)};
    candle.azimuths_deg = {0, 90, 45};
    specs.push_back(candle);
    SceneSpec licks;
    licks.name = "licks, 8 views";
    licks.kind = synthetic::FireKind::kLicks;
    licks.seed = 11;
    licks.peak_k = 2100;
    licks.soot = 2e-6;
    licks.box = Box3{Eigen::Vector3d(-0.05, 0.0, -0.05), Eigen::Vector3d(0.05, 0.14, 0.05)};
    for (int c = 0; c < 8; ++c) licks.azimuths_deg.push_back(45.0 * c);
    licks.azimuths_deg.push_back(22.5);
    licks.distance_m = 0.5;
    licks.elevation_deg = 10;
    licks.fill = 0.85;
    specs.push_back(licks);
    if (quick)
      for (auto& s : specs) {
        s.width = 96;
        s.height = 72;
        s.truth_resolution = 24;
        s.fit_resolution = 16;
        if (s.azimuths_deg.size() > 3) s.azimuths_deg = {0, 90, 180, 270, 45};
      }
  }
  const int long_iterations = quick ? 20 : 300;

  std::ostringstream md;
  md << "## Temperature accuracy: what limits it (issue 19)\n\n";
  md << "Machine: " << MachineDescription() << ".\n\n";
  md << "Oracle runs of the fast fit on synthetic truths finer than the fit's grid (truth "
     << specs[0].truth_resolution << ", fit " << specs[0].fit_resolution
     << " along the box's longest side), filmed as `flamerig simulate` films them (soot on the "
        "spectral path with self-absorption, 8-bit sRGB with 0.5 DN noise, the brightest 0.5% of "
        "fire pixels saturated), through the true rig, plus one held-out camera. Each row changes "
        "one thing. Temperature errors are over the truth's visible voxels (>= 1300 K and >= 1% "
        "of the peak emission), each against the fitted voxel that holds its centre, where the "
        "fit has medium: RMS, mean (bias), RMS weighted by the truth's emission, Pearson's "
        "correlation, and the fitted field's spread; the truth's own spread (the RMS of the best "
        "constant, the trivial baseline) is in each scene's heading. Delta E is the mean over fire "
        "pixels. Seconds include the per-voxel sigma, as `run` and `fit` compute it; the last "
        "column splits the scored voxels by the fit's `determined` grid.\n\n";
  for (const SceneSpec& spec : specs) {
    const auto t0 = Clock::now();
    Scene scene = MakeScene(spec);
    if (log) log("accuracy: " + spec.name + " filmed in " + Fixed(Since(t0), 1) + " s");
    const std::vector<FitView> fitted = Views(scene, false), held = Views(scene, true);
    // The oracles' scenes: noise-free unsaturated images (exposure halved) and their tomography.
    SceneSpec clean_spec = spec;
    clean_spec.noise_dn = 0;
    clean_spec.exposure_scale = 0.5;
    Scene clean = MakeScene(clean_spec);
    const std::vector<FitView> clean_fitted = Views(clean, false);
    const FireVolume truth_on_grid = TruthOnGrid(scene.truth, scene.fit_grid);
    const FireVolume image_equivalent =
        LightEquivalentTruth(scene.truth, scene.fit_grid, scene.absorption);

    std::vector<Variant> variants;
    const std::string its = std::to_string(long_iterations) + " iterations";
    // Rows with a count of iterations run exactly that many (no convergence criterion).
    FitOptions before;  // before issue 19: the exposure fitted per frame, the paper's w_sm 10
    before.objective.w_sm = ObjectiveOptions().w_sm;
    before.iterations_finest = 30;
    before.stall_window = 0;
    variants.push_back({"before: exposure fitted, w_sm = 10, 30 iterations", before});
    FitOptions known10 = before;
    known10.known_exposure = scene.exposure;
    variants.push_back({"exposure known, w_sm = 10, 30 iterations", known10});
    FitOptions known30 = known10;
    known30.objective.w_sm = FitOptions().objective.w_sm;
    variants.push_back(
        {"exposure known, w_sm = 1, 30 iterations (`run` and `fit` until issue 24)", known30});
    FitOptions known;  // the defaults: stops on its convergence criterion (fit.h)
    known.known_exposure = scene.exposure;
    variants.push_back(
        {"exposure known, w_sm = 1, until the energy stalls: `run` and `fit` now", known});
    // An axisymmetric flame (FitOptions::axisymmetric): one temperature and density per ring
    // about the flame's axis; the held-out camera judges it as it judges the rest.
    FitOptions rings = known;
    rings.axisymmetric = true;
    variants.push_back(
        {"... axisymmetric: one temperature and density per ring about the flame's axis "
         "(`--axisymmetric`)",
         rings});
    FitOptions rings_lm = rings;
    rings_lm.axisymmetric_solver = FitOptions::TiedSolver::kLevenbergMarquardt;
    variants.push_back(
        {"... the same converged by Levenberg-Marquardt (`--fit-solver lm`)", rings_lm});
    FitOptions converged10 = known10;
    converged10.iterations_finest = long_iterations;
    variants.push_back({"exposure known, w_sm = 10, " + its, converged10});
    FitOptions converged = known30;
    converged.iterations_finest = long_iterations;
    variants.push_back({"exposure known, w_sm = 1, " + its, converged});
    for (double w : {0.0, 3.0}) {
      FitOptions other = converged;
      other.objective.w_sm = w;
      variants.push_back({"... w_sm = " + Fixed(w, 0) + ", " + its, other});
    }
    FitOptions none = known;
    none.iterations_finest = 0;
    variants.push_back({"the start alone: the tomography's colour, no iteration", none});
    FitOptions from_truth = converged;
    from_truth.warm_start_density_from_emission = false;
    variants.push_back(
        {"started at the truth, exposure known, w_sm = 1, " + its, from_truth, true});
    // The start that the images cannot improve on (the truth as this grid shows it), and where
    // the fit goes from it, with and without the neighbour term.
    FitOptions from_equivalent = converged;
    from_equivalent.warm_start_density_from_emission = false;
    Variant equivalent_start{"the image-equivalent truth on the fit's grid, no iteration",
                             from_equivalent};
    equivalent_start.options.iterations_finest = 0;
    equivalent_start.start_at_image_equivalent = true;
    variants.push_back(equivalent_start);
    Variant equivalent_fit{"started at the image-equivalent truth, w_sm = 1, " + its,
                           from_equivalent};
    equivalent_fit.start_at_image_equivalent = true;
    variants.push_back(equivalent_fit);
    Variant equivalent_fit0{"started at the image-equivalent truth, w_sm = 0, " + its,
                            from_equivalent};
    equivalent_fit0.options.objective.w_sm = 0;
    equivalent_fit0.start_at_image_equivalent = true;
    variants.push_back(equivalent_fit0);
    FitOptions t_only = converged;
    t_only.vary.density = false;
    t_only.warm_start_density_from_emission = false;
    variants.push_back(
        {"the truth's densities given, temperature fitted from the truth's", t_only, true});

    const TruthError constant = CompareWithTruth(scene.truth, truth_on_grid);
    md << "### " << spec.name << ", " << spec.width << "x" << spec.height
       << ": the truth's spread (the best constant's RMS) " << Fixed(constant.truth_spread_k, 0)
       << " K, emission-weighted " << Fixed(constant.weighted_truth_spread_k, 0)
       << " K; the truth on the fit's grid scores RMS " << Fixed(constant.rms_k, 0)
       << " K as a box filter of temperature and "
       << Fixed(CompareWithTruth(scene.truth, image_equivalent).rms_k, 0)
       << " K as the temperatures its voxels' light shows (the grid's own limit). The box "
          "filter's limit against a truth of "
       << 2 * spec.truth_resolution << ":";
    {
      // The grid's own limit at finer fits, scored against a truth twice as fine.
      synthetic::FireOptions fo;
      fo.kind = spec.kind;
      fo.seed = spec.seed;
      fo.peak_temperature_k = spec.peak_k;
      fo.peak_soot_volume_fraction = spec.soot;
      FireVolume fine = synthetic::MakeFire(
          GridGeometry::FromBox(spec.box, 2 * spec.truth_resolution), fo, scene.absorption);
      fine.emission_rgb = synthetic::ThinEmissionRgb(fine, scene.absorption);
      const char* sep = " ";
      for (int r : {spec.fit_resolution, spec.fit_resolution * 3 / 2, spec.fit_resolution * 2}) {
        const GridGeometry g = GridGeometry::FromBox(spec.box, r);
        md << sep << Fixed(CompareWithTruth(fine, TruthOnGrid(fine, g)).rms_k, 0) << " K at " << r;
        sep = ", ";
      }
    }
    md << ".\n\n";
    md << "| oracle | seconds | iterations | stopped by | exposure / true | Delta E fitted | Delta "
          "E held out | T RMS K | bias K | emission-weighted RMS K | correlation | fitted spread K "
          "| visible voxels with medium | determined: share / T RMS / the rest's K |\n";
    md << "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
    auto row = [&](const std::string& name, const FitResult& r, double seconds, const Scene& on,
                   const std::vector<FitView>& views, const std::vector<FitView>& held_views) {
      const TruthError t = CompareWithTruth(on.truth, r.volume);
      const auto delta_e = FireDeltaE(r, views, held_views, on.absorption);
      md << "| " << name << " | " << Fixed(seconds, 1) << " | " << r.iterations << " | "
         << ToString(r.termination) << " | " << Fixed(r.exposure / on.exposure, 3) << " | "
         << Fixed(delta_e.first, 2) << " | " << Fixed(delta_e.second, 2) << " | "
         << Fixed(t.rms_k, 0) << " | " << Fixed(t.mean_k, 0) << " | " << Fixed(t.weighted_rms_k, 0)
         << " | " << Fixed(t.correlation, 2) << " | " << Fixed(t.fit_spread_k, 0) << " | "
         << t.counted << " / " << t.visible << " | " << DeterminedCell(t) << " |\n";
      if (log)
        log("accuracy: " + spec.name + ": " + name + ": " + Fixed(seconds, 1) + " s, T RMS " +
            Fixed(t.rms_k, 0) + " K, bias " + Fixed(t.mean_k, 0) + " K");
    };
    // The oracles' weights as labelled, on the scene's own grid (64, or 16 with --quick): not
    // scaled from 64 (FitOptions::neighbour_weight_resolution).
    const int grid_n = scene.fit_grid.dims.maxCoeff();
    for (Variant v : variants) {
      v.options.neighbour_weight_resolution = grid_n;
      v.options.estimate_uncertainty = true;  // as `run` and `fit` do
      const auto start = Clock::now();
      FitResult warm;
      if (v.start_at_truth || v.start_at_image_equivalent) {
        warm.volume = v.start_at_truth ? truth_on_grid : image_equivalent;
        warm.exposure = scene.exposure;
      }
      const bool warm_start = v.start_at_truth || v.start_at_image_equivalent;
      const FitResult r = FastFit(scene.fit_grid, scene.tomography, fitted, scene.absorption,
                                  v.options, warm_start ? &warm : nullptr);
      row(v.name, r, Since(start), scene, fitted, held);
    }
    {
      FitOptions o = converged;
      o.neighbour_weight_resolution = grid_n;
      o.known_exposure = clean.exposure;
      o.estimate_uncertainty = true;
      const auto start = Clock::now();
      const FitResult r =
          FastFit(clean.fit_grid, clean.tomography, clean_fitted, clean.absorption, o);
      row("noise-free, unsaturated images, exposure known, w_sm = 1, " + its, r, Since(start),
          clean, clean_fitted, Views(clean, true));
    }
    md << "\n";
  }
  md << FinerGridSection(specs.back(), log);
  return md.str();
}

}  // namespace flamerig
