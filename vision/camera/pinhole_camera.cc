#include "vision/camera/pinhole_camera.h"

#include <Eigen/LU>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace kinevis::vision {
namespace {

// The domain search looks this far off axis: tan(87°). A Brown polynomial is not a lens model
// beyond it (fisheye lenses need another model), so "no fold before 87°" counts as unlimited.
constexpr double kDomainSearchRadius = 19.081136687728211;
constexpr double kDomainSearchStep = 1e-3;

// Newton undistortion: stop once the residual is at rounding level, accept at kAcceptResidual.
constexpr int kMaxNewtonIterations = 50;
constexpr int kMaxStepHalvings = 60;
constexpr double kStopResidual = 1e-15;
constexpr double kAcceptResidual = 1e-12;

struct Radial {
  double value;        // radial(s) = N(s) / D(s), s = r²
  double derivative;   // d radial / ds
  double denominator;  // D(s)
};

// OpenCV's order k1 k2 p1 p2 k3 k4 k5 k6.
Radial EvaluateRadial(const std::array<double, 8>& k, double s) {
  const double n = 1.0 + s * (k[0] + s * (k[1] + s * k[4]));
  const double dn = k[0] + s * (2.0 * k[1] + s * 3.0 * k[4]);
  const double d = 1.0 + s * (k[5] + s * (k[6] + s * k[7]));
  const double dd = k[5] + s * (2.0 * k[6] + s * 3.0 * k[7]);
  return {n / d, (dn * d - n * dd) / (d * d), d};
}

// The distortion map (x', y') -> (x'', y'') and its Jacobian (symmetric: both off-diagonal
// terms are 2x'y' radial' + 2 p1 x' + 2 p2 y').
Eigen::Vector2d Distort(const std::array<double, 8>& k, const Eigen::Vector2d& x,
                        Eigen::Matrix2d* J) {
  const double xx = x.x();
  const double yy = x.y();
  const double s = xx * xx + yy * yy;
  const Radial radial = EvaluateRadial(k, s);
  const double p1 = k[2];
  const double p2 = k[3];
  Eigen::Vector2d x_d(xx * radial.value + 2.0 * p1 * xx * yy + p2 * (s + 2.0 * xx * xx),
                      yy * radial.value + p1 * (s + 2.0 * yy * yy) + 2.0 * p2 * xx * yy);
  if (J != nullptr) {
    const double off = 2.0 * xx * yy * radial.derivative + 2.0 * p1 * xx + 2.0 * p2 * yy;
    (*J)(0, 0) = radial.value + 2.0 * xx * xx * radial.derivative + 2.0 * p1 * yy + 6.0 * p2 * xx;
    (*J)(0, 1) = off;
    (*J)(1, 0) = off;
    (*J)(1, 1) = radial.value + 2.0 * yy * yy * radial.derivative + 6.0 * p1 * yy + 2.0 * p2 * xx;
  }
  return x_d;
}

// d/dr (r radial(r²)) = radial + 2 s radial'(s) > 0 and a positive denominator: the radial map is
// still increasing at r.
bool RadialMapIncreasing(const std::array<double, 8>& k, double r) {
  const double s = r * r;
  const Radial radial = EvaluateRadial(k, s);
  return radial.denominator > 0.0 && radial.value + 2.0 * s * radial.derivative > 0.0;
}

// Smallest r > 0 where the radial map stops increasing, by a scan and bisection; +inf if none
// within kDomainSearchRadius. The value returned is on the increasing side of the fold.
double FindMaxRadius(const std::array<double, 8>& k) {
  const int steps = static_cast<int>(kDomainSearchRadius / kDomainSearchStep);
  double good = 0.0;
  for (int step = 1; step <= steps; ++step) {
    const double r = step * kDomainSearchStep;
    if (!RadialMapIncreasing(k, r)) {
      double bad = r;
      for (int i = 0; i < 200 && bad - good > 0.0; ++i) {
        const double mid = 0.5 * (good + bad);
        if (mid <= good || mid >= bad) break;
        (RadialMapIncreasing(k, mid) ? good : bad) = mid;
      }
      return good;
    }
    good = r;
  }
  return std::numeric_limits<double>::infinity();
}

}  // namespace

PinholeBrownCamera::PinholeBrownCamera(const PinholeBrownParameters& parameters)
    : parameters_(parameters) {
  const std::string errors = Validate();
  if (!errors.empty()) throw std::invalid_argument("pinhole-brown camera: " + errors);
  max_radius_ = FindMaxRadius(parameters_.distortion);
  max_radius2_ = max_radius_ * max_radius_;
}

std::string PinholeBrownCamera::Validate() const {
  static constexpr const char* kCoefficientNames[8] = {"k1", "k2", "p1", "p2",
                                                       "k3", "k4", "k5", "k6"};
  const PinholeBrownParameters& p = parameters_;
  std::ostringstream errors;
  errors.precision(12);
  if (p.width <= 0) errors << "width = " << p.width << " must be > 0; ";
  if (p.height <= 0) errors << "height = " << p.height << " must be > 0; ";
  if (!std::isfinite(p.fx) || p.fx <= 0.0) errors << "fx = " << p.fx << " must be finite and > 0; ";
  if (!std::isfinite(p.fy) || p.fy <= 0.0) errors << "fy = " << p.fy << " must be finite and > 0; ";
  if (!std::isfinite(p.cx)) errors << "cx = " << p.cx << " is not finite; ";
  if (!std::isfinite(p.cy)) errors << "cy = " << p.cy << " is not finite; ";
  for (int i = 0; i < 8; ++i) {
    if (!std::isfinite(p.distortion[i])) {
      errors << "distortion[" << i << "] (" << kCoefficientNames[i] << ") = " << p.distortion[i]
             << " is not finite; ";
    }
  }
  std::string message = errors.str();
  if (message.size() >= 2) message.resize(message.size() - 2);  // drop the trailing "; "
  return message;
}

