#include "vision/camera/tsai_camera.h"

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace kinevis::vision {
namespace {

constexpr double kInfinity = std::numeric_limits<double>::infinity();

// Squared largest distorted radius (mm²) where r_u = r_d g(r_d²) still increases (see header).
double MaxDistortedRadius2(TsaiDistortionForm form, double kappa1) {
  if (form == TsaiDistortionForm::kTsai) {
    // d r_u / d r_d = 1 + 3 κ1 r_d².
    return kappa1 < 0.0 ? -1.0 / (3.0 * kappa1) : kInfinity;
  }
  // Division: d r_u / d r_d = (1 + κ1 r_d²) / (1 - κ1 r_d²)², and the pole at κ1 r_d² = 1.
  return kappa1 != 0.0 ? 1.0 / std::abs(kappa1) : kInfinity;
}

struct Distortion {
  double g;           // X_u = X_d g(s), s = r_d²
  double derivative;  // dg/ds
};

Distortion Evaluate(TsaiDistortionForm form, double kappa1, double s) {
  if (form == TsaiDistortionForm::kTsai) return {1.0 + kappa1 * s, kappa1};
  const double inv = 1.0 / (1.0 - kappa1 * s);
  return {inv, kappa1 * inv * inv};
}

// ∂q_u/∂q_d = g I + 2 g'(s) q_d q_dᵀ for q_u = q_d g(|q_d|²).
Eigen::Matrix2d UndistortionJacobian(const Distortion& d, const Eigen::Vector2d& q_d) {
  return d.g * Eigen::Matrix2d::Identity() + 2.0 * d.derivative * q_d * q_d.transpose();
}

// The distorted radius r_d (mm) of the undistorted radius r_u >= 0 (mm) on the physical branch
// (the one through r_d = r_u at r_u = 0); false when r_u is beyond the largest undistorted radius
// the model reaches.
bool DistortedRadius(TsaiDistortionForm form, double kappa1, double r_u, double* r_d) {
  double r;
  if (kappa1 == 0.0) {
    *r_d = r_u;
    return true;
  }
  if (form == TsaiDistortionForm::kTsai) {
    // κ1 r³ + r - r_u = 0, i.e. the depressed cubic r³ + p r + q = 0 with p = 1/κ1, q = -r_u/κ1.
    // Cardano's formula cancels badly for small κ1 r_u²; the trigonometric/hyperbolic forms do not.
    if (kappa1 > 0.0) {
      // p > 0: one real root, r = 2a sinh(asinh(3 r_u / (2a)) / 3), a = sqrt(p/3). It is
      // positive and increasing in r_u, so it is the physical one.
      const double a = std::sqrt(1.0 / (3.0 * kappa1));
      r = 2.0 * a * std::sinh(std::asinh(1.5 * r_u / a) / 3.0);
    } else {
      // p < 0: a = sqrt(-p/3) is the fold radius (dr_u/dr_d = 0), where r_u reaches (2/3) a.
      // Below it there are three real roots 2a cos(φ/3 - 2πk/3), cos φ = -3 r_u/(2a); k = 1 is the
      // one in [0, a) (k = 0 lies beyond the fold, k = 2 is negative). Since
      // cos(φ/3 - 2π/3) = sin(asin(3 r_u/(2a)) / 3), it is computed without cancellation as
      const double a = std::sqrt(-1.0 / (3.0 * kappa1));
      const double sine = 1.5 * r_u / a;
      if (!(sine < 1.0)) return false;
      r = 2.0 * a * std::sin(std::asin(sine) / 3.0);
    }
    // No Newton polish: these closed forms already round-trip to ~1e-12 px over the image (a
    // polishing step was tried and changed nothing measurable).
  } else {
    // κ1 r_u r² + r - r_u = 0. The root through r = r_u at κ1 = 0, written without cancellation,
    // is 2 r_u / (1 + sqrt(1 + 4 κ1 r_u²)); the other one is negative or beyond the pole. With
    // κ1 < 0 no root exists past 1 + 4 κ1 r_u² = 0, which is the fold.
    const double discriminant = 1.0 + 4.0 * kappa1 * r_u * r_u;
    if (!(discriminant > 0.0)) return false;
    r = 2.0 * r_u / (1.0 + std::sqrt(discriminant));
  }
  *r_d = r;
  return true;
}

}  // namespace

std::string_view ToString(TsaiDistortionForm form) {
  switch (form) {
    case TsaiDistortionForm::kTsai:
      return "tsai";
    case TsaiDistortionForm::kDivision:
      return "division";
  }
  return "unknown";
}

double Kappa1PerMm2FromPerPixel2(double k_per_px2, double pixel_pitch_y_mm) {
  return k_per_px2 / (pixel_pitch_y_mm * pixel_pitch_y_mm);
}

TsaiParameters TsaiParameters::Seed004() {
  // Seed 004, Table 1. The seed's text says "fx = f/sx" with s_x in pixel/mm; the units only work
  // as fx = f · 227.27 px/mm = 2144.9 px, i.e. the scale factors are 1/d'_x and 1/d_y (4.4 µm,
  // the Lumenera LW230's pixel) and Tsai's uncertainty factor s_x is 1.
  //
  // Units of k = 9.4604e-9: eq. (23) puts it against r² = μ²(u - C_x)² + (v - C_y)² in pixels².
  // Per pixel² it gives k r² = 0.011 at the far image corner (r ≈ 1080 px): a 1.1 % barrel, what a
  // 9.4 mm lens on a 7.1 × 5.4 mm sensor shows. Per mm² it would be 2e-7 at the corner (r_d =
  // 4.75 mm), far below anything a calibration resolves, so it is per pixel²; κ1 = k / d_y².
  constexpr double kScalePxPerMm = 227.27;
  TsaiParameters p;
  p.width = 1616;
  p.height = 1216;
  p.focal_length_mm = 9.43773;
  p.cx = 738.0;
  p.cy = 585.0;
  p.pixel_pitch_x_mm = 1.0 / kScalePxPerMm;
  p.pixel_pitch_y_mm = 1.0 / kScalePxPerMm;
  p.scale_x = 1.0;
  p.kappa1_per_mm2 = Kappa1PerMm2FromPerPixel2(9.4604e-9, p.pixel_pitch_y_mm);
  // The seed's eq. (23) divides by (1 - k r²): k was estimated in that form, so keep it.
  p.distortion_form = TsaiDistortionForm::kDivision;
  return p;
}

std::string TsaiParameters::Validate() const {
  std::ostringstream errors;
  errors.precision(12);
  const auto positive = [&errors](const char* name, double value) {
    if (!std::isfinite(value) || value <= 0.0) {
      errors << name << " = " << value << " must be finite and > 0; ";
      return false;
    }
    return true;
  };
  bool usable = true;
  if (width <= 0) errors << "width = " << width << " must be > 0; ";
  if (height <= 0) errors << "height = " << height << " must be > 0; ";
  usable &= width > 0 && height > 0;
  usable &= positive("focal_length_mm", focal_length_mm);
  if (!std::isfinite(cx)) errors << "cx = " << cx << " is not finite; ";
  if (!std::isfinite(cy)) errors << "cy = " << cy << " is not finite; ";
  usable &= std::isfinite(cx) && std::isfinite(cy);
  usable &= positive("pixel_pitch_x_mm", pixel_pitch_x_mm);
  usable &= positive("pixel_pitch_y_mm", pixel_pitch_y_mm);
  usable &= positive("scale_x", scale_x);
  if (!std::isfinite(kappa1_per_mm2)) {
    errors << "kappa1_per_mm2 = " << kappa1_per_mm2 << " is not finite; ";
    usable = false;
  }
  if (distortion_form != TsaiDistortionForm::kTsai &&
      distortion_form != TsaiDistortionForm::kDivision) {
    errors << "distortion_form = " << static_cast<int>(distortion_form)
           << " is neither tsai nor division; ";
    usable = false;
  }
  if (usable) {
    // The distortion must not fold inside the image: the farthest pixel corner from the centre.
    const double du = std::max(std::abs(-0.5 - cx), std::abs(width - 0.5 - cx));
    const double dv = std::max(std::abs(-0.5 - cy), std::abs(height - 0.5 - cy));
    const double x_d = pixel_pitch_x_mm * du / scale_x;
    const double y_d = pixel_pitch_y_mm * dv;
    const double corner_rd2 = x_d * x_d + y_d * y_d;
    const double max_rd2 = MaxDistortedRadius2(distortion_form, kappa1_per_mm2);
    if (!(corner_rd2 < max_rd2)) {
      errors << "kappa1_per_mm2 = " << kappa1_per_mm2 << " (" << ToString(distortion_form)
             << " form) folds the distortion at r_d = " << std::sqrt(max_rd2)
             << " mm, inside the image (its far corner is at r_d = " << std::sqrt(corner_rd2)
             << " mm); ";
    }
  }
  std::string message = errors.str();
  if (message.size() >= 2) message.resize(message.size() - 2);  // drop the trailing "; "
  return message;
}

TsaiCamera::TsaiCamera(const TsaiParameters& parameters) : parameters_(parameters) {
  const std::string errors = parameters_.Validate();
  if (!errors.empty()) throw std::invalid_argument("tsai camera: " + errors);
  max_rd_mm_ =
      std::sqrt(MaxDistortedRadius2(parameters_.distortion_form, parameters_.kappa1_per_mm2));
}

ProjectionStatus TsaiCamera::Project(const Eigen::Vector3d& p_C, Eigen::Vector2d* pixel,
                                     Matrix23d* J_pixel_point) const {
  const TsaiParameters& p = parameters_;
  if (!(p_C.z() > 0.0)) return ProjectionStatus::kBehindCamera;
  const double inv_z = 1.0 / p_C.z();
  const double f = p.focal_length_mm;
  const Eigen::Vector2d q_u(f * p_C.x() * inv_z, f * p_C.y() * inv_z);  // (X_u, Y_u), mm
  const double r_u = q_u.norm();
  double r_d = 0.0;
  if (!DistortedRadius(p.distortion_form, p.kappa1_per_mm2, r_u, &r_d)) {
    return ProjectionStatus::kOutsideDomain;
  }
  if (!(r_d < max_rd_mm_)) return ProjectionStatus::kOutsideDomain;
  // Radial: the distorted point lies on the ray of the undistorted one (the RAC itself).
  const Eigen::Vector2d q_d = r_u > 0.0 ? Eigen::Vector2d(q_u * (r_d / r_u)) : q_u;
  *pixel = Eigen::Vector2d(p.scale_x * q_d.x() / p.pixel_pitch_x_mm + p.cx,
                           q_d.y() / p.pixel_pitch_y_mm + p.cy);
  if (J_pixel_point != nullptr) {
    // ∂q_d/∂q_u is the inverse of ∂q_u/∂q_d (implicit-function theorem), regular in the domain.
    const Distortion d = Evaluate(p.distortion_form, p.kappa1_per_mm2, q_d.squaredNorm());
    const Eigen::Matrix2d J_qd_qu = UndistortionJacobian(d, q_d).inverse();
    Matrix23d J_qu_point;
    J_qu_point << f * inv_z, 0.0, -q_u.x() * inv_z, 0.0, f * inv_z, -q_u.y() * inv_z;
    *J_pixel_point = J_qd_qu * J_qu_point;
    J_pixel_point->row(0) *= p.scale_x / p.pixel_pitch_x_mm;
    J_pixel_point->row(1) /= p.pixel_pitch_y_mm;
  }
  return ProjectionStatus::kOk;
}

ProjectionStatus TsaiCamera::BackProject(const Eigen::Vector2d& pixel, Ray* ray,
                                         RayJacobian* J) const {
  const TsaiParameters& p = parameters_;
  const Eigen::Vector2d q_d(p.pixel_pitch_x_mm * (pixel.x() - p.cx) / p.scale_x,
                            p.pixel_pitch_y_mm * (pixel.y() - p.cy));  // (X_d, Y_d), mm
  const double s = q_d.squaredNorm();
  if (!(s < max_rd_mm_ * max_rd_mm_)) return ProjectionStatus::kOutsideDomain;
  const Distortion d = Evaluate(p.distortion_form, p.kappa1_per_mm2, s);
  // seed 004, eq. (25): the direction (A_x, B_y, 1) = (X_u / f, Y_u / f, 1).
  const Eigen::Vector3d m(d.g * q_d.x(), d.g * q_d.y(), p.focal_length_mm);
  const double m_norm = m.norm();
  ray->p_C_O.setZero();
  ray->d_C = m / m_norm;
  if (J != nullptr) {
    Eigen::Matrix2d J_qu_pixel = UndistortionJacobian(d, q_d);
    J_qu_pixel.col(0) *= p.pixel_pitch_x_mm / p.scale_x;
    J_qu_pixel.col(1) *= p.pixel_pitch_y_mm;
    const Eigen::Matrix3d J_d_m =
        (Eigen::Matrix3d::Identity() - ray->d_C * ray->d_C.transpose()) / m_norm;
    J->d_origin_d_pixel.setZero();
    J->d_direction_d_pixel = J_d_m.leftCols<2>() * J_qu_pixel;
  }
  return ProjectionStatus::kOk;
}

}  // namespace kinevis::vision
