#pragma once

// Residual functors of the DIAMOND identification (diamond_identification.h), templated for
// Ceres' autodiff. Private to calibration/diamond and its tests (which check the Jacobians
// against central differences).
//
// All functors take the one parameter block z (kDiamondParameterCount scaled parameters) and map
// it to x = x⁰ + s ⊙ z through the shared ParameterFrame; the frame also holds the initial camera
// pose the camera parameters perturb (diamond_identification.h, "Parameters x").

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cmath>
#include <memory>

#include "calibration/diamond/diamond_identification.h"
#include "robots/diamond/diamond_model.h"
#include "vision/camera/camera_model.h"
#include "vision/diamond/spherical_positioning.h"

namespace kinevis::calibration::internal {

inline double Value(double x) { return x; }
template <int N>
double Value(const ceres::Jet<double, N>& x) {
  return x.a;
}

// x = x⁰ + s ⊙ z, and the initial camera pose's pieces (row-major R⁰_OC, ĉ⁰, e_1, e_2).
struct ParameterFrame {
  std::array<double, kDiamondParameterCount> x0{};
  std::array<double, kDiamondParameterCount> scale{};
  double R0[9];
  double c0_hat[3];
  double e1[3];
  double e2[3];

  ParameterFrame(const std::array<double, kDiamondParameterCount>& x_initial,
                 const Eigen::Isometry3d& X_OC_initial)
      : x0(x_initial) {
    scale.fill(1.0);
    const Eigen::Matrix3d R = X_OC_initial.linear();
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) R0[3 * r + c] = R(r, c);
    }
    const Eigen::Vector3d c_hat = X_OC_initial.translation().normalized();
    Eigen::Vector3d e_1 = Eigen::Vector3d::UnitZ().cross(c_hat);
    if (e_1.norm() < 1e-6) e_1 = Eigen::Vector3d::UnitX();
    e_1.normalize();
    const Eigen::Vector3d e_2 = c_hat.cross(e_1);
    for (int k = 0; k < 3; ++k) {
      c0_hat[k] = c_hat[k];
      e1[k] = e_1[k];
      e2[k] = e_2[k];
    }
  }

  template <typename T>
  T X(const T* z, int j) const {
    return x0[j] + scale[j] * z[j];
  }

  // R_OC = G R⁰ Exp(ω) and c_O = d G ĉ⁰ (diamond_identification.h), from the parameters x.
  // Outputs the inverse map: p_C = R_OCᵀ (p_O − c_O).
  template <typename T>
  void PointInCamera(const T* x, const T p_O[3], T p_C[3]) const {
    const T g[3] = {x[kDiamondCameraDirection1] * e1[0] + x[kDiamondCameraDirection2] * e2[0],
                    x[kDiamondCameraDirection1] * e1[1] + x[kDiamondCameraDirection2] * e2[1],
                    x[kDiamondCameraDirection1] * e1[2] + x[kDiamondCameraDirection2] * e2[2]};
    const T c_hat0[3] = {T(c0_hat[0]), T(c0_hat[1]), T(c0_hat[2])};
    T c_dir[3];
    ceres::AngleAxisRotatePoint(g, c_hat0, c_dir);
    const T d = x[kDiamondCameraDistance];
    const T rel[3] = {p_O[0] - d * c_dir[0], p_O[1] - d * c_dir[1], p_O[2] - d * c_dir[2]};
    // Gᵀ rel, then R⁰ᵀ, then Exp(ω)ᵀ.
    const T minus_g[3] = {-g[0], -g[1], -g[2]};
    T a[3];
    ceres::AngleAxisRotatePoint(minus_g, rel, a);
    T b[3];
    for (int c = 0; c < 3; ++c) b[c] = R0[c] * a[0] + R0[3 + c] * a[1] + R0[6 + c] * a[2];
    const T minus_w[3] = {-x[kDiamondCameraRotationX], -x[kDiamondCameraRotationY],
                          -x[kDiamondCameraRotationZ]};
    ceres::AngleAxisRotatePoint(minus_w, b, p_C);
  }

  // The ray o_C + t d_C of C expressed in O.
  template <typename T>
  void RayInO(const T* x, const Eigen::Vector3d& o_C, const Eigen::Vector3d& d_C, T o_O[3],
              T d_O[3]) const {
    const T g[3] = {x[kDiamondCameraDirection1] * e1[0] + x[kDiamondCameraDirection2] * e2[0],
                    x[kDiamondCameraDirection1] * e1[1] + x[kDiamondCameraDirection2] * e2[1],
                    x[kDiamondCameraDirection1] * e1[2] + x[kDiamondCameraDirection2] * e2[2]};
    const T w[3] = {x[kDiamondCameraRotationX], x[kDiamondCameraRotationY],
                    x[kDiamondCameraRotationZ]};
    const auto to_O = [&](const Eigen::Vector3d& v_C, T out[3]) {  // G R⁰ Exp(ω) v
      const T v[3] = {T(v_C[0]), T(v_C[1]), T(v_C[2])};
      T a[3];
      ceres::AngleAxisRotatePoint(w, v, a);
      T b[3];
      for (int r = 0; r < 3; ++r)
        b[r] = R0[3 * r] * a[0] + R0[3 * r + 1] * a[1] + R0[3 * r + 2] * a[2];
      ceres::AngleAxisRotatePoint(g, b, out);
    };
    to_O(o_C, o_O);
    to_O(d_C, d_O);
    const T c_hat0[3] = {T(c0_hat[0]), T(c0_hat[1]), T(c0_hat[2])};
    T c_dir[3];
    ceres::AngleAxisRotatePoint(g, c_hat0, c_dir);
    for (int k = 0; k < 3; ++k) o_O[k] += x[kDiamondCameraDistance] * c_dir[k];
  }
};

