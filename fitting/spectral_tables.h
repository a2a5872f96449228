// Precomputed black-body tables used by the renderer's inner loops.
//
// BlackbodyXyzTable: XYZ (normalised by the integral of ybar, see colour.h) of a black body at
// every
//   kelvin from 0 to kMaxTableK, linearly interpolated in between (relative error below 3e-4 above
//   800 K, where fires are visible; 1.9e-4 measured at 800 K in Z, less in X and Y and at higher
//   T). Above kMaxTableK values are computed exactly (slow but correct). This is what lets a grey
//   medium carry three channels per ray instead of a spectrum.
// SpectralBins: the wavelengths of the spectral path (bin centres, first..last in steps) with the
//   colour matching functions averaged over each bin, and a per-bin Planck table with the same 1 K
//   spacing.
//
// Both are immutable after construction and safe to share between threads.
#ifndef FLAMERIG_FITTING_SPECTRAL_TABLES_H_
#define FLAMERIG_FITTING_SPECTRAL_TABLES_H_

#include <Eigen/Core>
#include <cmath>
#include <vector>

namespace flamerig {

class ChannelResponse;

// Linear interpolation in a table of 3 values per kelvin (row i holds T = i K) for
// 0 < T < the table's last row: the value, and when `d_out` is not null the slope of the segment
// holding T (what the interpolation differentiates to). Shared by every per-kelvin table.
template <typename Real>
inline void InterpolateKelvinRows(const double* rows, Real temperature_k, Real* out, Real* d_out) {
  const int i = static_cast<int>(temperature_k);
  const Real f = temperature_k - Real(i);
  const double* a = &rows[3 * i];
  for (int c = 0; c < 3; ++c) {
    if (d_out) d_out[c] = Real(a[c + 3] - a[c]);
    out[c] = Real(a[c] + f * (a[c + 3] - a[c]));
  }
}

class BlackbodyXyzTable {
 public:
  static constexpr int kMaxTableK = 20000;
  static const BlackbodyXyzTable& Get();

  // XYZ at `temperature_k` (values <= 0 or NaN give 0).
  template <typename Real>
  void Lookup(Real temperature_k, Real* xyz) const {
    if (!(temperature_k > Real(0))) {
      xyz[0] = xyz[1] = xyz[2] = Real(0);
      return;
    }
    if (temperature_k >= Real(kMaxTableK)) return LookupExact(double(temperature_k), xyz);
    InterpolateKelvinRows<Real>(xyz_.data(), temperature_k, xyz, nullptr);
  }

  // XYZ and its derivative in T: the slope of the table segment holding T (what Lookup's linear
  // interpolation differentiates to); above kMaxTableK a central difference over 1 K; zero at T <= 0.
  template <typename Real>
  void LookupWithDerivative(Real temperature_k, Real* xyz, Real* d_xyz) const {
    if (!(temperature_k > Real(0))) {
      for (int c = 0; c < 3; ++c) xyz[c] = d_xyz[c] = Real(0);
      return;
    }
    if (temperature_k >= Real(kMaxTableK))
      return LookupExactWithDerivative(double(temperature_k), xyz, d_xyz);
    InterpolateKelvinRows<Real>(xyz_.data(), temperature_k, xyz, d_xyz);
  }

  // The rows: 3 values per kelvin from 0 to kMaxTableK + 1.
  const double* rows() const { return xyz_.data(); }

 private:
  BlackbodyXyzTable();
  template <typename Real>
  void LookupExactWithDerivative(double temperature_k, Real* xyz, Real* d_xyz) const;
  template <typename Real>
  void LookupExact(double temperature_k, Real* xyz) const;
  std::vector<double> xyz_;  // 3 * (kMaxTableK + 2)
};

class SpectralBins {
 public:
  // Bins centred on first_nm, first_nm + step_nm, ..., last_nm. Throws InputError unless
  // 360 <= first < last <= 830 (a camera's response: 300 - step <= first <= last <= 1100 + step,
  // the range its tables integrate), step > 0 and there are at most kMaxBins bins. The weights are
  // the basis channels of `response` (camera_response.h; null: the sRGB observer, whose basis is
  // CIE XYZ); every channel must respond somewhere in the bins.
  SpectralBins(double first_nm, double last_nm, double step_nm,
               const ChannelResponse* response = nullptr);
  static constexpr int kMaxBins = 512;
  static constexpr int kMaxTableK = 20000;

