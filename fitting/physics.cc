#include "fitting/physics.h"

#include <cmath>

namespace flamerig::physics {

double PlanckRadiance(double wavelength_m, double temperature_k) {
  if (!(temperature_k > 0) || !(wavelength_m > 0) || !std::isfinite(temperature_k) ||
      !std::isfinite(wavelength_m)) {
    return 0.0;
  }
  const double x = kC2 / (wavelength_m * temperature_k);
  if (x > 700.0) return 0.0;  // exp(x) would overflow; the radiance is below 1e-280 of its peak
  const double l2 = wavelength_m * wavelength_m;
  const double l5 = l2 * l2 * wavelength_m;
  return kC1L / l5 / std::expm1(x);
}

double PlanckRadiancePerNmDerivative(double wavelength_nm, double temperature_k) {
  if (!(temperature_k > 0) || !(wavelength_nm > 0) || !std::isfinite(temperature_k)) return 0.0;
  const double lambda_m = wavelength_nm * 1e-9;
  const double x = kC2 / (lambda_m * temperature_k);
  if (x > 700.0) return 0.0;
  // dB/dT = B * x / T * e^x / (e^x - 1) = B * x / T / (1 - e^-x)
  const double b = PlanckRadiancePerNm(wavelength_nm, temperature_k);
  return b * x / temperature_k / (-std::expm1(-x));
}

}  // namespace flamerig::physics
