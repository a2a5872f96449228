// Synthetic fires whose truth is known (STYLE.md 10: synthetic ground truth as library code,
// options with fixed seeds; the same options give bit-identical output), used by `flamerig
// simulate`, the benchmarks and the tests of every layer from the tomography up.
//
// Fires are procedural fields of temperature (K) and soot number density (m^-3) defined in the
// normalised coordinates of the reconstruction box (x and z across, y up from the box floor), so
// they fill any box. Two kinds:
//  - candle: one teardrop flame, a cooler core and a hot sheath, soot in the upper half, a gentle
//    sway over time; peak about 2000 K (candles measure 1350..2050 K) and soot volume fraction
//    about 1e-6.
//  - licks: several turbulent tongues of flame from a shared base (count, heights, leans and
//    turbulence drawn from the seed), peak about 2100 K.
//
// This layer knows no physics: the soot's peak number density is given. fitting/synthetic_fire.h
// converts a volume fraction through an absorption model and computes the emission.
#ifndef FLAMERIG_TOMOGRAPHY_SYNTHETIC_FIRE_H_
#define FLAMERIG_TOMOGRAPHY_SYNTHETIC_FIRE_H_

#include <cstdint>
#include <string>
#include <vector>

#include "tomography/volume.h"

namespace flamerig::synthetic {

enum class FireKind { kCandle, kLicks };
// "candle" | "licks"; throws InputError
FireKind FireKindFromName(const std::string& name);
const char* ToString(FireKind kind);

struct FireOptions {
  FireKind kind = FireKind::kCandle;
  std::uint64_t seed = 1;
  double time_s = 0.0;                      // animation time; frames of a recording advance it
  double peak_temperature_k = 2000.0;       // hottest temperature of the flame
  double ambient_temperature_k = 300.0;     // temperature outside the flame
  double peak_soot_volume_fraction = 1e-6;  // converted to number density with the absorption model
  int licks = 0;        // licks: number of tongues; 0 = drawn from the seed (3..6)
  int supersample = 2;  // samples per voxel edge when filling the grid; [1, 8]
  // The part of the rig the fire's normalised coordinates span; empty (default): the grid's box.
  Box3 region;
  void Validate() const;  // throws InputError naming the field
};

// Fills `geometry` with the procedural fire, its soot peaking at `peak_density_per_m3`. Returns
// temperature and density (no emission); metadata: fire, seed, time_s.
FireVolume MakeFire(const GridGeometry& geometry, const FireOptions& options,
                    double peak_density_per_m3);

}  // namespace flamerig::synthetic

#endif  // FLAMERIG_TOMOGRAPHY_SYNTHETIC_FIRE_H_
