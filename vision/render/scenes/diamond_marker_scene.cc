#include "vision/render/scenes/diamond_marker_scene.h"

#include <cmath>
#include <sstream>
#include <stdexcept>

#include "common/config_error.h"
#include "vision/render/primitives.h"

namespace kinevis::vision::render {
namespace {

bool InUnit(double x) { return std::isfinite(x) && x >= 0.0 && x <= 1.0; }

}  // namespace

std::string DiamondMarkerSceneParameters::Validate() const {
  common::Problems problems;
  const auto add = [&problems](const char* name, double value, const char* rule) {
    problems.Add(name, value, rule);
  };
  if (!X_CO.matrix().allFinite()) add("X_CO", X_CO.translation().norm(), "must be finite");
  if (!p_O_T.allFinite()) add("p_O_T", p_O_T.norm(), "must be finite");
  if (!(std::isfinite(half_side) && half_side > 0.0 && half_side < 0.05)) {
    add("half_side", half_side, "must be in (0, 0.05) m");
  }
  if (!InUnit(white)) add("white", white, "must be in [0, 1]");
  if (!InUnit(black)) add("black", black, "must be in [0, 1]");
  if (!InUnit(background)) add("background", background, "must be in [0, 1]");
  return problems.Message();
}

DiamondMarkerScene::DiamondMarkerScene(const DiamondMarkerSceneParameters& parameters)
    : parameters_(parameters) {
  std::string message = parameters.Validate();
  if (message.empty()) {
    p_C_T_ = parameters.X_CO * parameters.p_O_T;
    if (!(p_C_T_.z() > parameters.half_side)) {
      std::ostringstream out;
      out << "marker centre z_C = " << p_C_T_.z() << " m (must be in front of the camera, > "
          << parameters.half_side << " m)";
      message = out.str();
    }
  }
  if (!message.empty()) throw std::invalid_argument("DiamondMarkerScene: " + message);
  // The plate faces the camera centre; x_P is x_C made orthogonal to the normal, so the plate's
  // edges run (nearly) along the image axes for any tool position.
  const Eigen::Vector3d z_P = -p_C_T_.normalized();
  const Eigen::Vector3d x_P = (Eigen::Vector3d::UnitX() - z_P.x() * z_P).normalized();
  X_CP_.setIdentity();
  X_CP_.linear().col(0) = x_P;
  X_CP_.linear().col(1) = z_P.cross(x_P);
  X_CP_.linear().col(2) = z_P;
  X_CP_.translation() = p_C_T_;
}

Hit DiamondMarkerScene::Trace(const Ray& ray_C) const {
  Hit hit;
  hit.radiance = parameters_.background;
  hit.object = kDiamondBackground;
  hit.depth = kNoHit;
  const Eigen::Vector3d z_P = X_CP_.linear().col(2);
  const double t = IntersectPlane(ray_C, p_C_T_, z_P);
  if (t == kNoHit) return hit;
  const Eigen::Vector3d d = ray_C.p_C_O + t * ray_C.d_C - p_C_T_;
  const double a = d.dot(X_CP_.linear().col(0));
  const double b = d.dot(X_CP_.linear().col(1));
  const double h = parameters_.half_side;
  if (std::abs(a) > h || std::abs(b) > h) return hit;
  // Quadrants (+, +) and (−, −) white: point-symmetric about T.
  const bool white = (a >= 0.0) == (b >= 0.0);
  hit.radiance = white ? parameters_.white : parameters_.black;
  hit.object = white ? kDiamondMarkerWhite : kDiamondMarkerBlack;
  hit.depth = t;
  return hit;
}

Eigen::Isometry3d DiamondCameraPose(double distance_m) {
  const double s = std::sqrt(0.5);
  const Eigen::Vector3d u_centre(0.0, s, s);  // (φ, γ) = (π/2, π/4)
  Eigen::Isometry3d X_OC = Eigen::Isometry3d::Identity();
  const Eigen::Vector3d z_C = -u_centre;
  const Eigen::Vector3d x_C = Eigen::Vector3d::UnitX();
  X_OC.linear().col(0) = x_C;
  X_OC.linear().col(1) = z_C.cross(x_C);
  X_OC.linear().col(2) = z_C;
  X_OC.translation() = distance_m * u_centre;
  return X_OC.inverse();
}

}  // namespace kinevis::vision::render
