#include "calibration/radiometry.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "core/config_reader.h"
#include "core/error.h"
#include "core/format.h"
#include "core/srgb.h"

namespace flamerig {
namespace {

// Linear interpolation in a strictly increasing table of y over evenly spaced x in [0, 1].
double CurveAt(const std::vector<double>& curve, double x) {
  const double u = std::clamp(x, 0.0, 1.0) * double(curve.size() - 1);
  const std::size_t i = std::min(static_cast<std::size_t>(u), curve.size() - 2);
  const double f = u - double(i);
  return curve[i] + f * (curve[i + 1] - curve[i]);
}

// The inverse of CurveAt (curve strictly increasing from curve[0] to curve.back()).
double CurveInverse(const std::vector<double>& curve, double y) {
  if (!(y > curve.front())) return 0;
  if (!(y < curve.back())) return 1;
  const std::size_t i =
      static_cast<std::size_t>(std::upper_bound(curve.begin(), curve.end(), y) - curve.begin() - 1);
  const double f = (y - curve[i]) / (curve[i + 1] - curve[i]);
  return (double(i) + f) / double(curve.size() - 1);
}

SpectralBand ReadBand(const YAML::Node& node, const std::string& where) {
  CheckKeys(node, {"centre_nm", "fwhm_nm"}, where);
  ConfigReader r(node, where);
  SpectralBand b;
  b.centre_nm = r.Range("centre_nm", 0, kMinWavelengthNm, kMaxWavelengthNm);
  b.fwhm_nm = r.Range("fwhm_nm", 0, kMinBandFwhmNm, kMaxBandFwhmNm);
  return b;
}

void WriteBand(YAML::Emitter* out, const SpectralBand& b) {
  *out << YAML::Flow << YAML::BeginMap << YAML::Key << "centre_nm" << YAML::Value << b.centre_nm
       << YAML::Key << "fwhm_nm" << YAML::Value << b.fwhm_nm << YAML::EndMap;
}

// Checks a table's shape: ascending wavelengths, 1 or 3 columns of finite values >= 0, some
// response in every column.
void CheckTable(const SpectralSensitivity& s, const std::string& where) {
  const std::size_t n = s.wavelengths_nm.size();
  if (n < 2)
    throw InputError(where + ": a sensitivity table needs at least 2 rows, got " +
                     std::to_string(n));
  if (s.columns.size() != 1 && s.columns.size() != 3)
    throw InputError(where + ": a sensitivity table has 1 (mono) or 3 (colour) channels, got " +
                     std::to_string(s.columns.size()));
  for (std::size_t i = 0; i < n; ++i) {
    if (!std::isfinite(s.wavelengths_nm[i]) || s.wavelengths_nm[i] < kMinWavelengthNm ||
        s.wavelengths_nm[i] > kMaxWavelengthNm)
      throw InputError(where + ": row " + std::to_string(i + 1) + ": wavelength " +
                       FormatNumber(s.wavelengths_nm[i]) + " nm is not in [" +
                       FormatNumber(kMinWavelengthNm) + ", " + FormatNumber(kMaxWavelengthNm) +
                       "]");
    if (i > 0 && !(s.wavelengths_nm[i] > s.wavelengths_nm[i - 1]))
      throw InputError(where + ": row " + std::to_string(i + 1) + ": wavelengths must increase, " +
                       FormatNumber(s.wavelengths_nm[i]) + " follows " +
                       FormatNumber(s.wavelengths_nm[i - 1]));
  }
  for (std::size_t c = 0; c < s.columns.size(); ++c) {
    if (s.columns[c].size() != n)
      throw InputError(where + ": channel " + std::to_string(c) + " has " +
                       std::to_string(s.columns[c].size()) + " values for " + std::to_string(n) +
                       " wavelengths");
    double peak = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const double v = s.columns[c][i];
      if (!std::isfinite(v) || v < 0)
        throw InputError(where + ": row " + std::to_string(i + 1) + ", channel " +
                         std::to_string(c) + ": sensitivity " + FormatNumber(v) +
                         " must be finite and >= 0");
      peak = std::max(peak, v);
    }
    if (!(peak > 0))
      throw InputError(where + ": channel " + std::to_string(c) + " has no sensitivity anywhere");
  }
}

}  // namespace

