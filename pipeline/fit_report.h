// Pictures and numbers a person can look at after a fit: for every view (the fitted ones and any
// held-out one) the input, the fitted volume rendered through the camera and their difference as
// a Delta E heat map; a plot of error against time; the trace as CSV; a Markdown summary.
#ifndef FLAMERIG_PIPELINE_FIT_REPORT_H_
#define FLAMERIG_PIPELINE_FIT_REPORT_H_

#include <string>
#include <vector>

#include "fitting/fit.h"
#include "pipeline/truth.h"

namespace flamerig {

struct ViewScore {
  std::string name;
  bool held_out = false;
  double mean_delta_e = 0;      // over all pixels
  double fire_delta_e = 0;      // over pixels where the input or the render is not black
  std::size_t fire_pixels = 0;  // how many
  double p95_delta_e = 0;       // 95th percentile over those pixels
};

// Renders `result.volume` through each view at `result.exposure` (a Bayer camera's view through
// its mosaic and demosaicing, FitView::mosaic, as the fit compares it), scores it and, when `dir`
// is not empty, writes the report there: index.html (pipeline/report_page.h) and report.md over
// views.png (input, rendered, Delta E map per view, labelled), slices.png (the fitted temperature,
// with `truth` the truth and the error, and the sigma; run_report.h's SlicesPicture), error.png
// and .svg (mean Delta E against time, pipeline/plot.h) and trace.csv; for an axisymmetric fit
// also profile.csv and profile.png (WriteRingProfileCsv and WriteRingProfilePlot below). Returns
// the scores, and the rendered 8-bit views (fitted, then held out) through *rendered when not
// null. `truth_error`: the truth's scores when the caller has them already
// (CompareWithTruth(*truth, result.volume, fit_from_truth)), or null to compute them here; and
// `limit_error` the fit's limit's (truth.h's CompareLimitWithTruth) likewise.
std::vector<ViewScore> WriteFitReport(
    const std::string& dir, const FitResult& result, const std::vector<FitView>& fitted,
    const std::vector<FitView>& held_out, const AbsorptionModel& absorption,
    const RenderOptions& render, const std::string& title, std::vector<ImageU8>* rendered = nullptr,
    const FireVolume* truth = nullptr, const Rigid3& fit_from_truth = Rigid3(),
    const Eigen::Vector3d& up_in_rig = Eigen::Vector3d::UnitY(),
    const TruthError* truth_error = nullptr, const TruthError* limit_error = nullptr);

// An axisymmetric fit's radial profile (FitResult::ring_profile) as CSV, one row per ring by
// layer and then radius: layer, height_m (along the rig's up: fit.h's MeasureRingHeights),
// axis_x_m, axis_y_m, axis_z_m, radius_voxels, radius_m, voxels, temperature_k,
// temperature_sigma_k, density_per_m3, log_density_sigma, soot_volume_fraction (0 for a grey
// model), and with `truth` (pipeline/truth.h's TruthOnRings, one per ring) truth_temperature_k and
// truth_voxels (empty where no truth voxel falls in the ring). Metres in the rig frame. Written
// atomically. Files from before 2026-11-29 have no soot_volume_fraction (read as 0); from before
// 2026-12-02 no axis_y_m, and their height_m is the rig y (read as both).
void WriteRingProfileCsv(const std::string& path, const std::vector<RingProfilePoint>& profile,
                         const std::vector<RingTruth>* truth = nullptr);

// Reads what WriteRingProfileCsv wrote, its columns found by name (the truth's, if any, are not
// read). Throws IoError when the file cannot be read and DataError naming the file and line of a
// missing column or a malformed value.
std::vector<RingProfilePoint> ReadRingProfileCsv(const std::string& path);

// The profile drawn (pipeline/plot.h, base + ".png" and the rest): temperature against radius at
// up to five heights spread over the flame, each with +- one sigma bars where the fit has a
// sigma, and with `truth` the truth's ring means dashed in the same colour. False with the reason
// in *error when the plot cannot be drawn (no gnuplot).
bool WriteRingProfilePlot(const std::string& base, const std::vector<RingProfilePoint>& profile,
                          const std::vector<RingTruth>* truth, const std::string& title,
                          std::string* error = nullptr);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_FIT_REPORT_H_
