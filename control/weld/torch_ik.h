#pragma once

// Torch inverse kinematics for weld paths on the 5-DOF weld robot (robots/weld5/weld5_model.h).
//
// Why not robots::Weld5InverseKinematics alone: on this arm the torch axis depends on θ1 and
// θ2 + θ4 only (seed eq. 37, 41, 45: a = (c1 s24, s1 s24, c24)), so for a fixed axis the tip can
// only move within ±px5 of a plane offset by pz2 (≈ 105 mm) from the base axis: an exact surface
// normal is reachable on a narrow strip only. Welders accept a torch tilt (travel or work angle)
// of several degrees, so this solver treats the contact point as the hard task and the axis as the
// soft one:
//
//   task 1 (exact):    w(q) = p_0T(q) + d · u_0T(q) = p_0W     (the wire, d out of the tip along
//                      the torch's actual axis, hits the work point p_0W)
//   task 2 (minimal):  the angle between u_0T(q) and the planned axis u_target
//
// solved by task-priority Gauss–Newton (Siciliano–Slotine): Δq = J_w⁺ r_w + N (J_a N)⁺ (r_a −
// J_a J_w⁺ r_w), N = I − J_w⁺ J_w, with J_w = J_v − d [u]× J_ω (ẇ = v + d ω × u), J_a = [e1ᵀ; e2ᵀ]
// J_ω (e1, e2 ⊥ u), damped pseudo-inverses, steps ≤ max_step, joints clamped to their limits.
// The axis reaches u_target exactly where the arm can; elsewhere it stays at the smallest tilt the
// arm allows from there, accepted up to max_tilt. Whatever the tilt, the stand-off d is measured
// along the actual torch axis, so it is constant.
//
// Frames and units as in weld5_model.h: positions in 0 (m), q in rad / m.

#include <Eigen/Core>

#include "robots/weld5/weld5_model.h"

namespace kinevis::control {

struct TorchIkOptions {
  double position_tolerance = 1e-7;       // |w(q) − p_0W| accepted (m), > 0
  double axis_tolerance = 1e-6;           // tilt below this counts as exact (rad), > 0
  double max_tilt = 10.0 * M_PI / 180.0;  // largest accepted tilt (rad), [0, 30°]
  int max_iterations = 100;               // per start, >= 1
  double damping = 1e-5;                  // λ of the damped pseudo-inverses, >= 0
  double max_step = 0.2;                  // largest |Δq_i| per iteration (rad or m), > 0
  int extra_starts = 7;                   // restarts when the guess fails, as Weld5IkOptions
};

struct TorchIkResult {
  robots::Weld5IkStatus status = robots::Weld5IkStatus::kNotReachable;
  robots::Vector5d q = robots::Vector5d::Zero();
  double position_error = 0.0;                      // |w(q) − p_0W| (m)
  double tilt = 0.0;                                // angle between u_0T(q) and u_target (rad)
  Eigen::Vector3d p_0T = Eigen::Vector3d::Zero();   // the tip at q (m, in 0)
  Eigen::Vector3d u_0T = Eigen::Vector3d::UnitZ();  // the torch axis at q
  int iterations = 0;
  int limiting_joint = -1;  // kJointLimit: the joint (0..4) that would leave its limits
  bool converged() const { return status == robots::Weld5IkStatus::kConverged; }
};

// The wire point w(q) = p_0T + d u_0T and its Jacobian J_w (3×5) = J_v − d [u]× J_ω.
Eigen::Vector3d WirePoint(const robots::Weld5Model& model, const robots::Vector5d& q, double d,
                          Eigen::Matrix<double, 3, 5>* J_w = nullptr);

// Solves for the torch with its wire d (m, >= 0) out of the tip along its axis hitting p_0W, the
// axis as close to u_target (unit, in 0) as the arm allows, from q_guess. kConverged: position
// within tolerance, tilt <= max_tilt, joints within limits. kJointLimit: an unclamped solve meets
// both but leaves the limits (revolute joints wrapped to (−π, π]), the joint is named.
// kNotReachable otherwise. Allocates nothing.
TorchIkResult SolveTorchIk(const robots::Weld5Model& model, const Eigen::Vector3d& p_0W,
                           const Eigen::Vector3d& u_target, double d,
                           const robots::Vector5d& q_guess, const TorchIkOptions& options = {});

}  // namespace kinevis::control
