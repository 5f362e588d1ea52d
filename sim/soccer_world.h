#pragma once

// SoccerRobotWorld: a RoboCup middle-size robot with its non-single-viewpoint catadioptric camera
// (seed 000, the CAMBADA robot) standing on the field (issue 5). The world holds the TRUE camera
// — the seed's 4 mm set with realistic misalignments — the robot's pose on the field, the field
// scene and the renderer; the host sees only the camera's frames ("sim:soccer-omni" in-process,
// "net:HOST:PORT" from another process) and, for checking a calibration, the ground truth of
// every pixel.
//
// Frames (hyperbolic_mirror_camera.h, soccer_field_scene.h): C the camera model's frame, G the
// camera's ground frame (origin under the mirror axis, x_G robot forward, y_G left, z_G up),
// F the field frame (origin at the centre spot). X_FG = (robot_x, robot_y, robot_heading).
//
// Truth and nominal: the nominal camera is HyperbolicMirrorParameters::Seed000Lens4mm() (no
// misalignment: what the seed's map assumes before calibration); the TRUE one adds the seed's
// three misalignment factors (§4.2): a sensor offset (d_x, d_z), sensor rotations (γ, ρ, θ) and a
// mirror-axis tilt (ground ρ, θ). Defaults — a low-cost camera on a plastic lens mount, as the
// seed describes it: d = (0.30, −0.20) mm; γ = 0.8°, ρ = 0.6°, θ = −0.5°; mirror tilt ρ = 0.5°,
// θ = −0.3°. All configurable (`camera:` in the config; any HyperbolicMirrorParameters field).
//
// Ground truth (seed §5's distance map, with the TRUE parameters): for a pixel, the ground point
// its reflected ray meets, in G and in F, and its distance from the robot (|p_G|, the map's
// "distance"). It is exact for the renderer: the rendered pixel shows the field at that point.
//
// Nothing moves in this world unless the host (or a test) moves the robot (SetRobotPose). Time:
// clock() is a SimulatedClock in kStepped mode (frame time stamps only) and the SteadyClock in
// kRealTime. Threads: every public method is thread-safe (the scene is swapped under a mutex;
// renders hold the render mutex).

#include <Eigen/Core>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "common/clock.h"
#include "hal/camera/camera.h"
#include "vision/camera/hyperbolic_mirror_camera.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/soccer_field_scene.h"

namespace kinevis::hal {
class FrameServer;
struct FrameServerOptions;
}  // namespace kinevis::hal

namespace kinevis::sim {

// Seed000Lens4mm() with the default misalignments above.
vision::HyperbolicMirrorParameters DefaultTrueSoccerCamera();
// The same parameters with every misalignment (sensor offset and rotations, mirror tilt) set to
// zero: the camera the seed's uncalibrated map assumes.
vision::HyperbolicMirrorParameters WithoutMisalignment(vision::HyperbolicMirrorParameters p);

struct SoccerWorldConfig {
  vision::HyperbolicMirrorParameters camera = DefaultTrueSoccerCamera();  // the TRUE camera
  // Field, robot body and the robot's pose on the field (robot_x, robot_y, robot_heading).
  vision::render::SoccerFieldSceneParameters field;
  std::string camera_name = "soccer-omni";  // render source name ("sim:soccer-omni")
  double fps = 30.0;                        // nominal frame rate, > 0
  vision::render::RenderOptions render;

  // Empty when usable; otherwise every bad field and its value, "; "-separated.
  std::string Validate() const;
};

// Reads a world config (`world: soccer`; keys in docs/simulation.md and config/soccer-sim.yaml).
// Missing keys keep the defaults above. Throws std::invalid_argument naming the file and every bad
// key and value.
SoccerWorldConfig LoadSoccerWorldConfig(const std::string& path);

// Ground truth of one pixel.
struct SoccerPixelTruth {
  bool valid = false;                             // the pixel sees the ground
  Eigen::Vector2d p_G = Eigen::Vector2d::Zero();  // ground point in G (m)
  Eigen::Vector2d p_F = Eigen::Vector2d::Zero();  // ground point in F (m)
  double distance = 0.0;                          // |p_G| (m): the distance map's value
};

// Ground truth of every pixel, row-major (index v * width + u); NaN where invalid.
struct SoccerGroundTruthMap {
  vision::GroundMap map_G;  // (x_G, y_G) per pixel and the valid mask
  std::vector<double> x_F, y_F;
  std::vector<double> distance;
};

class SoccerRobotWorld {
 public:
  enum class Timing { kStepped, kRealTime };

  // Builds the true camera, the scene and the renderer. Throws std::invalid_argument naming every
  // bad field.
  explicit SoccerRobotWorld(SoccerWorldConfig config, Timing timing = Timing::kStepped);
  ~SoccerRobotWorld();  // unregisters the camera, stops the frame server
  SoccerRobotWorld(const SoccerRobotWorld&) = delete;
  SoccerRobotWorld& operator=(const SoccerRobotWorld&) = delete;

  const SoccerWorldConfig& config() const { return config_; }
  const vision::HyperbolicMirrorCamera& true_camera() const { return true_camera_; }
  const vision::HyperbolicMirrorCamera& nominal_camera() const { return nominal_camera_; }
  common::Clock& clock();

  // Moves the robot on the field (m, m, rad; finite, std::invalid_argument otherwise).
  void SetRobotPose(double x, double y, double heading);
  // The scene of the moment (shared: a later SetRobotPose does not change it).
  std::shared_ptr<const vision::render::SoccerFieldScene> scene() const;

  // Ground truth of a pixel (u, v) (px) with the true camera at the current robot pose.
  SoccerPixelTruth GroundTruth(const Eigen::Vector2d& pixel) const;
  // Its distance |p_G| (m); NaN when the pixel does not see the ground.
  double GroundTruthDistance(const Eigen::Vector2d& pixel) const;
  // Every pixel (ComputeGroundMap with the true camera, transformed to F).
  SoccerGroundTruthMap GroundTruthMap() const;

  // Mono8, the camera's size, config fps.
  hal::CameraFormat camera_format() const;
  // Renders frame `frame_id` into `out` (camera-sized). `truth` may be null.
  void Render(uint64_t frame_id, const vision::ImageView8& out,
              vision::render::GroundTruth* truth = nullptr);

  // As WeldCellWorld: render source "sim:NAME" in this process, and a FrameServer ("net:...").
  std::string RegisterCamera();
  std::string ServeCamera(const hal::FrameServerOptions& options);

 private:
  const SoccerWorldConfig config_;
  const Timing timing_;
  const vision::HyperbolicMirrorCamera true_camera_;
  const vision::HyperbolicMirrorCamera nominal_camera_;
  common::SimulatedClock sim_time_;

  mutable std::mutex mutex_;
  std::shared_ptr<const vision::render::SoccerFieldScene> scene_;

  std::mutex render_mutex_;
  std::unique_ptr<vision::render::Renderer> renderer_;

  std::string registered_;
  std::unique_ptr<hal::FrameServer> frame_server_;
};

}  // namespace kinevis::sim
