#include "common/config_error.h"

#include <cmath>
#include <cstdlib>
#include <sstream>

namespace kinevis::common {

std::string Num(double value) {
  if (std::isnan(value)) return "nan";
  if (std::isinf(value)) return value > 0 ? "inf" : "-inf";
  for (int digits = 6; digits < 17; ++digits) {
    std::ostringstream o;
    o.precision(digits);
    o << value;
    if (std::strtod(o.str().c_str(), nullptr) == value) return o.str();
  }
  std::ostringstream o;
  o.precision(17);
  o << value;
  return o.str();
}

void Problems::Add(std::string text) { problems_.push_back(std::move(text)); }

void Problems::Add(std::string_view field, double value, std::string_view rule) {
  Add(std::string(field) + ": " + std::string(rule) + ", got " + Num(value));
}

void Problems::Add(std::string_view field, std::string_view value, std::string_view rule) {
  Add(std::string(field) + ": " + std::string(rule) + ", got '" + std::string(value) + "'");
}

void Problems::Finite(std::string_view field, double value) {
  if (!std::isfinite(value)) Add(field, value, "must be finite");
}

void Problems::Positive(std::string_view field, double value) {
  if (!(std::isfinite(value) && value > 0)) Add(field, value, "must be > 0");
}

void Problems::NonNegative(std::string_view field, double value) {
  if (!(std::isfinite(value) && value >= 0)) Add(field, value, "must be >= 0");
}

void Problems::InRange(std::string_view field, double value, double lo, double hi) {
  if (!(value >= lo && value <= hi)) {
    Add(field, value, "must be in " + Num(lo) + ".." + Num(hi));
  }
}

std::string Problems::Message() const {
  std::string message;
  for (const std::string& p : problems_) message += (message.empty() ? "" : "; ") + p;
  return message;
}

void Problems::ThrowIfAny() const {
  if (problems_.empty()) return;
  throw ConfigError(subject_.empty() ? Message() : subject_ + ": " + Message());
}

}  // namespace kinevis::common