void ParseTransferSpec(const std::string& spec, TransferFunction* transfer, double* gamma) {
  const std::string forms = "; use linear, srgb or gamma=G (G in [0.1, 10])";
  if (spec == "srgb") {
    *transfer = TransferFunction::kSrgb;
  } else if (spec == "linear") {
    *transfer = TransferFunction::kLinear;
  } else if (spec.rfind("gamma=", 0) == 0) {
    const std::string number = spec.substr(6);
    std::size_t used = 0;
    double g = 0;
    try {
      g = std::stod(number, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used == 0 || used != number.size() || !(g >= 0.1 && g <= 10))
      throw InputError("input transfer '" + spec + "': the gamma is not a number in [0.1, 10]" +
                       forms);
    *transfer = TransferFunction::kGamma;
    *gamma = g;
  } else {
    throw InputError("input transfer '" + spec + "'" + forms);
  }
}

const char* ToString(TransferFunction transfer) {
  switch (transfer) {
    case TransferFunction::kSrgb:
      return "srgb";
    case TransferFunction::kLinear:
      return "linear";
    case TransferFunction::kGamma:
      return "gamma";
    case TransferFunction::kCurve:
      return "curve";
  }
  return "?";
}

double SpectralBand::At(double wavelength_nm) const {
  const double sigma = fwhm_nm / (2.0 * std::sqrt(2.0 * std::log(2.0)));
  const double u = (wavelength_nm - centre_nm) / sigma;
  return std::exp(-0.5 * u * u);
}

int SpectralSensitivity::channels() const {
  switch (kind) {
    case Kind::kSrgbObserver:
      return 3;
    case Kind::kTable:
      return static_cast<int>(columns.size());
    case Kind::kBands:
      return static_cast<int>(bands.size());
  }
  return 3;
}

double SpectralSensitivity::RawAt(int channel, double wavelength_nm) const {
  double v = 0;
  if (kind == Kind::kBands) {
    v = bands[channel].At(wavelength_nm);
  } else if (kind == Kind::kTable) {
    const auto& w = wavelengths_nm;
    if (!(wavelength_nm >= w.front()) || !(wavelength_nm <= w.back())) return 0;
    const std::size_t i = std::min<std::size_t>(
        std::upper_bound(w.begin(), w.end(), wavelength_nm) - w.begin() - 1, w.size() - 2);
    const double f = (wavelength_nm - w[i]) / (w[i + 1] - w[i]);
    v = columns[channel][i] + f * (columns[channel][i + 1] - columns[channel][i]);
  } else {
    return 0;
  }
  return has_filter() ? v * filter.At(wavelength_nm) : v;
}

std::string SpectralSensitivity::Describe() const {
  std::string s;
  if (kind == Kind::kSrgbObserver) {
    s = "sRGB observer";
  } else if (kind == Kind::kTable) {
    s = "table " + (source.empty() ? std::string("(inline)") : source) + " (" +
        std::to_string(channels()) + (channels() == 1 ? " channel)" : " channels)");
  } else {
    s = "bands";
    for (std::size_t i = 0; i < bands.size(); ++i)
      s += (i ? ", " : " ") + FormatNumber(bands[i].centre_nm) + "/" +
           FormatNumber(bands[i].fwhm_nm);
    s += " nm";
  }
  if (has_filter())
    s += " behind a " + FormatNumber(filter.centre_nm) + "/" + FormatNumber(filter.fwhm_nm) +
         " nm filter";
  return s;
}

SpectralSensitivity SpectralSensitivity::FromTableFile(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec))
    throw InputError(path + ": not a file; a spectral sensitivity table is a CSV file");
  if (std::filesystem::file_size(path, ec) > (1u << 20))
    throw InputError(path + ": over 1 MiB, too large for a spectral sensitivity table");
  std::ifstream in(path);
  if (!in) throw InputError(path + ": cannot open the spectral sensitivity table");
  SpectralSensitivity s;
  s.kind = Kind::kTable;
  s.source = path;
  std::string line;
  int line_no = 0;
  std::size_t columns = 0;
  while (std::getline(in, line)) {
    ++line_no;
    const std::size_t first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos || line[first] == '#') continue;
    std::replace(line.begin(), line.end(), ',', ' ');
    std::istringstream fields(line);
    std::vector<double> row;
    std::string field;
    bool header = false;
    while (!header && fields >> field) {
      try {
        std::size_t used = 0;
        row.push_back(std::stod(field, &used));
        if (used != field.size()) throw std::invalid_argument(field);
      } catch (const std::exception&) {
        // A header line of names is allowed before the first row of numbers.
        header = s.wavelengths_nm.empty() && row.empty();
        if (header) break;
        throw InputError(path + ":" + std::to_string(line_no) + ": '" + field +
                         "' is not a number");
      }
    }
    if (header) continue;
    if (row.size() != 2 && row.size() != 4)
      throw InputError(path + ":" + std::to_string(line_no) +
                       ": a row is 'nm, value' (mono) or 'nm, r, g, b', got " +
                       std::to_string(row.size()) + " numbers");
    if (columns == 0) {
      columns = row.size() - 1;
      s.columns.assign(columns, {});
    } else if (row.size() - 1 != columns) {
      throw InputError(path + ":" + std::to_string(line_no) + ": " +
                       std::to_string(row.size() - 1) + " channels where earlier rows have " +
                       std::to_string(columns));
    }
    s.wavelengths_nm.push_back(row[0]);
    for (std::size_t c = 0; c < columns; ++c) s.columns[c].push_back(row[c + 1]);
  }
  CheckTable(s, path);
  return s;
}

