// Numbers in messages, reports and text files: printf's %g with `significant` digits ("0.55",
// "1.92e+03", "nan", "inf"), the same on every locale. One formatter for the whole project, so
// that a number reads the same in an error, a report and a log line.
//
//   FormatNumber(0.549999)      -> "0.549999"
//   FormatNumber(0.549999, 3)   -> "0.55"
//   FormatNumber(1.0 / 3, 17)   -> "0.33333333333333331" (round-trips a double exactly)
//   FormatExact(0.009)          -> "0.009" (the shortest text that reads back as the same double)
#ifndef FLAMERIG_CORE_FORMAT_H_
#define FLAMERIG_CORE_FORMAT_H_

#include <string>

namespace flamerig {

// `significant` in 1..17 (clamped).
std::string FormatNumber(double v, int significant = 6);

// The shortest text that reads back as exactly `v` (std::to_chars): for values that must survive a
// round trip and still read as their author wrote them (a board's 0.009 m, not
// 0.0089999999999999993).
std::string FormatExact(double v);

}  // namespace flamerig

#endif  // FLAMERIG_CORE_FORMAT_H_
