// A camera's radiometric model: how the light reaching a pixel becomes the number in its image
// file, per camera, stored with the rig (rig.h) and used alike by simulate, render, reconstruct and
// fit.
//
// The chain, for a pixel receiving spectral radiance L(lambda) (W m^-2 sr^-1 nm^-1) at exposure s:
//
//   signal_c = clamp(s * gain_c * sum_lambda L(lambda) S_c(lambda) dlambda / Ybar, 0, 1)
//   code_c   = black + encode(signal_c) * (saturation - black)        rounded, in [0, 2^bits - 1]
//
//  - S_c: the spectral sensitivity of channel c (SpectralSensitivity below): the CIE 1931 observer
//    through the sRGB primaries (today's default, what a consumer camera's sRGB output means),
//    tabulated curves from a file, or a parametric family of Gaussian bands; one channel for a
//    mono camera, optionally behind a band-pass filter. Ybar = the integral of the CIE y-bar
//    function (106.857 nm), so that the sRGB observer gives linear sRGB in the renderer's units
//    (fitting/colour.h). Tables and bands are scaled so that the channel with the largest
//    integral has the integral of y-bar: a flat spectrum of 1 gives 1 there, before the gain.
//  - gain_c: per channel (white balance, analogue gain ratios); radiometric calibration fits them.
//    The exposure s (exposure time x gain in the renderer's units) multiplies every channel.
//  - signal: the linear signal above black, 1 at saturation. Everything above the saturation
//    level is saturated: it constrains the fit only from below.
//  - encode: the transfer function. kSrgb: IEC 61966-2-1 (what 8-bit files from consumer cameras
//    and flamerig's own simulated 8-bit images hold); kLinear: raw sensor data (machine-vision
//    Mono8/Bayer8/Mono12/Mono16); kGamma: signal^(1/gamma); kCurve: a measured response, the
//    signal at evenly spaced normalised codes (0, 1/(n-1), ..., 1), strictly increasing.
//
// Bit depth 0 (the default) means "as the frame says", today's rule: 8-bit frames are sRGB over
// 0..255, 16-bit frames linear over 0..65535. Any other setting applies to every frame of the
// camera: a Mono12 camera's frames arrive as 16-bit values in 0..4095 (bit_depth 12; a take that
// flamerig recorded from a 10- to 14-bit wire format holds them in the words' high bits, and its
// frames are read with ForHighBitWords, below), and a value
// above 2^bits - 1 is a DataError naming the camera (a wrong bit depth, or a corrupt frame).
//
// On disk (a camera's entry in the rig YAML; every key optional, defaults shown):
//
//   radiometry:
//     transfer: srgb            # srgb | linear | gamma | curve
//     gamma: 2.2                # transfer: gamma
//     curve: [0, 0.1, ..., 1]   # transfer: curve; >= 2 values, strictly increasing
//     bit_depth: 0              # 0 = from the frame, or 8..16
//     black_level: 0            # DN
//     saturation_level: 0       # DN; 0 = 2^bits - 1
//     gain: [1, 1, 1]           # per channel (one value for a mono camera)
//     spectral: srgb            # srgb | table | bands
//     sensitivity_file: s.csv   # spectral: table; rows "nm, r, g, b" or "nm, value" (mono),
//                               # relative to the rig file; '#' lines are comments
//     sensitivity_table: [[400, 0.1, 0.2, 0.9], ...]   # spectral: table, inline instead
//     bands:                    # spectral: bands; 3 (colour) or 1 (mono)
//       - {centre_nm: 600, fwhm_nm: 100}
//     filter: {centre_nm: 650, fwhm_nm: 10}   # optional Gaussian band-pass in front of the sensor
//
// Errors name the file, the key and the rule (InputError).
#ifndef FLAMERIG_CALIBRATION_RADIOMETRY_H_
#define FLAMERIG_CALIBRATION_RADIOMETRY_H_

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

namespace YAML {
class Node;
class Emitter;
}  // namespace YAML

namespace flamerig {

enum class TransferFunction { kSrgb, kLinear, kGamma, kCurve };
const char* ToString(TransferFunction transfer);  // "srgb", "linear", "gamma", "curve"
// A transfer function as a person writes it for a folder of images: "srgb", "linear" or
// "gamma=G" (G in [0.1, 10]). Throws InputError quoting `spec` and the forms it takes.
void ParseTransferSpec(const std::string& spec, TransferFunction* transfer, double* gamma);

// A Gaussian band: a colour channel's sensitivity in the parametric family, or a band-pass filter.
struct SpectralBand {
  double centre_nm = 550;
  double fwhm_nm = 100;
  double At(double wavelength_nm) const;  // peak 1
};

// The wavelengths a rig file may name, for a band's centre and a table's rows, and a band's
// widths (nm); the reader and CameraRadiometry::Validate take the same.
constexpr double kMinWavelengthNm = 200, kMaxWavelengthNm = 2000;
constexpr double kMinBandFwhmNm = 0.1, kMaxBandFwhmNm = 2000;

struct SpectralSensitivity {
  enum class Kind { kSrgbObserver, kTable, kBands };
  Kind kind = Kind::kSrgbObserver;
  // kTable: ascending wavelengths and one column per channel (1 or 3), linear in between, zero
  // outside; `source` names the file it came from.
  std::vector<double> wavelengths_nm;
  std::vector<std::vector<double>> columns;
  std::string source;
  // kBands: one band per channel (1 or 3).
  std::vector<SpectralBand> bands;
  // An optional band-pass filter multiplying every channel (fwhm 0 = none).
  SpectralBand filter{0, 0};