bool CameraRadiometry::is_default() const {
  return transfer == TransferFunction::kSrgb && bit_depth == 0 && black_level == 0 &&
         saturation_level == 0 && gain == Eigen::Vector3d::Ones() &&
         spectral.kind == SpectralSensitivity::Kind::kSrgbObserver && !spectral.has_filter();
}

CameraRadiometry::Decoding CameraRadiometry::DecodingFor(int frame_bits) const {
  if (frame_bits != 8 && frame_bits != 16)
    throw InputError("radiometry: frames are 8 or 16 bits, got " + std::to_string(frame_bits));
  Decoding d;
  if (bit_depth == 0) {
    // Today's rule: 8-bit frames are what the camera wrote in sRGB, 16-bit ones linear.
    d.transfer = frame_bits == 8 ? transfer : TransferFunction::kLinear;
    d.max_code = frame_bits == 8 ? 255 : 65535;
  } else {
    if (bit_depth > frame_bits)
      throw InputError("radiometry: a " + std::to_string(bit_depth) +
                       "-bit camera's frames cannot arrive in " + std::to_string(frame_bits) +
                       " bits");
    d.transfer = transfer;
    d.max_code = std::ldexp(1.0, bit_depth) - 1;
  }
  d.black = black_level;
  d.saturation = saturation_level > 0 ? std::min(saturation_level, d.max_code) : d.max_code;
  if (!(d.black < d.saturation))
    throw InputError("radiometry: black level " + FormatNumber(d.black) +
                     " is not below the saturation " + "level " + FormatNumber(d.saturation) +
                     " of a " + std::to_string(frame_bits) + "-bit frame");
  return d;
}

double CameraRadiometry::Signal(double code, const Decoding& d) const {
  if (!(code > d.black)) return 0;
  if (code >= d.saturation) return 1;
  const double e = (code - d.black) / (d.saturation - d.black);
  switch (d.transfer) {
    case TransferFunction::kSrgb:
      return SrgbDecode(e);
    case TransferFunction::kLinear:
      return e;
    case TransferFunction::kGamma:
      return std::pow(e, gamma);
    case TransferFunction::kCurve:
      return CurveAt(curve, e);
  }
  return e;
}

double CameraRadiometry::Code(double signal, const Decoding& d) const {
  return std::clamp(std::round(Encode(signal, d)), 0.0, d.max_code);
}

double CameraRadiometry::Encode(double signal, const Decoding& d) const {
  if (!(signal > 0)) return d.black;
  const double s = std::min(signal, 1.0);
  double e = s;
  switch (d.transfer) {
    case TransferFunction::kSrgb:
      e = SrgbEncode(s);
      break;
    case TransferFunction::kLinear:
      break;
    case TransferFunction::kGamma:
      e = std::pow(s, 1.0 / gamma);
      break;
    case TransferFunction::kCurve:
      e = CurveInverse(curve, s);
      break;
  }
  return d.black + e * (d.saturation - d.black);
}

