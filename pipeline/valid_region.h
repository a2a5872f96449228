// The valid-intrinsics region of calibrated camera models, as mrcal-calibrate-cameras writes it:
// the part of each imager where the calibration can be trusted, a closed contour in pixels stored
// in the .cameramodel as 'valid_intrinsics_region', which mrcal-show-valid-intrinsics-region,
// mrcal-show-projection-uncertainty and mrcal-show-distortion-off-pinhole draw.
//
// mrcal computes it in Python (mrcal/calibration.py's _compute_valid_intrinsics_region) from the
// solve's optimization_inputs, which our models carry (calibration/mrcal_inputs.h): the imager is
// cut into a grid of `grid_width` cells across; a cell is valid where mrcal's linearised
// projection uncertainty at the cell's centre (worst direction, 1 sigma) is below `uncertainty`
// times the residuals' standard deviation, and (for lens models other than splined ones) the
// corners observed in the cell number more than `count`, their residuals' mean is below `mean`
// px and their standard deviation below `stdev` times the residuals' deviation; the region is
// the outline of the largest group of valid cells. Rather than write that again, this runs
// mrcal's own function on the written models, with mrcal-calibrate-cameras's defaults, so that
// the region is the one mrcal's tool would have written for the same solve.
//
// It needs python3 with mrcal's package (Debian's python3-mrcal, which scripts/install-deps.sh
// installs); without it, or when mrcal refuses a model, the models are left without a region and
// the reason is returned.
#ifndef FLAMERIG_PIPELINE_VALID_REGION_H_
#define FLAMERIG_PIPELINE_VALID_REGION_H_

#include <Eigen/Core>
#include <string>
#include <vector>

namespace flamerig {

// mrcal-calibrate-cameras's --valid-intrinsics-region-parameters (its defaults: 1 0.5 1.5 3 0).
struct ValidRegionParameters {
  double uncertainty = 1;  // times the residuals' standard deviation
  double mean = 0.5;       // px
  double stdev = 1.5;      // times the residuals' standard deviation
  int count = 3;           // corners a cell needs, exclusive
  double distance_m = 0;   // where the uncertainty is evaluated; 0: at infinity
  int grid_width = 30;     // cells across the imager (mrcal's gridn_width)

  // From the five numbers in mrcal's order (uncertainty, mean, stdev, count, distance), as
  // mrcal-calibrate-cameras takes them. Throws InputError naming `where` when there are not five,
  // one is not finite, a threshold is not above zero, the count is not a whole number >= 0 or
  // the distance is below zero.
  static ValidRegionParameters FromMrcal(const std::vector<double>& five, const std::string& where);
  // "1 0.5 1.5 3 0": as they are passed to mrcal-calibrate-cameras.
  std::string ToMrcal() const;
  // "at infinity" or "at 0.3 m".
  std::string DistanceText() const;
};

struct ValidRegion {
  std::string model_path;
  bool computed = false;  // false: see error
  std::string error;
  // Closed (the first point repeated last), in pixels; empty when computed and no cell is valid.
  std::vector<Eigen::Vector2i> contour;
  double imager_fraction = 0;  // the contour's area over the imager's
  // mrcal's projection uncertainty (worst direction, 1 sigma, px) over the grid's cell centres at
  // the parameters' distance, its least and its median, and the standard deviation of the
  // solve's board residuals that scales the thresholds: a region is empty when the least is
  // above `uncertainty` times the deviation.
  double min_uncertainty_px = 0, median_uncertainty_px = 0, residual_sigma_px = 0;
};

// Computes each model's region (one python3 run for all of them) and writes it into the model
// (inserted before its closing brace, the file rewritten atomically), replacing none: the models
// must not have one yet. Returns one entry per path, in order; when python3 or mrcal cannot be
// run, every entry says why and no file is changed.
std::vector<ValidRegion> AddValidIntrinsicsRegions(const std::vector<std::string>& model_paths,
                                                   const ValidRegionParameters& parameters = {});

// The region a .cameramodel holds ('valid_intrinsics_region'), or an empty vector when it has
// none. Throws IoError when the file cannot be read, DataError when the region is malformed.
std::vector<Eigen::Vector2i> ReadValidIntrinsicsRegion(const std::string& model_path);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_VALID_REGION_H_
