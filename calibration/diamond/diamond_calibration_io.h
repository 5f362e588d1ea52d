#pragma once

// The DIAMOND identification result as a YAML file (format: docs/diamond-calibration.md): the
// identified R, α, β, joint offsets and camera pose X_OC, every parameter's initial value,
// estimate and σ, the covariance, the residual statistics (pixels and the seed's Table II in
// (φ, γ)), the identifiability report and the warnings. The file is at the same time a DIAMOND
// robot description (robot: diamond, radius, alpha, beta, joint_offsets, limits; see
// docs/robot-description.md), so robots::LoadDiamondDescription() and everything that takes a
// robot file load the calibrated robot from it directly. yaml-cpp is used in the .cc only.
// Units: SI (m, rad) with the unit in the key name where it is not (…_px).

#include <string>

#include "calibration/diamond/diamond_identification.h"

namespace kinevis::calibration {

struct DiamondCalibrationMetadata {
  std::string name = "diamond-calibrated";  // the robot description's name
  std::string camera;                       // camera name or model spec ("builtin:...", a file)
  std::string created;                      // UTC, ISO 8601; empty: filled with now on write
  std::string robot;   // the initial (nominal) robot description used ("" = built-in a priori)
  std::string source;  // what the samples came from (dataset directory, "simulation", ...)
};

struct DiamondCalibrationFile {
  DiamondIdentificationSummary summary;  // per_sample_pixel_residuals and solver_message empty
  DiamondCalibrationMetadata metadata;
};

// Writes `summary` and `metadata` to `path`. Throws std::runtime_error naming the path when it
// cannot be written.
void WriteDiamondCalibration(const std::string& path, const DiamondIdentificationSummary& summary,
                             const DiamondCalibrationMetadata& metadata);

// Reads a file written by WriteDiamondCalibration. Throws std::invalid_argument naming the file
// and every missing or bad key (with its value) in one message — wrong kind or version, a model
// that fails DiamondModel::Validate(), a pose that is not a rotation, a covariance that is not
// 11×11 or not symmetric, non-finite values where finite ones are needed; std::runtime_error
// when it cannot be read.
DiamondCalibrationFile ReadDiamondCalibration(const std::string& path);

}  // namespace kinevis::calibration