CameraRadiometry CameraRadiometry::ForHighBitWords(int bits) const {
  CameraRadiometry out = *this;
  if (bits <= 8 || bits >= 16) return out;
  const double scale = std::ldexp(1.0, 16 - bits);
  const double top = (std::ldexp(1.0, bits) - 1) * scale;
  if (bit_depth == 0) {
    out.saturation_level = saturation_level > 0 ? std::min(saturation_level, top) : top;
  } else if (bit_depth == bits) {
    out.bit_depth = 16;
    out.black_level = black_level * scale;
    out.saturation_level =
        (saturation_level > 0 ? std::min(saturation_level, std::ldexp(1.0, bits) - 1)
                              : std::ldexp(1.0, bits) - 1) *
        scale;
  }
  return out;
}

std::vector<float> CameraRadiometry::SignalTable(int frame_bits) const {
  const Decoding d = DecodingFor(frame_bits);
  std::vector<float> table(frame_bits == 8 ? 256 : 65536);
  for (std::size_t i = 0; i < table.size(); ++i)
    table[i] = static_cast<float>(Signal(double(i), d));
  return table;
}

void CameraRadiometry::Validate(const std::string& where) const {
  auto fail = [&](const std::string& field, const std::string& rule) {
    throw InputError(where + ": radiometry." + field + ": " + rule);
  };
  if (bit_depth != 0 && (bit_depth < 8 || bit_depth > 16))
    fail("bit_depth", "must be 0 (from the frame) or 8..16, got " + std::to_string(bit_depth));
  if (transfer == TransferFunction::kGamma && !(gamma >= 0.1 && gamma <= 10))
    fail("gamma", "must be in [0.1, 10], got " + FormatNumber(gamma));
  if (transfer == TransferFunction::kCurve) {
    if (curve.size() < 2) fail("curve", "needs at least 2 values");
    for (std::size_t i = 0; i < curve.size(); ++i) {
      if (!std::isfinite(curve[i]) || curve[i] < 0)
        fail("curve", "value " + std::to_string(i) + " must be finite and >= 0");
      if (i > 0 && !(curve[i] > curve[i - 1]))
        fail("curve", "must increase strictly; value " + std::to_string(i) + " (" +
                          FormatNumber(curve[i]) + ") does not exceed the one before");
    }
    if (curve.front() != 0 || curve.back() != 1)
      fail("curve", "must run from 0 (black) to 1 (saturation), got " +
                        FormatNumber(curve.front()) + " .. " + FormatNumber(curve.back()));
  }
  const double max_code = bit_depth ? std::ldexp(1.0, bit_depth) - 1 : 65535;
  if (!std::isfinite(black_level) || black_level < 0 || black_level >= max_code)
    fail("black_level",
         "must be in [0, " + FormatNumber(max_code) + "), got " + FormatNumber(black_level));
  if (!std::isfinite(saturation_level) || saturation_level < 0 || saturation_level > max_code)
    fail("saturation_level", "must be 0 (full scale) or in (black_level, " +
                                 FormatNumber(max_code) + "], got " +
                                 FormatNumber(saturation_level));
  if (saturation_level > 0 && !(saturation_level > black_level))
    fail("saturation_level", "must exceed black_level (" + FormatNumber(black_level) + "), got " +
                                 FormatNumber(saturation_level));
  // The bands' and the filter's range, as a rig file's reader (ReadBand) takes them.
  auto check_band = [&](const SpectralBand& b, const std::string& field) {
    auto in = [&](const char* key, double v, double lo, double hi) {
      if (!(v >= lo && v <= hi))
        fail(field, std::string("'") + key + "' must be in [" + FormatNumber(lo) + ", " +
                        FormatNumber(hi) + "], got " + FormatNumber(v));
    };
    in("centre_nm", b.centre_nm, kMinWavelengthNm, kMaxWavelengthNm);
    in("fwhm_nm", b.fwhm_nm, kMinBandFwhmNm, kMaxBandFwhmNm);
  };
  if (spectral.has_filter()) check_band(spectral.filter, "filter");
  if (spectral.kind == SpectralSensitivity::Kind::kBands)
    for (std::size_t i = 0; i < spectral.bands.size(); ++i)
      check_band(spectral.bands[i], "bands[" + std::to_string(i) + "]");
  const int n = spectral.channels();
  for (int c = 0; c < 3; ++c)
    if (!std::isfinite(gain[c]) || !(gain[c] > 0))
      fail("gain", "channel " + std::to_string(c) + " must be finite and > 0, got " +
                       FormatNumber(gain[c]));
  if (n == 1 && !(gain[1] == gain[0] && gain[2] == gain[0]))
    fail("gain", "a mono camera has one gain");
  switch (spectral.kind) {
    case SpectralSensitivity::Kind::kSrgbObserver:
      if (spectral.has_filter())
        fail("filter",
             "needs a sensor's sensitivity (spectral: table or bands); the sRGB "
             "observer describes a camera's colour output, not its sensor");
      break;
    case SpectralSensitivity::Kind::kTable:
      CheckTable(spectral, where + ": radiometry.sensitivity");
      break;
    case SpectralSensitivity::Kind::kBands:
      if (n != 1 && n != 3)
        fail("bands", "gives 1 (mono) or 3 (colour) bands, got " + std::to_string(n));
      for (const SpectralBand& b : spectral.bands)
        if (!(b.fwhm_nm > 0) || !(b.centre_nm > 0)) fail("bands", "centre and width must be > 0");
      break;
  }
}

