// `flamerig benchmark footage` (issue 20): the tomography on frames as a real rig delivers them.
#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "calibration/synthetic_rig.h"
#include "core/error.h"
#include "core/memory.h"
#include "core/srgb.h"
#include "fitting/renderer.h"
#include "fitting/synthetic_fire.h"
#include "pipeline/frame_source.h"
#include "pipeline/simulate.h"
#include "pipeline/subprocess.h"
#include "pipeline/video_codec.h"
#include "tomography/reconstruct.h"
#include "tools/benchmark.h"

namespace flamerig {

namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

// The scene: a fire of licks on the left of the box and a grey, optically thin plume of smoke-like
// light beside it on the right, on an exactly black background.
struct Scene {
  Rig rig;  // the solve cameras, then "holdout"
  GridGeometry truth_grid;
  std::vector<float> truth_emission;  // thin-limit RGB emission on the truth grid
  std::vector<ImageF> linear;         // per camera, linear radiance (self-absorption included)
  double exposure = 1;
};

Scene MakeScene(const Box3& box, int cameras, bool holdout, int width, int height,
                int truth_resolution) {
  Scene s;
  synthetic::RingOptions ring;
  ring.cameras = cameras + (holdout ? 1 : 0);
  ring.width = width;
  ring.height = height;
  ring.distance_m = 0.5;
  ring.elevation_deg = 10;
  for (int v = 0; v < cameras; ++v) ring.azimuths_deg.push_back(180.0 * v / cameras);
  if (holdout) ring.azimuths_deg.push_back(90.0 / cameras);
  s.rig = synthetic::MakeRingRig(box, ring);
  if (holdout) s.rig.cameras.back().name = "holdout";
  s.truth_grid = GridGeometry::FromBox(box, truth_resolution);
  const AbsorptionModel soot = AbsorptionModel::DefaultSoot();
  synthetic::FireOptions fo;
  fo.kind = synthetic::FireKind::kLicks;
  fo.seed = 11;
  fo.peak_temperature_k = 2100;
  fo.peak_soot_volume_fraction = 2e-6;
  const Eigen::Vector3d lo = box.min_in_rig, hi = box.max_in_rig, size = hi - lo;
  fo.region = Box3{lo, lo + Eigen::Vector3d(0.62 * size.x(), size.y(), size.z())};
  const FireVolume fire = synthetic::MakeFire(s.truth_grid, fo, soot);
  s.truth_emission = synthetic::ThinEmissionRgb(fire, soot);
  // The plume: a candle's soot field, standing to the right, glowing grey.
  synthetic::FireOptions po;
  po.kind = synthetic::FireKind::kCandle;
  po.seed = 5;
  po.region = Box3{lo + Eigen::Vector3d(0.58 * size.x(), 0.15 * size.y(), 0.2 * size.z()),
                   lo + Eigen::Vector3d(0.98 * size.x(), 0.95 * size.y(), 0.8 * size.z())};
  const FireVolume plume = synthetic::MakeFire(s.truth_grid, po, soot);
  float peak_density = 0;
  for (float d : plume.density_per_m3) peak_density = std::max(peak_density, d);
  std::vector<float> plume_emission(s.truth_grid.num_voxels() * 3, 0.0f);
  for (std::size_t v = 0; v < s.truth_grid.num_voxels(); ++v)
    for (int c = 0; c < 3; ++c)
      plume_emission[3 * v + c] = peak_density > 0 ? plume.density_per_m3[v] / peak_density : 0;

  FireRenderer renderer(soot);
  renderer.SetVolume(s.truth_grid, fire.temperature_k, fire.density_per_m3);
  std::vector<ImageF> plume_images;
  float plume_peak = 0;
  for (const RigCamera& c : s.rig.cameras) {
    const CameraRays rays(c.model);
    ImageF image;
    renderer.Render(rays, &image);
    s.linear.push_back(std::move(image));
    plume_images.push_back(RenderThinEmission(s.truth_grid, plume_emission, rays));
    for (float v : plume_images.back().pixels) plume_peak = std::max(plume_peak, v);
  }
  s.exposure = AutoExposure(s.linear);
  // The plume's brightest pixel at 5% of full scale (sRGB code 63): faint beside the fire.
  const double k = plume_peak > 0 ? 0.05 / (s.exposure * plume_peak) : 0.0;
  for (std::size_t c = 0; c < s.linear.size(); ++c)
    for (std::size_t i = 0; i < s.linear[c].pixels.size(); ++i)
      s.linear[c].pixels[i] += static_cast<float>(k * plume_images[c].pixels[i]);
  for (std::size_t i = 0; i < s.truth_emission.size(); ++i)
    s.truth_emission[i] += static_cast<float>(k * plume_emission[i]);
  return s;
}

// One way frames reach the tomography.
struct InputPath {
  std::string name;
  std::vector<LinearFrame> frames;  // per rig camera
  double baseline_threshold = 0;    // the radiance of 8-bit code 10 in this path's encoding
};

LinearFrame DecodeWith(const ImageU8& u8, const ImageU16& u16, int bits, double exposure,
                       const CameraRadiometry& radiometry) {
  ImageU8 picture;
  LinearFrame linear;
  ImageF signal;
  DecodeCameraImage(u8, u16, bits, exposure, radiometry, &picture, &linear, &signal);
  return linear;
}

// The scene's 8-bit sRGB frames through a video codec (each camera's frame a video of its own).
InputPath CodecPath(const Scene& s, const VideoCodecOptions& codec, const std::string& name,
                    const std::function<void(const std::string&)>& log) {
  InputPath p{name, {}, SrgbDecode(10.0 / 255) / s.exposure};
  std::size_t specks = 0, pixels = 0;
  for (const ImageF& l : s.linear) {
    const ImageU8 i = ApplyCameraResponse(l, s.exposure);
    const ImageU8 coded = ThroughVideoCodec({i}, codec)[0];
    for (std::size_t q = 0; q < coded.num_pixels(); ++q) {
      const bool black =
          i.pixels[3 * q] == 0 && i.pixels[3 * q + 1] == 0 && i.pixels[3 * q + 2] == 0;
      const bool lit = coded.pixels[3 * q] || coded.pixels[3 * q + 1] || coded.pixels[3 * q + 2];
      specks += black && lit;
      ++pixels;
    }
    p.frames.push_back(DecodeSrgb8(coded, s.exposure));
  }
  if (log)
    log("footage: " + name + " lit " + Fixed(100.0 * specks / std::max<std::size_t>(1, pixels), 2) +
        "% of the pixels that were exactly black");
  return p;
}

std::vector<InputPath> MakePaths(const Scene& s, bool quick,
                                 const std::function<void(const std::string&)>& log) {
  std::vector<InputPath> paths;
  const double exposure = s.exposure;
  const double srgb10 = SrgbDecode(10.0 / 255) / exposure, linear10 = 10.0 / 255 / exposure;
  std::vector<ImageU8> srgb;
  for (const ImageF& l : s.linear) srgb.push_back(ApplyCameraResponse(l, exposure));
  {
    InputPath p{"8-bit sRGB", {}, srgb10};
    for (const ImageU8& i : srgb) p.frames.push_back(DecodeSrgb8(i, exposure));
    paths.push_back(std::move(p));
  }
  paths.push_back(CodecPath(s, VideoCodecOptions(), "H.264 (libx264 crf 30, 4:2:0)", log));
  if (quick) return paths;
  // Machine-vision raw: linear codes. 12 bits in 16-bit frames, and 8 bits read as they are
  // (--input-transfer linear) or, as flamerig once did, as sRGB.
  CameraRadiometry raw12;
  raw12.transfer = TransferFunction::kLinear;
  raw12.bit_depth = 12;
  CameraRadiometry raw8 = raw12;
  raw8.bit_depth = 8;
  CameraRadiometry raw8_as_srgb;  // the default: 8-bit frames are sRGB
  InputPath p12{"linear raw, 12 bit", {}, linear10};
  InputPath p8{"linear raw, 8 bit, --input-transfer linear", {}, linear10};
  InputPath p8s{"linear raw, 8 bit, read as sRGB (no --input-transfer)", {}, srgb10};
  for (std::size_t c = 0; c < s.linear.size(); ++c) {
    ImageU8 u8;
    ImageU16 u16;
    int bits = RecordCameraImage(s.linear[c], exposure, raw12, 0.0, c, &u8, &u16);
    p12.frames.push_back(DecodeWith(u8, u16, bits, exposure, raw12));
    bits = RecordCameraImage(s.linear[c], exposure, raw8, 0.0, c, &u8, &u16);
    p8.frames.push_back(DecodeWith(u8, u16, bits, exposure, raw8));
    p8s.frames.push_back(DecodeWith(u8, u16, bits, exposure, raw8_as_srgb));
  }
  paths.push_back(std::move(p12));
  paths.push_back(std::move(p8));
  paths.push_back(std::move(p8s));
  return paths;
}

struct Score {
  double heldout = -1, volume = 0, outside = 0, hull = 0, ms = 0, build_ms = 0, solve_ms = 0;
  double peak_mb = 0, added_mb = 0, matrix_mb = 0;
  int iterations = 0;
  std::size_t specks = 0;
};

// Reconstructs from every camera but the last (held out when `held_out`) and scores against the
// truth: the held-out camera's clean image (every pixel), the emission on the fit grid, and the
// share of the emission outside the fire's support.
Score Reconstruct(const Scene& s, const InputPath& path, const ReconstructOptions& options,
                  bool held_out) {
  Score score;
  Rig rig = s.rig;
  std::vector<LinearFrame> frames = path.frames;
  if (held_out) {
    rig.cameras.pop_back();
    frames.pop_back();
  }
  const std::size_t before = ResidentBytes();
  ResetPeakResident();
  const auto t0 = Clock::now();
  Reconstructor reconstructor(rig, options);
  ReconstructSummary summary;
  const FireVolume v = reconstructor.Reconstruct(frames, &summary);
  score.ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  score.peak_mb = PeakResidentBytes() / 1048576.0;
  score.added_mb = (PeakResidentBytes() - std::min(before, PeakResidentBytes())) / 1048576.0;
  score.matrix_mb = summary.matrix_bytes / 1048576.0;
  score.build_ms = summary.matrix_ms;
  score.solve_ms = summary.solve_ms;
  score.hull = summary.voxel_fraction_in_hull;
  for (const auto& solve : summary.solves) score.iterations += solve.iterations;
  for (const auto& m : summary.masks) score.specks += m.speck_regions;
  // The truth on the fit's grid, and its support (above 1e-3 of the peak, one voxel of margin).
  const std::vector<float> truth = ResampleEmission(s.truth_grid, s.truth_emission, v.geometry);
  double peak = 0;
  for (float t : truth) peak = std::max(peak, double(t));
  const GridGeometry& g = v.geometry;
  std::vector<std::uint8_t> support(g.num_voxels(), 0);
  for (int k = 0; k < g.dims.z(); ++k)
    for (int j = 0; j < g.dims.y(); ++j)
      for (int i = 0; i < g.dims.x(); ++i) {
        bool near = false;
        for (int dk = -1; dk <= 1 && !near; ++dk)
          for (int dj = -1; dj <= 1 && !near; ++dj)
            for (int di = -1; di <= 1 && !near; ++di) {
              const int a = i + di, b = j + dj, c = k + dk;
              if (a < 0 || b < 0 || c < 0 || a >= g.dims.x() || b >= g.dims.y() || c >= g.dims.z())
                continue;
              const std::size_t f = g.Flat(a, b, c);
              near = std::max({truth[3 * f], truth[3 * f + 1], truth[3 * f + 2]}) > 1e-3 * peak;
            }
        support[g.Flat(i, j, k)] = near;
      }
  double num = 0, den = 0, outside = 0, total = 0;
  for (std::size_t f = 0; f < g.num_voxels(); ++f)
    for (int c = 0; c < 3; ++c) {
      const double e = v.emission_rgb[3 * f + c], t = truth[3 * f + c];
      num += (e - t) * (e - t);
      den += t * t;
      total += e;
      if (!support[f]) outside += e;
    }
  score.volume = den > 0 ? std::sqrt(num / den) : 0;
  score.outside = total > 0 ? outside / total : 0;
  if (held_out) {
    const ImageF got =
        RenderThinEmission(g, v.emission_rgb, CameraRays(s.rig.cameras.back().model));
    const ImageF& want = s.linear.back();
    const double full = 1.0 / s.exposure;
    double e = 0, w = 0;
    for (std::size_t i = 0; i < want.pixels.size(); ++i) {
      const double t = std::min(double(want.pixels[i]), full);
      e += (got.pixels[i] - t) * (got.pixels[i] - t);
      w += t * t;
    }
    score.heldout = w > 0 ? std::sqrt(e / w) : 0;
  }
  return score;
}

// `flamerig reconstruct` in a process of its own on the scene's frames written as 8-bit sRGB PNGs
// (every camera but a held-out one), as a user runs it: its peak resident memory (MB) and wall time
// (ms).
std::pair<double, double> ReconstructProcess(const Scene& s, bool held_out, int resolution,
                                             const std::string& binary) {
  const fs::path dir =
      fs::temp_directory_path() / ("flamerig-footage-" + std::to_string(::getpid()));
  fs::create_directories(dir / "images");
  Rig rig = s.rig;
  if (held_out) rig.cameras.pop_back();
  rig.Save((dir / "rig.yaml").string());
  for (std::size_t c = 0; c < rig.cameras.size(); ++c)
    WritePng((dir / "images" / (rig.cameras[c].name + ".png")).string(),
             ApplyCameraResponse(s.linear[c], s.exposure));
  const ProgramResult r =
      RunProgram({binary, "-q", "reconstruct", "--rig", (dir / "rig.yaml").string(), "--images",
                  (dir / "images").string(), "--out", (dir / "e.vdb").string(), "--exposure",
                  fmt::format("{:.17g}", s.exposure), "--resolution", std::to_string(resolution)});
  std::error_code ignored;
  fs::remove_all(dir, ignored);
  if (!r.ok()) throw IoError("footage benchmark: flamerig reconstruct failed: " + r.error);
  return {r.peak_resident_bytes / 1048576.0, r.seconds * 1000};
}

ReconstructOptions Flamerig(int resolution, double exposure) {
  ReconstructOptions o;
  o.resolution = resolution;
  o.exposure = exposure;
  return o;
}

// The baseline a person would write: fire where brighter than 8-bit code 10, a hull that every
// camera agrees on, then five LSQR (CGLS) iterations from zero, clipped to >= 0.
ReconstructOptions Baseline(int resolution, double exposure, double threshold, int cameras) {
  ReconstructOptions o = Flamerig(resolution, exposure);
  o.hull.noise_sigma = threshold;
  o.hull.threshold_sigmas = 1;
  o.hull.dilation_px = 0;
  o.hull.min_speck_px = 0;
  o.hull.min_views = cameras;
  o.solve.solver = "cgls";
  o.solve.max_iterations = 5;
  o.solve.stagnation_tolerance = 0;
  o.solve.discrepancy_tau = 1e-9;  // no early stop: five iterations
  o.coarse_to_fine = false;
  return o;
}

}  // namespace

