#include "sim/diamond_world.h"

#include <spdlog/spdlog.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <set>
#include <stdexcept>

#include "common/check.h"
#include "common/clock.h"
#include "common/units.h"
#include "hal/camera/sim_camera.h"
#include "hal/common/error.h"
#include "hal/mock/rs485_drive_sim.h"
#include "hal/serial/pty_pair.h"
#include "robots/io/robot_description.h"
#include "vision/camera/camera_file.h"

namespace kinevis::sim {

using robots::kDiamondJoints;

namespace {

// The conditions that stop the mechanism (the rest of DiamondReachability, the (φ, γ) box, is a
// task-space convention, not a stop).
bool Blocks(const robots::DiamondReachability& reach, robots::DiamondReach* reason) {
  for (int i = 0; i < reach.count; ++i) {
    const robots::DiamondReach r = reach.issues[i].reach;
    if (r != robots::DiamondReach::kPhiOutside && r != robots::DiamondReach::kGammaOutside) {
      *reason = r;
      return true;
    }
  }
  return false;
}

}  // namespace

std::string DiamondWorldConfig::Validate() const {
  common::Problems p;
  const std::string t = truth.Validate();
  if (!t.empty()) p.Add("truth (" + truth_description + "): " + t);
  const std::string n = nominal.Validate();
  if (!n.empty()) p.Add("nominal (" + nominal_description + "): " + n);
  for (int i = 0; i < kDiamondJoints; ++i) {
    const std::string k = "[" + std::to_string(i) + "]";
    if (!std::isfinite(joint_offset_errors[i])) {
      p.Add("perturbation.joint_offset_errors_deg" + k + ": not finite");
    }
    if (!std::isfinite(home_task[i])) p.Add("home_task_deg" + k + ": not finite");
  }
  std::set<int> seen;
  for (int i = 0; i < kDiamondJoints; ++i) {
    const std::string key = "drives.units[" + std::to_string(i) + "]";
    if (units[i] < 1 || units[i] > 247) {
      p.Add(key + ": must be in 1..247, got " + std::to_string(units[i]));
    } else if (!seen.insert(units[i]).second) {
      p.Add(key + ": " + std::to_string(units[i]) + " appears twice");
    }
  }
  p.Positive("drives.counts_per_rad", counts_per_rad);
  p.Positive("drives.max_velocity", max_velocity);
  p.Positive("drives.max_acceleration", max_acceleration);
  p.Positive("drives.following_error_window", following_error_window);
  if (baud <= 0) p.Add("drives.baud: must be > 0, got " + std::to_string(baud));
  p.Positive("step_period_ms", step_period_s * 1e3);
  if (step_period_s > 0.01) {
    p.Add("step_period_ms: " + common::Num(step_period_s * 1e3) + " must be <= 10");
  }
  internal::ValidateCameras(cameras, &p);
  return p.Message();
}

robots::DiamondModel TrueDiamondModel(const DiamondWorldConfig& config) {
  robots::DiamondModel truth = config.truth;
  for (int i = 0; i < kDiamondJoints; ++i) truth.joint_offsets[i] += config.joint_offset_errors[i];
  return truth;
}

DiamondWorldConfig LoadDiamondWorldConfig(const std::string& path) {
  internal::WorldConfigReader r(path, "diamond");
  DiamondWorldConfig c;
  const auto load = [&](const char* key, std::string* file, robots::DiamondModel* model) {
    *file = r.Path(key);
    if (file->empty()) return;
    try {
      *model = robots::LoadDiamondDescription(*file).model;
    } catch (const std::exception& e) {
      r.Problem(std::string(key) + ": " + e.what());
    }
  };
  load("truth", &c.truth_description, &c.truth);
  load("nominal", &c.nominal_description, &c.nominal);
  const std::vector<double> errors =
      r.Numbers("perturbation.joint_offset_errors_deg", kDiamondJoints,
                {c.joint_offset_errors[0] / common::kDeg, c.joint_offset_errors[1] / common::kDeg});
  for (int i = 0; i < kDiamondJoints; ++i) c.joint_offset_errors[i] = errors[i] * common::kDeg;
  r.CheckKeys("perturbation", {"joint_offset_errors_deg"});
  const std::vector<double> home =
      r.Numbers("home_task_deg", 2, {c.home_task[0] / common::kDeg, c.home_task[1] / common::kDeg});
  c.home_task = Eigen::Vector2d(home[0], home[1]) * common::kDeg;
  const std::vector<double> units =
      r.Numbers("drives.units", kDiamondJoints, {double(c.units[0]), double(c.units[1])});
  for (int i = 0; i < kDiamondJoints; ++i) c.units[i] = static_cast<int>(units[i]);
  c.counts_per_rad = r.Number("drives.counts_per_rad", c.counts_per_rad);
  c.max_velocity = r.Number("drives.max_velocity", c.max_velocity);
  c.max_acceleration = r.Number("drives.max_acceleration", c.max_acceleration);
  c.following_error_window = r.Number("drives.following_error_window", c.following_error_window);
  c.baud = static_cast<int>(r.Integer("drives.baud", c.baud));
  r.CheckKeys("drives", {"units", "counts_per_rad", "max_velocity", "max_acceleration",
                         "following_error_window", "baud"});
  c.step_period_s = r.Number("step_period_ms", c.step_period_s * 1e3) * 1e-3;
  c.cameras = r.Cameras(c.cameras);
  r.CheckKeys("", {"world", "truth", "nominal", "perturbation", "home_task_deg", "drives",
                   "step_period_ms", "cameras"});
  r.ThrowIfProblems();
  const std::string invalid = c.Validate();
  if (!invalid.empty()) r.Problem(invalid);
  r.ThrowIfProblems();
  return c;
}

struct DiamondWorld::Camera {
  WorldCameraConfig config;
  std::unique_ptr<vision::CameraModel> model;
  std::mutex mutex;
  std::unique_ptr<vision::render::Renderer> renderer;
};

DiamondWorld::DiamondWorld(DiamondWorldConfig config, Timing timing, const std::string& link)
    : config_(std::move(config)),
      timing_(timing),
      true_(TrueDiamondModel(config_)),
      clock_(timing == Timing::kStepped ? static_cast<common::Clock*>(&sim_time_)
                                        : &common::SteadyClock::Instance()) {
  std::string invalid = config_.Validate();
  if (invalid.empty()) {
    const std::string t = true_.Validate();
    if (!t.empty()) invalid = "the true robot is not valid: " + t;
  }
  if (!invalid.empty()) throw std::invalid_argument("diamond world: " + invalid);

  Eigen::Vector2d q_home;
  const robots::DiamondReachability reach =
      robots::InverseKinematics(true_, config_.home_task, &q_home);
  robots::DiamondReach reason;
  if (reach.Has(robots::DiamondReach::kUnreachable) ||
      reach.Has(robots::DiamondReach::kInvalidInput) ||
      reach.Has(robots::DiamondReach::kFoldedBranchOnly) || Blocks(reach, &reason)) {
    throw std::invalid_argument("diamond world: the true robot cannot reach the home task point: " +
                                reach.Describe());
  }
  commanded_q_ = {q_home[0], q_home[1]};
  state_.q = q_home;
  robots::DiamondData data;
  robots::ForwardKinematics(true_, q_home, &data);
  state_.task = data.task;
  state_.u_O = data.u_O;
  state_.p_O_T = data.p_O_T;

  world_clock_ =
      std::make_unique<WorldClock>(&sim_time_, [this](common::Duration t) { StepTo(t); });
  pty_ = std::make_unique<hal::PtyPair>();
  std::string path = pty_->slave_path();
  if (!link.empty()) {
    pty_->CreateLink(link);
    path = link;
  }
  hal::Rs485DriveSim::Options options;
  options.baud = config_.baud;
  options.step_period_s = config_.step_period_s;
  options.drives.clear();
  const double cpr = config_.counts_per_rad;
  for (int i = 0; i < kDiamondJoints; ++i) {
    hal::Rs485DriveSim::DriveOptions d;
    d.unit = config_.units[i];
    d.serial_number = static_cast<uint32_t>(2000 + i);
    d.device.limits.max_velocity = config_.max_velocity * cpr;
    d.device.limits.max_acceleration = config_.max_acceleration * cpr;
    // The joint stops: the true θ range, in readings.
    d.device.limits.min_position = std::ceil((true_.theta_min[i] - true_.joint_offsets[i]) * cpr);
    d.device.limits.max_position = std::floor((true_.theta_max[i] - true_.joint_offsets[i]) * cpr);
    d.device.following_error_window =
        static_cast<uint32_t>(std::llround(config_.following_error_window * cpr));
    options.drives.push_back(d);
  }
  drives_ = std::make_unique<hal::Rs485DriveSim>(pty_->master_fd(), path, clock_, options);
  for (int i = 0; i < kDiamondJoints; ++i) {
    drives_->device(config_.units[i])
        .SetPlantHook([this, i](const hal::AxisState& commanded, double /*dt_s*/) {
          return OnDriveStep(i, commanded);
        });
  }
}

DiamondWorld::~DiamondWorld() {
  for (const auto& camera : cameras_) hal::UnregisterRenderSource(camera->config.name);
  Stop();
  drives_->Stop();  // the line thread too, before the hooks' target goes
}

const std::string& DiamondWorld::backend() const { return drives_->backend(); }

common::Clock& DiamondWorld::clock() {
  if (timing_ == Timing::kStepped) return *world_clock_;
  return common::SteadyClock::Instance();
}

void DiamondWorld::Step(common::Duration dt) { StepTo(sim_time_.Now() + dt); }

void DiamondWorld::StepTo(common::Duration t) {
  KINEVIS_DEMAND_MSG(timing_ == Timing::kStepped, "DiamondWorld::Step called on a real-time world");
  const common::Duration period = common::FromSeconds(config_.step_period_s);
  while (sim_time_.Now() < t) {
    sim_time_.AdvanceTo(std::min(t, sim_time_.Now() + period));
    drives_->Step();
    UpdatePlant();
  }
}

void DiamondWorld::Start() {
  if (timing_ != Timing::kRealTime || running_.exchange(true)) return;
  drives_->Start();
  plant_thread_ = std::thread([this] {
    const auto period = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
        std::chrono::duration<double>(config_.step_period_s));
    auto next = std::chrono::steady_clock::now();
    while (running_) {
      UpdatePlant();
      next = std::max(next + period, std::chrono::steady_clock::now());
      std::this_thread::sleep_until(next);
    }
  });
}

