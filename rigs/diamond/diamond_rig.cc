#include "rigs/diamond/diamond_rig.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <thread>

#include "common/clock.h"
#include "common/yaml_reader.h"
#include "control/diamond/diamond_drives.h"
#include "control/diamond/diamond_laws.h"
#include "hal/camera/camera_factory.h"
#include "hal/common/error.h"
#include "hal/drive/rs485_drive.h"
#include "rigs/deployment.h"
#include "rigs/rig_camera.h"
#include "robots/io/robot_description.h"
#include "sim/diamond_world.h"
#include "vision/camera/camera_file.h"
#include "vision/render/scenes/diamond_marker_scene.h"

namespace kinevis::rigs {
namespace {

using namespace std::chrono_literals;

// config/diamond-sim.yaml's camera, for the built-in world (DiamondWorldConfig has none): the
// world config camera model at the seed's placement, 45° towards the RCM, 0.4462 m away.
sim::WorldCameraConfig DefaultDiamondCamera() {
  sim::WorldCameraConfig c;
  c.name = "diamond-marker";
  c.model = "builtin:tsai-seed004";
  c.X_WC = vision::render::DiamondCameraPose(0.4462).inverse();
  c.fps = 30.0;
  c.render.supersampling = 4;
  c.render.noise_sigma = 1.0;
  return c;
}

}  // namespace

// The library's defaults suit h ≈ 20 px (the seed's 1280×640 camera); the world config's
// 1616×1216 camera sees h ≈ 40 px (experiments/diamond_visual_servo.cc uses 8 / 12 / 60 there).
vision::MarkerDetectorOptions DiamondDetectorOptions(const vision::CameraModel& camera,
                                                     const Eigen::Isometry3d& X_OC,
                                                     const robots::DiamondModel& model,
                                                     double half_side_m) {
  vision::MarkerDetectorOptions o;
  const Eigen::Vector3d p_O = robots::DiamondToolPoint(model.radius, M_PI / 2, M_PI / 4);
  const Eigen::Vector3d p_C = X_OC.inverse() * p_O;
  Eigen::Vector2d a, b;
  if (camera.Project(p_C, &a) != vision::ProjectionStatus::kOk ||
      camera.Project(p_C + Eigen::Vector3d(half_side_m, 0, 0), &b) !=
          vision::ProjectionStatus::kOk) {
    return o;  // the marker is not in view at home: keep the defaults
  }
  const double h = (b - a).norm();
  o.ring_radius_px = std::clamp(0.3 * h, 3.0, 50.0);
  o.refine_half_window_px = std::clamp(static_cast<int>(0.2 * h), 2, 20);
  o.search_half_window_px =
      std::max({40, static_cast<int>(o.ring_radius_px) + 4, static_cast<int>(1.5 * h)});
  return o;
}

DiamondRig::DiamondRig(const DiamondRigOptions& options) : config_path_(options.config) {
  control::DiamondDriveBusConfig drives;
  std::string camera_source;
  double marker_half_side_m = 0.005;

  if (IsWorldConfig(config_path_, "diamond")) {
    sim::DiamondWorldConfig config;
    if (!config_path_.empty()) {
      config = sim::LoadDiamondWorldConfig(config_path_);
    } else {
      config.cameras = {DefaultDiamondCamera()};
    }
    if (config.cameras.empty()) {
      throw std::invalid_argument(config_path_ +
                                  ": no camera in `cameras:`; the diamond commands need one");
    }
    real_time_ = options.real_time;
    robot_description_ = config.nominal_description;
    nominal_ = config.nominal;
    const sim::WorldCameraConfig camera = config.cameras.front();
    world_ = std::make_unique<sim::DiamondWorld>(config, options.real_time
                                                             ? sim::DiamondWorld::Timing::kRealTime
                                                             : sim::DiamondWorld::Timing::kStepped);
    world_->RegisterCameras([](const robots::DiamondModel&, const sim::DiamondPlantState& state,
                               const Eigen::Isometry3d& X_OC) {
      vision::render::DiamondMarkerSceneParameters p;
      p.X_CO = X_OC.inverse();
      p.p_O_T = state.p_O_T;
      return std::make_unique<vision::render::DiamondMarkerScene>(p);
    });
    if (options.real_time) {
      world_->Start();
      // Let the drive simulators' stepping thread sync their motion models to the plant before
      // the host enables them (experiments/diamond_straightness.cc).
      std::this_thread::sleep_for(100ms);
    }
    drives.backend = world_->backend() + ",timeout_ms=100,retries=1";
    drives.units = config.units;
    drives.counts_per_rad = config.counts_per_rad;
    camera_name_ = camera.name;
    camera_model_spec_ = camera.model;
    camera_fps_ = camera.fps;
    X_OC_ = camera.X_WC;
    camera_distance_source_ = "simulated world's true camera pose";
    camera_source = "sim:" + camera.name;
    clock_ = &world_->clock();
  } else {
    // A deployment file (docs/deployment.md, docs/diamond-calibration.md "Command line").
    DeploymentFile file(config_path_, "diamond");
    robot_description_ = file.RobotDescription(/*required=*/false);
    if (!robot_description_.empty()) {
      try {
        nominal_ = robots::LoadDiamondDescription(robot_description_).model;
      } catch (const std::exception& e) {
        file.Problem(std::string("robot: ") + e.what());
      }
    }
    DrivesSection ds;
    ds.ids_key = "units";
    ds.default_ids = {1, 2};
    ds.max_id = 247;  // Modbus unit ids
    ds.counts_key = "counts_per_rad";
    ds.default_counts = drives.counts_per_rad;
    ds.default_cycle_ms = 1.0;
    ds.min_cycle_ms = 0.25;
    ds.heartbeat = false;
    ds.backend_example = "modbus-rtu:/dev/ttyUSB0@3000000,8E1";
    const DeploymentDrives d = file.Drives(ds);
    drives.backend = d.backend;
    for (int i = 0; i < robots::kDiamondJoints; ++i)
      drives.units[i] = d.ids[static_cast<size_t>(i)];
    drives.counts_per_rad = d.counts_per_unit;
    cycle_period_s_ = d.cycle_ms * 1e-3;
    CameraSection cs;
    cs.pose_meaning = "the camera's pose in the RCM frame O, measured";
    cs.default_fps = camera_fps_;
    cs.extra_keys = {"distance_source", "marker_half_side_mm"};
    const DeploymentCamera camera = file.Camera(cs);
    camera_name_ = camera.name;
    camera_source = camera.source;
    camera_model_spec_ = camera.model;
    X_OC_ = camera.pose;
    camera_fps_ = camera.fps;
    common::YamlReader& r = file.reader();
    camera_distance_source_ = r.Text("camera.distance_source", "");
    if (camera_distance_source_.empty()) {
      file.Problem(
          "camera.distance_source: missing (how the camera's distance from the RCM was measured: "
          "it fixes the scale of R)");
    }
    marker_half_side_m = r.Number("camera.marker_half_side_mm", 5.0) * 1e-3;
    if (!(marker_half_side_m > 0)) file.Problem("camera.marker_half_side_mm: must be > 0");
    const std::string bad = drives.Validate();
    if (!bad.empty()) file.Problem("drives: " + bad);
    file.Finish({"robot", "drives", "camera"});
    clock_ = &common::SteadyClock::Instance();
  }

  camera_model_ = vision::OpenCameraModel(camera_model_spec_);
  detector_options_ = DiamondDetectorOptions(*camera_model_, X_OC_, nominal_, marker_half_side_m);
  drives.cycle_period = std::chrono::microseconds(std::lround(cycle_period_s_ * 1e6));
  bus_ = control::MakeDiamondDriveBus(drives, clock_);

  camera_ = OpenRigCamera(camera_source, *clock_, camera_model_->width(), camera_model_->height(),
                          "camera " + camera_name_, camera_model_spec_);
}

DiamondRig::~DiamondRig() {
  try {
    // Disabled drives need no watchdog: switch it off, or a drive left on the line faults with
    // a lost heartbeat (0x8130) 200 ms after this process exits, and the next job finds it in
    // fault.
    Release();
  } catch (const std::exception& e) {
    spdlog::warn("diamond: disabling the drives on exit: {}", e.what());
  }
  camera_.reset();
  bus_.reset();
  if (world_) world_->Stop();
  world_.reset();
}

void DiamondRig::Enable() {
  try {
    control::BringUpDiamondDrives(bus_.get(), 2000ms);
  } catch (const hal::HalError&) {
    throw;
  } catch (const std::runtime_error& e) {
    // Not a bad input: the drives did not come up.
    throw hal::HalError(bus_->name(), "enable", e.what());
  }
  enabled_ = true;
}

Eigen::Vector2d DiamondRig::Readings() const {
  const std::vector<hal::MotorDrive*> d = bus_->drives();
  return Eigen::Vector2d(d[0]->status().position, d[1]->status().position);
}

control::DiamondLoopReport DiamondRig::MoveTo(const Eigen::Vector2d& task, double speed,
                                              const robots::DiamondModel* model) {
  const robots::DiamondModel& m = model != nullptr ? *model : nominal_;
  robots::DiamondData data;
  robots::ForwardKinematics(m, Readings(), &data);
  control::DiamondLine line;
  line.kind = control::DiamondLineKind::kTaskLine;
  line.from = data.valid ? data.task : task;
  line.to = task;
  // The quintic's mean rate is distance / duration.
  line.duration_s = std::max(0.2, (task - line.from).cwiseAbs().maxCoeff() / speed);
  // A move only has to get near its end: settled within 5e-4 rad (~0.1 mm at R = 0.2 m, ~10
  // encoder counts of the seed's drives), where the line's law takes over; the law's default
  // (1e-4 rad, two counts) is for the line's own end and can take longer than a move should
  // when the bus is slow.
  control::DiamondPdOptions pd;
  pd.settle_tolerance = 5e-4;
  pd.settle_timeout_s = 2.0;
  control::DiamondTaskPdLaw law(m, line, pd);
  control::DiamondLoopOptions o;
  // Point-to-point moves need no 1 kHz: the seed's 2.5 ms (fewer bus exchanges per move).
  o.cycle_period_s = std::max(cycle_period_s_, 0.0025);
  o.max_consecutive_cycle_timeouts = 20;
  o.timeout_s = line.duration_s + 5.0;
  o.keep_samples = false;
  control::DiamondControlLoop loop(bus_.get(), clock_, m, o);
  return loop.Run(&law);
}

std::string DiamondRig::GrabFresh(hal::Image* image) {
  const common::Duration wanted = clock_->Now();
  const common::Duration deadline = wanted + common::FromSeconds(3.0 / camera_fps_ + 0.5);
  // Frame k is captured at start + k/fps: cycle the drives until the next capture has passed,
  // then the grab returns at once (a real camera: the frame is already there).
  bus_->RunCyclesUntil(wanted + common::FromSeconds(1.0 / camera_fps_), [] { return false; });
  for (;;) {
    if (const std::error_code ec = camera_->Grab(image, 2000ms)) {
      return "camera " + camera_name_ + ": " + ec.message();
    }
    if (image->timestamp >= wanted) {
      if (image->format != hal::PixelFormat::kMono8) {
        return "camera " + camera_name_ + ": frames are " + hal::ToString(image->format) +
               ", the marker detector needs mono8";
      }
      return "";
    }
    if (clock_->Now() > deadline) return "camera " + camera_name_ + ": no fresh frame";
    bus_->RunCyclesUntil(clock_->Now() + common::FromSeconds(0.5 / camera_fps_),
                         [] { return false; });
  }
}

void DiamondRig::Hold(double seconds) {
  bus_->RunCyclesUntil(clock_->Now() + common::FromSeconds(seconds), [] { return false; });
}

void DiamondRig::Release() {
  Disable();
  if (bus_) {
    if (const std::error_code ec = bus_->Close()) {
      spdlog::warn("diamond: releasing the drive line: {}", ec.message());
    }
  }
}

void DiamondRig::Disable() {
  if (bus_ && enabled_) {
    enabled_ = false;
    bus_->DisableAll();
  }
}

}  // namespace kinevis::rigs
