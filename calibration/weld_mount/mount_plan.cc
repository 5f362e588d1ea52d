#include "calibration/weld_mount/mount_plan.h"

#include <Eigen/QR>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "common/units.h"

namespace kinevis::calibration {

std::vector<PlannedTouch> MountTouchPlan(bool sides) {
  std::vector<PlannedTouch> plan = {
      {"top", {-0.7, -0.6, 1}}, {"top", {0.7, -0.6, 1}}, {"top", {0.6, 0.72, 1}},
      {"top", {-0.6, 0.6, 1}},  {"board", {0, 1.8, -1}}, {"board", {1.4, 0, -1}},
  };
  if (sides) {
    const std::vector<PlannedTouch> more = {
        {"+x", {1, -0.48, 0}}, {"+x", {1, 0.48, 0}}, {"-x", {-1, 0, 0}},  {"+y", {-0.6, 1, 0}},
        {"+y", {0.6, 1, 0}},   {"-y", {0, -1, 0}},   {"+x+z", {1, 0, 1}}, {"-x-y+z", {-1, -1, 1}},
    };
    plan.insert(plan.end(), more.begin(), more.end());
  }
  return plan;
}

Eigen::Vector3d TouchApproachNormal(const BlockFeature& feature, const Eigen::Matrix3d& R_0B) {
  Eigen::Vector3d n_B = feature.sign.cast<double>();
  if (n_B.z() < 0.0) n_B.z() = 1.0;
  return R_0B * n_B.normalized();
}

std::vector<Eigen::Vector3d> TouchApproachAxes(const Eigen::Vector3d& n_0, double max_dot) {
  std::vector<Eigen::Vector3d> axes;
  for (int yaw = -40; yaw <= 40; yaw += 5) {
    for (int pitch = -60; pitch <= 60; pitch += 10) {
      const double a = yaw * common::kDeg, b = pitch * common::kDeg;
      const Eigen::Vector3d axis(std::cos(a) * std::cos(b), std::sin(a) * std::cos(b),
                                 -std::sin(b));
      if (axis.dot(n_0) <= max_dot) axes.push_back(axis);
    }
  }
  std::stable_sort(
      axes.begin(), axes.end(),
      [&](const Eigen::Vector3d& a, const Eigen::Vector3d& b) { return a.dot(n_0) < b.dot(n_0); });
  return axes;
}

std::vector<Eigen::Vector2d> MountViewPlan(int count) {
  if (count < 1 || count > kMaxMountViews) {
    throw std::invalid_argument("scanner-mount view plan: views: must be in [1, " +
                                std::to_string(kMaxMountViews) + "], got " + std::to_string(count));
  }
  static const double kViews[kMaxMountViews][2] = {
      {0.0, 0.0},   {0.25, 0.5}, {-0.25, -0.5}, {0.0, 0.9},  {0.0, -0.9},   {-0.25, 0.5},
      {0.25, -0.5}, {0.3, 0.0},  {-0.3, 0.0},   {0.15, 0.3}, {-0.15, -0.3}, {0.0, 0.3}};
  std::vector<Eigen::Vector2d> views;
  for (int v = 0; v < count; ++v) views.emplace_back(kViews[v][0], kViews[v][1]);
  return views;
}

std::vector<double> MountLaserAngles() { return {0.22, 0.25, 0.28}; }

robots::Vector5d AimOpticalAxisAt(
    const std::function<Eigen::Isometry3d(const robots::Vector5d&)>& X_0C,
    const Eigen::Vector3d& p_0, robots::Vector5d q, double tolerance, int max_iterations) {
  const auto miss = [&](const robots::Vector5d& qq) -> Eigen::Vector2d {
    const Eigen::Vector3d p_C = X_0C(qq).inverse() * p_0;
    return {p_C.x() / p_C.z(), p_C.y() / p_C.z()};
  };
  constexpr double kStep = 1e-6;
  for (int it = 0; it < max_iterations; ++it) {
    const Eigen::Vector2d m = miss(q);
    if (m.norm() < tolerance) break;
    Eigen::Matrix2d J;
    for (int j = 0; j < 2; ++j) {
      robots::Vector5d qh = q;
      qh(j) += kStep;
      J.col(j) = (miss(qh) - m) / kStep;
    }
    const Eigen::Vector2d step = J.colPivHouseholderQr().solve(-m);
    q(0) += step(0);
    q(1) += step(1);
  }
  return q;
}

}  // namespace kinevis::calibration
