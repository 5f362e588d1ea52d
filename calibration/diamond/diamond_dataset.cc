#include "calibration/diamond/diamond_dataset.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>
#include <stdexcept>

#include "calibration/common/csv_internal.h"
#include "calibration/common/yaml_reader_internal.h"
#include "robots/io/robot_description.h"

namespace kinevis::calibration {
namespace {

using internal::ParseDouble;
using internal::SplitCsv;

namespace fs = std::filesystem;
constexpr const char* kKind = "kinevis-diamond-dataset";
constexpr int kVersion = 1;
constexpr const char* kHeader = "index,image,q1_rad,q2_rad,u_px,v_px";

std::string Num(double v) {
  std::ostringstream out;
  out.precision(17);
  out << v;
  return out.str();
}

using internal::NowUtc;

void Copy(const std::string& from, const fs::path& to) {
  std::error_code ec;
  fs::copy_file(from, to, fs::copy_options::overwrite_existing, ec);
  if (ec) {
    throw std::runtime_error("diamond dataset: cannot copy " + from + " to " + to.string() + ": " +
                             ec.message());
  }
}

std::string CheckRigid(const Eigen::Isometry3d& X) {
  const Eigen::Matrix3d R = X.linear();
  if (!R.allFinite() || !X.translation().allFinite()) return "not finite";
  const double orth = (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (orth > 1e-6 || R.determinant() < 0) return "linear part is not a rotation";
  return "";
}

}  // namespace

void CreateDiamondDataset(DiamondDataset* d) {
  const fs::path dir(d->directory);
  if (fs::exists(dir / "dataset.yaml")) {
    throw std::invalid_argument("diamond dataset: " + (dir / "dataset.yaml").string() +
                                " exists; record into a new directory");
  }
  if (const std::string bad = CheckRigid(d->X_OC); !bad.empty()) {
    throw std::invalid_argument("diamond dataset: camera pose X_OC: " + bad);
  }
  std::error_code ec;
  fs::create_directories(dir / "images", ec);
  if (ec) {
    throw std::runtime_error("diamond dataset: cannot create " + (dir / "images").string() + ": " +
                             ec.message());
  }
  if (!d->robot_file.empty()) {
    Copy(d->robot_file, dir / "robot.yaml");
    d->robot_file = "robot.yaml";
  }
  if (!d->camera_model.empty() && d->camera_model.rfind("builtin:", 0) != 0) {
    const std::string name = "camera" + fs::path(d->camera_model).extension().string();
    Copy(d->camera_model, dir / name);
    d->camera_model = name;
  }
  if (d->created.empty()) d->created = NowUtc();
  const Eigen::Quaterniond q(d->X_OC.linear());
  YAML::Emitter out;
  out.SetDoublePrecision(17);
  out << YAML::BeginMap;
  out << YAML::Key << "kind" << YAML::Value << kKind;
  out << YAML::Key << "version" << YAML::Value << kVersion;
  out << YAML::Key << "created" << YAML::Value << d->created;
  out << YAML::Key << "source" << YAML::Value << d->source;
  out << YAML::Key << "robot" << YAML::Value << (d->robot_file.empty() ? "apriori" : d->robot_file);
  out << YAML::Key << "camera" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "name" << YAML::Value << d->camera_name;
  out << YAML::Key << "model" << YAML::Value << d->camera_model;
  out << YAML::Key << "pose" << YAML::Value << YAML::Flow << YAML::BeginMap;
  out << YAML::Key << "position" << YAML::Value << YAML::Flow << YAML::BeginSeq
      << d->X_OC.translation().x() << d->X_OC.translation().y() << d->X_OC.translation().z()
      << YAML::EndSeq;
  out << YAML::Key << "quaternion_wxyz" << YAML::Value << YAML::Flow << YAML::BeginSeq << q.w()
      << q.x() << q.y() << q.z() << YAML::EndSeq;
  out << YAML::EndMap;
  out << YAML::Key << "distance_source" << YAML::Value << d->camera_distance_source;
  out << YAML::EndMap;
  out << YAML::Key << "samples" << YAML::Value << "samples.csv";
  out << YAML::EndMap;
  std::ofstream yaml(dir / "dataset.yaml");
  yaml << "# kinevis DIAMOND calibration dataset; format: docs/diamond-calibration.md\n"
       << "# camera.pose is X_OC (camera in the RCM frame O): position m, unit quaternion.\n"
       << out.c_str() << "\n";
  std::ofstream csv(dir / "samples.csv");
  csv << kHeader << "\n";
  if (!yaml || !csv) {
    throw std::runtime_error("diamond dataset: cannot write " + (dir / "dataset.yaml").string() +
                             " or samples.csv");
  }
}

void AppendDiamondDatasetSample(const DiamondDataset& d, const DiamondDatasetSample& s,
                                const uint8_t* pixels, int width, int height, size_t stride) {
  if (!s.q.allFinite() || (s.has_pixel && !s.pixel.allFinite())) {
    throw std::invalid_argument("diamond dataset: sample " + std::to_string(s.index) +
                                ": q or pixel not finite");
  }
  const fs::path dir(d.directory);
  if (pixels != nullptr) {
    if (s.image.empty() || width <= 0 || height <= 0 || stride < static_cast<size_t>(width)) {
      throw std::invalid_argument("diamond dataset: sample " + std::to_string(s.index) +
                                  ": an image needs a file name and width, height > 0, stride >= "
                                  "width (got '" +
                                  s.image + "', " + std::to_string(width) + "x" +
                                  std::to_string(height) + ", stride " + std::to_string(stride) +
                                  ")");
    }
    const cv::Mat image(height, width, CV_8UC1, const_cast<uint8_t*>(pixels), stride);
    const fs::path png = dir / s.image;
    if (!cv::imwrite(png.string(), image)) {
      throw std::runtime_error("diamond dataset: cannot write " + png.string());
    }
  }
  std::ofstream csv(dir / "samples.csv", std::ios::app);
  csv << s.index << "," << s.image << "," << Num(s.q.x()) << "," << Num(s.q.y()) << ",";
  if (s.has_pixel)
    csv << Num(s.pixel.x()) << "," << Num(s.pixel.y());
  else
    csv << ",";
  csv << "\n";
  csv.flush();
  if (!csv) {
    throw std::runtime_error("diamond dataset: cannot append to " + (dir / "samples.csv").string());
  }
}

DiamondDataset ReadDiamondDataset(const std::string& directory) {
  DiamondDataset d;
  d.directory = directory;
  const fs::path dir(directory);
  const std::string yaml_path = (dir / "dataset.yaml").string();
  std::vector<std::string> problems;
  const auto bad = [&problems](const std::string& text) { problems.push_back(text); };
  const auto throw_if_bad = [&problems, &yaml_path] {
    if (problems.empty()) return;
    std::string message = "diamond dataset " + yaml_path + ": ";
    for (size_t i = 0; i < problems.size(); ++i) message += (i ? "; " : "") + problems[i];
    throw std::invalid_argument(message);
  };
  YAML::Node root;
  try {
    root = YAML::LoadFile(yaml_path);
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument("diamond dataset " + yaml_path + ": cannot read (" + e.what() +
                                ")");
  }
  const auto scalar = [&](const YAML::Node& node, const std::string& key) -> std::string {
    if (!node || !node.IsScalar()) {
      bad(key + ": missing or not a scalar");
      return "";
    }
    return node.Scalar();
  };
  if (scalar(root["kind"], "kind") != kKind) bad("kind: expected " + std::string(kKind));
  const std::string version = scalar(root["version"], "version");
  if (version != std::to_string(kVersion)) {
    bad("version: " + version + " (this reader reads " + std::to_string(kVersion) + ")");
  }
  d.created = root["created"] ? scalar(root["created"], "created") : "";
  d.source = root["source"] ? scalar(root["source"], "source") : "";
  const std::string robot = scalar(root["robot"], "robot");
  const YAML::Node camera = root["camera"];
  if (!camera || !camera.IsMap()) {
    bad("camera: missing or not a mapping");
  } else {
    d.camera_name = camera["name"] ? scalar(camera["name"], "camera.name") : "";
    d.camera_model = scalar(camera["model"], "camera.model");
    d.camera_distance_source = camera["distance_source"]
                                   ? scalar(camera["distance_source"], "camera.distance_source")
                                   : "";
    const YAML::Node pose = camera["pose"];
    std::vector<double> p, q;
    const auto numbers = [&](const YAML::Node& n, size_t count, const std::string& key) {
      std::vector<double> v;
      if (!n || !n.IsSequence() || n.size() != count) {
        bad(key + ": must be a list of " + std::to_string(count) + " numbers");
        return v;
      }
      for (const YAML::Node& e : n) {
        double x = 0;
        if (!e.IsScalar() || !YAML::convert<double>::decode(e, x) || !std::isfinite(x)) {
          bad(key + ": not a finite number (" + (e.IsScalar() ? e.Scalar() : "?") + ")");
          return std::vector<double>();
        }
        v.push_back(x);
      }
      return v;
    };
    if (!pose || !pose.IsMap()) {
      bad("camera.pose: missing (position, quaternion_wxyz)");
    } else {
      p = numbers(pose["position"], 3, "camera.pose.position");
      q = numbers(pose["quaternion_wxyz"], 4, "camera.pose.quaternion_wxyz");
      if (p.size() == 3 && q.size() == 4) {
        const Eigen::Quaterniond quat(q[0], q[1], q[2], q[3]);
        if (std::abs(quat.norm() - 1.0) > 1e-6) {
          bad("camera.pose.quaternion_wxyz: not a unit quaternion (norm " + Num(quat.norm()) + ")");
        } else {
          d.X_OC.linear() = quat.normalized().matrix();
          d.X_OC.translation() = Eigen::Vector3d(p[0], p[1], p[2]);
        }
      }
    }
  }
  throw_if_bad();
  if (robot != "apriori") {
    d.robot_file = robot;
    try {
      d.nominal = robots::LoadDiamondDescription((dir / robot).string()).model;
    } catch (const std::exception& e) {
      throw std::invalid_argument("diamond dataset " + yaml_path + ": robot " + robot + ": " +
                                  e.what());
    }
  }

  const std::string csv_path = (dir / "samples.csv").string();
  std::ifstream csv(csv_path);
  if (!csv) throw std::invalid_argument("diamond dataset: cannot read " + csv_path);
  std::string line;
  std::getline(csv, line);
  if (!line.empty() && line.back() == '\r') line.pop_back();
  if (line != kHeader) {
    throw std::invalid_argument("diamond dataset " + csv_path + ": line 1: header '" + line +
                                "', expected '" + kHeader + "'");
  }
  std::vector<std::string> csv_problems;
  int line_number = 1;
  while (std::getline(csv, line)) {
    ++line_number;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) continue;
    const std::vector<std::string> f = SplitCsv(line);
    const std::string where = "line " + std::to_string(line_number);
    if (f.size() != 6) {
      csv_problems.push_back(where + ": " + std::to_string(f.size()) + " fields, expected 6");
      continue;
    }
    DiamondDatasetSample s;
    double index = 0;
    if (!ParseDouble(f[0], &index) || index != std::floor(index) || index < 0) {
      csv_problems.push_back(where + ": index '" + f[0] + "' is not a non-negative integer");
      continue;
    }
    s.index = static_cast<int>(index);
    s.image = f[1];
    if (!ParseDouble(f[2], &s.q.x()) || !ParseDouble(f[3], &s.q.y())) {
      csv_problems.push_back(where + ": q1_rad/q2_rad '" + f[2] + "', '" + f[3] +
                             "' are not finite numbers");
      continue;
    }
    if (f[4].empty() != f[5].empty()) {
      csv_problems.push_back(where + ": give both u_px and v_px or neither");
      continue;
    }
    if (!f[4].empty()) {
      if (!ParseDouble(f[4], &s.pixel.x()) || !ParseDouble(f[5], &s.pixel.y())) {
        csv_problems.push_back(where + ": u_px/v_px '" + f[4] + "', '" + f[5] +
                               "' are not finite numbers");
        continue;
      }
      s.has_pixel = true;
    }
    if (!s.image.empty() && !fs::exists(dir / s.image)) {
      csv_problems.push_back(where + ": image " + (dir / s.image).string() + " does not exist");
      continue;
    }
    d.samples.push_back(s);
    if (csv_problems.size() > 20) break;
  }
  if (!csv_problems.empty()) {
    std::string message = "diamond dataset " + csv_path + ": ";
    for (size_t i = 0; i < csv_problems.size(); ++i) message += (i ? "; " : "") + csv_problems[i];
    throw std::invalid_argument(message);
  }
  return d;
}

std::vector<uint8_t> ReadDiamondDatasetImage(const DiamondDataset& d, const DiamondDatasetSample& s,
                                             int* width, int* height) {
  const std::string path = (fs::path(d.directory) / s.image).string();
  if (s.image.empty()) {
    throw std::invalid_argument("diamond dataset: sample " + std::to_string(s.index) +
                                " has no image");
  }
  const cv::Mat image = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (image.empty() || image.type() != CV_8UC1) {
    throw std::invalid_argument("diamond dataset: " + path +
                                (image.empty() ? ": cannot read" : ": not 8-bit grey"));
  }
  *width = image.cols;
  *height = image.rows;
  std::vector<uint8_t> pixels(static_cast<size_t>(image.cols) * image.rows);
  for (int r = 0; r < image.rows; ++r) {
    std::copy(image.ptr<uint8_t>(r), image.ptr<uint8_t>(r) + image.cols,
              pixels.begin() + static_cast<size_t>(r) * image.cols);
  }
  return pixels;
}

std::vector<DiamondSample> DiamondSamplesWithPixels(const DiamondDataset& dataset) {
  std::vector<DiamondSample> out;
  for (const DiamondDatasetSample& s : dataset.samples) {
    if (!s.has_pixel) continue;
    out.push_back({s.q, s.pixel});
  }
  return out;
}

}  // namespace kinevis::calibration
