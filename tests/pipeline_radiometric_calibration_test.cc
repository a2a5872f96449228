// Radiometric calibration against the simulator's truth: a camera is filmed looking at a black-body
// calibrator at several temperatures and exposures through its true model (gains, black level,
// gamma, spectral sensitivity set here), calibration starts from a model that knows only the
// datasheet (transfer, bit depth, spectral curves) and must recover what was set; a wrong
// spectral model must be caught; and end to end, a fire filmed by such cameras is fitted with
// the uncalibrated, the calibrated and the true models, scored against the fire's truth.
#include <gtest/gtest.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include "calibration/synthetic_rig.h"
#include "core/atomic_file.h"
#include "core/error.h"
#include "core/format.h"
#include "core/read_file.h"
#include "fitting/camera_response.h"
#include "fitting/colour.h"
#include "pipeline/fit_job.h"
#include "pipeline/radiometric_calibration.h"
#include "pipeline/simulate.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

fs::path TempDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() /
                       ("flamerig_radiometric_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

Rig SmallRig(int cameras = 1) {
  synthetic::RingOptions ring;
  ring.cameras = cameras;
  ring.width = 160;
  ring.height = 120;
  return synthetic::MakeRingRig(
      Box3{Eigen::Vector3d(-0.015, 0.0, -0.015), Eigen::Vector3d(0.015, 0.07, 0.015)}, ring, "t");
}

CameraRadiometry BandCamera12() {
  CameraRadiometry r;
  r.transfer = TransferFunction::kLinear;
  r.bit_depth = 12;
  r.spectral.kind = SpectralSensitivity::Kind::kBands;
  r.spectral.bands = {{640, 60}, {540, 80}, {450, 60}};
  return r;
}

// Films the calibrator with `film` for camera `camera` at every temperature and level (fraction
// of full scale of the brightest channel) and returns the shots.
RadiometricShots Film(const fs::path& dir, const std::string& camera, const CameraRadiometry& film,
                      const std::vector<double>& temperatures, const std::vector<double>& levels,
                      double noise_dn, double emissivity = 0.98) {
  RadiometricShots shots;
  shots.emissivity = emissivity;
  shots.path = (dir / "shots.yaml").string();
  fs::create_directories(dir);
  const auto response = ChannelResponse::ForCamera(film);
  int i = 0;
  for (double t : temperatures)
    for (double level : levels) {
      RadiometricShot s;
      s.camera = camera;
      s.temperature_k = t;
      // The exposure from the true model: what a person does by watching the histogram.
      const double peak = response->Blackbody(t).head(film.channels()).maxCoeff();
      s.exposure = level / (emissivity * peak);
      s.image = (dir / (camera + "_" + std::to_string(i++) + ".png")).string();
      ImageU8 u8;
      ImageU16 u16;
      const int bits = FilmCalibrationSource(160, 120, t, emissivity, s.exposure, film, noise_dn,
                                             17 + i, &u8, &u16);
      if (bits == 16)
        WritePng16(s.image, u16);
      else
        WritePng(s.image, u8);
      shots.shots.push_back(s);
    }
  return shots;
}

const std::vector<double> kTemperatures{1300, 1600, 1900};
const std::vector<double> kLevels{0.05, 0.15, 0.35, 0.6, 0.85, 1.3};

TEST(RadiometricCalibration, RecoversTheGainsAndBlackLevelOfALinearCamera) {
  const fs::path dir = TempDir("linear");
  Rig rig = SmallRig();
  CameraRadiometry film = BandCamera12();
  film.gain = Eigen::Vector3d(0.55, 1.0, 1.45);
  film.black_level = 64;
  // The datasheet: transfer, bit depth and spectral curves; gains and black level unknown.
  CameraRadiometry datasheet = BandCamera12();
  rig.cameras[0].radiometry = datasheet;
  const RadiometricShots shots =
      Film(dir, rig.cameras[0].name, film, kTemperatures, kLevels, /*noise_dn=*/0.25);
  const RadiometricCalibration cal = CalibrateRadiometry(rig, shots, RadiometricOptions());
  ASSERT_EQ(cal.cameras.size(), 1u);
  const CameraRadiometricResult& r = cal.cameras[0];
  std::printf("%s", cal.Brief().c_str());
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(r.after.gain[c] / film.gain[c], 1.0, 0.005) << c;
  EXPECT_TRUE(r.fitted_black_level);
  EXPECT_NEAR(r.after.black_level, 64, 0.2);  // as the README states
  // The dark pixels say the same, independently of the fit.
  EXPECT_NEAR(r.dark_level_dn, 64, 2.0);
  // The right spectral model passes its check: noise only.
  EXPECT_LT(r.spectral_mismatch.maxCoeff(), 0.01);
  EXPECT_TRUE(r.warnings.empty());
  // The over-exposed shots (level 1.3) are left out, saying why, and only those.
  int saturated = 0;
  for (const RadiometricShotResult& s : cal.shots)
    for (int c = 0; c < 3; ++c)
      if (s.left_out[c].find("saturated") != std::string::npos) ++saturated;
  EXPECT_GE(saturated, 3);  // the brightest channel at each temperature
  EXPECT_LE(saturated, 9);
  // Residuals at the noise of a patch mean (4 DN per pixel over about a thousand pixels).
  EXPECT_LT(r.rms_dn, 1.0);
  // The calibrated rig round-trips through its YAML.
  ApplyRadiometricCalibration(rig, cal).Save((dir / "out" / "rig.yaml").string());
  const Rig back = Rig::Load((dir / "out" / "rig.yaml").string());
  EXPECT_NEAR(back.cameras[0].radiometry.gain[2], r.after.gain[2], 1e-6 * r.after.gain[2]);
  EXPECT_NEAR(back.cameras[0].radiometry.black_level, r.after.black_level, 1e-6);
  fs::remove_all(dir);
}

// Shots given as the camera took them (exposure time in us and gain in dB) with the file's
// exposure unit: each shot's exposure is exposure_us x 10^(gain_db / 20) / unit, so the same images
// calibrate to the same gains as when given in the renderer's units (to rounding), and the
// calibrated rig keeps the unit, exactly, through its YAML; a lamp's does not. A time without the
// unit, both forms at once and a gain without a time are refused, naming the shot.
TEST(RadiometricCalibration, ShotsInMicrosecondsGiveTheSameGainsAndTheRigKeepsTheUnit) {
  const fs::path dir = TempDir("unit");
  Rig rig = SmallRig();
  CameraRadiometry film = BandCamera12();
  film.gain = Eigen::Vector3d(0.55, 1.0, 1.45);
  rig.cameras[0].radiometry = BandCamera12();
  const RadiometricShots plain =
      Film(dir, rig.cameras[0].name, film, {1500, 1800}, {0.1, 0.3, 0.6}, 0.25);
  // The same shots as a camera's settings: exposure 1 is 2500 us at 0 dB; every other shot at
  // 6 dB of gain, its exposure time halved (x 10^(-6/20) exactly).
  const double unit_us = 2500;
  RadiometricShots timed = plain;
  timed.exposure_unit_us = unit_us;
  for (std::size_t i = 0; i < timed.shots.size(); ++i) {
    RadiometricShot& shot = timed.shots[i];
    shot.gain_db = i % 2 ? 6 : 0;
    shot.exposure_us = shot.exposure * unit_us / std::pow(10.0, shot.gain_db / 20);
  }
  timed.Save((dir / "timed.yaml").string());
  const std::string text = ReadFile((dir / "timed.yaml").string());
  EXPECT_NE(text.find("exposure_unit_us: 2500"), std::string::npos) << text;
  EXPECT_NE(text.find("exposure_us:"), std::string::npos) << text;
  const RadiometricShots back = RadiometricShots::Load((dir / "timed.yaml").string());
  ASSERT_EQ(back.shots.size(), plain.shots.size());
  EXPECT_EQ(back.exposure_unit_us, unit_us);
  for (std::size_t i = 0; i < back.shots.size(); ++i)
    EXPECT_NEAR(back.shots[i].exposure / plain.shots[i].exposure, 1.0, 1e-8) << i;
  const RadiometricCalibration a = CalibrateRadiometry(rig, plain, RadiometricOptions()),
                               b = CalibrateRadiometry(rig, back, RadiometricOptions());
  for (int c = 0; c < 3; ++c)
    EXPECT_NEAR(b.cameras[0].after.gain[c] / a.cameras[0].after.gain[c], 1.0, 1e-6) << c;
  EXPECT_NE(b.Report().find("Exposure 1 stands for 2500 us at 0 dB"), std::string::npos);
  ApplyRadiometricCalibration(rig, b).Save((dir / "out" / "rig.yaml").string());
  EXPECT_EQ(Rig::Load((dir / "out" / "rig.yaml").string()).exposure_unit_us, unit_us);
  EXPECT_EQ(ApplyRadiometricCalibration(rig, a).exposure_unit_us, 0.0);
  RadiometricCalibration lamp = b;
  lamp.lamp = true;
  EXPECT_EQ(ApplyRadiometricCalibration(rig, lamp).exposure_unit_us, 0.0);
  EXPECT_NE(lamp.Report().find("not kept: a lamp"), std::string::npos);
  // Refused, naming the shot.
  const auto error = [&](const std::string& yaml) {
    WriteFileAtomically((dir / "bad.yaml").string(), yaml);
    try {
      RadiometricShots::Load((dir / "bad.yaml").string());
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("accepted");
  };
  const std::string shot = "{camera: c0, image: x.png, temperature_k: 1500, ";
  EXPECT_NE(error("shots:\n  - " + shot + "exposure_us: 500}\n")
                .find("shots[0]: exposure_us needs the file's exposure_unit_us"),
            std::string::npos);
  EXPECT_NE(error("exposure_unit_us: 1000\nshots:\n  - " + shot + "exposure: 1, exposure_us: 5}\n")
                .find("shots[0]: give one of 'exposure'"),
            std::string::npos);
  EXPECT_NE(error("shots:\n  - " + shot + "exposure: 1, gain_db: 6}\n")
                .find("shots[0]: 'gain_db' goes with 'exposure_us'"),
            std::string::npos);
  EXPECT_NE(error("exposure_unit_us: -3\nshots:\n  - " + shot + "exposure: 1}\n")
                .find("exposure_unit_us: must be a finite time > 0"),
            std::string::npos);
  fs::remove_all(dir);
}

// Shots that cannot fit the black level (one level per temperature, their signals within a factor
// 1.5 of each other in a channel) and a datasheet that says black 0 for a camera whose offset is
// 64 DN: the dark pixels around the source give it, and the gains come out right. Held at 0 as
// before, the gains were up to 5 times off (blue 7.4 for 1.45) with residuals of 24 DN and no word
// of the black level. Held by the user (fit_black_level false), a warning names both levels.
TEST(RadiometricCalibration, ShotsThatCannotFitTheBlackLevelTakeItFromTheDarkPixels) {
  const fs::path dir = TempDir("dark");
  Rig rig = SmallRig();
  CameraRadiometry film = BandCamera12();
  film.gain = Eigen::Vector3d(0.7, 1.1, 1.2);
  film.black_level = 64;
  rig.cameras[0].radiometry = BandCamera12();  // black 0
  const RadiometricShots shots =
      Film(dir, rig.cameras[0].name, film, {1600, 1700, 1800}, {0.6}, /*noise_dn=*/0.25);
  const RadiometricCalibration cal = CalibrateRadiometry(rig, shots, RadiometricOptions());
  const CameraRadiometricResult& r = cal.cameras.at(0);
  std::printf("%s", cal.Brief().c_str());
  EXPECT_FALSE(r.fitted_black_level);
  EXPECT_TRUE(r.black_level_from_dark);
  EXPECT_NEAR(r.after.black_level, 64, 2.0);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(r.after.gain[c] / film.gain[c], 1.0, 0.01) << c;
  ASSERT_FALSE(r.notes.empty());
  EXPECT_NE(r.notes.front().find("the dark pixels' median"), std::string::npos) << r.notes.front();
  EXPECT_NE(cal.Report().find("(dark pixels)"), std::string::npos);

  RadiometricOptions hold;
  hold.fit_black_level = false;
  const RadiometricCalibration held = CalibrateRadiometry(rig, shots, hold);
  const CameraRadiometricResult& h = held.cameras.at(0);
  EXPECT_FALSE(h.black_level_from_dark);
  EXPECT_EQ(h.after.black_level, 0);
  bool named = false;
  for (const std::string& w : h.warnings)
    named |= w.find("the dark pixels around the source read " + FormatNumber(h.dark_level_dn, 4) +
                    " DN, the model's black level is 0 DN (held)") != std::string::npos;
  EXPECT_NEAR(h.dark_level_dn, 64, 2.0);
  EXPECT_TRUE(named) << (h.warnings.empty() ? "no warning" : h.warnings.front());
  fs::remove_all(dir);
}

// The sRGB observer's blue of a black body below about 2000 K is negative (outside the sRGB
// gamut): such shots say nothing of the blue gain, and the error says from which temperature
// they would (the closed form: the first 50 K step at which the observer's blue is positive).
TEST(RadiometricCalibration, ShotsTooCoolForTheSrgbObserversBlueNameTheTemperatureNeeded) {
  const fs::path dir = TempDir("srgb_cool");
  Rig rig = SmallRig();
  CameraRadiometry srgb;
  srgb.transfer = TransferFunction::kLinear;
  srgb.bit_depth = 12;
  rig.cameras[0].radiometry = srgb;
  const RadiometricShots shots =
      Film(dir, rig.cameras[0].name, srgb, kTemperatures, {0.3, 0.6}, /*noise_dn=*/0.25);
  double from = 0;
  for (double t = 1000; t <= 20000 && from == 0; t += 50)
    if ((colour::LinearSrgbFromXyz() * colour::BlackbodyXyz(t))[2] > 0) from = t;
  ASSERT_GT(from, 1900);
  try {
    CalibrateRadiometry(rig, shots, RadiometricOptions());
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("no usable shot for channel 2"), std::string::npos) << what;
    EXPECT_NE(what.find("at 1300 to 1900 K no signal"), std::string::npos) << what;
    EXPECT_NE(what.find("film the source at " + FormatNumber(from, 5) + " K or hotter"),
              std::string::npos)
        << what;
  }
  fs::remove_all(dir);
}

TEST(RadiometricCalibration, RecoversGammaAndGainsOfAnEightBitGammaCamera) {
  const fs::path dir = TempDir("gamma");
  Rig rig = SmallRig();
  CameraRadiometry film;
  film.transfer = TransferFunction::kGamma;
  film.gamma = 2.2;
  film.bit_depth = 8;
  film.black_level = 16;
  film.gain = Eigen::Vector3d(0.8, 1.0, 1.25);
  CameraRadiometry datasheet = film;
  datasheet.gamma = 1.8;
  datasheet.black_level = 0;
  datasheet.gain = Eigen::Vector3d::Ones();
  rig.cameras[0].radiometry = datasheet;
  const RadiometricShots shots = Film(dir, rig.cameras[0].name, film, {1500, 2000},
                                      {0.03, 0.08, 0.2, 0.4, 0.7, 0.95}, /*noise_dn=*/0.7);
  const RadiometricCalibration cal = CalibrateRadiometry(rig, shots, RadiometricOptions());
  const CameraRadiometricResult& r = cal.cameras[0];
  std::printf("%s", cal.Brief().c_str());
  EXPECT_TRUE(r.fitted_gamma);
  EXPECT_NEAR(r.after.gamma, 2.2, 0.03);
  EXPECT_NEAR(r.after.black_level, 16, 1.0);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(r.after.gain[c] / film.gain[c], 1.0, 0.02) << c;
  fs::remove_all(dir);
}

TEST(RadiometricCalibration, AWrongSpectralModelIsCaughtAndNamed) {
  const fs::path dir = TempDir("spectral");
  Rig rig = SmallRig();
  CameraRadiometry film = BandCamera12();
  CameraRadiometry srgb = film;  // decodes right, but assumes the sRGB observer
  srgb.spectral = SpectralSensitivity();
  rig.cameras[0].radiometry = srgb;
  const RadiometricShots shots =
      Film(dir, rig.cameras[0].name, film, {1900, 2400, 2900}, {0.2, 0.5, 0.8}, 0.25);
  const RadiometricCalibration cal = CalibrateRadiometry(rig, shots, RadiometricOptions());
  const CameraRadiometricResult& r = cal.cameras[0];
  std::printf("%s", cal.Brief().c_str());
  EXPECT_GT(r.spectral_mismatch.maxCoeff(), 0.05);
  ASSERT_FALSE(r.warnings.empty());
  EXPECT_NE(r.warnings[0].find("sRGB observer"), std::string::npos) << r.warnings[0];
  EXPECT_NE(r.warnings[0].find("sensitivity_file"), std::string::npos) << r.warnings[0];
  EXPECT_NE(cal.Report().find("**Warning:**"), std::string::npos);
  fs::remove_all(dir);
}

TEST(RadiometricCalibration, ALampCalibratesTheRatiosOnlyAndSaysSo) {
  const fs::path dir = TempDir("lamp");
  Rig rig = SmallRig();
  CameraRadiometry film = BandCamera12();
  film.gain = Eigen::Vector3d(0.5, 1.0, 2.0);
  rig.cameras[0].radiometry = BandCamera12();
  // A tungsten filament: a black body's spectrum times an unknown grey factor (0.43 here).
  RadiometricShots shots = Film(dir, rig.cameras[0].name, film, {2800}, {0.1, 0.4, 0.8}, 0.25,
                                /*emissivity=*/0.43);
  shots.source = RadiometricShots::Source::kLamp;
  const RadiometricCalibration cal = CalibrateRadiometry(rig, shots, RadiometricOptions());
  const CameraRadiometricResult& r = cal.cameras[0];
  EXPECT_NEAR(r.after.gain[0] / r.after.gain[1], 0.5, 0.005);
  EXPECT_NEAR(r.after.gain[2] / r.after.gain[1], 2.0, 0.01);
  EXPECT_NEAR(r.after.gain.mean(), 1.0, 1e-9);  // the model's scale
  bool said = false, unchecked = false;
  for (const std::string& n : r.notes) {
    said |= n.find("lamp") != std::string::npos;
    unchecked |= n.find("one source temperature") != std::string::npos;
  }
  EXPECT_TRUE(said);
  EXPECT_TRUE(unchecked);
  fs::remove_all(dir);
}

TEST(RadiometricCalibration, BadShotsAreRefusedNamingWhatAndWhere) {
  const fs::path dir = TempDir("errors");
  Rig rig = SmallRig();
  rig.cameras[0].radiometry = BandCamera12();
  RadiometricShots shots = Film(dir, rig.cameras[0].name, BandCamera12(), {1500}, {0.3, 0.6}, 0.25);
  auto message = [&](const RadiometricShots& s) -> std::string {
    try {
      CalibrateRadiometry(rig, s, RadiometricOptions());
    } catch (const InputError& e) {
      return e.what();
    }
    return "";
  };
  RadiometricShots unknown = shots;
  unknown.shots[1].camera = "cam9";
  EXPECT_NE(message(unknown).find("camera 'cam9' is not in the rig"), std::string::npos)
      << message(unknown);
  // An image of the wrong size names both sizes.
  RadiometricShots wrong = shots;
  WritePng16((dir / "small.png").string(), ImageU16(80, 60, 3, 100));
  wrong.shots[1].image = (dir / "small.png").string();
  EXPECT_NE(message(wrong).find("80x60"), std::string::npos) << message(wrong);
  EXPECT_NE(message(wrong).find("160x120"), std::string::npos) << message(wrong);
  // Every shot over-exposed: nothing to fit, and it says so.
  RadiometricShots burnt =
      Film(dir / "burnt", rig.cameras[0].name, BandCamera12(), {1500}, {3.0, 5.0}, 0.25);
  EXPECT_NE(message(burnt).find("no usable shot for channel 0 (2 saturated)"), std::string::npos)
      << message(burnt);
  // A missing image is an I/O error naming the file.
  RadiometricShots missing = shots;
  missing.shots[0].image = (dir / "gone.png").string();
  try {
    CalibrateRadiometry(rig, missing, RadiometricOptions());
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("gone.png"), std::string::npos) << e.what();
  }
  // The shots file: a malformed entry names the shot and the key.
  std::ofstream(dir / "bad.yaml") << "shots:\n  - {camera: cam0, image: a.png, exposure: 1}\n";
  try {
    RadiometricShots::Load((dir / "bad.yaml").string());
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("shots[0]: missing 'temperature_k'"), std::string::npos)
        << e.what();
  }
  // A misspelt key is refused, naming it and where it is (it would otherwise keep its default).
  const std::pair<const char*, const char*> misspelt[] = {
      {"source: {kind: blackbody, emisivity: 0.5}\nshots: [{camera: cam0, image: a.png, "
       "temperature_k: 1500, exposure: 1}]\n",
       "source: unknown key 'emisivity'"},
      {"regoin: [1, 2, 3, 4]\nshots: [{camera: cam0, image: a.png, temperature_k: 1500, "
       "exposure: 1}]\n",
       "unknown key 'regoin'"},
      {"shots: [{camera: cam0, image: a.png, temperature_k: 1500, exposure: 1, colour: red}]\n",
       "shots[0]: unknown key 'colour'"},
      // Not a number: named with its field and value (yaml-cpp said "bad conversion" at a line).
      {"shots: [{camera: cam0, image: a.png, temperature_k: nan, exposure: 1}]\n",
       "shots[0]: temperature_k: 'nan' is not a number"},
      {"shots: [{camera: cam0, image: a.png, temperature_k: 1500, exposure: 1 ms}]\n",
       "shots[0]: exposure: '1 ms' is not a number"},
      {"source: {kind: blackbody, emissivity: high}\nshots: [{camera: cam0, image: a.png, "
       "temperature_k: 1500, exposure: 1}]\n",
       "source.emissivity: 'high' is not a number"}};
  for (const auto& [text, said] : misspelt) {
    std::ofstream(dir / "misspelt.yaml") << text;
    try {
      RadiometricShots::Load((dir / "misspelt.yaml").string());
      ADD_FAILURE() << "accepted: " << text;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(said), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("misspelt.yaml"), std::string::npos) << e.what();
    }
  }
  fs::remove_all(dir);
}

