// Radiometric calibration: each camera's per-channel gains, black level and (for a gamma camera)
// gamma, from images of a source of known spectrum at several exposures, stored into the rig's
// radiometric models (calibration/radiometry.h). `flamerig calibrate-radiometry` runs it.
//
// The source is a black-body calibrator (a cavity of known emissivity at a known temperature) or a
// tungsten lamp at a known colour temperature (in the visible and near infrared its spectrum is a
// black body's at that temperature times an unknown grey factor). Its aperture fills a patch of
// each image. For a shot (one camera's image of the source at temperature T and exposure s, in
// the units of the fire recordings' exposure: the take's exposure is its recording's first
// camera's start settings', and every camera is fitted at its exposure time x dB gain against
// those, frame_source.h's StartExposureOfCamera; so a shot's s is the take's exposure times its
// exposure time x dB gain over that camera's, whichever camera took it) the patch's mean code in
// channel c is modelled as
//
//   code_c = black + encode(s * gain_c * emissivity * B_c(T)) * (saturation - black)
//
// where B_c(T) is a black body at T through channel c's spectral sensitivity with unit gain
// (fitting/camera_response.h): the renderer's units, in which an optically thick fire at T renders
// as exactly B_c(T), so that a calibrated gain makes fitted densities absolute. The unknowns:
//  - gain_c, always (one per channel; a mono camera's one gain is written to all three);
//  - the black level, when each channel's usable shots span signals a factor 1.5 apart or more
//    (else it keeps its model value, noted);
//  - gamma, for `transfer: gamma` with three distinct signal levels or more.
// They are solved by Levenberg-Marquardt (Ceres) on the code residuals in DN, started from the
// model's black level and the least-squares gains of the decoded signals. The transfer function,
// bit depth, saturation level and spectral sensitivity are the model's: they are what a datasheet
// gives, and what calibration checks.
//
// What is left out, per shot and channel, with the reason in the report: a channel with more than
// 0.1% of its patch at the saturation level (it would pull the gain down), a channel the model
// says sees nothing (the sRGB observer's negative blue of a cool black body), and, when the black
// level is held, a channel below 1% of full scale (when the black level is fitted such a dark
// channel stays in the fit, where it mostly weighs on the black level, and the report says so).
//
// A shot that disagrees with all the others (a wrong image, a covered lens, a mistyped exposure)
// is left out with a warning naming it, when leaving it out divides the fit's RMS by
// `outlier_ratio` (5) or more; at most a quarter of a camera's shots, and three must remain. A
// systematic misfit (a wrong spectral model) spreads over every shot and leaves none out. A fit
// whose RMS is still above `max_rms` (5%) of full scale is an error (DataError) naming the camera
// and its worst shot, and nothing is written: such gains would bias every fire fitted with them.
//
// The spectral check: with shots at two temperatures or more, the ratio of the measured signal to
// the model's at each temperature, per channel, should be 1 whatever the temperature when the
// spectral sensitivity is right. A spread above `max_spectral_mismatch` (2%) is a warning that
// names the channel, the temperatures and the remedy (the sensor's measured curves): gains alone
// cannot fix a wrong spectral shape, and a wrong shape biases every fitted temperature.
//
// A lamp fixes only the ratios between channels: its gains are scaled so that their mean is the
// model's, and the report says so (fit the exposure, `--fit-exposure`, or calibrate the scale
// with a black body).
//
// The patch: `region: [x, y, width, height]` in the shots file (or per shot), else found in the
// camera's brightest shot: the largest connected area brighter than halfway between the image's
// median and its 99.5th percentile, shrunk by `erode_px` against blur at the aperture's edge.
//
// The shots file (YAML, paths relative to it):
//
//   source: {kind: blackbody, emissivity: 0.99}   # kind: blackbody | lamp
//   region: auto                                  # or [x, y, width, height]
//   exposure_unit_us: 2000                        # optional: what exposure 1 stands for
//   shots:
//     - {camera: cam0, image: cam0_1500K_1.png, temperature_k: 1500, exposure: 0.25}
//     - {camera: cam1, image: cam1_1500K_1.png, temperature_k: 1500, exposure_us: 500,
//        gain_db: 0}
//     - ...
//
// A shot gives its exposure in the renderer's units (`exposure`), or as the camera's exposure
// time in microseconds and gain in dB (`exposure_us`, `gain_db`, default 0), which needs the
// file's `exposure_unit_us`: the exposure time at 0 dB that exposure 1 stands for, so that a
// shot's exposure is exposure_us x 10^(gain_db / 20) / exposure_unit_us. The calibrated rig keeps
// that unit (Rig::exposure_unit_us), and `flamerig run` then knows a recording's exposure from its
// first camera's settings at the start, with no `--exposure` (and `fit`, `reconstruct` and `run`
// an export's, from its exposure_reference.yaml: frame_source.h): the calibration's gains hold for
// the fire in the same units.
//
// `flamerig simulate` writes such a file and its images (radiometry/shots.yaml) when its config
// has `radiometric_calibration:` (simulate.h). Errors name the file, the shot and the rule
// (InputError); a camera with too few usable shots is an error naming the camera and why.
#ifndef FLAMERIG_PIPELINE_RADIOMETRIC_CALIBRATION_H_
#define FLAMERIG_PIPELINE_RADIOMETRIC_CALIBRATION_H_

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "calibration/rig.h"
#include "core/image.h"

