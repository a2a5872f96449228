// `flamerig reconstruct`: algebraic tomography of one frame set (a folder DIR/<camera>.png for
// every rig camera) into an emission volume (tomography/reconstruct.h), with an optional preview
// picture and an optional score against a ground-truth volume.
#ifndef FLAMERIG_PIPELINE_RECONSTRUCT_JOB_H_
#define FLAMERIG_PIPELINE_RECONSTRUCT_JOB_H_

#include <string>
#include <vector>

#include "core/progress.h"
#include "tomography/reconstruct.h"

namespace flamerig {

struct ReconstructJob {
  std::string rig_path;
  std::string images_dir;
  std::string out_path;  // the .vdb (its folder is made)
  // The exposure the images were taken with; 0 = ResolveExposure's (run.h: dataset.yaml beside the
  // rig or the images), else an export's recorded settings over the rig's exposure unit
  // (ExposureFromReference), else 1.
  double exposure = 0;
  ReconstructOptions reconstruct;  // its exposure is the job's
  std::string input_transfer;      // "" = the rig's; else srgb | linear | gamma=G (frame_source.h)
  // "" = none: each camera's fire mask as DIR/<camera>.png (white: the pixels the solve uses, the
  // dilated mask) and DIR/masks.png, a labelled picture of the masks, the specks removed and the
  // hull's outline over each input.
  std::string masks_dir;
  std::string preview_path;  // "" = none: per camera input, rendered back, 4x difference
  std::string truth_path;    // "" = none: a volume with an 'emission' grid
  // "" = none: a report folder, index.html (pipeline/report_page.h) with the tomography's summary,
  // the score against the truth and views.png (the preview's picture).
  std::string report_dir;
};

struct ReconstructJobResult {
  ReconstructSummary summary;
  double exposure = 1;
  std::string exposure_source;     // "--exposure", the dataset.yaml or the settings, "default 1"
  std::vector<std::string> notes;  // cameras left out and why; a truth not compared and why
  double truth_error = -1;         // relative L2 against the truth's emission; -1 without one
};

// Throws InputError for bad options or input, DataError for a damaged image or truth, IoError for
// outputs that cannot be written; Cancelled when the progress callback asks to stop (nothing is
// written then).
ReconstructJobResult RunReconstructJob(const ReconstructJob& job,
                                       const ProgressCallback& progress = nullptr);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_RECONSTRUCT_JOB_H_
