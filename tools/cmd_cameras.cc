// `flamerig cameras`: every camera each driver can see now (acquisition/camera_drivers.h).
#include <cstdio>
#include <memory>

#include "acquisition/camera_drivers.h"
#include "tools/cli.h"

namespace flamerig::cli {

Runner AddCameras(CLI::App* command) {
  auto driver = std::make_shared<std::string>();
  command->footer(
      "List the cameras each driver can see now (Aravis: GigE Vision and USB3 Vision on every\n"
      "interface; v4l2: /dev/video* capture devices), with the id a capture config opens them by.");
  std::vector<std::string> names;
  for (const CameraDriver& d : CameraDrivers()) names.push_back(d.name);
  command->add_option("--driver", *driver, "Only this driver's cameras")->check(CLI::IsMember(names));
  return [driver](Context&) {
    std::printf("%-8s %-24s %-20s %-24s %s\n", "driver", "id", "vendor", "model", "address");
    std::size_t found = 0;
    for (const CameraDriver& d : CameraDrivers()) {
      if (!driver->empty() && d.name != *driver) continue;
      if (!d.discover) continue;  // the sim driver's cameras exist only in a config
      for (const CameraDescription& c : d.discover()) {
        std::printf("%-8s %-24s %-20s %-24s %s\n", d.name.c_str(), c.id.c_str(), c.vendor.c_str(),
                    c.model.c_str(), c.address.c_str());
        ++found;
      }
    }
    Log().info("cameras: {} found", found);
    return kExitOk;
  };
}

}  // namespace flamerig::cli
