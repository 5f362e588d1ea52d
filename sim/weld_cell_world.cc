#include "sim/weld_cell_world.h"

#include <spdlog/spdlog.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <random>
#include <stdexcept>

#include "common/check.h"
#include "common/clock.h"
#include "common/units.h"
#include "hal/camera/frame_server.h"
#include "hal/camera/sim_camera.h"
#include "hal/mock/weld_robot_sim.h"
#include "robots/io/robot_description.h"
#include "vision/camera/camera_file.h"

namespace kinevis::sim {

namespace {

constexpr size_t kScanLogLength = 10000;

Eigen::Isometry3d Pose(const Eigen::Vector3d& p, const Eigen::Vector3d& rpy_deg) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = (Eigen::AngleAxisd(rpy_deg.z() * common::kDeg, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(rpy_deg.y() * common::kDeg, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(rpy_deg.x() * common::kDeg, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  X.translation() = p;
  return X;
}

robots::Vector5d ToVector(const std::array<double, robots::kWeld5Joints>& q) {
  robots::Vector5d v;
  for (int i = 0; i < robots::kWeld5Joints; ++i) v(i) = q[static_cast<size_t>(i)];
  return v;
}

}  // namespace

Eigen::Isometry3d NominalScannerMount() {
  return Pose(Eigen::Vector3d(-0.050, -0.060, 0.100), Eigen::Vector3d::Zero());
}

Eigen::Isometry3d DefaultTrueScannerMount() {
  // A clamp tightened by hand: under a millimetre and under a degree.
  return NominalScannerMount() *
         Pose(Eigen::Vector3d(0.6e-3, -0.4e-3, 0.9e-3), Eigen::Vector3d(0.4, -0.3, 0.7));
}

Eigen::Isometry3d DefaultWorkpiecePose() {
  // x_S = z_0 (up), y_S = y_0, z_S = −x_0 (facing the robot): Ry(−90°). Centre 0.40 m in front
  // of the camera at the default initial joints.
  return Pose(Eigen::Vector3d(0.70, 0.045, 0.294), Eigen::Vector3d(0.0, -90.0, 0.0));
}

vision::render::LaserSceneParameters DefaultCalibrationBoard(bool gauge_block) {
  vision::render::LaserSceneParameters p;
  p.surface = vision::render::LaserSurfaceKind::kBoard;
  p.half_extent = Eigen::Vector2d(0.15, 0.10);
  p.gauge_block = gauge_block;
  if (!gauge_block) {
    // The scanner calibration board: the seed's 9 x 9 dots at 26.5 mm (212 mm across) need a
    // taller board.
    p.half_extent = Eigen::Vector2d(0.15, 0.13);
    p.dot_grid = true;  // the seed's DotGrid defaults
  }
  return p;
}

vision::render::LaserSceneParameters DefaultBlade() {
  vision::render::LaserSceneParameters p;
  p.surface = vision::render::LaserSurfaceKind::kBlade;
  p.half_extent = Eigen::Vector2d(0.10, 0.08);
  p.curvature_xx = 1.5;
  p.curvature_yy = 0.5;
  p.curvature_xy = 0.3;
  vision::render::CavitationPit a, b, c;
  a.centre_S = Eigen::Vector2d(0.020, 0.0);  // on the rotating laser's stripe
  a.depth = 1.0e-3;
  a.sigma = 3.0e-3;
  b.centre_S = Eigen::Vector2d(-0.045, 0.002);
  b.depth = 0.6e-3;
  b.sigma = 2.0e-3;
  c.centre_S = Eigen::Vector2d(-0.030, 0.030);  // on the fixed laser's stripe
  c.depth = 1.2e-3;
  c.sigma = 4.0e-3;
  p.pits = {a, b, c};
  return p;
}

std::string WeldCellWorldConfig::Validate() const {
  common::Problems p;
  using common::Num;
  const std::string robot =
      robot_description.empty() ? "robot" : "robot (" + robot_description + ")";
  const std::string model_problems = nominal.Validate();
  if (!model_problems.empty()) p.Add(robot + ": " + model_problems);
  for (int j = 0; j < robots::kWeld5Joints; ++j) {
    const std::string name = robots::Weld5JointName(j);
    const double q0 = initial_joints[static_cast<size_t>(j)];
    if (!(q0 >= nominal.q_min(j) && q0 <= nominal.q_max(j))) {
      p.Add("modbus.initial_joints[" + std::to_string(j) + "]: " + Num(q0) +
            " is outside the limits of " + name);
    }
  }
  p.NonNegative("truth.dh_length_sigma_mm", dh_length_sigma_mm);
  p.NonNegative("truth.dh_angle_sigma_deg", dh_angle_sigma_deg);
  if (scanner_camera.empty()) p.Add("scanner.camera: must not be empty");
  if (!X_5C_nominal.matrix().allFinite()) p.Add("scanner.nominal_mount: not finite");
  if (!X_5C.matrix().allFinite()) p.Add("truth.scanner_mount: not finite");
  const std::string geometry = scanner.Validate();
  if (!geometry.empty()) p.Add("scanner: " + geometry);
  if (!std::isfinite(cot_theta_y))
    p.Add("scanner.cot_theta_y: must be finite, got " + Num(cot_theta_y));
  if (camera_name.empty()) p.Add("scanner.name: must not be empty");
  p.Positive("scanner.fps", fps);
  const std::string render_problems = render.Validate();
  if (!render_problems.empty()) p.Add("scanner.render: " + render_problems);
  const std::string surface = workpiece.Validate();
  if (!surface.empty()) p.Add("workpiece: " + surface);
  if (!X_0S.matrix().allFinite()) p.Add("workpiece.pose: not finite");
  if (tcp_port < 0 || tcp_port > 65535) {
    p.Add("modbus.port: must be in 0..65535, got " + std::to_string(tcp_port));
  }
  if (!rtu && !rtu_link.empty()) p.Add("modbus.link: only with transport rtu");
  if (unit < 1 || unit > 247) p.Add("modbus.unit: must be in 1..247, got " + std::to_string(unit));
  if (buffer_capacity < 1 || buffer_capacity > 1000) {
    p.Add("modbus.buffer: must be in 1..1000, got " + std::to_string(buffer_capacity));
  }
  if (!(step_period_s > 0 && step_period_s <= 0.1)) {
    p.Add("step_period_ms: must be in (0, 100], got " + Num(step_period_s * 1e3));
  }
  return p.Message();
}

namespace {

// The workpiece's cavitation pits: a list of {centre_mm: [x, y], depth_mm, sigma_mm}. The shared
// reader walks mappings only, so the list is read here.
std::vector<vision::render::CavitationPit> ReadPits(const std::string& path,
                                                    internal::WorldConfigReader* r) {
  std::vector<vision::render::CavitationPit> pits;
  const YAML::Node root = YAML::LoadFile(path);  // the reader has already parsed it once
  const YAML::Node list = root["workpiece"]["pits"];
  if (!list.IsSequence()) {
    r->Problem("workpiece.pits: expected a list of {centre_mm: [x, y], depth_mm, sigma_mm}");
    return pits;
  }
  for (size_t i = 0; i < list.size(); ++i) {
    const std::string key = "workpiece.pits[" + std::to_string(i) + "]";
    const YAML::Node n = list[i];
    vision::render::CavitationPit pit;
    if (!n.IsMap()) {
      r->Problem(key + ": expected a mapping");
      continue;
    }
    const auto number = [&](const YAML::Node& v, const std::string& k) {
      try {
        const double x = v.as<double>();
        if (std::isfinite(x)) return x;
      } catch (const YAML::Exception&) {
      }
      r->Problem(key + "." + k + ": expected a finite number");
      return std::nan("");
    };
    for (const auto& kv : n) {
      const std::string k = kv.first.Scalar();
      if (k == "centre_mm") {
        if (!kv.second.IsSequence() || kv.second.size() != 2) {
          r->Problem(key + ".centre_mm: need a list of 2 numbers");
        } else {
          pit.centre_S = Eigen::Vector2d(number(kv.second[0], k), number(kv.second[1], k)) * 1e-3;
        }
      } else if (k == "depth_mm") {
        pit.depth = number(kv.second, k) * 1e-3;
      } else if (k == "sigma_mm") {
        pit.sigma = number(kv.second, k) * 1e-3;
      } else {
        r->Problem(key + "." + k + ": unknown key");
      }
    }
    pits.push_back(pit);
  }
  return pits;
}

}  // namespace

WeldCellWorldConfig LoadWeldCellWorldConfig(const std::string& path) {
  internal::WorldConfigReader r(path, "weld-cell");
  WeldCellWorldConfig c;
  const std::string robot = r.Path("robot");
  if (!robot.empty()) {
    try {
      const robots::Weld5Description d = robots::LoadWeld5Description(robot);
      c.nominal = d.model;
      c.robot_description = robot;
    } catch (const std::invalid_argument& e) {
      r.Problem(std::string("robot: ") + e.what());
    }
  }
  c.seed = static_cast<uint32_t>(r.Integer("seed", c.seed));

  r.CheckKeys("truth", {"dh_length_sigma_mm", "dh_angle_sigma_deg", "scanner_mount"});
  c.dh_length_sigma_mm = r.Number("truth.dh_length_sigma_mm", c.dh_length_sigma_mm);
  c.dh_angle_sigma_deg = r.Number("truth.dh_angle_sigma_deg", c.dh_angle_sigma_deg);
  c.X_5C = r.Pose("truth.scanner_mount", c.X_5C);

  r.CheckKeys("scanner", {"camera", "nominal_mount", "rotating_b_y_mm", "rotating_d_y_mm",
                          "fixed_b_x_prime_mm", "fixed_cot_theta_x", "cot_theta_y", "fixed_laser",
                          "rotating_laser", "name", "fps", "render"});
  if (r.Has("scanner.camera")) {
    c.scanner_camera = r.Text("scanner.camera", c.scanner_camera);
    if (c.scanner_camera.rfind("builtin:", 0) != 0) c.scanner_camera = r.Path("scanner.camera");
  }
  c.X_5C_nominal = r.Pose("scanner.nominal_mount", c.X_5C_nominal);
  c.scanner.rotating_b_y = r.Number("scanner.rotating_b_y_mm", c.scanner.rotating_b_y * 1e3) * 1e-3;
  c.scanner.rotating_d_y = r.Number("scanner.rotating_d_y_mm", c.scanner.rotating_d_y * 1e3) * 1e-3;
  c.scanner.fixed_b_x_prime =
      r.Number("scanner.fixed_b_x_prime_mm", c.scanner.fixed_b_x_prime * 1e3) * 1e-3;
  c.scanner.fixed_cot_theta_x = r.Number("scanner.fixed_cot_theta_x", c.scanner.fixed_cot_theta_x);
  c.cot_theta_y = r.Number("scanner.cot_theta_y", c.cot_theta_y);
  const auto flag = [&](const std::string& key, bool fallback) {
    const std::string text = r.Text(key, fallback ? "true" : "false");
    if (text == "true") return true;
    if (text == "false") return false;
    r.Problem(key + ": expected true or false, got '" + text + "'");
    return fallback;
  };
  c.fixed_laser_on = flag("scanner.fixed_laser", c.fixed_laser_on);
  c.rotating_laser_on = flag("scanner.rotating_laser", c.rotating_laser_on);
  c.camera_name = r.Text("scanner.name", c.camera_name);
  c.fps = r.Number("scanner.fps", c.fps);
  r.CheckKeys("scanner.render",
              {"supersampling", "blur_sigma_px", "vignetting", "exposure", "noise_sigma", "seed"});
  c.render.supersampling =
      static_cast<int>(r.Integer("scanner.render.supersampling", c.render.supersampling));
  c.render.blur_sigma_px = r.Number("scanner.render.blur_sigma_px", c.render.blur_sigma_px);
  c.render.vignetting = r.Number("scanner.render.vignetting", c.render.vignetting);
  c.render.exposure = r.Number("scanner.render.exposure", c.render.exposure);
  c.render.noise_sigma = r.Number("scanner.render.noise_sigma", c.render.noise_sigma);
  c.render.seed = static_cast<uint64_t>(
      r.Integer("scanner.render.seed", static_cast<long long>(c.render.seed)));

  r.CheckKeys("workpiece", {"kind", "pose", "half_extent_mm", "curvature", "pits", "gauge_block"});
  vision::render::LaserSceneParameters& w = c.workpiece;
  const std::string kind = r.Text("workpiece.kind", "blade");
  if (kind == "board") {
    // A board starts from the board defaults, not the blade's shape.
    w = DefaultCalibrationBoard(/*gauge_block=*/true);
  } else if (kind != "blade") {
    r.Problem("workpiece.kind: expected blade or board, got '" + kind + "'");
  }
  c.X_0S = r.Pose("workpiece.pose", c.X_0S);
  const std::vector<double> extent =
      r.Numbers("workpiece.half_extent_mm", 2, {w.half_extent.x() * 1e3, w.half_extent.y() * 1e3});
  w.half_extent = Eigen::Vector2d(extent[0], extent[1]) * 1e-3;
  const std::vector<double> k =
      r.Numbers("workpiece.curvature", 3, {w.curvature_xx, w.curvature_yy, w.curvature_xy});
  w.curvature_xx = k[0];
  w.curvature_yy = k[1];
  w.curvature_xy = k[2];
  if (r.Has("workpiece.pits")) w.pits = ReadPits(r.path(), &r);
  if (r.Has("workpiece.gauge_block")) {
    r.CheckKeys("workpiece.gauge_block", {"present", "centre_mm", "heading_deg", "size_mm"});
    w.gauge_block = flag("workpiece.gauge_block.present", true);
    const std::vector<double> centre =
        r.Numbers("workpiece.gauge_block.centre_mm", 2,
                  {w.gauge_centre_S.x() * 1e3, w.gauge_centre_S.y() * 1e3});
    w.gauge_centre_S = Eigen::Vector2d(centre[0], centre[1]) * 1e-3;
    w.gauge_heading =
        r.Number("workpiece.gauge_block.heading_deg", w.gauge_heading / common::kDeg) *
        common::kDeg;
    const std::vector<double> size =
        r.Numbers("workpiece.gauge_block.size_mm", 3,
                  {w.gauge_size.x() * 1e3, w.gauge_size.y() * 1e3, w.gauge_size.z() * 1e3});
    w.gauge_size = Eigen::Vector3d(size[0], size[1], size[2]) * 1e-3;
  }

  r.CheckKeys("modbus", {"transport", "host", "port", "link", "unit", "buffer", "initial_joints"});
  const std::string transport = r.Text("modbus.transport", "tcp");
  if (transport == "rtu") {
    c.rtu = true;
  } else if (transport != "tcp") {
    r.Problem("modbus.transport: expected tcp or rtu, got '" + transport + "'");
  }
  c.tcp_host = r.Text("modbus.host", c.tcp_host);
  c.tcp_port = static_cast<int>(r.Integer("modbus.port", c.tcp_port));
  c.rtu_link = r.Text("modbus.link", c.rtu_link);
  c.unit = static_cast<int>(r.Integer("modbus.unit", c.unit));
  c.buffer_capacity = static_cast<int>(r.Integer("modbus.buffer", c.buffer_capacity));
  // [θ1, θ2, pz3, θ4, θ5] in deg, deg, mm, deg, deg (the `kinevis weld-robot move` units).
  const std::array<double, 5> scale{common::kDeg, common::kDeg, 1e-3, common::kDeg, common::kDeg};
  std::vector<double> fallback;
  for (size_t j = 0; j < 5; ++j) fallback.push_back(c.initial_joints[j] / scale[j]);
  const std::vector<double> q0 = r.Numbers("modbus.initial_joints", 5, fallback);
  for (size_t j = 0; j < 5; ++j) c.initial_joints[j] = q0[j] * scale[j];
  c.step_period_s = r.Number("step_period_ms", c.step_period_s * 1e3) * 1e-3;
  r.CheckKeys(
      "", {"world", "robot", "seed", "truth", "scanner", "workpiece", "modbus", "step_period_ms"});
  r.ThrowIfProblems();
  const std::string invalid = c.Validate();
  if (!invalid.empty()) r.Problem(invalid);
  r.ThrowIfProblems();
  return c;
}

robots::Weld5Model TrueWeld5Model(const WeldCellWorldConfig& config) {
  robots::Weld5Model m = config.nominal;
  std::mt19937 generator(config.seed);
  std::normal_distribution<double> length(0.0, 1.0), angle(0.0, 1.0);
  const double s_len = config.dh_length_sigma_mm * 1e-3;
  const double s_ang = config.dh_angle_sigma_deg * common::kDeg;
  // Fixed draw order, link by link: a, d, α, θ offset.
  for (robots::DhJoint& j : m.joints) {
    j.a += s_len * length(generator);
    j.d += s_len * length(generator);
    j.alpha += s_ang * angle(generator);
    j.theta_offset += s_ang * angle(generator);
  }
  return m;
}

// ---------------------------------------------------------------------------------------------

WeldCellWorld::WeldCellWorld(WeldCellWorldConfig config, Timing timing)
    : config_(std::move(config)),
      timing_(timing),
      true_(TrueWeld5Model(config_)),
      clock_(timing == Timing::kStepped ? static_cast<common::Clock*>(&sim_time_)
                                        : &common::SteadyClock::Instance()),
      cot_theta_y_(config_.cot_theta_y),
      fixed_on_(config_.fixed_laser_on),
      rotating_on_(config_.rotating_laser_on) {
  const std::string invalid = config_.Validate();
  if (!invalid.empty()) throw std::invalid_argument("weld-cell world: " + invalid);
  camera_ = vision::OpenCameraModel(config_.scanner_camera);
  renderer_ = std::make_unique<vision::render::Renderer>(*camera_, config_.render);
  // Throws for a bad workpiece now rather than at the first frame.
  (void)SceneAt(config_.initial_joints);

  world_clock_ =
      std::make_unique<WorldClock>(&sim_time_, [this](common::Duration t) { StepTo(t); });

  hal::WeldRobotSim::Options o;
  for (int j = 0; j < robots::kWeld5Joints; ++j) {
    // The controller enforces the nominal description's limits (the host's file).
    o.joints[static_cast<size_t>(j)] = {config_.nominal.q_min(j), config_.nominal.q_max(j),
                                        config_.nominal.qd_max(j)};
  }
  o.initial_joints = config_.initial_joints;
  o.buffer_capacity = config_.buffer_capacity;
  o.unit = config_.unit;
  o.run_executor = timing_ == Timing::kRealTime;
  o.clock = clock_;
  o.name = "weld-cell robot";
  robot_ = config_.rtu ? hal::WeldRobotSim::ServeRtu(o, config_.rtu_link)
                       : hal::WeldRobotSim::ListenTcp(config_.tcp_host, config_.tcp_port, o);
}

WeldCellWorld::~WeldCellWorld() {
  if (!registered_.empty()) hal::UnregisterRenderSource(registered_);
  if (frame_server_) frame_server_->Stop();
  frame_server_.reset();
  robot_.reset();
}

const std::string& WeldCellWorld::backend() const { return robot_->backend(); }
hal::WeldRobotSim& WeldCellWorld::robot() { return *robot_; }

common::Clock& WeldCellWorld::clock() {
  if (timing_ == Timing::kStepped) return *world_clock_;
  return *clock_;
}

void WeldCellWorld::Step(common::Duration dt) { StepTo(sim_time_.Now() + dt); }

void WeldCellWorld::StepTo(common::Duration t) {
  KINEVIS_DEMAND(timing_ == Timing::kStepped);
  const common::Duration period = common::FromSeconds(config_.step_period_s);
  while (sim_time_.Now() < t) {
    const common::Duration dt = std::min(period, t - sim_time_.Now());
    sim_time_.Advance(dt);
    robot_->Step(dt);
  }
}

std::array<double, robots::kWeld5Joints> WeldCellWorld::joints() const {
  return robot_->state().joints;
}

Eigen::Isometry3d WeldCellWorld::TrueScannerPose(
    const std::array<double, robots::kWeld5Joints>& q) const {
  return robots::DhForwardKinematics(true_.joints, ToVector(q)) * config_.X_5C;
}

void WeldCellWorld::SetLaserAngle(double cot_theta_y) {
  if (!std::isfinite(cot_theta_y)) {
    throw std::invalid_argument("weld-cell world: laser angle cot_theta_y must be finite, got " +
                                common::Num(cot_theta_y));
  }
  std::lock_guard<std::mutex> lock(mutex_);
  cot_theta_y_ = cot_theta_y;
}

void WeldCellWorld::SetLasers(bool fixed_on, bool rotating_on) {
  std::lock_guard<std::mutex> lock(mutex_);
  fixed_on_ = fixed_on;
  rotating_on_ = rotating_on;
}

double WeldCellWorld::laser_angle() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return cot_theta_y_;
}

std::unique_ptr<vision::render::LaserScene> WeldCellWorld::SceneAt(
    const std::array<double, robots::kWeld5Joints>& q) const {
  vision::render::LaserSceneParameters p = config_.workpiece;
  p.scanner = config_.scanner;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    p.rotating_cot_theta_y = cot_theta_y_;
    p.fixed_on = fixed_on_;
    p.rotating_on = rotating_on_;
  }
  // X_CS = X_0C⁻¹ · X_0S with the true robot and mount.
  p.X_CS = TrueScannerPose(q).inverse() * config_.X_0S;
  return std::make_unique<vision::render::LaserScene>(p);
}

hal::CameraFormat WeldCellWorld::camera_format() const {
  hal::CameraFormat f;
  f.width = camera_->width();
  f.height = camera_->height();
  f.pixel_format = hal::PixelFormat::kMono8;
  f.fps = config_.fps;
  return f;
}

ScanRecord WeldCellWorld::RenderScan(uint64_t frame_id, const vision::ImageView8& out,
                                     vision::render::GroundTruth* truth) {
  ScanRecord record;
  record.frame_id = frame_id;
  record.time = clock_->Now();
  record.joints = joints();  // the controller's actual joints at this instant
  record.X_0C = TrueScannerPose(record.joints);
  record.cot_theta_y = laser_angle();
  const std::unique_ptr<vision::render::LaserScene> scene = SceneAt(record.joints);
  {
    std::lock_guard<std::mutex> lock(render_mutex_);
    renderer_->Render(*scene, frame_id, out, truth);
  }
  std::lock_guard<std::mutex> lock(mutex_);
  scan_log_.push_back(record);
  while (scan_log_.size() > kScanLogLength) scan_log_.pop_front();
  return record;
}

std::vector<ScanRecord> WeldCellWorld::scan_log() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return {scan_log_.begin(), scan_log_.end()};
}

std::string WeldCellWorld::RegisterCamera() {
  if (!registered_.empty()) throw std::logic_error("weld-cell world: camera registered twice");
  hal::RegisterRenderSource(
      config_.camera_name, camera_format(),
      [this](uint64_t frame_id, common::Duration, hal::Image* image) {
        RenderScan(frame_id, vision::ImageView8{image->data.data(), image->width, image->height,
                                                image->stride});
        return std::error_code{};
      },
      config_.scanner_camera);
  registered_ = config_.camera_name;
  return registered_;
}

std::string WeldCellWorld::ServeCamera(const hal::FrameServerOptions& options) {
  if (frame_server_) throw std::logic_error("weld-cell world: camera served twice");
  hal::FrameServerOptions o = options;
  o.fps = config_.fps;
  frame_server_ = hal::FrameServer::Listen(
      hal::RenderFrameSource(
          camera_format(),
          [this](uint64_t frame_id, common::Duration, hal::Image* image) {
            RenderScan(frame_id, vision::ImageView8{image->data.data(), image->width, image->height,
                                                    image->stride});
            return std::error_code{};
          },
          config_.scanner_camera, clock()),
      o);
  spdlog::info("weld-cell world: scanner camera {} served at {}", config_.scanner_camera,
               frame_server_->backend());
  return frame_server_->backend();
}

}  // namespace kinevis::sim
