#include "acquisition/camera_drivers.h"

#include "core/error.h"

namespace flamerig {

const std::vector<CameraDriver>& CameraDrivers() {
  // The registry: add a driver here (and its files to CMakeLists.txt).
  static const std::vector<CameraDriver> drivers = {
      SimCameraDriver(),
      AravisCameraDriver(),
      V4l2CameraDriver(),
  };
  return drivers;
}

const CameraDriver& FindCameraDriver(const std::string& name) {
  std::string names;
  for (const CameraDriver& d : CameraDrivers()) {
    if (d.name == name) return d;
    names += (names.empty() ? "" : ", ") + d.name;
  }
  throw InputError("driver '" + name + "': use " + names);
}

}  // namespace flamerig
