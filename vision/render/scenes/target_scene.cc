#include "vision/render/scenes/target_scene.h"

#include <cmath>
#include <sstream>
#include <stdexcept>

#include "common/config_error.h"
#include "vision/render/primitives.h"

namespace kinevis::vision::render {
namespace {

bool InUnitRange(double x) { return std::isfinite(x) && x >= 0.0 && x <= 1.0; }
bool Positive(double x) { return std::isfinite(x) && x > 0.0; }

}  // namespace

std::string TargetSpec::Validate() const {
  common::Problems problems;
  const auto add = [&problems](const char* field, double value, const char* why) {
    problems.Add(field, value, why);
  };
  const bool chess = pattern == TargetPattern::kChessboard;
  const int min_count = chess ? 3 : 2;
  if (cols < min_count) add("cols", cols, chess ? "must be >= 3" : "must be >= 2");
  if (rows < min_count) add("rows", rows, chess ? "must be >= 3" : "must be >= 2");
  if (chess) {
    if (!Positive(square)) add("square", square, "must be finite and > 0");
    if (!Positive(border)) add("border", border, "must be finite and > 0");
  } else {
    if (!Positive(pitch)) add("pitch", pitch, "must be finite and > 0");
    if (!Positive(dot_diameter) || (Positive(pitch) && dot_diameter >= pitch))
      add("dot_diameter", dot_diameter, "must be finite, > 0 and < pitch");
    if (!Positive(border) || (Positive(dot_diameter) && border <= 0.5 * dot_diameter))
      add("border", border, "must be finite and > dot_diameter / 2");
  }
  if (!InUnitRange(white_radiance)) add("white_radiance", white_radiance, "must be in [0, 1]");
  if (!InUnitRange(black_radiance)) add("black_radiance", black_radiance, "must be in [0, 1]");
  if (!InUnitRange(background_radiance))
    add("background_radiance", background_radiance, "must be in [0, 1]");
  const std::string message = problems.Message();
  return message.empty() ? message : "invalid target: " + message;
}

std::vector<Eigen::Vector3d> TargetSpec::FeaturePoints() const {
  const double step = pattern == TargetPattern::kChessboard ? square : pitch;
  std::vector<Eigen::Vector3d> points;
  points.reserve(static_cast<size_t>(feature_cols()) * feature_rows());
  for (int j = 0; j < feature_rows(); ++j) {
    for (int i = 0; i < feature_cols(); ++i) points.emplace_back(i * step, j * step, 0.0);
  }
  return points;
}

TargetScene::TargetScene(const TargetSpec& spec, const Eigen::Isometry3d& X_CT)
    : spec_(spec), X_CT_(X_CT) {
  std::string message = spec_.Validate();
  if (!X_CT.matrix().allFinite())
    message += (message.empty() ? "" : "; ") + std::string("X_CT is not finite");
  if (!message.empty()) throw std::invalid_argument("target scene: " + message);
  R_TC_ = X_CT.linear().transpose();
  p_CT_ = X_CT.translation();
  normal_C_ = X_CT.linear().col(2);
  if (spec_.pattern == TargetPattern::kChessboard) {
    x_min_ = -spec_.square - spec_.border;
    y_min_ = -spec_.square - spec_.border;
    x_max_ = (spec_.cols - 1) * spec_.square + spec_.border;
    y_max_ = (spec_.rows - 1) * spec_.square + spec_.border;
  } else {
    x_min_ = -spec_.border;
    y_min_ = -spec_.border;
    x_max_ = (spec_.cols - 1) * spec_.pitch + spec_.border;
    y_max_ = (spec_.rows - 1) * spec_.pitch + spec_.border;
  }
}

Hit TargetScene::Trace(const Ray& ray_C) const {
  const double t = IntersectPlane(ray_C, p_CT_, normal_C_);
  if (t == kNoHit) return Hit{spec_.background_radiance, 0, kNoHit};
  const Eigen::Vector3d r_C = ray_C.p_C_O + t * ray_C.d_C - p_CT_;
  const double x = R_TC_.row(0).dot(r_C), y = R_TC_.row(1).dot(r_C);
  if (x < x_min_ || x > x_max_ || y < y_min_ || y > y_max_) {
    return Hit{spec_.background_radiance, 0, kNoHit};
  }
  bool black = false;
  if (spec_.pattern == TargetPattern::kChessboard) {
    const double s = spec_.square;
    if (x >= -s && x < (spec_.cols - 1) * s && y >= -s && y < (spec_.rows - 1) * s) {
      const long c = static_cast<long>(std::floor(x / s)) + 1;
      const long r = static_cast<long>(std::floor(y / s)) + 1;
      black = ((c + r) & 1) == 0;
    }
  } else {
    const double p = spec_.pitch;
    const long i = std::lround(x / p), j = std::lround(y / p);
    if (i >= 0 && i < spec_.cols && j >= 0 && j < spec_.rows) {
      const double dx = x - i * p, dy = y - j * p;
      const double r = 0.5 * spec_.dot_diameter;
      black = dx * dx + dy * dy <= r * r;
    }
  }
  return black ? Hit{spec_.black_radiance, kTargetBlackId, t}
               : Hit{spec_.white_radiance, kTargetWhiteId, t};
}

int TargetScene::ProjectFeatures(const CameraModel& camera, std::vector<Eigen::Vector2d>* pixels,
                                 std::vector<ProjectionStatus>* status) const {
  const std::vector<Eigen::Vector3d> points = spec_.FeaturePoints();
  pixels->assign(points.size(), Eigen::Vector2d::Zero());
  status->assign(points.size(), ProjectionStatus::kOk);
  int visible = 0;
  for (size_t k = 0; k < points.size(); ++k) {
    (*status)[k] = camera.Project(X_CT_ * points[k], &(*pixels)[k]);
    if ((*status)[k] == ProjectionStatus::kOk && camera.InImage((*pixels)[k])) ++visible;
  }
  return visible;
}

}  // namespace kinevis::vision::render
