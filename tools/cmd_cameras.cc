// `flamerig cameras`: every camera each driver can see now (acquisition/camera_drivers.h).
#include <cstdio>
#include <memory>

#include "acquisition/camera_drivers.h"
#include "tools/cli.h"

namespace flamerig::cli {

Runner AddCameras(CLI::App* command) {
  struct Options {
    std::string driver;
    bool details = false;
  };
  auto o = std::make_shared<Options>();
  command->footer(
      "List the cameras each driver can see now (Aravis: GigE Vision and USB3 Vision on every\n"
      "interface; v4l2: /dev/video* capture devices), with the id a capture config opens them by.\n"
      "--details opens each one and shows its sensor size, pixel formats and current settings.");
  std::vector<std::string> names;
  for (const CameraDriver& d : CameraDrivers()) names.push_back(d.name);
  command->add_option("--driver", o->driver, "Only this driver's cameras")
      ->check(CLI::IsMember(names));
  command->add_flag("--details", o->details,
                    "Open each camera: sensor size, formats, current settings");
  return [o](Context&) {
    std::printf("%-8s %-24s %-20s %-24s %-20s %s\n", "driver", "id", "vendor", "model", "serial",
                "address");
    std::size_t found = 0, failed = 0;
    for (const CameraDriver& d : CameraDrivers()) {
      if (!o->driver.empty() && d.name != o->driver) continue;
      if (!d.discover) continue;  // the sim driver's cameras exist only in a config
      for (const CameraDescription& c : d.discover()) {
        std::printf("%-8s %-24s %-20s %-24s %-20s %s\n", d.name.c_str(), c.id.c_str(),
                    c.vendor.c_str(), c.model.c_str(), c.serial.c_str(), c.address.c_str());
        ++found;
        if (!o->details || !d.details) continue;
        try {
          for (const auto& [label, value] : d.details(c))
            std::printf("    %-22s %s\n", label.c_str(), value.c_str());
        } catch (const std::exception& e) {
          std::printf("    cannot open it: %s\n", e.what());
          ++failed;
        }
      }
    }
    Log().info("cameras: {} found{}", found,
               failed ? ", " + std::to_string(failed) + " could not be opened" : std::string());
    return kExitOk;
  };
}

}  // namespace flamerig::cli
