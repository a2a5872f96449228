// `flamerig run`: the daily job. Every frame set of a recording (ours, StreamPix sequences, or a
// folder of images), in a chosen range, goes through decode -> tomography -> fit and comes out as
// a volume, with a summary line per frame and, at the end, a report a person can look at.
//
// Per frame, as explicit stages (pipeline/frame_stages.h, which a caller can run, test and
// replace one by one):
//   1. Read the set (frame_source.h). Cameras that dropped the frame, or delivered it incomplete,
//      are left out of this frame, with a note.
//   2. Skip when nothing changed: if every camera's image equals the one of the last frame that was
//      computed, up to noise (CompareImages), the previous result is reused (copied) and the
//      summary says so. The comparison is with the last *computed* frame, so slow drift cannot
//      accumulate unseen.
//   3. Reconstruct (Reconstructor): the system matrix is kept and reused while the fire stays in
//      its envelope, and the previous frame's emission starts the solve.
//   4. Fit (FastFit) warm-started from the previous frame's result (an axisymmetric fit: cold).
//   5. Write OUT/frame_NNNNNN.vdb (temperature K, density m^-3; exposure, Delta E, timings and the
//      fit's termination in metadata), OUT/blender/frame_NNNNNN.vdb (blender_export.h) and a small
//      picture OUT/frames/frame_NNNNNN.png (input over rendered, per camera); an axisymmetric
//      fit's radial profile OUT/frames/frame_NNNNNN_profile.csv (fit_report.h).
//   6. Score against the truth, when there is one (truth.h).
//   7. Commit: the state the next frame starts from, then the summary OUT/frames/frame_NNNNNN.yaml,
//      written last: the mark of a complete frame.
//
// Failures. A DataError in any stage (a corrupt PNG, a StreamPix frame cut short, a recording frame
// whose checksum fails, an image of the wrong size, cameras that see fire where no voxel of the
// box lies) fails that frame only: its summary says why, the next frame starts cold, and the run
// goes on. Bad options, a missing rig (InputError) and a disk that refuses to write (IoError) stop
// the run. A frame set whose images hold no fire (before ignition, after the flame is out) is not a
// failure: it is written as an empty volume with the status "no fire" (frame_stages.h), counted
// apart (RunSummary::no_fire), and the next frame starts cold.
//
// Resuming and stopping. Every output is written to a temporary name and renamed, so a killed run
// never leaves a half-written file under a final name; a frame is complete when its summary exists.
// A run started again over the same OUT continues at the first frame of its range without a
// complete output, with the state an uninterrupted run would have had there: the previous result
// (read back from its .vdb; floats and the exposure are stored exactly), the last computed frame's
// tomography (OUT/tomography/frame_NNNNNN.vdb) and images (read again from the source), and the
// reconstructor's envelope (OUT/state/frame_NNNNNN.state). With one thread the resumed outputs are
// bit-identical to an uninterrupted run's (tested); with more, TBB's reductions may round
// differently from run to run, a few ulps that L-BFGS can grow. A progress callback that answers
// kCancel (SIGINT in the CLI) stops the run inside the frame at hand (its solve or fit stops at the
// next iteration) and commits nothing for that frame: a run started again computes it.
//
// Ranks (MPI, distributed.h): a run over frames [begin, end) of the range is what one rank does;
// warm starts chain inside it; the first frame of a rank's run starts cold (from the tomography)
// unless the previous frame's output is already there.
//
// Thread safety: RunFrames uses TBB inside; call it from one thread.
#ifndef FLAMERIG_PIPELINE_RUN_H_
#define FLAMERIG_PIPELINE_RUN_H_

#include <cstddef>
#include <functional>
#include <string>
#include <vector>

#include "core/progress.h"
#include "fitting/fit.h"
#include "pipeline/calibrate_job.h"
#include "pipeline/frame_source.h"
#include "tomography/reconstruct.h"

