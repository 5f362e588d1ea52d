#pragma once

// The hexapod calibration result as a YAML file (format: docs/hexapod-calibration.md): the base
// attachment points A_j in the camera frame C with their uncertainty, the rigid fit X_CB (eq. 15),
// the scale (eq. 16), residuals, condition numbers, down-weighted equations, warnings and where the
// result came from. yaml-cpp is used in the .cc only.
//
// X_CB is written as `position` (m) and `quaternion_wxyz` (unit, w first; Eigen's
// Quaterniond(w, x, y, z)); p_C = R(q) p_B + position.

#include <string>

#include "calibration/hexapod/leg_calibration.h"

namespace kinevis::calibration {

struct HexapodCalibrationMetadata {
  std::string camera;   // camera name (e.g. "hexapod-perspective") or model spec
  std::string created;  // UTC, ISO 8601 ("2024-05-01T12:00:00Z"); empty: filled with now on write
  std::string robot;    // the CAD robot description used for the rigid fit ("" = built-in default)
  std::string source;   // what the normals came from (dataset directory, "synthetic", ...)
};

struct HexapodCalibrationFile {
  HexapodCalibrationResult result;
  HexapodCalibrationMetadata metadata;
};

// Writes `result` and `metadata` to `path`. Throws std::runtime_error naming the path when it
// cannot be written.
void WriteHexapodCalibration(const std::string& path, const HexapodCalibrationResult& result,
                             const HexapodCalibrationMetadata& metadata);

// Reads a file written by WriteHexapodCalibration. Throws std::invalid_argument naming the file and
// every missing or bad key (with its value) in one message; std::runtime_error when it cannot be
// read. Statistics not stored in the file (individual down-weighted residuals are stored; the
// IRLS iteration counts are not) come back at their defaults.
HexapodCalibrationFile ReadHexapodCalibration(const std::string& path);

}  // namespace kinevis::calibration