// The marker in the camera frame for joint readings q (3 outputs, m):
//   x = x⁰ + s ⊙ z; θ_i = q_i + o_i (o_1 = m + h, o_2 = m − h); (φ, γ) by eq. (34)–(35) on the
//   "+" branch; p_O_T = R u(φ, γ); p_C = R_OCᵀ (p_O_T − c_O).
// Returns false when the limbs cannot close (the sample has no prediction at these parameters).
struct DiamondMarkerInCamera {
  DiamondMarkerInCamera(const ParameterFrame* frame, const Eigen::Vector2d& q)
      : frame_(frame), q_(q) {}

  template <typename T>
  bool operator()(const T* z, T* p_C) const {
    T x[kDiamondParameterCount];
    for (int j = 0; j < kDiamondParameterCount; ++j) x[j] = frame_->X(z, j);
    const T o1 = x[kDiamondMeanOffset] + x[kDiamondHalfOffsetDifference];
    const T o2 = x[kDiamondMeanOffset] - x[kDiamondHalfOffsetDifference];
    T phi, gamma;
    Eigen::Matrix<T, 3, 1> p_O;
    if (robots::DiamondToolPointFromJoints<T>(x[kDiamondRadius], x[kDiamondAlpha], x[kDiamondBeta],
                                              o1, o2, T(q_[0]), T(q_[1]), &phi, &gamma,
                                              &p_O) != robots::DiamondSolve::kOk) {
      return false;
    }
    const T p[3] = {p_O[0], p_O[1], p_O[2]};
    frame_->PointInCamera(x, p, p_C);
    return true;
  }

  static ceres::CostFunction* Create(const ParameterFrame* frame, const Eigen::Vector2d& q) {
    return new ceres::AutoDiffCostFunction<DiamondMarkerInCamera, 3, kDiamondParameterCount>(
        new DiamondMarkerInCamera(frame, q));
  }

 private:
  const ParameterFrame* frame_;
  Eigen::Vector2d q_;
};

// kPixel residual: r = (pixel_measured − Project(p_C)) / σ_px (2, dimensionless). Project is the
// camera model's (not templated): its analytic ∂pixel/∂p_C times the autodiff ∂p_C/∂z of
// DiamondMarkerInCamera gives the Jacobian. False when the marker has no prediction or does not
// project.
class DiamondPixelCost final : public ceres::SizedCostFunction<2, kDiamondParameterCount> {
 public:
  DiamondPixelCost(const ParameterFrame* frame, const vision::CameraModel* camera,
                   const DiamondSample& sample, double sigma)
      : point_(DiamondMarkerInCamera::Create(frame, sample.q)),
        camera_(camera),
        pixel_(sample.pixel),
        inv_sigma_(1.0 / sigma) {}

  static ceres::CostFunction* Create(const ParameterFrame* frame, const vision::CameraModel* camera,
                                     const DiamondSample& sample, double sigma) {
    return new DiamondPixelCost(frame, camera, sample, sigma);
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    double p_C[3];
    double J_point[3 * kDiamondParameterCount];
    double* J_point_ptr[1] = {J_point};
    if (!point_->Evaluate(parameters, p_C, jacobians != nullptr ? J_point_ptr : nullptr)) {
      return false;
    }
    Eigen::Vector2d predicted;
    vision::Matrix23d J_pixel;
    if (camera_->Project(Eigen::Vector3d(p_C[0], p_C[1], p_C[2]), &predicted,
                         jacobians != nullptr ? &J_pixel : nullptr) !=
        vision::ProjectionStatus::kOk) {
      return false;
    }
    residuals[0] = (pixel_.x() - predicted.x()) * inv_sigma_;
    residuals[1] = (pixel_.y() - predicted.y()) * inv_sigma_;
    if (jacobians != nullptr && jacobians[0] != nullptr) {
      const Eigen::Map<const Eigen::Matrix<double, 3, kDiamondParameterCount, Eigen::RowMajor>> Jp(
          J_point);
      Eigen::Map<Eigen::Matrix<double, 2, kDiamondParameterCount, Eigen::RowMajor>> J(jacobians[0]);
      J = -inv_sigma_ * (J_pixel * Jp);
    }
    return true;
  }

