// The radiometric camera model (calibration/radiometry.h): each transfer function against its
// closed form, every bit depth's round trip, black and saturation levels, spectral tables from
// files, and the rig YAML that stores it, with its errors.
#include "calibration/radiometry.h"

#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <unistd.h>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>

#include "calibration/rig.h"
#include "core/error.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

// A file in this process's scratch folder, which is removed when the tests exit.
std::string Temp(const std::string& name) {
  struct Scratch {
    fs::path path =
        fs::temp_directory_path() / ("flamerig_radiometry_" + std::to_string(::getpid()));
    Scratch() { fs::create_directories(path); }
    ~Scratch() {
      std::error_code ignored;
      fs::remove_all(path, ignored);
    }
  };
  static const Scratch dir;
  return (dir.path / name).string();
}

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

CameraRadiometry FromText(const std::string& yaml, const std::string& base = ".") {
  return CameraRadiometry::FromYaml(YAML::Load(yaml), base, "test.yaml: radiometry");
}

TEST(Radiometry, DefaultDecodesEightBitAsSrgbAndSixteenBitAsLinear) {
  const CameraRadiometry m;
  EXPECT_TRUE(m.is_default());
  const auto d8 = m.DecodingFor(8), d16 = m.DecodingFor(16);
  // IEC 61966-2-1: ((v + 0.055) / 1.055)^2.4 above 0.04045, v / 12.92 below.
  EXPECT_NEAR(m.Signal(128, d8), std::pow((128 / 255.0 + 0.055) / 1.055, 2.4), 1e-12);
  EXPECT_NEAR(m.Signal(5, d8), 5 / 255.0 / 12.92, 1e-12);
  EXPECT_EQ(m.Signal(255, d8), 1.0);
  EXPECT_EQ(m.Signal(0, d8), 0.0);
  EXPECT_NEAR(m.Signal(32768, d16), 32768 / 65535.0, 1e-12);
  EXPECT_EQ(d16.transfer, TransferFunction::kLinear);
}

TEST(Radiometry, EveryTransferFunctionRoundTripsEveryCodeAtEveryBitDepth) {
  for (const char* transfer : {"srgb", "linear", "gamma", "curve"}) {
    for (int bits : {8, 10, 12, 14, 16}) {
      std::string yaml = std::string("{transfer: ") + transfer +
                         ", bit_depth: " + std::to_string(bits) + ", black_level: 16";
      if (std::string(transfer) == "gamma") yaml += ", gamma: 2.6";
      if (std::string(transfer) == "curve") yaml += ", curve: [0, 0.02, 0.1, 0.3, 0.6, 1]";
      yaml += "}";
      SCOPED_TRACE(yaml);
      const CameraRadiometry m = FromText(yaml);
      const auto d = m.DecodingFor(bits > 8 ? 16 : 8);
      EXPECT_EQ(d.max_code, std::ldexp(1.0, bits) - 1);
      // Codes strictly inside (black, saturation) encode back to themselves.
      const int step = bits > 12 ? 7 : 1;
      for (int code = 17; code < d.max_code; code += step) {
        const double s = m.Signal(code, d);
        ASSERT_GT(s, 0);
        ASSERT_LT(s, 1);
        ASSERT_EQ(m.Code(s, d), code) << "signal " << s;
      }
      EXPECT_EQ(m.Signal(16, d), 0.0);  // black
      EXPECT_EQ(m.Signal(3, d), 0.0);   // below black: clipped
      EXPECT_EQ(m.Signal(d.max_code, d), 1.0);
      EXPECT_EQ(m.Code(2.0, d), d.max_code);  // beyond saturation
      EXPECT_EQ(m.Code(std::nan(""), d), 16);
    }
  }
}

