#include "calibration/laser_scanner/laser_scanner_calibration_io.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <ctime>
#include <fstream>
#include <limits>
#include <stdexcept>

#include "calibration/common/estimation_yaml_internal.h"
#include "calibration/common/yaml_reader_internal.h"
#include "common/units.h"

namespace kinevis::calibration {
namespace {

constexpr const char* kKind = "kinevis-laser-scanner-calibration";
// 2: the estimator contract's `estimation:` block; version 1 files (without it) are read, their
// report rebuilt from the planes' values and covariances.
constexpr int kVersion = 2;

using internal::NowUtc;

double Correlation(const Eigen::Matrix2d& c) {
  const double d = std::sqrt(c(0, 0) * c(1, 1));
  return d > 0.0 ? c(0, 1) / d : 0.0;
}

// A version 1 file's report: the four plane parameters with their covariances (the per-position
// cot θ_y and the identifiability analysis were not stored).
EstimationReport VersionOneEstimation(const LaserScannerCalibration& r) {
  EstimationReport e;
  e.estimator = "laser scanner planes (seed 004)";
  e.message = "read from a version 1 file (before the estimator contract)";
  e.iterations = r.iterations;
  const struct {
    const char* name;
    const char* unit;
    double value;
    bool calibrated;
  } rows[] = {{"b_y", "m", r.geometry.rotating_b_y, r.rotating_calibrated},
              {"d_y", "m", r.geometry.rotating_d_y, r.rotating_calibrated},
              {"b_x_prime", "m", r.geometry.fixed_b_x_prime, r.fixed_calibrated},
              {"cot_theta_x", "1", r.geometry.fixed_cot_theta_x, r.fixed_calibrated}};
  e.covariance = Eigen::Matrix4d::Zero();
  e.covariance.topLeftCorner<2, 2>() = r.rotating_covariance;
  e.covariance.bottomRightCorner<2, 2>() = r.fixed_covariance;
  int identified = 0;
  for (int i = 0; i < 4; ++i) {
    ParameterEstimate p;
    p.name = rows[i].name;
    p.unit = rows[i].unit;
    p.value = rows[i].value;
    p.estimated = true;
    p.identified = rows[i].calibrated;
    p.sigma = p.identified ? std::sqrt(std::max(0.0, e.covariance(i, i)))
                           : std::numeric_limits<double>::infinity();
    if (!p.identified) e.covariance(i, i) = std::numeric_limits<double>::infinity();
    identified += p.identified ? 1 : 0;
    e.parameters.push_back(p);
  }
  e.identifiability.parameters = 4;
  e.identifiability.rank = identified;
  e.status = identified == 4   ? EstimationStatus::kConverged
             : identified == 0 ? EstimationStatus::kInsufficientData
                               : EstimationStatus::kUnidentified;
  if (r.rotating_points > 0) {
    e.residuals.push_back({"rotating plane distance", "m", r.rotating_points,
                           std::numeric_limits<double>::quiet_NaN(), r.rotating_residual_rms,
                           r.rotating_residual_max});
  }
  if (r.fixed_points > 0) {
    e.residuals.push_back({"fixed plane distance", "m", r.fixed_points,
                           std::numeric_limits<double>::quiet_NaN(), r.fixed_residual_rms,
                           r.fixed_residual_max});
  }
  e.warnings = r.warnings;
  return e;
}

class Reader : public internal::CheckedYamlReader {
 public:
  explicit Reader(std::string path)
      : CheckedYamlReader("laser scanner calibration file", std::move(path)) {}
};

}  // namespace

void WriteLaserScannerCalibration(const std::string& path, const LaserScannerCalibration& r,
                                  const LaserScannerCalibrationMetadata& metadata) {
  YAML::Emitter out;
  out.SetDoublePrecision(12);
  out << YAML::BeginMap;
  out << YAML::Key << "kind" << YAML::Value << kKind;
  out << YAML::Key << "version" << YAML::Value << kVersion;
  out << YAML::Key << "camera" << YAML::Value << metadata.camera;
  out << YAML::Key << "camera_name" << YAML::Value << metadata.camera_name;
  out << YAML::Key << "created" << YAML::Value
      << (metadata.created.empty() ? NowUtc() : metadata.created);
  out << YAML::Key << "source" << YAML::Value << metadata.source;
  out << YAML::Key << "ok" << YAML::Value << r.ok();
  out << YAML::Key << "images" << YAML::Value << r.images;
  out << YAML::Key << "unusable_pixels" << YAML::Value << r.unusable_pixels;

  out << YAML::Key << "rotating_laser" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "calibrated" << YAML::Value << r.rotating_calibrated;
  out << YAML::Key << "b_y_mm" << YAML::Value << common::kMmPerM * r.geometry.rotating_b_y;
  out << YAML::Key << "b_y_sigma_mm" << YAML::Value << common::kMmPerM * r.b_y_sigma();
  out << YAML::Key << "d_y_mm" << YAML::Value << common::kMmPerM * r.geometry.rotating_d_y;
  out << YAML::Key << "d_y_sigma_mm" << YAML::Value << common::kMmPerM * r.d_y_sigma();
  out << YAML::Key << "b_y_d_y_correlation" << YAML::Value << Correlation(r.rotating_covariance);
  out << YAML::Key << "separation_condition" << YAML::Value << r.separation_condition;
  out << YAML::Key << "points" << YAML::Value << r.rotating_points;
  out << YAML::Key << "outliers" << YAML::Value << r.rotating_outliers;
  out << YAML::Key << "residual_rms_mm" << YAML::Value << common::kMmPerM * r.rotating_residual_rms;
  out << YAML::Key << "residual_max_mm" << YAML::Value << common::kMmPerM * r.rotating_residual_max;
  out << YAML::Key << "positions" << YAML::Value << YAML::BeginSeq;
  for (const RotatingPositionEstimate& p : r.positions) {
    out << YAML::Flow << YAML::BeginMap;
    out << YAML::Key << "step" << YAML::Value << p.step;
    out << YAML::Key << "estimated" << YAML::Value << p.estimated;
    out << YAML::Key << "images" << YAML::Value << p.images;
    out << YAML::Key << "points" << YAML::Value << p.points;
    out << YAML::Key << "outliers" << YAML::Value << p.outliers;
    out << YAML::Key << "cot_theta_y" << YAML::Value << p.cot_theta_y;
    out << YAML::Key << "cot_theta_y_sigma" << YAML::Value << p.cot_theta_y_sigma;
    out << YAML::Key << "b_y_prime_mm" << YAML::Value << common::kMmPerM * p.b_y_prime;
    out << YAML::Key << "depth_condition" << YAML::Value << p.depth_condition;
    out << YAML::Key << "residual_rms_mm" << YAML::Value << common::kMmPerM * p.residual_rms;
    out << YAML::Key << "problem" << YAML::Value << p.problem;
    out << YAML::EndMap;
  }
  out << YAML::EndSeq;
  out << YAML::Key << "stepper" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "fitted" << YAML::Value << r.stepper.fitted;
  out << YAML::Key << "theta_at_step0_deg" << YAML::Value
      << common::kDegPerRad * r.stepper.theta_at_step0;
  out << YAML::Key << "theta_per_step_deg" << YAML::Value
      << common::kDegPerRad * r.stepper.theta_per_step;
  out << YAML::Key << "residual_rms_deg" << YAML::Value
      << common::kDegPerRad * r.stepper.residual_rms;
  out << YAML::Key << "positions" << YAML::Value << r.stepper.positions;
  out << YAML::EndMap;
  out << YAML::EndMap;

  out << YAML::Key << "fixed_laser" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "calibrated" << YAML::Value << r.fixed_calibrated;
  out << YAML::Key << "b_x_prime_mm" << YAML::Value << common::kMmPerM * r.geometry.fixed_b_x_prime;
  out << YAML::Key << "b_x_prime_sigma_mm" << YAML::Value << common::kMmPerM * r.b_x_prime_sigma();
  out << YAML::Key << "cot_theta_x" << YAML::Value << r.geometry.fixed_cot_theta_x;
  out << YAML::Key << "cot_theta_x_sigma" << YAML::Value << r.cot_theta_x_sigma();
  out << YAML::Key << "b_x_prime_cot_theta_x_correlation" << YAML::Value
      << Correlation(r.fixed_covariance);
  out << YAML::Key << "depth_condition" << YAML::Value << r.fixed_depth_condition;
  out << YAML::Key << "points" << YAML::Value << r.fixed_points;
  out << YAML::Key << "outliers" << YAML::Value << r.fixed_outliers;
  out << YAML::Key << "residual_rms_mm" << YAML::Value << common::kMmPerM * r.fixed_residual_rms;
  out << YAML::Key << "residual_max_mm" << YAML::Value << common::kMmPerM * r.fixed_residual_max;
  out << YAML::EndMap;

  out << YAML::Key << "errors" << YAML::Value << YAML::BeginSeq;
  for (const std::string& e : r.errors) out << e;
  out << YAML::EndSeq;
  out << YAML::Key << "warnings" << YAML::Value << YAML::BeginSeq;
  for (const std::string& w : r.warnings) out << w;
  out << YAML::EndSeq;
  internal::EmitEstimation(out, r.estimation);
  out << YAML::EndMap;

  std::ofstream file(path);
  if (!file) throw std::runtime_error("cannot write laser scanner calibration file " + path);
  file << "# kinevis laser scanner calibration (seed 004); docs/laser-scanner-calibration.md\n"
       << out.c_str() << "\n";
  if (!file) throw std::runtime_error("cannot write laser scanner calibration file " + path);
}

LaserScannerCalibrationFile ReadLaserScannerCalibration(const std::string& path) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw std::runtime_error("cannot read laser scanner calibration file " + path);
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument("laser scanner calibration file " + path + ": " + e.what());
  }
  Reader in(path);
  LaserScannerCalibrationFile file;
  LaserScannerCalibration& r = file.result;
  const std::string kind = in.String(root, "kind", "kind");
  if (root["kind"] && kind != kKind)
    in.Bad("kind", "must be " + std::string(kKind) + " (" + kind + ")");
  const int version = in.Int(root, "version", "version", 1);
  if (root["version"] && (version < 1 || version > kVersion)) {
    in.Bad("version", "unsupported (" + std::to_string(version) + ", this reader knows 1 and 2)");
  }
  file.metadata.camera = in.String(root, "camera", "camera");
  if (root["camera"] && file.metadata.camera.empty()) in.Bad("camera", "must not be empty");
  file.metadata.camera_name = in.String(root, "camera_name", "camera_name");
  file.metadata.created = in.String(root, "created", "created");
  file.metadata.source = in.String(root, "source", "source");
  in.Bool(root, "ok", "ok");
  r.images = in.Int(root, "images", "images", 0);
  r.unusable_pixels = in.Int(root, "unusable_pixels", "unusable_pixels", 0);

  const YAML::Node rot = in.Child(root, "rotating_laser", "rotating_laser");
  if (rot) {
    const std::string k = "rotating_laser.";
    r.rotating_calibrated = in.Bool(rot, "calibrated", k + "calibrated");
    const bool f = r.rotating_calibrated;
    r.geometry.rotating_b_y = in.Double(rot, "b_y_mm", k + "b_y_mm", f) / common::kMmPerM;
    const double sb = in.Double(rot, "b_y_sigma_mm", k + "b_y_sigma_mm", f) / common::kMmPerM;
    r.geometry.rotating_d_y = in.Double(rot, "d_y_mm", k + "d_y_mm", f) / common::kMmPerM;
    const double sd = in.Double(rot, "d_y_sigma_mm", k + "d_y_sigma_mm", f) / common::kMmPerM;
    const double rho = in.Double(rot, "b_y_d_y_correlation", k + "b_y_d_y_correlation", f);
    r.rotating_covariance << sb * sb, rho * sb * sd, rho * sb * sd, sd * sd;
    r.separation_condition =
        in.Double(rot, "separation_condition", k + "separation_condition", false);
    r.rotating_points = in.Int(rot, "points", k + "points", 0);
    r.rotating_outliers = in.Int(rot, "outliers", k + "outliers", 0);
    r.rotating_residual_rms =
        in.Double(rot, "residual_rms_mm", k + "residual_rms_mm", f) / common::kMmPerM;
    r.rotating_residual_max =
        in.Double(rot, "residual_max_mm", k + "residual_max_mm", f) / common::kMmPerM;
    const YAML::Node positions = in.Child(rot, "positions", k + "positions");
    if (positions && !positions.IsSequence()) in.Bad(k + "positions", "not a list");
    if (positions && positions.IsSequence()) {
      for (size_t i = 0; i < positions.size(); ++i) {
        const YAML::Node n = positions[i];
        const std::string pk = k + "positions[" + std::to_string(i) + "].";
        RotatingPositionEstimate p;
        p.step = in.Int(n, "step", pk + "step", std::numeric_limits<int>::min());
        p.estimated = in.Bool(n, "estimated", pk + "estimated");
        p.images = in.Int(n, "images", pk + "images", 0);
        p.points = in.Int(n, "points", pk + "points", 0);
        p.outliers = in.Int(n, "outliers", pk + "outliers", 0);
        p.cot_theta_y = in.Double(n, "cot_theta_y", pk + "cot_theta_y", p.estimated);
        p.cot_theta_y_sigma =
            in.Double(n, "cot_theta_y_sigma", pk + "cot_theta_y_sigma", p.estimated);
        p.b_y_prime =
            in.Double(n, "b_y_prime_mm", pk + "b_y_prime_mm", p.estimated) / common::kMmPerM;
        p.depth_condition = in.Double(n, "depth_condition", pk + "depth_condition", false);
        p.residual_rms =
            in.Double(n, "residual_rms_mm", pk + "residual_rms_mm", p.estimated) / common::kMmPerM;
        p.problem = in.String(n, "problem", pk + "problem");
        r.positions.push_back(p);
      }
    }
    const YAML::Node stepper = in.Child(rot, "stepper", k + "stepper");
    if (stepper) {
      const std::string sk = k + "stepper.";
      r.stepper.fitted = in.Bool(stepper, "fitted", sk + "fitted");
      const bool sf = r.stepper.fitted;
      r.stepper.theta_at_step0 =
          in.Double(stepper, "theta_at_step0_deg", sk + "theta_at_step0_deg", sf) /
          common::kDegPerRad;
      r.stepper.theta_per_step =
          in.Double(stepper, "theta_per_step_deg", sk + "theta_per_step_deg", sf) /
          common::kDegPerRad;
      r.stepper.residual_rms =
          in.Double(stepper, "residual_rms_deg", sk + "residual_rms_deg", sf) / common::kDegPerRad;
      r.stepper.positions = in.Int(stepper, "positions", sk + "positions", 0);
    }
  }
  const YAML::Node fix = in.Child(root, "fixed_laser", "fixed_laser");
  if (fix) {
    const std::string k = "fixed_laser.";
    r.fixed_calibrated = in.Bool(fix, "calibrated", k + "calibrated");
    const bool f = r.fixed_calibrated;
    r.geometry.fixed_b_x_prime =
        in.Double(fix, "b_x_prime_mm", k + "b_x_prime_mm", f) / common::kMmPerM;
    const double sb =
        in.Double(fix, "b_x_prime_sigma_mm", k + "b_x_prime_sigma_mm", f) / common::kMmPerM;
    r.geometry.fixed_cot_theta_x = in.Double(fix, "cot_theta_x", k + "cot_theta_x", f);
    const double sc = in.Double(fix, "cot_theta_x_sigma", k + "cot_theta_x_sigma", f);
    const double rho = in.Double(fix, "b_x_prime_cot_theta_x_correlation",
                                 k + "b_x_prime_cot_theta_x_correlation", f);
    r.fixed_covariance << sb * sb, rho * sb * sc, rho * sb * sc, sc * sc;
    r.fixed_depth_condition = in.Double(fix, "depth_condition", k + "depth_condition", false);
    r.fixed_points = in.Int(fix, "points", k + "points", 0);
    r.fixed_outliers = in.Int(fix, "outliers", k + "outliers", 0);
    r.fixed_residual_rms =
        in.Double(fix, "residual_rms_mm", k + "residual_rms_mm", f) / common::kMmPerM;
    r.fixed_residual_max =
        in.Double(fix, "residual_max_mm", k + "residual_max_mm", f) / common::kMmPerM;
  }
  r.errors = in.Strings(root, "errors", "errors");
  r.warnings = in.Strings(root, "warnings", "warnings");
  if (r.rotating_calibrated && r.geometry.Validate() != "" && r.fixed_calibrated) {
    in.Bad("geometry", r.geometry.Validate());
  }
  if (version >= 2) r.estimation = internal::ReadEstimation(in, root);
  in.ThrowIfBad();
  if (version < 2) r.estimation = VersionOneEstimation(r);
  return file;
}

}  // namespace kinevis::calibration