namespace flamerig {

struct RunOptions {
  FrameSourceSpec source;
  // The rig: a rig file, or a calibration recording (or folder of board views) calibrated first
  // into OUT/calibrated with `calibrate` (reused when OUT/calibrated/rig.yaml exists).
  std::string rig_path;
  CalibrateInput calibration;
  CalibrateConfig calibrate;
  std::string out_dir;
  std::size_t first = 0;                // first frame set
  std::size_t count = ~std::size_t(0);  // how many (clipped to the source)
  // The exposure the images were taken with, in the renderer's units (a recording's: its first
  // camera's at its start settings; every camera is fitted at its own against that,
  // frame_source.h's StartExposureOfCamera); 0 = the rig's dataset.yaml when it says, else
  // unknown. A known exposure is the tomography's and the fit holds it, so
  // that densities are absolute and comparable across frames. An unknown one: the tomography
  // takes 1, the take's first computed frame fits the exposure and the frames after it hold
  // that (one exposure per take, not per frame: a steady fire stays steady).
  double exposure = 0;
  // Fit a free exposure on every frame (the paper's s), known or not.
  bool fit_exposure = false;
  std::string absorption;  // soot | grey; "" = the rig's dataset.yaml, else soot
  ReconstructOptions reconstruct = [] {
    ReconstructOptions r;
    r.resolution = 64;
    return r;
  }();
  // How 8-bit frames encode light when the rig does not say (or to override it): "" = the rig's;
  // srgb | linear | gamma=G (frame_source.h, WithInputTransfer).
  std::string input_transfer;
  FitOptions fit;
  std::string holdout_camera;  // scored, not fitted; "" = none
  ChangeOptions unchanged;
  bool skip_unchanged = true;
  // Per-voxel sigma and determined grids in every frame's .vdb (fitting/uncertainty.h).
  bool sigma = true;
  // true: each frame's tomography starts from the previous frame's, and its fit from the previous
  // result. false: every frame is its own images' alone, its tomography solved cold and its fit
  // started from it (for comparisons, and what a frame gives whatever came before it). An
  // axisymmetric fit (FitOptions::axisymmetric) always starts cold: its rings follow each frame's
  // own flame axis, and a cool ring carried from the previous frame takes whatever density this
  // frame's light needs at that temperature, which at its neighbour weight (0.3 then, alike in
  // every direction) the fit does not undo. On the main job's 12 frames, fits warm-started, total
  // soot rose to 1.1 to 2.2 times the truth and the temperature RMS to 122 to 142 K, against 0.65
  // to 0.77 and 111 to 127 K started cold; the warm start saved no iterations (55 to 89 against 55
  // to 70). Its tomography too: on two views a warm-started solve keeps the previous frame's
  // streaks, and the tied fit took their colour as a hot bias: the main job's frames 0 and 12, the
  // same images, scored 84 and 114 K RMS (bias +11 and +55 K) with the tomography warm after frame
  // 0; every tomography cold, the frames score 82 to 104 K (bias +10 to +48 K) against 100 to 117 K
  // (+44 to +58 K), the truth moved into the calibrated frame (truth_rig). An untied fit does not
  // move (147 to 152 K either way). (Those with point-sampled RGB8 frames; the main job's pixels
  // now integrate and its cameras send Bayer mosaics, which the fit renders: tied 81 to 91 K,
  // BENCHMARKS.md.)
  bool warm_start = true;
  // Ground truth of a simulated recording: DIR/frame_NNNNNN.vdb. The truth of a set is the one
  // numbered by its frame id modulo the number of truth volumes (a simulated camera replaying a
  // dataset shows frame id mod N).
  std::string truth_dir;
  // The rig the truth was simulated in (a simulated recording's rig.yaml), when the run's rig is
  // another calibration of its cameras: the truth is moved into the run's frame before it is
  // scored (truth.h, calibration/rig_registration.h). "" = the truth is in the run's rig frame.
  std::string truth_rig;
  bool blender = true;    // also write OUT/blender/
  bool pictures = true;   // per-frame picture (input over rendered)
  void Validate() const;  // throws InputError naming the field
};

struct ViewDeltaE {
  std::string camera;
  bool held_out = false;
  double mean = 0;  // over all pixels
  double fire = 0;  // over pixels where the input or the render is not black
};

struct FrameSummary {
  std::size_t frame = 0;
  // "computed", "unchanged (reused frame N)", "no fire" (an empty volume written: the images hold
  // no fire, the notes say which cameras saw any), "failed: ..."
  std::string status;
  std::vector<std::string> notes;  // cameras left out and why, matrix rebuilt, ...
  int cameras_used = 0;
  double read_ms = 0, reconstruct_ms = 0, fit_ms = 0, write_ms = 0, total_ms = 0;
  std::string matrix_source;  // "built", "reused (envelope)", "disk cache", "" when not run
  double hull_fraction = 0;   // of the voxels
  std::size_t active_voxels = 0;
  int fit_evaluations = 0;
  double exposure = 0;
  // Where the exposure came from: "known" (given or the dataset's), "fitted" (this frame's, the
  // take's from here on), "held from frame N" (the take's), "fitted (free)" (--fit-exposure).
  std::string exposure_from;
  double soot = 0;  // particles in the fitted volume (sum of density x voxel volume)
  // The soot's own volume in the fitted volume, m^3 (its metadata soot_volume_m3: particles x
  // 4/3 pi R^3, fitting/absorption.h's StampAbsorption); what the images determine whatever the
  // particles' assumed radius. 0 for a grey medium.
  double soot_volume_m3 = 0;
  double energy = 0;
  // The fit's summary (fitting/fit.h): why it stopped, in the solver's words, after how many
  // iterations, from what energy.
  std::string fit_termination;
  std::string fit_message;
  int fit_iterations = 0;
  double initial_energy = 0;
  // Voxels the fit left at the upper bound of its temperature and density range (FitResult's):
  // held there by the bound, not by the images. 0 in summaries from before they were counted.
  std::size_t voxels_at_temperature_bound = 0, voxels_at_density_bound = 0;
  std::vector<ViewDeltaE> delta_e;
  // Against the truth, on visible voxels (>= 1300 K, >= 1% of the peak emission) where the fit put
  // medium; -1 without truth.
  double truth_rms_k = -1, truth_bias_k = 0;
  // The truth's own spread on the same voxels: the RMS of the best constant, the trivial baseline
  // a fit must beat (issue 19's two-view target: at most 0.7 of it); -1 without truth.
  double truth_spread_k = -1;
  // The RMS weighted by each truth voxel's emission: the error where the light comes from (the
  // benchmarks' "emission-weighted RMS"); -1 without truth. And the mean error weighted the same
  // way: the images show temperatures weighted by emission, so a fit that cannot resolve a
  // fire's cool edge from its hot core tends to put the edge near the light's mean, and its
  // plain bias (truth_bias_k, over voxels) is then hotter than this one. NaN in a summary written
  // before it was (2026-12-03).
  double truth_weighted_rms_k = -1, truth_weighted_bias_k = 0;
  std::size_t truth_voxels = 0, truth_visible = 0;
  int truth_frame = -1;
  double truth_soot = 0;  // particles in the truth
  // Particles over the truth's visible voxels, in the truth and in the fit there (pipeline/
  // truth.h's TruthError::truth_visible_soot): the soot the cameras can show; 0 without truth
  // (and in a summary written before 2026-12-05).
  double truth_visible_soot = 0, visible_soot = 0;
  // The fit's limit (pipeline/truth.h's LightEquivalentTruth on the fit's grid, pooled over its
  // rings when the fit is tied): the truth as the grid or the rings could at best show it,
  // scored as the fit is: its temperature RMS and bias on the truth's visible voxels where it has
  // medium, its soot over the truth's visible voxels (against truth_visible_soot) and in all; -1
  // (the RMS) and 0 without truth or an emission grid in it, when a tied frame's profile cannot be
  // read, and in a summary written before 2026-12-05.
  double limit_rms_k = -1, limit_bias_k = 0, limit_visible_soot = 0, limit_soot = 0;
  // The fit's temperature sigma against the truth (fitting/uncertainty.h): the share of the
  // counted voxels whose error lies within one and two sigma (calibrated: 0.68 and 0.95), and
  // the median sigma; -1 without a sigma grid or truth.
  double truth_within_1_sigma = -1, truth_within_2_sigma = -1, truth_median_sigma_k = -1;
  // Of the counted voxels, the share the fit calls determined (its `determined` grid), and the
  // temperature RMS over those and over the rest; -1 without a sigma grid or truth (or, for an
  // RMS, without such voxels).
  double truth_determined_share = -1, truth_determined_rms_k = -1, truth_undetermined_rms_k = -1;

