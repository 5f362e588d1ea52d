#include "vision/camera/unified_camera.h"

#include <Eigen/Dense>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace kinevis::vision {
namespace {

constexpr double kUndistortTolerance = 1e-14;  // normalised image units
constexpr int kUndistortMaxIterations = 100;
constexpr double kUnitNormTolerance = 1e-9;
constexpr double kDegenerateConicRatio = 1e-9;

// Mei's distortion (as cv::omnidir::projectPoints): x_d = D(x_u) and ∂x_d/∂x_u.
void Distort(const std::array<double, 4>& k, const Eigen::Vector2d& xu, Eigen::Vector2d* xd,
             Eigen::Matrix2d* J) {
  const double k1 = k[0], k2 = k[1], p1 = k[2], p2 = k[3];
  const double x = xu.x(), y = xu.y();
  const double r2 = x * x + y * y;
  const double radial = 1.0 + k1 * r2 + k2 * r2 * r2;
  (*xd) << x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
      y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
  if (J != nullptr) {
    const double dradial_dr2 = k1 + 2.0 * k2 * r2;
    // ∂r²/∂x = 2x, ∂r²/∂y = 2y.
    (*J)(0, 0) = radial + 2.0 * x * x * dradial_dr2 + 2.0 * p1 * y + 6.0 * p2 * x;
    (*J)(0, 1) = 2.0 * x * y * dradial_dr2 + 2.0 * p1 * x + 2.0 * p2 * y;
    (*J)(1, 0) = 2.0 * x * y * dradial_dr2 + 2.0 * p1 * x + 2.0 * p2 * y;
    (*J)(1, 1) = radial + 2.0 * y * y * dradial_dr2 + 6.0 * p1 * y + 2.0 * p2 * x;
  }
}

void CheckFinite(double value, const char* name, std::ostringstream& errors) {
  if (!std::isfinite(value)) errors << name << " = " << value << " is not finite; ";
}

}  // namespace

std::string_view ToString(LineConicStatus status) {
  switch (status) {
    case LineConicStatus::kOk:
      return "ok";
    case LineConicStatus::kDistorted:
      return "distortion is non-zero (a line's image is not a conic)";
    case LineConicStatus::kInvalidInput:
      return "invalid input";
    case LineConicStatus::kDegenerate:
      return "degenerate (interpretation plane contains the mirror axis)";
  }
  return "unknown line conic status";
}

UnifiedParameters UnifiedParameters::Default() {
  UnifiedParameters p;
  p.width = 640;
  p.height = 480;
  p.xi = 0.95;
  p.gamma1 = 230.0;
  p.gamma2 = 230.0;
  p.skew = 0.0;
  p.u0 = 319.5;
  p.v0 = 239.5;
  p.distortion = {0.0, 0.0, 0.0, 0.0};
  return p;
}

UnifiedCamera::UnifiedCamera(const UnifiedParameters& parameters) : parameters_(parameters) {
  const std::string problems = Validate();
  if (!problems.empty()) throw std::invalid_argument("unified camera: " + problems);
  K_ << parameters_.gamma1, parameters_.skew, parameters_.u0, 0.0, parameters_.gamma2,
      parameters_.v0, 0.0, 0.0, 1.0;
}

bool UnifiedCamera::HasDistortion() const {
  for (double k : parameters_.distortion) {
    if (k != 0.0) return true;
  }
  return false;
}

std::string UnifiedCamera::Validate() const {
  const UnifiedParameters& p = parameters_;
  std::ostringstream errors;
  if (p.width <= 0) errors << "width = " << p.width << " must be > 0; ";
  if (p.height <= 0) errors << "height = " << p.height << " must be > 0; ";
  if (!(std::isfinite(p.xi) && p.xi >= 0.0)) errors << "xi = " << p.xi << " must be >= 0; ";
  if (!(std::isfinite(p.gamma1) && p.gamma1 > 0.0)) {
    errors << "gamma1 = " << p.gamma1 << " must be > 0; ";
  }
  if (!(std::isfinite(p.gamma2) && p.gamma2 > 0.0)) {
    errors << "gamma2 = " << p.gamma2 << " must be > 0; ";
  }
  CheckFinite(p.skew, "skew", errors);
  CheckFinite(p.u0, "u0", errors);
  CheckFinite(p.v0, "v0", errors);
  static constexpr const char* kDistortionNames[4] = {"k1", "k2", "p1", "p2"};
  for (int i = 0; i < 4; ++i) CheckFinite(p.distortion[i], kDistortionNames[i], errors);
  std::string message = errors.str();
  if (message.size() >= 2) message.resize(message.size() - 2);  // drop the trailing "; "
  return message;
}

