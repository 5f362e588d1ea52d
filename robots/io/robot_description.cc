#include "robots/io/robot_description.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <sstream>
#include <stdexcept>
#include <vector>

#include "common/units.h"

namespace kinevis::robots {
namespace {

std::string Text(double v) {
  std::ostringstream s;
  s.precision(10);
  s << v;
  return s.str();
}

// Reads one file, collects every problem, throws them together.
class Reader {
 public:
  explicit Reader(const std::string& path) : path_(path) {
    try {
      root_ = YAML::LoadFile(path);
    } catch (const YAML::BadFile&) {
      throw std::invalid_argument(path + ": cannot open the robot description file");
    } catch (const YAML::Exception& e) {
      throw std::invalid_argument(path + ": not valid YAML: " + e.what());
    }
    if (!root_.IsMap()) throw std::invalid_argument(path + ": expected a YAML mapping at the top");
  }

  const YAML::Node& root() const { return root_; }
  void Problem(const std::string& message) { problems_.push_back(message); }

  void ThrowIfAny() const {
    if (problems_.empty()) return;
    std::string message = path_ + ": ";
    for (size_t i = 0; i < problems_.size(); ++i) message += (i ? "; " : "") + problems_[i];
    throw std::invalid_argument(message);
  }

  std::string String(const YAML::Node& map, const std::string& key, const std::string& where,
                     bool required) {
    const YAML::Node n = map[key];
    if (!n) {
      if (required) Problem(where + key + ": missing");
      return {};
    }
    if (!n.IsScalar()) {
      Problem(where + key + ": expected a string");
      return {};
    }
    return n.as<std::string>();
  }

  // A finite number at map[key]; NaN (and a problem) when missing or not a number.
  double Number(const YAML::Node& map, const std::string& key, const std::string& where) {
    const YAML::Node n = map[key];
    if (!n) {
      Problem(where + key + ": missing");
      return std::nan("");
    }
    return Scalar(n, where + key);
  }

  double Scalar(const YAML::Node& n, const std::string& name) {
    double v = std::nan("");
    if (!n.IsScalar() || !YAML::convert<double>::decode(n, v) || !std::isfinite(v)) {
      Problem(name + ": expected a finite number, got " +
              (n.IsScalar() ? "'" + n.Scalar() + "'" : std::string("a ") + TypeName(n)));
      return std::nan("");
    }
    return v;
  }

  // A quantity that may be given in SI under `key` or scaled under `key + suffix` (e.g. "_mm"),
  // but not both. Returns SI; NaN and a problem when neither or both are present.
  double Quantity(const YAML::Node& map, const std::string& key, const std::string& suffix,
                  double scale, const std::string& where) {
    const bool si = static_cast<bool>(map[key]);
    const bool scaled = static_cast<bool>(map[key + suffix]);
    if (si && scaled) {
      Problem(where + key + " and " + key + suffix + ": give one, not both");
      return std::nan("");
    }
    if (!si && !scaled) {
      Problem(where + key + " (or " + key + suffix + "): missing");
      return std::nan("");
    }
    return si ? Scalar(map[key], where + key)
              : scale * Scalar(map[key + suffix], where + key + suffix);
  }
  double Length(const YAML::Node& map, const std::string& key, const std::string& where) {
    return Quantity(map, key, "_mm", 1e-3, where);
  }
  double Angle(const YAML::Node& map, const std::string& key, const std::string& where) {
    return Quantity(map, key, "_deg", common::kDeg, where);
  }

  // A sequence of exactly `n` numbers.
  std::vector<double> Numbers(const YAML::Node& node, size_t n, const std::string& name) {
    if (!node || !node.IsSequence() || node.size() != n) {
      Problem(name + ": need a list of " + std::to_string(n) + " numbers" +
              (node && node.IsSequence() ? ", got " + std::to_string(node.size()) : ""));
      return std::vector<double>(n, std::nan(""));
    }
    std::vector<double> out;
    for (size_t i = 0; i < n; ++i)
      out.push_back(Scalar(node[i], name + "[" + std::to_string(i) + "]"));
    return out;
  }

  static const char* TypeName(const YAML::Node& n) {
    switch (n.Type()) {
      case YAML::NodeType::Sequence:
        return "list";
      case YAML::NodeType::Map:
        return "mapping";
      case YAML::NodeType::Null:
        return "null";
      default:
        return "scalar";
    }
  }

  void ExpectKind(const std::string& kind) {
    const std::string got = String(root_, "robot", "", true);
    if (!got.empty() && got != kind) {
      // A file for another robot: its other keys would only bury this in noise.
      throw std::invalid_argument(path_ + ": robot: expected '" + kind + "', got '" + got + "'");
    }
  }

