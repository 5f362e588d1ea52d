#include "vision/cloud/cloud_sidecar.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <stdexcept>

#include "common/units.h"
#include "vision/cloud/ply.h"

namespace kinevis::vision::cloud {
namespace {

constexpr const char* kKind = "kinevis-point-cloud";
constexpr int kVersion = 1;

std::string NowUtc() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char buffer[32];
  std::strftime(buffer, sizeof(buffer), "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buffer;
}

void EmitVector(YAML::Emitter& out, const Eigen::Vector3d& v) {
  out << YAML::Flow << YAML::BeginSeq << v.x() << v.y() << v.z() << YAML::EndSeq;
}

void EmitPose(YAML::Emitter& out, const Eigen::Isometry3d& X) {
  // R = Rz(yaw) Ry(pitch) Rx(roll): eulerAngles(2, 1, 0) returns (yaw, pitch, roll).
  const Eigen::Vector3d ypr = X.linear().eulerAngles(2, 1, 0);
  out << YAML::BeginMap;
  out << YAML::Key << "position_mm" << YAML::Value;
  EmitVector(out, X.translation() * common::kMmPerM);
  out << YAML::Key << "rpy_deg" << YAML::Value;
  EmitVector(out, Eigen::Vector3d(ypr.z(), ypr.y(), ypr.x()) * common::kDegPerRad);
  out << YAML::EndMap;
}

class Reader {
 public:
  explicit Reader(std::string path) : path_(std::move(path)) {}
  [[noreturn]] void Fail(const std::string& key, const std::string& what) const {
    throw std::invalid_argument("point cloud sidecar " + path_ + ": " + key + ": " + what);
  }
  YAML::Node Child(const YAML::Node& node, const std::string& key, const std::string& name) const {
    const YAML::Node child = node[name];
    if (!child) Fail(key.empty() ? name : key + "." + name, "missing");
    return child;
  }
  template <typename T>
  T Get(const YAML::Node& node, const std::string& key, const std::string& name) const {
    const YAML::Node child = Child(node, key, name);
    try {
      return child.as<T>();
    } catch (const YAML::Exception&) {
      Fail(key.empty() ? name : key + "." + name, "has the wrong type ('" + Dump(child) + "')");
    }
  }
  double Number(const YAML::Node& node, const std::string& key, const std::string& name) const {
    const double v = Get<double>(node, key, name);
    if (!std::isfinite(v)) Fail(key + "." + name, "is not finite");
    return v;
  }
  Eigen::Vector3d Vector(const YAML::Node& node, const std::string& key,
                         const std::string& name) const {
    const YAML::Node child = Child(node, key, name);
    const std::string full = key + "." + name;
    if (!child.IsSequence() || child.size() != 3) Fail(full, "expected a list of 3 numbers");
    Eigen::Vector3d v;
    for (int k = 0; k < 3; ++k) {
      try {
        v[k] = child[static_cast<std::size_t>(k)].as<double>();
      } catch (const YAML::Exception&) {
        Fail(full, "entry " + std::to_string(k) + " is not a number");
      }
      if (!std::isfinite(v[k])) Fail(full, "entry " + std::to_string(k) + " is not finite");
    }
    return v;
  }
  Eigen::Isometry3d Pose(const YAML::Node& node, const std::string& key,
                         const std::string& name) const {
    const YAML::Node child = Child(node, key, name);
    const std::string full = key + "." + name;
    const Eigen::Vector3d p = Vector(child, full, "position_mm") / common::kMmPerM;
    const Eigen::Vector3d rpy = Vector(child, full, "rpy_deg") / common::kDegPerRad;
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = (Eigen::AngleAxisd(rpy.z(), Eigen::Vector3d::UnitZ()) *
                  Eigen::AngleAxisd(rpy.y(), Eigen::Vector3d::UnitY()) *
                  Eigen::AngleAxisd(rpy.x(), Eigen::Vector3d::UnitX()))
                     .toRotationMatrix();
    X.translation() = p;
    return X;
  }
  static std::string Dump(const YAML::Node& node) {
    YAML::Emitter e;
    e << YAML::Flow << node;
    return e.c_str();
  }

