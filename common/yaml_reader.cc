#include "common/yaml_reader.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "common/config_error.h"
#include "common/units.h"

namespace kinevis::common {

struct YamlReader::Impl {
  std::string path;
  YAML::Node root;
  Problems problems;

  // The node at a dotted key with list indices ("a.b[2].c"); an invalid (undefined) node when it
  // is not there. Read-only walk: a const Node's operator[] does not insert.
  YAML::Node Find(const std::string& key) const {
    YAML::Node cur = YAML::Clone(root);
    if (key.empty()) return cur;
    size_t begin = 0;
    while (begin < key.size()) {
      const size_t end = key.find_first_of(".[", begin);
      const std::string part = key.substr(begin, end == std::string::npos ? end : end - begin);
      if (!part.empty()) {
        if (!cur.IsMap()) return YAML::Node(YAML::NodeType::Undefined);
        const YAML::Node& c = cur;
        const YAML::Node next = c[part];
        if (!next) return YAML::Node(YAML::NodeType::Undefined);
        cur.reset(next);
      }
      if (end == std::string::npos) return cur;
      if (key[end] == '[') {
        const size_t close = key.find(']', end);
        if (close == std::string::npos) return YAML::Node(YAML::NodeType::Undefined);
        const size_t index = std::stoul(key.substr(end + 1, close - end - 1));
        if (!cur.IsSequence() || index >= cur.size()) return YAML::Node(YAML::NodeType::Undefined);
        const YAML::Node& c = cur;
        const YAML::Node next = c[index];
        cur.reset(next);
        begin = close + 1;
        if (begin < key.size() && key[begin] == '.') ++begin;
      } else {
        begin = end + 1;
      }
    }
    return cur;
  }

  double ToNumber(const YAML::Node& n, const std::string& key) {
    if (n.IsScalar()) {
      try {
        const double v = n.as<double>();
        if (std::isfinite(v)) return v;
      } catch (const YAML::Exception&) {
      }
      problems.Add(key + ": expected a finite number, got '" + n.Scalar() + "'");
    } else {
      problems.Add(key + ": expected a number");
    }
    return std::nan("");
  }

  std::vector<double> ToNumbers(const YAML::Node& n, const std::string& key, size_t count,
                                bool scalar_ok) {
    std::vector<double> out(count, std::nan(""));
    if (scalar_ok && n.IsScalar()) {
      const double v = ToNumber(n, key);
      std::fill(out.begin(), out.end(), v);
      return out;
    }
    if (!n.IsSequence() || n.size() != count) {
      problems.Add(key + ": need a list of " + std::to_string(count) + " numbers" +
                   (scalar_ok ? " (or one number)" : ""));
      return out;
    }
    for (size_t i = 0; i < count; ++i) out[i] = ToNumber(n[i], key + "[" + std::to_string(i) + "]");
    return out;
  }

