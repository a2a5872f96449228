// A rig YAML file (calibration/rig.h) beside a valid camera model: errors are std::runtime_error or
// std::invalid_argument naming the file.
#include <filesystem>

#include "calibration/rig.h"
#include "tests/fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const bool ready = [] {
    flamerig::CameraModel model("LENSMODEL_PINHOLE", {500, 500, 319.5, 239.5}, flamerig::Rigid3(),
                                640, 480);
    std::filesystem::create_directories(flamerig_fuzz::Dir() / "cameras");
    model.Save((flamerig_fuzz::Dir() / "cameras" / "cam0.cameramodel").string());
    return true;
  }();
  (void)ready;
  const std::string path = flamerig_fuzz::WriteFile("rig.yaml", data, size);
  try {
    flamerig::Rig::Load(path);
  } catch (const std::runtime_error&) {
  } catch (const std::invalid_argument&) {
  }
  return 0;
}
