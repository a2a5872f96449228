// A .vdb file given to reconstruct, fit, render or run (tomography/vdb_io.h): errors are
// std::runtime_error naming the file.
#include "tests/fuzz/fuzz_util.h"
#include "tomography/vdb_io.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string path = flamerig_fuzz::WriteFile("in.vdb", data, size);
  try {
    // A budget of 256 MB for the dense fields: a damaged flamerig_dims states up to 2^31 voxels,
    // which ReadVdb refuses beyond the budget (by default the machine's memory, beyond the
    // fuzzer's limit).
    flamerig::ReadVdb(path, std::size_t(256) << 20);
  } catch (const std::runtime_error&) {
  } catch (const std::invalid_argument&) {
  }
  return 0;
}