std::string CameraRadiometry::Describe() const {
  std::ostringstream s;
  s << ToString(transfer);
  if (transfer == TransferFunction::kGamma) s << " " << gamma;
  if (transfer == TransferFunction::kCurve) s << " of " << curve.size() << " points";
  if (bit_depth)
    s << ", " << bit_depth << " bit";
  else
    s << " (16-bit frames linear)";
  if (black_level > 0) s << ", black " << black_level;
  if (saturation_level > 0) s << ", saturation " << saturation_level;
  if (gain != Eigen::Vector3d::Ones()) {
    s << ", gain " << gain[0];
    if (channels() == 3) s << "/" << gain[1] << "/" << gain[2];
  }
  s << ", " << spectral.Describe();
  return s.str();
}

CameraRadiometry CameraRadiometry::FromYaml(const YAML::Node& node, const std::string& base_dir,
                                            const std::string& where) {
  if (!node.IsMap()) throw InputError(where + ": must be a map");
  ConfigReader r(node, where);
  CameraRadiometry m;
  const std::string transfer = r.Get<std::string>("transfer", "srgb");
  if (transfer == "srgb")
    m.transfer = TransferFunction::kSrgb;
  else if (transfer == "linear")
    m.transfer = TransferFunction::kLinear;
  else if (transfer == "gamma")
    m.transfer = TransferFunction::kGamma;
  else if (transfer == "curve")
    m.transfer = TransferFunction::kCurve;
  else
    throw InputError(where + ": 'transfer' is '" + transfer +
                     "'; one of srgb, linear, gamma, curve");
  m.gamma = r.Get<double>("gamma", 2.2);
  m.curve = r.Get<std::vector<double>>("curve", {});
  if (m.transfer != TransferFunction::kCurve && !m.curve.empty())
    throw InputError(where + ": 'curve' is given but transfer is " + transfer);
  m.bit_depth = r.Whole<int>("bit_depth", 0, 0, 16);
  m.black_level = r.NonNegative("black_level", 0);
  m.saturation_level = r.NonNegative("saturation_level", 0);
  const std::string spectral = r.Get<std::string>("spectral", "srgb");
  if (spectral == "srgb") {
    m.spectral.kind = SpectralSensitivity::Kind::kSrgbObserver;
  } else if (spectral == "table") {
    const std::string file = r.Get<std::string>("sensitivity_file", "");
    const YAML::Node inline_table = node["sensitivity_table"];
    r.Seen("sensitivity_table");
    if (file.empty() == !inline_table)
      throw InputError(where +
                       ": spectral: table needs one of 'sensitivity_file' and "
                       "'sensitivity_table'");
    if (!file.empty()) {
      const std::filesystem::path p(file);
      m.spectral = SpectralSensitivity::FromTableFile(
          p.is_absolute() ? file : (std::filesystem::path(base_dir) / p).string());
      m.spectral.source = file;
    } else {
      if (!inline_table.IsSequence())
        throw InputError(where + ": 'sensitivity_table' must be a list of rows");
      m.spectral.kind = SpectralSensitivity::Kind::kTable;
      for (std::size_t i = 0; i < inline_table.size(); ++i) {
        std::vector<double> row;
        try {
          row = inline_table[i].as<std::vector<double>>();
        } catch (const YAML::Exception&) {
          throw InputError(where + ": sensitivity_table row " + std::to_string(i + 1) +
                           " is not a list of numbers");
        }
        if (row.size() != 2 && row.size() != 4)
          throw InputError(where + ": sensitivity_table row " + std::to_string(i + 1) +
                           " is [nm, value] or [nm, r, g, b]");
        if (m.spectral.columns.empty()) m.spectral.columns.assign(row.size() - 1, {});
        if (row.size() - 1 != m.spectral.columns.size())
          throw InputError(where + ": sensitivity_table row " + std::to_string(i + 1) +
                           " has a different number of channels");
        m.spectral.wavelengths_nm.push_back(row[0]);
        for (std::size_t c = 0; c + 1 < row.size(); ++c)
          m.spectral.columns[c].push_back(row[c + 1]);
      }
    }
  } else if (spectral == "bands") {
    const YAML::Node bands = node["bands"];
    r.Seen("bands");
    if (!bands || !bands.IsSequence())
      throw InputError(where + ": spectral: bands needs 'bands', a list of {centre_nm, fwhm_nm}");
    m.spectral.kind = SpectralSensitivity::Kind::kBands;
    for (std::size_t i = 0; i < bands.size(); ++i)
      m.spectral.bands.push_back(ReadBand(bands[i], where + ".bands[" + std::to_string(i) + "]"));
  } else {
    throw InputError(where + ": 'spectral' is '" + spectral + "'; one of srgb, table, bands");
  }
  if (node["filter"]) m.spectral.filter = ReadBand(node["filter"], where + ".filter");
  r.Seen("filter");
  const std::vector<double> gain = r.Get<std::vector<double>>("gain", {});
  if (!gain.empty()) {
    if (gain.size() == 1)
      m.gain.setConstant(gain[0]);
    else if (gain.size() == 3)
      m.gain = Eigen::Vector3d(gain[0], gain[1], gain[2]);
    else
      throw InputError(where + ": 'gain' has 1 (mono) or 3 values");
    if (gain.size() != static_cast<std::size_t>(m.channels()))
      throw InputError(where + ": 'gain' has " + std::to_string(gain.size()) +
                       " values for a camera of " + std::to_string(m.channels()) + " channels");
  }
  r.CheckKnown();
  m.Validate(where);
  return m;
}

