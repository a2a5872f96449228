// Synthetic fires with their physics (tomography/synthetic_fire.h has the fields): the soot's
// peak volume fraction made a number density through an absorption model, and the emission a
// renderer sees in the optically thin limit, the ground truth of the tomography.
#ifndef FLAMERIG_FITTING_SYNTHETIC_FIRE_H_
#define FLAMERIG_FITTING_SYNTHETIC_FIRE_H_

#include <vector>

#include "fitting/absorption.h"
#include "tomography/synthetic_fire.h"

namespace flamerig::synthetic {

// The procedural fire (tomography/synthetic_fire.h) with its soot's peak number density from
// options.peak_soot_volume_fraction through `absorption`; metadata also names the absorption.
FireVolume MakeFire(const GridGeometry& geometry, const FireOptions& options,
                    const AbsorptionModel& absorption);

// The emission a renderer sees from each voxel in the optically thin limit, as linear sRGB radiance
// per metre of path: sigma(grey) * density * XYZ(T) -> RGB. For wavelength-dependent absorption the
// spectral integral is done per voxel. This is the ground truth of the tomography.
std::vector<float> ThinEmissionRgb(const FireVolume& fire, const AbsorptionModel& absorption);

}  // namespace flamerig::synthetic

#endif  // FLAMERIG_FITTING_SYNTHETIC_FIRE_H_
