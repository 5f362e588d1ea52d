#include "calibration/weld_mount/mount_dataset.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <set>
#include <sstream>
#include <stdexcept>

#include "calibration/common/csv_internal.h"
#include "calibration/common/yaml_reader_internal.h"
#include "common/units.h"

namespace kinevis::calibration {
namespace {

using internal::ParseDouble;
using internal::ParseInt;
using internal::SplitCsv;

namespace fs = std::filesystem;
constexpr const char* kKind = "kinevis-scanner-mount-dataset";
constexpr const char* kTouchHeader =
    "touch,feature,theta1_deg,theta2_deg,pz3_mm,theta4_deg,theta5_deg";
constexpr const char* kScanHeader =
    "scan,theta1_deg,theta2_deg,pz3_mm,theta4_deg,theta5_deg,laser,cot_theta_y,points,image";
constexpr const char* kPointsHeader = "x_mm,y_mm,z_mm,confidence";
// File units per joint: degrees for the revolute joints, mm for pz3.
constexpr double kJointScale[5] = {common::kDegPerRad, common::kDegPerRad, common::kMmPerM,
                                   common::kDegPerRad, common::kDegPerRad};

using internal::NowUtc;

std::string Num(double v) {
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%.17g", v);
  return buffer;
}

void EmitPose(YAML::Emitter& out, const Eigen::Isometry3d& X) {
  const Eigen::Vector3d ypr = X.linear().eulerAngles(2, 1, 0);
  const Eigen::Vector3d p = X.translation() * common::kMmPerM;
  out << YAML::BeginMap << YAML::Key << "position_mm" << YAML::Value << YAML::Flow << YAML::BeginSeq
      << p.x() << p.y() << p.z() << YAML::EndSeq;
  out << YAML::Key << "rpy_deg" << YAML::Value << YAML::Flow << YAML::BeginSeq
      << ypr.z() * common::kDegPerRad << ypr.y() * common::kDegPerRad
      << ypr.x() * common::kDegPerRad << YAML::EndSeq << YAML::EndMap;
}

std::string JointFields(const robots::Vector5d& q) {
  std::string s;
  for (int i = 0; i < 5; ++i) s += (i ? "," : "") + Num(q(i) * kJointScale[i]);
  return s;
}

void AppendLine(const fs::path& file, const std::string& line) {
  std::ofstream out(file, std::ios::app);
  out << line << "\n";
  out.flush();
  if (!out) throw std::runtime_error("scanner mount dataset: cannot append to " + file.string());
}

class YamlReader {
 public:
  explicit YamlReader(std::string file) : file_(std::move(file)) {}
  [[noreturn]] void Fail(const std::string& key, const std::string& what) const {
    throw std::invalid_argument("scanner mount dataset " + file_ + ": " + key + ": " + what);
  }
  YAML::Node Child(const YAML::Node& n, const std::string& key) const {
    const size_t dot = key.rfind('.');
    const YAML::Node c = n[dot == std::string::npos ? key : key.substr(dot + 1)];
    if (!c) Fail(key, "missing");
    return c;
  }
  std::string String(const YAML::Node& n, const std::string& key) const {
    try {
      return Child(n, key).as<std::string>();
    } catch (const YAML::Exception&) {
      Fail(key, "expected a string");
    }
  }
  Eigen::Vector3d Vector(const YAML::Node& n, const std::string& key) const {
    const YAML::Node c = Child(n, key);
    if (!c.IsSequence() || c.size() != 3) Fail(key, "expected a list of 3 numbers");
    Eigen::Vector3d v;
    for (size_t k = 0; k < 3; ++k) {
      try {
        v[static_cast<int>(k)] = c[k].as<double>();
      } catch (const YAML::Exception&) {
        Fail(key, "entry " + std::to_string(k) + " is not a number");
      }
      if (!std::isfinite(v[static_cast<int>(k)]))
        Fail(key, "entry " + std::to_string(k) + " is not finite");
    }
    return v;
  }
  Eigen::Isometry3d Pose(const YAML::Node& n, const std::string& key) const {
    const YAML::Node c = Child(n, key);
    const Eigen::Vector3d p = Vector(c, key + ".position_mm") / common::kMmPerM;
    const Eigen::Vector3d rpy = Vector(c, key + ".rpy_deg") / common::kDegPerRad;
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = (Eigen::AngleAxisd(rpy.z(), Eigen::Vector3d::UnitZ()) *
                  Eigen::AngleAxisd(rpy.y(), Eigen::Vector3d::UnitY()) *
                  Eigen::AngleAxisd(rpy.x(), Eigen::Vector3d::UnitX()))
                     .toRotationMatrix();
    X.translation() = p;
    return X;
  }

