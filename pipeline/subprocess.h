// Running another program (gnuplot, ffmpeg) and waiting for it, without a shell: the arguments go
// to the program as they are, so paths with spaces or quotes need no escaping.
#ifndef FLAMERIG_PIPELINE_SUBPROCESS_H_
#define FLAMERIG_PIPELINE_SUBPROCESS_H_

#include <cstddef>
#include <string>
#include <vector>

namespace flamerig {

struct ProgramResult {
  bool started = false;  // false: the program could not be run (not installed); see `error`
  int exit_status = -1;  // the exit status, or -1 when it was killed by a signal
  std::string error;     // why it did not start, or the first 2000 bytes of its standard error
  // The program's own peak resident memory: its VmHWM read while it runs (wait4's ru_maxrss when
  // it could not be read, which counts this process's peak at the spawn too).
  std::size_t peak_resident_bytes = 0;
  double seconds = 0;  // wall time from start to exit
  bool ok() const { return started && exit_status == 0; }
};

// Runs argv[0] (looked up in PATH) with argv[1..] in the folder `dir` ("" = this process's),
// standard input and output from and to /dev/null, standard error kept; waits for it.
ProgramResult RunProgram(const std::vector<std::string>& argv, const std::string& dir = "");

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_SUBPROCESS_H_
