#include "sim/hexapod_world.h"

#include <spdlog/spdlog.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <random>
#include <set>
#include <sstream>
#include <stdexcept>

#include "common/check.h"
#include "common/clock.h"
#include "common/units.h"
#include "hal/camera/sim_camera.h"
#include "hal/can/virtual_can_bus.h"
#include "hal/common/backend_spec.h"
#include "hal/common/error.h"
#include "hal/mock/canopen_drive_sim.h"
#include "hal/mock/slcan_adapter_sim.h"
#include "hal/serial/pty_pair.h"
#include "robots/io/robot_description.h"
#include "vision/camera/camera_file.h"

namespace kinevis::sim {

using robots::kHexapodLegs;

namespace {

constexpr int kSlcanSerialBaud = 115200;  // a pty carries any rate; the host must name one

}  // namespace

std::string HexapodWorldConfig::Validate() const {
  common::Problems p;
  const std::string model = nominal.Validate();
  if (!model.empty()) p.Add("robot (" + robot_description + "): " + model);
  if (!X_BP_home.matrix().allFinite()) p.Add("home pose: not finite");
  p.NonNegative("perturbation.base_point_sigma_mm", base_point_sigma_mm);
  p.NonNegative("perturbation.platform_point_sigma_mm", platform_point_sigma_mm);
  p.NonNegative("perturbation.joint_offset_sigma_mm", joint_offset_sigma_mm);
  std::set<int> seen;
  for (int j = 0; j < kHexapodLegs; ++j) {
    const std::string key = "drives.nodes[" + std::to_string(j) + "]";
    if (nodes[j] < 1 || nodes[j] > 127) {
      p.Add(key + ": must be in 1..127, got " + std::to_string(nodes[j]));
    } else if (!seen.insert(nodes[j]).second) {
      p.Add(key + ": " + std::to_string(nodes[j]) + " appears twice");
    }
  }
  p.Positive("drives.counts_per_metre", counts_per_metre);
  p.Positive("drives.max_velocity", max_velocity);
  p.Positive("drives.max_acceleration", max_acceleration);
  p.Positive("drives.following_error_window", following_error_window);
  if (std::isfinite(counts_per_metre) && counts_per_metre > 0 &&
      std::isfinite(nominal.leg_length_max) &&
      std::abs(nominal.leg_length_max) * counts_per_metre > 2e9) {
    p.Add("drives.counts_per_metre: " + common::Num(counts_per_metre) +
          " overflows the drives' 32-bit positions over the stroke");
  }
  if (network.empty()) p.Add("can.network: must not be empty");
  if (hal::SlcanBitrateCode(can_bitrate) < 0) {
    p.Add("can.bitrate: " + std::to_string(can_bitrate) +
          " is not one an slcan adapter knows (10000 ... 1000000)");
  }
  p.Positive("step_period_ms", step_period_s * 1e3);
  if (step_period_s > 0.01)
    p.Add("step_period_ms: " + common::Num(step_period_s * 1e3) + " must be <= 10");
  internal::ValidateCameras(cameras, &p);
  return p.Message();
}

std::vector<WorldCameraConfig> DefaultHexapodCameras() {
  const auto pose = [](const Eigen::Vector3d& p, double roll_deg, double pitch_deg,
                       double yaw_deg) {
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.translation() = p;
    X.linear() = (Eigen::AngleAxisd(yaw_deg * common::kDeg, Eigen::Vector3d::UnitZ()) *
                  Eigen::AngleAxisd(pitch_deg * common::kDeg, Eigen::Vector3d::UnitY()) *
                  Eigen::AngleAxisd(roll_deg * common::kDeg, Eigen::Vector3d::UnitX()))
                     .toRotationMatrix();
    return X;
  };
  WorldCameraConfig perspective;
  perspective.name = "hexapod-perspective";
  perspective.model = "builtin:tsai-seed004";
  perspective.X_WC = pose(Eigen::Vector3d(0.85, -1.47, 1.0), -115.2, 0, 30);
  perspective.fps = 10;
  perspective.render.supersampling = 4;
  perspective.render.noise_sigma = 1.0;
  WorldCameraConfig omni = perspective;
  omni.name = "hexapod-omni";
  omni.model = "builtin:unified-default";
  omni.X_WC = pose(Eigen::Vector3d(0.0, 0.0, 0.03), 0, 0, 0);
  return {perspective, omni};
}

robots::HexapodModel TrueHexapodModel(const HexapodWorldConfig& config) {
  robots::HexapodModel truth = config.nominal;
  std::mt19937 rng(config.seed);
  std::normal_distribution<double> unit(0.0, 1.0);
  // Fixed draw order (base points, platform points, offsets), so a seed names one robot.
  for (auto& a : truth.p_B_A) {
    for (int k = 0; k < 3; ++k) a[k] += config.base_point_sigma_mm * 1e-3 * unit(rng);
  }
  for (auto& b : truth.p_P_B) {
    for (int k = 0; k < 3; ++k) b[k] += config.platform_point_sigma_mm * 1e-3 * unit(rng);
  }
  for (double& q0 : truth.q0) q0 += config.joint_offset_sigma_mm * 1e-3 * unit(rng);
  return truth;
}

HexapodWorldConfig LoadHexapodWorldConfig(const std::string& path) {
  internal::WorldConfigReader r(path, "hexapod");
  HexapodWorldConfig c;
  c.robot_description = r.Path("robot");
  if (!c.robot_description.empty()) {
    try {
      robots::HexapodDescription d = robots::LoadHexapodDescription(c.robot_description);
      c.nominal = d.model;
      c.X_BP_home = d.X_BP_home;
    } catch (const std::exception& e) {
      r.Problem(std::string("robot: ") + e.what());
    }
  }
  c.seed = static_cast<uint32_t>(r.Integer("seed", c.seed));
  c.base_point_sigma_mm = r.Number("perturbation.base_point_sigma_mm", c.base_point_sigma_mm);
  c.platform_point_sigma_mm =
      r.Number("perturbation.platform_point_sigma_mm", c.platform_point_sigma_mm);
  c.joint_offset_sigma_mm = r.Number("perturbation.joint_offset_sigma_mm", c.joint_offset_sigma_mm);
  r.CheckKeys("perturbation",
              {"base_point_sigma_mm", "platform_point_sigma_mm", "joint_offset_sigma_mm"});
  const std::vector<double> nodes =
      r.Numbers("drives.nodes", kHexapodLegs, std::vector<double>(c.nodes.begin(), c.nodes.end()));
  for (int j = 0; j < kHexapodLegs; ++j) c.nodes[j] = static_cast<int>(nodes[j]);
  c.counts_per_metre = r.Number("drives.counts_per_metre", c.counts_per_metre);
  c.max_velocity = r.Number("drives.max_velocity", c.max_velocity);
  c.max_acceleration = r.Number("drives.max_acceleration", c.max_acceleration);
  c.following_error_window = r.Number("drives.following_error_window", c.following_error_window);
  r.CheckKeys("drives", {"nodes", "counts_per_metre", "max_velocity", "max_acceleration",
                         "following_error_window"});
  c.network = r.Text("can.network", c.network);
  c.can_bitrate = static_cast<int>(r.Integer("can.bitrate", c.can_bitrate));
  r.CheckKeys("can", {"network", "bitrate"});
  c.step_period_s = r.Number("step_period_ms", c.step_period_s * 1e3) * 1e-3;
  c.cameras = r.Cameras(c.cameras);
  r.CheckKeys(
      "", {"world", "robot", "seed", "perturbation", "drives", "can", "step_period_ms", "cameras"});
  r.ThrowIfProblems();
  const std::string invalid = c.Validate();
  if (!invalid.empty()) r.Problem(invalid);
  r.ThrowIfProblems();
  return c;
}

// ---------------------------------------------------------------------------------------------

struct HexapodWorld::Camera {
  WorldCameraConfig config;
  std::unique_ptr<vision::CameraModel> model;
  std::mutex mutex;  // the renderer's scratch is not shared between threads
  std::unique_ptr<vision::render::Renderer> renderer;
};

HexapodWorld::HexapodWorld(HexapodWorldConfig config, Timing timing)
    : config_(std::move(config)),
      timing_(timing),
      true_(TrueHexapodModel(config_)),
      clock_(timing == Timing::kStepped ? static_cast<common::Clock*>(&sim_time_)
                                        : &common::SteadyClock::Instance()) {
  std::string invalid = config_.Validate();
  if (invalid.empty()) {
    const std::string truth = true_.Validate();
    if (!truth.empty()) invalid = "the perturbed (true) robot is not valid: " + truth;
  }
  if (!invalid.empty()) throw std::invalid_argument("hexapod world: " + invalid);

  // The legs start where the true platform is at the home pose.
  const robots::Reachability reach = robots::InverseKinematics(true_, config_.X_BP_home, &fk_data_);
  if (!reach.ok()) {
    throw std::invalid_argument("hexapod world: the true robot cannot reach the home pose: " +
                                reach.Describe(true_, fk_data_.q));
  }
  state_.X_BP = config_.X_BP_home;
  state_.q = fk_data_.q;
  for (int j = 0; j < kHexapodLegs; ++j) {
    state_.s[j] = state_.q[j] - true_.q0[j];
    commanded_s_[j] = state_.s[j];
  }

  world_clock_ =
      std::make_unique<WorldClock>(&sim_time_, [this](common::Duration t) { StepTo(t); });

  hal::VirtualCanNetwork::Options net;
  net.bitrate = config_.can_bitrate;
  net.clock = clock_;
  network_ = hal::VirtualCanNetwork::Get(config_.network, net);
  if (&network_->clock() != clock_) {
    throw common::ConfigError("hexapod world: CAN network \"" + config_.network +
                              "\" already exists in this process with another clock");
  }
  const double cpm = config_.counts_per_metre;
  for (int j = 0; j < kHexapodLegs; ++j) {
    const int node = config_.nodes[j];
    drive_buses_.push_back(network_->Connect("hexapod leg " + std::to_string(j) + " (node " +
                                             std::to_string(node) + ")"));
    hal::CanopenDriveSim::Options o;
    o.node = static_cast<uint8_t>(node);
    o.serial_number = static_cast<uint32_t>(1000 + j);
    o.device.limits.max_velocity = config_.max_velocity * cpm;
    o.device.limits.max_acceleration = config_.max_acceleration * cpm;
    // The actuator's end stops: the true stroke, in readings.
    o.device.limits.min_position = std::ceil((true_.leg_length_min - true_.q0[j]) * cpm);
    o.device.limits.max_position = std::floor((true_.leg_length_max - true_.q0[j]) * cpm);
    o.device.following_error_window =
        static_cast<uint32_t>(std::llround(config_.following_error_window * cpm));
    drives_.push_back(std::make_unique<hal::CanopenDriveSim>(drive_buses_.back().get(), clock_, o));
    drives_.back()->device().SetPlantHook(
        [this, j](const hal::AxisState& commanded, double /*dt_s*/) {
          return OnDriveStep(j, commanded);
        });
  }
}

HexapodWorld::~HexapodWorld() {
  for (const auto& camera : cameras_) hal::UnregisterRenderSource(camera->config.name);
  Stop();
  // The drives' plant hooks point here: clear them before the drives go (they go with us).
  for (auto& d : drives_) d->device().SetPlantHook({});
}

common::Clock& HexapodWorld::clock() {
  if (timing_ == Timing::kStepped) return *world_clock_;
  return common::SteadyClock::Instance();
}

void HexapodWorld::Step(common::Duration dt) { StepTo(sim_time_.Now() + dt); }

void HexapodWorld::StepTo(common::Duration t) {
  KINEVIS_DEMAND_MSG(timing_ == Timing::kStepped, "HexapodWorld::Step called on a real-time world");
  const common::Duration period = common::FromSeconds(config_.step_period_s);
  while (sim_time_.Now() < t) {
    sim_time_.AdvanceTo(std::min(t, sim_time_.Now() + period));
    for (auto& d : drives_) d->Service();
    UpdatePlant();
  }
}

std::unique_ptr<hal::CanBus> HexapodWorld::ConnectHost(const std::string& node_name) {
  return network_->Connect(node_name);
}

std::string HexapodWorld::virtual_backend() const { return "virtual:" + config_.network; }

std::string HexapodWorld::ExposeSlcan(const std::string& link) {
  if (timing_ != Timing::kRealTime) {
    throw common::ConfigError("hexapod world: an slcan adapter needs a real-time world");
  }
  if (adapter_) throw common::ConfigError("hexapod world: the bus is already exposed");
  pty_ = std::make_unique<hal::PtyPair>();
  adapter_bus_ = network_->Connect("slcan adapter");
  adapter_ = std::make_unique<hal::SlcanAdapterSim>(
      pty_->MasterPort(kSlcanSerialBaud), adapter_bus_.get(), hal::SlcanAdapterSim::Options{});
  std::string path = pty_->slave_path();
  if (!link.empty()) {
    pty_->CreateLink(link);
    path = link;
  }
  if (running_) adapter_->Start();
  return "slcan:" + path + "@" + std::to_string(kSlcanSerialBaud) +
         ",bitrate=" + std::to_string(config_.can_bitrate);
}

void HexapodWorld::Start() {
  if (timing_ != Timing::kRealTime || running_.exchange(true)) return;
  if (adapter_) adapter_->Start();
  for (auto& d : drives_) d->Start();
  plant_thread_ = std::thread([this] { PlantLoop(); });
}

void HexapodWorld::Stop() {
  if (!running_.exchange(false)) return;
  if (plant_thread_.joinable()) plant_thread_.join();
  if (adapter_) adapter_->Stop();
  for (auto& d : drives_) d->Stop();
}

void HexapodWorld::PlantLoop() {
  const auto period = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
      std::chrono::duration<double>(config_.step_period_s));
  auto next = std::chrono::steady_clock::now();
  while (running_) {
    UpdatePlant();
    next += period;
    const auto now = std::chrono::steady_clock::now();
    if (next < now) next = now;  // overran: do not try to catch up
    std::this_thread::sleep_until(next);
  }
}

