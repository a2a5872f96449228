// flamerig: one binary, subcommands. Run `flamerig help` for the list.
#include <signal.h>
#include <tbb/global_control.h>

#include <yaml-cpp/yaml.h>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "core/error.h"
#include "acquisition/capture.h"
#include "acquisition/control.h"
#include "acquisition/netns.h"
#include "acquisition/recording.h"
#include "core/srgb.h"
#include "fitting/fit.h"
#include "fitting/renderer.h"
#include "tomography/reconstruct.h"
#include "tomography/vdb_io.h"
#include "tools/benchmark.h"
#include "pipeline/calibrate_job.h"
#include "pipeline/export.h"
#include "pipeline/fit_report.h"
#include "pipeline/run.h"
#include "pipeline/distributed.h"
#include "pipeline/run_report.h"
#include "pipeline/scene_job.h"
#include "pipeline/simulate.h"
#include "tools/soak.h"

namespace fs = std::filesystem;
using namespace flamerig;

namespace {

const char* kUsage = R"(flamerig: fire reconstruction from a calibrated multi-camera rig

usage: flamerig <command> [options]

commands:
  simulate --config FILE --out DIR
        Write a synthetic dataset (rig, camera models, fire images, calibration board images,
        ground-truth .vdb) from a simulation config such as config/sim_rig.yaml.
  render --rig RIG.yaml --volume V.vdb --out DIR [--exposure S|auto] [--absorption soot|grey]
         [--step VOXELS]
        Render every rig camera's view of a temperature/density volume to DIR/<camera>.png.
  render --scene SCENE.yaml --out DIR [--volume V.vdb] [--samples N] [--seed N]
         [--lighting fire|point|sphere|compare] [--threads N]
        Fitted fires lighting a virtual scene (config/scene_candle.yaml): the fire's own emission
        lights the surfaces (soft shadows, no placed light); DIR/fire.exr (linear HDR), fire.png
        (Reinhard 2002 tone mapping), fire_linear.png; --lighting compare adds the usual point and
        sphere lights coloured like the hottest voxel, side by side in compare.png.
  reconstruct --rig RIG.yaml --images DIR --out E.vdb [--exposure S] [--resolution N]
              [--solver sart|cgls] [--iterations N] [--holdout CAMERA] [--cache DIR] [--no-coarse]
              [--truth T.vdb] [--preview P.png]
        Algebraic tomography of one frame set (DIR/<camera>.png for every rig camera) into an RGB
        emission volume. The exposure defaults to the one in dataset.yaml beside the rig, else 1.
        With --truth, report the error against a ground-truth volume's emission.
  fit --rig RIG.yaml --images DIR --out F.vdb [--views CAM,CAM] [--holdout CAMERA]
      [--resolution N] [--tomography E.vdb] [--method fast|alg1|alg2] [--absorption soot|grey]
      [--exposure S] [--w-sm W] [--iterations N] [--time-limit S] [--report DIR] [--truth T.vdb]
      [--coarse-to-fine]
        Fit temperature, density and exposure so that rendering reproduces the images: the fast
        fit (default) or the paper's Algorithm 1 or 2. The tomography is reconstructed from the
        fitted views unless given. Writes F.vdb (temperature, density; exposure in metadata) and a
        report (input, rendered and Delta E images per view and held-out view, error against time).
  run (--recording DIR | --seq A.seq,B.seq [--names CAM,CAM] | --images DIR)
      (--rig RIG.yaml | --calibration-recording DIR | --calibration-images DIR [--board B.yaml]
       [--calibrate-config C.yaml]) --out OUT [--first N] [--count N] [--resolution N]
      [--exposure S] [--absorption soot|grey] [--iterations N] [--holdout CAMERA] [--truth DIR]
      [--no-skip-unchanged] [--no-blender] [--cold] [--threads N]
        The daily job: every frame set of a recording through tomography and the fit (warm
        started from the previous frame) into OUT/frame_NNNNNN.vdb, a Blender-ready sequence in
        OUT/blender/, a summary line per frame and OUT/report/index.html. Stopped runs resume at
        the first frame without a complete output. Under `mpirun -n N` the frames are split into
        contiguous runs per rank. --truth: ground-truth volumes of a simulated recording.
  capture --config RIG.yaml [--record NAME | --event NAME] [--duration S]
        Run the capture daemon: open the cameras of the config (see config/capture_sim.yaml),
        stream, assemble frame sets and serve the control API (`flamerig ctl`). --record starts
        recording into data_dir/NAME at once; --event saves the pre-trigger ring first;
        --duration stops after S seconds (else: Ctrl-C or `flamerig ctl shutdown`).
  ctl [--config RIG.yaml | --endpoint unix:PATH|tcp:HOST:PORT] REQUEST... [--out FILE]
        Talk to a running daemon: status, cameras, arm, disarm, configure CAMERA KEY VALUE,
        start NAME, stop, event NAME, preview CAMERA [K] (PNG to --out), shutdown.
  calibrate (--images DIR | --recording DIR) --out DIR [--config calibrate.yaml] [--board B.yaml]
        Calibrate the rig from views of a board (DIR/<view>/<camera>.png, as `simulate` writes
        calibration/ and `export` writes frame sets, or a recording): board detection (cached),
        one joint mrcal solve, the rig (OUT/rig.yaml + cameras/*.cameramodel), and a report
        (OUT/report.md with coverage and rig pictures). Config: config/calibrate_sim.yaml.
  export (--recording DIR | --seq A.seq,B.seq [--names CAM,CAM]) --out DIR [--first N] [--count N]
        Write a recording's (or StreamPix sequences') frame sets as DIR/frame_NNNNNN/<camera>.png
        (the layout reconstruct and fit read) and DIR/sets.csv; reports what a recovered recording
        left out.
  benchmark render|tomography|fit|capture|calibration|run|scene|soak [--out BENCHMARKS.md] [--quick] [--figures DIR]
            [--seconds S] [--segment-seconds S]
        Time the forward renderer, the tomography or the fit (ours against the paper's
        Algorithm 2) against its error, or sustained recording from simulated and Aravis fake
        cameras against the disk's bandwidth, or the calibration of a simulated ring against
        mrcal-calibrate-cameras, and write the figures to BENCHMARKS.md, plots to
        DIR (default benchmarks/) (--quick: a small smoke run). soak: S seconds (default 600) of
        capture with faults injected, a new recording every --segment-seconds (default 300).
  help  This text.

Errors name the file, the field and the rule; the exit status is non-zero.
)";


// --key value pairs after the command; flags without a value get "1". A value that starts with
// "--" (a forgotten value), an option given twice, or more words than the command takes
// (`max_positional`) is a UsageError naming it.
struct Args {
  std::vector<std::string> positional;
  std::map<std::string, std::string> named;
  std::vector<std::string> original;  // argv[1..]: the command line, to run it again

  Args(int argc, char** argv, int first, const std::vector<std::string>& flags,
       std::size_t max_positional = 0) {
    for (int i = 1; i < argc; ++i) original.push_back(argv[i]);
    for (int i = first; i < argc; ++i) {
      std::string a = argv[i];
      if (a.rfind("--", 0) == 0) {
        std::string key = a.substr(2);
        if (named.count(key)) throw UsageError("option --" + key + " is given twice");
        bool is_flag = std::find(flags.begin(), flags.end(), key) != flags.end();
        if (is_flag) {
          named[key] = "1";
        } else {
          if (i + 1 >= argc) throw UsageError("option --" + key + " needs a value");
          const std::string value = argv[++i];
          if (value.rfind("--", 0) == 0)
            throw UsageError("option --" + key + " needs a value, got the option " + value);
          named[key] = value;
        }
      } else {
        if (positional.size() >= max_positional)
          throw UsageError("unexpected argument '" + a + "' (options are --key value)");
        positional.push_back(a);
      }
    }
  }
  std::string Required(const std::string& key) const {
    auto it = named.find(key);
    if (it == named.end()) throw UsageError("missing required option --" + key);
    return it->second;
  }
  std::string Get(const std::string& key, const std::string& fallback) const {
    auto it = named.find(key);
    return it == named.end() ? fallback : it->second;
  }
  void CheckKnown(const std::vector<std::string>& known) const {
    for (const auto& [k, v] : named) {
      if (std::find(known.begin(), known.end(), k) == known.end()) {
        throw UsageError("unknown option --" + k);
      }
    }
  }
};

double ParseNumber(const std::string& text, const std::string& what) {
  try {
    std::size_t used = 0;
    double v = std::stod(text, &used);
    if (used != text.size()) throw InputError("");
    return v;
  } catch (const std::exception&) {
    throw UsageError(what + " '" + text + "' is not a number");
  }
}

// A whole number in [min, max] (finite; 2.5, nan and 1e30 are refused), naming the option.
std::int64_t ParseInteger(const std::string& text, const std::string& what, std::int64_t min,
                          std::int64_t max) {
  const double v = ParseNumber(text, what);
  if (!(v >= double(min) && v <= double(max)) || v != std::floor(v))
    throw UsageError(what + " '" + text + "' must be a whole number in [" + std::to_string(min) +
                     ", " + std::to_string(max) + "]");
  return static_cast<std::int64_t>(v);
}

// A finite number > 0 (exposures, durations), naming the option.
double ParsePositive(const std::string& text, const std::string& what) {
  const double v = ParseNumber(text, what);
  if (!(std::isfinite(v) && v > 0))
    throw UsageError(what + " '" + text + "' must be finite and > 0");
  return v;
}

// An input file given with --key exists, checked before the work that would need it at the end.
void CheckInputFile(const Args& args, const std::string& key) {
  if (!args.named.count(key)) return;
  const std::string path = args.Get(key, "");
  if (!fs::is_regular_file(path)) throw InputError(path + " (--" + key + "): no such file");
}

constexpr std::int64_t kMaxFrames = std::int64_t(1) << 48;  // frame indices and counts

void ProgressBar(const std::string& stage, int done, int total) {
  const int width = 30;
  int filled = total > 0 ? width * done / total : width;
  std::fprintf(stderr, "\r%-20s [%s%s] %d/%d", stage.c_str(), std::string(filled, '#').c_str(),
               std::string(width - filled, '.').c_str(), done, total);
  if (done >= total) std::fprintf(stderr, "\n");
  std::fflush(stderr);
}

int Simulate(const Args& args) {
  args.CheckKnown({"config", "out"});
  SimulateConfig config = SimulateConfig::Load(args.Required("config"));
  std::string out = args.Required("out");
  SimulateSummary s = Simulate(config, out, Observe([](const Progress& p) {
    ProgressBar(p.stage, static_cast<int>(p.done), static_cast<int>(p.total));
  }));
  std::printf("simulate: wrote %s\n", out.c_str());
  std::printf(
      "  %d camera(s), %d frame(s) of a %s fire, grid %d along the longest axis, %s absorption\n",
      s.cameras, s.frames, synthetic::ToString(config.fire.kind), config.grid_resolution,
      config.absorption.c_str());
  std::printf("  exposure %.6g (%s); %.2f%% of fire pixels saturated at frame 0\n", s.exposure,
              s.exposure_source.c_str(), 100 * s.saturated_pixel_fraction);
  std::printf("  calibration: %d board views, %d images\n", s.calibration_views,
              s.calibration_images);
  std::printf("  last render: %s\n", s.last_render.BriefReport().c_str());
  std::printf("  preview: %s/preview.png; %.2f s in all\n", out.c_str(), s.time_s);
  return 0;
}

// `flamerig render --scene`: fires lighting a scene (pipeline/scene_job.h).
int RenderScene(const Args& args) {
  args.CheckKnown({"scene", "out", "volume", "samples", "lighting", "seed", "threads"});
  // The numbers first: a bad one is reported before the scene is loaded.
  const std::int64_t samples = args.named.count("samples")
                                   ? ParseInteger(args.Get("samples", ""), "--samples", 1, 1 << 20)
                                   : 0;
  const std::int64_t seed = args.named.count("seed") ? ParseInteger(args.Get("seed", ""), "--seed",
                                                                    0, std::int64_t(1) << 53)
                                                     : -1;
  const std::int64_t threads =
      args.named.count("threads") ? ParseInteger(args.Get("threads", ""), "--threads", 1, 4096) : 0;
  // --volume: the same fire placement with another volume (a frame of a run, say).
  SceneJob job = SceneJob::Load(args.Required("scene"), args.Get("volume", ""));
  if (samples > 0) {
    job.render.samples_per_pixel = static_cast<int>(samples);
    job.render.Validate();
  }
  if (seed >= 0) job.render.seed = static_cast<std::uint64_t>(seed);
  if (args.named.count("lighting")) {
    job.compare = args.Get("lighting", "") == "compare";
    if (!job.compare) job.render.lighting = SceneLightingFromName(args.Get("lighting", ""));
  }
  std::unique_ptr<tbb::global_control> limit;
  if (threads > 0)
    limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                  static_cast<std::size_t>(threads));
  std::string stage;
  auto progress = [&](const SceneProgress& p) {
    ProgressBar("render", p.samples_done, p.samples_total);
  };
  const SceneJobResult r = RunSceneJob(job, args.Required("out"), progress);
  for (const auto& summary : r.renders) std::printf("render: %s\n", summary.BriefReport().c_str());
  for (const auto& f : r.files) std::printf("  %s\n", f.c_str());
  return 0;
}

int Render(const Args& args) {
  if (args.named.count("scene")) return RenderScene(args);
  args.CheckKnown({"rig", "volume", "out", "exposure", "absorption", "step"});
  Rig rig = Rig::Load(args.Required("rig"));
  FireVolume volume = ReadVdb(args.Required("volume"));
  if (volume.temperature_k.empty() || volume.density_per_m3.empty()) {
    throw InputError(args.Required("volume") +
                                ": needs both 'temperature' and 'density' grids to render");
  }
  std::string absorption_name = args.Get("absorption", "");
  if (absorption_name.empty()) {
    auto it = volume.metadata_text.find("absorption_model");
    absorption_name = it != volume.metadata_text.end() ? it->second : "soot";
  }
  RenderOptions options;
  if (args.named.count("step")) options.step_voxels = ParseNumber(args.Get("step", ""), "--step");
  FireRenderer renderer(AbsorptionModel::FromName(absorption_name), options);
  renderer.SetVolume(volume.geometry, volume.temperature_k, volume.density_per_m3);
  std::string exposure_text = args.Get("exposure", "auto");
  double exposure = 1.0;
  if (exposure_text == "auto") {
    auto it = volume.metadata_numbers.find("exposure");
    exposure = it != volume.metadata_numbers.end() ? it->second : 1.0;
  } else {
    exposure = ParsePositive(exposure_text, "--exposure");
  }
  std::string out = args.Required("out");
  fs::create_directories(out);
  for (const auto& camera : rig.cameras) {
    CameraRays rays(camera.model);
    ImageF linear;
    RenderSummary summary = renderer.Render(rays, &linear);
    std::string path = (fs::path(out) / (camera.name + ".png")).string();
    WritePng(path, ApplyCameraResponse(linear, exposure));
    std::printf("%s: %s\n", path.c_str(), summary.BriefReport().c_str());
  }
  return 0;
}

// One frame set: DIR/<camera>.png for every rig camera, 8-bit sRGB as the camera wrote it or
// 16-bit linear (value / 65535 is the linear signal). A missing file leaves that camera out with a
// note (its entries stay empty). images8: 8-bit sRGB views of every input (16-bit ones encoded).
void ReadFrameSet(const Rig& rig, const std::string& dir, double exposure, const char* command,
                  std::vector<ImageU8>* images8, std::vector<LinearFrame>* frames) {
  images8->assign(rig.cameras.size(), ImageU8());
  frames->assign(rig.cameras.size(), LinearFrame());
  for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
    const fs::path path = fs::path(dir) / (rig.cameras[c].name + ".png");
    if (!fs::exists(path)) {
      std::fprintf(stderr, "%s: no image for camera '%s' (%s): camera left out\n", command,
                   rig.cameras[c].name.c_str(), path.c_str());
      continue;
    }
    ImageU8 image8;
    ImageU16 image16;
    try {
      const int bits = ReadImage(path.string(), &image8, &image16, 3);
      DecodeCameraImage(image8, image16, bits, exposure, &(*images8)[c], &(*frames)[c]);
    } catch (const InputError& e) {
      throw InputError(path.string() + ": " + e.what());
    }
  }
}

std::vector<std::string> SplitList(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ','))
    if (!item.empty()) out.push_back(item);
  return out;
}

int Reconstruct(const Args& args) {
  args.CheckKnown({"rig", "images", "out", "exposure", "resolution", "solver", "iterations",
                   "holdout", "cache", "no-coarse", "truth", "preview"});
  CheckInputFile(args, "truth");
  const std::string rig_path = args.Required("rig");
  ReconstructOptions options;
  std::string exposure_source = "default 1";
  if (args.named.count("exposure")) {
    options.exposure = ParsePositive(args.Get("exposure", ""), "--exposure");
    exposure_source = "--exposure";
  } else if (DatasetExposure(rig_path, &options.exposure)) {
    exposure_source = "dataset.yaml";
  }
  if (args.named.count("resolution"))
    options.resolution =
        static_cast<int>(ParseInteger(args.Get("resolution", ""), "--resolution", 1, 1024));
  if (args.named.count("solver"))
    options.solve.solver = TomographySolverFromName(args.Get("solver", ""));
  if (args.named.count("iterations")) {
    options.solve.max_iterations =
        static_cast<int>(ParseInteger(args.Get("iterations", ""), "--iterations", 1, 100000));
  }
  options.holdout_camera = args.Get("holdout", "");
  options.cache_dir = args.Get("cache", "");
  options.coarse_to_fine = args.named.count("no-coarse") == 0;
  Rig rig = Rig::Load(rig_path);  // after the options: a bad number is reported before any I/O
  std::vector<ImageU8> images;    // 8-bit views of the inputs, for the preview
  std::vector<LinearFrame> frames;
  ReadFrameSet(rig, args.Required("images"), options.exposure, "reconstruct", &images, &frames);
  Reconstructor reconstructor(rig, options);
  ReconstructSummary summary;
  FireVolume volume = reconstructor.Reconstruct(frames, &summary);
  volume.metadata_text["exposure_source"] = exposure_source;
  const std::string out = args.Required("out");
  if (fs::path(out).has_parent_path()) fs::create_directories(fs::path(out).parent_path());
  WriteVdb(out, volume);
  if (args.named.count("preview")) {
    // Each camera: its input, the reconstruction rendered back through it, and 4x their difference.
    std::vector<ImageU8> tiles;
    for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
      if (images[c].empty()) continue;
      ImageU8 rendered =
          ApplyCameraResponse(RenderThinEmission(volume.geometry, volume.emission_rgb,
                                                 CameraRays(rig.cameras[c].model)),
                              options.exposure);
      ImageU8 difference(rendered.width, rendered.height, 3);
      const ImageU8& input = images[c];
      for (std::size_t p = 0; p < difference.pixels.size(); ++p) {
        const int a = input.channels == 3 ? input.pixels[p] : input.pixels[p / 3];
        difference.pixels[p] =
            static_cast<std::uint8_t>(std::min(255, 4 * std::abs(a - rendered.pixels[p])));
      }
      tiles.push_back(input);
      tiles.push_back(rendered);
      tiles.push_back(difference);
    }
    WritePng(args.Get("preview", ""), ContactSheet(tiles, 240));
    std::printf("  preview (input, reconstruction rendered back, 4x difference per camera): %s\n",
                args.Get("preview", "").c_str());
  }
  std::printf("reconstruct: wrote %s (exposure %.6g from %s)\n  %s\n", out.c_str(),
              options.exposure, exposure_source.c_str(), summary.BriefReport().c_str());
  if (args.named.count("truth")) {
    FireVolume truth = ReadVdb(args.Get("truth", ""));
    if (truth.emission_rgb.empty())
      throw InputError(args.Get("truth", "") + ": has no 'emission' grid");
    std::vector<float> t =
        truth.geometry.SameVoxels(volume.geometry)
            ? truth.emission_rgb
            : ResampleEmission(truth.geometry, truth.emission_rgb, volume.geometry);
    double num = 0, den = 0;
    for (std::size_t i = 0; i < t.size(); ++i) {
      num += (double(volume.emission_rgb[i]) - t[i]) * (double(volume.emission_rgb[i]) - t[i]);
      den += double(t[i]) * t[i];
    }
    std::printf("  volume error against %s: relative L2 %.4f\n", args.Get("truth", "").c_str(),
                den > 0 ? std::sqrt(num / den) : 0.0);
  }
  return 0;
}

int Benchmark(const Args& args) {
  const std::string target = args.positional.empty() ? "" : args.positional[0];
  if (target.empty()) {
    throw InputError(
        "benchmark needs a target: render, tomography, fit, capture, calibration, run, scene or "
        "soak");
  }
  args.CheckKnown({"out", "quick", "figures", "seconds", "segment-seconds"});
  auto log = [](const std::string& line) { std::fprintf(stderr, "%s\n", line.c_str()); };
  std::string md;
  if (target == "render") {
    RenderBenchmarkOptions options;
    options.quick = args.named.count("quick") > 0;
    md = RunRenderBenchmark(options, log);
  } else if (target == "tomography") {
    TomographyBenchmarkOptions options;
    options.quick = args.named.count("quick") > 0;
    md = RunTomographyBenchmark(options, log);
  } else if (target == "fit") {
    FitBenchmarkOptions options;
    options.quick = args.named.count("quick") > 0;
    if (args.named.count("figures")) options.figure_dir = args.Get("figures", "");
    md = RunFitBenchmark(options, log);
  } else if (target == "capture") {
    CaptureBenchmarkOptions options;
    options.quick = args.named.count("quick") > 0;
    if (args.named.count("seconds"))
      options.seconds = ParseNumber(args.Get("seconds", ""), "--seconds");
    // The Aravis scenario needs 127.0.0.2..5: rerun this command in a private network namespace.
    std::vector<std::string> command = {fs::read_symlink("/proc/self/exe").string()};
    command.insert(command.end(), args.original.begin(), args.original.end());
    RerunInLoopbackNamespace(command);
    md = RunCaptureBenchmark(options, log);
  } else if (target == "soak") {
    SoakOptions options;
    options.binary = fs::read_symlink("/proc/self/exe").string();
    options.directory = ".flamerig_soak";
    options.seconds = args.named.count("seconds")
                          ? ParseNumber(args.Get("seconds", ""), "--seconds")
                          : (args.named.count("quick") ? 10 : 600);
    options.segment_seconds =
        args.named.count("segment-seconds")
            ? ParseNumber(args.Get("segment-seconds", ""), "--segment-seconds")
            : 300;
    md = RunSoakBenchmark(options, log);
  } else if (target == "scene") {
    SceneBenchmarkOptions options;
    options.quick = args.named.count("quick") > 0;
    md = RunSceneBenchmark(options, log);
  } else if (target == "run") {
    RunBenchmarkOptions options;
    options.quick = args.named.count("quick") > 0;
    md = RunRunBenchmark(options, log);
  } else if (target == "calibration") {
    CalibrationBenchmarkOptions options;
    options.quick = args.named.count("quick") > 0;
    md = RunCalibrationBenchmark(options, log);
  } else {
    throw InputError(
        "benchmark target '" + target +
        "': use render, tomography, fit, capture, calibration, run, scene or soak");
  }
  std::string out = args.Get("out", "BENCHMARKS.md");
  WriteBenchmarkSection(out, target, md);
  std::printf("%s\nwritten to %s\n", md.c_str(), out.c_str());
  return 0;
}

int Fit(const Args& args) {
  args.CheckKnown({"rig", "images", "out", "views", "holdout", "resolution", "tomography", "method",
                   "absorption", "exposure", "w-sm", "time-limit", "iterations", "report", "truth",
                   "seed", "coarse-to-fine"});
  CheckInputFile(args, "truth");
  CheckInputFile(args, "tomography");
  const std::string rig_path = args.Required("rig");
  Rig rig = Rig::Load(rig_path);
  double exposure = 1.0;
  if (args.named.count("exposure"))
    exposure = ParsePositive(args.Get("exposure", ""), "--exposure");
  else
    DatasetExposure(rig_path, &exposure);
  const std::string absorption_name = args.Get("absorption", DatasetAbsorption(rig_path));
  const AbsorptionModel absorption = AbsorptionModel::FromName(absorption_name);
  std::vector<ImageU8> images;
  std::vector<LinearFrame> frames;
  ReadFrameSet(rig, args.Required("images"), exposure, "fit", &images, &frames);

  // Views: --views, else every camera with an image but the held-out one.
  const std::string holdout = args.Get("holdout", "");
  std::vector<std::string> view_names = SplitList(args.Get("views", ""));
  auto camera_index = [&](const std::string& name) {
    for (std::size_t c = 0; c < rig.cameras.size(); ++c)
      if (rig.cameras[c].name == name) return static_cast<int>(c);
    throw InputError(rig_path + ": no camera named '" + name + "'");
  };
  if (view_names.empty()) {
    for (std::size_t c = 0; c < rig.cameras.size(); ++c)
      if (!images[c].empty() && rig.cameras[c].name != holdout)
        view_names.push_back(rig.cameras[c].name);
  }
  for (std::size_t i = 0; i < view_names.size(); ++i) {
    if (view_names[i] == holdout)
      throw UsageError("--views and --holdout both name '" + holdout +
                       "': a view is fitted or held out");
    for (std::size_t j = 0; j < i; ++j)
      if (view_names[j] == view_names[i])
        throw UsageError("--views names '" + view_names[i] + "' twice");
  }
  std::vector<std::unique_ptr<CameraRays>> rays(rig.cameras.size());
  auto make_view = [&](const std::string& name) {
    const int c = camera_index(name);
    if (images[c].empty())
      throw InputError("fit: camera '" + name + "' has no image in " +
                                  args.Required("images"));
    if (!rays[c]) rays[c] = std::make_unique<CameraRays>(rig.cameras[c].model);
    FitView v;
    v.name = name;
    v.rays = rays[c].get();
    v.image = images[c];
    return v;
  };
  std::vector<FitView> views, held;
  for (const auto& name : view_names) views.push_back(make_view(name));
  if (!holdout.empty()) held.push_back(make_view(holdout));
  if (views.empty()) throw InputError("fit: no views to fit");

  ReconstructOptions ro;
  ro.exposure = exposure;
  if (args.named.count("resolution"))
    ro.resolution =
        static_cast<int>(ParseInteger(args.Get("resolution", ""), "--resolution", 1, 1024));
  // The tomography: from a file, or reconstructed here from the fitted views only.
  FireVolume tomography;
  if (args.named.count("tomography")) {
    tomography = ReadVdb(args.Get("tomography", ""));
  } else {
    std::vector<LinearFrame> used(rig.cameras.size());
    for (const auto& v : views) used[camera_index(v.name)] = frames[camera_index(v.name)];
    Reconstructor reconstructor(rig, ro);
    ReconstructSummary rs;
    tomography = reconstructor.Reconstruct(used, &rs);
    std::fprintf(stderr, "fit: tomography from %zu view(s): %s\n", views.size(),
                 rs.BriefReport().c_str());
  }
  const GridGeometry grid = GridGeometry::FromBox(rig.box, ro.resolution);

  FitOptions options;
  if (args.named.count("w-sm"))
    options.objective.w_sm = ParseNumber(args.Get("w-sm", ""), "--w-sm");
  if (args.named.count("time-limit"))
    options.time_limit_s = ParseNumber(args.Get("time-limit", ""), "--time-limit");
  const std::string method = args.Get("method", "fast");
  double last_progress = -1;
  auto progress = [&last_progress](const FitProgress& p) {
    if (p.seconds - last_progress < 0.5) return;  // twice a second is enough to watch
    last_progress = p.seconds;
    std::fprintf(stderr, "\r%-60s iteration %4d  %7.1f s  energy %10.4g  mean Delta E %.4f",
                 p.stage.c_str(), p.iteration, p.seconds, p.energy, p.mean_delta_e);
    std::fflush(stderr);
  };
  FitResult result;
  if (method == "fast") {
    if (args.named.count("iterations")) {
      options.iterations_finest = options.iterations_per_level =
          static_cast<int>(ParseInteger(args.Get("iterations", ""), "--iterations", 0, 1000000));
    }
    options.coarse_to_fine = args.named.count("coarse-to-fine") > 0;
    result = FastFit(grid, tomography, views, absorption, options, nullptr, progress);
  } else if (method == "alg1" || method == "alg2") {
    PaperFitOptions paper;
    paper.algorithm =
        method == "alg1" ? PaperAlgorithm::kPerVoxelDensity : PaperAlgorithm::kDensityScale;
    paper.time_limit_s = options.time_limit_s;
    if (args.named.count("iterations"))
      paper.iterations =
          static_cast<int>(ParseInteger(args.Get("iterations", ""), "--iterations", 1, 1000000));
    if (args.named.count("seed"))
      paper.seed = static_cast<std::uint64_t>(
          ParseInteger(args.Get("seed", ""), "--seed", 0, std::int64_t(1) << 53));
    result = PaperFit(grid, tomography, views, absorption, options, paper, progress);
  } else {
    throw InputError("--method '" + method + "': use fast, alg1 or alg2");
  }
  std::fprintf(stderr, "\n");
  result.volume.metadata_text["absorption_model"] = absorption.name();
  const std::string out = args.Required("out");
  if (fs::path(out).has_parent_path()) fs::create_directories(fs::path(out).parent_path());
  WriteVdb(out, result.volume);
  const std::string report = args.Get(
      "report",
      (fs::path(out).parent_path() / (fs::path(out).stem().string() + "_report")).string());
  const auto scores = WriteFitReport(report, result, views, held, absorption, options.render,
                                     "flamerig fit (" + method + ")");
  std::printf("fit: wrote %s\n  %s\n", out.c_str(), result.BriefReport().c_str());
  for (const auto& sc : scores) {
    std::printf(
        "  %s (%s): mean Delta E %.3f over all pixels, %.3f over fire pixels (95th "
        "percentile %.2f)\n",
        sc.name.c_str(), sc.held_out ? "held out" : "fitted", sc.mean_delta_e, sc.fire_delta_e,
        sc.p95_delta_e);
  }
  std::printf("  report: %s/report.md\n", report.c_str());
  if (args.named.count("truth")) {
    const FireVolume truth = ReadVdb(args.Get("truth", ""));
    const TruthError t = CompareWithTruth(truth, result.volume);
    if (!t.compared) {
      std::printf("  truth: %s not compared: %s\n", args.Get("truth", "").c_str(),
                  t.why_not.c_str());
    } else if (t.counted) {
      std::printf(
          "  temperature against %s on the %zu of %zu visible voxels (>= 1300 K, >= 1%% "
          "of the peak emission) with medium: RMS %.1f K, mean %+.1f K\n",
          args.Get("truth", "").c_str(), t.counted, t.visible, t.rms_k, t.mean_k);
    }
  }
  return 0;
}

// `flamerig run`: see pipeline/run.h (and pipeline/distributed.h under mpirun).
int Run(const Args& args, MpiSession& mpi) {
  args.CheckKnown({"recording",
                   "seq",
                   "names",
                   "images",
                   "rig",
                   "calibration-recording",
                   "calibration-images",
                   "board",
                   "calibrate-config",
                   "out",
                   "first",
                   "count",
                   "resolution",
                   "exposure",
                   "absorption",
                   "iterations",
                   "holdout",
                   "truth",
                   "no-skip-unchanged",
                   "no-blender",
                   "threads",
                   "cold"});
  RunOptions o;
  o.source.recording_dir = args.Get("recording", "");
  o.source.seq_files = SplitList(args.Get("seq", ""));
  o.source.seq_names = SplitList(args.Get("names", ""));
  o.source.images_dir = args.Get("images", "");
  o.rig_path = args.Get("rig", "");
  o.calibration.recording_dir = args.Get("calibration-recording", "");
  o.calibration.images_dir = args.Get("calibration-images", "");
  if (args.named.count("calibrate-config"))
    o.calibrate = CalibrateConfig::Load(args.Get("calibrate-config", ""));
  if (args.named.count("board")) o.calibrate.board = LoadBoardSpec(args.Get("board", ""));
  o.out_dir = args.Required("out");
  auto integer = [&](const std::string& key, std::int64_t min, std::int64_t max) {
    return static_cast<std::size_t>(ParseInteger(args.Get(key, ""), "--" + key, min, max));
  };
  if (args.named.count("first")) o.first = integer("first", 0, kMaxFrames);
  if (args.named.count("count")) o.count = integer("count", 1, kMaxFrames);
  if (args.named.count("resolution"))
    o.reconstruct.resolution = static_cast<int>(integer("resolution", 1, 1024));
  if (args.named.count("exposure"))
    o.exposure = ParsePositive(args.Get("exposure", ""), "--exposure");
  o.absorption = args.Get("absorption", "");
  if (args.named.count("iterations"))
    o.fit.iterations_finest = static_cast<int>(integer("iterations", 0, 1000000));
  o.holdout_camera = args.Get("holdout", "");
  o.truth_dir = args.Get("truth", "");
  o.skip_unchanged = args.named.count("no-skip-unchanged") == 0;
  o.blender = args.named.count("no-blender") == 0;
  o.warm_start = args.named.count("cold") == 0;
  // Threads: --threads, else under mpirun the cores shared among this node's ranks.
  std::size_t threads = 0;
  if (args.named.count("threads")) {
    threads = integer("threads", 1, 4096);
  } else if (mpi.ranks_on_this_node() > 1) {
    threads = std::max<std::size_t>(
        1, std::thread::hardware_concurrency() / static_cast<unsigned>(mpi.ranks_on_this_node()));
  }
  std::unique_ptr<tbb::global_control> limit;
  if (threads)
    limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                  threads);
  o.Validate();
  const auto start = std::chrono::steady_clock::now();
  const std::string who = mpi.size() > 1 ? "[rank " + std::to_string(mpi.rank()) + "] " : "";
  // Rank 0 prepares the rig (it may calibrate) while the others wait.
  std::string rig_path;
  if (mpi.rank() == 0) {
    fs::create_directories(o.out_dir);
    rig_path = PrepareRig(o, ProgressBar);
  }
  mpi.Barrier();
  if (mpi.rank() != 0) rig_path = PrepareRig(o);
  std::size_t begin, end;
  {
    const FrameSource source(o.source, Rig::Load(rig_path));
    if (mpi.rank() == 0)
      for (const auto& note : source.notes()) std::fprintf(stderr, "run: %s\n", note.c_str());
    RunRange(o, source, &begin, &end);
  }
  std::size_t mine_begin, mine_end;
  RankFrames(begin, end, mpi.rank(), mpi.size(), &mine_begin, &mine_end);
  std::fprintf(stderr, "%srun: frames %zu..%zu of %s through %s into %s\n", who.c_str(), mine_begin,
               mine_end - 1, o.source.Describe().c_str(), rig_path.c_str(), o.out_dir.c_str());
  const bool bar = mpi.rank() == 0;
  auto progress = [&](const RunProgress& p) {
    if (bar) std::fprintf(stderr, "\r%-78s\r", "");
    if (p.last) std::fprintf(stderr, "%s%s\n", who.c_str(), p.last->Line().c_str());
    if (!bar) return;
    const int width = 30;
    const int filled = p.total ? static_cast<int>(width * p.done / p.total) : width;
    std::fprintf(stderr, "%srun [%s%s] %zu/%zu frames, %.1f frames/min, %.0f s left", who.c_str(),
                 std::string(filled, '#').c_str(), std::string(width - filled, '.').c_str(), p.done,
                 p.total, p.elapsed_s > 0 ? 60.0 * p.done / p.elapsed_s : 0.0, p.eta_s);
    if (p.done >= p.total) std::fprintf(stderr, "\n");
    std::fflush(stderr);
  };
  RunSummary summary;
  if (mine_begin < mine_end) summary = RunFrames(o, rig_path, mine_begin, mine_end, progress);
  std::printf("%srun: %s\n", who.c_str(), summary.BriefReport().c_str());
  std::fflush(stdout);
  // Every rank's summaries to rank 0, which writes the one report.
  std::string mine;
  for (const auto& f : summary.frames) mine += f.ToYaml() + '\0';
  const std::vector<std::string> all = mpi.Gather(mine);
  if (mpi.rank() != 0) return 0;
  std::vector<FrameSummary> frames;
  for (const auto& text : all) {
    std::size_t at = 0;
    while (at < text.size()) {
      const std::size_t stop = text.find('\0', at);
      frames.push_back(FrameSummary::FromYaml(text.substr(at, stop - at), "a rank's summary"));
      at = stop + 1;
    }
  }
  std::sort(frames.begin(), frames.end(),
            [](const FrameSummary& a, const FrameSummary& b) { return a.frame < b.frame; });
  RunReportInfo info;
  info.source = o.source.Describe();
  info.rig_path = rig_path;
  info.truth_dir = o.truth_dir;
  info.ranks = mpi.size();
  info.wall_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const std::string report = WriteRunReport(o.out_dir, frames, info);
  std::printf("run: report %s\n", report.c_str());
  std::size_t failed = 0;
  for (const auto& f : frames) failed += f.status.rfind("failed", 0) == 0;
  if (failed) {
    // The other frames are written; a script must still see that this run is not complete.
    std::fprintf(stderr,
                 "flamerig run: %zu of %zu frame(s) failed (their lines above, OUT/frames)\n",
                 failed, frames.size());
    return 1;
  }
  return 0;
}

std::atomic<bool> g_interrupted{false};
void OnSignal(int) { g_interrupted = true; }

int Capture(const Args& args) {
  args.CheckKnown({"config", "record", "event", "duration"});
  // Checked before the cameras start.
  const double duration =
      args.named.count("duration") ? ParsePositive(args.Get("duration", ""), "--duration") : -1;
  if (args.named.count("record") && args.named.count("event"))
    throw UsageError("--record and --event: give one");
  const CaptureConfig config = CaptureConfig::Load(args.Required("config"));
  fs::create_directories(config.data_dir);
  SystemClock clock;
  SimTriggerBus bus;
  CaptureDaemon daemon(config, MakeCameras(config, &clock, &bus), &clock, &bus);
  daemon.Start();
  ControlServer server(&daemon, config.control, config.allow_remote);
  std::fprintf(stderr, "capture: %zu camera(s), %s, control at %s\n", config.cameras.size(),
               ToString(config.sync), config.control.c_str());
  if (args.named.count("event") && config.pretrigger_seconds > 0) {
    // Let the ring fill before the event.
    std::this_thread::sleep_for(std::chrono::duration<double>(config.pretrigger_seconds));
  }
  if (args.named.count("record"))
    std::fprintf(stderr, "capture: recording into %s\n",
                 daemon.StartRecording(args.Get("record", "")).c_str());
  if (args.named.count("event"))
    std::fprintf(stderr, "capture: event, recording into %s\n",
                 daemon.TriggerEvent(args.Get("event", "")).c_str());
  ::signal(SIGINT, OnSignal);
  ::signal(SIGTERM, OnSignal);
  const auto start = std::chrono::steady_clock::now();
  auto elapsed = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  };
  double last_line = 0;
  while (!g_interrupted && !server.shutdown_requested() && (duration < 0 || elapsed() < duration)) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    if (elapsed() - last_line >= 1.0) {
      last_line = elapsed();
      const CaptureStatus s = daemon.status();
      std::string fps;
      for (const auto& c : s.cameras) {
        char b[64];
        std::snprintf(b, sizeof b, " %s %.0f fps%s", c.name.c_str(), c.fps,
                      c.connected ? "" : " (gone)");
        fps += b;
      }
      std::fprintf(
          stderr,
          "\r%6.1f s:%s | sets %llu (%llu incomplete) | recorded %llu, dropped %llu, backlog %.0f "
          "MB   ",
          elapsed(), fps.c_str(), (unsigned long long)s.sets.sets,
          (unsigned long long)s.sets.incomplete, (unsigned long long)s.recorder.sets_recorded,
          (unsigned long long)s.recorder.sets_dropped, s.recorder.queued_bytes / 1048576.0);
      std::fflush(stderr);
      if (s.recorder.stopped && s.recording) {
        std::fprintf(stderr, "\ncapture: %s\n", s.recorder.error.c_str());
        daemon.StopRecording();
      }
    }
  }
  std::fprintf(stderr, "\n");
  const CaptureStatus s = daemon.status();
  if (s.recording) {
    const RecorderStatus r = daemon.StopRecording();
    std::fprintf(stderr, "capture: %s: %llu frame sets recorded, %llu dropped%s%s\n",
                 s.recording_dir.c_str(), (unsigned long long)r.sets_recorded,
                 (unsigned long long)r.sets_dropped, r.error.empty() ? "" : "; ", r.error.c_str());
  }
  // Each camera's story, for the log (and the soak test, which reads the disconnects).
  for (const auto& c : daemon.status().cameras)
    std::fprintf(
        stderr,
        "capture: %s: %llu frames, %llu missing by frame id, %llu incomplete, %llu "
        "disconnects, %llu reconnects%s%s\n",
        c.name.c_str(), (unsigned long long)c.frames, (unsigned long long)c.stream.missing_by_id,
        (unsigned long long)c.stream.incomplete, (unsigned long long)c.disconnects,
        (unsigned long long)c.reconnects, c.error.empty() ? "" : "; last error: ", c.error.c_str());
  daemon.Stop();
  return 0;
}

int Ctl(const Args& args) {
  args.CheckKnown({"config", "endpoint", "out"});
  std::string endpoint = args.Get("endpoint", "");
  if (endpoint.empty()) endpoint = CaptureConfig::Load(args.Required("config")).control;
  if (args.positional.empty()) throw InputError("ctl: give a request (status, ...)");
  std::string line;
  for (const auto& w : args.positional) line += (line.empty() ? "" : " ") + w;
  const ControlReply r = ControlRequest(endpoint, line);
  if (!r.ok) {
    std::fprintf(stderr, "flamerig ctl: the daemon says: %s", r.body.c_str());
    return 1;
  }
  if (args.named.count("out")) {
    std::ofstream out(args.Get("out", ""), std::ios::binary);
    out << r.body;
    if (!out) throw IoError("cannot write " + args.Get("out", ""));
  } else {
    std::fwrite(r.body.data(), 1, r.body.size(), stdout);
  }
  return 0;
}

int Calibrate(const Args& args) {
  args.CheckKnown({"images", "recording", "out", "config", "board"});
  CalibrateConfig config;
  if (args.named.count("config")) config = CalibrateConfig::Load(args.Get("config", ""));
  if (args.named.count("board")) config.board = LoadBoardSpec(args.Get("board", ""));
  CalibrateInput input{args.Get("images", ""), args.Get("recording", "")};
  auto progress = [&](const std::string& stage, int done, int total) {
    ProgressBar(stage, done, total);
  };
  const std::string out = args.Required("out");
  const CalibrationSummary s = RunCalibration(config, input, out, progress);
  std::fprintf(stderr, "%s", s.BriefReport().c_str());
  std::fprintf(stderr, "calibrate: wrote %s/rig.yaml, %s/report.md\n", out.c_str(), out.c_str());
  return 0;
}

int Export(const Args& args) {
  args.CheckKnown({"recording", "seq", "names", "out", "first", "count"});
  ExportOptions o;
  if (args.named.count("first"))
    o.first =
        static_cast<std::size_t>(ParseInteger(args.Get("first", ""), "--first", 0, kMaxFrames));
  if (args.named.count("count"))
    o.count =
        static_cast<std::size_t>(ParseInteger(args.Get("count", ""), "--count", 1, kMaxFrames));
  auto progress = [](std::size_t done, std::size_t total) {
    ProgressBar("export", static_cast<int>(done), static_cast<int>(total));
  };
  if (args.named.count("seq")) {
    const ExportSummary s =
        ExportStreamPix(SplitList(args.Get("seq", "")), SplitList(args.Get("names", "")),
                        args.Required("out"), o, progress);
    std::fprintf(stderr, "export: %zu frame sets, %zu images\n", s.sets, s.images);
    return 0;
  }
  const Recording rec = Recording::Open(args.Required("recording"));
  for (const auto& note : rec.recovery().notes)
    std::fprintf(stderr, "export: recovered recording: %s\n", note.c_str());
  const ExportSummary s =
      ExportRecording(args.Required("recording"), args.Required("out"), o, progress);
  std::fprintf(stderr, "export: %zu frame sets, %zu images, %zu camera frames missing\n", s.sets,
               s.images, s.missing_frames);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2 || !std::strcmp(argv[1], "help") || !std::strcmp(argv[1], "--help") ||
      !std::strcmp(argv[1], "-h")) {
    std::fputs(kUsage, argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  const std::string command = argv[1];
  if (command == "run") {
    // Under mpirun every rank runs this; a failing rank stops the others.
    std::unique_ptr<MpiSession> mpi;
    try {
      mpi = std::make_unique<MpiSession>(&argc, &argv);
      return Run(Args(argc, argv, 2, {"no-skip-unchanged", "no-blender", "cold"}), *mpi);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "flamerig run: error: %s\n", e.what());
      const bool usage = dynamic_cast<const UsageError*>(&e) != nullptr;
      if (mpi && mpi->size() > 1) mpi->Abort(usage ? 2 : 1);
      return usage ? 2 : 1;
    }
  }
  try {
    if (command == "simulate") return Simulate(Args(argc, argv, 2, {}));
    if (command == "render") return Render(Args(argc, argv, 2, {}));
    if (command == "reconstruct") return Reconstruct(Args(argc, argv, 2, {"no-coarse"}));
    if (command == "fit") return Fit(Args(argc, argv, 2, {"coarse-to-fine"}));
    if (command == "benchmark") return Benchmark(Args(argc, argv, 2, {"quick"}, 1));
    if (command == "capture") return Capture(Args(argc, argv, 2, {}));
    if (command == "ctl") return Ctl(Args(argc, argv, 2, {}, 64));
    if (command == "calibrate") return Calibrate(Args(argc, argv, 2, {}));
    if (command == "export") return Export(Args(argc, argv, 2, {}));
    std::fprintf(stderr, "flamerig: unknown command '%s'\n\n%s", command.c_str(), kUsage);
    return 2;
  } catch (const UsageError& e) {
    std::fprintf(stderr, "flamerig %s: error: %s (see flamerig help)\n", command.c_str(), e.what());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "flamerig %s: error: %s\n", command.c_str(), e.what());
    return 1;
  }
}
