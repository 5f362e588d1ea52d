#include "calibration/weld_mount/scan_dataset.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>
#include <stdexcept>

#include "calibration/common/csv_internal.h"
#include "calibration/common/yaml_reader_internal.h"
#include "common/units.h"

namespace kinevis::calibration {
namespace {

using internal::ParseDouble;
using internal::SplitCsv;

namespace fs = std::filesystem;
constexpr const char* kKind = "kinevis-scan-dataset";
constexpr const char* kHeader =
    "frame,image,theta1_deg,theta2_deg,pz3_mm,theta4_deg,theta5_deg,commanded_cot_theta_y";

// Joint j to its file unit (deg, or mm for pz3) and back.
double ToFile(int j, double q) { return j == 2 ? 1e3 * q : q / common::kDeg; }
double FromFile(int j, double v) { return j == 2 ? 1e-3 * v : v * common::kDeg; }

}  // namespace

void CreateScanDataset(ScanDataset* dataset) {
  const fs::path dir(dataset->directory);
  if (fs::exists(dir / "scan.yaml")) {
    throw std::invalid_argument("scan dataset " + dataset->directory +
                                ": already holds a dataset (scan.yaml)");
  }
  std::error_code error;
  fs::create_directories(dir / "images", error);
  if (error) {
    throw std::runtime_error("cannot create " + dataset->directory + ": " + error.message());
  }
  if (dataset->created.empty()) dataset->created = internal::NowUtc();
  YAML::Emitter out;
  out << YAML::BeginMap;
  out << YAML::Key << "kind" << YAML::Value << kKind;
  out << YAML::Key << "version" << YAML::Value << 1;
  out << YAML::Key << "camera" << YAML::Value << dataset->camera_model;
  out << YAML::Key << "source" << YAML::Value << dataset->source;
  out << YAML::Key << "created" << YAML::Value << dataset->created;
  out << YAML::EndMap;
  std::ofstream yaml(dir / "scan.yaml");
  yaml << "# kinevis scan dataset; docs/point-clouds.md\n" << out.c_str() << "\n";
  std::ofstream csv(dir / "frames.csv");
  csv << kHeader << "\n";
  if (!yaml || !csv) throw std::runtime_error("cannot write " + dataset->directory);
  dataset->frames.clear();
}

void AppendScanFrame(ScanDataset* dataset, ScanDatasetFrame frame, const uint8_t* pixels, int width,
                     int height, size_t stride) {
  if (!frame.q.allFinite()) {
    throw std::invalid_argument("scan dataset " + dataset->directory + ": frame " +
                                std::to_string(dataset->frames.size()) +
                                ": joint readings are not finite");
  }
  const fs::path dir(dataset->directory);
  char name[32];
  std::snprintf(name, sizeof(name), "images/frame_%04zu.png", dataset->frames.size());
  frame.image = name;
  const cv::Mat image(height, width, CV_8UC1, const_cast<uint8_t*>(pixels), stride);
  const std::string image_path = (dir / frame.image).string();
  if (!cv::imwrite(image_path, image)) throw std::runtime_error("cannot write " + image_path);
  std::ofstream csv(dir / "frames.csv", std::ios::app);
  csv.precision(12);
  csv << dataset->frames.size() << "," << frame.image;
  for (int j = 0; j < robots::kWeld5Joints; ++j) csv << "," << ToFile(j, frame.q(j));
  csv << ",";
  if (std::isfinite(frame.commanded_cot_theta_y)) csv << frame.commanded_cot_theta_y;
  csv << "\n";
  csv.flush();
  if (!csv) throw std::runtime_error("cannot append to " + (dir / "frames.csv").string());
  dataset->frames.push_back(frame);
}

ScanDataset ReadScanDataset(const std::string& directory) {
  const fs::path dir(directory);
  const std::string yaml_path = (dir / "scan.yaml").string();
  if (!fs::exists(yaml_path)) {
    throw std::invalid_argument("scan dataset " + directory + ": no scan.yaml (not a dataset)");
  }
  YAML::Node root;
  try {
    root = YAML::LoadFile(yaml_path);
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument("scan dataset " + yaml_path + ": " + e.what());
  }
  internal::CheckedYamlReader r("scan dataset", yaml_path);
  ScanDataset d;
  d.directory = directory;
  if (r.String(root, "kind", "kind") != kKind) r.Bad("kind", std::string("must be ") + kKind);
  r.Int(root, "version", "version", 1);
  if (root["version"] && root["version"].Scalar() != "1") r.Bad("version", "must be 1");
  d.camera_model = r.String(root, "camera", "camera");
  if (!d.camera_model.empty() && d.camera_model.rfind("builtin:", 0) != 0 &&
      fs::path(d.camera_model).is_relative()) {
    d.camera_model = (dir / d.camera_model).string();
  }
  d.source = root["source"] ? root["source"].as<std::string>("") : "";
  d.created = root["created"] ? root["created"].as<std::string>("") : "";

  const std::string csv_path = (dir / "frames.csv").string();
  std::ifstream csv(csv_path);
  std::string line;
  if (!csv || !std::getline(csv, line) || line != kHeader) {
    r.Bad(csv_path, "missing or without the header \"" + std::string(kHeader) + "\"");
  } else {
    for (int number = 2; std::getline(csv, line); ++number) {
      if (line.empty()) continue;
      const std::string where = "frames.csv line " + std::to_string(number);
      const std::vector<std::string> f = SplitCsv(line);
      if (f.size() != 8) {
        r.Bad(where, std::to_string(f.size()) + " fields, expected 8");
        continue;
      }
      ScanDatasetFrame frame;
      frame.image = f[1];
      for (int j = 0; j < robots::kWeld5Joints; ++j) {
        double v = 0.0;
        if (!ParseDouble(f[static_cast<size_t>(2 + j)], &v)) {
          r.Bad(where, std::string(robots::Weld5JointName(j)) + " is not a number (\"" +
                           f[static_cast<size_t>(2 + j)] + "\")");
        }
        frame.q(j) = FromFile(j, v);
      }
      if (!f[7].empty() && !ParseDouble(f[7], &frame.commanded_cot_theta_y)) {
        r.Bad(where, "commanded_cot_theta_y is not a number (\"" + f[7] + "\")");
      }
      if (!fs::exists(dir / frame.image)) r.Bad(where, "image " + frame.image + " does not exist");
      d.frames.push_back(frame);
    }
    if (d.frames.empty()) r.Bad(csv_path, "no frames");
  }
  r.ThrowIfBad();
  return d;
}

std::vector<uint8_t> ReadScanFrameImage(const ScanDataset& dataset, const ScanDatasetFrame& frame,
                                        int width, int height) {
  const std::string path = (fs::path(dataset.directory) / frame.image).string();
  const cv::Mat image = cv::imread(path, cv::IMREAD_GRAYSCALE);
  if (image.empty()) throw std::invalid_argument("scan dataset: cannot read image " + path);
  if (image.cols != width || image.rows != height) {
    throw std::invalid_argument("scan dataset: image " + path + " is " +
                                std::to_string(image.cols) + " x " + std::to_string(image.rows) +
                                " px, the scanner camera is " + std::to_string(width) + " x " +
                                std::to_string(height));
  }
  std::vector<uint8_t> pixels(static_cast<size_t>(width) * height);
  for (int v = 0; v < height; ++v) {
    const uint8_t* row = image.ptr<uint8_t>(v);
    std::copy(row, row + width, pixels.begin() + static_cast<std::ptrdiff_t>(v) * width);
  }
  return pixels;
}

}  // namespace kinevis::calibration
