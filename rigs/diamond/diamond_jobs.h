#pragma once

// The DIAMOND jobs behind `kinevis record|calibrate|servo diamond`, `kinevis demo` and the
// experiments. Each runs on a DiamondRig (the simulated world in this process or the real robot,
// docs/diamond-calibration.md, "Command line") and returns a report struct; printing is the
// caller's.
//
// Units: SI inside (m, rad, s); the command line converts degrees at its edge.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "calibration/diamond/diamond_dataset.h"
#include "calibration/diamond/diamond_identification.h"
#include "control/diamond/diamond_laws.h"
#include "control/diamond/diamond_loop.h"
#include "rigs/diamond/diamond_rig.h"

namespace kinevis::rigs {

// The file a simulated recording writes beside its dataset: the world's truth, for comparison only.
inline constexpr char kDiamondTruthFile[] = "simulation_truth.yaml";

// --- record -------------------------------------------------------------------------------------

struct DiamondRecordOptions {
  std::string out;      // dataset directory to create
  int samples = 60;     // joint configurations, >= 10
  double speed = 0.5;   // mean task-space rate between configurations (rad/s), > 0
  double inset = 0.05;  // keep this far (rad) inside the nominal workspace box, >= 0
  // The marker's image by the nominal model at least this far inside the image (px); < 0: 10 %
  // of the image's shorter side.
  double margin_px = -1;
  // Polled before each sample; true ends the recording ("interrupted"). Empty: never.
  std::function<bool()> stop_requested;
};

struct DiamondRecordSummary {
  int planned = 0;
  int recorded = 0;
  std::string stopped;          // why the recording ended early ("" when complete)
  bool hardware_fault = false;  // a drive or the camera failed
  bool simulated = false;       // a simulation_truth.yaml was written beside the dataset
  // Samples whose image shows no marker to the detector (still recorded: raw data), with why.
  std::vector<std::string> marker_not_found;
  int retries = 0;            // moves nearer the view's centre because the marker was not seen
  std::string truth_file;     // simulated: the simulation_truth.yaml written ("" otherwise)
  double wall_seconds = 0.0;  // of the whole recording
};

// Plans `samples` task points spread over the part of the nominal workspace whose marker the
// camera sees (calibration::DiamondVisibleTaskGrid on a grid fine enough, subsampled evenly and
// visited nearest-first), moves there through the two drives (DiamondRig::MoveTo: the control
// loop's task-space PD and safety), grabs a fresh image and appends it with the joint readings to
// a new dataset. On a simulated rig it also writes DIR/simulation_truth.yaml (the world's true
// R, α, β, joint offsets and camera pose; for comparison only). Enables the drives first, moves
// back to where the tool started and disables them at the end. Throws std::invalid_argument (bad
// options, nothing visible, the directory holds a dataset), hal::HalError.
DiamondRecordSummary RecordDiamondDataset(DiamondRig* rig, const DiamondRecordOptions& options);

// --- calibrate ----------------------------------------------------------------------------------

struct DiamondCalibrateOptions {
  std::string dataset;                     // dataset directory
  std::string out = "diamond_calib.yaml";  // result YAML
  std::string residual = "pixel";          // pixel | spherical (seed eq. 6)
  double pixel_sigma = 0.1;                // a-priori marker noise (px), > 0
  bool estimate_camera_distance = false;   // free the scale gauge (then R is not identified)
};

// What a simulated recording says the truth was (DIR/simulation_truth.yaml).
struct DiamondSimulationTruth {
  robots::DiamondModel model;  // R, α, β, joint offsets of the true robot
  Eigen::Isometry3d X_OC = Eigen::Isometry3d::Identity();
};

struct DiamondCalibrationRun {
  calibration::DiamondIdentificationSummary summary;
  std::string dataset;
  std::string out;
  int images = 0;    // samples in the dataset
  int detected = 0;  // with a marker pixel (given in samples.csv or detected in the image)
  std::vector<std::string> not_detected;  // "sample 12 (images/sample_0012.png): not found"
  double detection_seconds = 0.0;         // wall time of the marker detection
  double identification_seconds = 0.0;
  bool has_truth = false;
  DiamondSimulationTruth truth;
  // ok: converged, full rank and every estimated parameter identified.
  bool identified = false;
};

// Detects the marker in every image of the dataset that has no pixel yet (whole image,
// MarkerDetector sized as the recording rig's), identifies R, α, β, the joint offsets' difference
// and the camera pose from the dataset's nominal model (the a-priori set unless the dataset names
// another) and camera pose, and writes the result YAML. Throws std::invalid_argument for a bad
// dataset or options, std::runtime_error when the result cannot be written.
DiamondCalibrationRun CalibrateDiamondFromDataset(const DiamondCalibrateOptions& options);

// --- servo --------------------------------------------------------------------------------------

enum class DiamondServoLaw { kTaskPd, kMarkerIbvs };

struct DiamondServoOptions {
  // The controller's model: a result of `kinevis calibrate diamond` (robot and camera pose), or
  // "" for the rig's nominal model and camera pose.
  std::string calib;
  // The model that locates the detected marker on the sphere for the measured path (R and
  // X_OC): "" = the same as the controller's. The demo measures both runs with the identified
  // model, as the seed measures both with one device.
  std::string measure_calib;
  DiamondServoLaw law = DiamondServoLaw::kTaskPd;
  control::DiamondLineKind kind = control::DiamondLineKind::kTopViewLine;
  Eigen::Vector2d from{M_PI / 3, M_PI / 4};  // (φ, γ) (rad)
  Eigen::Vector2d to{2 * M_PI / 3, M_PI / 4};
  double duration_s = 3.0;      // along the line (PD), > 0
  double approach_speed = 0.5;  // to the start, mean rate (rad/s)
  double gain = 4.0;            // IBVS λ (1/s)
  double timeout_s = 20.0;      // of the main run
  std::string log;              // CSV of the main run ("" = none)
  // Real-time scheduling of the loop's thread for the main run (hal/common/realtime.h): applied
  // after the camera worker and the simulators exist, restored after. Priority 0: none.
  int rt_priority = 0;
  int rt_cpu = -1;
  bool rt_lock_memory = false;
  long timer_slack_ns = 1;  // the loop thread's timer slack during the run (-1: kernel default)
};

struct DiamondServoRun {
  std::string model_source;  // "a priori (...)" or the calibration file
  robots::DiamondModel model;
  Eigen::Isometry3d X_OC = Eigen::Isometry3d::Identity();
  control::DiamondLoopReport approach;  // to --from
  control::DiamondLoopReport report;    // the line or the servo
  bool reached_start = false;
  // Measured path: marker detections located on the sphere (measurement model), top view.
  int measured_points = 0;
  double measured_straightness = 0.0;  // RMS from the LS line (m); 0 for < 3 points
  int frames = 0;                      // camera frames processed during the run
  int frames_without_marker = 0;
  std::string camera_error;  // a camera failure during the run (-> exit 3)
  // IBVS: target pixel and the last detected pixel's distance from it (px).
  Eigen::Vector2d target_pixel = Eigen::Vector2d::Constant(NAN);
  double final_pixel_error = NAN;
  bool real_time = true;  // false on a stepped simulated clock (period statistics exact)
  std::string realtime;   // what the kernel granted of rt_priority / rt_cpu / rt_lock_memory
  // Simulated rig only: the true tool path.
  bool simulated = false;
  int true_points = 0;
  double true_straightness = 0.0;       // of the true top-view path (m)
  double true_position_rms = 0.0;       // PD: RMS |p_true − R_true u(reference)| (m)
  double true_final_task_error = NAN;   // |true (φ, γ) − to| at the end (rad)
  double true_final_pixel_error = NAN;  // IBVS: |true projection − target| (px)
};

// Moves to options.from (task-space PD in the controller's model), then follows the line to
// options.to with the PD, or servoes the marker to the projection of options.to with the IBVS,
// measuring the marker path with the camera. Enables the drives (if not yet) and releases them
// when its loop ends (DiamondRig::Release: disabled, watchdog off). Throws std::invalid_argument
// (bad calibration file, a line or target outside the workspace, naming --from / --to),
// hal::HalError.
DiamondServoRun ServoDiamond(DiamondRig* rig, const DiamondServoOptions& options);

// "(φ, γ) deg" of a task point (rad), with two decimals: how the jobs name a point in messages.
std::string FormatTaskDeg(const Eigen::Vector2d& task);

}  // namespace kinevis::rigs
