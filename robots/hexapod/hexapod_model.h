#pragma once

// Gough–Stewart platform (6-UPS hexapod) kinematics, after seed 002 §III.
//
// Frames (defined once, here):
//   B  base frame, fixed to the base plate; the base joint centres A_j are constant in B.
//   P  platform frame, fixed to the moving platform; the platform joint centres B_j are constant
//      in P. X_BP (Eigen::Isometry3d) is the pose of P in B: p_B = R_BP p_P + p_BP.
//   C  a camera frame rigidly attached to the base; X_CB is the pose of B in C.
// Legs are indexed j = 0..5. Leg j joins A_j to B_j; its length is q_j (m) and its unit direction
// u_j points from A_j towards B_j. The platform twist [v; ω] is the linear velocity of the platform
// origin and the angular velocity of the platform, both expressed in B (m/s, rad/s), unless a
// function says it is expressed in C.
//
// Model: immutable value (HexapodModel); results: HexapodData; algorithms: free functions.
// Nothing here allocates on the heap except Validate(), the *Options::Validate() methods and
// ToString(): the kinematic functions are fixed-size Eigen only.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <string>

namespace kinevis::robots {

inline constexpr int kHexapodLegs = 6;

using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;
using Matrix36d = Eigen::Matrix<double, 3, 6>;

// Parameters of a Gough–Stewart platform. A value: algorithms take it by const reference.
struct HexapodModel {
  // Base joint centres A_j expressed in B (m).
  std::array<Eigen::Vector3d, kHexapodLegs> p_B_A{};
  // Platform joint centres B_j expressed in P (m).
  std::array<Eigen::Vector3d, kHexapodLegs> p_P_B{};
  // Radius of the cylindrical legs (m), > 0. Used by vision (leg edges, seed eq. 3, 12–13).
  double leg_radius = 0.0;
  // Admissible leg length q_j = |A_j B_j| (m): 0 < leg_length_min < leg_length_max.
  double leg_length_min = 0.0;
  double leg_length_max = 0.0;
  // Joint offsets q_j0 (m): leg length when the actuator reading s_j is zero, q_j = q_j0 + s_j.
  std::array<double, kHexapodLegs> q0{};

  // Returns an empty string when the model is usable, otherwise one message naming every bad
  // field and its value (non-finite entries, leg_radius <= 0, bad length limits, non-finite
  // q0, coincident base or platform attachment points).
  std::string Validate() const;

