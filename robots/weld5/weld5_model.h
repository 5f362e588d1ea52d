#pragma once

// 5-DOF weld-repair robot (θ1, θ2 rotary; pz3 prismatic; θ4, θ5 rotary) and a generic
// Denavit–Hartenberg chain, after seed 004 §4.1 (eq. 33–46) and §4.2 (eq. 47–50).
//
// D–H convention: seed eq. (34) is the STANDARD (distal) convention,
//   X_{i-1,i} = Rz(θ_i) · Tz(d_i) · Tx(a_i) · Rx(α_i),
// joint i moves about / along z_{i-1}. (The printed matrix of eq. 34 has a typo in entry (2,3):
// it must read −sin α cos θ, as eq. 52 prints it.)
//
// Frames (defined once, here):
//   0  robot base frame (the seed's b with X_b0 = identity); z_0 up, joint 1 turns about z_0.
//   i  D–H frame of link i, i = 1..n; X_0i is its pose in 0.
//   T  torch frame: origin at the torch tip, z_T along the torch axis (pointing out of the torch,
//      towards the work); X_5T is the tool transform, from configuration.
// Joint vector q: revolute entries in rad, prismatic entries in m. Twists are [v; ω]: linear
// velocity of the tool origin and angular velocity, both in frame 0 (m/s, rad/s).
//
// Nothing here allocates: FK, Jacobian and IK use fixed-size Eigen only.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cmath>
#include <cstddef>
#include <string>

namespace kinevis::robots {

// One link of a standard D–H chain. Lengths in m, angles in rad.
// Revolute: θ = q + theta_offset, d fixed. Prismatic: d = q + d (d acts as offset), θ =
// theta_offset.
struct DhJoint {
  double a = 0.0;             // along x_i (the seed's l / px)
  double alpha = 0.0;         // about x_i
  double d = 0.0;             // along z_{i-1} (the seed's pz)
  double theta_offset = 0.0;  // about z_{i-1}
  bool prismatic = false;
};

// Seed eq. (34) (corrected entry (2,3)): Rz(θ) Tz(d) Tx(a) Rx(α) for joint value q.
inline Eigen::Isometry3d DhLinkTransform(const DhJoint& joint, double q) {
  const double theta = joint.prismatic ? joint.theta_offset : q + joint.theta_offset;
  const double d = joint.prismatic ? joint.d + q : joint.d;
  const double ct = std::cos(theta), st = std::sin(theta);
  const double ca = std::cos(joint.alpha), sa = std::sin(joint.alpha);
  Eigen::Matrix4d m;
  m << ct, -ca * st, sa * st, joint.a * ct,  //
      st, ca * ct, -sa * ct, joint.a * st,   //
      0.0, sa, ca, d,                        //
      0.0, 0.0, 0.0, 1.0;
  Eigen::Isometry3d X;
  X.matrix() = m;
  return X;
}

// Seed eq. (33)/(47): X_0n = Π X_{i-1,i}(q_i). Writes the per-link frames X_0i (i = 1..N) to
// X_0L[i-1] when X_0L is not null, and returns X_0n.
template <std::size_t N>
Eigen::Isometry3d DhForwardKinematics(const std::array<DhJoint, N>& joints,
                                      const Eigen::Matrix<double, static_cast<int>(N), 1>& q,
                                      std::array<Eigen::Isometry3d, N>* X_0L = nullptr) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  for (std::size_t i = 0; i < N; ++i) {
    X = X * DhLinkTransform(joints[i], q(static_cast<int>(i)));
    if (X_0L != nullptr) (*X_0L)[i] = X;
  }
  return X;
}

