#pragma once

// The DIAMOND as the diamond commands (record, calibrate, servo) use it: the nominal model, the two
// RS485 motor-arm drives on one Modbus RTU line (control/diamond/diamond_drives.h) and the marker
// camera with its model and pose — either a simulated DiamondWorld in this process (a world
// config, `world: diamond`, or none: the built-in world with config/diamond-sim.yaml's camera) or
// real hardware, or a world in another process (a deployment file, `rig: diamond`;
// docs/diamond-calibration.md, "Command line"). The commands cannot tell which.
//
// Frames as in robots/diamond/diamond_model.h: O the RCM frame, C the camera frame; X_OC the pose
// of C in O. Joint readings q (rad), task coordinates (φ, γ) (rad).

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <chrono>
#include <memory>
#include <string>

#include "control/diamond/diamond_loop.h"
#include "hal/camera/camera.h"
#include "robots/diamond/diamond_model.h"
#include "vision/diamond/marker_detector.h"

namespace kinevis::common {
class Clock;
}  // namespace kinevis::common
namespace kinevis::hal {
class Rs485DriveBus;
}  // namespace kinevis::hal
namespace kinevis::sim {
class DiamondWorld;
}
namespace kinevis::vision {
class CameraModel;
}

namespace kinevis::rigs {

struct DiamondRigOptions {
  // A world config (simulated in this process), a deployment file (real hardware), or empty: the
  // built-in simulated world.
  std::string config;
  // Simulated only: run the world in real time (steady clock, its own threads) instead of on a
  // stepped clock, so that the loop's period statistics are real. Ignored for a deployment file
  // (always real time).
  bool real_time = false;
};

// Marker detector settings for a marker of half side `half_side_m` (m) seen by `camera` at X_OC
// when the tool is at the centre of the working region (φ, γ) = (π/2, π/4) of `model`: the
// verification ring, the corner refinement window and the search window scale with its image
// (the library defaults suit a half side of about 20 px). The defaults when it is not in view.
vision::MarkerDetectorOptions DiamondDetectorOptions(const vision::CameraModel& camera,
                                                     const Eigen::Isometry3d& X_OC,
                                                     const robots::DiamondModel& model,
                                                     double half_side_m = 0.005);

class DiamondRig {
 public:
  // Reads the file, builds the world (simulated) or opens the RS485 line, adds the two drives and
  // starts the camera; does not enable the drives. Throws std::invalid_argument (bad file: names
  // it and every bad key), common::ConfigError or hal::HalError (a device that cannot be opened).
  explicit DiamondRig(const DiamondRigOptions& options);
  ~DiamondRig();  // disables the drives (the safe state), stops the world
  DiamondRig(const DiamondRig&) = delete;
  DiamondRig& operator=(const DiamondRig&) = delete;

  bool simulated() const { return world_ != nullptr; }
  // False on a stepped simulated clock.
  bool real_time() const { return real_time_; }
  sim::DiamondWorld* world() const { return world_.get(); }
  const std::string& config_path() const { return config_path_; }
  // Where the nominal model came from ("" for the built-in a-priori set).
  const std::string& robot_description() const { return robot_description_; }
  const robots::DiamondModel& nominal() const { return nominal_; }
  common::Clock& clock() const { return *clock_; }
  hal::Rs485DriveBus& bus() const { return *bus_; }
  double cycle_period_s() const { return cycle_period_s_; }

  const std::string& camera_name() const { return camera_name_; }
  const std::string& camera_model_spec() const { return camera_model_spec_; }
  const vision::CameraModel& camera_model() const { return *camera_model_; }
  hal::Camera& camera() const { return *camera_; }
  double camera_fps() const { return camera_fps_; }
  // The camera pose in O as the file gives it (simulated: the world's true pose; real: measured,
  // its distance from the RCM is the scale gauge of the identification) and how it was obtained.
  const Eigen::Isometry3d& X_OC() const { return X_OC_; }
  const std::string& camera_distance_source() const { return camera_distance_source_; }
  // Marker detector settings sized for the marker's image at the home position (the search
  // window, the corner refinement window and the verification ring scale with its size in px).
  const vision::MarkerDetectorOptions& detector_options() const { return detector_options_; }

  // Configures and enables both drives (CSP). Throws hal::HalError naming the drive when one does
  // not enable.
  void Enable();
  bool enabled() const { return enabled_; }
  // Joint readings q (rad) of the last cycle.
  Eigen::Vector2d Readings() const;
  // Moves the tool to task point `task` (rad) along a straight line in (φ, γ) of `model` (null:
  // the nominal one), at a mean rate of `speed` (rad/s), with the control loop's safety (limits,
  // RCM closure, drive faults); the run ends when the task-space PD has settled there. The
  // report's outcome says whether it got there (kCompleted) and, if not, why. Drives enabled.
  // The loop runs at the drive cycle or 2.5 ms (the seed's rate), whichever is slower.
  control::DiamondLoopReport MoveTo(const Eigen::Vector2d& task, double speed,
                                    const robots::DiamondModel* model = nullptr);
  // Keeps cycling the drives (holding their targets) until the camera has a frame captured after
  // now and grabs it into `image` (mono8). Returns an empty string or the reason it failed.
  std::string GrabFresh(hal::Image* image);
  // Runs drive cycles (holding targets) for `seconds`.
  void Hold(double seconds);
  // Disables both drives.
  void Disable();
  // The drives' safe state between jobs: disabled and their communication watchdog switched off,
  // so that a pause in the bus cycles (the job's own work after its loop, the process exiting)
  // does not fault them with a lost heartbeat (0x8130). Enable() brings them up again.
  void Release();

 private:
  std::string config_path_;
  std::string robot_description_;
  robots::DiamondModel nominal_ = robots::DiamondModel::APriori();
  std::unique_ptr<sim::DiamondWorld> world_;
  common::Clock* clock_ = nullptr;
  std::unique_ptr<hal::Rs485DriveBus> bus_;
  double cycle_period_s_ = 0.001;
  std::string camera_name_;
  std::string camera_model_spec_;
  std::unique_ptr<vision::CameraModel> camera_model_;
  std::unique_ptr<hal::Camera> camera_;
  double camera_fps_ = 30.0;
  Eigen::Isometry3d X_OC_ = Eigen::Isometry3d::Identity();
  std::string camera_distance_source_;
  vision::MarkerDetectorOptions detector_options_;
  bool enabled_ = false;
  bool real_time_ = true;
};

}  // namespace kinevis::rigs
