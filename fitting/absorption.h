// How strongly soot absorps (and so, by Kirchhoff's law, emits) light: the absorption coefficient
// kappa(lambda) = density * cross_section(lambda), in 1/m, with density in particles per m^3.
//
// Models:
//  - grey: one cross-section at every wavelength. The renderer then needs only three colour
//  channels
//    per ray (the fast path).
//  - soot: Rayleigh absorption by small spherical soot particles (Pegoraro & Parker 2006):
//        cross_section(lambda) = 48 pi^2 R^3 n k / (lambda_alpha ((n^2 - k^2 + 2)^2 + 4 n^2 k^2))
//    where R is the particle radius, m = n - ik the complex refractive index of soot and
//    lambda_alpha = lambda (lambda / lambda_ref)^(alpha - 1): alpha = 1 is pure Rayleigh theory;
//    other alphas (empirical dispersion exponents, around 1.39 in the combustion literature) tilt
//    the spectrum while keeping the cross-section at lambda_ref. Wavelength-dependent, so the
//    renderer uses the spectral path.
//
// Density ranges: the paper searches 0.01e27 .. 500e27 particles/m^3, which for any plausible
// particle size means a soot volume fraction far above 1. flamerig's default bounds instead come
// from plausible soot volume fractions, 1e-9 .. 1e-4 (a candle peaks near 1e-6); both are available
// (DensityBounds).
#ifndef FLAMERIG_FITTING_ABSORPTION_H_
#define FLAMERIG_FITTING_ABSORPTION_H_

#include <string>

#include "tomography/volume.h"

namespace flamerig {

struct SootParameters {
  double particle_radius_m = 20e-9;  // R, metres; (0, 1e-6]: Rayleigh needs R << lambda
  double refractive_index_n = 1.57;  // n, real part of soot's refractive index (Dalzell & Sarofim)
  double absorption_index_k = 0.56;  // k, imaginary part
  double alpha = 1.0;                // dispersion exponent; 1 = pure Rayleigh
  double reference_wavelength_nm = 550.0;  // lambda_ref for alpha != 1
};

class AbsorptionModel {
 public:
  enum class Kind { kGrey, kSoot };

  // Grey absorption with the given cross-section (m^2 per particle, > 0 and finite).
  static AbsorptionModel Grey(double cross_section_m2);
  // Rayleigh soot. Throws InputError naming the bad parameter.
  static AbsorptionModel Soot(const SootParameters& parameters);
  // Default soot, and a grey model with the default soot's cross-section at 550 nm.
  static AbsorptionModel DefaultSoot() { return Soot(SootParameters{}); }
  static AbsorptionModel DefaultGrey();
  // "grey" or "soot" with default parameters; throws InputError for other names.
  static AbsorptionModel FromName(const std::string& name);

  Kind kind() const { return kind_; }
  bool is_grey() const { return kind_ == Kind::kGrey; }
  const SootParameters& soot() const { return soot_; }
  std::string name() const { return is_grey() ? "grey" : "soot"; }

  // Absorption cross-section per particle at a wavelength, m^2.
  double CrossSectionM2(double wavelength_nm) const;

  // Volume of one particle (m^3): 4/3 pi R^3 (the default soot radius for grey models).
  double ParticleVolumeM3() const;
  // Soot volume fraction of a number density, and back.
  double VolumeFraction(double density_per_m3) const { return density_per_m3 * ParticleVolumeM3(); }
  double DensityFromVolumeFraction(double volume_fraction) const {
    return volume_fraction / ParticleVolumeM3();
  }

 private:
  Kind kind_ = Kind::kGrey;
  double grey_cross_section_m2_ = 0;
  SootParameters soot_;
};

// Bounds on the soot number density used by the fit.
struct DensityBounds {
  double min_per_m3 = 0;
  double max_per_m3 = 0;
  std::string source;  // "plausible soot volume fraction 1e-9..1e-4" or "paper 0.01e27..500e27"

  static DensityBounds Plausible(const AbsorptionModel& model);
  static DensityBounds Paper();
};

// Says in `volume` which absorption model its densities are counted in: metadata_text
// "absorption_model" ("soot" or "grey"), and for soot the particle's radius, volume and refractive
// index (metadata_numbers soot_particle_radius_m, soot_particle_volume_m3, soot_refractive_index_n
// and _k) and, where the volume has a density, the soot's volume fraction per voxel
// (FireVolume::soot_volume_fraction, density x particle volume) with its peak and the soot's
// whole volume (soot_volume_fraction_peak; soot_volume_m3, the fraction summed over the voxels
// times a voxel's volume). The volume fraction is what a combustion paper quotes, and what the
// images determine: Rayleigh absorption grows as density x radius^3, so the number density of a
// fit is only as right as the radius assumed (20 nm by default), the volume fraction whatever it
// is. A grey model's density has no particle size: no volume fraction is written (an old one is
// cleared).
void StampAbsorption(const AbsorptionModel& model, FireVolume* volume);

}  // namespace flamerig

#endif  // FLAMERIG_FITTING_ABSORPTION_H_
