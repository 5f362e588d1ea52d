// kinevis calibrate ...: calibration routines.
//   calibrate camera: chessboard calibration of a pinhole + Brown camera
//   (docs/camera-calibration.md)

#include <glob.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <regex>
#include <set>
#include <stdexcept>
#include <string>
#include <system_error>
#include <vector>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "calibration/camera/chessboard_calibration.h"
#include "hal/common/error.h"
#include "vision/camera/camera_info_yaml.h"

namespace kinevis::cli {
namespace {

constexpr double kRadToDeg = 180.0 / 3.14159265358979323846;

struct CalibrateCameraOptions {
  std::vector<std::string> images;  // glob patterns or files
  std::string board;                // "COLSxROWS"
  double square_m = 0.0;
  std::string out = "intrinsics.yaml";
  std::string overlay_dir;
  std::string camera_name = "camera";
  bool rational = false;
  int min_images = 3;
  bool json = false;
};

// Files matching the patterns (each expanded and sorted by glob(3)), directories left out,
// duplicates dropped, in pattern order. A pattern that matches nothing is a usage error.
std::vector<std::string> ExpandImages(const std::vector<std::string>& patterns) {
  std::vector<std::string> files;
  std::set<std::string> seen;
  common::Problems problems("--images");
  for (const std::string& pattern : patterns) {
    glob_t g{};
    const int rc = ::glob(pattern.c_str(), GLOB_MARK, nullptr, &g);
    int matched = 0;
    if (rc == 0) {
      for (size_t i = 0; i < g.gl_pathc; ++i) {
        const std::string path = g.gl_pathv[i];
        if (!path.empty() && path.back() == '/') continue;  // a directory
        ++matched;
        if (seen.insert(path).second) files.push_back(path);
      }
    }
    globfree(&g);
    if (matched == 0) problems.Add("\"" + pattern + "\" matches no file");
  }
  problems.ThrowIfAny();
  return files;
}

calibration::ChessboardCalibrationOptions ToOptions(const CalibrateCameraOptions& o) {
  calibration::ChessboardCalibrationOptions options;
  std::smatch m;
  static const std::regex kBoard(R"(^\s*(\d+)\s*[xX]\s*(\d+)\s*$)");
  if (!std::regex_match(o.board, m, kBoard)) {
    throw common::ConfigError(
        "--board \"" + o.board +
        "\": expected COLSxROWS, the inner corners of the chessboard, e.g. 9x6");
  }
  options.board_cols = std::stoi(m[1]);
  options.board_rows = std::stoi(m[2]);
  options.square_m = o.square_m;
  options.min_images = o.min_images;
  if (o.rational) {
    options.rational_model = true;
    options.fix_k3 = false;
  }
  const std::string problems = options.Validate();
  if (!problems.empty()) throw common::ConfigError(problems);
  return options;
}

std::string OverlayPath(const std::string& dir, const std::string& image,
                        std::set<std::string>* used) {
  const std::string stem = std::filesystem::path(image).stem().string();
  std::string name = stem + "_overlay.png";
  for (int k = 2; !used->insert(name).second; ++k) {
    name = stem + "_" + std::to_string(k) + "_overlay.png";
  }
  return (std::filesystem::path(dir) / name).string();
}

vision::IntrinsicsFileExtras Extras(const calibration::ChessboardCalibrationResult& r,
                                    const calibration::ChessboardCalibrationOptions& options,
                                    const std::string& camera_name) {
  vision::IntrinsicsFileExtras e;
  e.camera_name = camera_name;
  e.strings = {{"calibration_tool", "kinevis calibrate camera"}};
  e.numbers = {{"board_cols", options.board_cols}, {"board_rows", options.board_rows},
               {"square_m", options.square_m},     {"rms_px", r.rms_px},
               {"coverage", r.coverage},           {"max_tilt_deg", r.max_tilt_rad * kRadToDeg}};
  const int n_distortion = options.rational_model ? 8 : 5;
  e.number_lists.push_back(
      {"camera_matrix_std", {r.stddev.fx, r.stddev.fy, r.stddev.cx, r.stddev.cy}});
  e.number_lists.push_back({"distortion_coefficients_std",
                            std::vector<double>(r.stddev.distortion.begin(),
                                                r.stddev.distortion.begin() + n_distortion)});
  std::vector<std::string> used, refused;
  std::vector<double> rms, max;
  for (const calibration::ImageReport& image : r.images) {
    if (image.status == calibration::ImageStatus::kUsed) {
      used.push_back(image.name);
      rms.push_back(image.rms_px);
      max.push_back(image.max_px);
    } else {
      refused.push_back(image.name + ": " + image.reason);
    }
  }
  e.string_lists = {{"images", used}, {"refused_images", refused}, {"warnings", r.warnings}};
  e.number_lists.push_back({"per_image_rms_px", rms});
  e.number_lists.push_back({"per_image_max_px", max});
  return e;
}

void PrintTable(const calibration::ChessboardCalibrationResult& r) {
  size_t width = 5;
  for (const auto& image : r.images) width = std::max(width, image.name.size());
  std::printf("%-*s  %-16s %8s %8s %9s\n", static_cast<int>(width), "image", "status", "rms_px",
              "max_px", "tilt_deg");
  for (const auto& image : r.images) {
    if (image.status == calibration::ImageStatus::kUsed && r.calibrated) {
      std::printf("%-*s  %-16s %8.4f %8.4f %9.1f\n", static_cast<int>(width), image.name.c_str(),
                  ToString(image.status), image.rms_px, image.max_px, image.tilt_rad * kRadToDeg);
    } else {
      std::printf(
          "%-*s  %-16s %8s %8s %9s\n", static_cast<int>(width), image.name.c_str(),
          image.status == calibration::ImageStatus::kUsed ? "board found" : ToString(image.status),
          "-", "-", "-");
    }
  }
}

void PrintResult(const calibration::ChessboardCalibrationResult& r, bool rational) {
  const vision::PinholeBrownParameters& p = r.parameters;
  std::printf(
      "\ncalibrated from %d of %zu images: RMS %.4f px, coverage %.0f %%, largest tilt "
      "%.1f deg\n",
      r.used_images, r.images.size(), r.rms_px, 100 * r.coverage, r.max_tilt_rad * kRadToDeg);
  std::printf("image size  %d x %d px\n", p.width, p.height);
  std::printf("fx = %.4f +- %.4f px\nfy = %.4f +- %.4f px\n", p.fx, r.stddev.fx, p.fy, r.stddev.fy);
  std::printf("cx = %.4f +- %.4f px\ncy = %.4f +- %.4f px\n", p.cx, r.stddev.cx, p.cy, r.stddev.cy);
  static const char* const kNames[8] = {"k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"};
  std::printf("distortion (%s):\n", rational ? "rational_polynomial" : "plumb_bob");
  for (int i = 0; i < (rational ? 8 : 5); ++i) {
    std::printf("  %s = %+.6g +- %.2g\n", kNames[i], p.distortion[i], r.stddev.distortion[i]);
  }
  std::printf("estimation: %s\n", r.estimation.BriefReport().c_str());
  for (const std::string& w : r.warnings) std::printf("warning: %s\n", w.c_str());
}

nlohmann::json ToJson(const calibration::ChessboardCalibrationResult& r, bool rational,
                      const std::string& intrinsics_path,
                      const std::vector<std::string>& overlays) {
  nlohmann::json images = nlohmann::json::array();
  for (const auto& image : r.images) {
    nlohmann::json j = {{"name", image.name}, {"status", ToString(image.status)}};
    if (image.status == calibration::ImageStatus::kUsed && r.calibrated) {
      j["rms_px"] = image.rms_px;
      j["max_px"] = image.max_px;
      j["tilt_deg"] = image.tilt_rad * kRadToDeg;
    } else if (!image.reason.empty()) {
      j["reason"] = image.reason;
    }
    images.push_back(j);
  }
  nlohmann::json out = {{"calibrated", r.calibrated},
                        {"used_images", r.used_images},
                        {"images", images},
                        {"warnings", r.warnings}};
  if (!r.calibrated) {
    out["message"] = r.message;
    return out;
  }
  const vision::PinholeBrownParameters& p = r.parameters;
  const int n = rational ? 8 : 5;
  out["rms_px"] = r.rms_px;
  out["coverage"] = r.coverage;
  out["max_tilt_deg"] = r.max_tilt_rad * kRadToDeg;
  out["intrinsics"] = {
      {"width", p.width},
      {"height", p.height},
      {"fx", p.fx},
      {"fy", p.fy},
      {"cx", p.cx},
      {"cy", p.cy},
      {"distortion_model", rational ? "rational_polynomial" : "plumb_bob"},
      {"distortion", std::vector<double>(p.distortion.begin(), p.distortion.begin() + n)}};
  out["stddev"] = {{"fx", r.stddev.fx},
                   {"fy", r.stddev.fy},
                   {"cx", r.stddev.cx},
                   {"cy", r.stddev.cy},
                   {"distortion", std::vector<double>(r.stddev.distortion.begin(),
                                                      r.stddev.distortion.begin() + n)}};
  out["files"] = {{"intrinsics", intrinsics_path}, {"overlays", overlays}};
  return out;
}

int RunCalibrateCamera(const CalibrateCameraOptions& o) {
  const calibration::ChessboardCalibrationOptions options = ToOptions(o);
  const std::vector<std::string> files = ExpandImages(o.images);
  if (!o.overlay_dir.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(o.overlay_dir, ec);
    if (ec || !std::filesystem::is_directory(o.overlay_dir)) {
      throw common::ConfigError("--overlay-dir: cannot create the directory \"" + o.overlay_dir +
                                "\"" + (ec ? ": " + ec.message() : ""));
    }
  }
  spdlog::info("calibrate camera: {} images, board {}x{} inner corners, squares {} m", files.size(),
               options.board_cols, options.board_rows, options.square_m);

  const calibration::ChessboardCalibrationResult r =
      calibration::CalibrateChessboardFiles(files, options);
  for (const auto& image : r.images) {
    if (image.status != calibration::ImageStatus::kUsed) {
      spdlog::warn("refused {}: {}", image.name, image.reason);
    }
  }
  if (!r.calibrated) {
    if (o.json) {
      std::cout << ToJson(r, options.rational_model, "", {}).dump(2) << "\n";
    } else {
      PrintTable(r);
    }
    throw std::runtime_error(r.message);
  }
  for (const std::string& w : r.warnings) spdlog::warn("{}", w);

  vision::WritePinholeIntrinsics(o.out, r.parameters, Extras(r, options, o.camera_name));
  std::vector<std::string> overlays;
  if (!o.overlay_dir.empty()) {
    std::set<std::string> names;
    for (const auto& image : r.images) {
      if (image.status != calibration::ImageStatus::kUsed) continue;
      const std::string path = OverlayPath(o.overlay_dir, image.name, &names);
      calibration::WriteOverlayPng(calibration::LoadCalibrationImage(image.name), image, path);
      overlays.push_back(path);
    }
  }

  if (o.json) {
    std::cout << ToJson(r, options.rational_model, o.out, overlays).dump(2) << "\n";
    return kExitOk;
  }
  PrintTable(r);
  PrintResult(r, options.rational_model);
  std::printf("\nwrote %s\n", o.out.c_str());
  if (!overlays.empty()) {
    std::printf("wrote %zu overlays in %s\n", overlays.size(), o.overlay_dir.c_str());
  }
  return kExitOk;
}

}  // namespace

void AddCalibrateCommands(const Parents& parents, CommandList* commands) {
  CLI::App* calibrate = parents.calibrate;

  auto o = std::make_shared<CalibrateCameraOptions>();
  CLI::App* camera = calibrate->add_subcommand(
      "camera",
      "Chessboard calibration of a pinhole + Brown camera (OpenCV): detects the board in every "
      "image, refuses (and names) images where it is not found, estimates the intrinsics and "
      "prints a per-image table of reprojection errors and the result with standard deviations");
  camera
      ->add_option("--images", o->images,
                   "Images: one or more files or quoted glob patterns, e.g. 'calib/*.png'")
      ->required();
  camera->add_option("--board", o->board, "Inner corners of the chessboard, COLSxROWS, e.g. 9x6")
      ->required();
  camera->add_option("--square", o->square_m, "Side of one square, metres, e.g. 0.025")
      ->required()
      ->check(CLI::PositiveNumber);
  camera
      ->add_option("--out", o->out,
                   "Intrinsics file to write: ROS camera_info YAML (OpenCV-readable) with the "
                   "per-image reprojection errors and standard deviations as extra keys")
      ->capture_default_str();
  camera->add_option("--overlay-dir", o->overlay_dir,
                     "Write DIR/<image>_overlay.png for every used image: detected corners (green "
                     "circles) and reprojected corners (red crosses); the directory is created");
  camera->add_option("--camera-name", o->camera_name, "camera_name written to the file")
      ->capture_default_str();
  camera->add_flag("--rational", o->rational,
                   "Rational distortion model (k1..k6, rational_polynomial) instead of plumb_bob "
                   "with k3 = 0, for wide-angle lenses");
  camera->add_option("--min-images", o->min_images, "Fewest usable images to calibrate from")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  camera->add_flag("--json", o->json, "Print one JSON object instead of the table");
  camera->footer(
      "Writes the intrinsics YAML (--out) and, with --overlay-dir, one overlay PNG per used "
      "image. Exit code 1 when fewer than --min-images images show the board (the message names "
      "them), 2 for a bad option or a pattern that matches no file.");
  commands->push_back({camera, [o] { return RunCalibrateCamera(*o); }});
}

}  // namespace kinevis::cli
