// One way for the tests to run a command line: its exit status and everything it printed (stderr
// merged into stdout), as a person at a terminal would see it.
#ifndef FLAMERIG_TESTS_SHELL_UTIL_H_
#define FLAMERIG_TESTS_SHELL_UTIL_H_

#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <string>

namespace flamerig_test {

struct Result {
  int status = -1;  // the exit status; -1 when it did not exit normally or could not start
  std::string output;
};

inline Result Shell(const std::string& command) {
  Result r;
  FILE* pipe = popen((command + " 2>&1").c_str(), "r");
  if (!pipe) return r;
  std::array<char, 4096> buffer;
  while (fgets(buffer.data(), buffer.size(), pipe)) r.output += buffer.data();
  const int status = pclose(pipe);
  r.status = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

// `flamerig ARGS` (the binary the tests were built with).
inline Result Flamerig(const std::string& args) {
  return Shell(std::string(FLAMERIG_BINARY) + " " + args);
}

}  // namespace flamerig_test

#endif  // FLAMERIG_TESTS_SHELL_UTIL_H_
