#pragma once

// The scanner-mount calibration result as a YAML file (issue 7; format and every key:
// docs/scanner-mount-calibration.md, "Result file"): the mount X_5C (the pose of the scanner's
// camera frame C on link 5, seed 004's A2S) with its 6×6 covariance and σ, the correction from the
// CAD mount, the gauge block's pose X_0B, the D–H errors when they were estimated (and which were
// held at nominal), the identifiability report (rank, condition number, singular values,
// unidentified directions), residual statistics, warnings and status. Written by
// `kinevis calibrate scanner-mount`, read by `kinevis scan` to put scans into the robot frame.
//
// Units at the file edge: mm and deg, named in the keys (position_mm, rpy_deg, ...); quaternions
// are (w, x, y, z); rpy is X = Rz(yaw) · Ry(pitch) · Rx(roll), listed [roll, pitch, yaw], the
// convention of the world configs and datasets. In memory everything is SI (m, rad).
// yaml-cpp is used in the .cc only.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <string>

#include "calibration/weld_mount/mount_calibration.h"
#include "robots/weld5/weld5_model.h"

namespace kinevis::calibration {

struct ScannerMountCalibrationMetadata {
  std::string created;  // UTC, ISO 8601; empty: now, on write
  std::string source;   // the dataset directory (or "live: ..."), for the record
  std::string robot;  // the nominal robot description the calibration started from ("" = built-in)
  std::string scanner;  // the scanner calibration / geometry the stripe points were made with
  // The CAD mount (the calibration's start) and the block's guess; its size.
  Eigen::Isometry3d X_5C_guess = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d X_0B_guess = Eigen::Isometry3d::Identity();
  GaugeBlock block;
};

struct ScannerMountCalibrationFile {
  // What the file holds of the summary: status, converged, iterations, costs, sigma_ratio, X_5C,
  // X_0B, touch and scan statistics, parameter_names, correction, estimated, identified, std_dev,
  // mount_covariance, mount_position_std, mount_angle_std, rank, condition_number,
  // singular_values, unidentified, fixed_dh, warnings. Not stored: the full covariance beyond the
  // mount block (left empty) and `robot` (the nominal is not in the file: use CalibratedRobot()).
  MountCalibrationSummary summary;
  ScannerMountCalibrationMetadata metadata;
  bool dh_estimated = false;  // the D–H errors were part of the calibration
  Eigen::VectorXd dh_errors;  // 20 (DhErrorNames() order; m, rad), zero when not estimated
};

// Writes `summary` (from CalibrateScannerMount) to `path`. Throws std::invalid_argument when the
// summary is inconsistent (parameter_names not the 12 mount + block names, optionally followed by
// the 20 D–H names; vectors of another length), std::runtime_error naming the path when it cannot
// be written.
void WriteScannerMountCalibration(const std::string& path, const MountCalibrationSummary& summary,
                                  const ScannerMountCalibrationMetadata& metadata);

// Reads a file written by WriteScannerMountCalibration (mm, deg → m, rad). Throws
// std::invalid_argument naming the file and every missing or bad key with its value in one
// message (wrong kind or version, an unknown status, a quaternion that is not unit or disagrees
// with rpy_deg, a covariance that is not 6×6 and symmetric, a parameter list out of order, ...);
// std::runtime_error when the file cannot be read.
ScannerMountCalibrationFile ReadScannerMountCalibration(const std::string& path);

// The mount X_5C to put scans into the robot base frame (p_0 = FK(q) · X_5C · p_C). Reads `path`
// as above and throws std::invalid_argument naming the file when its status is not "ok" (a mount
// the data did not identify, or a solve that did not converge, is not to be used for maps).
Eigen::Isometry3d ReadScannerMount(const std::string& path);

// The robot the mount was calibrated with: `nominal` (the file's metadata.robot loaded by the
// caller) with the file's D–H errors applied (unchanged when they were not estimated).
robots::Weld5Model CalibratedRobot(const ScannerMountCalibrationFile& file,
                                   const robots::Weld5Model& nominal);

}  // namespace kinevis::calibration