ProjectionStatus UnifiedCamera::Project(const Eigen::Vector3d& p_C, Eigen::Vector2d* pixel,
                                        Matrix23d* J_pixel_point) const {
  const double xi = parameters_.xi;
  const double norm = p_C.norm();
  if (!(norm > 0.0) || !std::isfinite(norm)) return ProjectionStatus::kOutsideDomain;
  const double zs = p_C.z() / norm;
  if (xi > 1.0) {
    // The perspective centre (0, 0, -ξ) is outside the sphere: only the cap beyond the tangency
    // circle X_s.z = -1/ξ is seen (Mei's lifting picks that root).
    if (!(zs > -1.0 / xi)) return ProjectionStatus::kOutsideDomain;
  } else if (!(zs + xi > 0.0)) {
    return ProjectionStatus::kBehindCamera;
  }
  // x_u = x / (z + ξ|p|): the same as X_s.x / (X_s.z + ξ), written on p_C for the Jacobian.
  const double den = p_C.z() + xi * norm;
  const Eigen::Vector2d xu(p_C.x() / den, p_C.y() / den);
  Eigen::Vector2d xd;
  Eigen::Matrix2d J_d;
  Distort(parameters_.distortion, xu, &xd, &J_d);
  if (!(J_d.determinant() > 0.0)) return ProjectionStatus::kOutsideDomain;
  const UnifiedParameters& p = parameters_;
  (*pixel) << p.gamma1 * xd.x() + p.skew * xd.y() + p.u0, p.gamma2 * xd.y() + p.v0;
  if (J_pixel_point != nullptr) {
    // ∂den/∂p = e_z + ξ p/|p|;  ∂x_u/∂p = (e_x - x_u ∂den/∂p) / den.
    const Eigen::RowVector3d d_den = Eigen::RowVector3d::UnitZ() + xi * p_C.transpose() / norm;
    Matrix23d J_u;
    J_u.row(0) = (Eigen::RowVector3d::UnitX() - xu.x() * d_den) / den;
    J_u.row(1) = (Eigen::RowVector3d::UnitY() - xu.y() * d_den) / den;
    Eigen::Matrix2d J_k;
    J_k << p.gamma1, p.skew, 0.0, p.gamma2;
    *J_pixel_point = J_k * J_d * J_u;
  }
  return ProjectionStatus::kOk;
}

ProjectionStatus UnifiedCamera::LiftToSphere(const Eigen::Vector2d& pixel, Eigen::Vector3d* X_s,
                                             Matrix32d* J_sphere_pixel) const {
  const UnifiedParameters& p = parameters_;
  if (!pixel.allFinite()) return ProjectionStatus::kOutsideDomain;
  // Inverse of the generalised intrinsics (upper triangular K).
  const double yd = (pixel.y() - p.v0) / p.gamma2;
  const Eigen::Vector2d xd((pixel.x() - p.u0 - p.skew * yd) / p.gamma1, yd);
  Eigen::Matrix2d J_kinv;
  J_kinv << 1.0 / p.gamma1, -p.skew / (p.gamma1 * p.gamma2), 0.0, 1.0 / p.gamma2;

  // Undistort: Newton on D(x_u) = x_d from x_u = x_d. OpenCV's undistortPoints runs 20 fixed-point
  // iterations instead; Newton converges to the same root, to machine precision.
  Eigen::Vector2d xu = xd;
  Eigen::Matrix2d J_d = Eigen::Matrix2d::Identity();
  if (HasDistortion()) {
    bool converged = false;
    for (int iteration = 0; iteration < kUndistortMaxIterations; ++iteration) {
      Eigen::Vector2d x_current;
      Distort(p.distortion, xu, &x_current, &J_d);
      const Eigen::Vector2d residual = x_current - xd;
      const double det = J_d.determinant();
      if (!(det > 0.0)) return ProjectionStatus::kOutsideDomain;
      if (residual.norm() <= kUndistortTolerance * (1.0 + xd.norm())) {
        converged = true;
        break;
      }
      xu -= J_d.inverse() * residual;
      if (!xu.allFinite()) return ProjectionStatus::kNoConvergence;
    }
    if (!converged) return ProjectionStatus::kNoConvergence;
  }

  // Mei's lifting: the ray from the perspective centre (0,0,-ξ) through (x_u, y_u, 1 - ξ) meets
  // the sphere where η (x_u, y_u, 1) - (0, 0, ξ) has unit norm; the larger root is the point
  // imaged (for ξ > 1 the one beyond the tangency circle).
  const double xi = p.xi;
  const double r2 = xu.squaredNorm();
  const double disc = 1.0 + (1.0 - xi * xi) * r2;
  if (!(disc > 0.0)) return ProjectionStatus::kOutsideDomain;  // outside the image of the sphere
  const double root = std::sqrt(disc);
  const double eta = (xi + root) / (1.0 + r2);
  (*X_s) << eta * xu.x(), eta * xu.y(), eta - xi;
  if (J_sphere_pixel != nullptr) {
    const double deta_dr2 =
        ((1.0 - xi * xi) / (2.0 * root) * (1.0 + r2) - (xi + root)) / ((1.0 + r2) * (1.0 + r2));
    const Eigen::RowVector2d deta_dxu = 2.0 * deta_dr2 * xu.transpose();
    Matrix32d J_s_u;
    J_s_u.topRows<2>() = eta * Eigen::Matrix2d::Identity() + xu * deta_dxu;
    J_s_u.row(2) = deta_dxu;
    // x_u = D⁻¹(x_d): ∂x_u/∂x_d = J_d⁻¹ at the solution.
    *J_sphere_pixel = J_s_u * J_d.inverse() * J_kinv;
  }
  return ProjectionStatus::kOk;
}