TEST(RadiometricCalibration, AShotThatDisagreesWithAllTheOthersIsLeftOutAndNamed) {
  const fs::path dir = TempDir("outlier");
  Rig rig = SmallRig();
  CameraRadiometry film = BandCamera12();
  film.gain = Eigen::Vector3d(0.55, 1.0, 1.45);
  film.black_level = 64;
  rig.cameras[0].radiometry = BandCamera12();
  RadiometricShots shots = Film(dir, rig.cameras[0].name, film, kTemperatures, kLevels, 0.25);
  // A capped lens: one mid-level shot's image is black, below the camera's black level.
  const std::string capped = shots.shots[8].image;
  WritePng16(capped, ImageU16(160, 120, 3, 0));
  const RadiometricCalibration cal = CalibrateRadiometry(rig, shots, RadiometricOptions());
  const CameraRadiometricResult& r = cal.cameras[0];
  std::printf("%s", cal.Brief().c_str());
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(r.after.gain[c] / film.gain[c], 1.0, 0.005) << c;
  EXPECT_NEAR(r.after.black_level, 64, 0.2);  // as the README states
  EXPECT_LT(r.rms_dn, 1.0);
  ASSERT_EQ(r.warnings.size(), 1u);
  EXPECT_NE(r.warnings[0].find(capped), std::string::npos) << r.warnings[0];
  EXPECT_NE(r.warnings[0].find("left out"), std::string::npos) << r.warnings[0];
  EXPECT_NE(cal.shots[8].left_out[0].find("an outlier"), std::string::npos);
  // Kept in, the black shot pulls the gains and the black level far off (what the check is for).
  RadiometricOptions keep;
  keep.outlier_ratio = 1e9;
  keep.max_rms = 1;
  const CameraRadiometricResult kept = CalibrateRadiometry(rig, shots, keep).cameras[0];
  EXPECT_GT(kept.rms_dn, 100);
  EXPECT_GT(
      (kept.after.gain.cwiseQuotient(film.gain) - Eigen::Vector3d::Ones()).cwiseAbs().maxCoeff(),
      0.05);
  fs::remove_all(dir);
}

