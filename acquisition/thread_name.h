// Names the calling thread, so that `top -H`, gdb, /proc/PID/task/*/comm and the capture soak's
// fault injector (tools/soak.h) can tell the daemon's threads apart. Linux keeps at most 15
// characters; longer names are cut there.
#ifndef FLAMERIG_ACQUISITION_THREAD_NAME_H_
#define FLAMERIG_ACQUISITION_THREAD_NAME_H_

#include <pthread.h>

#include <string>

namespace flamerig {

inline void NameThisThread(const std::string& name) {
  (void)pthread_setname_np(pthread_self(), name.substr(0, 15).c_str());
}

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_THREAD_NAME_H_