hal::PlantFeedback HexapodWorld::OnDriveStep(int leg, const hal::AxisState& commanded) {
  std::lock_guard<std::mutex> lock(mutex_);
  const double cpm = config_.counts_per_metre;
  hal::PlantFeedback fb;
  fb.torque = static_cast<int16_t>(std::lround(commanded.torque));
  if (!hooked_[leg]) {
    // The drive's first step: its motion model still starts at 0 counts. Report where the leg
    // is; the drive is powered off and re-synchronises its model to that.
    hooked_[leg] = true;
    fb.position = static_cast<int32_t>(std::lround(state_.s[leg] * cpm));
    return fb;
  }
  commanded_s_[leg] = commanded.position / cpm;
  if (state_.held) {
    fb.position = static_cast<int32_t>(std::lround(state_.s[leg] * cpm));
    fb.velocity = 0;
  } else {
    fb.position = static_cast<int32_t>(std::lround(commanded.position));
    fb.velocity = static_cast<int32_t>(std::lround(commanded.velocity));
  }
  return fb;
}

void HexapodWorld::UpdatePlant() {
  std::lock_guard<std::mutex> lock(mutex_);
  state_.time = clock_->Now();
  ++state_.updates;
  robots::Vector6d q;
  for (int j = 0; j < kHexapodLegs; ++j) q[j] = true_.q0[j] + commanded_s_[j];
  if (!state_.held && q == state_.q) return;  // nothing moved
  // The previous pose is the warm start: legs move by micrometres per step, so Newton stays on
  // the assembly mode the platform is in.
  const robots::ForwardKinematicsSummary fk = robots::ForwardKinematics(
      true_, q, state_.X_BP, robots::ForwardKinematicsOptions{}, &fk_data_);
  const bool was_held = state_.held;
  state_.fk_status = fk.status;
  if (fk.converged()) {
    state_.X_BP = fk.X_BP;
    state_.q = q;
    for (int j = 0; j < kHexapodLegs; ++j) state_.s[j] = commanded_s_[j];
    state_.held = false;
    if (was_held) spdlog::info("hexapod world: the platform follows the legs again");
  } else {
    state_.held = true;
    ++state_.holds;
    if (!was_held) {
      spdlog::warn(
          "hexapod world: forward kinematics of the commanded legs failed ({}, residual {} m, "
          "condition {}): the platform holds",
          robots::ToString(fk.status), fk.residual, fk.condition_number);
    }
  }
}