TEST(RadiometricCalibration, ShotsTheModelCannotExplainAreAnErrorNamingTheWorst) {
  const fs::path dir = TempDir("unexplained");
  Rig rig = SmallRig();
  rig.cameras[0].radiometry = BandCamera12();
  RadiometricShots shots =
      Film(dir, rig.cameras[0].name, BandCamera12(), kTemperatures, kLevels, 0.25);
  // Exposures copied from another session: every shot's is off by its own factor, 1/3 to 3.
  for (std::size_t i = 0; i < shots.shots.size(); ++i)
    shots.shots[i].exposure *= std::pow(3.0, std::sin(2.7 * double(i) + 0.4));
  try {
    CalibrateRadiometry(rig, shots, RadiometricOptions());
    ADD_FAILURE() << "calibrated from shots the model cannot explain";
  } catch (const DataError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("camera " + rig.cameras[0].name), std::string::npos) << what;
    EXPECT_NE(what.find("does not explain the shots"), std::string::npos) << what;
    EXPECT_NE(what.find("the worst is " + dir.string()), std::string::npos) << what;
  }
  fs::remove_all(dir);
}

// The fit's temperature error (truth finer than the fit's grid) of a simulated 2-view candle, with
// the cameras' models taken from `rig_path`.
TruthError FitWith(const fs::path& data, const std::string& rig_path, double exposure,
                   const fs::path& out) {
  FitJob job;
  job.rig_path = rig_path;
  job.images_dir = (data / "frames" / "frame_000000").string();
  job.out_path = (out / "fit.vdb").string();
  job.resolution = 32;
  job.exposure = exposure;
  job.absorption = "soot";
  job.truth_path = (data / "truth" / "frame_000000.vdb").string();
  const FitJobResult r = RunFitJob(job);
  EXPECT_TRUE(r.have_truth);
  return r.truth;
}

