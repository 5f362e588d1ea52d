#pragma once

// DiamondWorld: the simulated DIAMOND eye-surgery robot (issue 5, seed 001) — a clock, two RS485
// motor drives (Modbus RTU, multi-drop, units 1 and 2) on a pseudo-terminal at 3 Mbit/s, the
// plant (the true spherical parallelogram: joint readings -> forward kinematics -> tool point)
// and the marker camera. The host (Rs485DriveBus, `kinevis drive modbus-rtu:...`) reaches it
// through the pty exactly as through a USB-RS485 adapter; docs/simulation.md draws the picture.
//
// Truth and nominal: the true robot is the seed's identified set (robots/diamond/
// diamond_identified.yaml: R = 0.2221 m, α = 0.7634, β = 0.8037) plus joint offset errors; the
// nominal one, which the host loads, is the a-priori set (diamond_apriori.yaml: R = 0.2, α = β =
// π/4). Drive i (unit units[i]) reads q_i (rad); θ_i = q_i + true offset_i (seed 001 §V-B).
//
// Plant: as HexapodWorld (hexapod_world.h): the drives' plant hooks report the commanded joint
// angles; the plant solves seed 001 eq. (34)–(35) on the "+" branch for them. When the limbs
// cannot close (no assembly), collide (separation below the minimum) or leave their θ range, the
// mechanism holds and the drives see a following error. (φ, γ) outside the workspace box is not
// a mechanical limit and does not hold.
//
// Timing and threads: as HexapodWorld: kStepped (SimulatedClock, Step(), clock() for an
// in-process host; the Modbus exchanges themselves run on the line's thread in real time, as in
// the RS485 HAL tests) or kRealTime (SteadyClock, Start()). The plant state is guarded by one
// mutex, taken by the drive hooks (under the device mutex), by the plant update, and by plant()
// and the camera renders only to copy it.

#include <Eigen/Core>
#include <array>
#include <atomic>
#include <cmath>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "common/clock.h"
#include "hal/mock/cia402_device.h"
#include "robots/diamond/diamond_model.h"
#include "sim/world_common.h"  // WorldClock, WorldCameraConfig, internal::WorldConfigReader

namespace kinevis::hal {
class PtyPair;
class Rs485DriveSim;
}  // namespace kinevis::hal

namespace kinevis::sim {

struct DiamondWorldConfig {
  // Where the models came from (for messages); empty: the seed's sets built into robots/.
  std::string truth_description;
  std::string nominal_description;
  robots::DiamondModel truth = robots::DiamondModel::SeedIdentified();
  robots::DiamondModel nominal = robots::DiamondModel::APriori();
  // Added to truth.joint_offsets (rad): the encoders' zero is not where the design says. Default
  // 0.6° and −0.4°: a hand-mounted encoder.
  std::array<double, robots::kDiamondJoints> joint_offset_errors{0.6 * M_PI / 180,
                                                                 -0.4 * M_PI / 180};
  // The tool starts at this task point (φ, γ) (rad), the centre of the seed's working region.
  Eigen::Vector2d home_task{M_PI / 2, M_PI / 4};

  // Drives: two Modbus units on one line, joint i = units[i]; distinct ids in 1..247.
  std::array<int, robots::kDiamondJoints> units{1, 2};
  double counts_per_rad = 131072.0 / (2 * M_PI);  // a 17-bit encoder, > 0
  double max_velocity = 2.0;                      // rad/s, > 0
  double max_acceleration = 20.0;                 // rad/s^2, > 0
  double following_error_window = 0.05;           // rad, > 0
  int baud = 3'000'000;                           // named in the backend string (seed 001)

  double step_period_s = 0.0005;  // plant update (and stepping) period, s, in (0, 0.01]
  std::vector<WorldCameraConfig> cameras;

  std::string Validate() const;
};

// Reads a world config (`world: diamond`; docs/simulation.md). Throws std::invalid_argument
// naming the file and every bad key and value.
DiamondWorldConfig LoadDiamondWorldConfig(const std::string& path);

// The true robot of a config: truth with the joint offset errors added.
robots::DiamondModel TrueDiamondModel(const DiamondWorldConfig& config);

struct DiamondPlantState {
  common::Duration time{0};
  Eigen::Vector2d q = Eigen::Vector2d::Zero();      // joint readings (rad)
  Eigen::Vector2d task = Eigen::Vector2d::Zero();   // true (φ, γ) (rad)
  Eigen::Vector3d u_O = Eigen::Vector3d::UnitZ();   // true tool axis in O
  Eigen::Vector3d p_O_T = Eigen::Vector3d::Zero();  // true marker point in O (m)
  bool held = false;  // the commanded joints are not a feasible configuration (reason)
  robots::DiamondReach reason = robots::DiamondReach::kOk;
  uint64_t updates = 0;
  uint64_t holds = 0;
};

class DiamondWorld {
 public:
  enum class Timing { kStepped, kRealTime };

  // Builds the truth, the pty (and the symbolic link `link` to it when not empty) and the drive
  // simulator, whose line is served at once. Throws std::invalid_argument for a bad config or an
  // unreachable home; hal::HalError when the pty cannot be made.
  explicit DiamondWorld(DiamondWorldConfig config, Timing timing = Timing::kStepped,
                        const std::string& link = "");
  ~DiamondWorld();
  DiamondWorld(const DiamondWorld&) = delete;
  DiamondWorld& operator=(const DiamondWorld&) = delete;

  const DiamondWorldConfig& config() const { return config_; }
  const robots::DiamondModel& true_model() const { return true_; }
  const robots::DiamondModel& nominal_model() const { return config_.nominal; }

  // "modbus-rtu:/dev/pts/N@3000000,8E1" (or the link); add ",unit=N" per drive.
  const std::string& backend() const;
  common::Clock& clock();          // as HexapodWorld::clock()
  void Step(common::Duration dt);  // kStepped only
  void StepTo(common::Duration t);
  void Start();  // kRealTime: the drives' stepping thread and the plant thread
  void Stop();

  DiamondPlantState plant() const;
  hal::Cia402Device& drive_device(int joint);  // joint 0 or 1

  // Makes the marker scene at a plant state for a camera at X_OC (pose of C in O).
  using SceneFactory = std::function<std::unique_ptr<vision::render::Scene>(
      const robots::DiamondModel& true_model, const DiamondPlantState& state,
      const Eigen::Isometry3d& X_OC)>;
  std::vector<std::string> RegisterCameras(SceneFactory factory);
  std::vector<std::string> camera_sources() const;

 private:
  struct Camera;
  hal::PlantFeedback OnDriveStep(int joint, const hal::AxisState& commanded);
  void UpdatePlant();

  const DiamondWorldConfig config_;
  const Timing timing_;
  const robots::DiamondModel true_;
  common::SimulatedClock sim_time_;
  std::unique_ptr<WorldClock> world_clock_;
  common::Clock* clock_;
  std::unique_ptr<hal::PtyPair> pty_;
  std::unique_ptr<hal::Rs485DriveSim> drives_;

  mutable std::mutex mutex_;
  DiamondPlantState state_;
  std::array<double, robots::kDiamondJoints> commanded_q_{};
  std::array<bool, robots::kDiamondJoints> hooked_{};

  std::atomic<bool> running_{false};
  std::thread plant_thread_;
  std::vector<std::unique_ptr<Camera>> cameras_;
};

}  // namespace kinevis::sim