ProjectionStatus PinholeBrownCamera::Project(const Eigen::Vector3d& p_C, Eigen::Vector2d* pixel,
                                             Matrix23d* J_pixel_point) const {
  if (!(p_C.z() > 0.0)) return ProjectionStatus::kBehindCamera;
  const double inv_z = 1.0 / p_C.z();
  const Eigen::Vector2d x(p_C.x() * inv_z, p_C.y() * inv_z);
  if (!(x.squaredNorm() < max_radius2_)) return ProjectionStatus::kOutsideDomain;
  Eigen::Matrix2d J_dist;
  const Eigen::Vector2d x_d = Distort(parameters_.distortion, x, &J_dist);
  // With tangential terms the 2-D map can fold before the radial one does.
  if (!(J_dist.determinant() > 0.0)) return ProjectionStatus::kOutsideDomain;
  *pixel = Eigen::Vector2d(parameters_.fx * x_d.x() + parameters_.cx,
                           parameters_.fy * x_d.y() + parameters_.cy);
  if (J_pixel_point != nullptr) {
    Matrix23d J_x_point;  // ∂(x', y')/∂p_C
    J_x_point << inv_z, 0.0, -x.x() * inv_z, 0.0, inv_z, -x.y() * inv_z;
    *J_pixel_point = J_dist * J_x_point;
    J_pixel_point->row(0) *= parameters_.fx;
    J_pixel_point->row(1) *= parameters_.fy;
  }
  return ProjectionStatus::kOk;
}

ProjectionStatus PinholeBrownCamera::BackProject(const Eigen::Vector2d& pixel, Ray* ray,
                                                 RayJacobian* J) const {
  const std::array<double, 8>& k = parameters_.distortion;
  const Eigen::Vector2d target((pixel.x() - parameters_.cx) / parameters_.fx,
                               (pixel.y() - parameters_.cy) / parameters_.fy);
  if (!target.allFinite()) return ProjectionStatus::kOutsideDomain;
  // Start at the distorted point; pull it inside the domain if a pincushion model put it out.
  Eigen::Vector2d x = target;
  if (!(x.squaredNorm() < max_radius2_)) x *= 0.5 * max_radius_ / x.norm();
  Eigen::Matrix2d J_dist;
  Eigen::Vector2d residual = Distort(k, x, &J_dist) - target;
  double residual_norm = residual.norm();
  bool converged = false;
  for (int iteration = 0; iteration < kMaxNewtonIterations; ++iteration) {
    if (residual_norm <= kStopResidual * (1.0 + target.norm())) {
      converged = true;
      break;
    }
    if (!(J_dist.determinant() > 0.0)) return ProjectionStatus::kOutsideDomain;
    const Eigen::Vector2d step = -J_dist.inverse() * residual;
    // Newton's direction always decreases |residual| where the map is regular; halve the step
    // until it does and the iterate stays where the map is one-to-one.
    double t = 1.0;
    bool accepted = false;
    for (int halving = 0; halving < kMaxStepHalvings; ++halving, t *= 0.5) {
      const Eigen::Vector2d x_new = x + t * step;
      if (!(x_new.squaredNorm() < max_radius2_)) continue;
      Eigen::Matrix2d J_new;
      const Eigen::Vector2d residual_new = Distort(k, x_new, &J_new) - target;
      const double norm_new = residual_new.norm();
      if (!(J_new.determinant() > 0.0) || !(norm_new < residual_norm)) continue;
      x = x_new;
      J_dist = J_new;
      residual = residual_new;
      residual_norm = norm_new;
      accepted = true;
      break;
    }
    if (!accepted) {
      // Either rounding noise (done) or the way to the solution leaves the domain: the pixel
      // lies beyond the fold of the distortion.
      if (residual_norm <= kAcceptResidual) {
        converged = true;
        break;
      }
      return ProjectionStatus::kOutsideDomain;
    }
  }
  if (!converged && !(residual_norm <= kAcceptResidual)) return ProjectionStatus::kNoConvergence;

  const Eigen::Vector3d m(x.x(), x.y(), 1.0);
  const double m_norm = m.norm();
  ray->p_C_O.setZero();
  ray->d_C = m / m_norm;
  if (J != nullptr) {
    // ∂(x', y')/∂(u, v) = J_dist⁻¹ diag(1/fx, 1/fy) (implicit-function theorem on the
    // distortion map); ∂d/∂m = (I - d dᵀ)/|m|.
    Eigen::Matrix2d J_x_pixel = J_dist.inverse();
    J_x_pixel.col(0) /= parameters_.fx;
    J_x_pixel.col(1) /= parameters_.fy;
    const Eigen::Matrix3d J_d_m =
        (Eigen::Matrix3d::Identity() - ray->d_C * ray->d_C.transpose()) / m_norm;
    J->d_origin_d_pixel.setZero();
    J->d_direction_d_pixel = J_d_m.leftCols<2>() * J_x_pixel;
  }
  return ProjectionStatus::kOk;
}

}  // namespace kinevis::vision
