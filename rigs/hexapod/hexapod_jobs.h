#pragma once

// The hexapod jobs behind `kinevis record|calibrate|servo hexapod`, `kinevis demo` and the
// experiments. Each runs on a HexapodRig (the simulated world in this process or the real machine,
// docs/hexapod-rig.md) and returns a report struct; printing is the caller's.

#include <Eigen/Geometry>
#include <cmath>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "calibration/hexapod/dataset_calibration.h"
#include "control/hexapod/image_leg_features.h"
#include "control/hexapod/servo_loop.h"
#include "rigs/hexapod/hexapod_rig.h"

namespace kinevis::rigs {

struct HexapodRecordOptions {
  std::string out;        // dataset directory to create
  int poses = 60;         // seed 002: 60 configurations on the workspace limits
  int candidates = 2000;  // pose planner candidates
  uint64_t seed = 1;      // of the pose planner
  double speed = 0.05;    // fastest leg speed between poses (m/s)
  double settle_s = 0.3;  // wait after each move before the image (s)
  // Polled before each pose; true ends the recording ("interrupted"). Empty: never.
  std::function<bool()> stop_requested;
};

struct HexapodRecordSummary {
  int recorded = 0;
  std::string stopped;                // why the recording ended early ("" when complete)
  bool hardware_fault = false;        // a drive or the camera failed
  std::vector<std::string> warnings;  // the planner's
};

// Plans `poses` poses (every leg in the camera's image by the nominal model and the camera pose
// hint), moves to each, grabs a fresh image and appends it with the readings to a new dataset.
// Enables the drives first and disables them at the end (after moving back home). Throws
// std::invalid_argument (bad options, nothing admissible, the directory holds a dataset),
// hal::HalError.
HexapodRecordSummary RecordHexapodDataset(HexapodRig* rig, const HexapodRecordOptions& options);

struct HexapodCalibrateOptions {
  std::string dataset;                     // dataset directory
  std::string out = "hexapod_calib.yaml";  // result YAML
  std::string image;                       // re-projection PNG ("" = out with .png)
  std::string loss = "tukey";              // tukey | huber | least-squares
  std::string scale = "least-squares";     // least-squares | median-ratio | max-ratio
  bool correct_scale = false;
  int passes = 2;
  // The edge locator: "" = what the dataset says (the recording rig's camera settings), else
  // "step-ramp" or "parabola", with edge_blur_px (px, the step-ramp model's blur; < 0 = the
  // dataset's).
  std::string edge_locator;
  double edge_blur_px = -1.0;
};

struct HexapodCalibrationRun {
  calibration::DatasetCalibrationResult calibration;
  std::string image;  // the PNG written
};

// Calibrates from options.dataset, writes options.out and the re-projection PNG.
HexapodCalibrationRun CalibrateHexapodFromDataset(const HexapodCalibrateOptions& options);

struct HexapodServoOptions {
  std::string calib;                                              // calibration result YAML
  Eigen::Isometry3d X_BP_target = Eigen::Isometry3d::Identity();  // target pose of P in B
  double gain = 1.0;
  bool adaptive = false;
  std::string mode = "csv";  // csv | csp
  double threshold = 1e-4;   // on |e|: reached with desired features taught at the target
  // ... or the law's remaining displacement below these (m, rad): with u* from a model pose, |e|
  // stops above zero when the true robot cannot show those directions exactly.
  double remaining_translation = 2e-4;
  double remaining_rotation = 0.05 * M_PI / 180;  // low-passed over 0.5 s
  double timeout_s = 30.0;
  double max_leg_velocity = 0.02;  // m/s
  int min_visible_legs = 6;
  std::string log;   // CSV ("" = none)
  std::string plot;  // PNG ("" = none)
};

struct HexapodServoRun {
  control::ServoLoopReport report;
  control::ImageLegFeatureCounters feature_counters;
  std::string camera_error;   // the feature source's last camera error
  std::string last_not_seen;  // legs not seen in the last frame, with the reasons
  bool simulated = false;
  double true_position_error = 0.0;  // simulated: |p_BP true − target| at the end (m)
  double true_rotation_error = 0.0;  // (rad)
};

// Reads a target pose file: `pose: {position: [x, y, z], rpy_deg: [r, p, y]}` (P in B). Throws
// std::invalid_argument naming the file and the bad key.
Eigen::Isometry3d ReadTargetPose(const std::string& path);

// Servoes the rig's platform to options.X_BP_target from the camera's leg edges with the
// calibration in options.calib. Enables the drives and disables them at the end. Throws
// std::invalid_argument (bad calibration file, unreachable target), hal::HalError.
HexapodServoRun ServoHexapod(HexapodRig* rig, const HexapodServoOptions& options);

}  // namespace kinevis::rigs