TEST(Radiometry, GammaAndCurveFollowTheirClosedForms) {
  const CameraRadiometry g = FromText("{transfer: gamma, gamma: 2.2, bit_depth: 12}");
  const auto d = g.DecodingFor(16);
  EXPECT_NEAR(g.Signal(2048, d), std::pow(2048 / 4095.0, 2.2), 1e-12);
  // A curve is the signal at evenly spaced normalised codes, linear between: code 0.3 of full
  // scale lies 1/2 of the way between the 0.2 and 0.4 points.
  const CameraRadiometry c = FromText(
      "{transfer: curve, curve: [0, 0.01, 0.05, 0.2, 0.5, 1], "
      "bit_depth: 10}");
  const auto dc = c.DecodingFor(16);
  EXPECT_NEAR(c.Signal(0.3 * 1023, dc), 0.5 * (0.01 + 0.05), 1e-9);
  EXPECT_NEAR(c.Signal(0.9 * 1023, dc), 0.5 * (0.5 + 1), 1e-9);
}

TEST(Radiometry, SaturationLevelBelowFullScaleSaturatesThere) {
  const CameraRadiometry m =
      FromText("{transfer: linear, bit_depth: 12, black_level: 64, saturation_level: 4000}");
  const auto d = m.DecodingFor(16);
  EXPECT_NEAR(m.Signal(2032, d), (2032.0 - 64) / (4000 - 64), 1e-12);
  EXPECT_EQ(m.Signal(4000, d), 1.0);
  EXPECT_EQ(m.Signal(4095, d), 1.0);
  EXPECT_EQ(m.Code(1.0, d), 4000);
  const std::vector<float> table = m.SignalTable(16);
  ASSERT_EQ(table.size(), 65536u);
  EXPECT_FLOAT_EQ(table[2032], float((2032.0 - 64) / (4000 - 64)));
}

// A 12-bit camera's values stored in the high bits of 16-bit words (acquisition's unpacked wire
// formats, v << 4): the entry counted in 12 bits decodes the words as it decodes the codes, and
// saturates at the highest word a 12-bit value reaches; an entry that takes its depth from the
// frame saturates there too; a 16-bit entry, and 16-bit data, are left as they are.
TEST(Radiometry, TwelveBitValuesInTheHighBitsOfWordsDecodeAsTheirCodes) {
  CameraRadiometry raw12;
  raw12.transfer = TransferFunction::kGamma;
  raw12.gamma = 1.8;
  raw12.bit_depth = 12;
  raw12.black_level = 64;
  const CameraRadiometry words = raw12.ForHighBitWords(12);
  EXPECT_EQ(words.bit_depth, 16);
  const auto low = raw12.DecodingFor(16), high = words.DecodingFor(16);
  EXPECT_EQ(high.black, 64 * 16);
  EXPECT_EQ(high.saturation, 4095 * 16);
  for (int v : {0, 64, 65, 100, 1000, 2047, 4000, 4094, 4095})
    EXPECT_NEAR(words.Signal(v << 4, high), raw12.Signal(v, low), 1e-12) << v;
  raw12.saturation_level = 4000;
  EXPECT_EQ(raw12.ForHighBitWords(12).DecodingFor(16).saturation, 4000 * 16);
  CameraRadiometry from_frame;  // bit depth 0: 16-bit frames linear over the words
  const auto f = from_frame.ForHighBitWords(12).DecodingFor(16);
  EXPECT_EQ(f.transfer, TransferFunction::kLinear);
  EXPECT_EQ(f.saturation, 0xFFF0);
  EXPECT_EQ(from_frame.ForHighBitWords(12).Signal(0xFFF0, f), 1.0);
  EXPECT_EQ(from_frame.ForHighBitWords(10).DecodingFor(16).saturation, 0xFFC0);
  CameraRadiometry deep;
  deep.bit_depth = 16;
  deep.black_level = 100;
  EXPECT_EQ(deep.ForHighBitWords(12).DecodingFor(16).black, 100);
  EXPECT_EQ(raw12.ForHighBitWords(0).bit_depth, 12);
  EXPECT_EQ(raw12.ForHighBitWords(16).bit_depth, 12);
}