 private:
  std::string path_;
  YAML::Node root_;
  std::vector<std::string> problems_;
};

// Six points, either `key: [[x, y, z] x6]` (m) or `key_polar: {radius, angles_deg, z}` (m, deg).
std::array<Eigen::Vector3d, kHexapodLegs> ReadSixPoints(Reader& r, const std::string& key) {
  std::array<Eigen::Vector3d, kHexapodLegs> points{};
  const YAML::Node& root = r.root();
  const YAML::Node list = root[key];
  const YAML::Node polar = root[key + "_polar"];
  if (list && polar) {
    r.Problem(key + " and " + key + "_polar: give one, not both");
    return points;
  }
  if (list) {
    if (!list.IsSequence() || list.size() != kHexapodLegs) {
      r.Problem(key + ": need a list of 6 points [x, y, z] (m)");
      return points;
    }
    for (int j = 0; j < kHexapodLegs; ++j) {
      const auto v = r.Numbers(list[j], 3, key + "[" + std::to_string(j) + "]");
      points[j] = Eigen::Vector3d(v[0], v[1], v[2]);
    }
    return points;
  }
  if (polar) {
    if (!polar.IsMap()) {
      r.Problem(key + "_polar: expected a mapping {radius, angles_deg, z}");
      return points;
    }
    const double radius = r.Length(polar, "radius", key + "_polar.");
    const double z = polar["z"] || polar["z_mm"] ? r.Length(polar, "z", key + "_polar.") : 0.0;
    const auto angles = r.Numbers(polar["angles_deg"], kHexapodLegs, key + "_polar.angles_deg");
    if (!(radius > 0)) r.Problem(key + "_polar.radius: must be > 0, got " + Text(radius));
    for (int j = 0; j < kHexapodLegs; ++j) {
      const double a = angles[j] * common::kDeg;
      points[j] = Eigen::Vector3d(radius * std::cos(a), radius * std::sin(a), z);
    }
    return points;
  }
  r.Problem(key + " (or " + key + "_polar): missing");
  return points;
}

// A pose as {position: [x, y, z] (m), rpy_deg: [roll, pitch, yaw]} (R = Rz(yaw) Ry(pitch)
// Rx(roll)).
Eigen::Isometry3d ReadPose(Reader& r, const YAML::Node& node, const std::string& name) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  if (!node.IsMap()) {
    r.Problem(name + ": expected {position: [x, y, z], rpy_deg: [r, p, y]}");
    return X;
  }
  const auto p = r.Numbers(node["position"], 3, name + ".position");
  std::vector<double> rpy{0.0, 0.0, 0.0};
  if (node["rpy_deg"]) rpy = r.Numbers(node["rpy_deg"], 3, name + ".rpy_deg");
  X.translation() = Eigen::Vector3d(p[0], p[1], p[2]);
  X.linear() = (Eigen::AngleAxisd(rpy[2] * common::kDeg, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(rpy[1] * common::kDeg, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(rpy[0] * common::kDeg, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  return X;
}

}  // namespace

std::string ReadRobotKind(const std::string& path) {
  Reader r(path);
  const std::string kind = r.String(r.root(), "robot", "", true);
  if (!kind.empty() && kind != "hexapod" && kind != "weld5" && kind != "diamond") {
    r.Problem("robot: unknown kind '" + kind + "' (hexapod, weld5, diamond)");
  }
  r.ThrowIfAny();
  return kind;
}

HexapodDescription LoadHexapodDescription(const std::string& path) {
  Reader r(path);
  r.ExpectKind("hexapod");
  HexapodDescription d;
  d.name = r.String(r.root(), "name", "", false);
  d.model.p_B_A = ReadSixPoints(r, "base_points");
  d.model.p_P_B = ReadSixPoints(r, "platform_points");
  d.model.leg_radius = r.Length(r.root(), "leg_radius", "");
  const YAML::Node stroke = r.root()["leg_length"];
  if (stroke && stroke.IsMap()) {
    d.model.leg_length_min = r.Length(stroke, "min", "leg_length.");
    d.model.leg_length_max = r.Length(stroke, "max", "leg_length.");
  } else {
    r.Problem("leg_length: expected {min, max} (m)");
  }
  const YAML::Node q0 = r.root()["joint_offsets"];
  if (q0 && q0.IsScalar()) {
    d.model.q0.fill(r.Scalar(q0, "joint_offsets"));
  } else {
    const auto v = r.Numbers(q0, kHexapodLegs, "joint_offsets");
    for (int j = 0; j < kHexapodLegs; ++j) d.model.q0[j] = v[j];
  }
  if (r.root()["home_pose"]) d.X_BP_home = ReadPose(r, r.root()["home_pose"], "home_pose");
  r.ThrowIfAny();
  if (const std::string bad = d.model.Validate(); !bad.empty()) r.Problem(bad);
  r.ThrowIfAny();
  return d;
}

Weld5Description LoadWeld5Description(const std::string& path) {
  Reader r(path);
  r.ExpectKind("weld5");
  Weld5Description d;
  d.name = r.String(r.root(), "name", "", false);
  const YAML::Node joints = r.root()["joints"];
  if (!joints || !joints.IsSequence() || joints.size() != kWeld5Joints) {
    r.Problem("joints: need a list of 5 joints (θ1, θ2, pz3, θ4, θ5)");
    r.ThrowIfAny();
  }
  for (int i = 0; i < kWeld5Joints; ++i) {
    const YAML::Node j = joints[i];
    const std::string where = "joints[" + std::to_string(i) + "].";
    if (!j.IsMap()) {
      r.Problem("joints[" + std::to_string(i) + "]: expected a mapping");
      continue;
    }
    const std::string type = r.String(j, "type", where, true);
    const bool prismatic = type == "prismatic";
    if (!type.empty() && type != "prismatic" && type != "revolute") {
      r.Problem(where + "type: expected revolute or prismatic, got '" + type + "'");
    }
    DhJoint& dh = d.model.joints[i];
    dh.prismatic = prismatic;
    dh.a = r.Length(j, "a", where);
    dh.alpha = r.Angle(j, "alpha", where);
    dh.d = r.Length(j, "d", where);
    dh.theta_offset = r.Angle(j, "theta_offset", where);
    // Limits and speeds in the joint's own unit: m or rad, or mm and deg with the suffix.
    const YAML::Node limits = j["limits"];
    if (!limits || !limits.IsMap()) {
      r.Problem(where + "limits: expected {min, max, speed}");
      continue;
    }
    const std::string w = where + "limits.";
    if (prismatic) {
      d.model.q_min(i) = r.Length(limits, "min", w);
      d.model.q_max(i) = r.Length(limits, "max", w);
      d.model.qd_max(i) = r.Quantity(limits, "speed", "_mm_s", 1e-3, w);
    } else {
      d.model.q_min(i) = r.Angle(limits, "min", w);
      d.model.q_max(i) = r.Angle(limits, "max", w);
      d.model.qd_max(i) = r.Quantity(limits, "speed", "_deg_s", common::kDeg, w);
    }
    if (!(d.model.q_min(i) < d.model.q_max(i))) {
      r.Problem(w + "min < max does not hold (" + Text(d.model.q_min(i)) + " .. " +
                Text(d.model.q_max(i)) + ")");
    }
    if (!(d.model.qd_max(i) > 0))
      r.Problem(w + "speed: must be > 0, got " + Text(d.model.qd_max(i)));
  }
  const YAML::Node torch = r.root()["torch"];
  if (torch && torch.IsMap()) {
    d.model.X_5T =
        Weld5TorchTransform(r.Length(torch, "px5", "torch."), r.Length(torch, "pz5", "torch."),
                            r.Angle(torch, "beta", "torch."));
  } else {
    r.Problem("torch: expected {px5, pz5, beta} (tip and tilt in link frame 5)");
  }
  r.ThrowIfAny();
  // What the keys' own checks cannot see (an infinite length given as .inf).
  const std::string invalid = d.model.Validate();
  if (!invalid.empty()) r.Problem(invalid);
  r.ThrowIfAny();
  return d;
}

DiamondDescription LoadDiamondDescription(const std::string& path) {
  Reader r(path);
  r.ExpectKind("diamond");
  DiamondDescription d;
  const YAML::Node& root = r.root();
  d.name = r.String(root, "name", "", false);
  DiamondModel& m = d.model;
  m.radius = r.Length(root, "radius", "");
  m.alpha = r.Angle(root, "alpha", "");
  m.beta = r.Angle(root, "beta", "");
  // Pairs of angles: `key: [a, b]` (rad) or `key_deg: [a, b]`.
  const auto pair = [&r, &root](const std::string& key, std::array<double, kDiamondJoints>* out) {
    const bool si = static_cast<bool>(root[key]);
    const bool deg = static_cast<bool>(root[key + "_deg"]);
    if (si == deg) {
      r.Problem(key + (si ? " and " + key + "_deg: give one, not both"
                          : " (or " + key + "_deg): missing"));
      return;
    }
    const auto v =
        r.Numbers(root[si ? key : key + "_deg"], kDiamondJoints, si ? key : key + "_deg");
    for (int i = 0; i < kDiamondJoints; ++i) (*out)[i] = si ? v[i] : v[i] * common::kDeg;
  };
  pair("joint_offsets", &m.joint_offsets);
  pair("theta_min", &m.theta_min);
  pair("theta_max", &m.theta_max);
  m.separation_min = r.Angle(root, "separation_min", "");
  m.separation_max = r.Angle(root, "separation_max", "");
  m.phi_min = r.Angle(root, "phi_min", "");
  m.phi_max = r.Angle(root, "phi_max", "");
  m.gamma_min = r.Angle(root, "gamma_min", "");
  m.gamma_max = r.Angle(root, "gamma_max", "");
  r.ThrowIfAny();
  if (const std::string bad = m.Validate(); !bad.empty()) r.Problem(bad);
  r.ThrowIfAny();
  return d;
}

}  // namespace kinevis::robots