  int count() const { return static_cast<int>(centers_nm_.size()); }
  const std::vector<double>& centers_nm() const { return centers_nm_; }
  double step_nm() const { return step_nm_; }
  // Weight of bin i in X, Y or Z: the colour matching function averaged over the bin times its
  // width, divided by the integral of ybar. XYZ = sum_i weight(i) * L_i (L per nm). With a
  // response: its basis channels likewise (ChannelResponse::BinWeight).
  const Eigen::Vector3d& weight(int i) const { return weights_[i]; }

  // Planck radiance per nm at bin i's centre, linearly interpolated from a 1 K table (exact above
  // kMaxTableK).
  template <typename Real>
  Real Planck(int bin, Real temperature_k) const {
    if (!(temperature_k > Real(0))) return Real(0);
    if (temperature_k >= Real(kMaxTableK)) return Real(PlanckExact(bin, double(temperature_k)));
    const int i = static_cast<int>(temperature_k);
    const Real f = temperature_k - Real(i);
    const float* row = &planck_[static_cast<std::size_t>(i) * count()];
    const float a = row[bin], b = row[bin + count()];
    return Real(a) + f * (Real(b) - Real(a));
  }

  // All bins at once into `out[count()]`: the renderer's vectorisable form of Planck().
  template <typename Real>
  void PlanckAll(Real temperature_k, Real* out) const {
    const int n = count();
    if (!(temperature_k > Real(0))) {
      for (int b = 0; b < n; ++b) out[b] = Real(0);
      return;
    }
    if (temperature_k >= Real(kMaxTableK)) {
      for (int b = 0; b < n; ++b) out[b] = Real(PlanckExact(b, double(temperature_k)));
      return;
    }
    const int i = static_cast<int>(temperature_k);
    const Real f = temperature_k - Real(i);
    const float* row0 = &planck_[static_cast<std::size_t>(i) * n];
    const float* row1 = row0 + n;
    for (int b = 0; b < n; ++b) out[b] = Real(row0[b]) + f * (Real(row1[b]) - Real(row0[b]));
  }

  // The table's row at `kelvin` (0 <= kelvin <= kMaxTableK + 1): count() values, the Planck
  // radiance of each bin at that temperature, which Planck() interpolates.
  const float* PlanckRow(int kelvin) const {
    return &planck_[static_cast<std::size_t>(kelvin) * count()];
  }
  // All bins and their derivatives in T (the table segment's slope; exact above kMaxTableK).
  template <typename Real>
  void PlanckAllWithDerivative(Real temperature_k, Real* out, Real* d_out) const {
    const int n = count();
    if (!(temperature_k > Real(0))) {
      for (int b = 0; b < n; ++b) out[b] = d_out[b] = Real(0);
      return;
    }
    if (temperature_k >= Real(kMaxTableK)) {
      for (int b = 0; b < n; ++b) {
        out[b] = Real(PlanckExact(b, double(temperature_k)));
        d_out[b] = Real(PlanckExactDerivative(b, double(temperature_k)));
      }
      return;
    }
    const int i = static_cast<int>(temperature_k);
    const Real f = temperature_k - Real(i);
    const float* row0 = &planck_[static_cast<std::size_t>(i) * n];
    const float* row1 = row0 + n;
    for (int b = 0; b < n; ++b) {
      d_out[b] = Real(row1[b]) - Real(row0[b]);
      out[b] = Real(row0[b]) + f * d_out[b];
    }
  }

 private:
  double PlanckExact(int bin, double temperature_k) const;
  double PlanckExactDerivative(int bin, double temperature_k) const;
  double step_nm_;
  std::vector<double> centers_nm_;
  std::vector<Eigen::Vector3d> weights_;
  std::vector<float> planck_;  // (kMaxTableK + 2) rows of count() values
};

}  // namespace flamerig

#endif  // FLAMERIG_FITTING_SPECTRAL_TABLES_H_
