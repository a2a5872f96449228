// Per-voxel confidence of a fit: the standard deviation of each active voxel's temperature and
// log density, from the data's Gauss-Newton curvature at the fitted volume, and whether the images
// determine the voxel at all (issue 19, item 5). Written into every fitted .vdb as the grids
// `temperature_sigma` (K), `density_sigma` (sigma of ln n: 0.1 is about 10%) and `determined`.
//
// The model: each pixel's CIELab value (the data term's residuals, 3 per pixel of every fitted
// view) is the rendered one plus independent Gaussian noise of one deviation sigma_lab, estimated
// from the fit's own residuals over fire pixels by their successive differences: half the mean
// squared difference between the residuals of neighbouring fire pixels (FitObjective::Curvature),
// times the residuals' count over their degrees of freedom (the count less two per unknown, at
// least half the count); with fewer than 30 such pairs, the residuals' level instead. Noise
// independent from pixel to pixel passes into that whole; the error of a model that cannot hold
// what the images show (a ring's fit of a swaying flame, a grid coarser than the fire) changes
// slowly across the image and mostly cancels in it, and so does noise that neighbouring pixels
// share (a codec's blocks, demosaicing, blur), which the estimate therefore understates. The
// residuals' plain level, noise and model error together, is `residual_lab`. Until 2026-11-28 the
// residuals' level was taken as the noise: on two views its sigma held 81 to 93% (tied fit) and
// 85 to 96% (untied) of the visible voxels within one sigma, because a ring averages opposite
// sides of the flame and so much of the model error the level counted (BENCHMARKS.md, "The
// sigma's noise from neighbouring pixels"). Per voxel, the 2x2 precision over (T, ln n) is
// J^T J / sigma_lab^2 (the voxel's exact diagonal block, FitObjective::DataCurvature) plus a weak
// prior: the search range as
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
// A tied fit (FitOptions::axisymmetric) has one (T, ln n) per node, and each voxel's parameters
// are a weighted sum of at most two nodes' (NodeTie: a ring's node, weight 1; or the two nodes at
// the whole radii either side of the voxel's, weights 1 - f and f, FitOptions::
// axisymmetric_interpolate). The nodes' precision is A^T H A plus the prior, where H holds the
// voxels' blocks and A the weights (a voxel's parameter moves by its weight when a node's does):
// a node's diagonal block sums its voxels' blocks x their weights squared, and two nodes that share
// voxels are coupled by the blocks x the product of the weights. Its inverse, taken per component
// of nodes that share voxels (an interpolated tie's layer; a ring is a component alone, where this
// is the 2x2 algebra above), gives each voxel's variance as w^T C w over its nodes' covariance C.
// Nodes that share a voxel trade against each other (one up, the other down, the voxel between
// them unmoved), which the nodes' own blocks leave out: their deviations grow, and a half-way
// voxel's is what the images hold of it. Measured on the interpolated tied fit (BENCHMARKS.md, "The
// interpolated tie's sigma from its nodes' covariance"): the main job 51 to 66% of the visible
// voxels within one sigma, `simulate`'s candle seeds 69 to 81%. Until 2026-12-03 a voxel's
// deviation was the bound sum_k w_k sigma_k over the nodes' block-diagonal deviations (58 to 75%
// and 76 to 85%); that bound stays for a component of more than `max_dense_nodes` nodes or one the
// Cholesky factorisation refuses. The noise level's degrees of freedom are the residuals less two
// per node. With weights 1 (`groups`: lists of active indices) every member takes its group's
// deviations.
//
// `determined`: 1 where the temperature's deviation is below `determined_fraction` of the prior's,
// i.e. where the images, not the search range, say what the temperature is.
//
// One band (OneBand: every fitted view a mono camera with the same spectral response, e.g. all
// behind one 650 nm filter): the images give each voxel's emission in that band, which any
// temperature makes with a matching density, so neither is determined whatever the curvature says
// (a band's self-absorption separates them a little, and the noise-level curvature called 60% of
// such a rig's voxels determined, their errors 400 K): every voxel gets the prior's deviations and
// none is determined. Two bands or more (two-colour pyrometry) measure the temperature.
#ifndef FLAMERIG_FITTING_UNCERTAINTY_H_
#define FLAMERIG_FITTING_UNCERTAINTY_H_

#include <array>
#include <cstdint>
#include <vector>

#include "fitting/objective.h"
#include "tomography/volume.h"

namespace flamerig {

struct UncertaintyOptions {
  double determined_fraction = 0.5;  // of the prior's temperature deviation
  // A tied fit's component of nodes that share voxels is inverted densely up to this many nodes
  // (a 2n x 2n matrix); a larger one takes the bound sum_k w_k sigma_k. An interpolated tie's
  // components are its layers, a node per voxel of the radius (tens).
  std::size_t max_dense_nodes = 256;
  void Validate() const;  // throws InputError naming the field
};

struct VoxelUncertainty {
  std::vector<float> temperature_sigma_k;  // per active voxel
  std::vector<float> log_density_sigma;    // per active voxel
  std::vector<float> determined;           // per active voxel: 1 or 0
  double sigma_lab = 0;      // the noise per Lab residual (from neighbouring pixels' differences)
  double residual_lab = 0;   // the residuals' level per Lab residual: noise and model error
  double prior_sigma_k = 0;  // the search range's deviation
  std::size_t determined_count = 0;
  bool one_band = false;  // OneBand(the fitted views): the prior's deviations everywhere
  double seconds = 0;
};

// True when every view is a mono camera and all share one spectral response (by
// ChannelResponse::name(): sensitivity and filter, not gains): the images hold no temperature.
bool OneBand(const std::vector<FitView>& views);

// A tied fit's parameters: active voxel a's are sum over k of weight[a][k] x those of node
// node[a][k] (a weight of 0 leaves its node out). FastFit's interpolated tie weighs its nodes in
// the fit's parameters (the logit of T's place in its range, likewise of ln n's), and the curvature
// blocks are in T and ln n: the weights hold there to first order, between nodes of like values.
struct NodeTie {
  std::size_t nodes = 0;
  std::vector<std::array<std::uint32_t, 2>> node;  // per active voxel, each < nodes
  std::vector<std::array<double, 2>> weight;       // per active voxel, each in [0, 1]
};

// At the fitted temperatures `t`, densities `n` (per active voxel of `objective`) and exposure `s`.
// `groups`: null, or the tied fit's groups (every active voxel in exactly one).
VoxelUncertainty EstimateUncertainty(const FitObjective& objective, const std::vector<double>& t,
                                     const std::vector<double>& n, double s,
                                     const UncertaintyOptions& options,
                                     const std::vector<std::vector<std::size_t>>* groups = nullptr);
// The same for a fit tied to nodes (every active voxel with a weight above 0 on one node at least).
VoxelUncertainty EstimateUncertainty(const FitObjective& objective, const std::vector<double>& t,
                                     const std::vector<double>& n, double s,
                                     const UncertaintyOptions& options, const NodeTie& tie);

// Writes the three grids into `volume` (on `grid`, whose voxels `active` are the estimate's; 0
// elsewhere) and the noise level, the residuals' level and the determined count into its metadata
// (sigma_lab, residual_lab, determined_voxels; one_band 1 when the estimate's was).
void StoreUncertainty(const GridGeometry& grid, const std::vector<std::uint32_t>& active,
                      const VoxelUncertainty& u, FireVolume* volume);

}  // namespace flamerig

#endif  // FLAMERIG_FITTING_UNCERTAINTY_H_