  // A realistic symmetric 6-6 geometry: base radius 0.30 m, platform radius 0.15 m, joints in
  // pairs 120° apart (pair spread 20° on the base, 20° on the platform, platform pairs rotated
  // 60°), nominal height 0.40 m (NominalPose()), leg radius 0.02 m, strokes 0.35–0.55 m,
  // q_j0 = 0.35 m.
  static HexapodModel Default();
  // Pose of P in B for Default(): P parallel to B, 0.40 m above it.
  static Eigen::Isometry3d NominalPose();
};

// Why a leg cannot reach a pose.
enum class LegReach { kOk, kTooShort, kTooLong, kDegenerate };

// Per-leg result of inverse kinematics against the stroke limits.
struct Reachability {
  std::array<LegReach, kHexapodLegs> legs{};
  bool ok() const;
  // Index of the first leg that is not kOk, or -1 when all are.
  int FirstBadLeg() const;
  // E.g. "leg 2 too long (0.61 m > max 0.55 m)"; empty when ok(). Allocates.
  std::string Describe(const HexapodModel& model, const Eigen::Matrix<double, 6, 1>& q) const;
};

// Results of InverseKinematics(); scratch for the Jacobians below.
struct HexapodData {
  Eigen::Isometry3d X_BP = Eigen::Isometry3d::Identity();  // pose the data was computed at
  std::array<Eigen::Vector3d, kHexapodLegs> r_B_PB{};      // R_BP p_P_Bj: P origin to B_j, in B (m)
  std::array<Eigen::Vector3d, kHexapodLegs> p_B_B{};       // B_j in B (m)
  std::array<Eigen::Vector3d, kHexapodLegs> l_B{};         // leg vector A_j -> B_j in B (m)
  Vector6d q = Vector6d::Zero();                           // leg lengths q_j (m)
  std::array<Eigen::Vector3d, kHexapodLegs> u_B{};  // unit directions u_j in B (zero if q_j=0)
  Reachability reach;
  bool valid = false;  // set by InverseKinematics()
};

// Seed 002, eq. (4)–(5): q_j u_j = R_BP p_P_Bj + p_BP − p_B_Aj, written in B. Fills *data and
// returns the per-leg reachability against [leg_length_min, leg_length_max]; a leg of length
// (numerically) zero is kDegenerate and gets u_j = 0. data must not be null.
Reachability InverseKinematics(const HexapodModel& model, const Eigen::Isometry3d& X_BP,
                               HexapodData* data);

// Actuator readings s_j = q_j − q_j0 and back (m).
Vector6d JointPositionsFromLegLengths(const HexapodModel& model, const Vector6d& q);
Vector6d LegLengthsFromJointPositions(const HexapodModel& model, const Vector6d& s);

// Seed 002, eq. (7), with the twist referred to the platform origin: q̇ = D_inv [v; ω] with
// row j = [u_jᵀ, (R_BP p_P_Bj × u_j)ᵀ]. data must come from InverseKinematics() (aborts if not).
Matrix6d InverseDifferential(const HexapodData& data);

// 2-norm condition number σ_max/σ_min of a 6×6 matrix; +inf when σ_min == 0.
double ConditionNumber(const Matrix6d& m);

// Interaction matrix of the leg direction u_j (seed 002 eq. (8)–(9), re-derived, see README.md):
// u̇_j = L_uj [v; ω] with L_uj = (I − u_j u_jᵀ)/q_j · [I₃, −[R_BP p_P_Bj]×], twist in B.
// leg in 0..5; data from InverseKinematics() with q_j > 0 (aborts otherwise).
Matrix36d LegDirectionInteractionMatrix(const HexapodData& data, int leg);

// The same for a camera C fixed to the base: u_j in C is R_CB u_j, and with the twist expressed
// in C ([v_C; ω_C] = blockdiag(R_CB, R_CB) [v; ω], still referred to the platform origin)
// L_uj^C = R_CB L_uj blockdiag(R_BC, R_BC). Only the rotation of X_CB matters.
Matrix36d LegDirectionInteractionMatrixInCamera(const HexapodData& data, int leg,
                                                const Eigen::Isometry3d& X_CB);

struct ForwardKinematicsOptions {
  int max_iterations = 50;
  double residual_tolerance = 1e-12;   // converged when max_j |q_j(X) − q_j| <= this (m)
  double max_condition_number = 1e8;   // above this the Jacobian is treated as singular
  double max_step_translation = 0.05;  // Newton steps are scaled down to these bounds (m)
  double max_step_rotation = 0.2;      // (rad)
  // Empty when usable, otherwise every bad field and its value.
  std::string Validate() const;
};

enum class ForwardKinematicsStatus { kConverged, kMaxIterations, kSingular, kInvalidInput };
const char* ToString(ForwardKinematicsStatus status);

struct ForwardKinematicsSummary {
  ForwardKinematicsStatus status = ForwardKinematicsStatus::kInvalidInput;
  int iterations = 0;           // Newton steps taken
  double residual = 0.0;        // max_j |q_j(X_BP) − q_j| at X_BP (m); NaN for kInvalidInput
  double condition_number = 0;  // of D_inv at X_BP
  // The solution when status == kConverged; otherwise the last iterate, NOT a solution.
  Eigen::Isometry3d X_BP = Eigen::Isometry3d::Identity();
  bool converged() const { return status == ForwardKinematicsStatus::kConverged; }
};

// Forward kinematics: the pose X_BP whose leg lengths are q (m), by Newton iteration from
// X_BP_guess. The increment is a 6-vector [δp; δθ] applied as p_BP += δp, R_BP = exp([δθ]×) R_BP,
// so the Jacobian of q with respect to it is exactly D_inv. Reports kSingular when
// cond(D_inv) exceeds options.max_condition_number, kMaxIterations when the residual did not
// reach the tolerance, kInvalidInput for non-finite or non-positive q, a non-finite guess or
// invalid options. Converges to the assembly mode nearest the guess; stroke limits are not
// enforced (see data->reach). On return *data holds the IK of summary.X_BP. data must not be null.
ForwardKinematicsSummary ForwardKinematics(const HexapodModel& model, const Vector6d& q,
                                           const Eigen::Isometry3d& X_BP_guess,
                                           const ForwardKinematicsOptions& options,
                                           HexapodData* data);

}  // namespace kinevis::robots
