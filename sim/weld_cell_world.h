#pragma once

// WeldCellWorld: the simulated weld-repair cell of seed 004 (issue 5) — a clock, the weld-robot
// controller simulator (hal::WeldRobotSim: Modbus TCP on loopback or RTU on a pty), the plant
// (the TRUE 5-DOF robot, whose torch follows the controller's actual joints by forward
// kinematics), the laser-triangulation scanner mounted on link 5 and the workpiece it scans. The
// host (hal::WeldRobotClient, `kinevis weld-robot`, the scan and weld-path programs) reaches the
// robot only through Modbus and the scanner only through its camera source, exactly as on the
// real cell; docs/simulation.md draws the picture.
//
// Frames (robots/weld5/weld5_model.h defines 0, 5 and T; vision/render/scenes/laser_scene.h
// defines C and S):
//   0  robot base frame.
//   5  D–H frame of link 5 (the torch carrier).
//   C  the scanner camera frame (x right, y down in the image, z along the optical axis). The
//      scanner — camera, fixed and rotating laser — is one rigid body clamped to the torch; its
//      pose in link 5 is the mount X_5C. Default (nominal, the CAD value): the camera 50 mm
//      behind the torch along −x_5, 60 mm to its side along −y_5 and 100 mm down the torch
//      barrel along z_5, looking along the torch axis (R_5C = I: z_C = z_5, towards the work).
//      The rotating laser's emitter then sits ≈ 100 mm along y_C, on the torch's other side.
//      The TRUE mount differs from it by a realistic clamping error (default: (+0.6, −0.4,
//      +0.9) mm and rpy (0.4°, −0.3°, 0.7°)), which hand–eye calibration has to find.
//   S  the workpiece's surface frame, z_S the surface normal out of the material; its pose in the
//      base frame is X_0S (config). Default: a blade standing upright 0.70 m in front of the
//      robot (x_S up along z_0, z_S facing the robot along −x_0), 0.40 m in front of the camera
//      at the home joints — in the seed's 250–650 mm working range.
//
// Truth and nominal: the nominal robot is the description file's (robots/weld5/weld5.yaml, or
// Weld5Model::Seed with its torch when none is given); the TRUE robot perturbs every link's a,
// d (normal, dh_length_sigma_mm) and α, θ offset (normal, dh_angle_sigma_deg), drawn from a
// std::mt19937 seeded with `seed`: machining and assembly errors that kinematic calibration can
// find. Joint values q are the controller's (hal::WeldJoints, SI), entering the D–H chain as
// robots::Weld5Model says.
//
// What the scanner sees at joints q: X_0C = FK_true(q) · X_5C (true), X_CS = X_0C⁻¹ · X_0S; the
// laser scene (laser_scene.h) is built with that X_CS and rendered through the scanner camera
// model (default the built-in "tsai-seed004"). The rotating laser's angle (cot θ_y, seed 004
// eq. (17)) is a world setting the host cannot change over Modbus (on the real cell it is the
// scanner's own stepper; SetLaserAngle()). Every rendered frame is logged with the actual
// joints it was rendered at (ScanRecord): the "joint readings at each scan".
//
// Timing, as HexapodWorld: kStepped (tests): a SimulatedClock, the controller's executor thread
// off; Step(dt) advances the clock and the controller's motion; clock() is a WorldClock an
// in-process host (WeldRobotClient::Options::clock) sleeps on, which steps the world. The Modbus
// server itself answers on its own thread in real time. kRealTime (`kinevis sim world
// weld-cell`): SteadyClock, the controller's executor thread.
//
// Threads: every public method is thread-safe. The controller's state is read through
// WeldRobotSim::state() (its own lock); the laser settings and the scan log are guarded by the
// world's mutex; each render holds the render mutex (the renderer's scratch).

#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "common/clock.h"
#include "hal/camera/camera.h"
#include "robots/weld5/weld5_model.h"
#include "sim/world_common.h"  // WorldClock, internal::WorldConfigReader, common::Problems
#include "vision/camera/camera_model.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/laser_scene.h"

namespace kinevis::hal {
class WeldRobotSim;
class FrameServer;
struct FrameServerOptions;
}  // namespace kinevis::hal

