// What a camera's channels make of a spectrum, in the renderer's units: the spectral half of the
// radiometric camera model (calibration/radiometry.h), built for the renderer's inner loops.
//
// The renderer carries three "basis" channels along each ray and maps them to the camera's output
// channels at the end with output_from_basis():
//  - the sRGB observer: the basis is CIE XYZ (the CIE 1931 2-degree functions over the integral of
//    y-bar) and the output linear sRGB, output_from_basis = colour::LinearSrgbFromXyz(). This is
//    exactly what the renderer computed before cameras had a spectral model, and it shares
//    BlackbodyXyzTable. Gains other than 1 scale the output: diag(gain) * LinearSrgbFromXyz.
//  - a camera with tabulated or parametric sensitivities (and a filter): the basis is the camera's
//    own channels, S_c(lambda) * gain_c / Ybar with S_c scaled so that the channel with the largest
//    integral integrates to Ybar (radiometry.h), and output_from_basis is the identity (times a
//    frame's exposure factor, Exposed()). A mono camera's one channel fills all three (an image of
//    three equal channels: the data term sees a grey with no colour to match).
//
// Black bodies: Lookup() and LookupWithDerivative() give the basis channels of B(lambda, T) per
// kelvin from 0 to kMaxTableK, linear between kelvins, exact above (the same contract as
// BlackbodyXyzTable, whose rows serve the observer). A camera's table integrates Planck over 1 nm from
// 300 to 1100 nm (sensors see into the near infrared; the CIE table ends at 830 nm).
//
// Responses are immutable and shared (std::shared_ptr<const ChannelResponse>); ForCamera() returns
// one object per distinct sensitivity and gain while any user holds it, and keeps the last 8 built
// alive, so that asking again does not rebuild (a camera's black-body table takes about 0.2 s).
#ifndef FLAMERIG_FITTING_CAMERA_RESPONSE_H_
#define FLAMERIG_FITTING_CAMERA_RESPONSE_H_

#include <Eigen/Core>
#include <memory>
#include <string>
#include <vector>

#include "calibration/radiometry.h"
#include "fitting/spectral_tables.h"

namespace flamerig {

class ChannelResponse {
 public:
  static constexpr int kMaxTableK = BlackbodyXyzTable::kMaxTableK;
  static constexpr int kFirstNm = 300, kLastNm = 1100;  // a camera table's integration range

  // The sRGB observer with unit gains: the renderer's default.
  static std::shared_ptr<const ChannelResponse> SrgbObserver();
  // A camera's response from its radiometry's spectral sensitivity and gains (SrgbObserver() for
  // the defaults). Throws InputError from the radiometry's Validate.
  static std::shared_ptr<const ChannelResponse> ForCamera(const CameraRadiometry& radiometry);

  // `response` for a frame exposed `factor` times (> 0, finite) as long as the take's exposure
  // (the frame's exposure time x gain over the take's reference: SourceFrameSet::exposure_ratio,
  // pipeline/frame_source.h): its output and its gains times the factor, its sensitivity, tables
  // and name the same (so that bands group as before, and the output divided by gain() is still
  // the unit-gain channels the tomography's frames, decoded at the frame's exposure, hold).
  // `response` itself when the factor is 1. The copy shares the black-body table with `response`
  // (and keeps it alive): it costs a camera's 1 nm basis (20 kB), not its table (0.5 MB). Throws
  // InputError for a factor that is not finite and > 0.
  static std::shared_ptr<const ChannelResponse> Exposed(
      const std::shared_ptr<const ChannelResponse>& response, double factor);

  const std::string& name() const { return name_; }  // "sRGB observer", or the camera's spectral
  int channels() const { return channels_; }         // 1 or 3
  // True when the basis is CIE XYZ (the sRGB observer, with any gains in output_from_basis).
  bool basis_is_xyz() const { return observer_; }
  const Eigen::Matrix3d& output_from_basis() const { return output_from_basis_; }
  // The camera's gains, included in the output: a camera's output divided by them is its
  // unit-gain channels, what cameras of one kind but different gains agree on (the tomography's).
  const Eigen::Vector3d& gain() const { return gain_; }

