#include "core/format.h"

#include <algorithm>
#include <charconv>
#include <cstdio>

namespace flamerig {

std::string FormatNumber(double v, int significant) {
  char text[40];
  std::snprintf(text, sizeof text, "%.*g", std::clamp(significant, 1, 17), v);
  return text;
}

std::string FormatExact(double v) {
  char text[40];
  const std::to_chars_result r = std::to_chars(text, text + sizeof text, v);
  return std::string(text, r.ptr);
}

}  // namespace flamerig