TEST(RadiometricCalibration, EndToEndTheCalibratedRigFitsTheTemperaturesOfTheTrueModel) {
  const fs::path dir = TempDir("end_to_end");
  SimulateConfig config;
  config.grid_resolution = 48;
  config.ring.width = 160;
  config.ring.height = 120;
  config.calibration = false;
  config.radiometry = BandCamera12();
  config.radiometry.black_level = 64;
  config.camera_gains = {Eigen::Vector3d(0.55, 1.0, 1.45), Eigen::Vector3d(0.7, 1.1, 1.2)};
  config.radiometric_calibration.enabled = true;
  const fs::path data = dir / "data";
  const SimulateSummary s = Simulate(config, data.string());
  EXPECT_EQ(s.radiometric_shots, 2 * 3 * 6);
  // What the user knows before calibrating: the datasheet's curves, unit gains, black 0.
  Rig datasheet = Rig::Load((data / "rig.yaml").string());
  for (RigCamera& c : datasheet.cameras) c.radiometry = BandCamera12();
  datasheet.Save((dir / "datasheet" / "rig.yaml").string());
  const RadiometricCalibration cal = RunRadiometricCalibration(
      (dir / "datasheet" / "rig.yaml").string(), (data / "radiometry" / "shots.yaml").string(),
      (dir / "calibrated").string(), RadiometricOptions());
  std::printf("%s", cal.Brief().c_str());
  ASSERT_EQ(cal.cameras.size(), 2u);
  for (std::size_t c = 0; c < 2; ++c)
    for (int k = 0; k < 3; ++k)
      EXPECT_NEAR(cal.cameras[c].after.gain[k] / config.camera_gains[c][k], 1.0, 0.005);
  EXPECT_TRUE(fs::exists(dir / "calibrated" / "report.md"));
  EXPECT_TRUE(fs::exists(dir / "calibrated" / "shots.csv"));
  // The shots as the cameras took them, in microseconds at 0 dB, and the unit that makes
  // the sim cameras' default 10000 us the dataset's exposure: the calibrated rig keeps it.
  const RadiometricShots shots =
      RadiometricShots::Load((data / "radiometry" / "shots.yaml").string());
  for (const RadiometricShot& shot : shots.shots) {
    EXPECT_GE(shot.exposure_us, 1.0) << shot.image;
    if (shot.exposure_us >= 100) {
      EXPECT_EQ(shot.exposure_us, std::round(shot.exposure_us)) << shot.image;
    }
    EXPECT_EQ(shot.gain_db, 0.0) << shot.image;
  }
  const double unit_us = Rig::Load((dir / "calibrated" / "rig.yaml").string()).exposure_unit_us;
  EXPECT_NEAR(unit_us * s.exposure / 10000, 1.0, 1e-9);
  EXPECT_NEAR(
      unit_us / YAML::LoadFile((data / "dataset.yaml").string())["dataset"]["exposure_unit_us"]
                    .as<double>(),
      1.0, 1e-9);
  // Into the rig's own folder (by another spelling of it): refused before any work, the datasheet
  // rig untouched.
  const auto datasheet_time = fs::last_write_time(dir / "datasheet" / "rig.yaml");
  try {
    RunRadiometricCalibration(
        (dir / "datasheet" / "rig.yaml").string(), (data / "radiometry" / "shots.yaml").string(),
        (dir / "datasheet" / ".." / "datasheet" / ".").string(), RadiometricOptions());
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("would overwrite the rig"), std::string::npos) << e.what();
  }
  EXPECT_EQ(fs::last_write_time(dir / "datasheet" / "rig.yaml"), datasheet_time);
  EXPECT_FALSE(fs::exists(dir / "datasheet" / "report.md"));

  const TruthError uncalibrated = FitWith(data, (dir / "datasheet" / "rig.yaml").string(),
                                          s.exposure, dir / "fit_uncalibrated");
  const TruthError calibrated =
      FitWith(data, (dir / "calibrated" / "rig.yaml").string(), s.exposure, dir / "fit_calibrated");
  const TruthError truth =
      FitWith(data, (data / "rig.yaml").string(), s.exposure, dir / "fit_true");
  std::printf(
      "temperature bias / RMS on visible voxels: datasheet model %.1f / %.1f K; calibrated "
      "%.1f / %.1f K; true model %.1f / %.1f K\n",
      uncalibrated.mean_k, uncalibrated.rms_k, calibrated.mean_k, calibrated.rms_k, truth.mean_k,
      truth.rms_k);
  // Calibration brings the fit to what the true model gives, within a few kelvin; without it the
  // gains' colour cast is a bias several times larger.
  EXPECT_LT(std::abs(calibrated.mean_k - truth.mean_k), 5.0);
  EXPECT_LT(std::abs(calibrated.rms_k - truth.rms_k), 5.0);
  EXPECT_GT(std::abs(uncalibrated.mean_k - truth.mean_k), 30.0);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace flamerig
