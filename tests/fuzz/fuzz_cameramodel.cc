// An mrcal .cameramodel file (calibration/camera_model.h), parsed by libmrcal and checked by us:
// errors are std::runtime_error naming the file.
#include "calibration/camera_model.h"
#include "tests/fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string path = flamerig_fuzz::WriteFile("cam.cameramodel", data, size);
  try {
    const flamerig::CameraModel m = flamerig::CameraModel::Load(path);
    // What every user of a model does next: project and unproject a pixel.
    m.Unproject(Eigen::Vector2d(0.5 * m.width(), 0.5 * m.height()));
  } catch (const std::runtime_error&) {
  } catch (const std::invalid_argument&) {
  }
  return 0;
}