namespace kinevis::sim {

// The nominal scanner mount X_5C described above (CAD).
Eigen::Isometry3d NominalScannerMount();
// The default true mount: NominalScannerMount() with the clamping error described above.
Eigen::Isometry3d DefaultTrueScannerMount();
// The default workpiece pose X_0S described above.
Eigen::Isometry3d DefaultWorkpiecePose();
// The default blade: 200 × 160 mm, curvatures (1.5, 0.5, 0.3) 1/m, three cavitation pits of
// 0.6–1.2 mm depth and 2–4 mm width near the centre.
vision::render::LaserSceneParameters DefaultBlade();
// The flat calibration boards, posed like the workpiece (DefaultWorkpiecePose()): with
// `gauge_block`, 300 x 200 mm with the seed's gauge block (100 x 50 x 10 mm) at its centre (mount
// calibration); without, 300 x 260 mm with the seed's 9 x 9 dot grid at 26.5 mm (scanner
// calibration).
vision::render::LaserSceneParameters DefaultCalibrationBoard(bool gauge_block);

struct WeldCellWorldConfig {
  // The nominal robot (what the host loads) and where it came from (for messages; empty:
  // Weld5Model::Seed with the torch of robots/weld5/weld5.yaml, px5 25 mm, pz5 250 mm, β 0).
  std::string robot_description;
  robots::Weld5Model nominal =
      robots::Weld5Model::Seed(robots::Weld5TorchTransform(0.025, 0.250, 0.0));

  // True-vs-nominal D–H errors, normal per link parameter, >= 0 (0: the truth is the nominal).
  double dh_length_sigma_mm = 0.2;   // a_i and d_i
  double dh_angle_sigma_deg = 0.05;  // α_i and the θ offset
  uint32_t seed = 1;

  // Scanner: camera model spec (vision::OpenCameraModel: "builtin:NAME" or a file) — the TRUE
  // intrinsics the renderer uses; the mount (nominal, and the truth the renderer uses); the
  // laser geometry in C (seed 004, Table 2); the rotating laser's initial angle cot θ_y.
  std::string scanner_camera = "builtin:tsai-seed004";
  Eigen::Isometry3d X_5C_nominal = NominalScannerMount();
  Eigen::Isometry3d X_5C = DefaultTrueScannerMount();
  vision::render::LaserScannerGeometry scanner;
  double cot_theta_y = 0.25;  // finite
  bool fixed_laser_on = true;
  bool rotating_laser_on = true;
  std::string camera_name = "weld-scanner";  // render source name ("sim:weld-scanner")
  double fps = 5.0;                          // nominal frame rate, > 0
  vision::render::RenderOptions render;

  // The workpiece: surface kind, extent, blade shape, pits, gauge block and radiances (X_CS is
  // ignored: it follows from the robot) and its pose in the base frame.
  vision::render::LaserSceneParameters workpiece = DefaultBlade();
  Eigen::Isometry3d X_0S = DefaultWorkpiecePose();

  // The controller: Modbus TCP on tcp_host:tcp_port (0: any free port), or RTU on a new pty
  // (with a symbolic link rtu_link when not empty).
  bool rtu = false;
  std::string tcp_host = "127.0.0.1";
  int tcp_port = 0;  // 0..65535
  std::string rtu_link;
  int unit = 1;              // Modbus unit id, 1..247
  int buffer_capacity = 16;  // segments, 1..1000
  // Power-on joints [θ1, θ2, pz3, θ4, θ5] (rad, rad, m, rad, rad), within the nominal limits.
  // Default: the torch horizontal, pointing at the workpiece (pz3 = 0.2 m).
  std::array<double, robots::kWeld5Joints> initial_joints{0.0, 0.0, 0.2, 0.0, 0.0};

  double step_period_s = 0.001;  // kStepped step of the controller's motion, s, in (0, 0.1]

  // Empty when usable; otherwise every bad field and its value, "; "-separated.
  std::string Validate() const;
};

// Reads a world config (`world: weld-cell`; the keys are in docs/simulation.md and
// config/weld-cell-sim.yaml). Missing keys keep the defaults above. Throws std::invalid_argument
// naming the file and every bad key and value.
WeldCellWorldConfig LoadWeldCellWorldConfig(const std::string& path);

// The true robot of a config: the nominal with the seeded D–H errors. Deterministic.
robots::Weld5Model TrueWeld5Model(const WeldCellWorldConfig& config);

// One rendered scan: when, at which actual joints, and where the scanner truly was.
struct ScanRecord {
  uint64_t frame_id = 0;
  common::Duration time{0};                                // world clock at the render
  std::array<double, robots::kWeld5Joints> joints{};       // actual joints (controller values, SI)
  Eigen::Isometry3d X_0C = Eigen::Isometry3d::Identity();  // true scanner pose
  double cot_theta_y = 0.0;                                // the rotating laser's angle
};

class WeldCellWorld {
 public:
  enum class Timing { kStepped, kRealTime };

