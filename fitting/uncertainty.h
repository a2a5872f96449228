// Per-voxel confidence of a fit: the standard deviation of each active voxel's temperature and
// log density, from the data's Gauss-Newton curvature at the fitted volume, and whether the images
// determine the voxel at all (issue 19, item 5). Written into every fitted .vdb as the grids
// `temperature_sigma` (K), `density_sigma` (sigma of ln n: 0.1 is about 10%) and `determined`.
//
// The model: each pixel's CIELab value (the data term's residuals, 3 per pixel of every fitted
// view) is the rendered one plus independent Gaussian noise of one deviation sigma_lab, estimated
// from the fit's own residuals over fire pixels (sum of squares over the residuals' count less two
// per active voxel): model error counts as noise, so the sigma is not flattered by a model that
// cannot match. Per voxel, the 2x2 precision over (T, ln n) is J^T J / sigma_lab^2 (the voxel's
// exact diagonal block, FitObjective::DataCurvature) plus a weak prior: the search range as
// a uniform distribution (deviation (t_max - t_min) / sqrt(12) for T, likewise for ln n between the
// density bounds), so that a voxel the images do not see keeps the prior's deviation instead of an
// infinite one. Its inverse gives the two deviations.
//
// What it leaves out, and so how to read it: each voxel's deviation holds the others at the fit
// (the block diagonal of the precision), so trade-offs between voxels along one ray, which two
// views cannot separate, are not in it, nor is the neighbour prior. Its calibration against a
// synthetic truth (the share of visible voxels within one and two sigma) is measured in
// BENCHMARKS.md and by pipeline_uncertainty_test.
//
// A tied fit (FitOptions::axisymmetric: one temperature and density per ring of voxels) has one
// (T, ln n) per group: `groups` (lists of active indices) then sums its members' blocks into the
// group's precision, every member takes the group's deviations, and the noise level's degrees of
// freedom are the residuals less two per group.
//
// `determined`: 1 where the temperature's deviation is below `determined_fraction` of the prior's,
// i.e. where the images, not the search range, say what the temperature is.
#ifndef FLAMERIG_FITTING_UNCERTAINTY_H_
#define FLAMERIG_FITTING_UNCERTAINTY_H_

#include <cstdint>
#include <vector>

#include "fitting/objective.h"
#include "tomography/volume.h"

namespace flamerig {

struct UncertaintyOptions {
  double determined_fraction = 0.5;  // of the prior's temperature deviation
  void Validate() const;             // throws InputError naming the field
};

struct VoxelUncertainty {
  std::vector<float> temperature_sigma_k;  // per active voxel
  std::vector<float> log_density_sigma;    // per active voxel
  std::vector<float> determined;           // per active voxel: 1 or 0
  double sigma_lab = 0;                    // the noise per Lab residual
  double prior_sigma_k = 0;                // the search range's deviation
  std::size_t determined_count = 0;
  double seconds = 0;
};

// At the fitted temperatures `t`, densities `n` (per active voxel of `objective`) and exposure `s`.
// `groups`: null, or the tied fit's groups (every active voxel in exactly one).
VoxelUncertainty EstimateUncertainty(const FitObjective& objective, const std::vector<double>& t,
                                     const std::vector<double>& n, double s,
                                     const UncertaintyOptions& options,
                                     const std::vector<std::vector<std::size_t>>* groups = nullptr);

// Writes the three grids into `volume` (on `grid`, whose voxels `active` are the estimate's; 0
// elsewhere) and the noise level and determined count into its metadata.
void StoreUncertainty(const GridGeometry& grid, const std::vector<std::uint32_t>& active,
                      const VoxelUncertainty& u, FireVolume* volume);

}  // namespace flamerig

#endif  // FLAMERIG_FITTING_UNCERTAINTY_H_