 private:
  std::string path_;
};

}  // namespace

void WriteCloudSidecar(const std::string& path, const CloudSidecar& s) {
  if (s.ply.empty()) throw std::invalid_argument("point cloud sidecar " + path + ": ply is empty");
  if (!s.X_5T.matrix().allFinite() || !s.X_5C.matrix().allFinite()) {
    throw std::invalid_argument("point cloud sidecar " + path + ": X_5T or X_5C is not finite");
  }
  YAML::Emitter out;
  out.SetDoublePrecision(17);
  out << YAML::BeginMap;
  out << YAML::Key << "kind" << YAML::Value << kKind;
  out << YAML::Key << "version" << YAML::Value << kVersion;
  out << YAML::Key << "ply" << YAML::Value << s.ply;
  out << YAML::Key << "units" << YAML::Value << s.units;
  out << YAML::Key << "frame" << YAML::Value << s.frame;
  out << YAML::Key << "frame_description" << YAML::Value << s.frame_description;
  out << YAML::Key << "created" << YAML::Value << (s.created.empty() ? NowUtc() : s.created);
  out << YAML::Key << "source" << YAML::Value << s.source;
  out << YAML::Key << "counts" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "points" << YAML::Value << s.points;
  out << YAML::Key << "scan_lines" << YAML::Value << s.scan_lines;
  out << YAML::Key << "normals_estimated" << YAML::Value << s.normals_estimated;
  out << YAML::Key << "normals_missing" << YAML::Value << s.normals_missing;
  out << YAML::Key << "has_confidence" << YAML::Value << s.has_confidence;
  out << YAML::EndMap;
  out << YAML::Key << "robot" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "calibration" << YAML::Value << s.robot_calibration;
  out << YAML::Key << "dh" << YAML::Value << YAML::BeginSeq;
  for (const SidecarDhLink& l : s.robot_dh) {
    out << YAML::Flow << YAML::BeginMap;
    out << YAML::Key << "a_mm" << YAML::Value << l.a * common::kMmPerM;
    out << YAML::Key << "alpha_deg" << YAML::Value << l.alpha * common::kDegPerRad;
    out << YAML::Key << "d_mm" << YAML::Value << l.d * common::kMmPerM;
    out << YAML::Key << "theta_offset_deg" << YAML::Value << l.theta_offset * common::kDegPerRad;
    out << YAML::Key << "prismatic" << YAML::Value << l.prismatic;
    out << YAML::EndMap;
  }
  out << YAML::EndSeq;
  out << YAML::Key << "torch" << YAML::Value;
  EmitPose(out, s.X_5T);
  out << YAML::EndMap;
  out << YAML::Key << "mount" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "calibration" << YAML::Value << s.mount_calibration;
  out << YAML::Key << "X_5C" << YAML::Value;
  EmitPose(out, s.X_5C);
  out << YAML::EndMap;
  out << YAML::Key << "scanner" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "calibration" << YAML::Value << s.scanner_calibration;
  out << YAML::Key << "parameters" << YAML::Value << YAML::BeginMap;
  for (const auto& [name, value] : s.scanner_parameters) {
    out << YAML::Key << name << YAML::Value << value;
  }
  out << YAML::EndMap << YAML::EndMap;
  out << YAML::EndMap;
  std::ofstream file(path);
  file << out.c_str() << "\n";
  file.close();
  if (!file) throw std::runtime_error("point cloud sidecar " + path + ": cannot write");
}

CloudSidecar ReadCloudSidecar(const std::string& path) {
  const Reader r(path);
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw std::invalid_argument("point cloud sidecar " + path + ": cannot open");
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument("point cloud sidecar " + path + ": not YAML: " + e.what());
  }
  if (!root.IsMap()) r.Fail("(root)", "expected a map");
  const std::string kind = r.Get<std::string>(root, "", "kind");
  if (kind != kKind) r.Fail("kind", "is '" + kind + "'; expected " + kKind);
  const int version = r.Get<int>(root, "", "version");
  if (version != kVersion) r.Fail("version", std::to_string(version) + " is not supported");
  CloudSidecar s;
  s.ply = r.Get<std::string>(root, "", "ply");
  if (s.ply.empty()) r.Fail("ply", "is empty");
  s.units = r.Get<std::string>(root, "", "units");
  if (s.units != "m") r.Fail("units", "is '" + s.units + "'; expected m");
  s.frame = r.Get<std::string>(root, "", "frame");
  s.frame_description = r.Get<std::string>(root, "", "frame_description");
  s.created = r.Get<std::string>(root, "", "created");
  s.source = r.Get<std::string>(root, "", "source");
  const YAML::Node counts = r.Child(root, "", "counts");
  s.points = r.Get<std::uint64_t>(counts, "counts", "points");
  s.scan_lines = r.Get<std::uint64_t>(counts, "counts", "scan_lines");
  s.normals_estimated = r.Get<std::uint64_t>(counts, "counts", "normals_estimated");
  s.normals_missing = r.Get<std::uint64_t>(counts, "counts", "normals_missing");
  s.has_confidence = r.Get<bool>(counts, "counts", "has_confidence");
  if (s.normals_estimated + s.normals_missing != 0 &&
      s.normals_estimated + s.normals_missing != s.points) {
    r.Fail("counts", "normals_estimated + normals_missing = " +
                         std::to_string(s.normals_estimated + s.normals_missing) +
                         " is neither 0 nor points = " + std::to_string(s.points));
  }
  const YAML::Node robot = r.Child(root, "", "robot");
  s.robot_calibration = r.Get<std::string>(robot, "robot", "calibration");
  const YAML::Node dh = r.Child(robot, "robot", "dh");
  if (!dh.IsSequence()) r.Fail("robot.dh", "expected a list of links");
  for (std::size_t i = 0; i < dh.size(); ++i) {
    const std::string key = "robot.dh[" + std::to_string(i) + "]";
    SidecarDhLink l;
    l.a = r.Number(dh[i], key, "a_mm") / common::kMmPerM;
    l.alpha = r.Number(dh[i], key, "alpha_deg") / common::kDegPerRad;
    l.d = r.Number(dh[i], key, "d_mm") / common::kMmPerM;
    l.theta_offset = r.Number(dh[i], key, "theta_offset_deg") / common::kDegPerRad;
    l.prismatic = r.Get<bool>(dh[i], key, "prismatic");
    s.robot_dh.push_back(l);
  }
  s.X_5T = r.Pose(robot, "robot", "torch");
  const YAML::Node mount = r.Child(root, "", "mount");
  s.mount_calibration = r.Get<std::string>(mount, "mount", "calibration");
  s.X_5C = r.Pose(mount, "mount", "X_5C");
  const YAML::Node scanner = r.Child(root, "", "scanner");
  s.scanner_calibration = r.Get<std::string>(scanner, "scanner", "calibration");
  const YAML::Node parameters = r.Child(scanner, "scanner", "parameters");
  if (!parameters.IsMap()) r.Fail("scanner.parameters", "expected a map of name: number");
  for (const auto& entry : parameters) {
    const std::string name = entry.first.as<std::string>();
    s.scanner_parameters[name] = r.Number(parameters, "scanner.parameters", name);
  }
  return s;
}

