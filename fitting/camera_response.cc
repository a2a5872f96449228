#include "fitting/camera_response.h"

#include <cmath>
#include <deque>
#include <map>
#include <mutex>
#include <sstream>

#include "core/error.h"
#include "fitting/colour.h"
#include "fitting/physics.h"

namespace flamerig {

std::shared_ptr<const ChannelResponse> ChannelResponse::SrgbObserver() {
  static const std::shared_ptr<const ChannelResponse> observer = [] {
    std::shared_ptr<ChannelResponse> r(new ChannelResponse());
    r->name_ = "sRGB observer";
    r->output_from_basis_ = colour::LinearSrgbFromXyz();
    r->rows_ = BlackbodyXyzTable::Get().rows();
    return r;
  }();
  return observer;
}

std::shared_ptr<const ChannelResponse> ChannelResponse::ForCamera(
    const CameraRadiometry& radiometry) {
  radiometry.Validate("camera response");
  const SpectralSensitivity& s = radiometry.spectral;
  const bool observer = s.kind == SpectralSensitivity::Kind::kSrgbObserver;
  if (observer && radiometry.gain == Eigen::Vector3d::Ones()) return SrgbObserver();

  // One response per distinct sensitivity and gain: its key is everything that defines it.
  std::ostringstream key;
  key.precision(17);
  key << int(s.kind) << "|" << s.filter.centre_nm << "/" << s.filter.fwhm_nm << "|"
      << radiometry.gain.transpose() << "|";
  for (const SpectralBand& b : s.bands) key << b.centre_nm << "/" << b.fwhm_nm << ",";
  for (std::size_t i = 0; i < s.wavelengths_nm.size(); ++i) {
    key << s.wavelengths_nm[i];
    for (const auto& col : s.columns) key << ":" << col[i];
    key << ",";
  }
  static std::mutex mutex;
  // Weak entries, so that a response lives as long as its users, and the last few built held
  // strongly, so that a caller asking again and again (calibration, simulate) builds one once.
  static std::map<std::string, std::weak_ptr<const ChannelResponse>> cache;
  static std::deque<std::shared_ptr<const ChannelResponse>> recent;
  constexpr std::size_t kRecent = 8;
  std::lock_guard<std::mutex> lock(mutex);
  if (auto found = cache[key.str()].lock()) return found;
  for (auto it = cache.begin(); it != cache.end();)
    it = it->second.expired() && it->first != key.str() ? cache.erase(it) : std::next(it);

  std::shared_ptr<ChannelResponse> r(new ChannelResponse());
  r->name_ = s.Describe();
  r->channels_ = s.channels();
  r->gain_ = radiometry.gain;
  if (observer) {
    r->output_from_basis_ = radiometry.gain.asDiagonal() * colour::LinearSrgbFromXyz();
    r->rows_ = BlackbodyXyzTable::Get().rows();
  } else {
    r->observer_ = false;
    r->first_nm_ = kFirstNm;
    r->last_nm_ = kLastNm;
    const double ybar = colour::CieObserver::Cie1931TwoDegree().YIntegral();
    // Raw sensitivities, then scaled so that the largest channel integral is Ybar.
    const int n = kLastNm - kFirstNm + 1;
    std::vector<Eigen::Vector3d> raw(n);
    Eigen::Vector3d integral = Eigen::Vector3d::Zero();
    for (int i = 0; i < n; ++i) {
      for (int c = 0; c < 3; ++c)
        raw[i][c] = s.RawAt(r->channels_ == 1 ? 0 : c, double(kFirstNm + i));
      integral += raw[i];
    }
    if (!(integral.minCoeff() > 0))
      throw InputError("camera response (" + r->name_ + "): a channel has no sensitivity between " +
                       std::to_string(kFirstNm) + " and " + std::to_string(kLastNm) + " nm");
    const double scale = ybar / integral.maxCoeff();
    r->basis_.resize(n);
    // basis = S * gain / Ybar, so that basis = sum L S gain / Ybar over 1 nm steps.
    for (int i = 0; i < n; ++i)
      r->basis_[i] = (raw[i] * scale).cwiseProduct(radiometry.gain) / ybar;
    Eigen::Vector3d peak = Eigen::Vector3d::Zero();
    for (const auto& b : r->basis_) peak = peak.cwiseMax(b.cwiseAbs());
    auto responds = [&](int i) {
      for (int c = 0; c < 3; ++c)
        if (std::abs(r->basis_[i][c]) > kSupportShare * peak[c]) return true;
      return false;
    };
    int lo = 0, hi = n - 1;
    while (lo < hi && !responds(lo)) ++lo;
    while (hi > lo && !responds(hi)) --hi;
    r->support_first_nm_ = kFirstNm + lo;
    r->support_last_nm_ = kFirstNm + hi;
    r->table_.assign(3 * (kMaxTableK + 2), 0.0);
    for (int t = 1; t <= kMaxTableK + 1; ++t) {
      Eigen::Vector3d v = Eigen::Vector3d::Zero();
      for (int i = 0; i < n; ++i)
        v += physics::PlanckRadiancePerNm(double(kFirstNm + i), double(t)) * r->basis_[i];
      for (int c = 0; c < 3; ++c) r->table_[3 * t + c] = v[c];
    }
    r->rows_ = r->table_.data();
  }
  cache[key.str()] = r;
  recent.push_back(r);
  if (recent.size() > kRecent) recent.pop_front();
  return r;
}

std::shared_ptr<const ChannelResponse> ChannelResponse::Exposed(
    const std::shared_ptr<const ChannelResponse>& response, double factor) {
  if (!(factor > 0) || !std::isfinite(factor))
    throw InputError("camera response (" + (response ? response->name() : "sRGB observer") +
                     "): an exposure factor of " + std::to_string(factor) +
                     " (must be finite and > 0)");
  const auto& base = response ? response : SrgbObserver();
  if (factor == 1) return base;
  // Everything but the table, which stays the base's (held by base_; the observer's rows are
  // BlackbodyXyzTable's): a camera's re-exposed frame costs no table.
  std::shared_ptr<ChannelResponse> r(new ChannelResponse());
  r->name_ = base->name_;
  r->channels_ = base->channels_;
  r->observer_ = base->observer_;
  r->output_from_basis_ = factor * base->output_from_basis_;
  r->gain_ = factor * base->gain_;
  r->first_nm_ = base->first_nm_;
  r->last_nm_ = base->last_nm_;
  r->support_first_nm_ = base->support_first_nm_;
  r->support_last_nm_ = base->support_last_nm_;
  r->basis_ = base->basis_;
  r->rows_ = base->rows_;
  r->base_ = base;
  return r;
}

Eigen::Vector3d ChannelResponse::At(int nm) const {
  if (nm < first_nm_ || nm > last_nm_) return Eigen::Vector3d::Zero();
  if (observer_) {
    const auto& cie = colour::CieObserver::Cie1931TwoDegree();
    return cie.At(nm) / cie.YIntegral();
  }
  return basis_[nm - first_nm_];
}

Eigen::Vector3d ChannelResponse::BasisAt(double wavelength_nm) const {
  if (!(wavelength_nm >= first_nm_) || !(wavelength_nm <= last_nm_)) return Eigen::Vector3d::Zero();
  const int i = std::min(static_cast<int>(wavelength_nm), last_nm_ - 1);
  const double f = wavelength_nm - i;
  return (1 - f) * At(i) + f * At(i + 1);
}

Eigen::Vector3d ChannelResponse::Blackbody(double temperature_k) const {
  return Integrate([&](double nm) { return physics::PlanckRadiancePerNm(nm, temperature_k); });
}

template <typename Real>
void ChannelResponse::LookupExact(double temperature_k, Real* out) const {
  Eigen::Vector3d v = Eigen::Vector3d::Zero();
  for (int nm = first_nm_; nm <= last_nm_; ++nm)
    v += physics::PlanckRadiancePerNm(double(nm), temperature_k) * At(nm);
  for (int c = 0; c < 3; ++c) out[c] = Real(v[c]);
}
template void ChannelResponse::LookupExact<float>(double, float*) const;
template void ChannelResponse::LookupExact<double>(double, double*) const;

Eigen::Vector3d ChannelResponse::BinWeight(double centre_nm, double step_nm) const {
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  const int sub = std::max(1, static_cast<int>(std::round(step_nm * 10)));
  for (int k = 0; k < sub; ++k)
    sum += BasisAt(centre_nm - 0.5 * step_nm + (k + 0.5) * step_nm / sub);
  return sum / sub * step_nm;
}

}  // namespace flamerig