// Geometric Jacobian (6×N) of the frame X_0T = X_0n · X_nT: [v; ω] = J q̇ with v the velocity of
// the tool origin and ω the angular velocity, in frame 0. Column i: revolute
// [z_{i-1} × (p_T − o_{i-1}); z_{i-1}], prismatic [z_{i-1}; 0] (z_0 = e_z, o_0 = 0).
template <std::size_t N>
Eigen::Matrix<double, 6, static_cast<int>(N)> DhGeometricJacobian(
    const std::array<DhJoint, N>& joints, const Eigen::Matrix<double, static_cast<int>(N), 1>& q,
    const Eigen::Isometry3d& X_nT = Eigen::Isometry3d::Identity()) {
  std::array<Eigen::Isometry3d, N> X_0L;
  const Eigen::Isometry3d X_0T = DhForwardKinematics(joints, q, &X_0L) * X_nT;
  const Eigen::Vector3d p_T = X_0T.translation();
  Eigen::Matrix<double, 6, static_cast<int>(N)> J;
  for (std::size_t i = 0; i < N; ++i) {
    const Eigen::Vector3d z =
        i == 0 ? Eigen::Vector3d::UnitZ() : Eigen::Vector3d(X_0L[i - 1].linear().col(2));
    const Eigen::Vector3d o =
        i == 0 ? Eigen::Vector3d::Zero() : Eigen::Vector3d(X_0L[i - 1].translation());
    const int c = static_cast<int>(i);
    if (joints[i].prismatic) {
      J.template block<3, 1>(0, c) = z;
      J.template block<3, 1>(3, c).setZero();
    } else {
      J.template block<3, 1>(0, c) = z.cross(p_T - o);
      J.template block<3, 1>(3, c) = z;
    }
  }
  return J;
}

inline constexpr int kWeld5Joints = 5;
using Vector5d = Eigen::Matrix<double, 5, 1>;
using Matrix65d = Eigen::Matrix<double, 6, 5>;

// Parameters of the weld-repair robot. A value: algorithms take it by const reference.
struct Weld5Model {
  // D–H links 1..5 (seed eq. 34, standard convention). Joint 3 is prismatic (pz3).
  std::array<DhJoint, kWeld5Joints> joints{};
  // Joint limits on q (rad for joints 1, 2, 4, 5; m for joint 3), q_min < q_max.
  Vector5d q_min = Vector5d::Zero();
  Vector5d q_max = Vector5d::Zero();
  // Joint speed limits (rad/s for joints 1, 2, 4, 5; m/s for joint 3), > 0.
  Vector5d qd_max = Vector5d::Zero();
  // Torch tip and axis in link frame 5 (the seed's px5, pz5 and tilt β; from configuration).
  Eigen::Isometry3d X_5T = Eigen::Isometry3d::Identity();

  // Seed 004 parameters in SI: α1 = −89.827°, α2 = 90°, d1 = pz1 = 0.275 m, d2 = pz2 = 0.104718 m,
  // a1 = px1 = −0.059e-3 m, a2 = px2 = 0.033389 m, θ1 offset +0.1097°, θ2 offset +89.602°;
  // α3 = −90°, α4 = +90°, α5 = 0 and zero a, d for links 3–5, which are what eq. (35)–(46)
  // imply (see README.md). Joint and speed limits are not in the seed; these are assumptions,
  // the same as the weld-robot simulator's defaults and robots/weld5/weld5.yaml:
  // θ1 ∈ [−170°, 170°], θ2 ∈ [−120°, 120°], pz3 ∈ [0, 0.50] m, θ4 ∈ [−180°, 180°],
  // θ5 ∈ [−120°, 120°]; 90°/s for the rotary joints, 0.05 m/s for pz3.
  // X_5T is the torch transform given by the caller.
  static Weld5Model Seed(const Eigen::Isometry3d& X_5T);
  // The seed geometry with ideal values as eq. (35)–(46) assume them: α1 = −90°, a1 = 0, both
  // joint offsets 0.
  static Weld5Model Ideal(const Eigen::Isometry3d& X_5T);

  // Empty when usable, otherwise every bad field and its value ("FIELD: RULE, got VALUE"; joints
  // named theta1, theta2, pz3, theta4, theta5): finite D–H parameters, finite limits with
  // q_min < q_max, finite qd_max > 0, and a finite X_5T whose linear part is a rotation.
  // Allocates (the message).
  std::string Validate() const;
};