void DiamondWorld::Stop() {
  if (!running_.exchange(false)) return;
  if (plant_thread_.joinable()) plant_thread_.join();
}

hal::PlantFeedback DiamondWorld::OnDriveStep(int joint, const hal::AxisState& commanded) {
  std::lock_guard<std::mutex> lock(mutex_);
  const double cpr = config_.counts_per_rad;
  hal::PlantFeedback fb;
  fb.torque = static_cast<int16_t>(std::lround(commanded.torque));
  if (!hooked_[joint]) {  // first step: the drive's model still starts at 0 (hexapod_world.cc)
    hooked_[joint] = true;
    fb.position = static_cast<int32_t>(std::lround(state_.q[joint] * cpr));
    return fb;
  }
  commanded_q_[joint] = commanded.position / cpr;
  if (state_.held) {
    fb.position = static_cast<int32_t>(std::lround(state_.q[joint] * cpr));
  } else {
    fb.position = static_cast<int32_t>(std::lround(commanded.position));
    fb.velocity = static_cast<int32_t>(std::lround(commanded.velocity));
  }
  return fb;
}

void DiamondWorld::UpdatePlant() {
  std::lock_guard<std::mutex> lock(mutex_);
  state_.time = clock_->Now();
  ++state_.updates;
  const Eigen::Vector2d q(commanded_q_[0], commanded_q_[1]);
  if (!state_.held && q == state_.q) return;
  robots::DiamondData data;
  const robots::DiamondReachability reach = robots::ForwardKinematics(true_, q, &data);
  robots::DiamondReach reason = robots::DiamondReach::kOk;
  const bool was_held = state_.held;
  if (data.valid && !Blocks(reach, &reason)) {
    state_.q = q;
    state_.task = data.task;
    state_.u_O = data.u_O;
    state_.p_O_T = data.p_O_T;
    state_.held = false;
    state_.reason = robots::DiamondReach::kOk;
    if (was_held) spdlog::info("diamond world: the mechanism follows the drives again");
  } else {
    if (!data.valid) reason = reach.first();
    state_.held = true;
    state_.reason = reason;
    ++state_.holds;
    if (!was_held) {
      spdlog::warn("diamond world: the commanded joints are not feasible ({}): the mechanism holds",
                   robots::ToString(reason));
    }
  }
}

DiamondPlantState DiamondWorld::plant() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return state_;
}

hal::Cia402Device& DiamondWorld::drive_device(int joint) {
  return drives_->device(config_.units.at(static_cast<size_t>(joint)));
}

std::vector<std::string> DiamondWorld::RegisterCameras(SceneFactory factory) {
  if (!factory) throw std::invalid_argument("diamond world: RegisterCameras needs a scene factory");
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
          const DiamondPlantState state = plant();
          const auto scene = factory(true_, state, cam->config.X_WC);
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

std::vector<std::string> DiamondWorld::camera_sources() const {
  std::vector<std::string> names;
  for (const auto& camera : cameras_) names.push_back(camera->config.name);
  return names;
}

}  // namespace kinevis::sim