void CameraRadiometry::ToYaml(YAML::Emitter* out) const {
  YAML::Emitter& o = *out;
  o << YAML::BeginMap;
  o << YAML::Key << "transfer" << YAML::Value << ToString(transfer);
  if (transfer == TransferFunction::kGamma) o << YAML::Key << "gamma" << YAML::Value << gamma;
  if (transfer == TransferFunction::kCurve)
    o << YAML::Key << "curve" << YAML::Value << YAML::Flow << curve;
  o << YAML::Key << "bit_depth" << YAML::Value << bit_depth;
  o << YAML::Key << "black_level" << YAML::Value << black_level;
  o << YAML::Key << "saturation_level" << YAML::Value << saturation_level;
  o << YAML::Key << "gain" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (int c = 0; c < channels(); ++c) o << gain[c];
  o << YAML::EndSeq;
  switch (spectral.kind) {
    case SpectralSensitivity::Kind::kSrgbObserver:
      o << YAML::Key << "spectral" << YAML::Value << "srgb";
      break;
    case SpectralSensitivity::Kind::kTable:
      o << YAML::Key << "spectral" << YAML::Value << "table";
      o << YAML::Key << "sensitivity_table" << YAML::Value << YAML::BeginSeq;
      for (std::size_t i = 0; i < spectral.wavelengths_nm.size(); ++i) {
        o << YAML::Flow << YAML::BeginSeq << spectral.wavelengths_nm[i];
        for (const auto& col : spectral.columns) o << col[i];
        o << YAML::EndSeq;
      }
      o << YAML::EndSeq;
      break;
    case SpectralSensitivity::Kind::kBands:
      o << YAML::Key << "spectral" << YAML::Value << "bands";
      o << YAML::Key << "bands" << YAML::Value << YAML::BeginSeq;
      for (const SpectralBand& b : spectral.bands) WriteBand(out, b);
      o << YAML::EndSeq;
      break;
  }
  if (spectral.has_filter()) {
    o << YAML::Key << "filter" << YAML::Value;
    WriteBand(out, spectral.filter);
  }
  o << YAML::EndMap;
}

}  // namespace flamerig
