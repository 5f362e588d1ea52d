#pragma once

// Bad input at set-up, the second error tier of STYLE.md: a configuration file, a deployment
// file, a backend string, a command-line option. Such input is checked as a whole and thrown once,
// with every bad field and its value in one message that names the source, so that the user
// fixes all of it in one go:
//
//   common::Problems p("config/hexapod-sim.yaml");
//   p.Positive("drives.counts_per_metre", config.counts_per_metre);
//   p.InRange("modbus.unit", config.unit, 1, 247);
//   p.ThrowIfAny();  // ConfigError: "config/hexapod-sim.yaml: drives.counts_per_metre: must be
//                    //  > 0, got -1; modbus.unit: must be in 1..247, got 0"
//
// Every problem reads "FIELD: RULE, got VALUE" (or free text where no single value is at fault).
// Validate() methods that return the message instead of throwing use Message().

#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace kinevis::common {

// Thrown at set-up for bad configuration or arguments: names the source, the field and the value.
// The CLI maps it to exit code 2.
class ConfigError : public std::invalid_argument {
 public:
  explicit ConfigError(const std::string& message) : std::invalid_argument(message) {}
};

// The shortest decimal text that reads back as `value` ("0.1", not "0.10000000000000001");
// "nan", "inf", "-inf" for non-finite values.
std::string Num(double value);

// Collects the problems of one piece of input, then reports them together.
class Problems {
 public:
  Problems() = default;
  // subject: what is being checked, put before the problems when thrown ("backend \"tty:\"",
  // a file's path). Empty: the message is the problems alone.
  explicit Problems(std::string subject) : subject_(std::move(subject)) {}

  // A free-text problem.
  void Add(std::string text);
  // "field: rule, got value".
  void Add(std::string_view field, double value, std::string_view rule);
  void Add(std::string_view field, std::string_view value, std::string_view rule);

  // The common rules; each adds a problem when the value breaks it. NaN breaks every rule.
  void Finite(std::string_view field, double value);                         // "must be finite"
  void Positive(std::string_view field, double value);                       // finite and > 0
  void NonNegative(std::string_view field, double value);                    // finite and >= 0
  void InRange(std::string_view field, double value, double lo, double hi);  // lo <= v <= hi

  bool empty() const { return problems_.empty(); }
  const std::vector<std::string>& problems() const { return problems_; }
  const std::string& subject() const { return subject_; }
  // The problems joined by "; "; empty when there are none.
  std::string Message() const;
  // Throws ConfigError("SUBJECT: " + Message()) when any problem was added.
  void ThrowIfAny() const;

 private:
  std::string subject_;
  std::vector<std::string> problems_;
};

}  // namespace kinevis::common
