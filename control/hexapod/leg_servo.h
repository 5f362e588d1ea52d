#pragma once

// Leg-direction visual servoing of a Gough–Stewart platform (seed 002 §III, after Andreff and
// Martinet): the six leg directions u_j seen by a camera C fixed to the base are regulated to
// their desired values u_j*, and only the base attachment points A_j expressed in C (the
// calibration parameters, seed §IV) and the leg lengths q_j enter the law.
//
// Frames and conventions (shared by kinevis):
//   C  the camera frame of the CameraModel (for a central catadioptric camera the mirror frame,
//      the seed's F_m). p_C_A[j] = A_j in C (m). X_CB = pose of the base frame B in C.
//   u_j  unit direction of leg j from A_j towards B_j, in C. q_j = |A_j B_j| (m), from the drives
//      as model q0_j + actuator reading s_j (robots::LegLengthsFromJointPositions).
//   τ = [v; ω]  the platform twist EXPRESSED IN C AND REFERRED TO THE ORIGIN OF C: ω the angular
//      velocity, v the velocity of the (platform-fixed) point passing through C's origin (m/s,
//      rad/s). A platform point p (in C) moves with ṗ = v + ω × p. This is the seed's ^mτ_m.
//
// The law (seed eq. 6–9, re-derived; see control/README.md):
//   e   = stack over the visible legs of (u_j − u_j*)               (3 rows per visible leg)
//   L_j = (I − u_j u_jᵀ)/q_j · [I₃, −[A_j + q_j u_j]×]               (ė_j = u̇_j = L_j τ)
//   τ   = −λ L⁺ e                                                    (computed by vpServo)
//   q̇_j = [u_jᵀ, (A_j × u_j)ᵀ] τ                                     (D_inv, seed eq. 7)
// with the measured u_j, the measured q_j and the calibrated A_j (L at the current features:
// vpServo::CURRENT).
//
// No ViSP in this header. LegServo::Compute() allocates (vpServo works on heap matrices); the
// free functions below do not.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <memory>
#include <string>

#include "robots/hexapod/hexapod_model.h"

namespace kinevis::control {

using robots::kHexapodLegs;
using robots::Matrix36d;
using robots::Vector6d;
using LegDirections = std::array<Eigen::Vector3d, kHexapodLegs>;  // unit vectors, in C
using LegPoints = std::array<Eigen::Vector3d, kHexapodLegs>;      // points in C (m)
using LegMask = std::array<bool, kHexapodLegs>;                   // true = leg visible

// Interaction matrix of one leg direction with the twist in C referred to C's origin (seed eq.
// 8–9 re-derived): u̇ = L τ, L = (I − u uᵀ)/q · [I₃, −[p_C_A + q u]×]. u unit, q > 0 (m).
Matrix36d LegDirectionInteractionMatrixAtCameraOrigin(const Eigen::Vector3d& p_C_A,
                                                      const Eigen::Vector3d& u_C, double q);

// Row j of the inverse differential model (seed eq. 7), same twist: q̇_j = [uᵀ, (A × u)ᵀ] τ.
Eigen::Matrix<double, 1, 6> InverseDifferentialRowAtCameraOrigin(const Eigen::Vector3d& p_C_A,
                                                                 const Eigen::Vector3d& u_C);

// The full 6×6 D_inv of eq. 7 from six directions and six attachment points.
robots::Matrix6d InverseDifferentialAtCameraOrigin(const LegPoints& p_C_A,
                                                   const LegDirections& u_C);

// Desired features from a desired platform pose: u_j* = R_CB u_j(X_BP*) by
// robots::InverseKinematics of `model` (in B). Returns the reachability of X_BP* against the
// model's strokes (the directions are filled whatever it says, except for degenerate legs).
// u_C_star must not be null.
robots::Reachability DesiredLegDirections(const robots::HexapodModel& model,
                                          const Eigen::Isometry3d& X_BP_desired,
                                          const Eigen::Isometry3d& X_CB, LegDirections* u_C_star);

// A_j in C from a model in B and a camera pose: p_C_A[j] = X_CB p_B_A[j]. What the seed calls
// the hand-estimated (CAD + measured X_CB) or the CAD + rigid fit (eq. 15) attachment points.
LegPoints AttachmentPointsInCamera(const robots::HexapodModel& model,
                                   const Eigen::Isometry3d& X_CB);

struct LegServoOptions {
  // λ (1/s), > 0: the constant gain, or (adaptive_gain) ignored.
  double gain = 1.0;
  // vpAdaptiveGain λ(x) = (λ0 − λ∞) exp(−λ'0 x / (λ0 − λ∞)) + λ∞ of x = ‖L⁺e‖∞: all > 0,
  // gain_at_zero > gain_at_infinity.
  bool adaptive_gain = false;
  double gain_at_zero = 4.0;
  double gain_at_infinity = 1.0;
  double slope_at_zero = 30.0;
  // Fewest visible legs the law runs with, 3..6 (each leg constrains 2 of the 6 DOF). Below it
  // Compute() refuses (kTooFewLegs) and the caller must hold.
  int min_visible_legs = 3;

