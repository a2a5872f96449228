#include "fitting/synthetic_fire.h"

#include <tbb/parallel_for.h>

#include "fitting/colour.h"
#include "fitting/physics.h"
#include "fitting/spectral_tables.h"

namespace flamerig::synthetic {

FireVolume MakeFire(const GridGeometry& geometry, const FireOptions& options,
                    const AbsorptionModel& absorption) {
  options.Validate();
  FireVolume fire = MakeFire(
      geometry, options, absorption.DensityFromVolumeFraction(options.peak_soot_volume_fraction));
  StampAbsorption(absorption, &fire);
  return fire;
}

std::vector<float> ThinEmissionRgb(const FireVolume& fire, const AbsorptionModel& absorption) {
  const std::size_t n = fire.geometry.num_voxels();
  std::vector<float> rgb(3 * n, 0.0f);
  const Eigen::Matrix3d& to_rgb = colour::LinearSrgbFromXyz();
  const auto& cie = colour::CieObserver::Cie1931TwoDegree();
  const BlackbodyXyzTable& table = BlackbodyXyzTable::Get();
  const double sigma550 = absorption.CrossSectionM2(550);
  std::vector<double> sigma(colour::CieObserver::kCount);
  for (int i = 0; i < colour::CieObserver::kCount; ++i) {
    sigma[i] = absorption.CrossSectionM2(colour::CieObserver::kFirstNm + i);
  }
  tbb::parallel_for(std::size_t(0), n, [&](std::size_t f) {
    double density = fire.density_per_m3[f];
    if (!(density > 0)) return;
    double t = fire.temperature_k[f];
    Eigen::Vector3d xyz;
    if (absorption.is_grey()) {
      double v[3];
      table.Lookup(t, v);
      xyz = sigma550 * density * Eigen::Vector3d(v[0], v[1], v[2]);
    } else {
      int i = 0;
      xyz = cie.Integrate(
          [&](double nm) { return sigma[i++] * density * physics::PlanckRadiancePerNm(nm, t); });
    }
    Eigen::Vector3d c = to_rgb * xyz;
    for (int ch = 0; ch < 3; ++ch) rgb[3 * f + ch] = static_cast<float>(c[ch]);
  });
  return rgb;
}

}  // namespace flamerig::synthetic
