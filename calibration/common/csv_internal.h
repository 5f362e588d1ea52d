#pragma once

// Shared by the calibration dataset readers (hexapod, laser scanner, scanner mount, scan,
// DIAMOND): splitting a CSV line (no quoting: the datasets' fields never hold commas) and strict
// number parsing (the whole field, finite). Private to calibration/.

#include <climits>
#include <cmath>
#include <cstdlib>
#include <sstream>
#include <string>
#include <vector>

namespace kinevis::calibration::internal {

// Fields of a comma-separated line; a trailing comma gives a trailing empty field.
inline std::vector<std::string> SplitCsv(const std::string& line) {
  std::vector<std::string> out;
  std::stringstream in(line);
  for (std::string field; std::getline(in, field, ',');) out.push_back(field);
  if (!line.empty() && line.back() == ',') out.emplace_back();
  return out;
}

// The whole of `text` as a finite double; false (value unspecified) otherwise.
inline bool ParseDouble(const std::string& text, double* value) {
  if (text.empty()) return false;
  char* end = nullptr;
  *value = std::strtod(text.c_str(), &end);
  return end == text.c_str() + text.size() && std::isfinite(*value);
}

// The whole of `text` as an int; false otherwise.
inline bool ParseInt(const std::string& text, int* value) {
  if (text.empty()) return false;
  char* end = nullptr;
  const long v = std::strtol(text.c_str(), &end, 10);
  if (end != text.c_str() + text.size() || v < INT_MIN || v > INT_MAX) return false;
  *value = static_cast<int>(v);
  return true;
}

}  // namespace kinevis::calibration::internal