namespace flamerig {

struct RadiometricShot {
  std::string camera;
  std::string image;  // absolute, or relative to the working directory once loaded
  double temperature_k = 0;
  double exposure =
      0;  // in the renderer's units (from exposure_us and gain_db when they are given)
  double exposure_us = 0;  // the camera's exposure time as the file gave it; 0 = `exposure` given
  double gain_db = 0;
  std::array<int, 4> region{0, 0, 0, 0};  // x, y, width, height; width 0 = the file's or auto
};

struct RadiometricShots {
  enum class Source { kBlackbody, kLamp };
  Source source = Source::kBlackbody;
  double emissivity = 1.0;                // black body only
  std::array<int, 4> region{0, 0, 0, 0};  // width 0 = auto
  double exposure_unit_us = 0;            // what exposure 1 stands for; 0 = not given
  std::vector<RadiometricShot> shots;
  std::string path;  // the file read, for messages

  // Reads a shots file; image paths become relative to its directory. Throws InputError naming
  // the file, the shot and the key.
  static RadiometricShots Load(const std::string& path);
  void Save(const std::string& path) const;  // images written relative to `path`'s directory
};

struct RadiometricOptions {
  int erode_px = 3;                      // the auto patch shrinks by this against edge blur
  double max_saturated_fraction = 1e-3;  // of a patch's pixels at the saturation level
  double min_signal = 0.01;              // of full scale, for a shot's channel to count for gains
  double max_spectral_mismatch = 0.02;   // the spectral check's warning threshold
  double outlier_ratio = 5;              // leaving a shot out must divide the RMS by this
  double max_rms = 0.05;                 // of full scale: a worse fit is an error
  bool fit_black_level = true;           // when the data allow
  bool fit_gamma = true;                 // transfer gamma, when the data allow
  void Validate() const;                 // throws InputError naming the field
};

struct RadiometricShotResult {
  RadiometricShot shot;
  int patch_pixels = 0;
  Eigen::Vector3d mean_code = Eigen::Vector3d::Zero();   // per channel (mono: channel 0)
  Eigen::Vector3d model_code = Eigen::Vector3d::Zero();  // the fitted model's
  std::array<std::string, 3> left_out;  // why a channel was left out or what it weighs on
};

struct CameraRadiometricResult {
  std::string camera;
  int channels = 3;
  CameraRadiometry before, after;
  bool fitted_black_level = false, fitted_gamma = false;
  // The black level is the dark pixels' median (dark_level_dn): the shots could not fit it, and
  // the model's disagreed with the dark pixels (a datasheet's 0 for a camera whose offset is 64).
  bool black_level_from_dark = false;
  int shots = 0;             // of this camera
  int residuals = 0;         // shot channels in the fit
  double rms_dn = 0;         // of the fit's code residuals
  double dark_level_dn = 0;  // median code of the pixels far from the patch (a cross-check)
  std::array<int, 4> region{0, 0, 0, 0};
  // The spectral check: per channel, max |measured / model - 1| over the temperatures (0 with one).
  Eigen::Vector3d spectral_mismatch = Eigen::Vector3d::Zero();
  std::vector<double> temperatures_k;  // distinct, ascending
  std::vector<std::string> notes;      // what was held and why
  std::vector<std::string> warnings;   // the spectral check
};

struct RadiometricCalibration {
  std::vector<CameraRadiometricResult> cameras;  // in rig order, cameras with shots only
  std::vector<RadiometricShotResult> shots;
  bool lamp = false;
  double exposure_unit_us = 0;  // the shots file's (RadiometricShots::exposure_unit_us)
  std::string Report() const;   // markdown: per camera before/after, the check, the shots
  std::string Brief() const;    // a few lines for the terminal
  void WriteCsv(const std::string& path) const;  // one row per shot and channel
};

// Fits every rig camera that has shots; cameras without shots are left out of the result (their
// models unchanged). Reads the images (8- or 16-bit PNG, decoded through each camera's bit depth
// and levels). Throws InputError naming a shot whose camera is not in the rig, an image of the
// wrong size or channel count, a camera with no usable shot, or a patch that cannot be found.
RadiometricCalibration CalibrateRadiometry(const Rig& rig, const RadiometricShots& shots,
                                           const RadiometricOptions& options);

// The rig with every calibrated camera's model replaced by its fitted one, and the shots' exposure
// unit when they gave one (Rig::exposure_unit_us; not for a lamp, whose gains' scale is not
// calibrated).
Rig ApplyRadiometricCalibration(const Rig& rig, const RadiometricCalibration& calibration);

// `flamerig calibrate-radiometry`: calibrates and writes OUT/rig.yaml (with the camera models),
// OUT/report.md and OUT/shots.csv. Returns the calibration.
RadiometricCalibration RunRadiometricCalibration(const std::string& rig_path,
                                                 const std::string& shots_path,
                                                 const std::string& out_dir,
                                                 const RadiometricOptions& options);

// What the simulator films of a source for calibration: a disc of radiance emissivity *
// B_c(T) through `film`'s response (its gains included) covering a quarter of the image's smaller
// side in radius, its edge blurred over 3 px, on black; recorded with RecordCameraImage
// (simulate.h) at `exposure` with `noise_dn` noise. Returns the frame's bit depth.
int FilmCalibrationSource(int width, int height, double temperature_k, double emissivity,
                          double exposure, const CameraRadiometry& film, double noise_dn,
                          std::uint64_t seed, ImageU8* u8, ImageU16* u16);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_RADIOMETRIC_CALIBRATION_H_
