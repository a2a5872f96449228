#include "core/csv.h"

#include <sstream>

namespace flamerig {

std::vector<std::string> SplitCsvRow(const std::string& line) {
  std::vector<std::string> cells;
  std::stringstream row(line);
  for (std::string cell; std::getline(row, cell, ',');) cells.push_back(cell);
  if (!line.empty() && line.back() == ',') cells.emplace_back();
  return cells;
}

}  // namespace flamerig
