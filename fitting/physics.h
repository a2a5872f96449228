// Physical constants and black-body radiation.
//
// Constants are CODATA 2018 (exact SI definitions where they exist). Planck's law is evaluated in
// double precision with expm1, so that it neither overflows nor loses precision anywhere in 1 K ..
// 1e5 K and 300 .. 900 nm: very cold or very short-wave arguments underflow cleanly to 0, never NaN
// or Inf. Temperatures <= 0 and non-finite inputs give 0.
#ifndef FLAMERIG_FITTING_PHYSICS_H_
#define FLAMERIG_FITTING_PHYSICS_H_

namespace flamerig::physics {

inline constexpr double kPlanckJs = 6.62607015e-34;      // h, J s (exact)
inline constexpr double kSpeedOfLightMps = 299792458.0;  // c, m/s (exact)
inline constexpr double kBoltzmannJpK = 1.380649e-23;    // k, J/K (exact)
inline constexpr double kPi = 3.14159265358979323846;
// First radiation constant for radiance, c1L = 2 h c^2, W m^2 sr^-1.
inline constexpr double kC1L = 2.0 * kPlanckJs * kSpeedOfLightMps * kSpeedOfLightMps;
// Second radiation constant, c2 = h c / k, m K.
inline constexpr double kC2 = kPlanckJs * kSpeedOfLightMps / kBoltzmannJpK;
// Stefan-Boltzmann constant, sigma = 2 pi^5 k^4 / (15 h^3 c^2), W m^-2 K^-4.
inline constexpr double kStefanBoltzmann =
    2.0 * kPi * kPi * kPi * kPi * kPi * kBoltzmannJpK * kBoltzmannJpK * kBoltzmannJpK *
    kBoltzmannJpK /
    (15.0 * kPlanckJs * kPlanckJs * kPlanckJs * kSpeedOfLightMps * kSpeedOfLightMps);

// Spectral radiance of a black body, B(lambda, T) = 2 h c^2 / lambda^5 / (exp(h c / (lambda k T)) -
// 1), in W m^-2 sr^-1 per metre of wavelength. `wavelength_m` > 0.
double PlanckRadiance(double wavelength_m, double temperature_k);

// The same per nanometre of wavelength (W m^-2 sr^-1 nm^-1), wavelength in nanometres: the unit of
// the spectral tables and the renderer.
inline double PlanckRadiancePerNm(double wavelength_nm, double temperature_k) {
  return PlanckRadiance(wavelength_nm * 1e-9, temperature_k) * 1e-9;
}

// d B / d T per nanometre (W m^-2 sr^-1 nm^-1 K^-1), analytically; 0 where B underflows.
double PlanckRadiancePerNmDerivative(double wavelength_nm, double temperature_k);

}  // namespace flamerig::physics

#endif  // FLAMERIG_FITTING_PHYSICS_H_
