#include "rigs/weld/weld_rig.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>
#include <vector>

#include "common/clock.h"
#include "hal/camera/camera_factory.h"
#include "hal/common/error.h"
#include "hal/weld/weld_robot_client.h"
#include "rigs/deployment.h"
#include "rigs/rig_camera.h"
#include "robots/io/robot_description.h"
#include "sim/weld_cell_world.h"
#include "vision/camera/camera_file.h"

namespace kinevis::rigs {
namespace {

using namespace std::chrono_literals;

}  // namespace

WeldRig::WeldRig(const WeldRigOptions& options) : config_path_(options.config) {
  std::string robot_backend;
  std::string camera_source;

  if (IsWorldConfig(config_path_, "weld-cell")) {
    sim::WeldCellWorldConfig config;
    if (!config_path_.empty()) config = sim::LoadWeldCellWorldConfig(config_path_);
    switch (options.workpiece) {
      case WeldWorkpiece::kFromConfig:
        break;
      case WeldWorkpiece::kBlade: {
        const vision::render::LaserSceneParameters blade = sim::DefaultBlade();
        if (config.workpiece.surface != vision::render::LaserSurfaceKind::kBlade) {
          config.workpiece = blade;
        }
        break;
      }
      case WeldWorkpiece::kDotBoard:
        config.workpiece = sim::DefaultCalibrationBoard(/*gauge_block=*/false);
        config.X_0S = sim::DefaultWorkpiecePose();
        break;
      case WeldWorkpiece::kGaugeBlock:
        config.workpiece = sim::DefaultCalibrationBoard(/*gauge_block=*/true);
        config.X_0S = sim::DefaultWorkpiecePose();
        break;
    }
    robot_description_ = config.robot_description;
    nominal_ = config.nominal;
    X_5C_nominal_ = config.X_5C_nominal;
    camera_model_spec_ = config.scanner_camera;
    camera_fps_ = config.fps;
    world_ = std::make_unique<sim::WeldCellWorld>(config, sim::WeldCellWorld::Timing::kStepped);
    robot_backend = world_->backend();
    camera_source = "sim:" + world_->RegisterCamera();
    clock_ = &world_->clock();
  } else {
    // The real cell: a deployment file (docs/deployment.md, docs/deployment.md).
    DeploymentFile file(config_path_, "weld-cell");
    robot_description_ = file.RobotDescription();
    if (!robot_description_.empty()) {
      try {
        nominal_ = robots::LoadWeld5Description(robot_description_).model;
      } catch (const std::exception& e) {
        file.Problem(std::string("robot: ") + e.what());
      }
    }
    robot_backend = file.Backend("welder", "modbus-tcp:192.168.0.10:502");
    CameraSection cs;
    cs.section = "scanner";
    cs.model_key = "camera";
    cs.pose_key = "nominal_mount";
    cs.pose_meaning = "the CAD pose of the scanner camera on link 5";
    cs.has_name = false;
    cs.default_fps = camera_fps_;
    const DeploymentCamera camera = file.Camera(cs);
    camera_source = camera.source;
    camera_model_spec_ = camera.model;
    X_5C_nominal_ = camera.pose;
    camera_fps_ = camera.fps;
    file.Finish({"robot", "welder", "scanner"});
    clock_ = &common::SteadyClock::Instance();
  }

  camera_model_ = vision::OpenCameraModel(camera_model_spec_);
  hal::WeldRobotClient::Options o;
  o.clock = clock_;
  robot_ = hal::WeldRobotClient::Open(robot_backend, o);
  robot_->Configure();
  if (const std::error_code ec = robot_->Activate()) {
    throw hal::HalError(robot_->name(), "activate", robot_->last_error_text(), ec);
  }
  camera_ = OpenRigCamera(camera_source, *clock_, camera_model_->width(), camera_model_->height(),
                          "scanner camera " + camera_source, camera_model_spec_);
}

WeldRig::~WeldRig() {
  if (robot_) {
    if (const std::error_code ec = robot_->Stop()) {
      spdlog::warn("{}: stopping on exit: {}", robot_->name(), robot_->last_error_text());
    }
  }
  camera_.reset();
  robot_.reset();
  world_.reset();
}

robots::Vector5d WeldRig::Joints() const {
  hal::WeldRobotState state;
  if (const std::error_code ec = robot_->ReadState(&state)) {
    throw hal::HalError(robot_->name(), "read state", robot_->last_error_text(), ec);
  }
  robots::Vector5d q;
  for (int i = 0; i < robots::kWeld5Joints; ++i) q[i] = state.joints[static_cast<size_t>(i)];
  return q;
}

std::string WeldRig::MoveTo(const robots::Vector5d& q, double speed_fraction, double settle_s) {
  if (!(speed_fraction > 0 && speed_fraction <= 1)) {
    return "move: speed fraction " + std::to_string(speed_fraction) + " is not in (0, 1]";
  }
  robots::Vector5d from;
  try {
    from = Joints();
  } catch (const std::exception& e) {
    return e.what();
  }
  // The slowest joint sets the time; segments no longer than the controller allows.
  double duration = 0.001;
  for (int i = 0; i < robots::kWeld5Joints; ++i) {
    duration = std::max(duration, std::abs(q[i] - from[i]) / (speed_fraction * nominal_.qd_max(i)));
  }
  const double max_segment = std::max(0.001, robot_->identity().max_segment_duration);
  const int segments = static_cast<int>(std::ceil(duration / max_segment - 1e-9));
  std::vector<hal::WeldTrajectoryPoint> points;
  for (int k = 1; k <= segments; ++k) {
    hal::WeldTrajectoryPoint p;
    const robots::Vector5d qk = from + (q - from) * (static_cast<double>(k) / segments);
    for (int i = 0; i < robots::kWeld5Joints; ++i) p.joints[static_cast<size_t>(i)] = qk[i];
    p.duration = std::max(0.001, std::round(1e3 * duration / segments) * 1e-3);
    points.push_back(p);
  }
  hal::WeldStreamReport report;
  if (robot_->StreamTrajectory(points, {}, nullptr, hal::WeldStreamOptions(), &report)) {
    return "move: " + robot_->last_error_text();
  }
  clock_->SleepFor(common::FromSeconds(settle_s));
  return "";
}

std::string WeldRig::GrabFresh(hal::Image* image, robots::Vector5d* q) {
  const common::Duration wanted = clock_->Now();
  const common::Duration deadline = wanted + common::FromSeconds(3.0 / camera_fps_ + 0.5);
  for (;;) {
    if (const std::error_code ec = camera_->Grab(image, 2000ms)) {
      return "scanner camera: " + ec.message();
    }
    if (image->timestamp >= wanted) break;
    if (clock_->Now() > deadline) return "scanner camera: no fresh frame";
    clock_->SleepFor(common::FromSeconds(0.25 / camera_fps_));
  }
  if (q != nullptr) {
    try {
      *q = Joints();
    } catch (const std::exception& e) {
      return e.what();
    }
  }
  return "";
}

bool WeldRig::SetLaserAngle(double cot_theta_y) {
  if (!world_) return false;
  world_->SetLaserAngle(cot_theta_y);
  return true;
}

bool WeldRig::SetLasers(bool fixed_on, bool rotating_on) {
  if (!world_) return false;
  world_->SetLasers(fixed_on, rotating_on);
  return true;
}

bool WeldRig::OperatorTouch(const Eigen::Vector3d& p_0, const Eigen::Vector3d& axis_0,
                            double touch_sigma, robots::Vector5d* q) const {
  if (!world_) return false;
  std::mt19937 rng(static_cast<uint32_t>(0x70c4 + touches_++));
  std::normal_distribution<double> n(0.0, touch_sigma);
  const Eigen::Vector3d p = p_0 + Eigen::Vector3d(n(rng), n(rng), n(rng));
  robots::Vector5d guess;
  try {
    guess = Joints();
  } catch (const std::exception&) {
    return false;
  }
  const robots::Weld5IkResult ik =
      robots::Weld5InverseKinematics(world_->true_model(), p, axis_0, guess);
  if (!ik.converged()) return false;
  *q = ik.q;
  return true;
}

}  // namespace kinevis::rigs
