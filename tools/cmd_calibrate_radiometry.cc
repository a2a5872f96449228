// `flamerig calibrate-radiometry`: each camera's gains, black level and gamma from images of a
// black body or a lamp (pipeline/radiometric_calibration.h).
#include <cstdio>
#include <memory>

#include "pipeline/radiometric_calibration.h"
#include "tools/cli.h"

namespace flamerig::cli {

Runner AddCalibrateRadiometry(CLI::App* command) {
  struct Options {
    std::string rig, shots, out;
    RadiometricOptions radiometric;
    bool hold_black = false, hold_gamma = false;
  };
  auto o = std::make_shared<Options>();
  command->footer(
      "Fit each camera's per-channel gains, black level and (transfer: gamma) gamma to its\n"
      "images of a black-body calibrator or a lamp at several exposures, and write the rig with\n"
      "them (OUT/rig.yaml), a report (OUT/report.md) and every shot's numbers (OUT/shots.csv).\n"
      "The shots file lists camera, image, source temperature and exposure per shot; `simulate`\n"
      "writes one with `radiometric_calibration: {enabled: true}`. With two source\n"
      "temperatures or more the fit also checks each camera's spectral sensitivity.");
  command->add_option("--rig", o->rig, "The rig whose cameras' models to calibrate")
      ->required()
      ->type_name("R.yaml");
  command->add_option("--shots", o->shots, "The calibration shots")
      ->required()
      ->type_name("S.yaml");
  command->add_option("--out", o->out, "Output folder")->required()->type_name("DIR");
  command
      ->add_option("--erode", o->radiometric.erode_px,
                   "Shrink the found source patch by N px (default 3)")
      ->type_name("N")
      ->check(Whole(0, 100));
  command->add_flag("--hold-black-level", o->hold_black, "Keep each model's black level");
  command->add_flag("--hold-gamma", o->hold_gamma, "Keep each model's gamma");
  return [o](Context&) {
    RadiometricOptions options = o->radiometric;
    options.fit_black_level = !o->hold_black;
    options.fit_gamma = !o->hold_gamma;
    const RadiometricCalibration c = RunRadiometricCalibration(o->rig, o->shots, o->out, options);
    std::fprintf(stderr, "%s", c.Brief().c_str());
    Log().info("calibrate-radiometry: wrote {}/rig.yaml, {}/report.md, {}/shots.csv", o->out,
               o->out, o->out);
    return kExitOk;
  };
}

}  // namespace flamerig::cli