std::string RunFootageBenchmark(const FootageBenchmarkOptions& options,
                                const std::function<void(const std::string&)>& log) {
  const bool quick = options.quick;
  const int width = quick ? 192 : options.width, height = quick ? 108 : options.height;
  const int resolution = quick ? 36 : options.resolution;
  const int truth_resolution = quick ? 54 : options.truth_resolution;
  const int cameras = 4;
  const Box3 box{Eigen::Vector3d(-0.05, 0.0, -0.05), Eigen::Vector3d(0.05, 0.15, 0.05)};
  std::ostringstream md;
  md << "## Tomography on real footage (issue 20)\n\n";
  md << "Machine: " << MachineDescription() << ".\n\n";
  const GridGeometry fit_grid = GridGeometry::FromBox(box, resolution);
  md << "A fire of licks (soot, spectral path, self-absorption) and, beside it, a grey optically "
        "thin plume whose brightest pixel is 5% of full scale, on an exactly black background; "
     << cameras << " cameras of " << width << "x" << height
     << " over 180 degrees at 0.5 m and one held out between the first two. Truth on a "
     << truth_resolution << " grid, the tomography on " << fit_grid.dims.x() << "x"
     << fit_grid.dims.y() << "x" << fit_grid.dims.z()
     << ". Each input path is how a rig's frames reach the tomography. Held-out: relative RMS "
        "error of the held-out camera's image rendered from the reconstruction against its clean "
        "image, every pixel (the held-out camera is not used to stop the solve). Volume: relative "
        "L2 against the truth's emission on the fit grid. Outside: share of the reconstructed "
        "emission in voxels more than a voxel from where the truth has any (above 1e-3 of its "
        "peak). Baseline: fire where brighter than 8-bit code 10, a hull every camera agrees on, "
        "five LSQR (CGLS) iterations from zero. Methods besides flamerig's defaults (OS-EM): the "
        "total-variation prior at its default weight (--prior tv), the quadratic (Laplacian) "
        "prior at its default weight (--prior quadratic), pixels binned 2x2 (--bin 2), "
        "OS-SART (--solver sart). Peak: the process's resident memory during the "
        "reconstruction (VmHWM, reset before each), and what the reconstruction added to it.\n\n";
  if (log)
    log("footage: rendering the scene at " + std::to_string(width) + "x" + std::to_string(height));
  const Scene scene = MakeScene(box, cameras, true, width, height, truth_resolution);
  const std::vector<InputPath> paths = MakePaths(scene, quick, log);
  md << "| input | method | hull | specks removed | iterations | matrix MB | build ms | solve ms "
        "| total ms | peak MB (added) | held-out error | volume error | outside |\n";
  md << "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  // Methods: flamerig's defaults (OS-EM), OS-EM with the total-variation prior, with the
  // quadratic prior, with pixels binned 2x2, flamerig with OS-SART (the default before issue 20),
  // the baseline.
  const std::vector<std::string> methods = {"flamerig (osem)",
                                            "flamerig, osem + tv prior",
                                            "flamerig, osem + quadratic prior",
                                            "flamerig, pixels binned 2x2",
                                            "flamerig, sart",
                                            "baseline"};
  const std::size_t kBaseline = 5;
  std::vector<std::vector<Score>> scores(methods.size());
  for (const InputPath& path : paths) {
    for (std::size_t method = 0; method < methods.size(); ++method) {
      ReconstructOptions o = method == kBaseline ? Baseline(resolution, scene.exposure,
                                                            path.baseline_threshold, cameras)
                                                 : Flamerig(resolution, scene.exposure);
      if (method == 1) o.solve.prior = "tv";
      if (method == 2) o.solve.prior = "quadratic";
      if (method == 3) o.bin = 2;
      if (method == 4) o.solve.solver = "sart";
      const Score s = Reconstruct(scene, path, o, true);
      scores[method].push_back(s);
      md << "| " << path.name << " | " << methods[method] << " | " << Fixed(100 * s.hull, 1)
         << "% | " << s.specks << " | " << s.iterations << " | " << Fixed(s.matrix_mb, 0) << " | "
         << Fixed(s.build_ms, 0) << " | " << Fixed(s.solve_ms, 0) << " | " << Fixed(s.ms, 0)
         << " | " << Fixed(s.peak_mb, 0) << " (" << Fixed(s.added_mb, 0) << ") | "
         << Fixed(s.heldout, 3) << " | " << Fixed(s.volume, 3) << " | " << Fixed(100 * s.outside, 2)
         << "% |\n";
      if (log)
        log("footage: " + path.name + ", " + methods[method] + ": held-out " + Fixed(s.heldout, 3) +
            ", volume " + Fixed(s.volume, 3) + ", outside " + Fixed(100 * s.outside, 2) + "%, " +
            std::to_string(s.iterations) + " iterations, " + Fixed(s.ms, 0) + " ms, peak " +
            Fixed(s.peak_mb, 0) + " MB");
    }
  }
  const std::vector<Score>& ours = scores[0];
  const std::vector<Score>& base = scores[kBaseline];
  // Targets on the codec frames (path 1) against the clean ones (path 0) and the baseline.
  const Score& clean = ours[0];
  const Score& coded = ours[1];
  const Score& coded_base = base[1];
  auto verdict = [](bool met) { return met ? "met" : "NOT met"; };
  md << "\nTargets on the H.264 frames:\n\n";
  md << "- held-out error at least 20% below the baseline's: " << Fixed(coded.heldout, 3)
     << " against " << Fixed(coded_base.heldout, 3) << " ("
     << Fixed(100 * (1 - coded.heldout / coded_base.heldout), 0)
     << "% below): " << verdict(coded.heldout <= 0.8 * coded_base.heldout) << ";\n";
  md << "- within 10% of flamerig's own on the uncompressed frames: " << Fixed(coded.heldout, 3)
     << " against " << Fixed(clean.heldout, 3) << " ("
     << Fixed(100 * (coded.heldout / clean.heldout - 1), 0)
     << "% above): " << verdict(coded.heldout <= 1.1 * clean.heldout) << ";\n";
  md << "- emission outside the fire's support at most 0.5%: " << Fixed(100 * coded.outside, 2)
     << "%: " << verdict(coded.outside <= 0.005) << ";\n";
  // The codec's ringing next to the fire lies a few codes above black, where the default threshold
  // (5 sigmas of a noise floored at one code on an exactly black background) takes it for fire.
  ReconstructOptions strict = Flamerig(resolution, scene.exposure);
  strict.hull.threshold_sigmas = 20;
  const Score coded_strict = Reconstruct(scene, paths[1], strict, true);
  const Score clean_strict = Reconstruct(scene, paths[0], strict, true);
  md << "- the same with `--mask-threshold 20` (for codec footage: its ringing lies a few codes "
        "above black): outside "
     << Fixed(100 * coded_strict.outside, 2) << "%: " << verdict(coded_strict.outside <= 0.005)
     << "; held-out " << Fixed(coded_strict.heldout, 3) << " against "
     << Fixed(clean_strict.heldout, 3) << " on the clean frames with the same setting ("
     << Fixed(100 * (coded_strict.heldout / clean_strict.heldout - 1), 0)
     << "% above): " << verdict(coded_strict.heldout <= 1.1 * clean_strict.heldout) << ".\n";
  if (log)
    log("footage: --mask-threshold 20: H.264 outside " + Fixed(100 * coded_strict.outside, 2) +
        "%, held-out " + Fixed(coded_strict.heldout, 3) + " (clean " +
        Fixed(clean_strict.heldout, 3) + ")");
  // What limits the codec frames: the same fire through libx264 at its own default quality
  // (crf 23), at crf 18 and 28 (the ends of the range FFmpeg's H.264 guide calls subjectively
  // sane, 17 to 28), and at crf 30 with full-resolution chroma (4:4:4).
  md << "\nThe codec's quality against the same clean frames (flamerig's defaults; the target "
        "within 10%):\n\n";
  struct Variant {
    int crf;
    const char* format;
  };
  for (const Variant& v : {Variant{23, "yuv420p"}, Variant{18, "yuv420p"}, Variant{28, "yuv420p"},
                           Variant{30, "yuv444p"}}) {
    VideoCodecOptions codec;
    codec.crf = v.crf;
    codec.pixel_format = v.format;
    const InputPath path = CodecPath(scene, codec, codec.Describe(), log);
    const Score sc = Reconstruct(scene, path, Flamerig(resolution, scene.exposure), true);
    md << "- " << codec.Describe()
       << (v.crf == 23   ? " (libx264's default quality)"
           : v.crf == 28 ? " (the top of the range FFmpeg's H.264 guide calls sane, 17 to 28)"
                         : "")
       << ": held-out " << Fixed(sc.heldout, 3) << " against " << Fixed(clean.heldout, 3) << " ("
       << Fixed(100 * (sc.heldout / clean.heldout - 1), 0)
       << "% above): " << verdict(sc.heldout <= 1.1 * clean.heldout) << "; outside "
       << Fixed(100 * sc.outside, 2) << "%: " << verdict(sc.outside <= 0.005) << ".\n";
    if (log)
      log("footage: " + codec.Describe() + ": held-out " + Fixed(sc.heldout, 3) + ", outside " +
          Fixed(100 * sc.outside, 2) + "%");
  }

  // The options: what the prior and binning give and cost on the same frames.
  const Score &tv_clean = scores[1][0], &tv_coded = scores[1][1];
  const Score &quadratic_clean = scores[2][0], &quadratic_coded = scores[2][1];
  const Score &bin_clean = scores[3][0], &bin_coded = scores[3][1];
  md << "\nOptions, on the same frames: the TV prior gives held-out " << Fixed(tv_clean.heldout, 3)
     << " (clean) and " << Fixed(tv_coded.heldout, 3) << " (H.264) against the defaults' "
     << Fixed(clean.heldout, 3) << " and " << Fixed(coded.heldout, 3) << ", volume "
     << Fixed(tv_clean.volume, 3) << " and " << Fixed(tv_coded.volume, 3) << " against "
     << Fixed(clean.volume, 3) << " and " << Fixed(coded.volume, 3)
     << "; the quadratic prior held-out " << Fixed(quadratic_clean.heldout, 3) << " and "
     << Fixed(quadratic_coded.heldout, 3) << " (its one-step-late update alone diverged here until "
     << "2026-11-28: 23.2 on the clean frames)"
     << "; pixels binned 2x2 give held-out " << Fixed(bin_clean.heldout, 3) << " and "
     << Fixed(bin_coded.heldout, 3) << " in " << Fixed(bin_clean.ms, 0) << " and "
     << Fixed(bin_coded.ms, 0) << " ms (the defaults " << Fixed(clean.ms, 0) << " and "
     << Fixed(coded.ms, 0) << " ms), peak " << Fixed(bin_clean.peak_mb, 0) << " MB against "
     << Fixed(clean.peak_mb, 0) << ".\n";
  if (!quick) {
    // As a user runs it: `flamerig reconstruct` in its own process.
    const auto [peak_mb, ms] = ReconstructProcess(scene, true, resolution, options.binary);
    md << "- " << cameras << " cameras at " << width << "x" << height << " and a "
       << fit_grid.dims.x() << "x" << fit_grid.dims.y() << "x" << fit_grid.dims.z()
       << " grid (8-bit sRGB), `flamerig reconstruct` in its own process: peak "
       << Fixed(peak_mb, 0) << " MB (at most 500: " << verdict(peak_mb <= 500) << "), "
       << Fixed(ms, 0) << " ms in all; in the table's run, matrix build "
       << Fixed(clean.build_ms, 0) << " ms (at most 1000: " << verdict(clean.build_ms <= 1000)
       << "), solve " << Fixed(clean.solve_ms, 0)
       << " ms (at most 1000: " << verdict(clean.solve_ms <= 1000) << ").\n";
    if (log) log("footage: flamerig reconstruct process: peak " + Fixed(peak_mb, 0) + " MB");
  }
  if (!quick && options.hd) {
    // Five cameras at full HD, `flamerig reconstruct` in its own process.
    if (log) log("footage: five cameras at 1920x1080");
    const Scene hd = MakeScene(box, 5, false, 1920, 1080, truth_resolution);
    const auto [peak_mb, ms] = ReconstructProcess(hd, false, options.hd_resolution, options.binary);
    const GridGeometry hd_grid = GridGeometry::FromBox(box, options.hd_resolution);
    md << "- five cameras at 1920x1080, " << hd_grid.dims.x() << "x" << hd_grid.dims.y() << "x"
       << hd_grid.dims.z() << " grid, `flamerig reconstruct` in its own process: peak "
       << Fixed(peak_mb, 0) << " MB (at most 4096: " << verdict(peak_mb <= 4096) << "), "
       << Fixed(ms / 1000, 1) << " s in all.\n";
    if (log) log("footage: HD: peak " + Fixed(peak_mb, 0) + " MB, " + Fixed(ms, 0) + " ms");
  }
  return md.str();
}

}  // namespace flamerig
