#include "vision/render/scenes/soccer_field_scene.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "vision/render/primitives.h"

namespace kinevis::vision::render {
namespace {

class Problems {
 public:
  void Add(const char* name, double value, const char* rule) {
    out_ << (out_.tellp() > 0 ? "; " : "") << name << " = " << value << " (" << rule << ")";
  }
  std::string str() const { return out_.str(); }

 private:
  std::ostringstream out_;
};

double SegmentDistance(const Eigen::Vector2d& p, const Eigen::Vector4d& s) {
  const Eigen::Vector2d a = s.head<2>(), b = s.tail<2>();
  const Eigen::Vector2d ab = b - a;
  const double t = std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
  return (p - a - t * ab).norm();
}

}  // namespace

std::string SoccerFieldSceneParameters::Validate() const {
  Problems bad;
  auto positive = [&bad](const char* name, double v) {
    if (!(std::isfinite(v) && v > 0.0)) bad.Add(name, v, "must be > 0");
  };
  positive("field_length", field_length);
  positive("field_width", field_width);
  positive("line_width", line_width);
  positive("centre_circle_radius", centre_circle_radius);
  positive("goal_area_depth", goal_area_depth);
  positive("goal_area_width", goal_area_width);
  positive("penalty_area_depth", penalty_area_depth);
  positive("penalty_area_width", penalty_area_width);
  if (!(std::isfinite(carpet_border) && carpet_border >= 0.0)) {
    bad.Add("carpet_border", carpet_border, "must be >= 0");
  }
  if (goal_area_width >= field_width) {
    bad.Add("goal_area_width", goal_area_width, "must be < field_width");
  }
  if (penalty_area_width >= field_width) {
    bad.Add("penalty_area_width", penalty_area_width, "must be < field_width");
  }
  if (2.0 * penalty_area_depth >= field_length) {
    bad.Add("penalty_area_depth", penalty_area_depth, "must be < field_length / 2");
  }
  if (goal_area_depth >= penalty_area_depth) {
    bad.Add("goal_area_depth", goal_area_depth, "must be < penalty_area_depth");
  }
  if (!std::isfinite(robot_x)) bad.Add("robot_x", robot_x, "must be finite");
  if (!std::isfinite(robot_y)) bad.Add("robot_y", robot_y, "must be finite");
  if (!std::isfinite(robot_heading)) bad.Add("robot_heading", robot_heading, "must be finite");
  positive("body_radius", body_radius);
  positive("body_height", body_height);
  positive("lens_radius", lens_radius);
  if (post_count < 0 || post_count > 8) bad.Add("post_count", post_count, "must be in 0..8");
  positive("post_radius", post_radius);
  if (!(std::isfinite(post_ring_radius) && post_ring_radius - post_radius > lens_radius)) {
    bad.Add("post_ring_radius", post_ring_radius,
            "must exceed lens_radius + post_radius (posts outside the lens body)");
  }
  if (!std::isfinite(post_azimuth)) bad.Add("post_azimuth", post_azimuth, "must be finite");
  const double radiances[7] = {line_radiance, carpet_radiance, floor_radiance,       body_radiance,
                               lens_radiance, post_radiance,   surroundings_radiance};
  const char* names[7] = {"line_radiance",        "carpet_radiance", "floor_radiance",
                          "body_radiance",        "lens_radiance",   "post_radiance",
                          "surroundings_radiance"};
  for (int i = 0; i < 7; ++i) {
    if (!(std::isfinite(radiances[i]) && radiances[i] >= 0.0 && radiances[i] <= 1.0)) {
      bad.Add(names[i], radiances[i], "must be in [0, 1]");
    }
  }
  return bad.str();
}

SoccerFieldScene::SoccerFieldScene(const HyperbolicMirrorCamera& camera,
                                   const SoccerFieldSceneParameters& parameters)
    : parameters_(parameters), X_CG_(camera.X_CG()), X_GC_(camera.X_CG().inverse()) {
  std::string message = parameters.Validate();
  pinhole_height_ = (X_GC_ * Eigen::Vector3d::Zero()).z();
  if (message.empty() && !(parameters.body_height < pinhole_height_)) {
    std::ostringstream out;
    out << "body_height = " << parameters.body_height << " (must be below the pinhole, which is "
        << pinhole_height_ << " m above the ground)";
    message = out.str();
  }
  if (!message.empty()) throw std::invalid_argument("SoccerFieldScene: " + message);

  X_FG_ = Eigen::Translation3d(parameters.robot_x, parameters.robot_y, 0.0) *
          Eigen::AngleAxisd(parameters.robot_heading, Eigen::Vector3d::UnitZ());

  // Posts: parallel to y_C (the mirror axis) from the pinhole's height to the mirror surface (or
  // the rim's height when outside the rim). Azimuth ψ from x_G (= z_C untilted) towards y_G
  // (= x_C).
  const HyperbolicMirrorParameters& m = camera.parameters();
  const double rho = std::min(parameters.post_ring_radius, m.mirror_radius);
  const double top_y = std::sqrt(m.mirror_constant + rho * rho) + m.mirror_offset();
  for (int i = 0; i < parameters.post_count; ++i) {
    const double psi = parameters.post_azimuth + 2.0 * M_PI * i / parameters.post_count;
    const double x = m.mirror_axis_x + parameters.post_ring_radius * std::sin(psi);
    const double z = m.mirror_axis_z + parameters.post_ring_radius * std::cos(psi);
    post_bottom_C_[i] = Eigen::Vector3d(x, 0.0, z);
    post_top_C_[i] = Eigen::Vector3d(x, top_y, z);
  }
  // Lens body: along y_C below the pinhole down to the robot body's top.
  lens_bottom_C_ = Eigen::Vector3d(0.0, -(pinhole_height_ - parameters.body_height), 0.0);

  // Field lines (centre-lines) in F.
  const double L = 0.5 * parameters.field_length, W = 0.5 * parameters.field_width;
  int k = 0;
  auto add = [this, &k](double x0, double y0, double x1, double y1) {
    segments_F_[k++] = Eigen::Vector4d(x0, y0, x1, y1);
  };
  add(-L, -W, L, -W);
  add(-L, W, L, W);
  add(-L, -W, -L, W);
  add(L, -W, L, W);
  add(0.0, -W, 0.0, W);
  for (double side : {-1.0, 1.0}) {
    for (const auto& [depth, half_width] :
         {std::pair<double, double>{parameters.goal_area_depth, 0.5 * parameters.goal_area_width},
          {parameters.penalty_area_depth, 0.5 * parameters.penalty_area_width}}) {
      const double x_front = side * (L - depth);
      add(x_front, -half_width, x_front, half_width);
      add(x_front, -half_width, side * L, -half_width);
      add(x_front, half_width, side * L, half_width);
    }
  }
}

void SoccerFieldScene::PostAxis(int i, Eigen::Vector3d* bottom_C, Eigen::Vector3d* top_C) const {
  *bottom_C = post_bottom_C_.at(i);
  *top_C = post_top_C_.at(i);
}

double SoccerFieldScene::LineDistance(const Eigen::Vector2d& p_F) const {
  double d = std::abs(p_F.norm() - parameters_.centre_circle_radius);
  for (const Eigen::Vector4d& s : segments_F_) d = std::min(d, SegmentDistance(p_F, s));
  return d;
}

FieldPoint SoccerFieldScene::ClassifyGround(const Eigen::Vector2d& p_G_xy) const {
  FieldPoint out;
  out.p_F = (X_FG_ * Eigen::Vector3d(p_G_xy.x(), p_G_xy.y(), 0.0)).head<2>();
  out.line_distance = LineDistance(out.p_F);
  out.on_line = out.line_distance <= 0.5 * parameters_.line_width;
  out.on_carpet =
      std::abs(out.p_F.x()) <= 0.5 * parameters_.field_length + parameters_.carpet_border &&
      std::abs(out.p_F.y()) <= 0.5 * parameters_.field_width + parameters_.carpet_border;
  return out;
}

Hit SoccerFieldScene::Trace(const Ray& ray_C) const {
  const SoccerFieldSceneParameters& p = parameters_;
  Hit hit;
  hit.radiance = kBackgroundRadiance;
  hit.object = kFieldBackground;
  hit.depth = kNoHit;
  // 1. The path pinhole → mirror point, against the posts.
  const double to_mirror = ray_C.p_C_O.norm();
  if (to_mirror > 0.0) {
    Ray incoming;
    incoming.p_C_O = Eigen::Vector3d::Zero();
    incoming.d_C = ray_C.p_C_O / to_mirror;
    for (int i = 0; i < p.post_count; ++i) {
      if (IntersectCylinder(incoming, post_bottom_C_[i], post_top_C_[i], p.post_radius) <
          to_mirror) {
        hit.radiance = p.post_radiance;
        hit.object = kFieldMirrorPost;
        hit.depth = 0.0;
        return hit;
      }
    }
  }
  // 2. The reflected ray: nearest of posts, lens body, robot body, ground.
  double best = kNoHit;
  int object = kFieldSurroundings;
  auto consider = [&best, &object](double t, int id) {
    if (t < best) {
      best = t;
      object = id;
    }
  };
  for (int i = 0; i < p.post_count; ++i) {
    consider(IntersectCylinder(ray_C, post_bottom_C_[i], post_top_C_[i], p.post_radius),
             kFieldMirrorPost);
  }
  consider(IntersectCylinder(ray_C, lens_bottom_C_, Eigen::Vector3d::Zero(), p.lens_radius),
           kFieldLensBody);
  consider(IntersectDisc(ray_C, Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitY(), p.lens_radius),
           kFieldLensBody);
  const Eigen::Vector3d z_G_in_C = X_CG_.linear().col(2);
  const Eigen::Vector3d body_bottom = X_CG_.translation();
  const Eigen::Vector3d body_top = X_CG_ * Eigen::Vector3d(0.0, 0.0, p.body_height);
  consider(IntersectCylinder(ray_C, body_bottom, body_top, p.body_radius), kFieldRobotBody);
  consider(IntersectDisc(ray_C, body_top, z_G_in_C, p.body_radius), kFieldRobotBody);
  const double t_ground = IntersectPlane(ray_C, body_bottom, z_G_in_C);
  const bool ground_nearest = t_ground < best;
  consider(t_ground, kFieldCarpet);
  hit.depth = best;
  switch (object) {
    case kFieldMirrorPost:
      hit.radiance = p.post_radiance;
      break;
    case kFieldLensBody:
      hit.radiance = p.lens_radiance;
      break;
    case kFieldRobotBody:
      hit.radiance = p.body_radiance;
      break;
    case kFieldSurroundings:
      hit.radiance = p.surroundings_radiance;
      break;
    default:
      break;
  }
  if (ground_nearest) {
    const Eigen::Vector3d p_G = X_GC_ * (ray_C.p_C_O + t_ground * ray_C.d_C);
    const FieldPoint field = ClassifyGround(p_G.head<2>());
    if (!field.on_carpet) {
      object = kFieldFloor;
      hit.radiance = p.floor_radiance;
    } else if (field.on_line) {
      object = kFieldLine;
      hit.radiance = p.line_radiance;
    } else {
      object = kFieldCarpet;
      hit.radiance = p.carpet_radiance;
    }
  }
  hit.object = object;
  return hit;
}

}  // namespace kinevis::vision::render
