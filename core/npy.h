// NumPy's .npy format 1.0, the part every writer shares: the magic, version, header length and
// header (a Python dict literal padded with spaces to a multiple of 64 bytes and ended by a
// newline). The data, little-endian and in C order, follows it.
#ifndef FLAMERIG_CORE_NPY_H_
#define FLAMERIG_CORE_NPY_H_

#include <cstddef>
#include <string>
#include <vector>

namespace flamerig {

// `descr` as it appears in the dict: a quoted dtype ("'<f8'") or a structured one's list
// ("[('x_m', '<f4'), ...]"); `shape` the array's dimensions, empty for a scalar.
std::string NpyHeader(const std::string& descr, const std::vector<std::size_t>& shape);

}  // namespace flamerig

#endif  // FLAMERIG_CORE_NPY_H_
