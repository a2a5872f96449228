#include "acquisition/netns.h"

#include <unistd.h>

#include <cstdlib>

namespace flamerig {

void RerunInLoopbackNamespace(const std::vector<std::string>& command) {
  if (std::getenv("FLAMERIG_ARAVIS_NETNS")) return;
  ::setenv("FLAMERIG_ARAVIS_NETNS", "1", 1);
  if (!command.empty() &&
      std::system("unshare -rn sh -c 'ip link set lo up && ip addr add 127.0.0.2/32 dev lo' "
                  ">/dev/null 2>&1") == 0) {
    std::vector<const char*> args = {
        "unshare",
        "-rn",
        "sh",
        "-c",
        "ip link set lo up && for a in 2 3 4 5 6 7 8 9; do ip addr add 127.0.0.$a/32 dev lo; "
        "done && exec \"$@\"",
        "flamerig-netns"};
    for (const auto& a : command) args.push_back(a.c_str());
    args.push_back(nullptr);
    ::execvp("unshare", const_cast<char* const*>(args.data()));
  }
  ::setenv("FLAMERIG_ARAVIS_NETNS", "unavailable", 1);
}

bool InLoopbackNamespace() {
  const char* v = std::getenv("FLAMERIG_ARAVIS_NETNS");
  return v && std::string(v) == "1";
}

}  // namespace flamerig