TEST(Radiometry, ACameraDeeperThanItsFramesIsAnError) {
  const CameraRadiometry m = FromText("{transfer: linear, bit_depth: 12}");
  EXPECT_NE(ErrorOf([&] { m.DecodingFor(8); }).find("12-bit camera's frames cannot arrive in 8"),
            std::string::npos);
}

TEST(Radiometry, BadValuesAreErrorsNamingTheKey) {
  EXPECT_NE(ErrorOf([] { FromText("{transfer: log}"); }).find("'transfer' is 'log'"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] { FromText("{bit_depth: 20}"); }).find("bit_depth"), std::string::npos);
  EXPECT_NE(ErrorOf([] { FromText("{bit_depth: 7}"); }).find("bit_depth"), std::string::npos);
  EXPECT_NE(ErrorOf([] {
              FromText("{transfer: curve, curve: [0, 0.5, 0.4, 1]}");
            }).find("must increase strictly"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] {
              FromText("{transfer: curve, curve: [0, 0.5, 0.9]}");
            }).find("from 0 (black) to 1"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] { FromText("{curve: [0, 1]}"); }).find("'curve' is given"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] {
              FromText("{bit_depth: 12, black_level: 100, saturation_level: 50}");
            }).find("saturation_level"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] { FromText("{gain: [1, -2, 1]}"); }).find("gain"), std::string::npos);
  EXPECT_NE(ErrorOf([] { FromText("{gain: [1, 2]}"); }).find("'gain' has 1 (mono) or 3"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] {
              FromText(
                  "{spectral: bands, bands: [{centre_nm: 650, fwhm_nm: 10}], "
                  "gain: [1, 1, 1]}");
            }).find("3 values for a camera of 1 channels"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] {
              FromText("{spectral: srgb, filter: {centre_nm: 650, fwhm_nm: 10}}");
            }).find("needs a sensor's sensitivity"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] { FromText("{spectral: table}"); }).find("sensitivity_file"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] { FromText("{exposure_time: 3}"); }).find("unknown key 'exposure_time'"),
            std::string::npos);
}

TEST(Radiometry, SpectralTableFromAFileWithHeaderAndComments) {
  const std::string path = Temp("sensor.csv");
  {
    std::ofstream out(path);
    out << "# a made-up sensor\nnm,r,g,b\n400, 0.0, 0.1, 0.8\n500, 0.1, 0.9, 0.3\n"
           "600, 0.9, 0.2, 0.0\n700, 0.4, 0.0, 0.0\n";
  }
  const SpectralSensitivity s = SpectralSensitivity::FromTableFile(path);
  EXPECT_EQ(s.channels(), 3);
  EXPECT_DOUBLE_EQ(s.RawAt(0, 650), 0.65);  // halfway between 0.9 and 0.4
  EXPECT_DOUBLE_EQ(s.RawAt(1, 450), 0.5);
  EXPECT_EQ(s.RawAt(2, 350), 0.0);  // outside the table
  EXPECT_EQ(s.RawAt(2, 750), 0.0);

  const std::string bad = Temp("bad.csv");
  {
    std::ofstream out(bad);
    out << "400, 0.1, 0.2, 0.3\n500, 0.1, x, 0.3\n";
  }
  EXPECT_NE(ErrorOf([&] { SpectralSensitivity::FromTableFile(bad); }).find("bad.csv:2: 'x'"),
            std::string::npos);
  {
    std::ofstream out(bad);
    out << "500, 0.1, 0.2, 0.3\n400, 0.1, 0.2, 0.3\n";
  }
  EXPECT_NE(ErrorOf([&] { SpectralSensitivity::FromTableFile(bad); }).find("must increase"),
            std::string::npos);
  {
    std::ofstream out(bad);
    out << "400, 0.1\n500, 0.1, 0.2, 0.3\n";
  }
  EXPECT_NE(ErrorOf([&] { SpectralSensitivity::FromTableFile(bad); }).find("3 channels where"),
            std::string::npos);

  // The rig's file path is relative to the rig file.
  const CameraRadiometry m = FromText("{spectral: table, sensitivity_file: sensor.csv}",
                                      fs::path(path).parent_path().string());
  EXPECT_EQ(m.channels(), 3);
  EXPECT_NE(m.Describe().find("table sensor.csv (3 channels)"), std::string::npos);
}