  // Empty when usable; otherwise every bad field and its value.
  std::string Validate() const;
};

enum class LegServoStatus {
  kOk,
  kTooFewLegs,     // fewer than min_visible_legs visible: hold
  kRankDeficient,  // rank(L) < 6 for the visible legs (a singular leg arrangement): hold
  kNoDirection,    // a hidden leg was never seen: D_inv has no row for it: hold
  kInvalidInput,   // non-finite or non-unit u, q <= 0, no desired features set: hold
};
const char* ToString(LegServoStatus status);

struct LegServoResult {
  LegServoStatus status = LegServoStatus::kInvalidInput;
  Vector6d twist_C = Vector6d::Zero();  // τ = [v; ω] in C at C's origin (m/s, rad/s)
  Vector6d q_dot = Vector6d::Zero();    // leg rates (m/s); zero unless kOk
  // u_j − u_j* per leg (zero for hidden legs) and the 2-norm of the stacked visible error.
  LegDirections error{};
  double error_norm = 0.0;
  // L⁺e referred to the platform centre c = mean of the B_j = A_j + q_j u_j (in C): [δp (m); δθ
  // (rad)], the first-order platform displacement that would remove e in the least-squares sense,
  // i.e. how far the law still wants to move (τ = −λ · this, for a constant gain, at c). When the
  // desired features are not exactly reachable by the true robot (u* from a model, 12 features for
  // 6 DOF) e does not go to zero but this does. Zero unless kOk.
  Vector6d remaining_displacement = Vector6d::Zero();
  int visible_legs = 0;
  int rank = 0;  // rank of L found by vpServo (6 when kOk)
  // D_inv row of a hidden leg used its last measured direction (the leg was seen before).
  LegMask stale_direction{};
  bool ok() const { return status == LegServoStatus::kOk; }
};

// The stacked interaction matrix (3 rows per visible leg, in leg order) and error e = u − u*.
// Returns the number of rows; L and e must be at least 18 rows (only the first rows are set).
int StackLegServoTask(const LegPoints& p_C_A, const LegDirections& u_C,
                      const LegDirections& u_C_star, const LegMask& visible, const Vector6d& q,
                      Eigen::Matrix<double, 18, 6>* L, Eigen::Matrix<double, 18, 1>* e);

// The control law, with vpServo doing τ = −λ L⁺ e (EYEINHAND_CAMERA with our own L, i.e.
// task Jacobian = L, CURRENT interaction matrix, pseudo-inverse).
class LegServo {
 public:
  // p_C_A: the calibrated attachment points in C. Throws std::invalid_argument with
  // options.Validate()'s message, or naming the non-finite A_j.
  LegServo(const LegPoints& p_C_A, const LegServoOptions& options = {});
  ~LegServo();
  LegServo(const LegServo&) = delete;
  LegServo& operator=(const LegServo&) = delete;

  // Desired features u_j* (unit vectors in C). Throws std::invalid_argument when not finite or
  // not unit (|1 − ‖u‖| > 1e-6).
  void SetDesired(const LegDirections& u_C_star);
  bool has_desired() const { return has_desired_; }
  const LegDirections& desired() const { return u_star_; }
  const LegPoints& attachment_points() const { return p_C_A_; }
  const LegServoOptions& options() const { return options_; }

  // One step of the law at a camera frame: u_C the measured directions (only visible entries
  // are read), q the measured leg lengths (m). Never throws.
  LegServoResult Compute(const LegDirections& u_C, const LegMask& visible, const Vector6d& q);

  // Forgets the last seen directions (a new run).
  void Reset();

 private:
  struct Impl;
  LegPoints p_C_A_;
  LegServoOptions options_;
  LegDirections u_star_{};
  bool has_desired_ = false;
  LegDirections last_seen_{};
  LegMask seen_{};
  std::unique_ptr<Impl> impl_;
};

}  // namespace kinevis::control
