#pragma once

// HexapodWorld: a simulated Gough–Stewart platform (issue 5) — a clock, six CiA 402 drive
// simulators on a virtual CAN bus, the plant (the true robot, whose platform pose follows the
// leg lengths by forward kinematics) and the cameras that watch it. The host side (CanopenMaster,
// `kinevis drive`, the controllers) talks to it only through the CAN bus, exactly as to the real
// machine; docs/simulation.md draws the picture.
//
// Truth and nominal. The world is built from a robot description (the nominal, CAD model the host
// also loads) and perturbs it into the true robot the plant obeys: every base and platform
// attachment point moves by a random error (per axis, normal, sigma in mm) and every joint offset
// q_j0 by another, drawn from a std::mt19937 with the config's seed. So calibration has something
// to find, and the same seed always gives the same robot.
//
// Drives. Drive j (CANopen node nodes[j]) is leg j. Its position is the actuator reading s_j in m
// (counts = s_j * counts_per_metre); the true leg length is q_j = q_j0_true + s_j (seed 002,
// q_j = q_j0 + s_j). The drive's mechanical end stops are the true stroke, [leg_length_min −
// q_j0_true, leg_length_max − q_j0_true]. The world starts at the description's home pose: the
// legs are set so that the true platform is at X_BP_home.
//
// Plant (Step, or the plant thread in real time): each drive step reports the commanded axis
// motion through Cia402Device's plant hook; the plant then solves forward kinematics of the true
// model for the commanded leg lengths, warm-started from the previous pose. When FK converges the
// legs move there and the true pose is updated; when it does not (singular, no assembly) the
// platform holds: the legs stay where they were, the drives report that (their following error
// grows and they fault, as a real drive against a jammed axis would), and plant().held says so
// until a commanded configuration is feasible again.
//
// Timing, two modes:
//  - kStepped (tests, benches): time is a SimulatedClock that moves only in Step(dt) (or when a
//    host sleeps on clock(), which steps the world up to the deadline). Deterministic: the drive
//    simulators are serviced, not threaded.
//  - kRealTime (`kinevis sim world hexapod`): the SteadyClock directly. Start() runs the drive
//    simulators' own threads and a plant thread that updates the pose every step_period_s.
//    (Chosen over a SimulatedClock driven from the steady clock: the simulators already run in
//    real time on any Clock, and a second clock would only add the jitter of its driver.)
//
// Threads: every public method is thread-safe. The plant state is guarded by one mutex that the
// drive plant hooks take (under the device's mutex: lock order device -> world) and that
// plant() and the camera renders take only long enough to copy the state, so a render never
// sees a half-updated pose and never blocks a step for the length of a frame.
//
// Cameras: each camera of the config becomes a render source "sim:NAME" (hal/camera/sim_camera.h)
// that renders the legs at the true pose of the moment of the Grab. The scene comes from a
// SceneFactory (RegisterCameras()); see sim/README.md for the default one.

#include <Eigen/Geometry>
#include <array>
#include <atomic>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "common/clock.h"
#include "common/config_error.h"
#include "hal/can/can_bus.h"
#include "hal/mock/cia402_device.h"
#include "robots/hexapod/hexapod_model.h"
#include "sim/world_common.h"
#include "vision/render/renderer.h"

namespace kinevis::hal {
class VirtualCanNetwork;
class CanopenDriveSim;
class PtyPair;
class SlcanAdapterSim;
}  // namespace kinevis::hal

namespace kinevis::sim {

struct HexapodWorldConfig {
  // Where the nominal model came from (for messages); empty: robots::HexapodModel::Default().
  std::string robot_description;
  robots::HexapodModel nominal = robots::HexapodModel::Default();
  Eigen::Isometry3d X_BP_home = robots::HexapodModel::NominalPose();

  // True-vs-nominal differences, normal per axis / per leg, >= 0 (0: the truth is the nominal).
  // Defaults: machining and assembly tolerances of a hand-built platform.
  double base_point_sigma_mm = 0.5;      // A_j in B
  double platform_point_sigma_mm = 0.5;  // B_j in P
  double joint_offset_sigma_mm = 1.0;    // q_j0
  uint32_t seed = 1;

  // Drives: one CANopen node per leg, leg j = nodes[j]; 6 distinct ids in 1..127.
  std::array<int, robots::kHexapodLegs> nodes{1, 2, 3, 4, 5, 6};
  double counts_per_metre = 1.0e6;        // encoder resolution of the actuators (1 µm), > 0
  double max_velocity = 0.1;              // m/s, > 0
  double max_acceleration = 1.0;          // m/s^2, > 0
  double following_error_window = 0.005;  // m, > 0 (0x6065)

  // The virtual CAN bus: its registry name (the in-process host opens "virtual:NAME"), bit rate.
  std::string network = "hexapod";
  int can_bitrate = 1'000'000;  // bit/s, one an slcan adapter knows (10k..1M)

  // Period of the plant update (and of the drive servicing in kStepped mode), s, > 0.
  double step_period_s = 0.0005;

  std::vector<WorldCameraConfig> cameras;

