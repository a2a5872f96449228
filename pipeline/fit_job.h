// `flamerig fit`: temperature, density and exposure from one frame set (a folder DIR/<camera>.png
// for every rig camera), by the fast fit or the paper's Algorithm 1 or 2 (fitting/fit.h), with the
// report a person looks at (fit_report.h) and an optional score against a ground truth.
#ifndef FLAMERIG_PIPELINE_FIT_JOB_H_
#define FLAMERIG_PIPELINE_FIT_JOB_H_

#include <string>
#include <vector>

#include "core/progress.h"
#include "fitting/fit.h"
#include "pipeline/fit_report.h"
#include "pipeline/truth.h"
#include "tomography/reconstruct.h"

namespace flamerig {

// The fit methods, by the names the CLI takes.
enum class FitMethod { kFast, kAlgorithm1, kAlgorithm2 };
const char* ToString(FitMethod method);  // "fast", "alg1", "alg2"

struct FitJob {
  std::string rig_path;
  std::string images_dir;
  std::string out_path;            // the .vdb (its folder is made)
  std::vector<std::string> views;  // cameras to fit; empty: every camera with an image but holdout
  std::string holdout;             // scored, not fitted; "" = none
  int resolution = 0;              // voxels along the box's longest side; 0 = reconstruct's
  ReconstructOptions reconstruct;  // the tomography's settings (its exposure is the job's)
  std::string input_transfer;      // "" = the rig's; else srgb | linear | gamma=G (frame_source.h)
  std::string tomography_path;     // "" = reconstruct from the fitted views
  FitMethod method = FitMethod::kFast;
  std::string absorption;  // soot | grey; "" = the rig's dataset.yaml, else soot
  // Of the images; 0 = dataset.yaml beside the rig, else an export's recorded settings over the
  // rig's exposure unit (run.h's ExposureFromReference), else unknown (1 for the tomography). The
  // fast fit holds a known exposure unless fit_exposure; the paper's algorithms fit their own.
  double exposure = 0;
  bool fit_exposure = false;
  FitOptions fit;
  PaperFitOptions paper;   // alg1, alg2
  std::string report_dir;  // "" = beside the output: F_report/
  std::string truth_path;  // "" = none
  // The rig the truth was simulated in, when rig_path is another calibration of its cameras: the
  // truth is moved into rig_path's frame before it is scored (truth.h's RegisterTruth). "" = none.
  std::string truth_rig;
  // Per-voxel sigma and determined grids in the .vdb (fitting/uncertainty.h; fast fit only).
  bool uncertainty = true;
};

struct FitJobResult {
  FitResult result;
  std::vector<ViewScore> scores;
  std::string report_dir;
  std::string tomography;  // how the tomography was had: "file ..." or the reconstruction's report
  bool have_truth = false;
  TruthError truth;
  // The fit's limit (truth.h's LightEquivalentTruth on its grid, per ring for a tied fit) scored
  // the same way; not compared when the truth has no emission grid.
  TruthError limit;
  RigRegistration truth_frame;  // FitJob::truth_rig's frame into the rig's (identity without)
};

// Throws InputError for bad options (views that are not in the rig, a view both fitted and held
// out, missing files), DataError for damaged input or no fire in view, IoError for outputs that
// cannot be written. Progress: the tomography's and the fit's; a cancel stops the fit, which still
// writes its result (termination "cancelled" in the volume's metadata).
FitJobResult RunFitJob(const FitJob& job, const ProgressCallback& progress = nullptr);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_FIT_JOB_H_
