#pragma once

// Residual functors of the scanner mount calibration (mount_calibration.h), templated for Ceres'
// autodiff. Private to calibration/weld_mount and its tests (the tests check the autodiff
// Jacobians against central differences and the closest-point geometry against brute force).
//
// Parameterisation (all "right" perturbations of a fixed anchor pose, so that the parameters
// start at zero and read as errors in the moving frame):
//   mount  x_m = [r; t] (6): X_5C = X_5C⁰ · (Exp(r), t), r a rotation vector (rad), t (m);
//   block  x_b = [r; t] (6): X_0B = X_0B⁰ · (Exp(r), t);
//   D–H    x_dh (20): per link i = 1..5 [Δa_i, Δα_i, Δd_i, Δθ_i] added to the nominal a, α, d and
//          θ offset (seed eq. 48's Δl, Δα, Δd, Δθ).

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cmath>

#include "robots/weld5/weld5_model.h"

namespace kinevis::calibration::internal {

inline constexpr int kDhErrors = 4 * robots::kWeld5Joints;

inline double Value(double x) { return x; }
template <int N>
double Value(const ceres::Jet<double, N>& x) {
  return x.a;
}

// A fixed pose as plain arrays (row-major rotation) for the functors.
struct FixedPose {
  double R[9];
  double t[3];
  FixedPose() : FixedPose(Eigen::Isometry3d::Identity()) {}
  explicit FixedPose(const Eigen::Isometry3d& X) {
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) R[3 * r + c] = X.linear()(r, c);
      t[r] = X.translation()(r);
    }
  }
  template <typename T>
  void Apply(const T p[3], T out[3]) const {  // out = R p + t
    for (int r = 0; r < 3; ++r)
      out[r] = R[3 * r] * p[0] + R[3 * r + 1] * p[1] + R[3 * r + 2] * p[2] + t[r];
  }
  template <typename T>
  void ApplyInverse(const T p[3], T out[3]) const {  // out = Rᵀ (p − t)
    const T d[3] = {p[0] - t[0], p[1] - t[1], p[2] - t[2]};
    for (int c = 0; c < 3; ++c) out[c] = R[c] * d[0] + R[3 + c] * d[1] + R[6 + c] * d[2];
  }
};

// p_A = X_A⁰ · (Exp(x[0..2]) p + x[3..5]): a point of the perturbed frame in the anchor's parent.
template <typename T>
void PerturbedToParent(const FixedPose& anchor, const T* x, const T p[3], T out[3]) {
  T rotated[3];
  ceres::AngleAxisRotatePoint(x, p, rotated);
  const T local[3] = {rotated[0] + x[3], rotated[1] + x[4], rotated[2] + x[5]};
  anchor.Apply(local, out);
}

// The inverse: p = Exp(−x[0..2]) (X_A⁰⁻¹ p_A − x[3..5]).
template <typename T>
void ParentToPerturbed(const FixedPose& anchor, const T* x, const T p_A[3], T out[3]) {
  T local[3];
  anchor.ApplyInverse(p_A, local);
  const T shifted[3] = {local[0] - x[3], local[1] - x[4], local[2] - x[5]};
  const T minus_r[3] = {-x[0], -x[1], -x[2]};
  ceres::AngleAxisRotatePoint(minus_r, shifted, out);
}

// The nominal D–H chain of the weld robot with errors: p_0 = Π_i X_{i−1,i}(q_i; nominal + Δ) p_5,
// each X = Rz(θ) Tz(d) Tx(a) Rx(α) (seed eq. 34, standard convention), applied to the point from
// link 5 down to link 1.
struct DhChain {
  std::array<robots::DhJoint, robots::kWeld5Joints> joints;
  double q[robots::kWeld5Joints];
  DhChain(const robots::Weld5Model& model, const robots::Vector5d& q_in) : joints(model.joints) {
    for (int i = 0; i < robots::kWeld5Joints; ++i) q[i] = q_in(i);
  }
  template <typename T>
  void Apply(const T* delta, const T p_5[3], T p_0[3]) const {
    T p[3] = {p_5[0], p_5[1], p_5[2]};
    for (int i = robots::kWeld5Joints - 1; i >= 0; --i) {
      const robots::DhJoint& j = joints[static_cast<size_t>(i)];
      const T a = j.a + delta[4 * i + 0];
      const T alpha = j.alpha + delta[4 * i + 1];
      const T d = (j.prismatic ? j.d + q[i] : j.d) + delta[4 * i + 2];
      const T theta = (j.prismatic ? j.theta_offset : q[i] + j.theta_offset) + delta[4 * i + 3];
      using std::cos;
      using std::sin;
      // Rx(α), then Tx(a) and Tz(d), then Rz(θ).
      const T ca = cos(alpha), sa = sin(alpha);
      const T y1 = ca * p[1] - sa * p[2];
      const T z1 = sa * p[1] + ca * p[2];
      const T x1 = p[0] + a;
      const T ct = cos(theta), st = sin(theta);
      p[0] = ct * x1 - st * y1;
      p[1] = st * x1 + ct * y1;
      p[2] = z1 + d;
    }
    p_0[0] = p[0];
    p_0[1] = p[1];
    p_0[2] = p[2];
  }
};