  double MeanFittedDeltaE() const;  // mean over the fitted views (fire pixels), 0 if none
  std::string Line() const;         // one line for the console and frames.csv's companion log
  // Every field, as JSON (OUT/report/frame_NNNNNN.json) and as YAML (the run's state files).
  std::string ToJson() const;
  std::string ToYaml() const;
  static FrameSummary FromYaml(const std::string& text, const std::string& where);
};

struct RunSummary {
  std::size_t begin = 0, end = 0;                        // frames of the range this call covered
  std::size_t computed = 0, unchanged = 0, resumed = 0;  // resumed: complete before this call
  std::size_t failed = 0;
  // Frames whose images held no fire (FrameStages::Fit): written as empty volumes, not failed.
  // Like `failed`, it counts the frames done before this call too.
  std::size_t no_fire = 0;
  bool cancelled = false;  // stopped by the progress callback; frames after the last are not done
  std::vector<FrameSummary> frames;  // every frame of [begin, end) done, in order
  std::string rig_path;              // the rig used
  double seconds = 0;
  std::string BriefReport() const;
};

// The rig for a run: options.rig_path, else a calibration (done now unless OUT/calibrated/rig.yaml
// exists). Returns the rig file's path.
std::string PrepareRig(const RunOptions& options, const ProgressCallback& progress = nullptr);

// The frames of the range: [first, min(first + count, sets)).
void RunRange(const RunOptions& options, const FrameSource& source, std::size_t* begin,
              std::size_t* end);

class FrameStages;

// Processes frames [begin, end) (inside the range) as described above and returns their
// summaries. The rig must exist (PrepareRig). Throws InputError for bad options or a source that
// does not fit the rig, IoError when outputs cannot be written; a frame with a DataError is
// reported in its summary, not thrown. Progress: stage "frames", unit "frames" (done counts the
// frames of [begin, end) complete, resumed ones too; the message is the frame's summary line),
// and the inner stages' own progress (the solve's, the fit's) while a frame is computed; a cancel
// from either stops the run as described above. `stages` (optional) replaces the stages
// (frame_stages.h), for tests and other pipelines; it must be made for the same options, rig and
// frames.
RunSummary RunFrames(const RunOptions& options, const std::string& rig_path, std::size_t begin,
                     std::size_t end, const ProgressCallback& progress = nullptr,
                     FrameStages* stages = nullptr);

// Reads the summaries of frames [begin, end) from OUT/frames (missing ones are skipped).
std::vector<FrameSummary> ReadFrameSummaries(const std::string& out_dir, std::size_t begin,
                                             std::size_t end);

// The name of frame i's files: "frame_NNNNNN".
std::string FrameName(std::size_t i);

// What a `flamerig simulate` dataset beside a rig file says: the exposure its images were taken
// with (false when there is no dataset.yaml or it has none) and its absorption model ("soot" when
// there is none). InputError naming dataset.yaml when it is malformed. Read through
// acquisition/sim_camera.h's ReadDatasetExposure, as the dataset's replay reads it.
bool DatasetExposure(const std::string& rig_path, double* exposure);

// The exposure of a job's images: `given` when > 0, else the dataset's beside the rig, else that of
// the `flamerig simulate` dataset the images belong to (`images_dir` is DATASET/frames or a
// DATASET/frames/frame_NNNNNN beside DATASET/dataset.yaml: a rig calibrated elsewhere, e.g. by
// calibrate-radiometry, films the same images); known when one of them says, `from` naming it.
// Unknown: value 1 (the tomography's), and the fit finds its own, the densities relative to it.
// A dataset that states its exposure in time (`exposure_unit_us`, simulate.h's SimExposureUnitUs)
// gives that unit too: a recording of it, by sim cameras at their own settings, is at the
// exposure its settings give over that unit (ExposureFromReference below), not at the dataset's.
struct ImagesExposure {
  double value = 1;
  bool known = false;
  bool given = false;  // --exposure: nothing overrides it
  std::string from;    // "--exposure" or the dataset.yaml that gave it; empty when unknown
  double unit_us = 0;  // the dataset.yaml's exposure_unit_us when it gave the value; else 0
};
ImagesExposure ResolveExposure(double given, const std::string& rig_path,
                               const std::string& images_dir = "");
// `*exposure` from a source's exposure reference (`reference()`: a recording's, or an export's
// folder's, FrameSource::exposure_reference, ReadExportedReference): the reference's exposure
// time x gain at 0 dB over an exposure unit, `from` naming both (the caller logs it). The unit
// is the dataset.yaml's that gave the exposure (ImagesExposure::unit_us: a simulated take at
// other settings than the dataset's 10000 us), or, when the exposure is not known, the rig's
// (a radiometric calibration's, Rig::exposure_unit_us). Unchanged for --exposure, without such a
// unit, or when the source has no reference; `reference()` is called only when a unit would be
// used (a damaged exposure_reference.yaml stops no job that has no use for it).
void ExposureFromReference(const std::function<std::optional<ExposureReference>()>& reference,
                           const Rig& rig, const std::string& rig_path, ImagesExposure* exposure);
// `exposure.value`, checked against the fit's exposure range, for a fit that holds it; InputError
// naming `job` and where the value came from when it lies outside.
double HeldExposure(const ImagesExposure& exposure, const FitOptions& fit, const std::string& job);
std::string DatasetAbsorption(const std::string& rig_path);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_RUN_H_