TEST(Radiometry, MonoBandsBehindAFilter) {
  const CameraRadiometry m = FromText(
      "{transfer: linear, bit_depth: 12, spectral: bands, bands: [{centre_nm: 600, fwhm_nm: 200}],"
      " filter: {centre_nm: 650, fwhm_nm: 10}, gain: [2]}");
  EXPECT_EQ(m.channels(), 1);
  EXPECT_EQ(m.gain, Eigen::Vector3d::Constant(2));
  // A Gaussian band is half its peak at centre +- fwhm / 2.
  EXPECT_NEAR(m.spectral.bands[0].At(700), 0.5, 1e-12);
  EXPECT_NEAR(m.spectral.RawAt(0, 655), m.spectral.bands[0].At(655) * 0.5, 1e-12);
  EXPECT_NE(m.Describe().find("behind a 650/10 nm filter"), std::string::npos);
}

TEST(Radiometry, TheRigStoresItAndReadsItBack) {
  Rig rig;
  rig.name = "r";
  rig.box.min_in_rig = Eigen::Vector3d(-1, -1, -1);
  rig.box.max_in_rig = Eigen::Vector3d(1, 1, 1);
  for (int i = 0; i < 2; ++i)
    rig.cameras.push_back(
        RigCamera{"cam" + std::to_string(i),
                  "",
                  CameraModel::Pinhole(300, 300, 159.5, 119.5, Rigid3(), 320, 240),
                  {}});
  CameraRadiometry& m = rig.cameras[1].radiometry;
  m.transfer = TransferFunction::kGamma;
  m.gamma = 1.8;
  m.bit_depth = 10;
  m.black_level = 32;
  m.gain = Eigen::Vector3d(1.5, 1, 0.75);
  m.spectral.kind = SpectralSensitivity::Kind::kTable;
  m.spectral.wavelengths_nm = {400, 550, 700};
  m.spectral.columns = {{0, 0.2, 1}, {0.1, 1, 0.1}, {1, 0.2, 0}};
  const std::string path = Temp("rig/rig.yaml");
  rig.Save(path);
  const Rig back = Rig::Load(path);
  EXPECT_TRUE(back.cameras[0].radiometry.is_default());
  const CameraRadiometry& b = back.cameras[1].radiometry;
  EXPECT_EQ(b.transfer, TransferFunction::kGamma);
  EXPECT_EQ(b.gamma, 1.8);
  EXPECT_EQ(b.bit_depth, 10);
  EXPECT_EQ(b.black_level, 32);
  EXPECT_EQ(b.gain, m.gain);
  EXPECT_EQ(b.spectral.wavelengths_nm, m.spectral.wavelengths_nm);
  EXPECT_EQ(b.spectral.columns, m.spectral.columns);

  // A bad radiometry in a rig file names the file and the camera.
  std::string text;
  {
    std::ifstream in(path);
    text.assign(std::istreambuf_iterator<char>(in), {});
  }
  const std::size_t at = text.find("bit_depth: 10");
  ASSERT_NE(at, std::string::npos);
  text.replace(at, 13, "bit_depth: 99");
  {
    std::ofstream out(path);
    out << text;
  }
  const std::string error = ErrorOf([&] { Rig::Load(path); });
  EXPECT_NE(error.find("rig.yaml: rig.cameras[1].radiometry"), std::string::npos) << error;
  EXPECT_NE(error.find("bit_depth"), std::string::npos) << error;
}

}  // namespace
}  // namespace flamerig
