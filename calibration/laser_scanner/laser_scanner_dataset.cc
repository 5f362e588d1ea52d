#include "calibration/laser_scanner/laser_scanner_dataset.h"

#include <yaml-cpp/yaml.h>

#include <ctime>
#include <filesystem>
#include <fstream>
#include <map>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>
#include <stdexcept>

#include "calibration/common/csv_internal.h"
#include "calibration/common/yaml_reader_internal.h"

namespace kinevis::calibration {
namespace {

using internal::ParseDouble;
using internal::ParseInt;
using internal::SplitCsv;

namespace fs = std::filesystem;
constexpr const char* kKind = "kinevis-laser-scanner-dataset";
constexpr const char* kHeader = "image,board_pose,lasers,rotating_step,stripes";

using internal::NowUtc;

}  // namespace

void CreateLaserScannerDataset(LaserScannerDataset* dataset) {
  const fs::path dir(dataset->directory);
  if (fs::exists(dir / "dataset.yaml")) {
    throw std::invalid_argument("laser scanner dataset " + dataset->directory +
                                ": already holds a dataset (dataset.yaml)");
  }
  std::error_code error;
  fs::create_directories(dir / "images", error);
  fs::create_directories(dir / "stripes", error);
  if (error)
    throw std::runtime_error("cannot create " + dataset->directory + ": " + error.message());
  if (dataset->created.empty()) dataset->created = NowUtc();
  YAML::Emitter out;
  out.SetDoublePrecision(12);
  out << YAML::BeginMap;
  out << YAML::Key << "kind" << YAML::Value << kKind;
  out << YAML::Key << "version" << YAML::Value << 1;
  out << YAML::Key << "camera" << YAML::Value << dataset->camera_model;
  out << YAML::Key << "camera_name" << YAML::Value << dataset->camera_name;
  out << YAML::Key << "board" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "rows" << YAML::Value << dataset->board.rows;
  out << YAML::Key << "cols" << YAML::Value << dataset->board.cols;
  out << YAML::Key << "pitch_mm" << YAML::Value << 1e3 * dataset->board.pitch;
  out << YAML::Key << "dot_diameter_mm" << YAML::Value << 2e3 * dataset->board.dot_radius;
  out << YAML::EndMap;
  out << YAML::Key << "source" << YAML::Value << dataset->source;
  out << YAML::Key << "created" << YAML::Value << dataset->created;
  out << YAML::EndMap;
  std::ofstream yaml(dir / "dataset.yaml");
  yaml << "# kinevis laser scanner calibration dataset; docs/laser-scanner-calibration.md\n"
       << out.c_str() << "\n";
  std::ofstream csv(dir / "images.csv");
  csv << kHeader << "\n";
  if (!yaml || !csv) throw std::runtime_error("cannot write " + dataset->directory);
  dataset->images.clear();
}

void AppendLaserScannerDatasetImage(LaserScannerDataset* dataset, LaserScannerDatasetImage entry,
                                    const uint8_t* pixels, int width, int height, size_t stride,
                                    const std::vector<Eigen::Vector2d>* fixed,
                                    const std::vector<Eigen::Vector2d>* rotating) {
  const fs::path dir(dataset->directory);
  const cv::Mat image(height, width, CV_8UC1, const_cast<uint8_t*>(pixels), stride);
  const std::string image_path = (dir / entry.image).string();
  if (!cv::imwrite(image_path, image)) throw std::runtime_error("cannot write " + image_path);
  if (fixed != nullptr || rotating != nullptr) {
    entry.stripes = "stripes/" + fs::path(entry.image).stem().string() + ".csv";
    std::ofstream csv(dir / entry.stripes);
    csv.precision(10);
    csv << "laser,u_px,v_px\n";
    for (const auto& [name, list] :
         {std::make_pair("fixed", fixed), std::make_pair("rotating", rotating)}) {
      if (list == nullptr) continue;
      for (const Eigen::Vector2d& p : *list) csv << name << "," << p.x() << "," << p.y() << "\n";
    }
    if (!csv) throw std::runtime_error("cannot write " + (dir / entry.stripes).string());
  }
  std::ofstream csv(dir / "images.csv", std::ios::app);
  csv << entry.image << "," << entry.board_pose << "," << (entry.lasers_on ? "on" : "off") << ","
      << entry.rotating_step << "," << entry.stripes << "\n";
  csv.flush();
  if (!csv) throw std::runtime_error("cannot append to " + (dir / "images.csv").string());
  dataset->images.push_back(entry);
}

LaserScannerDataset ReadLaserScannerDataset(const std::string& directory) {
  const fs::path dir(directory);
  const std::string yaml_path = (dir / "dataset.yaml").string();
  YAML::Node root;
  try {
    root = YAML::LoadFile(yaml_path);
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument("laser scanner dataset " + yaml_path + ": " + e.what());
  }
  std::string problems;
  auto bad = [&problems](const std::string& what) {
    problems += (problems.empty() ? "" : "; ") + what;
  };
  LaserScannerDataset d;
  d.directory = directory;
  auto scalar = [&](const YAML::Node& node, const char* key, const std::string& name) {
    if (!node[key] || !node[key].IsScalar()) {
      bad(name + ": missing");
      return std::string();
    }
    return node[key].Scalar();
  };
  if (scalar(root, "kind", "kind") != kKind) bad("kind: must be " + std::string(kKind));
  if (scalar(root, "version", "version") != "1") bad("version: must be 1");
  d.camera_model = scalar(root, "camera", "camera");
  // A relative camera file lives in the dataset directory.
  if (!d.camera_model.empty() && d.camera_model.rfind("builtin:", 0) != 0 &&
      fs::path(d.camera_model).is_relative()) {
    d.camera_model = (dir / d.camera_model).string();
  }
  d.camera_name = root["camera_name"] ? root["camera_name"].as<std::string>("") : "";
  d.source = root["source"] ? root["source"].as<std::string>("") : "";
  d.created = root["created"] ? root["created"].as<std::string>("") : "";
  const YAML::Node board = root["board"];
  if (!board || !board.IsMap()) {
    bad("board: missing");
  } else {
    int value = 0;
    double x = 0.0;
    if (ParseInt(scalar(board, "rows", "board.rows"), &value))
      d.board.rows = value;
    else
      bad("board.rows: not an integer");
    if (ParseInt(scalar(board, "cols", "board.cols"), &value))
      d.board.cols = value;
    else
      bad("board.cols: not an integer");
    if (ParseDouble(scalar(board, "pitch_mm", "board.pitch_mm"), &x))
      d.board.pitch = 1e-3 * x;
    else
      bad("board.pitch_mm: not a number");
    if (ParseDouble(scalar(board, "dot_diameter_mm", "board.dot_diameter_mm"), &x)) {
      d.board.dot_radius = 0.5e-3 * x;
    } else {
      bad("board.dot_diameter_mm: not a number");
    }
    const std::string grid = d.board.Validate("board.");
    if (!grid.empty()) bad(grid);
  }
  const std::string csv_path = (dir / "images.csv").string();
  std::ifstream csv(csv_path);
  std::string line;
  if (!csv || !std::getline(csv, line) || line != kHeader) {
    bad(csv_path + ": missing or without the header \"" + std::string(kHeader) + "\"");
  } else {
    for (int number = 2; std::getline(csv, line); ++number) {
      if (line.empty()) continue;
      const std::vector<std::string> f = SplitCsv(line);
      const std::string where = csv_path + " line " + std::to_string(number);
      LaserScannerDatasetImage e;
      if (f.size() != 5) {
        bad(where + ": " + std::to_string(f.size()) + " fields, expected 5");
        continue;
      }
      e.image = f[0];
      if (!ParseInt(f[1], &e.board_pose) || e.board_pose < 0) {
        bad(where + ": board_pose '" + f[1] + "' is not an integer >= 0");
      }
      if (f[2] != "on" && f[2] != "off") bad(where + ": lasers '" + f[2] + "' (on | off)");
      e.lasers_on = f[2] == "on";
      if (!ParseInt(f[3], &e.rotating_step)) {
        bad(where + ": rotating_step '" + f[3] + "' is not an integer");
      }
      e.stripes = f[4];
      if (!fs::exists(dir / e.image)) bad(where + ": image " + e.image + " does not exist");
      if (!e.stripes.empty() && !fs::exists(dir / e.stripes)) {
        bad(where + ": stripes " + e.stripes + " does not exist");
      }
      d.images.push_back(e);
    }
  }
  if (!problems.empty()) {
    throw std::invalid_argument("laser scanner dataset " + directory + ": " + problems);
  }
  return d;
}

std::vector<uint8_t> ReadLaserScannerDatasetImage(const LaserScannerDataset& dataset,
                                                  const LaserScannerDatasetImage& entry, int* width,
                                                  int* height) {
  const std::string path = (fs::path(dataset.directory) / entry.image).string();
  const cv::Mat image = cv::imread(path, cv::IMREAD_GRAYSCALE);
  if (image.empty()) throw std::invalid_argument("laser scanner dataset: cannot read " + path);
  *width = image.cols;
  *height = image.rows;
  std::vector<uint8_t> out(static_cast<size_t>(image.cols) * image.rows);
  for (int v = 0; v < image.rows; ++v) {
    std::copy(image.ptr<uint8_t>(v), image.ptr<uint8_t>(v) + image.cols,
              out.begin() + static_cast<size_t>(v) * image.cols);
  }
  return out;
}

void ReadLaserScannerDatasetStripes(const LaserScannerDataset& dataset,
                                    const LaserScannerDatasetImage& entry,
                                    std::vector<Eigen::Vector2d>* fixed,
                                    std::vector<Eigen::Vector2d>* rotating) {
  const std::string path = (fs::path(dataset.directory) / entry.stripes).string();
  std::ifstream csv(path);
  std::string line;
  if (entry.stripes.empty() || !csv || !std::getline(csv, line) || line != "laser,u_px,v_px") {
    throw std::invalid_argument("laser scanner dataset: " + path +
                                ": missing or without the header \"laser,u_px,v_px\"");
  }
  fixed->clear();
  rotating->clear();
  for (int number = 2; std::getline(csv, line); ++number) {
    if (line.empty()) continue;
    const std::vector<std::string> f = SplitCsv(line);
    Eigen::Vector2d p;
    if (f.size() != 3 || (f[0] != "fixed" && f[0] != "rotating") || !ParseDouble(f[1], &p.x()) ||
        !ParseDouble(f[2], &p.y())) {
      throw std::invalid_argument("laser scanner dataset: " + path + " line " +
                                  std::to_string(number) + ": '" + line +
                                  "' (expected fixed|rotating,u_px,v_px)");
    }
    (f[0] == "fixed" ? fixed : rotating)->push_back(p);
  }
}

LaserScannerDatasetCalibration CalibrateLaserScannerDataset(
    const LaserScannerDataset& dataset, const vision::CameraModel& camera,
    const StripeExtractor& extractor, const LaserScannerCalibrationOptions& options,
    const BoardPoseOptions& board_options) {
  std::map<int, std::vector<const LaserScannerDatasetImage*>> off, on;
  for (const LaserScannerDatasetImage& e : dataset.images) {
    (e.lasers_on ? on : off)[e.board_pose].push_back(&e);
    if (e.lasers_on && e.stripes.empty() && !extractor) {
      throw std::invalid_argument("laser scanner dataset " + dataset.directory + ": image " +
                                  e.image +
                                  " has no stripe file and no stripe extractor was given");
    }
  }
  for (const auto& [pose, list] : on) {
    if (off[pose].size() != 1) {
      throw std::invalid_argument("laser scanner dataset " + dataset.directory + ": board pose " +
                                  std::to_string(pose) + " has " +
                                  std::to_string(off[pose].size()) +
                                  " lasers-off images (exactly 1 needed for its pose)");
    }
  }
  LaserScannerDatasetCalibration out;
  std::vector<LaserCalibrationImage> images;
  for (const auto& [pose, list] : on) {
    int width = 0, height = 0;
    std::vector<uint8_t> pixels =
        ReadLaserScannerDatasetImage(dataset, *off[pose][0], &width, &height);
    const vision::ImageView8 view{pixels.data(), width, height, static_cast<size_t>(width)};
    const BoardPose board = EstimateBoardPose(view, camera, dataset.board, board_options);
    if (!board.ok()) {
      out.skipped.push_back("board pose " + std::to_string(pose) + " (" + off[pose][0]->image +
                            "): " + std::string(ToString(board.status)) + ": " + board.message);
      continue;
    }
    out.board_pose_ids.push_back(pose);
    out.board_poses.push_back(board);
    for (const LaserScannerDatasetImage* e : list) {
      LaserCalibrationImage image;
      image.name = e->image;
      image.X_CS = board.X_CS;
      image.rotating_step = e->rotating_step;
      if (extractor) {
        std::vector<uint8_t> stripe_pixels =
            ReadLaserScannerDatasetImage(dataset, *e, &width, &height);
        const vision::ImageView8 stripe_view{stripe_pixels.data(), width, height,
                                             static_cast<size_t>(width)};
        extractor(stripe_view, &image.fixed_pixels, &image.rotating_pixels);
      } else {
        ReadLaserScannerDatasetStripes(dataset, *e, &image.fixed_pixels, &image.rotating_pixels);
      }
      images.push_back(std::move(image));
    }
  }
  if (images.empty()) {
    out.calibration.errors.push_back("no board pose was found in the dataset's images");
    return out;
  }
  out.calibration = CalibrateLaserScanner(images, camera, options);
  for (const std::string& s : out.skipped) out.calibration.warnings.push_back(s);
  return out;
}

}  // namespace kinevis::calibration