// The closest point c_B on the block-on-board surface to p_B (block frame B, half sizes h): the
// top face z = h_z and the four side faces of the box, and the board plane z = −h_z outside the
// block's footprint. Each face's closest point is the projection clamped to the face; the surface's
// is the nearest of them (chosen on the values; the clamped coordinates are constants, so the
// derivative is that of the chosen face's closest point). Returns the face: 0 top, 1 +x, 2 −x,
// 3 +y, 4 −y, 5 board.
template <typename T>
int ClosestSurfacePoint(const double h[3], const T p[3], T c[3]) {
  const auto clamp = [](const T& v, double lo, double hi) -> T {
    if (Value(v) < lo) return T(lo);
    if (Value(v) > hi) return T(hi);
    return v;
  };
  T best[3] = {T(0.0), T(0.0), T(0.0)};
  double best_d2 = std::numeric_limits<double>::infinity();
  int best_face = -1;
  const auto consider = [&](int face, const T& x, const T& y, const T& z) {
    const double dx = Value(p[0]) - Value(x), dy = Value(p[1]) - Value(y),
                 dz = Value(p[2]) - Value(z);
    const double d2 = dx * dx + dy * dy + dz * dz;
    if (d2 < best_d2) {
      best_d2 = d2;
      best[0] = x;
      best[1] = y;
      best[2] = z;
      best_face = face;
    }
  };
  consider(0, clamp(p[0], -h[0], h[0]), clamp(p[1], -h[1], h[1]), T(h[2]));
  consider(1, T(h[0]), clamp(p[1], -h[1], h[1]), clamp(p[2], -h[2], h[2]));
  consider(2, T(-h[0]), clamp(p[1], -h[1], h[1]), clamp(p[2], -h[2], h[2]));
  consider(3, clamp(p[0], -h[0], h[0]), T(h[1]), clamp(p[2], -h[2], h[2]));
  consider(4, clamp(p[0], -h[0], h[0]), T(-h[1]), clamp(p[2], -h[2], h[2]));
  if (std::abs(Value(p[0])) > h[0] || std::abs(Value(p[1])) > h[1]) {
    consider(5, p[0], p[1], T(-h[2]));
  }
  c[0] = best[0];
  c[1] = best[1];
  c[2] = best[2];
  return best_face;
}

// Scan point, robot model fixed (mount only). Measured: the stripe point p_C (camera frame) of a
// scan taken at joints q with the link-5 pose X_05(q) known. Predicted: it lies on the block's
// surface. Residual (3): r = (p_B − c_B(p_B)) / σ_scan with
//   p_B = X_0B⁻¹ · X_05 · X_5C · p_C,   X_5C = X_5C⁰·(Exp(r_m), t_m),  X_0B = X_0B⁰·(Exp(r_b),
//   t_b),
// c_B the closest surface point (ClosestSurfacePoint). Inside a face r is the normal distance
// along the face normal (point-to-plane); beyond a face's rim it points to the rim (edges give
// the lateral constraints). Parameters: mount (6), block (6).
struct ScanPointResidual {
  ScanPointResidual(const Eigen::Vector3d& p_C, const Eigen::Isometry3d& X_05,
                    const Eigen::Isometry3d& X_5C0, const Eigen::Isometry3d& X_0B0,
                    const Eigen::Vector3d& half, double sigma)
      : X_05_(X_05), X_5C0_(X_5C0), X_0B0_(X_0B0), inv_sigma_(1.0 / sigma) {
    for (int k = 0; k < 3; ++k) {
      p_C_[k] = p_C(k);
      h_[k] = half(k);
    }
  }
  template <typename T>
  bool operator()(const T* mount, const T* block, T* residual) const {
    const T p_C[3] = {T(p_C_[0]), T(p_C_[1]), T(p_C_[2])};
    T p_5[3], p_0[3], p_B[3], c_B[3];
    PerturbedToParent(X_5C0_, mount, p_C, p_5);
    X_05_.Apply(p_5, p_0);
    ParentToPerturbed(X_0B0_, block, p_0, p_B);
    ClosestSurfacePoint(h_, p_B, c_B);
    for (int k = 0; k < 3; ++k) residual[k] = (p_B[k] - c_B[k]) * inv_sigma_;
    return true;
  }
  static ceres::CostFunction* Create(const Eigen::Vector3d& p_C, const Eigen::Isometry3d& X_05,
                                     const Eigen::Isometry3d& X_5C0, const Eigen::Isometry3d& X_0B0,
                                     const Eigen::Vector3d& half, double sigma) {
    return new ceres::AutoDiffCostFunction<ScanPointResidual, 3, 6, 6>(
        new ScanPointResidual(p_C, X_05, X_5C0, X_0B0, half, sigma));
  }

 private:
  FixedPose X_05_, X_5C0_, X_0B0_;
  double p_C_[3];
  double h_[3];
  double inv_sigma_;
};

