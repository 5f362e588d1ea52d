#pragma once

// The hexapod as the hexapod commands (record, calibrate, servo) use it: the nominal model, six
// CiA 402 drives behind a CanopenMaster, and one camera with its model and a rough pose — either a
// simulated HexapodWorld in this process (a world config, `world: hexapod`) or real hardware (a
// deployment file, `rig: hexapod`; docs/hexapod-calibration.md). The commands cannot tell which.
//
// Frames as in robots/hexapod/hexapod_model.h: B the base, P the platform, C the camera.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <chrono>
#include <memory>
#include <string>
#include <vector>

#include "hal/camera/camera.h"
#include "robots/hexapod/hexapod_model.h"
#include "vision/hexapod/leg_edges.h"

namespace kinevis::common {
class Clock;
}  // namespace kinevis::common
namespace kinevis::hal {
class Cia402CanDrive;
namespace canopen {
class CanopenMaster;
}
}  // namespace kinevis::hal
namespace kinevis::sim {
class HexapodWorld;
struct HexapodWorldConfig;
}  // namespace kinevis::sim
namespace kinevis::vision {
class CameraModel;
}

namespace kinevis::rigs {

struct HexapodRigOptions {
  std::string config;  // a world config (simulated) or a deployment file (real hardware)
  std::string camera;  // camera name; empty: the first of the file
  // A simulated world from this config in memory (the experiments' sweeps over cameras and
  // noise); when set, `config` only names it in messages.
  std::shared_ptr<const sim::HexapodWorldConfig> world;
};

class HexapodRig {
 public:
  // Reads the file, builds (or connects to) the drives and opens the camera; does not enable
  // the drives. Throws std::invalid_argument (bad file: names it and every bad key),
  // common::ConfigError or hal::HalError (a device that cannot be opened).
  explicit HexapodRig(const HexapodRigOptions& options);
  ~HexapodRig();  // disables the drives (the safe state), stops the world
  HexapodRig(const HexapodRig&) = delete;
  HexapodRig& operator=(const HexapodRig&) = delete;

  bool simulated() const { return world_ != nullptr; }
  sim::HexapodWorld* world() const { return world_.get(); }
  const std::string& config_path() const { return config_path_; }
  // Where the nominal model came from ("" for the built-in default).
  const std::string& robot_description() const { return robot_description_; }
  const robots::HexapodModel& nominal() const { return nominal_; }
  common::Clock& clock() const { return *clock_; }
  hal::canopen::CanopenMaster& master() const { return *master_; }
  const std::vector<hal::Cia402CanDrive*>& drives() const { return drives_; }

  const std::string& camera_name() const { return camera_name_; }
  const std::string& camera_model_spec() const { return camera_model_spec_; }
  const vision::CameraModel& camera_model() const { return *camera_model_; }
  // The camera pose in B as the file gives it (simulated: the true one; real: a hand estimate
  // that only seeds the leg predictions).
  const Eigen::Isometry3d& X_BC_hint() const { return X_BC_hint_; }
  double camera_fps() const { return camera_fps_; }
  // The camera (active, on clock()).
  hal::Camera& camera() const { return *camera_; }
  // The platform's home pose (the description's; HexapodModel::NominalPose() without one).
  const Eigen::Isometry3d& home_pose() const { return X_BP_home_; }
  // How this camera's leg edges are located (vision/hexapod/leg_edges.h): simulated, the
  // step-ramp model with the renderer's blur (known exactly); real, `camera.edge_locator` and
  // `camera.edge_blur_px` of the deployment file (docs/hexapod-rig.md).
  const vision::hexapod::LegEdgeOptions& edge_options() const { return edge_options_; }
  // The drive cycle (SYNC period), s.
  double cycle_period_s() const { return 1e-6 * static_cast<double>(cycle_period_.count()); }

  // Configures and enables the six drives in cyclic synchronous position mode. Throws
  // hal::HalError naming the drive when one does not enable.
  void Enable();
  // Actuator readings s_j (m) of the last cycle.
  robots::Vector6d Readings() const;
  // Moves every leg from where it is to `s_target` along a cosine ramp no leg of which exceeds
  // `speed` (m/s), then holds for `settle_s`. Returns an empty string, or why it stopped (a drive
  // fault, naming the drive and its error code).
  std::string MoveTo(const robots::Vector6d& s_target, double speed, double settle_s);
  // Keeps cycling the drives (holding their targets) until the camera has a frame captured after
  // now, and grabs it into `image` (mono8). Returns an empty string or the reason it failed.
  std::string GrabFresh(hal::Image* image);
  // Runs drive cycles (holding targets) for `seconds`.
  void Hold(double seconds);
  // Disables every drive.
  void Disable();

 private:
  std::string config_path_;
  std::string robot_description_;
  robots::HexapodModel nominal_;
  std::unique_ptr<sim::HexapodWorld> world_;
  common::Clock* clock_ = nullptr;
  std::unique_ptr<hal::canopen::CanopenMaster> master_;
  std::vector<hal::Cia402CanDrive*> drives_;
  std::string camera_name_;
  std::string camera_model_spec_;
  std::unique_ptr<vision::CameraModel> camera_model_;
  std::unique_ptr<hal::Camera> camera_;
  Eigen::Isometry3d X_BC_hint_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d X_BP_home_ = robots::HexapodModel::NominalPose();
  vision::hexapod::LegEdgeOptions edge_options_;
  double camera_fps_ = 10.0;
  std::chrono::microseconds cycle_period_{4000};
};

}  // namespace kinevis::rigs