 private:
  std::string file_;
};

// Lines of a CSV after its header (checked); calls row(fields, line_number).
template <typename Row>
void ReadCsv(const fs::path& file, const std::string& header, size_t fields, Row row) {
  std::ifstream in(file);
  if (!in) throw std::invalid_argument("scanner mount dataset: cannot open " + file.string());
  std::string line;
  if (!std::getline(in, line)) {
    throw std::invalid_argument("scanner mount dataset " + file.string() + ": empty (no header)");
  }
  if (!line.empty() && line.back() == '\r') line.pop_back();
  if (line != header) {
    throw std::invalid_argument("scanner mount dataset " + file.string() + ": header is '" + line +
                                "'; expected '" + header + "'");
  }
  int number = 1;
  while (std::getline(in, line)) {
    ++number;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) continue;
    const std::vector<std::string> f = SplitCsv(line);
    if (f.size() != fields) {
      throw std::invalid_argument("scanner mount dataset " + file.string() + " line " +
                                  std::to_string(number) + ": " + std::to_string(f.size()) +
                                  " fields; expected " + std::to_string(fields));
    }
    row(f, number);
  }
}

}  // namespace

void CreateMountDataset(MountDataset* dataset) {
  const fs::path dir(dataset->directory);
  if (fs::exists(dir / "dataset.yaml")) {
    throw std::invalid_argument("scanner mount dataset " + dataset->directory +
                                ": already holds a dataset (dataset.yaml)");
  }
  const std::string bad = dataset->block.Validate();
  if (!bad.empty())
    throw std::invalid_argument("scanner mount dataset " + dataset->directory + ": " + bad);
  std::error_code error;
  fs::create_directories(dir / "points", error);
  if (!error) fs::create_directories(dir / "images", error);
  if (error)
    throw std::runtime_error("cannot create " + dataset->directory + ": " + error.message());
  if (dataset->created.empty()) dataset->created = NowUtc();
  YAML::Emitter out;
  out.SetDoublePrecision(17);
  out << YAML::BeginMap;
  out << YAML::Key << "kind" << YAML::Value << kKind;
  out << YAML::Key << "version" << YAML::Value << 1;
  out << YAML::Key << "robot" << YAML::Value << dataset->robot_description;
  out << YAML::Key << "scanner" << YAML::Value << dataset->scanner;
  out << YAML::Key << "block" << YAML::Value << YAML::BeginMap;
  const Eigen::Vector3d size = dataset->block.size * common::kMmPerM;
  out << YAML::Key << "size_mm" << YAML::Value << YAML::Flow << YAML::BeginSeq << size.x()
      << size.y() << size.z() << YAML::EndSeq;
  out << YAML::Key << "guess" << YAML::Value;
  EmitPose(out, dataset->X_0B_guess);
  out << YAML::EndMap;
  out << YAML::Key << "mount_guess" << YAML::Value;
  EmitPose(out, dataset->X_5C_guess);
  out << YAML::Key << "source" << YAML::Value << dataset->source;
  out << YAML::Key << "created" << YAML::Value << dataset->created;
  out << YAML::EndMap;
  {
    std::ofstream f(dir / "dataset.yaml");
    f << out.c_str() << "\n";
    if (!f) throw std::runtime_error("cannot write " + (dir / "dataset.yaml").string());
  }
  for (const auto& [name, header] :
       {std::pair<const char*, const char*>{"touches.csv", kTouchHeader},
        {"scans.csv", kScanHeader}}) {
    std::ofstream f(dir / name);
    f << header << "\n";
    if (!f) throw std::runtime_error("cannot write " + (dir / name).string());
  }
  dataset->touches.clear();
  dataset->scans.clear();
}

void AppendMountTouch(MountDataset* dataset, const MountTouch& touch) {
  if (!touch.q.allFinite() || !touch.feature.Valid()) {
    throw std::invalid_argument("scanner mount dataset " + dataset->directory + ": touch " +
                                std::to_string(dataset->touches.size()) +
                                ": joints not finite or feature invalid");
  }
  AppendLine(fs::path(dataset->directory) / "touches.csv", std::to_string(dataset->touches.size()) +
                                                               "," + touch.feature.Name() + "," +
                                                               JointFields(touch.q));
  dataset->touches.push_back(touch);
}

