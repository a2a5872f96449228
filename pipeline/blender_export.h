// Fitted fires as `.vdb` files that Blender's Volume objects render as fire.
//
// Blender (Cycles and EEVEE, 3.2 and later; read from their sources) takes float grids named
// `density` and `temperature` as the Principled Volume's attributes with no setup, uses the file's
// transform as object space (metres at unit scale 1, Z up), and computes per unit length:
//   extinction = Density socket x density grid            (Color black: all of it absorption)
//   emission   = Temperature socket x T, then  1e-6 sigma_SB / pi x T^4 x colour(T)
//                (Blackbody Intensity 1; colour(T) has luminance 1; NOT multiplied by density)
// Our physics emits kappa(lambda) B(lambda, T) per unit length: emission scales with the soot. So:
//   density      FloatGrid, the absorption coefficient at 550 nm, 1/m (kappa = sigma_550 n): with
//                Density 1 and Color black, Blender attenuates as our renderer does at 550 nm.
//   temperature  FloatGrid, kelvin, 0 where there is no soot (Blender's blackbody would otherwise
//                make empty air at 300 K glow): set the Temperature socket to 1 (its default 1000
//                multiplies the grid). The Principled Volume's blackbody then has the right colour
//                and placement but ignores the soot's amount (bright where hot, not where hot and
//                sooty).
//   emission     Vec3SGrid, the emitted radiance per metre in linear sRGB (our renderer's units,
//                W m^-2 sr^-1 nm^-1 per m, luminance-normalised): exactly what our renderer
//                integrates in the thin limit. `tools/blender_fire.py` builds the material that uses
//                it (Emission Color from this grid, Strength 1): the physically right picture.
//   flame        FloatGrid, the luminance of `emission` (for users who prefer a strength map).
// Grid transforms are turned from the rig frame to Blender's Z-up, taking the rig's up
// (Rig::up_in_rig) to Blender's +Z so the flame stands upright: for a y-up rig (the ring frame,
// the simulator's) (x, y, z)_blender = (x, -z, y)_rig, a rotation of +90 degrees about X; for the
// first camera's frame, whose up is -y, (x, z, -y)_rig, so that a Blender camera looking along +y
// sees what that camera saw. (Until 2026-12-02 every rig was taken as y-up, and a rig calibrated
// in its first camera's frame gave an upside-down fire.)
// File metadata: exposure (render the sequence with Film > Exposure = log2(exposure) stops and the
// "Standard" view transform to get the camera's image), units, the frame and its source frame id
// (where the fitted volume has them), no_fire 1 for a frame set without fire (fitting/fit.h's
// NoFireResult), the absorption model.
#ifndef FLAMERIG_PIPELINE_BLENDER_EXPORT_H_
#define FLAMERIG_PIPELINE_BLENDER_EXPORT_H_

#include <Eigen/Core>
#include <string>

#include "fitting/absorption.h"
#include "tomography/volume.h"

namespace flamerig {

struct BlenderGrids {
  std::vector<float> density_per_m;       // kappa at 550 nm, 1/m
  std::vector<float> temperature_k;       // 0 where there is no soot
  std::vector<float> emission_rgb_per_m;  // 3 per voxel
  std::vector<float> flame;               // luminance of emission
};

// The grids above from a fitted volume (temperature and density on its grid). Throws
// InputError when the volume lacks either field.
BlenderGrids MakeBlenderGrids(const FireVolume& fitted, const AbsorptionModel& absorption);

// Writes them to `path` (to path.tmp, then renamed); IoError naming the path on failure.
void WriteBlenderVdb(const std::string& path, const FireVolume& fitted,
                     const AbsorptionModel& absorption,
                     const Eigen::Vector3d& up_in_rig = Eigen::Vector3d::UnitY());

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_BLENDER_EXPORT_H_
