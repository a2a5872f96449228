#include "fitting/spectral_tables.h"

#include <stdexcept>
#include <string>

#include "core/error.h"
#include "fitting/camera_response.h"
#include "fitting/colour.h"
#include "fitting/physics.h"

namespace flamerig {

BlackbodyXyzTable::BlackbodyXyzTable() : xyz_(3 * (kMaxTableK + 2), 0.0) {
  for (int t = 1; t <= kMaxTableK + 1; ++t) {
    Eigen::Vector3d v = colour::BlackbodyXyz(t);
    for (int c = 0; c < 3; ++c) xyz_[3 * t + c] = v[c];
  }
}

const BlackbodyXyzTable& BlackbodyXyzTable::Get() {
  static const BlackbodyXyzTable table;
  return table;
}

template <typename Real>
void BlackbodyXyzTable::LookupExact(double temperature_k, Real* xyz) const {
  Eigen::Vector3d v = colour::BlackbodyXyz(temperature_k);
  for (int c = 0; c < 3; ++c) xyz[c] = Real(v[c]);
}
template void BlackbodyXyzTable::LookupExact<float>(double, float*) const;
template void BlackbodyXyzTable::LookupExact<double>(double, double*) const;

template <typename Real>
void BlackbodyXyzTable::LookupExactWithDerivative(double temperature_k, Real* xyz,
                                                  Real* d_xyz) const {
  // Above the table the curve is smooth and flat in T: a central difference over 1 K.
  const Eigen::Vector3d v = colour::BlackbodyXyz(temperature_k);
  const Eigen::Vector3d d =
      0.5 * (colour::BlackbodyXyz(temperature_k + 1.0) - colour::BlackbodyXyz(temperature_k - 1.0));
  for (int c = 0; c < 3; ++c) {
    xyz[c] = Real(v[c]);
    d_xyz[c] = Real(d[c]);
  }
}
template void BlackbodyXyzTable::LookupExactWithDerivative<float>(double, float*, float*) const;
template void BlackbodyXyzTable::LookupExactWithDerivative<double>(double, double*, double*) const;

SpectralBins::SpectralBins(double first_nm, double last_nm, double step_nm,
                           const ChannelResponse* response)
    : step_nm_(step_nm) {
  if (!response) response = ChannelResponse::SrgbObserver().get();
  if (response->basis_is_xyz()) {
    if (!(first_nm >= 360) || !(last_nm <= 830) || !(first_nm < last_nm) || !(step_nm > 0)) {
      throw InputError(
          "spectral bins: need 360 <= first_nm < last_nm <= 830 and step_nm > 0, got " +
          std::to_string(first_nm) + ".." + std::to_string(last_nm) + " step " +
          std::to_string(step_nm));
    }
  } else if (!(step_nm > 0) || !(first_nm >= ChannelResponse::kFirstNm - step_nm) ||
             !(last_nm <= ChannelResponse::kLastNm + step_nm) || !(first_nm <= last_nm)) {
    throw InputError(
        "spectral bins for " + response->name() + ": need " +
        std::to_string(ChannelResponse::kFirstNm) +
        " - step <= first_nm <= last_nm <= " + std::to_string(ChannelResponse::kLastNm) +
        " + step and step_nm > 0, got " + std::to_string(first_nm) + ".." +
        std::to_string(last_nm) + " step " + std::to_string(step_nm));
  }
  // Counted in double first: a tiny step would overflow an int.
  const double bins = std::floor((last_nm - first_nm) / step_nm + 1e-9) + 1;
  if (bins > kMaxBins) {
    throw InputError("spectral bins: " + std::to_string(bins) + " bins exceed the maximum of " +
                     std::to_string(kMaxBins));
  }
  const int n = static_cast<int>(bins);
  for (int i = 0; i < n; ++i) {
    centers_nm_.push_back(first_nm + i * step_nm);
    weights_.push_back(response->BinWeight(centers_nm_.back(), step_nm));
  }
  // Every colour channel needs some response in the range (spectral transmittance to RGB divides
  // by each channel's weight sum): z-bar is 0 from 650 nm on, x-bar and y-bar below 360 nm.
  Eigen::Vector3d total = Eigen::Vector3d::Zero();
  for (const auto& w : weights_) total += w;
  for (int c = 0; c < 3; ++c)
    if (!(total[c] > 0))
      throw InputError("spectral bins: " + std::to_string(first_nm) + ".." +
                       std::to_string(last_nm) + " nm hold no response of " +
                       (response->basis_is_xyz()
                            ? std::string("the CIE ") + "xyz"[c] + "-bar colour matching function"
                            : "channel " + std::to_string(c) + " of " + response->name()));
  planck_.assign(static_cast<std::size_t>(kMaxTableK + 2) * n, 0.0f);
  for (int t = 1; t <= kMaxTableK + 1; ++t) {
    for (int i = 0; i < n; ++i) {
      planck_[static_cast<std::size_t>(t) * n + i] =
          static_cast<float>(physics::PlanckRadiancePerNm(centers_nm_[i], t));
    }
  }
}

double SpectralBins::PlanckExact(int bin, double temperature_k) const {
  return physics::PlanckRadiancePerNm(centers_nm_[bin], temperature_k);
}

double SpectralBins::PlanckExactDerivative(int bin, double temperature_k) const {
  return physics::PlanckRadiancePerNmDerivative(centers_nm_[bin], temperature_k);
}

}  // namespace flamerig