  int channels() const;  // 3 for the sRGB observer
  bool has_filter() const { return filter.fwhm_nm > 0; }
  // Channel c's sensitivity at a wavelength, before the scaling described above (the sRGB
  // observer is not evaluated here: fitting/camera_response.h owns the CIE table).
  double RawAt(int channel, double wavelength_nm) const;
  // "sRGB observer", "table cam0.csv (3 channels)", "bands 600/100, 540/100, 460/100 nm", each
  // with " behind a 650/10 nm filter" when filtered.
  std::string Describe() const;
  // Reads a table from a CSV file (see the header); throws InputError naming the file and line.
  static SpectralSensitivity FromTableFile(const std::string& path);
};

struct CameraRadiometry {
  TransferFunction transfer = TransferFunction::kSrgb;
  double gamma = 2.2;
  std::vector<double> curve;  // kCurve
  int bit_depth = 0;          // 0 = from the frame (8: sRGB rules, 16: linear), else 8..16
  double black_level = 0;
  double saturation_level = 0;  // 0 = 2^bits - 1
  Eigen::Vector3d gain = Eigen::Vector3d::Ones();
  SpectralSensitivity spectral;

  int channels() const { return spectral.channels(); }
  // True for the defaults: sRGB 8-bit or linear 16-bit by the frame, the sRGB observer, unit gains.
  bool is_default() const;

  // How a frame of `frame_bits` (8 or 16) decodes: its effective transfer, full-scale code,
  // black and saturation levels. Throws InputError when the frame's container cannot hold the
  // camera's bit depth (a 12-bit camera's frames in 8 bits).
  struct Decoding {
    TransferFunction transfer = TransferFunction::kSrgb;
    double max_code = 255, black = 0, saturation = 255;
  };
  Decoding DecodingFor(int frame_bits) const;

  // The linear signal (0..1, 1 = saturated) of one code. Codes at or below black give 0, at or
  // above the saturation level 1.
  double Signal(double code, const Decoding& d) const;
  // The code (rounded, clamped to [0, max_code]) that records `signal` (clamped to [0, 1]; NaN
  // records 0).
  double Code(double signal, const Decoding& d) const;
  // The same code before rounding: black + encode(signal) * (saturation - black), a smooth
  // function of the signal for fitting a model to mean codes (radiometric calibration).
  double Encode(double signal, const Decoding& d) const;
  // A 256- or 65536-entry table of Signal() for every code of a frame of `frame_bits`.
  std::vector<float> SignalTable(int frame_bits) const;

  // This camera's model for frames that arrive as 16-bit words holding `bits`-bit values (10 to
  // 15) in their high bits, as flamerig stores what a camera sent in a packed or 10/12-bit wire
  // format (acquisition/frame.h: value << (16 - bits)). An entry counted in those bits (bit_depth
  // `bits`) is scaled to the words: bit depth 16, black and saturation levels x 2^(16 - bits), the
  // saturation at most the highest word ((2^bits - 1) << (16 - bits)). An entry that takes its
  // bit depth from the frame (0) keeps its black level (in the words' units) and saturates at that
  // highest word, which a value of `bits` bits reaches. Any other entry (16, or another depth) is
  // returned as it is; so is any entry for `bits` 0 or 16.
  CameraRadiometry ForHighBitWords(int bits) const;

  // Throws InputError naming `where` and the field that breaks a rule.
  void Validate(const std::string& where) const;
  // One line for logs: "linear, 12 bit, black 64, saturation 4095, gain 1/1/1, bands ...".
  std::string Describe() const;

  // Reads a `radiometry:` map; `base_dir` resolves sensitivity_file. Throws InputError naming
  // `where` and the key.
  static CameraRadiometry FromYaml(const YAML::Node& node, const std::string& base_dir,
                                   const std::string& where);
  // Writes the map; a table is written inline (`sensitivity_table`), so that a saved rig holds
  // its cameras' curves wherever it is moved.
  void ToYaml(YAML::Emitter* out) const;
};

}  // namespace flamerig

#endif  // FLAMERIG_CALIBRATION_RADIOMETRY_H_
