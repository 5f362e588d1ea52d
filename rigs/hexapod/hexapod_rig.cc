#include "rigs/hexapod/hexapod_rig.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "common/clock.h"
#include "hal/camera/camera_factory.h"
#include "hal/can/can_bus_factory.h"
#include "hal/canopen/canopen_master.h"
#include "hal/common/error.h"
#include "hal/drive/cia402_can_drive.h"
#include "rigs/rig_camera.h"
#include "robots/io/robot_description.h"
#include "sim/hexapod_world.h"
#include "vision/camera/camera_file.h"
#include "vision/render/scenes/hexapod_scene.h"

namespace kinevis::rigs {
namespace {

using namespace std::chrono_literals;

// Is the file a world config (`world:` key) rather than a deployment file (`rig:`)?
bool IsWorldConfig(const std::string& path) {
  sim::internal::WorldConfigReader r(path, "hexapod");
  return r.Has("world");
}

}  // namespace

HexapodRig::HexapodRig(const HexapodRigOptions& options) : config_path_(options.config) {
  std::string drives_backend;
  std::array<int, robots::kHexapodLegs> nodes{1, 2, 3, 4, 5, 6};
  double counts_per_metre = 1e6;
  std::chrono::milliseconds heartbeat{20};
  std::string camera_source;

  if (options.world || config_path_.empty() || IsWorldConfig(config_path_)) {
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
    // Real hardware: a deployment file (docs/hexapod-calibration.md).
    sim::internal::WorldConfigReader r(config_path_, "hexapod");
    if (r.Text("rig", "") != "hexapod") {
      r.Problem("rig: expected `rig: hexapod` (or `world: hexapod` for a simulated world)");
    }
    robot_description_ = r.Path("robot");
    if (robot_description_.empty()) {
      r.Problem("robot: missing (the nominal robot description file)");
    } else {
      try {
        const robots::HexapodDescription d = robots::LoadHexapodDescription(robot_description_);
        nominal_ = d.model;
        X_BP_home_ = d.X_BP_home;
      } catch (const std::exception& e) {
        r.Problem(std::string("robot: ") + e.what());
      }
    }
    drives_backend = r.Text("drives.backend", "");
    if (drives_backend.empty()) r.Problem("drives.backend: missing (e.g. socketcan:can0)");
    const std::vector<double> n =
        r.Numbers("drives.nodes", robots::kHexapodLegs, {1, 2, 3, 4, 5, 6});
    for (int j = 0; j < robots::kHexapodLegs; ++j) nodes[j] = static_cast<int>(n[j]);
    counts_per_metre = r.Number("drives.counts_per_metre", counts_per_metre);
    if (!(counts_per_metre > 0)) r.Problem("drives.counts_per_metre: must be > 0");
    const double cycle_ms = r.Number("drives.cycle_ms", 4.0);
    if (!(cycle_ms >= 1 && cycle_ms <= 100)) r.Problem("drives.cycle_ms: must be in [1, 100]");
    cycle_period_ = std::chrono::microseconds(static_cast<long>(cycle_ms * 1000));
    const double heartbeat_ms = r.Number("drives.heartbeat_ms", 20);
    if (!(heartbeat_ms >= 1 && heartbeat_ms <= 1000)) {
      r.Problem("drives.heartbeat_ms: must be in [1, 1000]");
    }
    heartbeat = std::chrono::milliseconds(static_cast<long>(heartbeat_ms));
    r.CheckKeys("drives", {"backend", "nodes", "counts_per_metre", "cycle_ms", "heartbeat_ms"});
    camera_name_ = r.Text("camera.name", "camera");
    camera_source = r.Text("camera.source", "");
    if (camera_source.empty()) r.Problem("camera.source: missing (e.g. v4l2:/dev/video0)");
    camera_model_spec_ = r.Text("camera.model", "");
    if (camera_model_spec_.empty()) {
      r.Problem("camera.model: missing (a camera model file or builtin:NAME)");
    } else if (camera_model_spec_.rfind("builtin:", 0) != 0) {
      camera_model_spec_ = r.Path("camera.model");
    }
    if (!r.Has("camera.pose")) {
      r.Problem("camera.pose: missing (the camera's pose in the base frame, measured by hand)");
    }
    X_BC_hint_ = r.Pose("camera.pose", X_BC_hint_);
    camera_fps_ = r.Number("camera.fps", camera_fps_);
    if (!(camera_fps_ > 0)) r.Problem("camera.fps: must be > 0");
    // A real camera's blur is not known unless measured: the parabola locator (insensitive to
    // blur) by default, the step-ramp model when the blur is given.
    edge_options_.edge_blur_px = r.Number("camera.edge_blur_px", 0.0);
    if (!(edge_options_.edge_blur_px >= 0 && edge_options_.edge_blur_px <= 3)) {
      r.Problem("camera.edge_blur_px: must be in [0, 3] px");
    }
    const std::string locator =
        r.Text("camera.edge_locator", r.Has("camera.edge_blur_px") ? "step-ramp" : "parabola");
    if (locator == "step-ramp") {
      edge_options_.locator = vision::hexapod::EdgeLocator::kStepRamp;
    } else if (locator == "parabola") {
      edge_options_.locator = vision::hexapod::EdgeLocator::kParabola;
    } else {
      r.Problem("camera.edge_locator: '" + locator + "' is not step-ramp or parabola");
    }
    r.CheckKeys("camera",
                {"name", "source", "model", "pose", "fps", "edge_locator", "edge_blur_px"});
    r.CheckKeys("", {"rig", "robot", "drives", "camera"});
    r.ThrowIfProblems();
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
