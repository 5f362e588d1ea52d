#pragma once

// The laser-scanner calibration result as a YAML file (format: docs/laser-scanner-calibration.md):
// the scanner geometry in mm at the file edge (units in the key names), σ and correlations, the
// stepper positions and the stepper fit, residual statistics, errors, warnings, and the camera the
// stripes were triangulated with. yaml-cpp is used in the .cc only.

#include <string>

#include "calibration/laser_scanner/laser_scanner_calibration.h"

namespace kinevis::calibration {

struct LaserScannerCalibrationMetadata {
  std::string camera;       // vision::OpenCameraModel spec ("builtin:tsai-seed004" or a file)
  std::string camera_name;  // e.g. "weld-scanner"; may be empty
  std::string created;      // UTC, ISO 8601; empty: now, on write
  std::string source;       // the dataset directory, "synthetic", ...
};

struct LaserScannerCalibrationFile {
  LaserScannerCalibration result;
  LaserScannerCalibrationMetadata metadata;
};

// Throws std::runtime_error naming the path when it cannot be written.
void WriteLaserScannerCalibration(const std::string& path, const LaserScannerCalibration& result,
                                  const LaserScannerCalibrationMetadata& metadata);

// Reads a file written by WriteLaserScannerCalibration (mm → m). Throws std::invalid_argument
// naming the file and every missing or bad key with its value in one message (a calibrated
// laser's parameters must be finite), std::runtime_error when it cannot be read. Counts not
// stored (iterations) come back at their defaults.
LaserScannerCalibrationFile ReadLaserScannerCalibration(const std::string& path);

}  // namespace kinevis::calibration
