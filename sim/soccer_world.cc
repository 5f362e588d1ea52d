#include "sim/soccer_world.h"

#include <spdlog/spdlog.h>

#include <cmath>
#include <stdexcept>

#include "common/units.h"
#include "hal/camera/frame_server.h"
#include "hal/camera/sim_camera.h"
#include "sim/world_common.h"  // internal::WorldConfigReader, common::Problems

namespace kinevis::sim {

namespace {}  // namespace

vision::HyperbolicMirrorParameters DefaultTrueSoccerCamera() {
  vision::HyperbolicMirrorParameters p = vision::HyperbolicMirrorParameters::Seed000Lens4mm();
  p.sensor_offset_x = 0.05e-3;
  p.sensor_offset_z = -0.03e-3;
  p.sensor_gamma = 0.8 * common::kDeg;
  p.sensor_rho = 0.6 * common::kDeg;
  p.sensor_theta = -0.5 * common::kDeg;
  p.ground_rho = 0.5 * common::kDeg;
  p.ground_theta = -0.3 * common::kDeg;
  return p;
}

vision::HyperbolicMirrorParameters WithoutMisalignment(vision::HyperbolicMirrorParameters p) {
  p.sensor_offset_x = p.sensor_offset_z = 0.0;
  p.sensor_gamma = p.sensor_rho = p.sensor_theta = 0.0;
  p.ground_rho = p.ground_theta = 0.0;
  return p;
}

std::string SoccerWorldConfig::Validate() const {
  common::Problems p;
  const std::string cam = camera.Validate();
  if (!cam.empty()) p.Add("camera: " + cam);
  const std::string f = field.Validate();
  if (!f.empty()) p.Add("field: " + f);
  if (camera_name.empty()) p.Add("name: must not be empty");
  p.Positive("fps", fps);
  const std::string r = render.Validate();
  if (!r.empty()) p.Add("render: " + r);
  return p.Message();
}

SoccerWorldConfig LoadSoccerWorldConfig(const std::string& path) {
  internal::WorldConfigReader r(path, "soccer");
  SoccerWorldConfig c;
  vision::HyperbolicMirrorParameters& m = c.camera;
  r.CheckKeys("camera",
              {"lens", "sensor_offset_mm", "sensor_rotation_deg", "mirror_tilt_deg",
               "mirror_axis_mm", "apex_distance_mm", "apex_to_ground_mm", "focal_length_mm",
               "lens_correction", "width", "height", "cx", "cy", "pixel_pitch_um"});
  // The lens picks the seed's base set; the misalignments are then the defaults or the file's.
  const std::string lens = r.Text("camera.lens", "4mm");
  if (lens == "6mm") {
    const vision::HyperbolicMirrorParameters six =
        vision::HyperbolicMirrorParameters::Seed000Lens6mm();
    m.focal_length = six.focal_length;
    m.lens_correction = six.lens_correction;
    m.apex_distance = six.apex_distance;
  } else if (lens != "4mm") {
    r.Problem("camera.lens: expected 4mm or 6mm, got '" + lens + "'");
  }
  const std::vector<double> offset =
      r.Numbers("camera.sensor_offset_mm", 2, {m.sensor_offset_x * 1e3, m.sensor_offset_z * 1e3});
  m.sensor_offset_x = offset[0] * 1e-3;
  m.sensor_offset_z = offset[1] * 1e-3;
  const std::vector<double> rotation = r.Numbers(
      "camera.sensor_rotation_deg", 3,
      {m.sensor_gamma / common::kDeg, m.sensor_rho / common::kDeg, m.sensor_theta / common::kDeg});
  m.sensor_gamma = rotation[0] * common::kDeg;
  m.sensor_rho = rotation[1] * common::kDeg;
  m.sensor_theta = rotation[2] * common::kDeg;
  const std::vector<double> tilt = r.Numbers(
      "camera.mirror_tilt_deg", 2, {m.ground_rho / common::kDeg, m.ground_theta / common::kDeg});
  m.ground_rho = tilt[0] * common::kDeg;
  m.ground_theta = tilt[1] * common::kDeg;
  const std::vector<double> axis =
      r.Numbers("camera.mirror_axis_mm", 2, {m.mirror_axis_x * 1e3, m.mirror_axis_z * 1e3});
  m.mirror_axis_x = axis[0] * 1e-3;
  m.mirror_axis_z = axis[1] * 1e-3;
  m.apex_distance = r.Number("camera.apex_distance_mm", m.apex_distance * 1e3) * 1e-3;
  m.apex_to_ground = r.Number("camera.apex_to_ground_mm", m.apex_to_ground * 1e3) * 1e-3;
  m.focal_length = r.Number("camera.focal_length_mm", m.focal_length * 1e3) * 1e-3;
  const std::vector<double> k = r.Numbers(
      "camera.lens_correction", 4,
      {m.lens_correction[0], m.lens_correction[1], m.lens_correction[2], m.lens_correction[3]});
  for (size_t i = 0; i < 4; ++i) m.lens_correction[i] = k[i];
  m.width = static_cast<int>(r.Integer("camera.width", m.width));
  m.height = static_cast<int>(r.Integer("camera.height", m.height));
  m.cx = r.Number("camera.cx", m.cx);
  m.cy = r.Number("camera.cy", m.cy);
  m.pixel_pitch = r.Number("camera.pixel_pitch_um", m.pixel_pitch * 1e6) * 1e-6;

  r.CheckKeys("robot", {"x", "y", "heading_deg"});
  c.field.robot_x = r.Number("robot.x", c.field.robot_x);
  c.field.robot_y = r.Number("robot.y", c.field.robot_y);
  c.field.robot_heading =
      r.Number("robot.heading_deg", c.field.robot_heading / common::kDeg) * common::kDeg;
  r.CheckKeys("field", {"length", "width", "line_width", "centre_circle_radius", "carpet_border"});
  c.field.field_length = r.Number("field.length", c.field.field_length);
  c.field.field_width = r.Number("field.width", c.field.field_width);
  c.field.line_width = r.Number("field.line_width", c.field.line_width);
  c.field.centre_circle_radius =
      r.Number("field.centre_circle_radius", c.field.centre_circle_radius);
  c.field.carpet_border = r.Number("field.carpet_border", c.field.carpet_border);

  c.camera_name = r.Text("name", c.camera_name);
  c.fps = r.Number("fps", c.fps);
  r.CheckKeys("render",
              {"supersampling", "blur_sigma_px", "vignetting", "exposure", "noise_sigma", "seed"});
  c.render.supersampling =
      static_cast<int>(r.Integer("render.supersampling", c.render.supersampling));
  c.render.blur_sigma_px = r.Number("render.blur_sigma_px", c.render.blur_sigma_px);
  c.render.vignetting = r.Number("render.vignetting", c.render.vignetting);
  c.render.exposure = r.Number("render.exposure", c.render.exposure);
  c.render.noise_sigma = r.Number("render.noise_sigma", c.render.noise_sigma);
  c.render.seed =
      static_cast<uint64_t>(r.Integer("render.seed", static_cast<long long>(c.render.seed)));
  r.CheckKeys("", {"world", "camera", "robot", "field", "name", "fps", "render"});
  r.ThrowIfProblems();
  const std::string invalid = c.Validate();
  if (!invalid.empty()) r.Problem(invalid);
  r.ThrowIfProblems();
  return c;
}

namespace {

// Validates before the members that need a valid config are built.
SoccerWorldConfig Checked(SoccerWorldConfig config) {
  const std::string invalid = config.Validate();
  if (!invalid.empty()) throw std::invalid_argument("soccer world: " + invalid);
  return config;
}

}  // namespace

SoccerRobotWorld::SoccerRobotWorld(SoccerWorldConfig config, Timing timing)
    : config_(Checked(std::move(config))),
      timing_(timing),
      true_camera_(config_.camera),
      nominal_camera_(WithoutMisalignment(config_.camera)),
      scene_(std::make_shared<vision::render::SoccerFieldScene>(true_camera_, config_.field)),
      renderer_(std::make_unique<vision::render::Renderer>(true_camera_, config_.render)) {}

SoccerRobotWorld::~SoccerRobotWorld() {
  if (!registered_.empty()) hal::UnregisterRenderSource(registered_);
  if (frame_server_) frame_server_->Stop();
}

common::Clock& SoccerRobotWorld::clock() {
  if (timing_ == Timing::kStepped) return sim_time_;
  return common::SteadyClock::Instance();
}

void SoccerRobotWorld::SetRobotPose(double x, double y, double heading) {
  vision::render::SoccerFieldSceneParameters p = config_.field;
  p.robot_x = x;
  p.robot_y = y;
  p.robot_heading = heading;
  auto scene = std::make_shared<vision::render::SoccerFieldScene>(true_camera_, p);  // may throw
  std::lock_guard<std::mutex> lock(mutex_);
  scene_ = std::move(scene);
}

std::shared_ptr<const vision::render::SoccerFieldScene> SoccerRobotWorld::scene() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return scene_;
}

