// `flamerig benchmark`: run time against error, written to BENCHMARKS.md with the machine and date.
//
// Each benchmark owns one section of BENCHMARKS.md between "<!-- BEGIN name -->" and
// "<!-- END name -->", replaced on every run, so benchmarks of different modules share the file.
#ifndef FLAMERIG_TOOLS_BENCHMARK_H_
#define FLAMERIG_TOOLS_BENCHMARK_H_

#include <functional>
#include <string>
#include <vector>

namespace flamerig {

struct RenderBenchmarkOptions {
  std::vector<int> resolutions = {32, 64, 128};  // cubic grids N^3
  int width = 320;
  int height = 240;
  int repeats = 5;     // renders timed per configuration; the median is reported
  bool quick = false;  // CI smoke mode: 32^3 and 64^3, 2 repeats
};

// The forward-render benchmark: a 320x240 view of the candle fire on cubic grids, fast path (grey)
// and spectral path (soot), 1 and 2 threads, with and without empty-space skipping. Error is the
// mean and maximum CIE76 Delta E of the 8-bit image against a reference render (double precision,
// step 0.1 voxel, 5 nm spectral bins, no skipping). Returns the Markdown section.
std::string RunRenderBenchmark(const RenderBenchmarkOptions& options,
                               const std::function<void(const std::string&)>& log);

// Replaces (or appends) section `name` of the Markdown file at `path`.
void WriteBenchmarkSection(const std::string& path, const std::string& name,
                           const std::string& markdown);

// "CPU model, N cores, date" for the report header.
std::string MachineDescription();

}  // namespace flamerig

#endif  // FLAMERIG_TOOLS_BENCHMARK_H_
