#pragma once

// The weld-repair cell as the weld commands (record, calibrate scanner|scanner-mount, scan,
// weld-run) use it: the nominal robot model, the weld robot's Modbus controller
// (hal::WeldRobotClient) and the scanner's camera with its model — either a simulated
// WeldCellWorld in this process (a world config, `world: weld-cell`, or none: the defaults) or the
// real cell (a deployment file, `rig: weld-cell`; docs/deployment.md). The commands cannot tell
// which, except for the two things only a simulation can do for them: set the rotating laser's
// angle frame by frame (the real scanner sweeps on its own stepper, and the host never needs the
// angle: eq. (11) finds it from the stripes' intersection), and stand in for the operator who
// jogs the torch onto a gauge-block corner.
//
// Frames as in robots/weld5/weld5_model.h and sim/weld_cell_world.h: 0 the robot base, 5 link 5,
// T the torch, C the scanner camera, S the workpiece surface.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <memory>
#include <string>

#include "hal/camera/camera.h"
#include "robots/weld5/weld5_model.h"

namespace kinevis::common {
class Clock;
}  // namespace kinevis::common
namespace kinevis::hal {
class WeldRobotClient;
}  // namespace kinevis::hal
namespace kinevis::sim {
class WeldCellWorld;
}
namespace kinevis::vision {
class CameraModel;
}

namespace kinevis::rigs {

// What stands in front of the robot in a simulated cell (a real cell has what the operator put
// there). kFromConfig: the world config's workpiece.
enum class WeldWorkpiece { kFromConfig, kBlade, kDotBoard, kGaugeBlock };

struct WeldRigOptions {
  std::string config;  // a world config (simulated; empty: the defaults) or a deployment file
  WeldWorkpiece workpiece = WeldWorkpiece::kFromConfig;  // simulated only
};

class WeldRig {
 public:
  // Reads the file, builds the world (simulated) or connects to the robot, configures and
  // activates the robot client and starts the scanner camera. Throws std::invalid_argument (bad
  // file: names it and every bad key), common::ConfigError or hal::HalError (a device that cannot
  // be opened, configured or activated: names it).
  explicit WeldRig(const WeldRigOptions& options);
  ~WeldRig();  // stops the robot (the safe state: motion stopped, arc off), stops the world
  WeldRig(const WeldRig&) = delete;
  WeldRig& operator=(const WeldRig&) = delete;

  bool simulated() const { return world_ != nullptr; }
  sim::WeldCellWorld* world() const { return world_.get(); }
  const std::string& config_path() const { return config_path_; }
  const std::string& robot_description() const { return robot_description_; }
  // The nominal (CAD) robot: what the host knows.
  const robots::Weld5Model& nominal() const { return nominal_; }
  // The nominal (CAD) scanner mount X_5C: the start of mount calibration.
  const Eigen::Isometry3d& X_5C_nominal() const { return X_5C_nominal_; }
  common::Clock& clock() const { return *clock_; }
  hal::WeldRobotClient& robot() const { return *robot_; }

  const std::string& camera_model_spec() const { return camera_model_spec_; }
  const vision::CameraModel& camera_model() const { return *camera_model_; }
  hal::Camera& camera() const { return *camera_; }
  double camera_fps() const { return camera_fps_; }

  // The actual joints, read from the controller. Throws hal::HalError when the read fails.
  robots::Vector5d Joints() const;
  // Moves to `q` in one joint-space segment, no joint faster than `speed_fraction` (0, 1] of its
  // limit, and waits until the robot is there and has settled for `settle_s`. Returns an empty
  // string or why it did not get there (limits, an alarm, a lost link; the robot is then in its
  // safe state).
  std::string MoveTo(const robots::Vector5d& q, double speed_fraction, double settle_s = 0.05);
  // Grabs a frame captured after now (mono8) into `image`; the joints at that frame in `q`
  // (simulated: the world's record of the render; real: read right after the grab, with the
  // robot standing still). Returns an empty string or the reason it failed.
  std::string GrabFresh(hal::Image* image, robots::Vector5d* q);

  // Simulated only (false on a real cell): the rotating laser's angle as cot θ_y, and which
  // lasers are on.
  bool SetLaserAngle(double cot_theta_y);
  bool SetLasers(bool fixed_on, bool rotating_on);
  // Simulated only: the joints at which an operator jogging the torch would touch the point p_0
  // (base frame, m) with the torch axis along `axis_0` (unit, pointing into the work), on the
  // TRUE robot, with a touch error of `touch_sigma` (m, per axis, seeded). nullopt-like: returns
  // false when the point cannot be reached.
  bool OperatorTouch(const Eigen::Vector3d& p_0, const Eigen::Vector3d& axis_0, double touch_sigma,
                     robots::Vector5d* q) const;

 private:
  std::string config_path_;
  std::string robot_description_;
  robots::Weld5Model nominal_;
  Eigen::Isometry3d X_5C_nominal_ = Eigen::Isometry3d::Identity();
  std::unique_ptr<sim::WeldCellWorld> world_;
  common::Clock* clock_ = nullptr;
  std::unique_ptr<hal::WeldRobotClient> robot_;
  std::string camera_model_spec_;
  std::unique_ptr<vision::CameraModel> camera_model_;
  std::unique_ptr<hal::Camera> camera_;
  double camera_fps_ = 5.0;
  mutable uint64_t touches_ = 0;
};

}  // namespace kinevis::rigs
