// Scoring against a ground truth (a simulated recording's truth volumes): what a fit's
// temperatures and a reconstruction's emission are worth, on the voxels the images can show.
#ifndef FLAMERIG_PIPELINE_TRUTH_H_
#define FLAMERIG_PIPELINE_TRUTH_H_

#include <string>
#include <vector>

#include "calibration/pose.h"
#include "calibration/rig_registration.h"
#include "fitting/fit.h"
#include "tomography/volume.h"

namespace flamerig {

// A fitted volume's temperature against a ground truth, where it can be judged: the visible voxels
// of the truth (>= 1300 K with soot, and, when the truth has an emission grid, at least 1% of its
// peak emission: cooler or fainter voxels leave no trace in 8-bit images, notes/physics.md) in
// which the fit put medium. On the same voxels, voxel against voxel; on another grid (a truth
// simulated finer than the fit, or a fit in a calibrated rig's box), each visible truth voxel
// against the fitted voxel that holds its centre (a visible voxel outside the fitted box is
// visible, not counted).
struct TruthError {
  bool compared = false;  // false: no temperature or density in either
  bool same_grid = false;
  std::string why_not;
  std::size_t visible = 0;       // visible voxels of the truth
  std::size_t counted = 0;       // of those, where the fit has medium
  double rms_k = 0, mean_k = 0;  // fit - truth
  // On the counted voxels, what a combustion researcher weighs the error against:
  double truth_spread_k = 0;  // the truth's standard deviation: the RMS of the best constant
  double fit_spread_k = 0;    // the fit's standard deviation
  double correlation = 0;     // Pearson's, fit against truth
  // The same weighted by each truth voxel's emission (its green channel; 1 without an emission
  // grid): the error where the light comes from.
  double weighted_rms_k = 0, weighted_mean_k = 0, weighted_truth_spread_k = 0;
  // The number of soot particles in each volume (sum of density x voxel volume over all voxels):
  // absolute when the exposure is known, comparable across frames of a take.
  double truth_soot = 0, fit_soot = 0;
  // The same over the truth's visible voxels, the fit's at the voxel holding each one's centre
  // (no medium, or outside the fitted box: none) at the truth's voxel volume: the soot the
  // cameras can show against what the fit holds there. The truth's soot that is too cool or
  // too faint for an image (on the main job's candle about 15%: BENCHMARKS.md, "How much of the
  // truth's soot a camera can see") is in truth_soot and not here.
  double truth_visible_soot = 0, fit_visible_soot = 0;
  // When the fit has a temperature_sigma grid (fitting/uncertainty.h): of the counted voxels, the
  // share whose error lies within one and within two sigma (a calibrated sigma gives 0.68 and
  // 0.95), the median sigma, and the share the images determine (`determined` grid).
  bool have_sigma = false;
  double within_1_sigma = 0, within_2_sigma = 0, median_sigma_k = 0, determined_share = 0;
  // With a `determined` grid too: the temperature RMS over the counted voxels the fit calls
  // determined, and over the rest (-1 where there are none): what a researcher who quotes only
  // the determined voxels can expect. Without one, neither (and determined_share is 0).
  bool have_determined = false;
  double determined_rms_k = -1, undetermined_rms_k = -1;
};
// Frames: every function below takes the truth in its own rig frame and the fit in its own, and
// `fit_from_truth` (point_in_fit = fit_from_truth * point_in_truth) between them: identity when
// the fit was made in the rig the truth was simulated in. A fit through a calibrated rig is in the
// calibration's frame, about a voxel away from the simulator's (calibration/rig_registration.h
// measures it); scored without the motion, that gauge counts as temperature error (the main job's
// tied fits on 2026-11-28, their tomography still warm-started: 111 to 127 K RMS unmoved, 84 to
// 117 K with the truth moved, 98 to 122 K fitted through the true rig).
// A truth voxel pairs with the fitted voxel holding its centre moved into the fit's frame.
//
// `volume`'s temperature, density and soot volume fraction (those it has) on `grid`: each voxel of
// `grid` takes the value of the voxel of `volume` that holds its centre (none: no medium, the
// lowest temperature of `volume`), as the scorer pairs voxels, so that a truth finer (or coarser)
// than a fit can be shown beside it. The metadata is copied; emission and sigma grids are not.
FireVolume SampleOnGrid(const FireVolume& volume, const GridGeometry& grid,
                        const Rigid3& grid_from_volume = Rigid3());
// Sum of density x voxel volume: the number of particles in the volume.
double TotalSoot(const FireVolume& volume);
TruthError CompareWithTruth(const FireVolume& truth, const FireVolume& fitted,
                            const Rigid3& fit_from_truth = Rigid3());
// The motion of a truth simulated in the rig at `truth_rig_path` into the frame of `fit_rig`
// (RegisterRigs over the truth rig's box); identity (and no points) for an empty path. Throws
// InputError or DataError naming the path when that rig cannot be read or registered.
RigRegistration RegisterTruth(const std::string& truth_rig_path, const Rig& fit_rig);

// The temperature error of CompareWithTruth (the same voxels, paired the same way) in bands of the
// truth's emission: where in the fire the error lies. A truth voxel falls in the band [lo, hi) that
// holds its emission (green channel) as a share of the truth's brightest voxel's; the last band
// also holds its upper edge. `share` is the band's part of the summed squared error over all
// bands. Throws InputError when the truth has no emission grid or either volume lacks temperature
// or density, or when the edges do not rise; voxels outside every band are not counted.
struct EmissionBandError {
  double lo = 0, hi = 0;  // shares of the truth's peak emission
  std::size_t counted = 0;
  double rms_k = 0, mean_k = 0;  // fit - truth; 0 where nothing is counted
  double share = 0;              // of the squared error summed over the bands
};
std::vector<EmissionBandError> TemperatureErrorByEmission(
    const FireVolume& truth, const FireVolume& fitted,
    const std::vector<double>& edges = {0.01, 0.03, 0.1, 0.3, 1.0},
    const Rigid3& fit_from_truth = Rigid3());

// The truth on an axisymmetric fit's rings (FitResult::ring_profile on `fit_grid`), so that a
// radial profile can be drawn beside the truth's: per ring, the mean temperature of the truth's
// visible voxels (as CompareWithTruth counts them) that fall in it. A truth voxel falls in the
// ring of the layer of the fit voxel holding its centre whose radius is the distance from that
// centre to the layer's axis (in the xz plane) in fit voxels, rounded. `voxels` 0 and a NaN
// temperature where none falls. Throws InputError when the truth lacks temperature or density.
struct RingTruth {
  double temperature_k = 0;
  std::size_t voxels = 0;
};
std::vector<RingTruth> TruthOnRings(const FireVolume& truth, const GridGeometry& fit_grid,
                                    const std::vector<RingProfilePoint>& profile,
                                    const Rigid3& fit_from_truth = Rigid3());

// The truth as a fit on `fit_grid` could at best show it: its limit, a fit's oracle. Each fitted
// voxel takes the mean thin-limit emission of the truth voxels whose centres it holds (moved by
// `fit_from_truth`), and the temperature whose emission has that colour and the density that
// gives its brightness (ThinEmissionTable through the sRGB observer over `absorption`'s
// spectrum); a voxel whose truth gives no light keeps the truth's mean density. The fitted voxels
// are those holding truth soot.
//
// With `rings` (an axisymmetric fit's FitResult::ring_profile on `fit_grid`), the light is
// pooled over each ring first, and every voxel of a ring shows the ring's: what one temperature
// and density per ring can show. A ring holds the voxels in its layer at its radius about the
// layer's axis (in fit voxels, rounded, from the voxel's centre, as the fit ties them) that hold
// truth voxels and, with `fitted_density` (the tied fit's density on `fit_grid`), where the fit
// has medium (the fit's rings hold its active voxels), else where the truth has soot. A voxel of a
// layer or radius with no ring keeps its own light. An interpolated tie
// (FitOptions::axisymmetric_interpolate) can give a ring a radial slope: the rings' limit is not
// its own, and it can pass it.
//
// Emission grows steeply with temperature, so a voxel or ring whose truth is partly hot shows the
// hot part's colour: its temperature is hotter than the truth's mean, and the soot that gives its
// light is less than the truth's (on the main job's candle at 64 from a truth of 96, about 0.93
// of the visible soot per voxel and 0.87 per ring: BENCHMARKS.md, "The soot a fit's grid
// and rings can show"). Scored with CompareWithTruth, it is the fit's limit beside the fit: what
// a fit that gave every voxel (ring) exactly its truth's light would score. Not a bound on each
// figure: a fit whose light per voxel differs from the truth's can score better on one (the main
// job's tied fits are less biased than their rings' limit, and can hold more soot at other
// temperatures). Throws InputError when the truth lacks an emission, temperature or density grid.
FireVolume LightEquivalentTruth(const FireVolume& truth, const GridGeometry& fit_grid,
                                const AbsorptionModel& absorption,
                                const Rigid3& fit_from_truth = Rigid3(),
                                const std::vector<RingProfilePoint>* rings = nullptr,
                                const std::vector<float>* fitted_density = nullptr);
// The fit's limit scored as CompareWithTruth scores the fit: LightEquivalentTruth on `fitted`'s
// grid, pooled over `rings` (a tied fit's FitResult::ring_profile; empty: per voxel) and the
// fit's medium. Not compared (why_not says why) when the truth lacks an emission, temperature or
// density grid.
TruthError CompareLimitWithTruth(const FireVolume& truth, const FireVolume& fitted,
                                 const AbsorptionModel& absorption,
                                 const std::vector<RingProfilePoint>& rings,
                                 const Rigid3& fit_from_truth = Rigid3());

// The relative L2 error of a reconstruction's emission against a truth's emission grid (resampled
// onto the reconstruction's grid when they differ): |e - e_truth| / |e_truth|. Throws DataError
// naming `truth_name` when the truth has no emission grid.
double EmissionError(const FireVolume& reconstruction, const FireVolume& truth,
                     const std::string& truth_name);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_TRUTH_H_