  Eigen::Isometry3d ToPose(const YAML::Node& n, const std::string& key) {
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    if (!n.IsMap()) {
      problems.Add(key + ": expected {position: [x, y, z], rpy_deg: [roll, pitch, yaw]}");
      return X;
    }
    std::vector<double> position{0, 0, 0}, rpy{0, 0, 0};
    if (n["position"]) position = ToNumbers(n["position"], key + ".position", 3, false);
    if (n["rpy_deg"]) rpy = ToNumbers(n["rpy_deg"], key + ".rpy_deg", 3, false);
    for (const auto& kv : n) {
      const std::string k = kv.first.Scalar();
      if (k != "position" && k != "rpy_deg") problems.Add(key + "." + k + ": unknown key");
    }
    X.linear() = (Eigen::AngleAxisd(rpy[2] * kDeg, Eigen::Vector3d::UnitZ()) *
                  Eigen::AngleAxisd(rpy[1] * kDeg, Eigen::Vector3d::UnitY()) *
                  Eigen::AngleAxisd(rpy[0] * kDeg, Eigen::Vector3d::UnitX()))
                     .toRotationMatrix();
    X.translation() = Eigen::Vector3d(position[0], position[1], position[2]);
    return X;
  }
};

YamlReader::YamlReader(const std::string& path, const std::string& what)
    : impl_(std::make_unique<Impl>()) {
  impl_->path = path;
  try {
    impl_->root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw std::invalid_argument(path + ": cannot open the " + what);
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument(path + ": not valid YAML: " + e.what());
  }
  if (!impl_->root.IsMap()) throw std::invalid_argument(path + ": expected a YAML mapping");
}

YamlReader::~YamlReader() = default;

bool YamlReader::Has(const std::string& key) const { return static_cast<bool>(impl_->Find(key)); }

double YamlReader::Number(const std::string& key, double fallback) {
  const YAML::Node n = impl_->Find(key);
  return n ? impl_->ToNumber(n, key) : fallback;
}

// NOLINTNEXTLINE(google-runtime-int): the type of yaml-cpp's integers (yaml_reader.h)
long long YamlReader::Integer(const std::string& key, long long fallback) {
  const YAML::Node n = impl_->Find(key);
  if (!n) return fallback;
  try {
    if (n.IsScalar()) return n.as<long long>();  // NOLINT(google-runtime-int)
  } catch (const YAML::Exception&) {
  }
  impl_->problems.Add(key + ": expected an integer, got '" +
                      (n.IsScalar() ? n.Scalar() : "a list") + "'");
  return fallback;
}

std::string YamlReader::Text(const std::string& key, const std::string& fallback) {
  const YAML::Node n = impl_->Find(key);
  if (!n) return fallback;
  if (!n.IsScalar()) {
    impl_->problems.Add(key + ": expected a string");
    return fallback;
  }
  return n.Scalar();
}

std::vector<double> YamlReader::Numbers(const std::string& key, size_t n,
                                        std::vector<double> fallback, bool scalar_ok) {
  const YAML::Node node = impl_->Find(key);
  return node ? impl_->ToNumbers(node, key, n, scalar_ok) : std::move(fallback);
}

Eigen::Isometry3d YamlReader::Pose(const std::string& key, const Eigen::Isometry3d& fallback) {
  const YAML::Node n = impl_->Find(key);
  return n ? impl_->ToPose(n, key) : fallback;
}

std::string YamlReader::Resolve(const std::string& file) const {
  if (file.empty() || file[0] == '/') return file;
  const size_t slash = impl_->path.rfind('/');
  return slash == std::string::npos ? file : impl_->path.substr(0, slash + 1) + file;
}

std::string YamlReader::Path(const std::string& key) { return Resolve(Text(key, "")); }

size_t YamlReader::ListSize(const std::string& key) {
  const YAML::Node n = impl_->Find(key);
  if (!n) return 0;
  if (!n.IsSequence()) {
    impl_->problems.Add(key + ": expected a list");
    return 0;
  }
  return n.size();
}

void YamlReader::CheckKeys(const std::string& key, const std::vector<std::string>& known) {
  const YAML::Node n = impl_->Find(key);
  if (!n) return;
  if (!n.IsMap()) {
    impl_->problems.Add((key.empty() ? "the file" : key) + ": expected a mapping");
    return;
  }
  for (const auto& kv : n) {
    const std::string k = kv.first.Scalar();
    if (std::find(known.begin(), known.end(), k) == known.end()) {
      impl_->problems.Add((key.empty() ? "" : key + ".") + k + ": unknown key");
    }
  }
}

void YamlReader::Problem(const std::string& text) { impl_->problems.Add(text); }

bool YamlReader::HasProblems() const { return !impl_->problems.empty(); }

void YamlReader::ThrowIfProblems() const {
  const std::string message = impl_->problems.Message();
  if (!message.empty()) throw std::invalid_argument(impl_->path + ": " + message);
}

const std::string& YamlReader::path() const { return impl_->path; }

}  // namespace kinevis::common