SoccerPixelTruth SoccerRobotWorld::GroundTruth(const Eigen::Vector2d& pixel) const {
  SoccerPixelTruth t;
  Eigen::Vector2d p_G;
  if (true_camera_.BackProjectToGround(pixel, &p_G) != vision::ProjectionStatus::kOk) return t;
  const Eigen::Isometry3d X_FG = scene()->X_FG();
  t.valid = true;
  t.p_G = p_G;
  t.p_F = (X_FG * Eigen::Vector3d(p_G.x(), p_G.y(), 0.0)).head<2>();
  t.distance = p_G.norm();
  return t;
}

double SoccerRobotWorld::GroundTruthDistance(const Eigen::Vector2d& pixel) const {
  const SoccerPixelTruth t = GroundTruth(pixel);
  return t.valid ? t.distance : std::nan("");
}

SoccerGroundTruthMap SoccerRobotWorld::GroundTruthMap() const {
  SoccerGroundTruthMap out;
  vision::ComputeGroundMap(true_camera_, &out.map_G);
  const Eigen::Isometry3d X_FG = scene()->X_FG();
  const size_t n = out.map_G.x_m.size();
  out.x_F.assign(n, std::nan(""));
  out.y_F.assign(n, std::nan(""));
  out.distance.assign(n, std::nan(""));
  for (size_t i = 0; i < n; ++i) {
    if (!out.map_G.valid[i]) continue;
    const Eigen::Vector3d p_F = X_FG * Eigen::Vector3d(out.map_G.x_m[i], out.map_G.y_m[i], 0.0);
    out.x_F[i] = p_F.x();
    out.y_F[i] = p_F.y();
    out.distance[i] = std::hypot(out.map_G.x_m[i], out.map_G.y_m[i]);
  }
  return out;
}

