// The tomography's settings in a YAML file, for `reconstruct`, `fit` and `run`
// (--tomography-config T.yaml); config/tomography.yaml lists every key with its default:
//
//   tomography:
//     resolution: 64            # voxels along the box's longest side
//     bin: 1                    # pixels binned bin x bin before the tomography
//     input_transfer: srgb      # 8-bit images: srgb | linear | gamma=G (frame_source.h)
//     solver: osem              # osem | sart | cgls
//     max_iterations: 100
//     relaxation: 1.5           # SART's lambda
//     stagnation_tolerance: -1  # stop when an iteration improves the residual less; 0 never;
//                               # -1 the solver's own (osem 1e-3, sart and cgls 5e-3)
//     warm_stagnation_tolerance: 0.02  # the same, warm-started osem with 4 cameras or more
//     two_view_fine_iterations: 1  # two cameras, osem or os-sart: the fine level's sweeps from
//                                  # a start; -1 the solve's own rules
//     holdout_patience: 10
//     prior: none               # osem's smoothness prior: none | quadratic | tv (prior.h)
//     prior_weight: -1          # unit-free; -1 the prior's own (tv 3e-4, quadratic 1e-5)
//     prior_edge: 1             # TV: gradient below which it smooths quadratically
//     coarse_to_fine: true
//     coarse_iterations: 30
//     envelope_margin_voxels: 4
//     cache: ""                 # folder of cached system matrices, relative to this file
//     mask:                     # visual_hull.h
//       threshold_sigmas: 5
//       noise: 0                # radiance units; 0 = estimated per camera
//       dilation_px: 2
//       min_views: 2
//       min_speck_px: -1        # -1 = half a voxel's projected area
//
// Keys left out keep the values the caller had; unknown keys, wrong types and values out of range
// are InputErrors naming the file and the key.
#ifndef FLAMERIG_PIPELINE_TOMOGRAPHY_CONFIG_H_
#define FLAMERIG_PIPELINE_TOMOGRAPHY_CONFIG_H_

#include <string>

#include "tomography/reconstruct.h"

namespace flamerig {

void LoadTomographyConfig(const std::string& path, ReconstructOptions* options,
                          std::string* input_transfer);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_TOMOGRAPHY_CONFIG_H_