void AppendMountScan(MountDataset* dataset, MountDatasetScan scan,
                     const std::vector<Eigen::Vector3d>* p_C, const std::vector<float>& confidence,
                     const uint8_t* pixels, int width, int height, size_t stride) {
  const fs::path dir(dataset->directory);
  const size_t index = dataset->scans.size();
  const std::string where =
      "scanner mount dataset " + dataset->directory + ": scan " + std::to_string(index) + ": ";
  if (!scan.q.allFinite() || !std::isfinite(scan.cot_theta_y)) {
    throw std::invalid_argument(where + "joints or cot_theta_y not finite");
  }
  if (scan.laser != "fixed" && scan.laser != "rotating") {
    throw std::invalid_argument(where + "laser '" + scan.laser + "' (expected fixed or rotating)");
  }
  if (p_C == nullptr && pixels == nullptr)
    throw std::invalid_argument(where + "neither points nor image");
  char stem[32];
  std::snprintf(stem, sizeof(stem), "scan_%04zu", index);
  if (p_C != nullptr) {
    if (!confidence.empty() && confidence.size() != p_C->size()) {
      throw std::invalid_argument(where + std::to_string(confidence.size()) + " confidences for " +
                                  std::to_string(p_C->size()) + " points");
    }
    scan.points = std::string("points/") + stem + ".csv";
    std::ofstream f(dir / scan.points);
    f << kPointsHeader << "\n";
    for (size_t i = 0; i < p_C->size(); ++i) {
      const Eigen::Vector3d p = (*p_C)[i] * common::kMmPerM;
      if (!p.allFinite())
        throw std::invalid_argument(where + "point " + std::to_string(i) + " not finite");
      f << Num(p.x()) << "," << Num(p.y()) << "," << Num(p.z()) << ","
        << Num(confidence.empty() ? 1.0 : confidence[i]) << "\n";
    }
    if (!f) throw std::runtime_error("cannot write " + (dir / scan.points).string());
  }
  if (pixels != nullptr) {
    scan.image = std::string("images/") + stem + ".png";
    const cv::Mat image(height, width, CV_8UC1, const_cast<uint8_t*>(pixels), stride);
    if (!cv::imwrite((dir / scan.image).string(), image)) {
      throw std::runtime_error("cannot write " + (dir / scan.image).string());
    }
  }
  AppendLine(dir / "scans.csv", std::to_string(index) + "," + JointFields(scan.q) + "," +
                                    scan.laser + "," + Num(scan.cot_theta_y) + "," + scan.points +
                                    "," + scan.image);
  dataset->scans.push_back(scan);
}

MountDataset ReadMountDataset(const std::string& directory) {
  const fs::path dir(directory);
  const std::string yaml_file = (dir / "dataset.yaml").string();
  const YamlReader r(yaml_file);
  YAML::Node root;
  try {
    root = YAML::LoadFile(yaml_file);
  } catch (const YAML::BadFile&) {
    throw std::invalid_argument("scanner mount dataset " + directory + ": no dataset.yaml");
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument("scanner mount dataset " + yaml_file + ": not YAML: " + e.what());
  }
  MountDataset d;
  d.directory = directory;
  const std::string kind = r.String(root, "kind");
  if (kind != kKind) r.Fail("kind", "'" + kind + "' (expected " + kKind + ")");
  if (r.String(root, "version") != "1")
    r.Fail("version", "'" + r.String(root, "version") + "' (expected 1)");
  d.robot_description = r.String(root, "robot");
  d.scanner = r.String(root, "scanner");
  const YAML::Node block = r.Child(root, "block");
  d.block.size = r.Vector(block, "block.size_mm") / common::kMmPerM;
  if (!d.block.Validate().empty()) r.Fail("block.size_mm", "each size must be > 0");
  d.X_0B_guess = r.Pose(block, "block.guess");
  d.X_5C_guess = r.Pose(root, "mount_guess");
  d.source = r.String(root, "source");
  d.created = r.String(root, "created");

  const fs::path touches = dir / "touches.csv";
  ReadCsv(touches, kTouchHeader, 7, [&](const std::vector<std::string>& f, int line) {
    const std::string where =
        "scanner mount dataset " + touches.string() + " line " + std::to_string(line) + ": ";
    int index = 0;
    if (!ParseInt(f[0], &index) || index != static_cast<int>(d.touches.size())) {
      throw std::invalid_argument(where + "touch '" + f[0] + "' (expected " +
                                  std::to_string(d.touches.size()) + ")");
    }
    MountTouch t;
    try {
      t.feature = BlockFeature::Parse(f[1]);
    } catch (const std::invalid_argument& e) {
      throw std::invalid_argument(where + e.what());
    }
    for (int i = 0; i < 5; ++i) {
      double v = 0.0;
      if (!ParseDouble(f[static_cast<size_t>(2 + i)], &v)) {
        throw std::invalid_argument(where + "joint " + std::to_string(i + 1) + " '" +
                                    f[static_cast<size_t>(2 + i)] + "' is not a number");
      }
      t.q(i) = v / kJointScale[i];
    }
    d.touches.push_back(t);
  });

  const fs::path scans = dir / "scans.csv";
  ReadCsv(scans, kScanHeader, 10, [&](const std::vector<std::string>& f, int line) {
    const std::string where =
        "scanner mount dataset " + scans.string() + " line " + std::to_string(line) + ": ";
    int index = 0;
    if (!ParseInt(f[0], &index) || index != static_cast<int>(d.scans.size())) {
      throw std::invalid_argument(where + "scan '" + f[0] + "' (expected " +
                                  std::to_string(d.scans.size()) + ")");
    }
    MountDatasetScan s;
    for (int i = 0; i < 5; ++i) {
      double v = 0.0;
      if (!ParseDouble(f[static_cast<size_t>(1 + i)], &v)) {
        throw std::invalid_argument(where + "joint " + std::to_string(i + 1) + " '" +
                                    f[static_cast<size_t>(1 + i)] + "' is not a number");
      }
      s.q(i) = v / kJointScale[i];
    }
    s.laser = f[6];
    if (s.laser != "fixed" && s.laser != "rotating") {
      throw std::invalid_argument(where + "laser '" + s.laser + "' (expected fixed or rotating)");
    }
    if (!ParseDouble(f[7], &s.cot_theta_y))
      throw std::invalid_argument(where + "cot_theta_y '" + f[7] + "' is not a number");
    s.points = f[8];
    s.image = f[9];
    if (s.points.empty() && s.image.empty())
      throw std::invalid_argument(where + "neither points nor image");
    for (const std::string* file : {&s.points, &s.image}) {
      if (!file->empty() && !fs::exists(dir / *file)) {
        throw std::invalid_argument(where + "file " + (dir / *file).string() + " does not exist");
      }
    }
    d.scans.push_back(s);
  });
  return d;
}

