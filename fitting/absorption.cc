#include "fitting/absorption.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "core/error.h"
#include "fitting/physics.h"

namespace flamerig {

AbsorptionModel AbsorptionModel::Grey(double cross_section_m2) {
  if (!(cross_section_m2 > 0) || !std::isfinite(cross_section_m2)) {
    throw InputError("grey absorption: cross_section_m2 = " + std::to_string(cross_section_m2) +
                     " must be finite and > 0");
  }
  AbsorptionModel m;
  m.kind_ = Kind::kGrey;
  m.grey_cross_section_m2_ = cross_section_m2;
  return m;
}

AbsorptionModel AbsorptionModel::Soot(const SootParameters& p) {
  auto check = [](double v, double lo, double hi, const char* name) {
    if (!(v > lo) || !(v <= hi) || !std::isfinite(v)) {
      throw InputError(std::string("soot absorption: ") + name + " = " + std::to_string(v) +
                       " must be in (" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
    }
  };
  check(p.particle_radius_m, 0, 1e-6, "particle_radius_m");
  check(p.refractive_index_n, 0, 10, "refractive_index_n");
  check(p.absorption_index_k, 0, 10, "absorption_index_k");
  check(p.alpha, 0, 5, "alpha");
  check(p.reference_wavelength_nm, 100, 2000, "reference_wavelength_nm");
  AbsorptionModel m;
  m.kind_ = Kind::kSoot;
  m.soot_ = p;
  return m;
}

AbsorptionModel AbsorptionModel::DefaultGrey() { return Grey(DefaultSoot().CrossSectionM2(550.0)); }

AbsorptionModel AbsorptionModel::FromName(const std::string& name) {
  if (name == "grey" || name == "gray") return DefaultGrey();
  if (name == "soot") return DefaultSoot();
  throw InputError("absorption model '" + name + "' is unknown; use 'grey' or 'soot'");
}

double AbsorptionModel::CrossSectionM2(double wavelength_nm) const {
  if (is_grey()) return grey_cross_section_m2_;
  const double n = soot_.refractive_index_n, k = soot_.absorption_index_k;
  const double r = soot_.particle_radius_m;
  const double a = n * n - k * k + 2;
  const double denominator = a * a + 4 * n * n * k * k;
  const double lambda_m = wavelength_nm * 1e-9;
  const double lambda_alpha =
      lambda_m * std::pow(wavelength_nm / soot_.reference_wavelength_nm, soot_.alpha - 1);
  return 48.0 * physics::kPi * physics::kPi * r * r * r * n * k / (lambda_alpha * denominator);
}

double AbsorptionModel::ParticleVolumeM3() const {
  double r = is_grey() ? SootParameters{}.particle_radius_m : soot_.particle_radius_m;
  return 4.0 / 3.0 * physics::kPi * r * r * r;
}

DensityBounds DensityBounds::Plausible(const AbsorptionModel& model) {
  return DensityBounds{model.DensityFromVolumeFraction(1e-9), model.DensityFromVolumeFraction(1e-4),
                       "plausible soot volume fraction 1e-9..1e-4"};
}

DensityBounds DensityBounds::Paper() {
  return DensityBounds{0.01e27, 500e27, "paper 0.01e27..500e27"};
}

void StampAbsorption(const AbsorptionModel& model, FireVolume* volume) {
  volume->metadata_text["absorption_model"] = model.name();
  volume->soot_volume_fraction.clear();
  for (const char* key :
       {"soot_particle_radius_m", "soot_particle_volume_m3", "soot_refractive_index_n",
        "soot_refractive_index_k", "soot_volume_fraction_peak", "soot_volume_m3"})
    volume->metadata_numbers.erase(key);
  if (model.is_grey()) return;
  const double particle = model.ParticleVolumeM3();
  volume->metadata_numbers["soot_particle_radius_m"] = model.soot().particle_radius_m;
  volume->metadata_numbers["soot_particle_volume_m3"] = particle;
  volume->metadata_numbers["soot_refractive_index_n"] = model.soot().refractive_index_n;
  volume->metadata_numbers["soot_refractive_index_k"] = model.soot().absorption_index_k;
  const std::vector<float>& n = volume->density_per_m3;
  if (n.empty()) return;
  std::vector<float>& fv = volume->soot_volume_fraction;
  fv.resize(n.size());
  double peak = 0, sum = 0;
  for (std::size_t i = 0; i < n.size(); ++i) {
    const double f = double(n[i]) * particle;
    fv[i] = static_cast<float>(f);
    peak = std::max(peak, f);
    sum += f;
  }
  volume->metadata_numbers["soot_volume_fraction_peak"] = peak;
  volume->metadata_numbers["soot_volume_m3"] = sum * volume->geometry.voxel_size_m.prod();
}

}  // namespace flamerig
