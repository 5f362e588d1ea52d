#include "rigs/hexapod/hexapod_rig.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "common/clock.h"
#include "common/yaml_reader.h"
#include "hal/camera/camera_factory.h"
#include "hal/can/can_bus_factory.h"
#include "hal/canopen/canopen_master.h"
#include "hal/common/error.h"
#include "hal/drive/cia402_can_drive.h"
#include "rigs/deployment.h"
#include "rigs/rig_camera.h"
#include "robots/io/robot_description.h"
#include "sim/hexapod_world.h"
#include "vision/camera/camera_file.h"
#include "vision/render/scenes/hexapod_scene.h"

namespace kinevis::rigs {
namespace {

using namespace std::chrono_literals;

}  // namespace

HexapodRig::HexapodRig(const HexapodRigOptions& options) : config_path_(options.config) {
  std::string drives_backend;
  std::array<int, robots::kHexapodLegs> nodes{1, 2, 3, 4, 5, 6};
  double counts_per_metre = 1e6;
  std::chrono::milliseconds heartbeat{20};
  std::string camera_source;

  if (options.world || IsWorldConfig(config_path_, "hexapod")) {
    // Simulated: the world in this process, stepped (its clock advances when the host waits).
    sim::HexapodWorldConfig config;
    if (options.world) {
      config = *options.world;
    } else if (!config_path_.empty()) {
      config = sim::LoadHexapodWorldConfig(config_path_);
    } else {
      config.cameras = sim::DefaultHexapodCameras();
    }
    if (config.cameras.empty()) {
      throw std::invalid_argument(
          (config_path_.empty() ? std::string("the default hexapod world") : config_path_) +
          ": no camera in `cameras:`; the hexapod commands need one");
    }
    robot_description_ = config.robot_description;
    nominal_ = config.nominal;
    X_BP_home_ = config.X_BP_home;
    nodes = config.nodes;
    counts_per_metre = config.counts_per_metre;
    world_ = std::make_unique<sim::HexapodWorld>(config, sim::HexapodWorld::Timing::kStepped);
    world_->RegisterCameras([](const robots::HexapodModel& model,
                               const sim::HexapodPlantState& state, const Eigen::Isometry3d& X_BC) {
      return std::make_unique<vision::render::HexapodScene>(model, state.X_BP, X_BC.inverse());
    });
    const sim::WorldCameraConfig* camera = &config.cameras.front();
    if (!options.camera.empty()) {
      camera = nullptr;
      std::string names;
      for (const sim::WorldCameraConfig& c : config.cameras) {
        if (c.name == options.camera) camera = &c;
        names += (names.empty() ? "" : ", ") + c.name;
      }
      if (camera == nullptr) {
        throw std::invalid_argument("--camera " + options.camera + ": " + config_path_ +
                                    " has no such camera (it has " + names + ")");
      }
    }
    camera_name_ = camera->name;
    camera_model_spec_ = camera->model;
    edge_options_.locator = vision::hexapod::EdgeLocator::kStepRamp;
    edge_options_.edge_blur_px = camera->render.blur_sigma_px;
    X_BC_hint_ = camera->X_WC;
    camera_fps_ = camera->fps;
    camera_source = "sim:" + camera->name;
    clock_ = &world_->clock();
  } else {
    // Real hardware: a deployment file (docs/deployment.md, docs/hexapod-rig.md).
    DeploymentFile file(config_path_, "hexapod");
    robot_description_ = file.RobotDescription();
    if (!robot_description_.empty()) {
      try {
        const robots::HexapodDescription d = robots::LoadHexapodDescription(robot_description_);
        nominal_ = d.model;
        X_BP_home_ = d.X_BP_home;
      } catch (const std::exception& e) {
        file.Problem(std::string("robot: ") + e.what());
      }
    }
    DrivesSection ds;
    ds.ids_key = "nodes";
    ds.default_ids = {1, 2, 3, 4, 5, 6};
    ds.max_id = 127;
    ds.counts_key = "counts_per_metre";
    ds.default_counts = counts_per_metre;
    ds.default_cycle_ms = 4.0;
    ds.backend_example = "socketcan:can0";
    const DeploymentDrives drives = file.Drives(ds);
    drives_backend = drives.backend;
    for (int j = 0; j < robots::kHexapodLegs; ++j) nodes[j] = drives.ids[static_cast<size_t>(j)];
    counts_per_metre = drives.counts_per_unit;
    cycle_period_ = std::chrono::microseconds(static_cast<long>(drives.cycle_ms * 1000));
    heartbeat = std::chrono::milliseconds(static_cast<long>(drives.heartbeat_ms));
    CameraSection cs;
    cs.pose_meaning = "the camera's pose in the base frame, measured by hand";
    cs.default_fps = camera_fps_;
    cs.extra_keys = {"edge_locator", "edge_blur_px"};
    const DeploymentCamera camera = file.Camera(cs);
    camera_name_ = camera.name;
    camera_source = camera.source;
    camera_model_spec_ = camera.model;
    X_BC_hint_ = camera.pose;
    camera_fps_ = camera.fps;
    // A real camera's blur is not known unless measured: the parabola locator (insensitive to
    // blur) by default, the step-ramp model when the blur is given.
    common::YamlReader& r = file.reader();
    edge_options_.edge_blur_px = r.Number("camera.edge_blur_px", 0.0);
    if (!(edge_options_.edge_blur_px >= 0 && edge_options_.edge_blur_px <= 3)) {
      file.Problem("camera.edge_blur_px: must be in [0, 3] px");
    }
    const std::string locator =
        r.Text("camera.edge_locator", r.Has("camera.edge_blur_px") ? "step-ramp" : "parabola");
    if (locator == "step-ramp") {
      edge_options_.locator = vision::hexapod::EdgeLocator::kStepRamp;
    } else if (locator == "parabola") {
      edge_options_.locator = vision::hexapod::EdgeLocator::kParabola;
    } else {
      file.Problem("camera.edge_locator: '" + locator + "' is not step-ramp or parabola");
    }
    file.Finish({"robot", "drives", "camera"});
    clock_ = &common::SteadyClock::Instance();
  }

  camera_model_ = vision::OpenCameraModel(camera_model_spec_);

  hal::canopen::CanopenMasterOptions o;
  o.clock = clock_;
  // Six drives, 4 PDOs each plus SYNC: ~2.7 ms of a 1 Mbit/s bus; a 4 ms cycle leaves room.
  o.cycle_period = cycle_period_;
  o.cycle_timeout = cycle_period_ * 7 / 8;
  master_ = std::make_unique<hal::canopen::CanopenMaster>(
      world_ ? world_->ConnectHost() : hal::OpenCanBus(drives_backend), o);
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    hal::Cia402CanDriveConfig c;
    c.node = static_cast<uint8_t>(nodes[j]);
    c.drive.name = "hexapod/leg" + std::to_string(j);
    c.drive.scaling.position_counts_per_unit = counts_per_metre;
    c.drive.scaling.velocity_counts_per_unit = counts_per_metre;
    c.drive.command_timeout = 500ms;
    c.heartbeat_producer = heartbeat;
    drives_.push_back(master_->AddDrive(c));
  }