  // Empty when usable; otherwise every bad field and its value, "; "-separated.
  std::string Validate() const;
};

// Reads a world config (docs/simulation.md): `world: hexapod`, `robot:` (a description file,
// relative to the config's folder), `perturbation:`, `seed:`, `drives:`, `can:`,
// `step_period_ms:`, `cameras:`. Missing keys keep the defaults above. Throws
// std::invalid_argument naming the file and every bad key and value.
HexapodWorldConfig LoadHexapodWorldConfig(const std::string& path);

// The two cameras of config/hexapod-sim.yaml (a test keeps them equal): "hexapod-perspective"
// (builtin:tsai-seed004, 1616×1216, in front of and above the robot, 30° round so that no leg
// hides another) and "hexapod-omni" (builtin:unified-default, 640×480, between the legs 3 cm above
// the base centre, mirror axis up), both at 10 fps with supersampling 4 and noise σ = 1 grey
// level. For hosts that build a world without a config file (the hexapod commands' default).
std::vector<WorldCameraConfig> DefaultHexapodCameras();

// The true robot of a config: the nominal with the seeded perturbations. Deterministic.
robots::HexapodModel TrueHexapodModel(const HexapodWorldConfig& config);

// The state of the plant at one instant.
struct HexapodPlantState {
  common::Duration time{0};                                // world clock
  Eigen::Isometry3d X_BP = Eigen::Isometry3d::Identity();  // true pose of P in B
  robots::Vector6d q = robots::Vector6d::Zero();           // true leg lengths (m)
  robots::Vector6d s = robots::Vector6d::Zero();           // actuator readings (m)
  // The platform does not follow the drives: FK of the last commanded legs failed (fk_status).
  bool held = false;
  robots::ForwardKinematicsStatus fk_status = robots::ForwardKinematicsStatus::kConverged;
  uint64_t updates = 0;  // plant updates so far
  uint64_t holds = 0;    // plant updates that held
};

class HexapodWorld {
 public:
  enum class Timing { kStepped, kRealTime };

  // Builds the truth, the bus and the drives (not started). Throws std::invalid_argument with
  // config.Validate()'s message, or when the home pose is not reachable by the true robot;
  // common::ConfigError when the network name is in use with another bit rate.
  explicit HexapodWorld(HexapodWorldConfig config, Timing timing = Timing::kStepped);
  ~HexapodWorld();  // Stop(); unregisters the cameras
  HexapodWorld(const HexapodWorld&) = delete;
  HexapodWorld& operator=(const HexapodWorld&) = delete;

  const HexapodWorldConfig& config() const { return config_; }
  Timing timing() const { return timing_; }
  const robots::HexapodModel& true_model() const { return true_; }
  const robots::HexapodModel& nominal_model() const { return config_.nominal; }

  // The clock a host in this process uses: kStepped, a WorldClock (sleeping on it steps the
  // world); kRealTime, the SteadyClock.
  common::Clock& clock();
  // kStepped only (aborts otherwise): advances the time by dt in steps of step_period_s; each
  // step services the six drives (CAN frames, motion) and updates the plant.
  void Step(common::Duration dt);
  void StepTo(common::Duration t);

  // A new node on the world's CAN bus, for an in-process host (CanopenMaster). The bus is also
  // reachable as "virtual:NAME" through hal::OpenCanBus in this process.
  std::unique_ptr<hal::CanBus> ConnectHost(const std::string& node_name = "host");
  // "virtual:NAME".
  std::string virtual_backend() const;

  // kRealTime: exposes the bus to other processes through a simulated slcan USB-CAN adapter on a
  // pseudo-terminal (and a symbolic link to it when `link` is not empty). Returns the backend
  // string "slcan:/dev/pts/N@115200,bitrate=B". Call before Start(); at most once. Throws
  // hal::HalError when the pty cannot be made.
  std::string ExposeSlcan(const std::string& link = "");

  // kRealTime: starts the drives' threads (and the adapter) and the plant thread. Idempotent.
  void Start();
  void Stop();

  HexapodPlantState plant() const;
  // Drive of leg j (0..5): its device, for tests and fault injection.
  hal::Cia402Device& drive_device(int leg);
  hal::CanopenDriveSim& drive(int leg);

  // Makes a scene of the legs at a plant state, as seen by a camera at X_BC (pose of C in B).
  using SceneFactory = std::function<std::unique_ptr<vision::render::Scene>(
      const robots::HexapodModel& true_model, const HexapodPlantState& state,
      const Eigen::Isometry3d& X_BC)>;
  // Registers every configured camera as a render source "sim:NAME" rendering factory's scene.
  // Returns the registered names. Throws std::invalid_argument for a bad camera model spec and
  // common::ConfigError when a name is taken.
  std::vector<std::string> RegisterCameras(SceneFactory factory);
  std::vector<std::string> camera_sources() const;

 private:
  struct Camera;
  hal::PlantFeedback OnDriveStep(int leg, const hal::AxisState& commanded);
  void UpdatePlant();
  void PlantLoop();

  const HexapodWorldConfig config_;
  const Timing timing_;
  const robots::HexapodModel true_;

  common::SimulatedClock sim_time_;
  std::unique_ptr<WorldClock> world_clock_;
  common::Clock* clock_;  // the drives' and the network's clock

  std::shared_ptr<hal::VirtualCanNetwork> network_;
  std::vector<std::unique_ptr<hal::CanBus>> drive_buses_;
  std::vector<std::unique_ptr<hal::CanopenDriveSim>> drives_;
  std::unique_ptr<hal::PtyPair> pty_;
  std::unique_ptr<hal::CanBus> adapter_bus_;
  std::unique_ptr<hal::SlcanAdapterSim> adapter_;

  mutable std::mutex mutex_;  // guards the plant state below
  HexapodPlantState state_;
  robots::HexapodData fk_data_;
  std::array<double, robots::kHexapodLegs> commanded_s_{};  // m
  std::array<bool, robots::kHexapodLegs> hooked_{};         // the drive's first step has been seen

  std::atomic<bool> running_{false};
  std::thread plant_thread_;
  std::vector<std::unique_ptr<Camera>> cameras_;
};

}  // namespace kinevis::sim