ProjectionStatus UnifiedCamera::BackProject(const Eigen::Vector2d& pixel, Ray* ray,
                                            RayJacobian* J) const {
  Eigen::Vector3d X_s;
  Matrix32d J_s;
  const ProjectionStatus status = LiftToSphere(pixel, &X_s, J != nullptr ? &J_s : nullptr);
  if (status != ProjectionStatus::kOk) return status;
  ray->p_C_O.setZero();
  ray->d_C = X_s;  // unit by construction (Mei's lifting lands on the sphere)
  if (J != nullptr) {
    J->d_origin_d_pixel.setZero();
    J->d_direction_d_pixel = J_s;
  }
  return ProjectionStatus::kOk;
}

// seed 002, eq. (1), derived again: a point p = (X, Y, Z) of the interpretation plane n·p = 0
// images at x = X/λ, y = Y/λ with λ = Z + ξ|p|. Eliminating Z = -(n_x x + n_y y) λ / n_z and
// |p| = (λ - Z)/ξ gives ξ² (n_z² (x² + y²) + (n_x x + n_y y)²) = (n_x x + n_y y + n_z)², i.e.
// (x, y, 1) Ω_m (x, y, 1)ᵀ = 0 with exactly the seed's matrix (signs of λ ± ξ|p| both square to
// the same conic). Eq. (2): pixel m_p = K m, so Ω_p = K⁻ᵀ Ω_m K⁻¹.
LineConicStatus UnifiedCamera::LineConic(const Eigen::Vector3d& n_C,
                                         Eigen::Matrix3d* Omega_pixel) const {
  if (HasDistortion()) return LineConicStatus::kDistorted;
  if (!n_C.allFinite() || std::abs(n_C.norm() - 1.0) > kUnitNormTolerance) {
    return LineConicStatus::kInvalidInput;
  }
  const double xi2 = parameters_.xi * parameters_.xi;
  const double nx = n_C.x(), ny = n_C.y(), nz = n_C.z();
  Eigen::Matrix3d Omega_m;
  Omega_m << (1.0 - xi2) * nx * nx - nz * nz * xi2, (1.0 - xi2) * nx * ny, nx * nz,
      (1.0 - xi2) * nx * ny, (1.0 - xi2) * ny * ny - nz * nz * xi2, ny * nz,  //
      nx * nz, ny * nz, nz * nz;
  const Eigen::Matrix3d K_inv = K_.inverse();
  *Omega_pixel = K_inv.transpose() * Omega_m * K_inv;
  const double scale = Omega_pixel->norm();
  if (!(scale > 0.0)) return LineConicStatus::kDegenerate;  // ξ = 1 and n_z = 0: Ω_m = 0
  *Omega_pixel /= scale;
  return LineConicStatus::kOk;
}

// seed 002, eq. (10): the third column of Ω_m is n_z (n_x, n_y, n_z) = n_z n, so normalising it
// gives ±n. The printed left superscript "n" of eq. (10) (and (11)) is a misprint for "m" (the
// mirror frame). Departure: the seed leaves the sign open; we return n.z > 0.
LineConicStatus UnifiedCamera::InterpretationNormal(const Eigen::Matrix3d& Omega_pixel,
                                                    Eigen::Vector3d* n_C) const {
  if (HasDistortion()) return LineConicStatus::kDistorted;
  if (!Omega_pixel.allFinite()) return LineConicStatus::kInvalidInput;
  const Eigen::Matrix3d Omega_m = K_.transpose() * Omega_pixel * K_;
  const double scale = Omega_m.norm();
  if (!(scale > 0.0)) return LineConicStatus::kInvalidInput;
  const Eigen::Vector3d omega3 = Omega_m.col(2);
  const double length = omega3.norm();
  if (length < kDegenerateConicRatio * scale) return LineConicStatus::kDegenerate;
  *n_C = omega3 / length;
  if (n_C->z() < 0.0) *n_C = -*n_C;
  return LineConicStatus::kOk;
}

}  // namespace kinevis::vision
