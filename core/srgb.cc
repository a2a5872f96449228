#include "core/srgb.h"

#include <cmath>

namespace flamerig {

double SrgbEncode(double linear) {
  if (!(linear > 0)) return 0.0;  // also NaN
  if (linear >= 1) return 1.0;
  if (linear <= 0.0031308) return 12.92 * linear;
  return 1.055 * std::pow(linear, 1.0 / 2.4) - 0.055;
}

double SrgbDecode(double encoded) {
  if (!(encoded > 0)) return 0.0;
  if (encoded >= 1) return 1.0;
  if (encoded <= 0.04045) return encoded / 12.92;
  return std::pow((encoded + 0.055) / 1.055, 2.4);
}

std::uint8_t QuantizeU8(double encoded) {
  if (!(encoded > 0)) return 0;
  if (encoded >= 1) return 255;
  return static_cast<std::uint8_t>(std::lround(encoded * 255.0));
}

const std::array<double, 256>& SrgbU8ToLinearTable() {
  static const std::array<double, 256> table = [] {
    std::array<double, 256> t{};
    for (int i = 0; i < 256; ++i) t[i] = SrgbDecode(i / 255.0);
    return t;
  }();
  return table;
}

}  // namespace flamerig