 private:
  std::unique_ptr<ceres::CostFunction> point_;
  const vision::CameraModel* camera_;
  Eigen::Vector2d pixel_;
  double inv_sigma_;
};

// kSpherical residual (seed eq. 6): r = W · ((φ, γ)_measured − (φ, γ)_model) (2, dimensionless).
//   (φ, γ)_measured: the measured pixel's ray (o_C, d_C, fixed: the intrinsics are known) taken
//     to O with the current camera pose and met with the sphere |p| = R (near side,
//     vision::IntersectRaySphere), then vision::TaskFromPoint;
//   (φ, γ)_model: eq. (34)–(35) with the current R, α, β, offsets;
//   W = L⁻¹ with L Lᵀ = σ_px² J Jᵀ, J = ∂(φ,γ)/∂pixel: constant during a solve (held by the
//     caller, which recomputes it at the solution and solves again until it settles).
// The φ difference is wrapped to (−π, π]. False when the ray misses the sphere, meets it at an
// incidence cosine below the limit, or the limbs cannot close.
struct DiamondSphericalResidual {
  DiamondSphericalResidual(const ParameterFrame* frame, const Eigen::Vector2d& q,
                           const vision::Ray& ray_C, const Eigen::Matrix2d* W,
                           double min_incidence_cosine)
      : frame_(frame),
        q_(q),
        o_C_(ray_C.p_C_O),
        d_C_(ray_C.d_C),
        W_(W),
        min_incidence_(min_incidence_cosine) {}

  template <typename T>
  bool operator()(const T* z, T* residual) const {
    T x[kDiamondParameterCount];
    for (int j = 0; j < kDiamondParameterCount; ++j) x[j] = frame_->X(z, j);
    T o[3], d[3];
    frame_->RayInO(x, o_C_, d_C_, o, d);
    const Eigen::Matrix<T, 3, 1> o_O(o[0], o[1], o[2]);
    const Eigen::Matrix<T, 3, 1> d_O(d[0], d[1], d[2]);
    Eigen::Matrix<T, 3, 1> p;
    T incidence;
    if (vision::IntersectRaySphere<T>(o_O, d_O, x[kDiamondRadius], &p, &incidence) !=
            vision::RaySphereHit::kOk ||
        Value(incidence) < min_incidence_) {
      return false;
    }
    const Eigen::Matrix<T, 2, 1> measured = vision::TaskFromPoint<T>(p);
    const T o1 = x[kDiamondMeanOffset] + x[kDiamondHalfOffsetDifference];
    const T o2 = x[kDiamondMeanOffset] - x[kDiamondHalfOffsetDifference];
    T phi, gamma;
    if (robots::DiamondTaskFromThetas<T>(x[kDiamondAlpha], x[kDiamondBeta], T(q_[0]) + o1,
                                         T(q_[1]) + o2, &phi,
                                         &gamma) != robots::DiamondSolve::kOk) {
      return false;
    }
    T e_phi = measured[0] - phi;
    e_phi -= 2.0 * M_PI * std::round(Value(e_phi) / (2.0 * M_PI));
    const T e_gamma = measured[1] - gamma;
    const Eigen::Matrix2d& W = *W_;
    residual[0] = W(0, 0) * e_phi + W(0, 1) * e_gamma;
    residual[1] = W(1, 0) * e_phi + W(1, 1) * e_gamma;
    return true;
  }

  static ceres::CostFunction* Create(const ParameterFrame* frame, const Eigen::Vector2d& q,
                                     const vision::Ray& ray_C, const Eigen::Matrix2d* W,
                                     double min_incidence_cosine) {
    return new ceres::AutoDiffCostFunction<DiamondSphericalResidual, 2, kDiamondParameterCount>(
        new DiamondSphericalResidual(frame, q, ray_C, W, min_incidence_cosine));
  }

 private:
  const ParameterFrame* frame_;
  Eigen::Vector2d q_;
  Eigen::Vector3d o_C_;
  Eigen::Vector3d d_C_;
  const Eigen::Matrix2d* W_;  // not owned
  double min_incidence_;
};

}  // namespace kinevis::calibration::internal
