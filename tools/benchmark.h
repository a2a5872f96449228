// `flamerig benchmark`: run time against error, written to BENCHMARKS.md with the machine and date.
//
// Each benchmark owns one section of BENCHMARKS.md between "<!-- BEGIN name -->" and
// "<!-- END name -->", replaced on every run, so benchmarks of different modules share the file.
#ifndef FLAMERIG_TOOLS_BENCHMARK_H_
#define FLAMERIG_TOOLS_BENCHMARK_H_

#include <functional>
#include <string>
#include <vector>

namespace flamerig {

struct RenderBenchmarkOptions {
  std::vector<int> resolutions = {32, 64, 128};  // cubic grids N^3
  int width = 320;
  int height = 240;
  int repeats = 5;     // renders timed per configuration; the median is reported
  bool quick = false;  // CI smoke mode: 32^3 and 64^3, 2 repeats
};

// The forward-render benchmark: a 320x240 view of the candle fire on cubic grids, fast path (grey)
// and spectral path (soot), 1 and 2 threads, with and without empty-space skipping. Error is the
// mean and maximum CIE76 Delta E of the 8-bit image against a reference render (double precision,
// step 0.1 voxel, 5 nm spectral bins, no skipping). Returns the Markdown section.
std::string RunRenderBenchmark(const RenderBenchmarkOptions& options,
                               const std::function<void(const std::string&)>& log);

struct TomographyBenchmarkOptions {
  std::vector<int> resolutions = {64, 128};  // cubic grids N^3
  std::vector<int> views = {4, 8};
  int width = 320;
  int height = 240;
  bool quick = false;  // CI smoke mode: 32^3, 4 views
};

// The tomography benchmark: a fire of several licks rendered (soot, spectral path, self-absorption
// included) by `views` cameras spread over 180 degrees plus one held-out camera between the first two;
// for each grid and view count: the system matrix build (time, size), then OS-SART and CGLS (time,
// iterations, stop reason) with the relative L2 error of the emission against the ground truth's thin
// emission and the held-out camera's relative RMS image error; and the per-frame time of the next frame
// once the matrix is cached (warm start). Returns the Markdown section.
std::string RunTomographyBenchmark(const TomographyBenchmarkOptions& options,
                                   const std::function<void(const std::string&)>& log);

struct FootageBenchmarkOptions {
  int width = 640, height = 360;  // four cameras and a held-out one
  int resolution = 108;           // the tomography's grid (72x108x72 in the benchmark's box)
  int truth_resolution = 162;     // the truth's, finer
  bool hd = true;                 // also five cameras at 1920x1080
  int hd_resolution = 128;
  std::string binary;  // flamerig, run for the memory rows (a process of its own, as users run it)
  bool quick = false;  // CI smoke mode: 192x108, a 36 grid, sRGB and H.264 only, no HD
};

// The tomography on frames as a real rig delivers them (issue 20): a fire and a faint grey plume on
// an exactly black background, through 8-bit sRGB, H.264 (ffmpeg, libx264 crf 30), 12-bit and
// 8-bit linear raw (read right and read as sRGB); flamerig's defaults against a baseline (a
// thresholded visual hull and five LSQR iterations) on the same frames: held-out camera error,
// volume error, emission outside the fire's support, time and peak memory; then five cameras at
// 1920x1080. Returns the Markdown section.
std::string RunFootageBenchmark(const FootageBenchmarkOptions& options,
                                const std::function<void(const std::string&)>& log);

struct FitBenchmarkOptions {
  std::vector<int> resolutions = {32, 64, 128};  // grid along the box's longest axis
  // Time given to the paper's Algorithm 2 at each resolution (it needs hours to finish its 12
  // cluster doublings; it is stopped here and compared at the point it reached).
  std::vector<double> paper_seconds = {300, 300, 600};
  int width = 320;
  int height = 240;
  std::string figure_dir = "benchmarks";  // error-against-time plots (PNG), relative to cwd
  bool quick = false;                     // CI smoke mode: 16^3, 96x72, 5 s
};

// The fit benchmark (issue 4): a candle (soot) filmed from the front and the side at 320x240 as in
// the paper, plus a held-out view at 45 degrees; tomography of the two views; then the paper's
// Algorithm 2 (time-limited) and the fast fit, each traced as mean Delta E of the fitted views
// against time, with the held-out view's Delta E and the temperature error on visible voxels; the
// time the fast fit needs to reach Algorithm 2's final Delta E; and the next frame warm-started.
// Writes one plot per resolution to figure_dir. Returns the Markdown section.
std::string RunFitBenchmark(const FitBenchmarkOptions& options,
                            const std::function<void(const std::string&)>& log);

struct CaptureBenchmarkOptions {
  double seconds = 10;  // per scenario
  std::string directory =
      ".flamerig_capture_benchmark";  // on the disk being measured; removed after
  bool aravis = true;                 // the Aravis fake scenario (needs 127.0.0.2..5: a private
                                      // network namespace, see acquisition_aravis_test.cc)
  bool quick = false;                 // CI smoke mode: 1 s, smaller rigs
};

// The capture benchmark (issue 5): the disk's sequential write bandwidth (measured first, in the
// same run), then the daemon recording simulated cameras (8 x 640x480 Mono8 at 100 fps; 4 x
// 1920x1080 Mono8 at 30 fps) and Aravis' fake GigE Vision cameras over loopback (4 x 640x480 at
// 100 fps): frame sets recorded and dropped, CPU use, write bandwidth, timestamp spread in sets.
std::string RunCaptureBenchmark(const CaptureBenchmarkOptions& options,
                                const std::function<void(const std::string&)>& log);

// Replaces (or appends) section `name` of the Markdown file at `path`.
void WriteBenchmarkSection(const std::string& path, const std::string& name,
                           const std::string& markdown);

// `v` with `digits` decimals, for the benchmark tables.
std::string Fixed(double v, int digits);

// "CPU model, N cores, date" for the report header.
std::string MachineDescription();

// The machine's limits, measured in the run that reports against them (a roofline's two roofs):
// the memory bandwidth of a streaming read of 256 MB on one and on all hardware threads, and the
// arithmetic peak of one core in float multiply-adds (independent AVX2 FMAs where the CPU has
// them, else SSE multiply and add).
struct MachineLimits {
  double read_gb_s_one = 0, read_gb_s_all = 0;
  double gflops_one = 0;
  std::string arithmetic;  // what the peak was measured with
};
MachineLimits MeasureMachineLimits();

struct CalibrationBenchmarkOptions {
  int cameras = 4;
  int width = 640;
  int height = 480;
  int views_per_pair = 24;    // boards shared by neighbouring cameras
  int views_per_camera = 24;  // close-ups
  bool quick = false;         // CI smoke mode: 8 + 8 views
};

// The calibration benchmark (issue 6): a ring from `flamerig simulate` (boards rendered with
// noise); our detection (cold and from the cache) and joint solve against `mrcal-calibrate-cameras`
// on the same detections, each with its error against the true rig (relative camera rotations and
// translations) and its RMS; then a stereo pair through a k1 = -0.3 lens with shadowed
// chessboards, per chessboard detector (boards found, corners kept and left out, detection and
// solve time, RMS, lens error against the truth) and mrcal's tool on the default's corners.
// Returns the Markdown section.
std::string RunCalibrationBenchmark(const CalibrationBenchmarkOptions& options,
                                    const std::function<void(const std::string&)>& log);

struct RunBenchmarkOptions {
  int frames = 12;      // of the simulated candle
  int resolution = 64;  // grid along the box's longest axis
  int width = 320, height = 240;
  bool quick = false;  // CI smoke mode: 3 frames, 24^3, 120x90
};

// The run benchmark (issue 7): frames per minute of `flamerig run` on a simulated recording with
// the share of each stage, against every frame processed on its own (no matrix reuse, no warm
// start), and a still stretch of fire recognised as unchanged; error against the truth side by
// side. Returns the Markdown section.
std::string RunRunBenchmark(const RunBenchmarkOptions& options,
                            const std::function<void(const std::string&)>& log);

struct SceneBenchmarkOptions {
  int width = 960, height = 540;
  int reference_samples = 1024;  // light samples per pixel of the reference image
  bool quick = false;            // CI smoke mode: 240x135, a 64-sample reference
};

// The scene benchmark (issue 8): a candle lighting a small still life at 960x540; relative RMS
// error against a high-sample reference for 1, 2, 4, ... samples per pixel with their times, the
// time to 5%, 2% and 1% noise, and the point-light render of the usual practice. Returns the
// Markdown section.
std::string RunSceneBenchmark(const SceneBenchmarkOptions& options,
                              const std::function<void(const std::string&)>& log);

struct CameraBenchmarkOptions {
  bool quick = false;  // CI smoke mode: the candle only, 96x72, truth 24, fit 16
  std::string work_dir = ".flamerig_camera_benchmark";  // datasets, removed after
};
// The camera benchmark (issue 19): the candle from two views and licks from eight, filmed by
// sRGB-observer cameras (the reference) and by band cameras with their own gains and a black level,
// which also film a black-body calibrator; the fit's temperature error (bias, RMS, emission-
// weighted) and time with the band cameras assumed sRGB, with their datasheet (unit gains, black 0),
// calibrated by calibrate-radiometry, and with the true model. Returns the Markdown section.
std::string RunCameraBenchmark(const CameraBenchmarkOptions& options,
                               const std::function<void(const std::string&)>& log);

struct AccuracyBenchmarkOptions {
  bool quick = false;  // CI smoke mode: 96x72 images, truth 24, fit 16, 4 views for the licks
};

// The accuracy benchmark (issue 19): oracle runs of the fast fit on a candle from two views and
// licks of flame from eight, truth finer than the fit's grid: as `run` fits now, the exposure
// known, converged, without the neighbour term, the start alone, started at the truth, the
// truth's densities given, noise-free unsaturated images; the temperature's RMS, bias,
// emission-weighted RMS, correlation and spread against the truth's own spread. Returns the
// Markdown section.
std::string RunAccuracyBenchmark(const AccuracyBenchmarkOptions& options,
                                 const std::function<void(const std::string&)>& log);

}  // namespace flamerig

#endif  // FLAMERIG_TOOLS_BENCHMARK_H_
