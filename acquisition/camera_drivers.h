// The camera drivers, by name, in one registry: what each can do, the config keys it owns, how it
// opens a camera and how it finds the devices it can see. The capture daemon and its config decide
// by a driver's capabilities, never by its name.
//
// Adding a driver (README, "Extending flamerig"): its own files (a Camera, acquisition/camera.h,
// and a function returning its CameraDriver entry, declared below), one line in the registry
// (camera_drivers.cc) and its sources in acquisition/CMakeLists.txt. Nothing else changes: the
// config reads its keys through read_keys, the daemon opens it through open, `flamerig` lists
// its devices through discover.
//
// Thread safety: the registry is immutable; its functions may be called from any thread.
#ifndef FLAMERIG_ACQUISITION_CAMERA_DRIVERS_H_
#define FLAMERIG_ACQUISITION_CAMERA_DRIVERS_H_

#include <yaml-cpp/yaml.h>

#include <any>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "acquisition/camera.h"
#include "acquisition/clock.h"

namespace flamerig {

class SimTriggerBus;

// One camera of a capture config (acquisition/capture.h).
struct CaptureCameraConfig {
  std::string name;
  std::string driver = "sim";
  std::string id;  // serial, address or device path; what the driver opens
  CameraSettings settings;
  // false: the rig starts without this camera when it cannot be opened, and takes it in when it
  // can (MakeCameras tries again about once a second, as the daemon does for a lost camera).
  bool required = true;
  // The driver's own options, read from the camera's map under the driver's name (`sim:` for the
  // sim driver: SimCameraOptions) by CameraDriver::read_keys; empty for drivers without any.
  std::any options;

  // The driver's options as their type; std::logic_error when they are of another driver.
  template <typename T>
  T& Options() {
    T* o = std::any_cast<T>(&options);
    if (!o) throw std::logic_error("camera '" + name + "': no options of that driver");
    return *o;
  }
  template <typename T>
  const T& Options() const {
    const T* o = std::any_cast<T>(&options);
    if (!o) throw std::logic_error("camera '" + name + "': no options of that driver");
    return *o;
  }
};

// What a driver's cameras can do.
struct DriverCapabilities {
  // Frames carry the id of the trigger pulse that made them: triggered sets are matched by id
  // (otherwise by receive time).
  bool trigger_ids = false;
  // GigE Vision scheduled action commands (sync: ptp with an action block).
  bool action_commands = false;
};

// What the daemon gives a driver to open a camera.
struct DriverContext {
  Clock* clock = nullptr;                     // the daemon's clock
  SimTriggerBus* sim_trigger_line = nullptr;  // the simulated rig's trigger line (sim driver)
};

struct CameraDriver {
  std::string name;  // the config's `driver:`
  std::string description;
  DriverCapabilities capabilities;
  // The id of camera `index` when the config gives none; "" = the config must give one.
  std::string (*default_id)(int index) = nullptr;
  // Reads the driver's keys (`keys`: the camera's map under the driver's name; null when absent)
  // into camera->options. `where` names the map for errors ("rig.yaml: cameras[1].sim"),
  // `config_path` is the config file (paths in it are relative to its folder), `index` the
  // camera's place in the rig. Throws InputError naming `where` and the key. Null: the driver
  // has no keys of its own.
  void (*read_keys)(const YAML::Node& keys, const std::string& where,
                    const std::string& config_path, int index,
                    CaptureCameraConfig* camera) = nullptr;
  // Opens camera `index` of a rig. Throws IoError when the device cannot be opened.
  std::unique_ptr<Camera> (*open)(const CaptureCameraConfig& camera, int index,
                                  const DriverContext& context) = nullptr;
  // The devices this driver sees now (`flamerig cameras`); null: it finds none by itself.
  std::vector<CameraDescription> (*discover)() = nullptr;
  // What `flamerig cameras --details` shows of one discovered device, read by opening it: sensor
  // size, pixel formats, the current settings (name, value pairs in a reading order). Throws
  // IoError when it cannot be opened. Null: no details.
  std::vector<std::pair<std::string, std::string>> (*details)(const CameraDescription&) = nullptr;
};

// Every driver, in the order they are listed.
const std::vector<CameraDriver>& CameraDrivers();
// The driver named `name`; InputError listing the names when there is none.
const CameraDriver& FindCameraDriver(const std::string& name);

// The registry's entries, each defined in its driver's own file.
CameraDriver SimCameraDriver();     // sim_camera.cc
CameraDriver AravisCameraDriver();  // aravis_camera.cc
CameraDriver V4l2CameraDriver();    // v4l2_camera.cc

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_CAMERA_DRIVERS_H_
