#pragma once

// The weld-repair chain's jobs behind `kinevis scan`, `record scan`, `weld-path` and `weld-run`
// (seed 004 §2, §5): scan the workpiece into a map in the robot base frame, plan the repair from
// the map, and execute the plan on the robot with the arc sequenced safely. Each returns a report
// struct; printing is the caller's. On a simulated cell the reports also hold the figures against
// the world's truth (which a real cell cannot know: has_truth is false there).

#include <Eigen/Geometry>
#include <cstddef>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "calibration/weld_mount/scan_cloud.h"
#include "control/weld/weld_planner.h"
#include "hal/weld/weld_robot_client.h"
#include "rigs/weld/weld_rig.h"
#include "vision/laser/scanner_model.h"

namespace kinevis::rigs {

// ---- scan / record scan -------------------------------------------------------------------

struct ScanJobOptions {
  std::string scanner;  // scanner calibration YAML; empty: the nominal geometry (seed Table 2)
  std::string mount;    // scanner-mount calibration YAML; empty: the nominal (CAD) mount
  std::optional<robots::Vector5d> at;  // move here first; none: scan from where the robot stands
  std::string dataset;                 // rebuild from a recorded scan dataset (no rig)
  std::string record;                  // with a rig: keep the frames as a scan dataset here
  std::string out = "map.ply";         // the map: X.ply and its sidecar X.yaml
  int lines = 300;                     // frames in the sweep
  double depth = 0.40;  // expected camera-to-surface distance (m): the simulated sweep
  // Polled before each frame; true ends the sweep with std::runtime_error ("interrupted").
  std::function<bool()> stop_requested;
};

struct ScanFrames {
  std::vector<calibration::ScanLine> lines;
  int frames = 0;
  int failed = 0;                    // frames without a usable line
  double max_angle_deviation = 0.0;  // |eq. 11 − commanded| over the frames (simulated cell)
  std::string first_failure;
};

struct ScanJobReport {
  ScanFrames frames;
  double wall_seconds = 0.0;  // the sweep (or the dataset's triangulation)
  std::string scanner_source, mount_source, robot_source;
  vision::laser::ScannerGeometry geometry;
  // The map (when frames.lines is not empty; else nothing is written).
  size_t points = 0;
  size_t normals_estimated = 0, normals_missing = 0;
  std::string ply_path, sidecar_path;
  // Simulated cell: the map's signed distance from the true surface along its normal z_S (m).
  bool has_truth = false;
  double truth_mean_error = 0.0, truth_rms_error = 0.0, truth_max_error = 0.0;
};

// The scanner geometry from a calibration YAML (both lasers calibrated), or the seed's nominal one
// for an empty path; `source` says which. Throws std::invalid_argument naming the file.
vision::laser::ScannerGeometry LoadScannerGeometry(const std::string& path, std::string* source);

// Sweeps the rotating laser from where the robot stands (or options.at) — on a simulated cell
// the host steps the laser over vision::laser::PlanSweep's angles, a real scanner sweeps on its
// own and the host takes the frames while it does (eq. 11 reads each angle) — and triangulates
// each frame into a scan line; keeps the frames in options.record when set. Throws
// std::runtime_error on a failed move or grab, or a stop request.
ScanFrames SweepScanner(WeldRig* rig, const vision::laser::ScannerModel& model,
                        const ScanJobOptions& options);

// `kinevis scan`: the sweep on `rig` (or, with rig == nullptr, options.dataset's frames), the
// scan lines into the base frame with the mount (and its D–H errors when calibrated with them),
// written as binary PLY with normals + YAML sidecar (docs/point-clouds.md).
ScanJobReport ScanWorkpiece(WeldRig* rig, const ScanJobOptions& options);

// ---- weld-path ----------------------------------------------------------------------------

struct WeldPathRun {
  control::WeldPlan plan;
  double wall_seconds = 0.0;
  std::string top, section;  // the PNGs written (empty when the plan has no region)
};

// Plans the repair of the map `map` (X.ply or X.yaml, frame "0") for the robot that made it (the
// D–H in the sidecar; the built-in nominal when it has none) and writes the plan YAML `out` and,
// when there is a region, the top view and section PNGs (`top`/`section`, empty: next to `out`).
// Throws std::invalid_argument naming the file (not in the base frame, unreadable).
WeldPathRun PlanWeldPath(const std::string& map, const control::WeldPlanOptions& options,
                         const std::string& out, const std::string& top = "",
                         const std::string& section = "");

// ---- weld-run -----------------------------------------------------------------------------

enum class WeldRunOutcome {
  kCompleted,        // every segment executed (arc off at the end)
  kNoTrajectory,     // the plan has nothing to execute (nothing moved)
  kStartNotReached,  // the move to the plan's start failed (the robot is in its safe state)
  kWeldParameters,   // the weld set-points were refused (nothing moved)
  kArcOnFailed,      // the arc did not come on (the robot was stopped)
  kCancelled,        // a stop request ended the stream (the driver stopped the robot, arc off)
  kStopped,          // an alarm or a lost link ended the stream (the driver stopped it, arc off)
};
const char* ToString(WeldRunOutcome outcome);

struct WeldRunOptions {
  bool arc = true;  // false: a dry run, the motion with the arc disabled
  // Polled on every stream progress report; true cancels the stream (the driver stops the robot
  // with the arc off).
  std::function<bool()> stop_requested;
};

struct WeldRunReport {
  WeldRunOutcome outcome = WeldRunOutcome::kCompleted;
  std::string message;  // why it did not complete
  hal::WeldStreamReport stream;
  std::string arc_off_error;  // the final arc-off's error, empty when it was acknowledged
  // The joints read back after each completed segment: the executed targets.
  std::vector<control::ExecutedTorchPose> executed;
  // Simulated cell, completed run: the executed torch poses through the TRUE kinematics against
  // the plan's surface (the robot's error) and, on the bottom layers whose deposition surface is
  // the scanned one, against the true surface (everything: scanner, mount, robot).
  bool has_truth = false;
  control::StandOffComparison planned_surface;
  int true_surface_points = 0;
  double true_surface_mean_abs = 0.0, true_surface_rms = 0.0, true_surface_max = 0.0;  // m
  double true_surface_path = 0.0;  // m of arc-on path along consecutive targets
};

// Streams the plan's joint trajectory to the rig's robot (hal::WeldRobotClient::
// StreamTrajectory: flow control, arc on for the arc-on segments): moves to the plan's start
// first, sets the weld parameters and switches the arc on (unless a dry run), streams, and
// switches the arc off at the end whatever happened. On an alarm, a lost link or a cancel the
// driver stops the robot with the arc off and the report says whether that safe state was
// confirmed.
WeldRunReport RunWeldPlan(WeldRig* rig, const control::WeldPlan& plan,
                          const WeldRunOptions& options);

}  // namespace kinevis::rigs
