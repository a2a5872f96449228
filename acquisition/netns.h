// Running a program again inside a private network namespace (`unshare -rn`, no root needed) with
// the loopback addresses 127.0.0.2..9 up: each Aravis fake GigE Vision camera needs an address of
// its own, and the host's loopback has only 127.0.0.1. Used by the Aravis tests and the capture
// benchmark.
#ifndef FLAMERIG_ACQUISITION_NETNS_H_
#define FLAMERIG_ACQUISITION_NETNS_H_

#include <string>
#include <vector>

namespace flamerig {

// When the environment variable FLAMERIG_ARAVIS_NETNS is unset: sets it to "1" and replaces this
// process by `command` (argv, program path first) inside a new namespace; if namespaces are not
// allowed here, sets it to "unavailable" and returns. When it is already set, returns at once.
void RerunInLoopbackNamespace(const std::vector<std::string>& command);

// True inside such a namespace (the addresses 127.0.0.2..9 exist).
bool InLoopbackNamespace();

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_NETNS_H_
