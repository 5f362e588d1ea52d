#include "calibration/weld_mount/mount_calibration_io.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <stdexcept>
#include <vector>

#include "calibration/common/estimation_yaml_internal.h"
#include "calibration/common/yaml_reader_internal.h"
#include "common/units.h"

namespace kinevis::calibration {
namespace {

constexpr const char* kKind = "kinevis-scanner-mount-calibration";
// 2: the estimator contract's `estimation:` block; version 1 files (without it) are read, their
// report derived from what they hold.
constexpr int kVersion = 2;
constexpr int kPoseParameters = 12;  // mount (6) + block (6)
constexpr int kDhParameters = 20;
const char* const kPoseNames[kPoseParameters] = {"mount.rx", "mount.ry", "mount.rz", "mount.x",
                                                 "mount.y",  "mount.z",  "block.rx", "block.ry",
                                                 "block.rz", "block.x",  "block.y",  "block.z"};

using internal::NowUtc;

// The file unit of a parameter of the analysis and its factor from SI: rotations and D–H angles
// in deg, positions and D–H lengths in mm.
struct Unit {
  const char* name;
  double scale;
};
Unit UnitOf(const std::string& parameter) {
  const std::string last = parameter.substr(parameter.rfind('.') + 1);
  const bool angle = last == "rx" || last == "ry" || last == "rz" || last.rfind("alpha", 0) == 0 ||
                     last.rfind("theta", 0) == 0;
  return angle ? Unit{"deg", common::kDegPerRad} : Unit{"mm", common::kMmPerM};
}

// rpy [roll, pitch, yaw] of R = Rz(yaw) Ry(pitch) Rx(roll), pitch in [−90°, 90°].
Eigen::Vector3d Rpy(const Eigen::Matrix3d& R) {
  const double pitch = std::asin(std::clamp(-R(2, 0), -1.0, 1.0));
  return {std::atan2(R(2, 1), R(2, 2)), pitch, std::atan2(R(1, 0), R(0, 0))};
}
Eigen::Matrix3d FromRpy(const Eigen::Vector3d& rpy) {
  return (Eigen::AngleAxisd(rpy.z(), Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(rpy.y(), Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(rpy.x(), Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

template <typename Vec>
void EmitList(YAML::Emitter& out, const Vec& v, int n, double scale = 1.0) {
  out << YAML::Flow << YAML::BeginSeq;
  for (int i = 0; i < n; ++i) out << scale * v[i];
  out << YAML::EndSeq;
}

void EmitStrings(YAML::Emitter& out, const char* key, const std::vector<std::string>& v) {
  out << YAML::Key << key << YAML::Value << YAML::BeginSeq;
  for (const std::string& s : v) out << s;
  out << YAML::EndSeq;
}

// position_mm, rpy_deg, quaternion_wxyz of X (inside an open map).
void EmitPoseKeys(YAML::Emitter& out, const Eigen::Isometry3d& X) {
  Eigen::Quaterniond q(X.linear());
  q.normalize();
  if (q.w() < 0.0) q.coeffs() = -q.coeffs();
  out << YAML::Key << "position_mm" << YAML::Value;
  EmitList(out, X.translation(), 3, common::kMmPerM);
  out << YAML::Key << "rpy_deg" << YAML::Value;
  EmitList(out, Rpy(X.linear()), 3, common::kDegPerRad);
  out << YAML::Key << "quaternion_wxyz" << YAML::Value << YAML::Flow << YAML::BeginSeq << q.w()
      << q.x() << q.y() << q.z() << YAML::EndSeq;
}

void EmitStats(YAML::Emitter& out, const char* key, const ResidualStats& s) {
  out << YAML::Key << key << YAML::Value << YAML::Flow << YAML::BeginMap;
  out << YAML::Key << "count" << YAML::Value << s.count;
  out << YAML::Key << "rms_mm" << YAML::Value << common::kMmPerM * s.rms;
  out << YAML::Key << "median_mm" << YAML::Value << common::kMmPerM * s.median;
  out << YAML::Key << "max_mm" << YAML::Value << common::kMmPerM * s.max;
  out << YAML::Key << "beyond_k" << YAML::Value << s.beyond_k;
  out << YAML::EndMap;
}

class Reader : public internal::CheckedYamlReader {
 public:
  explicit Reader(std::string path)
      : CheckedYamlReader("scanner mount calibration file", std::move(path)) {}

  // A list of numbers of any length (non-finite allowed when !finite).
  std::vector<double> List(const YAML::Node& node, const std::string& name, const std::string& key,
                           bool finite = true) {
    std::vector<double> out;
    const YAML::Node v = Child(node, name, key);
    if (!v) return out;
    if (!v.IsSequence()) {
      Bad(key, "not a list of numbers (" + Dump(v) + ")");
      return out;
    }
    for (size_t i = 0; i < v.size(); ++i) {
      double d = 0.0;
      if (!v[i].IsScalar() || !YAML::convert<double>::decode(v[i], d) ||
          (finite && !std::isfinite(d))) {
        Bad(key, "element " + std::to_string(i) + " is not a " + (finite ? "finite " : "") +
                     "number (" + Dump(v) + ")");
        return {};
      }
      out.push_back(d);
    }
    return out;
  }

  // A pose map {position_mm, rpy_deg, quaternion_wxyz}: the quaternion must be unit and agree
  // with rpy_deg; rpy_deg alone is accepted when `quaternion_required` is false.
  Eigen::Isometry3d Pose(const YAML::Node& node, const std::string& name, const std::string& key,
                         bool quaternion_required = true) {
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    const YAML::Node m = Child(node, name, key);
    if (!m) return X;
    const Eigen::Vector3d p = Numbers<3>(m, "position_mm", key + ".position_mm") / common::kMmPerM;
    const Eigen::Vector3d rpy = Numbers<3>(m, "rpy_deg", key + ".rpy_deg") / common::kDegPerRad;
    if (p.allFinite()) X.translation() = p;
    if (rpy.allFinite()) X.linear() = FromRpy(rpy);
    if (!quaternion_required && !m["quaternion_wxyz"]) return X;
    const Eigen::Vector4d qv = Numbers<4>(m, "quaternion_wxyz", key + ".quaternion_wxyz");
    if (!qv.allFinite()) return X;
    const Eigen::Quaterniond q(qv(0), qv(1), qv(2), qv(3));
    if (std::abs(q.norm() - 1.0) > 1e-6) {
      Bad(key + ".quaternion_wxyz",
          "not a unit quaternion (norm " + std::to_string(q.norm()) + ")");
      return X;
    }
    const Eigen::Matrix3d R = q.normalized().toRotationMatrix();
    if (rpy.allFinite()) {
      const double angle = Eigen::AngleAxisd(R.transpose() * X.linear()).angle();
      if (angle > 1e-6) {
        Bad(key + ".quaternion_wxyz",
            "disagrees with rpy_deg by " + std::to_string(angle * common::kDegPerRad) + " deg (" +
                Dump(m["quaternion_wxyz"]) + " vs " + Dump(m["rpy_deg"]) + ")");
      }
    }
    X.linear() = R;
    return X;
  }

  ResidualStats Stats(const YAML::Node& node, const std::string& name, const std::string& key) {
    ResidualStats s;
    const YAML::Node m = Child(node, name, key);
    if (!m) return s;
    s.count = Int(m, "count", key + ".count", 0);
    s.rms = NonNegative(m, "rms_mm", key + ".rms_mm") / common::kMmPerM;
    s.median = NonNegative(m, "median_mm", key + ".median_mm") / common::kMmPerM;
    s.max = NonNegative(m, "max_mm", key + ".max_mm") / common::kMmPerM;
    s.beyond_k = Int(m, "beyond_k", key + ".beyond_k", 0);
    return s;
  }

  double NonNegative(const YAML::Node& node, const std::string& name, const std::string& key) {
    const double v = Double(node, name, key);
    if (v < 0.0) Bad(key, "must be >= 0 (" + std::to_string(v) + ")");
    return v;
  }
};

void CheckSummary(const MountCalibrationSummary& s) {
  const size_t n = s.parameter_names.size();
  std::string bad;
  const auto add = [&](const std::string& what) { bad += (bad.empty() ? "" : "; ") + what; };
  if (n != kPoseParameters && n != kPoseParameters + kDhParameters) {
    add(std::to_string(n) + " parameter_names (expected 12 or 32)");
  } else {
    const std::vector<std::string> dh = DhErrorNames();
    for (size_t i = 0; i < n; ++i) {
      const std::string want = i < kPoseParameters ? kPoseNames[i] : dh[i - kPoseParameters];
      if (s.parameter_names[i] != want) {
        add("parameter_names[" + std::to_string(i) + "] is " + s.parameter_names[i] +
            " (expected " + want + ")");
      }
    }
  }
  if (static_cast<size_t>(s.correction.size()) != n) add("correction size");
  if (static_cast<size_t>(s.std_dev.size()) != n) add("std_dev size");
  if (s.estimated.size() != n) add("estimated size");
  if (s.identified.size() != n) add("identified size");
  if (!bad.empty()) throw std::invalid_argument("WriteScannerMountCalibration: summary: " + bad);
}

bool ParseStatus(const std::string& text, MountCalibrationStatus* status) {
  for (const MountCalibrationStatus s :
       {MountCalibrationStatus::kOk, MountCalibrationStatus::kUnidentified,
        MountCalibrationStatus::kNotConverged}) {
    if (text == ToString(s)) {
      *status = s;
      return true;
    }
  }
  return false;
}

}  // namespace

void WriteScannerMountCalibration(const std::string& path, const MountCalibrationSummary& s,
                                  const ScannerMountCalibrationMetadata& metadata) {
  CheckSummary(s);
  const int n = static_cast<int>(s.parameter_names.size());
  const bool dh = n > kPoseParameters;
  YAML::Emitter out;
  out.SetDoublePrecision(17);
  out << YAML::BeginMap;
  out << YAML::Key << "kind" << YAML::Value << kKind;
  out << YAML::Key << "version" << YAML::Value << kVersion;
  out << YAML::Key << "created" << YAML::Value
      << (metadata.created.empty() ? NowUtc() : metadata.created);
  out << YAML::Key << "source" << YAML::Value << metadata.source;
  out << YAML::Key << "robot" << YAML::Value << metadata.robot;
  out << YAML::Key << "scanner" << YAML::Value << metadata.scanner;
  out << YAML::Key << "status" << YAML::Value << ToString(s.status);
  out << YAML::Key << "converged" << YAML::Value << s.converged;
  out << YAML::Key << "iterations" << YAML::Value << s.iterations;
  out << YAML::Key << "initial_cost" << YAML::Value << s.initial_cost;
  out << YAML::Key << "final_cost" << YAML::Value << s.final_cost;
  out << YAML::Key << "sigma_ratio" << YAML::Value << s.sigma_ratio;

  // The mount: what `kinevis scan` reads.
  out << YAML::Key << "mount" << YAML::Value << YAML::BeginMap;
  EmitPoseKeys(out, s.X_5C);
  const Eigen::Matrix<double, 6, 6>& C = s.mount_covariance;
  Eigen::Vector3d rotation_sigma, position_sigma;
  for (int i = 0; i < 3; ++i) {
    rotation_sigma(i) = std::sqrt(C(i, i));
    position_sigma(i) = std::sqrt(C(3 + i, 3 + i));
  }
  out << YAML::Key << "position_sigma_mm" << YAML::Value;
  EmitList(out, position_sigma, 3, common::kMmPerM);
  out << YAML::Key << "rotation_sigma_deg" << YAML::Value;
  EmitList(out, rotation_sigma, 3, common::kDegPerRad);
  out << YAML::Key << "position_std_mm" << YAML::Value << common::kMmPerM * s.mount_position_std;
  out << YAML::Key << "angle_std_deg" << YAML::Value << common::kDegPerRad * s.mount_angle_std;
  out << YAML::Key << "covariance_rad_m" << YAML::Value << YAML::BeginSeq;
  for (int r = 0; r < 6; ++r) EmitList(out, C.row(r), 6);
  out << YAML::EndSeq;
  out << YAML::Key << "cad" << YAML::Value << YAML::BeginMap;
  EmitPoseKeys(out, metadata.X_5C_guess);
  out << YAML::EndMap;
  const Eigen::Vector3d dp = s.X_5C.translation() - metadata.X_5C_guess.translation();
  const Eigen::AngleAxisd dR(metadata.X_5C_guess.linear().transpose() * s.X_5C.linear());
  out << YAML::Key << "correction" << YAML::Value << YAML::Flow << YAML::BeginMap;
  out << YAML::Key << "position_mm" << YAML::Value;
  EmitList(out, dp, 3, common::kMmPerM);
  out << YAML::Key << "rotation_vector_deg" << YAML::Value;
  EmitList(out, Eigen::Vector3d(dR.angle() * dR.axis()), 3, common::kDegPerRad);
  out << YAML::Key << "distance_mm" << YAML::Value << common::kMmPerM * dp.norm();
  out << YAML::Key << "angle_deg" << YAML::Value << common::kDegPerRad * dR.angle();
  out << YAML::EndMap;
  out << YAML::EndMap;

  out << YAML::Key << "block" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "size_mm" << YAML::Value;
  EmitList(out, metadata.block.size, 3, common::kMmPerM);
  EmitPoseKeys(out, s.X_0B);
  out << YAML::Key << "guess" << YAML::Value << YAML::BeginMap;
  EmitPoseKeys(out, metadata.X_0B_guess);
  out << YAML::EndMap;
  out << YAML::EndMap;

  const auto emit_parameter = [&](int i) {
    const std::string& name = s.parameter_names[static_cast<size_t>(i)];
    const Unit u = UnitOf(name);
    out << YAML::Flow << YAML::BeginMap;
    out << YAML::Key << "name" << YAML::Value << name;
    out << YAML::Key << "unit" << YAML::Value << u.name;
    out << YAML::Key << (i < kPoseParameters ? "correction" : "error") << YAML::Value
        << u.scale * s.correction(i);
    out << YAML::Key << "sigma" << YAML::Value << u.scale * s.std_dev(i);
    out << YAML::Key << "estimated" << YAML::Value << s.estimated[static_cast<size_t>(i)];
    out << YAML::Key << "identified" << YAML::Value << s.identified[static_cast<size_t>(i)];
    out << YAML::EndMap;
  };
  out << YAML::Key << "dh" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "estimated" << YAML::Value << dh;
  EmitStrings(out, "fixed", s.fixed_dh);
  out << YAML::Key << "errors" << YAML::Value << YAML::BeginSeq;
  for (int i = kPoseParameters; i < n; ++i) emit_parameter(i);
  out << YAML::EndSeq;
  out << YAML::EndMap;

  out << YAML::Key << "identifiability" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "rank" << YAML::Value << s.rank;
  out << YAML::Key << "condition_number" << YAML::Value << s.condition_number;
  out << YAML::Key << "singular_values" << YAML::Value;
  EmitList(out, s.singular_values, static_cast<int>(s.singular_values.size()));
  EmitStrings(out, "unidentified", s.unidentified);
  out << YAML::Key << "parameters" << YAML::Value << YAML::BeginSeq;
  for (int i = 0; i < kPoseParameters; ++i) emit_parameter(i);
  out << YAML::EndSeq;
  out << YAML::EndMap;

  out << YAML::Key << "residuals" << YAML::Value << YAML::BeginMap;
  EmitStats(out, "touch", s.touch);
  EmitStats(out, "scan", s.scan);
  out << YAML::EndMap;
  EmitStrings(out, "warnings", s.warnings);
  internal::EmitEstimation(out, s.estimation);
  out << YAML::EndMap;

  std::ofstream file(path);
  if (!file) throw std::runtime_error("cannot write scanner mount calibration file " + path);
  file << "# kinevis scanner mount calibration (seed 004 section 4): X_5C, the scanner camera C\n"
       << "# on link 5; format: docs/scanner-mount-calibration.md\n"
       << out.c_str() << "\n";
  if (!file) throw std::runtime_error("cannot write scanner mount calibration file " + path);
}

ScannerMountCalibrationFile ReadScannerMountCalibration(const std::string& path) {
  {
    std::ifstream probe(path);
    if (!probe) throw std::runtime_error("cannot read scanner mount calibration file " + path);
  }
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument("scanner mount calibration file " + path + ": not YAML (" +
                                e.what() + ")");
  }
  Reader in(path);
  if (!root.IsMap()) {
    in.Bad("(top level)", "not a mapping");
    in.ThrowIfBad();
  }
  ScannerMountCalibrationFile f;
  MountCalibrationSummary& s = f.summary;
  ScannerMountCalibrationMetadata& m = f.metadata;

  const std::string kind = in.String(root, "kind", "kind");
  if (root["kind"] && kind != kKind)
    in.Bad("kind", "must be " + std::string(kKind) + " (" + kind + ")");
  const int version = in.Int(root, "version", "version", 1);
  if (root["version"] && (version < 1 || version > kVersion)) {
    in.Bad("version", "unsupported (" + std::to_string(version) + ", this reader knows 1 and 2)");
  }
  m.created = in.String(root, "created", "created");
  m.source = in.String(root, "source", "source");
  m.robot = in.String(root, "robot", "robot");
  m.scanner = in.String(root, "scanner", "scanner");
  const std::string status = in.String(root, "status", "status");
  if (root["status"] && !ParseStatus(status, &s.status)) {
    in.Bad("status", "unknown '" + status + "' (ok, unidentified, not-converged)");
  }
  s.converged = in.Bool(root, "converged", "converged");
  s.iterations = in.Int(root, "iterations", "iterations", 0);
  s.initial_cost = in.NonNegative(root, "initial_cost", "initial_cost");
  s.final_cost = in.NonNegative(root, "final_cost", "final_cost");
  s.sigma_ratio = in.NonNegative(root, "sigma_ratio", "sigma_ratio");

  const YAML::Node mount = in.Child(root, "mount", "mount");
  if (mount) {
    s.X_5C = in.Pose(root, "mount", "mount");
    in.Numbers<3>(mount, "position_sigma_mm", "mount.position_sigma_mm", false);
    in.Numbers<3>(mount, "rotation_sigma_deg", "mount.rotation_sigma_deg", false);
    s.mount_position_std =
        in.Double(mount, "position_std_mm", "mount.position_std_mm", false) / common::kMmPerM;
    s.mount_angle_std =
        in.Double(mount, "angle_std_deg", "mount.angle_std_deg", false) / common::kDegPerRad;
    const YAML::Node cov = in.Child(mount, "covariance_rad_m", "mount.covariance_rad_m");
    if (cov && (!cov.IsSequence() || cov.size() != 6)) {
      in.Bad("mount.covariance_rad_m", "must be 6 rows of 6 numbers (" + Reader::Dump(cov) + ")");
    }
    if (cov && cov.IsSequence() && cov.size() == 6) {
      bool ok = true;
      for (int r = 0; r < 6 && ok; ++r) {
        const YAML::Node row = cov[r];
        if (!row.IsSequence() || row.size() != 6) {
          in.Bad("mount.covariance_rad_m[" + std::to_string(r) + "]",
                 "must be a list of 6 numbers (" + Reader::Dump(row) + ")");
          ok = false;
          break;
        }
        for (int c = 0; c < 6; ++c) {
          double d = 0.0;
          if (!row[c].IsScalar() || !YAML::convert<double>::decode(row[c], d) || std::isnan(d)) {
            in.Bad("mount.covariance_rad_m[" + std::to_string(r) + "]",
                   "element " + std::to_string(c) + " is not a number (" + Reader::Dump(row) + ")");
            ok = false;
            break;
          }
          s.mount_covariance(r, c) = d;
        }
      }
      if (ok) {
        const Eigen::Matrix<double, 6, 6>& C = s.mount_covariance;
        for (int r = 0; r < 6; ++r) {
          for (int c = r + 1; c < 6; ++c) {
            const double a = C(r, c), b = C(c, r);
            if (std::isfinite(a) && std::isfinite(b) &&
                std::abs(a - b) > 1e-9 * (std::abs(a) + std::abs(b)) + 1e-300) {
              in.Bad("mount.covariance_rad_m",
                     "not symmetric at (" + std::to_string(r) + ", " + std::to_string(c) + ")");
              r = 6;
              break;
            }
          }
          if (r < 6 && !(C(r, r) >= 0.0)) {
            in.Bad("mount.covariance_rad_m", "diagonal " + std::to_string(r) + " is negative (" +
                                                 std::to_string(C(r, r)) + ")");
          }
        }
      }
    }
    m.X_5C_guess = in.Pose(mount, "cad", "mount.cad");
    const YAML::Node corr = in.Child(mount, "correction", "mount.correction");
    if (corr) {
      in.Numbers<3>(corr, "position_mm", "mount.correction.position_mm");
      in.Numbers<3>(corr, "rotation_vector_deg", "mount.correction.rotation_vector_deg");
      in.NonNegative(corr, "distance_mm", "mount.correction.distance_mm");
      in.NonNegative(corr, "angle_deg", "mount.correction.angle_deg");
    }
  }

  const YAML::Node block = in.Child(root, "block", "block");
  if (block) {
    m.block.size = in.Numbers<3>(block, "size_mm", "block.size_mm") / common::kMmPerM;
    if (m.block.size.allFinite() && !m.block.Validate().empty()) {
      in.Bad("block.size_mm", "each size must be > 0 (" + Reader::Dump(block["size_mm"]) + ")");
    }
    s.X_0B = in.Pose(root, "block", "block");
    m.X_0B_guess = in.Pose(block, "guess", "block.guess");
  }

  // The parameters: the 12 of mount and block (identifiability.parameters), then the 20 D–H
  // errors when they were estimated (dh.errors).
  std::vector<std::string> names;
  std::vector<double> correction, sigma;
  const auto read_parameters = [&](const YAML::Node& list, const std::string& key,
                                   const std::vector<std::string>& expected, const char* value) {
    if (!list) return;
    if (!list.IsSequence()) {
      in.Bad(key, "not a list (" + Reader::Dump(list) + ")");
      return;
    }
    if (list.size() != expected.size()) {
      in.Bad(key, std::to_string(list.size()) + " entries (expected " +
                      std::to_string(expected.size()) + ")");
      return;
    }
    for (size_t i = 0; i < list.size(); ++i) {
      const std::string k = key + "[" + std::to_string(i) + "]";
      const YAML::Node e = list[i];
      const std::string name = in.String(e, "name", k + ".name");
      if (e["name"] && name != expected[i]) {
        in.Bad(k + ".name", "'" + name + "' (expected " + expected[i] + ")");
      }
      const Unit u = UnitOf(expected[i]);
      const std::string unit = in.String(e, "unit", k + ".unit");
      if (e["unit"] && unit != u.name) {
        in.Bad(k + ".unit", "'" + unit + "' (expected " + u.name + ")");
      }
      names.push_back(expected[i]);
      correction.push_back(in.Double(e, value, k + "." + value) / u.scale);
      const double sd = in.Double(e, "sigma", k + ".sigma", false);
      if (!(sd >= 0.0)) in.Bad(k + ".sigma", "must be >= 0 or .inf (" + std::to_string(sd) + ")");
      sigma.push_back(sd / u.scale);
      s.estimated.push_back(in.Bool(e, "estimated", k + ".estimated"));
      s.identified.push_back(in.Bool(e, "identified", k + ".identified"));
    }
  };
  const YAML::Node ident = in.Child(root, "identifiability", "identifiability");
  if (ident) {
    s.rank = in.Int(ident, "rank", "identifiability.rank", 0);
    s.condition_number =
        in.Double(ident, "condition_number", "identifiability.condition_number", false);
    const std::vector<double> sv =
        in.List(ident, "singular_values", "identifiability.singular_values");
    s.singular_values = Eigen::Map<const Eigen::VectorXd>(sv.data(), static_cast<long>(sv.size()));
    for (size_t i = 1; i < sv.size(); ++i) {
      if (sv[i] > sv[i - 1]) {
        in.Bad("identifiability.singular_values", "not in descending order");
        break;
      }
    }
    if (ident["rank"] && s.rank > static_cast<int>(sv.size()) && !sv.empty()) {
      in.Bad("identifiability.rank", std::to_string(s.rank) + " exceeds the " +
                                         std::to_string(sv.size()) + " singular values");
    }
    s.unidentified = in.Strings(ident, "unidentified", "identifiability.unidentified");
    read_parameters(
        in.Child(ident, "parameters", "identifiability.parameters"), "identifiability.parameters",
        std::vector<std::string>(kPoseNames, kPoseNames + kPoseParameters), "correction");
  }
  f.dh_errors = Eigen::VectorXd::Zero(kDhParameters);
  const YAML::Node dh = in.Child(root, "dh", "dh");
  if (dh) {
    f.dh_estimated = in.Bool(dh, "estimated", "dh.estimated");
    s.fixed_dh = in.Strings(dh, "fixed", "dh.fixed");
    const std::vector<std::string> dh_names = DhErrorNames();
    for (const std::string& fixed : s.fixed_dh) {
      if (std::find(dh_names.begin(), dh_names.end(), fixed) == dh_names.end()) {
        in.Bad("dh.fixed", "unknown D-H parameter '" + fixed + "'");
      }
    }
    const YAML::Node errors = in.Child(dh, "errors", "dh.errors");
    if (errors && errors.IsSequence() && errors.size() == 0) {
      if (f.dh_estimated) in.Bad("dh.errors", "empty although dh.estimated is true");
    } else if (errors) {
      if (!f.dh_estimated && dh["estimated"]) {
        in.Bad("dh.errors", "present although dh.estimated is false");
      }
      const size_t before = names.size();
      read_parameters(errors, "dh.errors", dh_names, "error");
      for (size_t i = before; i < correction.size(); ++i) {
        f.dh_errors(static_cast<long>(i - before)) = correction[i];
      }
    }
  }
  s.parameter_names = names;
  s.correction =
      Eigen::Map<const Eigen::VectorXd>(correction.data(), static_cast<long>(correction.size()));
  s.std_dev = Eigen::Map<const Eigen::VectorXd>(sigma.data(), static_cast<long>(sigma.size()));

  const YAML::Node residuals = in.Child(root, "residuals", "residuals");
  if (residuals) {
    s.touch = in.Stats(residuals, "touch", "residuals.touch");
    s.scan = in.Stats(residuals, "scan", "residuals.scan");
  }
  s.warnings = in.Strings(root, "warnings", "warnings");
  if (root["status"] && root["converged"] && s.status == MountCalibrationStatus::kOk &&
      !s.converged) {
    in.Bad("status", "ok although converged is false");
  }
  if (version >= 2) s.estimation = internal::ReadEstimation(in, root);
  in.ThrowIfBad();
  if (version < 2) s.estimation = MountEstimationReport(s);
  return f;
}

Eigen::Isometry3d ReadScannerMount(const std::string& path) {
  const ScannerMountCalibrationFile f = ReadScannerMountCalibration(path);
  if (!f.summary.ok()) {
    std::string why = "status is '" + std::string(ToString(f.summary.status)) + "'";
    if (!f.summary.unidentified.empty()) why += "; unidentified: " + f.summary.unidentified[0];
    throw std::invalid_argument("scanner mount calibration file " + path + ": " + why +
                                ": the mount is not usable for scans (recalibrate)");
  }
  return f.summary.X_5C;
}

robots::Weld5Model CalibratedRobot(const ScannerMountCalibrationFile& file,
                                   const robots::Weld5Model& nominal) {
  if (!file.dh_estimated) return nominal;
  return ApplyDhErrors(nominal, file.dh_errors);
}

}  // namespace kinevis::calibration