  camera_ = OpenRigCamera(camera_source, *clock_, camera_model_->width(), camera_model_->height(),
                          "camera " + camera_name_, camera_model_spec_);
}

HexapodRig::~HexapodRig() {
  try {
    Disable();
  } catch (const std::exception& e) {
    spdlog::warn("hexapod: disabling the drives on exit: {}", e.what());
  }
  camera_.reset();
  master_.reset();
  world_.reset();
}

void HexapodRig::Enable() {
  master_->ConfigureAll();
  if (const std::error_code ec = master_->EnableAll(2000ms)) {
    for (hal::Cia402CanDrive* d : drives_) {
      if (d->lifecycle() != common::DeviceLifecycle::kActive) {
        throw hal::HalError(d->name(), "enable", ec.message(), ec);
      }
    }
    throw hal::HalError(master_->name(), "enable", ec.message(), ec);
  }
}

robots::Vector6d HexapodRig::Readings() const {
  robots::Vector6d s;
  for (int j = 0; j < robots::kHexapodLegs; ++j) s[j] = drives_[j]->status().position;
  return s;
}

std::string HexapodRig::MoveTo(const robots::Vector6d& s_target, double speed, double settle_s) {
  const robots::Vector6d s_start = Readings();
  // A cosine ramp peaks at π/2 times its mean speed.
  const double distance = (s_target - s_start).cwiseAbs().maxCoeff();
  const double duration = std::max(0.05, M_PI / 2 * distance / speed);
  const common::Duration start = clock_->Now();
  std::string fault;
  master_->RunCyclesUntil(start + common::FromSeconds(duration + settle_s), [&] {
    for (hal::Cia402CanDrive* d : drives_) {
      const hal::DriveStatus st = d->status();
      if (d->lifecycle() == common::DeviceLifecycle::kFault) {
        fault = d->name() + " faulted (error code 0x" + fmt::format("{:04X}", st.error_code) + ")";
        return true;
      }
    }
    const double t = std::min(1.0, common::ToSeconds(clock_->Now() - start) / duration);
    const double a = 0.5 * (1 - std::cos(M_PI * t));
    for (int j = 0; j < robots::kHexapodLegs; ++j) {
      if (const std::error_code ec =
              drives_[j]->SetTargetPosition(s_start[j] + a * (s_target[j] - s_start[j]))) {
        fault = drives_[j]->name() + " refused its target: " + ec.message();
        return true;
      }
    }
    return false;
  });
  return fault;
}

std::string HexapodRig::GrabFresh(hal::Image* image) {
  const common::Duration wanted = clock_->Now();
  const common::Duration deadline = wanted + common::FromSeconds(3.0 / camera_fps_ + 0.5);
  // The camera captures frame k at start + k/fps: cycle the drives until the next capture time
  // has passed, then the grab returns at once (a real camera: the frame is already there).
  master_->RunCyclesUntil(wanted + common::FromSeconds(1.0 / camera_fps_), [] { return false; });
  for (;;) {
    if (const std::error_code ec = camera_->Grab(image, 2000ms)) {
      return "camera " + camera_name_ + ": " + ec.message();
    }
    if (image->timestamp >= wanted) return "";
    if (clock_->Now() > deadline) return "camera " + camera_name_ + ": no fresh frame";
    master_->RunCyclesUntil(clock_->Now() + common::FromSeconds(0.5 / camera_fps_),
                            [] { return false; });
  }
}

void HexapodRig::Hold(double seconds) {
  master_->RunCyclesUntil(clock_->Now() + common::FromSeconds(seconds), [] { return false; });
}

void HexapodRig::Disable() {
  if (master_) master_->DisableAll();
}

}  // namespace kinevis::rigs
