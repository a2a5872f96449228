// The `flamerig simulate` config (pipeline/simulate.h): errors are std::runtime_error or
// std::invalid_argument naming the file and the field.
#include "tests/fuzz/fuzz_util.h"
#include "pipeline/simulate.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string path = flamerig_fuzz::WriteFile("simulate.yaml", data, size);
  try {
    flamerig::SimulateConfig::Load(path).Validate();
  } catch (const std::runtime_error&) {
  } catch (const std::invalid_argument&) {
  }
  return 0;
}