// Scan point with the D–H errors: as ScanPointResidual with X_05 = X_05(q; nominal + x_dh) (seed
// eq. 48: the point moves with every link parameter). Parameters: mount (6), block (6), D–H (20).
struct ScanPointDhResidual {
  ScanPointDhResidual(const Eigen::Vector3d& p_C, const DhChain& chain,
                      const Eigen::Isometry3d& X_5C0, const Eigen::Isometry3d& X_0B0,
                      const Eigen::Vector3d& half, double sigma)
      : chain_(chain), X_5C0_(X_5C0), X_0B0_(X_0B0), inv_sigma_(1.0 / sigma) {
    for (int k = 0; k < 3; ++k) {
      p_C_[k] = p_C(k);
      h_[k] = half(k);
    }
  }
  template <typename T>
  bool operator()(const T* mount, const T* block, const T* dh, T* residual) const {
    const T p_C[3] = {T(p_C_[0]), T(p_C_[1]), T(p_C_[2])};
    T p_5[3], p_0[3], p_B[3], c_B[3];
    PerturbedToParent(X_5C0_, mount, p_C, p_5);
    chain_.Apply(dh, p_5, p_0);
    ParentToPerturbed(X_0B0_, block, p_0, p_B);
    ClosestSurfacePoint(h_, p_B, c_B);
    for (int k = 0; k < 3; ++k) residual[k] = (p_B[k] - c_B[k]) * inv_sigma_;
    return true;
  }
  static ceres::CostFunction* Create(const Eigen::Vector3d& p_C, const DhChain& chain,
                                     const Eigen::Isometry3d& X_5C0, const Eigen::Isometry3d& X_0B0,
                                     const Eigen::Vector3d& half, double sigma) {
    return new ceres::AutoDiffCostFunction<ScanPointDhResidual, 3, 6, 6, kDhErrors>(
        new ScanPointDhResidual(p_C, chain, X_5C0, X_0B0, half, sigma));
  }

 private:
  DhChain chain_;
  FixedPose X_5C0_, X_0B0_;
  double p_C_[3];
  double h_[3];
  double inv_sigma_;
};

// Touch. Measured: the torch tip p_0T = X_05(q; nominal + x_dh) · p_5T (p_5T = X_5T's origin) at a
// touch's joints. Predicted: it lies on the touched feature. Residual (3), per axis k of B:
//   r_k = s_k² (p_B[k] − s_k h_k) / σ_touch,   p_B = X_0B⁻¹ p_0T,
// zero (constant) where the feature leaves the axis free (s_k = 0). Parameters: block (6), D–H
// (20; held constant when the robot is not calibrated).
struct TouchResidual {
  TouchResidual(const DhChain& chain, const Eigen::Vector3d& p_5T, const Eigen::Vector3i& sign,
                const Eigen::Isometry3d& X_0B0, const Eigen::Vector3d& half, double sigma)
      : chain_(chain), X_0B0_(X_0B0), inv_sigma_(1.0 / sigma) {
    for (int k = 0; k < 3; ++k) {
      p_5T_[k] = p_5T(k);
      s_[k] = sign(k);
      h_[k] = half(k);
    }
  }
  template <typename T>
  bool operator()(const T* block, const T* dh, T* residual) const {
    const T p_5[3] = {T(p_5T_[0]), T(p_5T_[1]), T(p_5T_[2])};
    T p_0[3], p_B[3];
    chain_.Apply(dh, p_5, p_0);
    ParentToPerturbed(X_0B0_, block, p_0, p_B);
    for (int k = 0; k < 3; ++k) {
      residual[k] = s_[k] == 0 ? T(0.0) : (p_B[k] - s_[k] * h_[k]) * inv_sigma_;
    }
    return true;
  }
  static ceres::CostFunction* Create(const DhChain& chain, const Eigen::Vector3d& p_5T,
                                     const Eigen::Vector3i& sign, const Eigen::Isometry3d& X_0B0,
                                     const Eigen::Vector3d& half, double sigma) {
    return new ceres::AutoDiffCostFunction<TouchResidual, 3, 6, kDhErrors>(
        new TouchResidual(chain, p_5T, sign, X_0B0, half, sigma));
  }

 private:
  DhChain chain_;
  FixedPose X_0B0_;
  double p_5T_[3];
  int s_[3];
  double h_[3];
  double inv_sigma_;
};

// The pose X⁰ · (Exp(x[0..2]), x[3..5]).
inline Eigen::Isometry3d PerturbPose(const Eigen::Isometry3d& anchor, const double* x) {
  Eigen::Isometry3d delta = Eigen::Isometry3d::Identity();
  const Eigen::Vector3d r(x[0], x[1], x[2]);
  if (r.norm() > 0.0)
    delta.linear() = Eigen::AngleAxisd(r.norm(), r.normalized()).toRotationMatrix();
  delta.translation() = Eigen::Vector3d(x[3], x[4], x[5]);
  return anchor * delta;
}

}  // namespace kinevis::calibration::internal