  // The basis sensitivities at a wavelength (linear between 1 nm samples; zero outside the range):
  // basis = sum_lambda L(lambda) BasisAt(lambda) dlambda.
  Eigen::Vector3d BasisAt(double wavelength_nm) const;
  // The output channels of a spectrum given as radiance per nm at every integer wavelength of the
  // response's range (what the tables integrate; for tests and calibration).
  template <typename F>
  Eigen::Vector3d Integrate(F&& radiance_per_nm) const {
    Eigen::Vector3d basis = Eigen::Vector3d::Zero();
    for (int nm = first_nm_; nm <= last_nm_; ++nm) basis += radiance_per_nm(double(nm)) * At(nm);
    return output_from_basis_ * basis;
  }
  // Output channels of a black body at T (exact, not tabulated).
  Eigen::Vector3d Blackbody(double temperature_k) const;

  // Basis channels of B(T): the table, interpolated (contract as BlackbodyXyzTable).
  template <typename Real>
  void Lookup(Real temperature_k, Real* out) const {
    if (!(temperature_k > Real(0))) {
      out[0] = out[1] = out[2] = Real(0);
      return;
    }
    if (temperature_k >= Real(kMaxTableK)) return LookupExact(double(temperature_k), out);
    InterpolateKelvinRows<Real>(rows_, temperature_k, out, nullptr);
  }
  template <typename Real>
  void LookupWithDerivative(Real temperature_k, Real* out, Real* d_out) const {
    if (!(temperature_k > Real(0))) {
      for (int c = 0; c < 3; ++c) out[c] = d_out[c] = Real(0);
      return;
    }
    if (temperature_k >= Real(kMaxTableK)) {
      // Above the table the curve is smooth and flat in T: a central difference over 1 K, taken
      // in double (in float the two values' difference kept three digits at 25000 K).
      LookupExact(double(temperature_k), out);
      double lo[3], hi[3];
      LookupExact(double(temperature_k) - 1.0, lo);
      LookupExact(double(temperature_k) + 1.0, hi);
      for (int c = 0; c < 3; ++c) d_out[c] = Real(0.5 * (hi[c] - lo[c]));
      return;
    }
    InterpolateKelvinRows<Real>(rows_, temperature_k, out, d_out);
  }

  // Basis weight of a spectral bin [centre - step/2, centre + step/2]: the basis averaged over the
  // bin times its width (SpectralBins' weights for this response).
  Eigen::Vector3d BinWeight(double centre_nm, double step_nm) const;

  // Where the response responds: the first and last whole nm at which some basis channel exceeds
  // kSupportShare of its own peak (the sRGB observer: 360 and 830, the CIE table's ends). The
  // renderer's spectral path puts its bins there for a camera's response, so that a band-pass
  // filter at 850 nm is seen at 850 nm (renderer.h's RenderOptions) and one at 650/40 nm needs
  // 17 bins.
  static constexpr double kSupportShare = 1e-5;
  int support_first_nm() const { return support_first_nm_; }
  int support_last_nm() const { return support_last_nm_; }

 private:
  ChannelResponse() = default;
  Eigen::Vector3d At(int nm) const;  // basis at an integer wavelength
  template <typename Real>
  void LookupExact(double temperature_k, Real* out) const;

  std::string name_;
  int channels_ = 3;
  bool observer_ = true;
  Eigen::Matrix3d output_from_basis_ = Eigen::Matrix3d::Identity();
  Eigen::Vector3d gain_ = Eigen::Vector3d::Ones();
  int first_nm_ = 360, last_nm_ = 830;
  int support_first_nm_ = 360, support_last_nm_ = 830;
  std::vector<Eigen::Vector3d> basis_;  // per nm from first_nm_ (cameras only)
  std::vector<double> table_;           // 3 * (kMaxTableK + 2) (cameras only)
  const double* rows_ = nullptr;        // the table: BlackbodyXyzTable's rows, or table_
  // Exposed(): the response whose table rows_ points into, held while this one lives
  std::shared_ptr<const ChannelResponse> base_;
};

}  // namespace flamerig

#endif  // FLAMERIG_FITTING_CAMERA_RESPONSE_H_