  // Builds the truth, opens the scanner camera model and starts serving Modbus. Throws
  // std::invalid_argument for a bad config or camera model; common::ConfigError / hal::HalError
  // when the controller cannot listen (WeldRobotSim).
  explicit WeldCellWorld(WeldCellWorldConfig config, Timing timing = Timing::kStepped);
  ~WeldCellWorld();  // unregisters the camera, stops the frame server and the controller
  WeldCellWorld(const WeldCellWorld&) = delete;
  WeldCellWorld& operator=(const WeldCellWorld&) = delete;

  const WeldCellWorldConfig& config() const { return config_; }
  Timing timing() const { return timing_; }
  const robots::Weld5Model& true_model() const { return true_; }
  const robots::Weld5Model& nominal_model() const { return config_.nominal; }

  // The controller's Modbus backend ("modbus-tcp:127.0.0.1:40123" or "modbus-rtu:...").
  const std::string& backend() const;
  hal::WeldRobotSim& robot();

  // kStepped: a WorldClock (sleeping on it steps the world); kRealTime: the SteadyClock.
  common::Clock& clock();
  // kStepped only (aborts otherwise): advances time and the controller's motion by dt, in steps
  // of step_period_s.
  void Step(common::Duration dt);
  void StepTo(common::Duration t);

  // The controller's actual joints now.
  std::array<double, robots::kWeld5Joints> joints() const;
  // True scanner pose at joints q: FK_true(q) · X_5C.
  Eigen::Isometry3d TrueScannerPose(const std::array<double, robots::kWeld5Joints>& q) const;

  // The rotating laser's angle as cot θ_y (finite; std::invalid_argument otherwise).
  void SetLaserAngle(double cot_theta_y);
  double laser_angle() const;
  // Switches the lasers (the scanner's own controls; initially the config's fixed_laser_on and
  // rotating_laser_on).
  void SetLasers(bool fixed_on, bool rotating_on);

  // The laser scene the scanner sees at joints q (its X_CS from the true robot and mount).
  std::unique_ptr<vision::render::LaserScene> SceneAt(
      const std::array<double, robots::kWeld5Joints>& q) const;
  const vision::CameraModel& scanner_camera() const { return *camera_; }
  // Mono8, the scanner camera's size, config fps.
  hal::CameraFormat camera_format() const;

  // Renders a scan at the actual joints of this moment into `out` (camera-sized), logs and
  // returns its record. `truth` may be null.
  ScanRecord RenderScan(uint64_t frame_id, const vision::ImageView8& out,
                        vision::render::GroundTruth* truth = nullptr);
  // The scans rendered so far, oldest first (the last 10000).
  std::vector<ScanRecord> scan_log() const;

  // Registers the scanner as render source "sim:NAME" (config camera_name) for this process;
  // returns the name. Throws common::ConfigError when the name is taken. At most once.
  std::string RegisterCamera();
  // Serves the scanner's frames over TCP (hal::FrameServer, rendered on request at clock()
  // time); returns the source string "net:127.0.0.1:PORT". At most once. Throws hal::HalError
  // when it cannot listen.
  std::string ServeCamera(const hal::FrameServerOptions& options);

 private:
  const WeldCellWorldConfig config_;
  const Timing timing_;
  const robots::Weld5Model true_;
  common::SimulatedClock sim_time_;
  std::unique_ptr<WorldClock> world_clock_;
  common::Clock* clock_;
  std::unique_ptr<vision::CameraModel> camera_;
  std::unique_ptr<hal::WeldRobotSim> robot_;

  mutable std::mutex mutex_;  // laser settings, scan log
  double cot_theta_y_;
  bool fixed_on_ = true;
  bool rotating_on_ = true;
  std::deque<ScanRecord> scan_log_;

  std::mutex render_mutex_;  // the renderer's scratch
  std::unique_ptr<vision::render::Renderer> renderer_;

  std::string registered_;
  std::unique_ptr<hal::FrameServer> frame_server_;
};

}  // namespace kinevis::sim
