#include "vision/diamond/spherical_positioning.h"

#include <limits>
#include <sstream>
#include <stdexcept>

#include "common/so3.h"

namespace kinevis::vision {
namespace {

std::string CheckSetUp(const Eigen::Isometry3d& X_OC, double radius,
                       const SphericalPositioningOptions& options) {
  std::ostringstream out;
  if (!std::isfinite(radius) || !(radius > 0.0)) out << "radius = " << radius << " m (need > 0); ";
  const Eigen::Matrix3d R = X_OC.linear();
  if (!R.allFinite() || !X_OC.translation().allFinite()) {
    out << "X_OC is not finite; ";
  } else if ((R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() > 1e-9 ||
             R.determinant() < 0.0) {
    out << "X_OC's linear part is not a rotation (|R^T R - I| = "
        << (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff()
        << ", det = " << R.determinant() << "); ";
  }
  const std::string o = options.Validate();
  if (!o.empty()) out << o << "; ";
  std::string s = out.str();
  if (!s.empty()) s.resize(s.size() - 2);
  return s;
}

}  // namespace

const char* ToString(SphereFixStatus status) {
  switch (status) {
    case SphereFixStatus::kOk:
      return "ok";
    case SphereFixStatus::kBackProjectionFailed:
      return "back-projection failed";
    case SphereFixStatus::kCameraInsideSphere:
      return "camera inside sphere";
    case SphereFixStatus::kMiss:
      return "miss";
    case SphereFixStatus::kGrazing:
      return "grazing";
    case SphereFixStatus::kOnBaseAxis:
      return "on base axis";
  }
  return "?";
}

std::string SphericalPositioningOptions::Validate() const {
  if (!(min_incidence_cosine >= 0.0 && min_incidence_cosine < 1.0)) {
    std::ostringstream out;
    out << "min_incidence_cosine = " << min_incidence_cosine << " (need [0, 1))";
    return out.str();
  }
  return "";
}

SphereFix LocateOnSphere(const CameraModel& camera, const Eigen::Isometry3d& X_OC, double radius,
                         const Eigen::Vector2d& pixel, const SphericalPositioningOptions& options) {
  if (const std::string bad = CheckSetUp(X_OC, radius, options); !bad.empty()) {
    throw std::invalid_argument("LocateOnSphere: " + bad);
  }
  SphereFix fix;
  Ray ray;
  RayJacobian J_ray;
  fix.projection = camera.BackProject(pixel, &ray, &J_ray);
  if (fix.projection != ProjectionStatus::kOk) {
    fix.status = SphereFixStatus::kBackProjectionFailed;
    return fix;
  }
  const Eigen::Matrix3d R_OC = X_OC.linear();
  const Eigen::Vector3d o = X_OC * ray.p_C_O;
  const Eigen::Vector3d d = R_OC * ray.d_C;
  Eigen::Vector3d p;
  double incidence = 0.0;
  const RaySphereHit hit = IntersectRaySphere<double>(o, d, radius, &p, &incidence);
  if (hit == RaySphereHit::kOriginInside) {
    fix.status = SphereFixStatus::kCameraInsideSphere;
    return fix;
  }
  if (hit == RaySphereHit::kMiss) {
    fix.status = SphereFixStatus::kMiss;
    return fix;
  }
  fix.p_O = p;
  fix.range = (p - o).norm();
  fix.incidence_cosine = incidence;
  fix.task = TaskFromPoint<double>(p);

  // dp = P (do + t dd) + d R dR / (p·d), P = I − d pᵀ/(p·d); p·d = −R cos ι < 0 at the near hit.
  const double pd = p.dot(d);
  const double t = fix.range;
  const Eigen::Matrix3d P = Eigen::Matrix3d::Identity() - d * p.transpose() / pd;
  const Eigen::Vector3d dp_dR = d * radius / pd;
  // Pixel: do = R_OC ∂o_C/∂px, dd = R_OC ∂d_C/∂px.
  fix.J_point_pixel = P * (R_OC * J_ray.d_origin_d_pixel + t * (R_OC * J_ray.d_direction_d_pixel));
  // Pose, right perturbation (ω, v) in C: do = R_OC(−[o_C]× ω + v), dd = −R_OC [d_C]× ω.
  Eigen::Matrix<double, 3, 6> J_point_pose;
  J_point_pose.leftCols<3>() =
      P * (R_OC * (-common::Skew(ray.p_C_O)) + t * (R_OC * (-common::Skew(ray.d_C))));
  J_point_pose.rightCols<3>() = P * R_OC;

  const double rho2 = p.x() * p.x() + p.y() * p.y();
  const double rho = std::sqrt(rho2);
  Eigen::Matrix<double, 2, 3> J_task_point;
  J_task_point.row(0) << -p.y() / rho2, p.x() / rho2, 0.0;
  const double r2 = p.squaredNorm();
  J_task_point.row(1) << p.z() * p.x() / (rho * r2), p.z() * p.y() / (rho * r2), -rho / r2;
  fix.J_task_pixel = J_task_point * fix.J_point_pixel;
  fix.J_task_pose = J_task_point * J_point_pose;
  fix.J_task_radius = J_task_point * dp_dR;

  if (rho <= 1e-9 * radius) {
    fix.status = SphereFixStatus::kOnBaseAxis;
  } else if (incidence < options.min_incidence_cosine) {
    fix.status = SphereFixStatus::kGrazing;
  } else {
    fix.status = SphereFixStatus::kOk;
  }
  return fix;
}

double SeedCentralAngle(double tan_ray_angle, double camera_distance, double radius) {
  const double a = std::atan(tan_ray_angle);
  const double s = camera_distance / radius * std::sin(a);
  if (!(std::abs(s) <= 1.0)) return std::numeric_limits<double>::quiet_NaN();
  return std::asin(s) - a;
}

Eigen::Vector2d SeedSphericalPositioning(const Eigen::Vector2d& pixel, double fx, double fy,
                                         double cx, double cy, double camera_distance,
                                         double radius) {
  const double delta_u = SeedCentralAngle((pixel.x() - cx) / fx, camera_distance, radius);
  const double delta_v = SeedCentralAngle((pixel.y() - cy) / fy, camera_distance, radius);
  return {M_PI / 2 - delta_u, M_PI / 4 - delta_v};
}

}  // namespace kinevis::vision
