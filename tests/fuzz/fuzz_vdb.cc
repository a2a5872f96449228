// A .vdb file given to reconstruct, fit, render or run (tomography/vdb_io.h): errors are
// std::runtime_error naming the file.
#include "tests/fuzz/fuzz_util.h"
#include "tomography/vdb_io.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string path = flamerig_fuzz::WriteFile("in.vdb", data, size);
  try {
    flamerig::ReadVdb(path);
  } catch (const std::runtime_error&) {
  } catch (const std::invalid_argument&) {
  }
  return 0;
}
