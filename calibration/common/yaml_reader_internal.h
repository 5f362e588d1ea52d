#pragma once

// Shared by the calibration result readers (hexapod, laser scanner): a YAML reader that collects
// every missing or bad key of a file and throws once, naming the file and each key; and the UTC
// time stamp the writers put in their files. Private to calibration/ (yaml-cpp stays out of
// public headers).

#include <yaml-cpp/yaml.h>

#include <Eigen/Core>
#include <cmath>
#include <ctime>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace kinevis::calibration::internal {

// Now, UTC, ISO 8601 ("2026-12-01T21:31:00Z").
inline std::string NowUtc() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char buffer[32];
  std::strftime(buffer, sizeof(buffer), "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buffer;
}

// Collects every problem of a file, then throws once (std::invalid_argument).
class CheckedYamlReader {
 public:
  // `what` names the kind of file in the message ("hexapod calibration file").
  CheckedYamlReader(std::string what, std::string path)
      : what_(std::move(what)), path_(std::move(path)) {}

  void Bad(const std::string& key, const std::string& what) {
    errors_ += (errors_.empty() ? "" : "; ") + key + ": " + what;
  }
  void ThrowIfBad() const {
    if (!errors_.empty()) {
      throw std::invalid_argument(what_ + " " + path_ + ": " + errors_);
    }
  }

  YAML::Node Child(const YAML::Node& node, const std::string& name, const std::string& key) {
    if (!node.IsMap() || !node[name]) {
      Bad(key, "missing");
      // Undefined (not null), so that callers' `if (!v)` skips what is missing instead of
      // reporting it again as "not a number ()".
      return YAML::Node(YAML::NodeType::Undefined);
    }
    return node[name];
  }

  // A double; NaN / inf allowed only when `finite` is false.
  double Double(const YAML::Node& node, const std::string& name, const std::string& key,
                bool finite = true) {
    const YAML::Node v = Child(node, name, key);
    if (!v) return std::nan("");
    double d = 0.0;
    if (!v.IsScalar() || !YAML::convert<double>::decode(v, d)) {
      Bad(key, "not a number (" + Dump(v) + ")");
      return std::nan("");
    }
    if (finite && !std::isfinite(d)) Bad(key, "must be finite (" + v.Scalar() + ")");
    return d;
  }
  int Int(const YAML::Node& node, const std::string& name, const std::string& key, int min) {
    const YAML::Node v = Child(node, name, key);
    if (!v) return 0;
    int i = 0;
    if (!v.IsScalar() || !YAML::convert<int>::decode(v, i)) {
      Bad(key, "not an integer (" + Dump(v) + ")");
      return 0;
    }
    if (i < min) Bad(key, "must be >= " + std::to_string(min) + " (" + v.Scalar() + ")");
    return i;
  }
  bool Bool(const YAML::Node& node, const std::string& name, const std::string& key) {
    const YAML::Node v = Child(node, name, key);
    bool b = false;
    if (v && (!v.IsScalar() || !YAML::convert<bool>::decode(v, b))) {
      Bad(key, "not true/false (" + Dump(v) + ")");
    }
    return b;
  }
  std::string String(const YAML::Node& node, const std::string& name, const std::string& key) {
    const YAML::Node v = Child(node, name, key);
    if (!v) return "";
    if (!v.IsScalar()) {
      Bad(key, "not a string (" + Dump(v) + ")");
      return "";
    }
    return v.Scalar();
  }
  // A list of `n` numbers (NaN allowed when !finite).
  template <int N>
  Eigen::Matrix<double, N, 1> Numbers(const YAML::Node& node, const std::string& name,
                                      const std::string& key, bool finite = true) {
    Eigen::Matrix<double, N, 1> out = Eigen::Matrix<double, N, 1>::Constant(std::nan(""));
    const YAML::Node v = Child(node, name, key);
    if (!v) return out;
    if (!v.IsSequence() || v.size() != N) {
      Bad(key, "must be a list of " + std::to_string(N) + " numbers (" + Dump(v) + ")");
      return out;
    }
    for (int i = 0; i < N; ++i) {
      double d = 0.0;
      if (!v[i].IsScalar() || !YAML::convert<double>::decode(v[i], d) ||
          (finite && !std::isfinite(d))) {
        Bad(key, "element " + std::to_string(i) + " is not a finite number (" + Dump(v) + ")");
        return out;
      }
      out(i) = d;
    }
    return out;
  }

  std::vector<std::string> Strings(const YAML::Node& node, const std::string& name,
                                   const std::string& key) {
    std::vector<std::string> out;
    const YAML::Node v = Child(node, name, key);
    if (!v) return out;
    if (!v.IsSequence()) {
      Bad(key, "not a list (" + Dump(v) + ")");
      return out;
    }
    for (const YAML::Node& s : v) out.push_back(s.IsScalar() ? s.Scalar() : Dump(s));
    return out;
  }

  static std::string Dump(const YAML::Node& v) {
    YAML::Emitter e;
    e << YAML::Flow << v;
    return e.c_str();
  }

 private:
  std::string what_;
  std::string path_;
  std::string errors_;
};

}  // namespace kinevis::calibration::internal
