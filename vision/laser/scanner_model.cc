#include "vision/laser/scanner_model.h"

#include <cmath>
#include <sstream>
#include <stdexcept>

#include "common/config_error.h"

namespace kinevis::vision::laser {
namespace {

// Below this |cot θ + a| (normalised coordinate units, ~1e-9 px) a ray is taken as parallel to
// the plane.
constexpr double kParallel = 1e-12;

}  // namespace

Eigen::Vector4d ScannerGeometry::RotatingPlane(double cot_theta_y) const {
  return Eigen::Vector4d(0.0, 1.0, cot_theta_y, RotatingBPrime(cot_theta_y));
}

Eigen::Vector4d ScannerGeometry::FixedPlane() const {
  return Eigen::Vector4d(1.0, 0.0, fixed_cot_theta_x, fixed_b_x_prime);
}

std::string ScannerGeometry::Validate() const {
  common::Problems problems;
  const auto add = [&problems](const char* name, double value, const char* rule) {
    problems.Add(name, value, rule);
  };
  if (!std::isfinite(rotating_b_y)) add("rotating_b_y", rotating_b_y, "must be finite (m)");
  if (!std::isfinite(rotating_d_y)) add("rotating_d_y", rotating_d_y, "must be finite (m)");
  if (!(std::isfinite(fixed_b_x_prime) && std::abs(fixed_b_x_prime) >= 1e-5)) {
    add("fixed_b_x_prime", fixed_b_x_prime, "must be finite with |.| >= 1e-5 m");
  }
  if (!std::isfinite(fixed_cot_theta_x))
    add("fixed_cot_theta_x", fixed_cot_theta_x, "must be finite");
  return problems.Message();
}

ScannerGeometry FromSceneGeometry(const render::LaserScannerGeometry& scene) {
  ScannerGeometry g;
  g.rotating_b_y = scene.rotating_b_y;
  g.rotating_d_y = scene.rotating_d_y;
  g.fixed_b_x_prime = scene.fixed_b_x_prime;
  g.fixed_cot_theta_x = scene.fixed_cot_theta_x;
  return g;
}

render::LaserScannerGeometry ToSceneGeometry(const ScannerGeometry& geometry) {
  render::LaserScannerGeometry scene;
  scene.rotating_b_y = geometry.rotating_b_y;
  scene.rotating_d_y = geometry.rotating_d_y;
  scene.fixed_b_x_prime = geometry.fixed_b_x_prime;
  scene.fixed_cot_theta_x = geometry.fixed_cot_theta_x;
  return scene;
}

std::string_view ToString(TriangulationStatus status) {
  switch (status) {
    case TriangulationStatus::kOk:
      return "ok";
    case TriangulationStatus::kCameraFailed:
      return "camera failed";
    case TriangulationStatus::kParallelToPlane:
      return "ray parallel to the laser plane";
    case TriangulationStatus::kBehindCamera:
      return "behind the camera";
    case TriangulationStatus::kDegenerate:
      return "degenerate";
  }
  return "unknown";
}

ScannerModel::ScannerModel(const CameraModel& camera, const ScannerGeometry& geometry)
    : camera_(camera), geometry_(geometry) {
  std::string message = geometry.Validate();
  if (!camera.IsCentral()) {
    message += std::string(message.empty() ? "" : "; ") + "camera " + std::string(camera.Name()) +
               " is not central (the scanner equations need one viewpoint)";
  } else {
    Ray ray;
    const Eigen::Vector2d centre(0.5 * (camera.width() - 1), 0.5 * (camera.height() - 1));
    if (camera.BackProject(centre, &ray) != ProjectionStatus::kOk) {
      message += std::string(message.empty() ? "" : "; ") + "camera " + std::string(camera.Name()) +
                 " cannot back-project the image centre";
    } else if (ray.p_C_O.norm() > 1e-12) {
      message += std::string(message.empty() ? "" : "; ") + "camera " + std::string(camera.Name()) +
                 "'s viewpoint is not at C's origin";
    }
  }
  if (!message.empty()) throw std::invalid_argument("ScannerModel: " + message);
}

TriangulationStatus ScannerModel::Normalized(const Eigen::Vector2d& pixel, Eigen::Vector2d* ab,
                                             Eigen::Matrix2d* J) const {
  Ray ray;
  RayJacobian ray_J;
  if (camera_.BackProject(pixel, &ray, J != nullptr ? &ray_J : nullptr) != ProjectionStatus::kOk) {
    return TriangulationStatus::kCameraFailed;
  }
  const Eigen::Vector3d& d = ray.d_C;
  if (!(d.z() > 0.0)) return TriangulationStatus::kBehindCamera;
  const double inverse_z = 1.0 / d.z();
  *ab = Eigen::Vector2d(d.x() * inverse_z, d.y() * inverse_z);
  if (J != nullptr) {
    // a = d_x / d_z, b = d_y / d_z.
    Eigen::Matrix<double, 2, 3> J_ab_d;
    J_ab_d << inverse_z, 0.0, -ab->x() * inverse_z, 0.0, inverse_z, -ab->y() * inverse_z;
    *J = J_ab_d * ray_J.d_direction_d_pixel;
  }
  return TriangulationStatus::kOk;
}

TriangulationStatus ScannerModel::TriangulateRotating(const Eigen::Vector2d& pixel,
                                                      double cot_theta_y, Eigen::Vector3d* p_C,
                                                      TriangulationJacobian* J) const {
  Eigen::Vector2d ab;
  Eigen::Matrix2d J_ab;
  const TriangulationStatus status = Normalized(pixel, &ab, J != nullptr ? &J_ab : nullptr);
  if (status != TriangulationStatus::kOk) return status;
  // Eq. 9 over f: p = b_y' / (cot θ_y + b) (a, b, 1).
  const double s = cot_theta_y + ab.y();
  if (std::abs(s) < kParallel) return TriangulationStatus::kParallelToPlane;
  const double b_prime = geometry_.RotatingBPrime(cot_theta_y);
  const double k = b_prime / s;
  if (!(k > 0.0)) return TriangulationStatus::kBehindCamera;
  const Eigen::Vector3d m(ab.x(), ab.y(), 1.0);
  *p_C = k * m;
  if (J != nullptr) {
    Matrix32d J_p_ab;
    J_p_ab.col(0) = Eigen::Vector3d(k, 0.0, 0.0);
    J_p_ab.col(1) = Eigen::Vector3d(0.0, k, 0.0) - (k / s) * m;
    J->d_point_d_pixel = J_p_ab * J_ab;
    J->d_point_d_parameters.setZero();
    J->d_point_d_parameters.col(kRotatingBy) = m / s;
    J->d_point_d_parameters.col(kRotatingDy) = (cot_theta_y / s) * m;
    J->d_point_d_parameters.col(kRotatingCotThetaY) =
        (geometry_.rotating_d_y / s - b_prime / (s * s)) * m;
  }
  return TriangulationStatus::kOk;
}

TriangulationStatus ScannerModel::TriangulateFixed(const Eigen::Vector2d& pixel,
                                                   Eigen::Vector3d* p_C,
                                                   TriangulationJacobian* J) const {
  Eigen::Vector2d ab;
  Eigen::Matrix2d J_ab;
  const TriangulationStatus status = Normalized(pixel, &ab, J != nullptr ? &J_ab : nullptr);
  if (status != TriangulationStatus::kOk) return status;
  // Eq. 10 over f: p = b_x' / (cot θ_x + a) (a, b, 1).
  const double s = geometry_.fixed_cot_theta_x + ab.x();
  if (std::abs(s) < kParallel) return TriangulationStatus::kParallelToPlane;
  const double k = geometry_.fixed_b_x_prime / s;
  if (!(k > 0.0)) return TriangulationStatus::kBehindCamera;
  const Eigen::Vector3d m(ab.x(), ab.y(), 1.0);
  *p_C = k * m;
  if (J != nullptr) {
    Matrix32d J_p_ab;
    J_p_ab.col(0) = Eigen::Vector3d(k, 0.0, 0.0) - (k / s) * m;
    J_p_ab.col(1) = Eigen::Vector3d(0.0, k, 0.0);
    J->d_point_d_pixel = J_p_ab * J_ab;
    J->d_point_d_parameters.setZero();
    J->d_point_d_parameters.col(kFixedBxPrime) = m / s;
    J->d_point_d_parameters.col(kFixedCotThetaX) = (-k / s) * m;
  }
  return TriangulationStatus::kOk;
}

TriangulationStatus ScannerModel::CotThetaYFromIntersection(const Eigen::Vector2d& pixel,
                                                            double* cot_theta_y,
                                                            Eigen::RowVector2d* J_pixel,
                                                            RowVector5d* J_parameters) const {
  Eigen::Vector2d ab;
  Eigen::Matrix2d J_ab;
  const bool want_J = J_pixel != nullptr || J_parameters != nullptr;
  const TriangulationStatus status = Normalized(pixel, &ab, want_J ? &J_ab : nullptr);
  if (status != TriangulationStatus::kOk) return status;
  const ScannerGeometry& g = geometry_;
  // q = 1 / z of the intersection on the fixed plane (eq. 10: z = b_x' / (cot θ_x + a)).
  const double q = (g.fixed_cot_theta_x + ab.x()) / g.fixed_b_x_prime;
  if (!(q > 0.0)) return TriangulationStatus::kBehindCamera;
  // Eq. 11: y + cot θ_y z = b_y + d_y cot θ_y with y = b z, divided by z and solved for cot θ_y.
  const double numerator = g.rotating_b_y * q - ab.y();
  const double denominator = 1.0 - g.rotating_d_y * q;
  if (std::abs(denominator) < 1e-12) return TriangulationStatus::kDegenerate;
  const double c = numerator / denominator;
  *cot_theta_y = c;
  if (want_J) {
    const double dc_dq =
        (g.rotating_b_y * denominator + g.rotating_d_y * numerator) / (denominator * denominator);
    const double dc_db = -1.0 / denominator;
    const double dq_da = 1.0 / g.fixed_b_x_prime;
    if (J_pixel != nullptr) {
      *J_pixel = Eigen::RowVector2d(dc_dq * dq_da, dc_db) * J_ab;
    }
    if (J_parameters != nullptr) {
      J_parameters->setZero();
      (*J_parameters)(kRotatingBy) = q / denominator;
      (*J_parameters)(kRotatingDy) = numerator * q / (denominator * denominator);
      (*J_parameters)(kFixedBxPrime) = dc_dq * (-q / g.fixed_b_x_prime);
      (*J_parameters)(kFixedCotThetaX) = dc_dq * dq_da;
    }
  }
  return TriangulationStatus::kOk;
}

}  // namespace kinevis::vision::laser
