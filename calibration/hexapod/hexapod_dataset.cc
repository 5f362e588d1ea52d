#include "calibration/hexapod/hexapod_dataset.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>
#include <stdexcept>

#include "calibration/common/yaml_reader_internal.h"
#include "common/units.h"
#include "robots/io/robot_description.h"

namespace kinevis::calibration {
namespace {

namespace fs = std::filesystem;
constexpr const char* kKind = "hexapod-leg-images";
constexpr int kVersion = 1;

std::string Num(double v) {
  std::ostringstream s;
  s.precision(17);
  s << v;
  return s.str();
}

void EmitPose(YAML::Emitter& out, const Eigen::Isometry3d& X) {
  // rpy as in robot description files: R = Rz(yaw) Ry(pitch) Rx(roll).
  const Eigen::Vector3d ypr = X.linear().eulerAngles(2, 1, 0);
  out << YAML::Flow << YAML::BeginMap;
  out << YAML::Key << "position" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (int i = 0; i < 3; ++i) out << X.translation()[i];
  out << YAML::EndSeq;
  out << YAML::Key << "rpy_deg" << YAML::Value << YAML::Flow << YAML::BeginSeq
      << ypr[2] / common::kDeg << ypr[1] / common::kDeg << ypr[0] / common::kDeg << YAML::EndSeq;
  out << YAML::EndMap;
}

using internal::NowUtc;

void Copy(const std::string& from, const fs::path& to) {
  std::error_code ec;
  fs::copy_file(from, to, fs::copy_options::overwrite_existing, ec);
  if (ec) {
    throw std::runtime_error("hexapod dataset: cannot copy " + from + " to " + to.string() + ": " +
                             ec.message());
  }
}

}  // namespace

void CreateHexapodDataset(HexapodDataset* d) {
  const fs::path dir(d->directory);
  if (fs::exists(dir / "dataset.yaml")) {
    throw std::invalid_argument("hexapod dataset: " + (dir / "dataset.yaml").string() +
                                " exists; record into a new directory");
  }
  std::error_code ec;
  fs::create_directories(dir / "images", ec);
  if (ec) {
    throw std::runtime_error("hexapod dataset: cannot create " + (dir / "images").string() + ": " +
                             ec.message());
  }
  if (!d->robot_file.empty()) {
    Copy(d->robot_file, dir / "robot.yaml");
    d->robot_file = "robot.yaml";
  }
  if (d->camera_model.rfind("builtin:", 0) != 0) {
    const std::string name = "camera" + fs::path(d->camera_model).extension().string();
    Copy(d->camera_model, dir / name);
    d->camera_model = name;
  }
  if (d->created.empty()) d->created = NowUtc();

  YAML::Emitter out;
  out << YAML::BeginMap;
  out << YAML::Key << "kind" << YAML::Value << kKind;
  out << YAML::Key << "version" << YAML::Value << kVersion;
  out << YAML::Key << "created" << YAML::Value << d->created;
  out << YAML::Key << "source" << YAML::Value << d->source;
  out << YAML::Key << "robot" << YAML::Value << (d->robot_file.empty() ? "default" : d->robot_file);
  out << YAML::Key << "camera" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "name" << YAML::Value << d->camera_name;
  out << YAML::Key << "model" << YAML::Value << d->camera_model;
  out << YAML::Key << "pose_hint" << YAML::Value;
  EmitPose(out, d->X_BC_hint);
  out << YAML::Key << "edge_locator" << YAML::Value << d->edge_locator;
  out << YAML::Key << "edge_blur_px" << YAML::Value << d->edge_blur_px;
  out << YAML::EndMap;
  out << YAML::Key << "poses" << YAML::Value << "poses.csv";
  out << YAML::EndMap;
  std::ofstream yaml(dir / "dataset.yaml");
  yaml << "# kinevis hexapod calibration dataset; format: docs/hexapod-rig.md\n"
       << out.c_str() << "\n";
  std::ofstream csv(dir / "poses.csv");
  csv << "index,image,s0_m,s1_m,s2_m,s3_m,s4_m,s5_m,x_m,y_m,z_m,qw,qx,qy,qz\n";
  if (!yaml || !csv) {
    throw std::runtime_error("hexapod dataset: cannot write " + (dir / "dataset.yaml").string() +
                             " or poses.csv");
  }
}

void AppendHexapodDatasetPose(const HexapodDataset& d, const HexapodDatasetPose& pose,
                              const uint8_t* pixels, int width, int height, size_t stride) {
  const fs::path dir(d.directory);
  const cv::Mat image(height, width, CV_8UC1, const_cast<uint8_t*>(pixels), stride);
  const fs::path png = dir / pose.image;
  if (!cv::imwrite(png.string(), image)) {
    throw std::runtime_error("hexapod dataset: cannot write " + png.string());
  }
  std::ofstream csv(dir / "poses.csv", std::ios::app);
  const Eigen::Quaterniond q(pose.X_BP_commanded.linear());
  csv << pose.index << "," << pose.image;
  for (int j = 0; j < robots::kHexapodLegs; ++j) csv << "," << Num(pose.s[j]);
  for (int i = 0; i < 3; ++i) csv << "," << Num(pose.X_BP_commanded.translation()[i]);
  csv << "," << Num(q.w()) << "," << Num(q.x()) << "," << Num(q.y()) << "," << Num(q.z()) << "\n";
  csv.flush();
  if (!csv) throw std::runtime_error("hexapod dataset: cannot append to poses.csv");
}

HexapodDataset ReadHexapodDataset(const std::string& directory) {
  HexapodDataset d;
  d.directory = directory;
  const fs::path dir(directory);
  const std::string yaml_path = (dir / "dataset.yaml").string();
  std::vector<std::string> problems;
  YAML::Node root;
  try {
    root = YAML::LoadFile(yaml_path);
  } catch (const std::exception& e) {
    throw std::invalid_argument(yaml_path + ": cannot read: " + e.what());
  }
  auto text = [&](const YAML::Node& n, const std::string& key) -> std::string {
    if (!n || !n.IsScalar()) {
      problems.push_back(key + ": missing or not a scalar");
      return "";
    }
    return n.as<std::string>();
  };
  if (text(root["kind"], "kind") != kKind) {
    problems.push_back(std::string("kind: expected ") + kKind);
  }
  if (!root["version"] || !root["version"].IsScalar() ||
      root["version"].Scalar() != std::to_string(kVersion)) {
    problems.push_back("version: expected " + std::to_string(kVersion) + " (this kinevis reads " +
                       "version " + std::to_string(kVersion) + " datasets)");
  }
  d.created = root["created"] ? root["created"].as<std::string>() : "";
  d.source = root["source"] ? root["source"].as<std::string>() : "";
  const std::string robot = text(root["robot"], "robot");
  if (!robot.empty() && robot != "default") {
    d.robot_file = robot;
    try {
      d.nominal = robots::LoadHexapodDescription((dir / robot).string()).model;
    } catch (const std::exception& e) {
      problems.push_back(std::string("robot: ") + e.what());
    }
  }
  const YAML::Node camera = root["camera"];
  d.camera_name = text(camera["name"], "camera.name");
  d.camera_model = text(camera["model"], "camera.model");
  if (!d.camera_model.empty() && d.camera_model.rfind("builtin:", 0) != 0) {
    d.camera_model = (dir / d.camera_model).string();
  }
  if (camera["edge_locator"]) {
    d.edge_locator = camera["edge_locator"].as<std::string>();
    if (d.edge_locator != "step-ramp" && d.edge_locator != "parabola") {
      problems.push_back("camera.edge_locator: '" + d.edge_locator +
                         "' is not step-ramp or parabola");
    }
  }
  if (camera["edge_blur_px"]) {
    try {
      d.edge_blur_px = camera["edge_blur_px"].as<double>();
      if (!(d.edge_blur_px >= 0 && d.edge_blur_px <= 3)) throw std::invalid_argument("range");
    } catch (const std::exception&) {
      problems.push_back("camera.edge_blur_px: expected a number in [0, 3] (px)");
    }
  }
  const YAML::Node hint = camera["pose_hint"];
  try {
    const auto p = hint["position"].as<std::vector<double>>();
    const auto rpy = hint["rpy_deg"].as<std::vector<double>>();
    if (p.size() != 3 || rpy.size() != 3) throw std::invalid_argument("size");
    d.X_BC_hint.translation() = Eigen::Vector3d(p[0], p[1], p[2]);
    d.X_BC_hint.linear() = (Eigen::AngleAxisd(rpy[2] * common::kDeg, Eigen::Vector3d::UnitZ()) *
                            Eigen::AngleAxisd(rpy[1] * common::kDeg, Eigen::Vector3d::UnitY()) *
                            Eigen::AngleAxisd(rpy[0] * common::kDeg, Eigen::Vector3d::UnitX()))
                               .toRotationMatrix();
  } catch (const std::exception&) {
    problems.push_back("camera.pose_hint: expected {position: [x, y, z], rpy_deg: [r, p, y]}");
  }

  const std::string csv_path = (dir / "poses.csv").string();
  std::ifstream csv(csv_path);
  if (!csv) problems.push_back("poses.csv: cannot open " + csv_path);
  std::string line;
  int line_number = 0;
  while (csv && std::getline(csv, line)) {
    ++line_number;
    if (line_number == 1 || line.empty()) continue;  // header
    std::vector<std::string> cells;
    std::stringstream row(line);
    for (std::string cell; std::getline(row, cell, ',');) cells.push_back(cell);
    const std::string where = "poses.csv line " + std::to_string(line_number);
    if (cells.size() != 15) {
      problems.push_back(where + ": expected 15 values, got " + std::to_string(cells.size()));
      continue;
    }
    HexapodDatasetPose pose;
    try {
      size_t used = 0;
      pose.index = std::stoi(cells[0], &used);
      std::array<double, 13> v{};
      for (int i = 0; i < 13; ++i) {
        v[i] = std::stod(cells[2 + i], &used);
        if (used != cells[2 + i].size() || !std::isfinite(v[i])) throw std::invalid_argument("");
      }
      for (int j = 0; j < 6; ++j) pose.s[j] = v[j];
      pose.X_BP_commanded.translation() = Eigen::Vector3d(v[6], v[7], v[8]);
      const Eigen::Quaterniond q(v[9], v[10], v[11], v[12]);
      if (std::abs(q.norm() - 1.0) > 1e-6) {
        problems.push_back(where + ": the quaternion is not unit (norm " + Num(q.norm()) + ")");
        continue;
      }
      pose.X_BP_commanded.linear() = q.normalized().toRotationMatrix();
    } catch (const std::exception&) {
      problems.push_back(where + ": a value is not a finite number");
      continue;
    }
    pose.image = cells[1];
    if (!fs::exists(dir / pose.image)) {
      problems.push_back(where + ": image " + pose.image + " does not exist");
      continue;
    }
    d.poses.push_back(pose);
  }
  if (problems.empty() && d.poses.empty()) problems.push_back("poses.csv: no poses");
  if (!problems.empty()) {
    std::string message = directory + ": ";
    for (size_t i = 0; i < problems.size(); ++i) message += (i ? "; " : "") + problems[i];
    throw std::invalid_argument(message);
  }
  return d;
}

std::vector<uint8_t> ReadDatasetImage(const HexapodDataset& d, const HexapodDatasetPose& pose,
                                      int* width, int* height) {
  const std::string path = (fs::path(d.directory) / pose.image).string();
  const cv::Mat image = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (image.empty()) throw std::invalid_argument(path + ": cannot read the image");
  if (image.type() != CV_8UC1) {
    throw std::invalid_argument(path + ": expected an 8-bit grey image");
  }
  *width = image.cols;
  *height = image.rows;
  std::vector<uint8_t> pixels(static_cast<size_t>(image.cols) * image.rows);
  for (int y = 0; y < image.rows; ++y) {
    std::copy(image.ptr<uint8_t>(y), image.ptr<uint8_t>(y) + image.cols,
              pixels.begin() + static_cast<size_t>(y) * image.cols);
  }
  return pixels;
}

}  // namespace kinevis::calibration
