#pragma once

// The weld cell's calibration jobs behind `kinevis record|calibrate scanner` and
// `kinevis record|calibrate scanner-mount` (seed 004 §3–4). Each runs on a WeldRig (the simulated
// cell in this process or the real one, docs/deployment.md) or on a recorded dataset and returns
// a report struct; printing is the caller's.

#include <Eigen/Geometry>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "calibration/laser_scanner/laser_scanner_calibration_io.h"
#include "calibration/laser_scanner/laser_scanner_dataset.h"
#include "calibration/weld_mount/mount_calibration.h"
#include "calibration/weld_mount/mount_dataset.h"
#include "rigs/weld/weld_rig.h"
#include "vision/laser/scanner_model.h"

namespace kinevis::rigs {

// ---- The laser scanner (seed 004 eq. 26–32) -------------------------------------------------

struct ScannerRecordOptions {
  std::string out;  // dataset directory to create
  int poses = 6;    // board poses (1-8)
  int steps = 5;    // rotating-laser stepper positions per pose (2-15)
  double step_deg = 0.45;
  // Polled before each board pose; true ends the recording with std::runtime_error
  // ("interrupted"). Empty: never.
  std::function<bool()> stop_requested;
};

struct ScannerRecordReport {
  int board_poses = 0;
  int images = 0;  // lasers-off and lasers-on images written
};

// Carries the scanner in front of the dot board to `poses` board poses; at each one image with
// the lasers off (the dots: the board pose) and one per stepper position with both lasers on,
// written as a dataset (docs/laser-scanner-calibration.md). The rig's workpiece must be the dot
// board. Throws std::invalid_argument on a real cell (no host driver for the laser controller
// yet: the message says how to record by hand) and std::runtime_error on a failed move or grab.
ScannerRecordReport RecordScannerDataset(WeldRig* rig, const ScannerRecordOptions& options);

struct ScannerCalibrationRun {
  calibration::LaserScannerDataset dataset;
  calibration::LaserScannerDatasetCalibration run;
  double wall_seconds = 0.0;
};

// A scanner calibration file whose two lasers are both calibrated (the stripe crossing needs the
// fixed laser, the points the rotating one); throws std::invalid_argument naming the file and the
// laser that is not.
calibration::LaserScannerCalibrationFile ReadCalibratedScanner(const std::string& path);

// Board poses from the dots, stripes from the lasers-on images (vision/laser/laser_stripes.h),
// the calibration (calibration/laser_scanner/), written to `out` (laser_scanner_calibration_io.h).
ScannerCalibrationRun CalibrateScannerFromDataset(const std::string& dataset_dir,
                                                  const std::string& out);

// ---- The scanner mount X_5C (seed 004 §4) ---------------------------------------------------

enum class LaserAngleSource {
  kCommanded,  // the stepper angle the host set
  kCrossing,   // eq. (11) from the stripes' crossing
};

struct MountRecordOptions {
  std::string scanner;  // scanner calibration YAML; empty: the world config's scanner geometry
  std::string out;      // dataset directory to create
  int views = 7;        // 1..calibration::kMaxMountViews
  double touch_sigma = 0.05e-3;  // the simulated operator's touch error (m, per axis)
  LaserAngleSource laser_angle = LaserAngleSource::kCommanded;
  bool fixed_laser = true;  // also the fixed laser's stripe, once per viewpoint
  // Polled before each touch and each view; true ends the recording with std::runtime_error
  // ("interrupted"). Empty: never.
  std::function<bool()> stop_requested;
};

struct MountRecordReport {
  int touches = 0;
  std::vector<std::string> unreachable;  // features no torch approach reaches
  int scans = 0;
  int points = 0;
  std::vector<std::string> skipped;  // images or stripes left out, and why
  std::string scanner;               // what the stripe points were triangulated with
  LaserAngleSource laser_angle = LaserAngleSource::kCommanded;
  std::vector<double> eq11_deviation;  // eq. (11)'s cot θ_y minus the commanded one, per image
};

// The rig for the mount jobs: a world config whose workpiece already is a board with the gauge
// block keeps its placement (the truth the calibration must find); any other world config (or
// none) gets the default board with the block. A deployment file (the real cell) is refused with
// std::invalid_argument before anything connects or moves: the touches need an operator jogging
// the robot, and kinevis has no jog interface (the message says how to record by hand).
std::unique_ptr<WeldRig> OpenGaugeBlockRig(const std::string& config);

// The block's TRUE pose X_0B in a simulated cell.
Eigen::Isometry3d TrueGaugeBlockPose(const WeldRig& rig);

// The touches (simulated: WeldRig::OperatorTouch on the TRUE robot at the block's TRUE pose, what
// a person sees), then the scans: the robot carries the scanner to `views` viewpoints aimed at
// the block's layout pose with what the host knows (nominal robot, CAD mount;
// calibration/weld_mount/mount_plan.h), at each the plan's rotating-laser angles with both lasers
// on; stripes extracted, points triangulated (eq. 9, 10) into p_C. Written as a mount dataset
// (calibration/weld_mount/mount_dataset.h). Throws std::invalid_argument (a real cell, a bad
// scanner file), hal::HalError (a failed move or grab: the robot is in its safe state).
MountRecordReport RecordMountDataset(WeldRig* rig, const MountRecordOptions& options);

struct MountCalibrateOptions {
  bool estimate_dh = false;      // also the D–H errors (seed eq. 48)
  bool use_fixed_laser = false;  // also the fixed laser's scans (eq. 10's short base: ~15x less
                                 // precise depth)
  double touch_sigma = 0.1e-3;   // m, per axis
  double scan_sigma = 0.1e-3;    // m, per axis
  std::string out = "mount_calib.yaml";
};

// The mount's error against a simulated cell's truth.
struct MountTruthComparison {
  Eigen::Vector3d position_error = Eigen::Vector3d::Zero();  // estimated − true (m, in 5)
  double angle_error = 0.0;                                  // rad
  double cad_position_error = 0.0;                           // the CAD mount's, for scale (m)
  double cad_angle_error = 0.0;                              // rad
  double block_position_error = 0.0;
  double block_angle_error = 0.0;
};

struct MountCalibrationRun {
  calibration::MountDataset dataset;
  calibration::MountCalibrationData data;  // what was calibrated (fixed-laser scans left out
                                           // unless asked for)
  size_t fixed_left_out = 0;
  size_t points = 0;
  // Set when there was something to calibrate (touches and scans); then also written to `out`.
  bool calibrated = false;
  calibration::MountCalibrationSummary summary;
  double wall_seconds = 0.0;
  bool has_truth = false;  // `rig` was a simulated cell
  MountTruthComparison truth;
};

// Calibrates the mount from a recorded dataset with the robot of `rig` (when given) or the
// dataset's robot description (or the built-in nominal); with a simulated `rig` also against its
// truth. Writes options.out (mount_calibration_io.h) when there was something to calibrate.
MountCalibrationRun CalibrateScannerMountFromDataset(const std::string& dataset_dir,
                                                     const MountCalibrateOptions& options,
                                                     const WeldRig* rig = nullptr);

}  // namespace kinevis::rigs
