// The report of a `flamerig run`: one HTML page (OUT/report/index.html) with pictures a person can
// look at, made from the per-frame summaries and outputs in OUT:
//   errors.png       Delta E (fire pixels) of every view over the frames, held-out views dashed in
//                    the legend's name, and the temperature error against the truth when known
//   timing.png       run time per frame by stage (tomography, fit, everything)
//   contact.png      input over rendered views for up to `contact_frames` frames, evenly spaced
//   slices_NNNNNN.png  the fitted temperature of a few frames as slices through the middle of the
//                    box (front: the x-y plane; side: the z-y plane; up is up), with the truth's
//                    beside it when known, coloured by one scale with its colour bar in kelvin
//   frames.csv       every frame's summary as a table (OUT/frames.csv)
// plus a table of every frame's summary line.
#ifndef FLAMERIG_PIPELINE_RUN_REPORT_H_
#define FLAMERIG_PIPELINE_RUN_REPORT_H_

#include <string>
#include <vector>

#include "calibration/pose.h"
#include "pipeline/run.h"

namespace flamerig {

struct RunReportInfo {
  std::string title = "flamerig run";
  std::string source;  // what was read
  std::string rig_path;
  std::string truth_dir;  // "" = no truth
  std::string truth_rig;  // RunOptions::truth_rig: the truth's frame, moved into the rig's
  double wall_seconds = 0;
  int ranks = 1;
  int contact_frames = 6;
  int slice_frames = 3;
};

// Writes OUT/frames.csv and OUT/report/ (index.html and the pictures: errors and run time over the
// frames, a contact sheet, a few frames' slices and, where OUT/frames/frame_NNNNNN_profile.csv is
// (an axisymmetric fit), their radial profiles); returns index.html's path. Throws IoError naming
// a file that cannot be written or read; a malformed profile is a warning and no picture.
std::string WriteRunReport(const std::string& out_dir, const std::vector<FrameSummary>& frames,
                           const RunReportInfo& info);

// A temperature slice picture of a volume (kelvin coloured from t_lo to t_hi, voxels without soot
// dark grey): the plane of voxels at index `index` along `axis` (0 = x: the z-y plane, 2 = z: the
// x-y plane), y up, each voxel `scale` pixels. Exposed for tests.
ImageU8 TemperatureSlice(const FireVolume& volume, int axis, int index, double t_lo, double t_hi,
                         int scale);

// The report's slices of a fitted volume, a row per field, front (x-y) and side (z-y) through the
// box's middle, each with its colour bar and a scale bar: the fitted temperature; with `truth`
// (any grid, sampled at each fit voxel's centre, moved by `fit_from_truth` into the truth's
// frame, truth.h) the truth and fit - truth; the temperature sigma when the volume has one. The
// temperature scale spans the fit's and the truth's. The rig's up (Rig::up_in_rig) is up in the
// picture: +y, or -y for a rig in its first camera's frame (drawn upside down until 2026-12-02).
// Throws InputError when the volume lacks temperature or density.
ImageU8 SlicesPicture(const FireVolume& fit, const FireVolume* truth = nullptr,
                      const Rigid3& fit_from_truth = Rigid3(),
                      const Eigen::Vector3d& up_in_rig = Eigen::Vector3d::UnitY());

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_RUN_REPORT_H_