void WriteCloud(const std::string& sidecar_path, const PointCloud& cloud, CloudSidecar sidecar) {
  sidecar.points = cloud.size();
  sidecar.normals_missing = cloud.CountMissingNormals();
  sidecar.normals_estimated = cloud.has_normals() ? cloud.size() - sidecar.normals_missing : 0;
  sidecar.has_confidence = cloud.has_confidence();
  if (sidecar.ply.empty()) {
    throw std::invalid_argument("point cloud sidecar " + sidecar_path + ": ply is empty");
  }
  const std::filesystem::path ply = std::filesystem::path(sidecar_path).parent_path() / sidecar.ply;
  WritePly(ply.string(), cloud,
           {"sidecar " + std::filesystem::path(sidecar_path).filename().string(),
            "frame " + sidecar.frame + " (" + sidecar.frame_description + ")"});
  WriteCloudSidecar(sidecar_path, sidecar);
}

PointCloud ReadCloud(const std::string& sidecar_path, CloudSidecar* sidecar_out) {
  const CloudSidecar sidecar = ReadCloudSidecar(sidecar_path);
  const std::filesystem::path ply = std::filesystem::path(sidecar_path).parent_path() / sidecar.ply;
  PointCloud cloud = ReadPly(ply.string());
  const auto fail = [&](const std::string& what) {
    throw std::invalid_argument("point cloud " + sidecar_path + " with " + ply.string() + ": " +
                                what);
  };
  if (cloud.size() != sidecar.points) {
    fail("the sidecar says " + std::to_string(sidecar.points) + " points, the PLY holds " +
         std::to_string(cloud.size()));
  }
  const bool sidecar_normals = sidecar.normals_estimated + sidecar.normals_missing > 0;
  if (sidecar_normals != cloud.has_normals() && cloud.size() > 0) {
    fail(std::string("the sidecar says the points ") + (sidecar_normals ? "have" : "have no") +
         " normals, the PLY disagrees");
  }
  if (cloud.has_normals() && cloud.CountMissingNormals() != sidecar.normals_missing) {
    fail("the sidecar says " + std::to_string(sidecar.normals_missing) +
         " normals are missing, the PLY has " + std::to_string(cloud.CountMissingNormals()));
  }
  if (sidecar.has_confidence != cloud.has_confidence() && cloud.size() > 0) {
    fail("the sidecar and the PLY disagree on the confidence property");
  }
  if (sidecar_out != nullptr) *sidecar_out = sidecar;
  return cloud;
}

}  // namespace kinevis::vision::cloud