// Torch transform X_5T from the seed's symbols: tip at (px5, 0, pz5) in frame 5 (m), torch axis
// z_5 tilted by beta (rad) about y_5 (the seed's "rotation of the torch tip frame by β").
Eigen::Isometry3d Weld5TorchTransform(double px5, double pz5, double beta);

// Results of Weld5ForwardKinematics().
struct Weld5Data {
  std::array<Eigen::Isometry3d, kWeld5Joints> X_0L{};      // link frames X_0i, i = 1..5
  Eigen::Isometry3d X_0T = Eigen::Isometry3d::Identity();  // torch frame
  Eigen::Vector3d p_0T = Eigen::Vector3d::Zero();          // torch tip in 0 (m)
  Eigen::Vector3d u_0T = Eigen::Vector3d::UnitZ();         // torch axis z_T in 0 (unit)
  Matrix65d J = Matrix65d::Zero();                         // geometric Jacobian of T
};

// FK of the torch (eq. 33 with X_5T) and its geometric Jacobian. data must not be null.
void Weld5ForwardKinematics(const Weld5Model& model, const Vector5d& q, Weld5Data* data);

struct Weld5IkOptions {
  int max_iterations = 1000;
  double position_tolerance = 1e-9;  // m
  double axis_tolerance = 1e-9;      // rad, angle between torch axis and target axis
  double damping = 1e-3;             // λ of damped least squares (m-or-rad)
  double max_step = 0.2;             // largest |Δq_i| per iteration (rad or m)
  // Further starting points tried when the guess fails, 0..7: θ1 of the guess turned by k·90°
  // (k = 1..3), then the same four θ1 with θ2 and θ4 mirrored (negated, or moved by ±0.8 rad
  // when within 0.2 rad of zero).
  int extra_starts = 7;
};

enum class Weld5IkStatus { kConverged, kNotReachable, kJointLimit };
const char* ToString(Weld5IkStatus status);

struct Weld5IkResult {
  Weld5IkStatus status = Weld5IkStatus::kNotReachable;
  Vector5d q = Vector5d::Zero();  // solution if kConverged; else the last in-limit iterate
                                  // of the solve from q_guess
  int iterations = 0;
  double position_error = 0.0;  // |p_target − p_0T(q)| (m)
  double axis_error = 0.0;      // angle between u_target and u_0T(q) (rad)
  // For kJointLimit: index 0..4 of the joint that must leave its limits, and its name
  // ("theta1", "theta2", "pz3", "theta4", "theta5"); -1 / "" otherwise.
  int limiting_joint = -1;
  const char* limiting_joint_name = "";
  bool converged() const { return status == Weld5IkStatus::kConverged; }
};

// Joint name for index 0..4 ("theta1", "theta2", "pz3", "theta4", "theta5").
const char* Weld5JointName(int joint);

// IK for a torch tip p_0T_target (m, frame 0) and torch axis u_0T_target (frame 0, normalised
// here, must be non-zero); roll about the torch axis is free (5 constraints). Damped least squares
// on the residual r = [p_target − p; e_1ᵀ ε; e_2ᵀ ε] where ε = angle · (u × u_target)/|u ×
// u_target| and e_1, e_2 span the plane ⊥ u, starting from q_guess and keeping q inside the limits.
// kConverged: within tolerances and limits. kJointLimit: the same solve without limits converges,
// but to a q outside them (revolute joints wrapped to (−π, π]); the first offending joint is named.
// kNotReachable: neither converges (e.g. the target is out of the workspace).
Weld5IkResult Weld5InverseKinematics(const Weld5Model& model, const Eigen::Vector3d& p_0T_target,
                                     const Eigen::Vector3d& u_0T_target, const Vector5d& q_guess,
                                     const Weld5IkOptions& options = Weld5IkOptions{});

}  // namespace kinevis::robots
