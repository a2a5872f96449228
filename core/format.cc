#include "core/format.h"

#include <algorithm>
#include <cstdio>

namespace flamerig {

std::string FormatNumber(double v, int significant) {
  char text[40];
  std::snprintf(text, sizeof text, "%.*g", std::clamp(significant, 1, 17), v);
  return text;
}

}  // namespace flamerig