hal::CameraFormat SoccerRobotWorld::camera_format() const {
  hal::CameraFormat f;
  f.width = true_camera_.width();
  f.height = true_camera_.height();
  f.pixel_format = hal::PixelFormat::kMono8;
  f.fps = config_.fps;
  return f;
}

void SoccerRobotWorld::Render(uint64_t frame_id, const vision::ImageView8& out,
                              vision::render::GroundTruth* truth) {
  const std::shared_ptr<const vision::render::SoccerFieldScene> s = scene();
  std::lock_guard<std::mutex> lock(render_mutex_);
  renderer_->Render(*s, frame_id, out, truth);
}

std::string SoccerRobotWorld::RegisterCamera() {
  if (!registered_.empty()) throw std::logic_error("soccer world: camera registered twice");
  hal::RegisterRenderSource(
      config_.camera_name, camera_format(),
      [this](uint64_t frame_id, common::Duration, hal::Image* image) {
        Render(frame_id,
               vision::ImageView8{image->data.data(), image->width, image->height, image->stride});
        return std::error_code{};
      },
      "soccer-world:true-camera");
  registered_ = config_.camera_name;
  return registered_;
}

std::string SoccerRobotWorld::ServeCamera(const hal::FrameServerOptions& options) {
  if (frame_server_) throw std::logic_error("soccer world: camera served twice");
  hal::FrameServerOptions o = options;
  o.fps = config_.fps;
  frame_server_ = hal::FrameServer::Listen(
      hal::RenderFrameSource(
          camera_format(),
          [this](uint64_t frame_id, common::Duration, hal::Image* image) {
            Render(frame_id, vision::ImageView8{image->data.data(), image->width, image->height,
                                                image->stride});
            return std::error_code{};
          },
          "soccer-world:true-camera", clock()),
      o);
  spdlog::info("soccer world: omnidirectional camera served at {}", frame_server_->backend());
  return frame_server_->backend();
}

}  // namespace kinevis::sim