HexapodPlantState HexapodWorld::plant() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return state_;
}

hal::Cia402Device& HexapodWorld::drive_device(int leg) { return drive(leg).device(); }

hal::CanopenDriveSim& HexapodWorld::drive(int leg) {
  KINEVIS_DEMAND(leg >= 0 && leg < kHexapodLegs);
  return *drives_.at(static_cast<size_t>(leg));
}

std::vector<std::string> HexapodWorld::RegisterCameras(SceneFactory factory) {
  if (!factory) throw std::invalid_argument("hexapod world: RegisterCameras needs a scene factory");
  std::vector<std::string> names;
  for (const WorldCameraConfig& c : config_.cameras) {
    auto camera = std::make_unique<Camera>();
    camera->config = c;
    camera->model = vision::OpenCameraModel(c.model);
    camera->renderer = std::make_unique<vision::render::Renderer>(*camera->model, c.render);
    Camera* cam = camera.get();
    hal::CameraFormat format;
    format.width = cam->model->width();
    format.height = cam->model->height();
    format.pixel_format = hal::PixelFormat::kMono8;
    format.fps = c.fps;
    hal::RegisterRenderSource(
        c.name, format,
        [this, cam, factory](uint64_t frame_id, common::Duration, hal::Image* image) {
          const HexapodPlantState state = plant();  // a copy: the render never blocks a step
          const std::unique_ptr<vision::render::Scene> scene =
              factory(true_, state, cam->config.X_WC);
          std::lock_guard<std::mutex> lock(cam->mutex);
          cam->renderer->Render(
              *scene, frame_id,
              vision::ImageView8{image->data.data(), image->width, image->height, image->stride});
          return std::error_code{};
        },
        c.model);
    names.push_back(c.name);
    cameras_.push_back(std::move(camera));
  }
  return names;
}

std::vector<std::string> HexapodWorld::camera_sources() const {
  std::vector<std::string> names;
  for (const auto& camera : cameras_) names.push_back(camera->config.name);
  return names;
}

}  // namespace kinevis::sim
