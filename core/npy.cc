#include "core/npy.h"

namespace flamerig {

std::string NpyHeader(const std::string& descr, const std::vector<std::size_t>& shape) {
  std::string dims = "(";
  for (std::size_t i = 0; i < shape.size(); ++i)
    dims += std::to_string(shape[i]) + (shape.size() == 1 ? "," : i + 1 < shape.size() ? ", " : "");
  dims += ")";
  std::string header = "{'descr': " + descr + ", 'fortran_order': False, 'shape': " + dims + ", }";
  // Magic (6) + version (2) + length (2) + header, padded to a multiple of 64, then a newline.
  const std::size_t unpadded = 10 + header.size() + 1;
  header.append((64 - unpadded % 64) % 64, ' ');
  header += '\n';
  std::string out("\x93NUMPY\x01\x00", 8);
  out += static_cast<char>(header.size() & 0xff);  // the length, 16-bit little-endian
  out += static_cast<char>((header.size() >> 8) & 0xff);
  return out + header;
}

}  // namespace flamerig