std::vector<Eigen::Vector3d> ReadMountScanPoints(const MountDataset& dataset,
                                                 const MountDatasetScan& scan,
                                                 std::vector<float>* confidence) {
  if (scan.points.empty()) {
    throw std::invalid_argument("scanner mount dataset " + dataset.directory +
                                ": a scan has no points file (image " + scan.image + " only)");
  }
  const fs::path file = fs::path(dataset.directory) / scan.points;
  std::vector<Eigen::Vector3d> points;
  if (confidence != nullptr) confidence->clear();
  ReadCsv(file, kPointsHeader, 4, [&](const std::vector<std::string>& f, int line) {
    double v[4];
    for (size_t k = 0; k < 4; ++k) {
      if (!ParseDouble(f[k], &v[k])) {
        throw std::invalid_argument("scanner mount dataset " + file.string() + " line " +
                                    std::to_string(line) + ": field " + std::to_string(k + 1) +
                                    " '" + f[k] + "' is not a number");
      }
    }
    if (!(v[3] >= 0.0 && v[3] <= 1.0)) {
      throw std::invalid_argument("scanner mount dataset " + file.string() + " line " +
                                  std::to_string(line) + ": confidence " + f[3] +
                                  " outside [0, 1]");
    }
    points.emplace_back(v[0] / common::kMmPerM, v[1] / common::kMmPerM, v[2] / common::kMmPerM);
    if (confidence != nullptr) confidence->push_back(static_cast<float>(v[3]));
  });
  return points;
}

MountCalibrationData MountCalibrationDataFromDataset(const MountDataset& dataset,
                                                     const robots::Weld5Model& robot) {
  MountCalibrationData data;
  data.robot = robot;
  data.block = dataset.block;
  data.X_0B_guess = dataset.X_0B_guess;
  data.X_5C_guess = dataset.X_5C_guess;
  data.touches = dataset.touches;
  for (size_t i = 0; i < dataset.scans.size(); ++i) {
    const MountDatasetScan& s = dataset.scans[i];
    if (s.points.empty()) {
      throw std::invalid_argument("scanner mount dataset " + dataset.directory + ": scan " +
                                  std::to_string(i) + " has only an image (" + s.image +
                                  "): extract its stripe points first");
    }
    MountScan scan;
    scan.q = s.q;
    scan.p_C = ReadMountScanPoints(dataset, s);
    data.scans.push_back(std::move(scan));
  }
  return data;
}

}  // namespace kinevis::calibration
