// One row of the comma-separated files flamerig writes and reads back (an export's sets.csv, a
// fit's ring profile): its cells, split at every comma, a trailing comma giving a last empty
// cell. No quoting: these files hold numbers, names and statuses, never a comma inside a cell.
//
//   SplitCsvRow("set,cam0_exposure,")  -> {"set", "cam0_exposure", ""}
#ifndef FLAMERIG_CORE_CSV_H_
#define FLAMERIG_CORE_CSV_H_

#include <string>
#include <vector>

namespace flamerig {

std::vector<std::string> SplitCsvRow(const std::string& line);

}  // namespace flamerig

#endif  // FLAMERIG_CORE_CSV_H_
