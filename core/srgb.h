// The sRGB transfer curve and 8-bit quantisation: how a camera's linear signal becomes the 8-bit
// values in an image file, and back. Encoded values are in [0, 1]; linear values are clamped to [0,
// 1] before encoding (saturation), NaN maps to 0.
#ifndef FLAMERIG_CORE_SRGB_H_
#define FLAMERIG_CORE_SRGB_H_

#include <array>
#include <cstdint>

namespace flamerig {

double SrgbEncode(double linear);
double SrgbDecode(double encoded);
// round(255 * encoded), saturating; NaN maps to 0.
std::uint8_t QuantizeU8(double encoded);
// SrgbDecode(i / 255) for every 8-bit value.
const std::array<double, 256>& SrgbU8ToLinearTable();

}  // namespace flamerig

#endif  // FLAMERIG_CORE_SRGB_H_
