#pragma once

// DIAMOND (ARAS eye-surgery robot) kinematics, after seed 001 §V-B, eq. (34)–(35).
//
// The DIAMOND is a spherical parallelogram: two identical limbs, each a proximal link of arc α and
// a distal link of arc β, share the actuated base axis at one end and the tool (end-effector) axis
// at the other. All joint axes pass through one point, the remote centre of motion (RCM), so the
// tool only rotates about the RCM and its marker moves on a sphere of radius R.
//
// Frames and quantities (defined once, here):
//   O    RCM frame. Origin at the RCM. z_O along the common axis of the two actuated base joints.
//        x_O ⟂ z_O is the zero of the joint angles and of the azimuth φ; y_O = z_O × x_O.
//   q_i  joint readings (rad), i = 1, 2 (index 0, 1 in vectors).
//   θ_i  actuated link angles about z_O, from x_O (rad): θ_i = q_i + joint_offsets[i].
//   w_i  unit elbow axis of limb i in O: w_i = (sα cθ_i, sα sθ_i, cα) (proximal arc α from z_O).
//   u    unit tool axis in O, pointing from the RCM to the marker: u = (sγ cφ, sγ sφ, cγ).
//        Closure: each distal arc is β, w_i · u = cos β.
//   (φ, γ) task coordinates of the seed: φ the azimuth of u about z_O from x_O, γ its polar angle
//        from z_O (rad). The seed's working region is the quarter sphere φ ∈ [0, π],
//        γ ∈ [0, π/2], centred on (π/2, π/4) where its 45° camera looks (seed eq. 11, §V-B).
//   p_O_T tool point T (the marker) in O: p_O_T = R u (m).
//   A    = (θ_1 − θ_2)/2, half the angle between the limbs (rad).
// Assembly mode: limb 1 at the larger angle, θ_1 > θ_2 (A ∈ (0, π)); the model's separation limits
// keep it there. Branch: the "+" sign of eq. (35), the convex (non-colliding) rhombus; see
// README.md and DiamondTaskFromThetas().
//
// Model: immutable value (DiamondModel); results: DiamondData; algorithms: free functions. Nothing
// here allocates on the heap except Validate(), Checked() and Describe(). The maths that
// identification (calibration/diamond) differentiates with Ceres Jets is written once, as the
// templates at the end of this header; the double API below calls them.

#include <Eigen/Core>
#include <array>
#include <string>

namespace kinevis::robots {

inline constexpr int kDiamondJoints = 2;

using Matrix32d = Eigen::Matrix<double, 3, 2>;

// Parameters of a DIAMOND. A value: algorithms take it by const reference.
struct DiamondModel {
  // R (m): distance of the tool point (marker) from the RCM, > 0.
  double radius = 0.0;
  // α (rad): arc of each proximal link, angle between z_O and w_i; in (0, π).
  double alpha = 0.0;
  // β (rad): arc of each distal link, angle between w_i and u; in (0, π), α + β < π.
  double beta = 0.0;
  // θ_i = q_i + joint_offsets[i] (rad), finite. Zero for the seed's sets; identified in
  // calibration.
  std::array<double, kDiamondJoints> joint_offsets{};
  // Mechanical range of θ_i (rad): theta_min[i] < theta_max[i], finite.
  std::array<double, kDiamondJoints> theta_min{};
  std::array<double, kDiamondJoints> theta_max{};
  // Range of the limb separation θ_1 − θ_2 = 2A (rad): 0 < separation_min < separation_max < 2π.
  // Below the minimum the limbs collide (at 0 they coincide: constraint singularity).
  double separation_min = 0.0;
  double separation_max = 0.0;
  // Task workspace box (rad): phi_min < phi_max, 0 <= gamma_min < gamma_max <= π.
  double phi_min = 0.0;
  double phi_max = 0.0;
  double gamma_min = 0.0;
  double gamma_max = 0.0;

  // Empty when usable, otherwise one message naming every bad field and its value.
  std::string Validate() const;
  // Returns model when model.Validate() is empty; throws std::invalid_argument with that message.
  static DiamondModel Checked(const DiamondModel& model);

  // Seed 001, Table I, a priori: R = 0.2000 m, α = β = 0.7854 rad (π/4); zero offsets. Limits
  // (assumptions, the seed gives none; README.md): θ_1 ∈ [0, 3π/2], θ_2 ∈ [−π/2, π],
  // θ_1 − θ_2 ∈ [20°, 170°], workspace φ ∈ [0, π], γ ∈ [30°, 85°].
  static DiamondModel APriori();
  // Seed 001, Table I, identified: R = 0.2221 m, α = 0.7634 rad, β = 0.8037 rad; same limits.
  static DiamondModel SeedIdentified();
};

// Why a configuration or a task point is not acceptable.
enum class DiamondReach {
  kOk,
  kInvalidInput,  // non-finite q or (φ, γ), or a zero tool direction
  kNoAssembly,    // FK: sin²β < (sin α sin A)²: eq. (35) has no real γ, the limbs cannot close
  kUnreachable,   // IK: no A with cos A = (cβ − cα cγ)/(sα sγ) in [−1, 1], or sin γ <= 0
  kFoldedBranchOnly,  // IK: the limbs close there only on the "−" (colliding) branch of eq. (35)
  kBelowThetaMin,     // θ_i < theta_min[i]
  kAboveThetaMax,     // θ_i > theta_max[i]
  kLimbsTooClose,     // θ_1 − θ_2 < separation_min: the limbs collide (or have crossed)
  kLimbsTooFar,       // θ_1 − θ_2 > separation_max
  kPhiOutside,        // φ outside [phi_min, phi_max]
  kGammaOutside,      // γ outside [gamma_min, gamma_max]
};
const char* ToString(DiamondReach reach);

// One violated condition: what, which joint (0, 1; −1 if none), the value and the bound (rad).
struct DiamondIssue {
  DiamondReach reach = DiamondReach::kOk;
  int joint = -1;
  double value = 0.0;
  double bound = 0.0;
};

// Every condition a configuration violates (fixed capacity, no allocation).
struct DiamondReachability {
  static constexpr int kMaxIssues = 8;
  std::array<DiamondIssue, kMaxIssues> issues{};
  int count = 0;

  bool ok() const { return count == 0; }
  bool Has(DiamondReach reach) const;
  // First issue's reason, kOk when ok().
  DiamondReach first() const { return count > 0 ? issues[0].reach : DiamondReach::kOk; }
  // Records an issue (dropped silently beyond kMaxIssues).
  void Add(DiamondReach reach, int joint, double value, double bound);
  // E.g. "theta_1 = 4.9 rad above theta_max[0] = 4.71239 rad; gamma = 1.7 rad outside the
  // workspace (bound 1.48353 rad)"; empty when ok(). Allocates.
  std::string Describe() const;
};

// Results of ForwardKinematics(); input of the Jacobians.
struct DiamondData {
  Eigen::Vector2d q = Eigen::Vector2d::Zero();        // joint readings used (rad)
  Eigen::Vector2d theta = Eigen::Vector2d::Zero();    // θ_i (rad)
  double half_separation = 0.0;                       // A (rad)
  Eigen::Vector2d task = Eigen::Vector2d::Zero();     // (φ, γ) (rad)
  Eigen::Vector3d u_O = Eigen::Vector3d::UnitZ();     // unit tool axis in O
  Eigen::Vector3d p_O_T = Eigen::Vector3d::Zero();    // tool point in O (m)
  std::array<Eigen::Vector3d, kDiamondJoints> w_O{};  // unit elbow axes in O
  double dgamma_dA = 0.0;                             // ∂γ/∂A on the "+" branch
  DiamondReachability reach;
  // True when the closure has a real solution (the fields above hold the pose), even if limits
  // or the workspace box are violated (see reach). False for kInvalidInput and kNoAssembly.
  bool valid = false;
};

// Forward kinematics, seed 001 eq. (34)–(35) on the "+" (collision-free) branch: q → θ, (φ, γ),
// u_O, p_O_T. Reports, in one DiamondReachability, non-finite q, no real solution, θ limits,
// separation limits and a (φ, γ) outside the workspace box. data must not be null.
DiamondReachability ForwardKinematics(const DiamondModel& model, const Eigen::Vector2d& q,
                                      DiamondData* data);

// Inverse kinematics: task = (φ, γ) (rad) → q (rad) on the same branch and assembly mode
// (A = acos((cβ − cα cγ)/(sα sγ)) ∈ [0, π], θ_1 = φ + A, θ_2 = φ − A). Reports non-finite input,
// (φ, γ) outside the box, no solution, a folded-only solution, θ and separation limits. *q is
// written whenever a solution exists (even if limits are violated). q must not be null.
DiamondReachability InverseKinematics(const DiamondModel& model, const Eigen::Vector2d& task,
                                      Eigen::Vector2d* q);

// The same from a tool direction in O (any positive length; normalised here; zero → invalid).
DiamondReachability InverseKinematicsFromDirection(const DiamondModel& model,
                                                   const Eigen::Vector3d& u_O, Eigen::Vector2d* q);

// Whether (φ, γ) is in the workspace: inside the box, reachable on the "+" branch, within the θ
// and separation limits. ok() when it is; otherwise every reason.
DiamondReachability CheckWorkspace(const DiamondModel& model, const Eigen::Vector2d& task);

// d(φ, γ)/dq (2×2): [[1/2, 1/2], [γ_A/2, −γ_A/2]] with γ_A = ∂γ/∂A = sα sA sγ / (sα cA cγ − cα sγ)
// (implicit differentiation of the closure sα cA sγ + cα cγ = cβ). Offsets are additive, so
// d/dq = d/dθ. data from ForwardKinematics() with data.valid (aborts otherwise).
Eigen::Matrix2d TaskJacobian(const DiamondData& data);

// d p_O_T / dq (3×2, m/rad) = R [∂u/∂φ, ∂u/∂γ] · TaskJacobian. data.valid required.
Matrix32d ToolPointJacobian(const DiamondModel& model, const DiamondData& data);

// Where the parallelogram degenerates.
enum class DiamondSingularity {
  kNone,
  kLimbsAligned,  // A → 0 or π: w_1 = ±w_2, the rhombus folds flat; γ_A → 0 (constraint sing.)
  kBranchesMerge,   // the two roots of eq. (35) meet: u in the plane of w_1, w_2; γ_A → ∞
                    // (parallel singularity, boundary of the assembly)
  kToolOnBaseAxis,  // sin γ → 0: φ undefined (a singularity of the coordinates (φ, γ) only)
};
const char* ToString(DiamondSingularity singularity);

struct DiamondSingularityReport {
  DiamondSingularity kind = DiamondSingularity::kNone;
  // σ_max/σ_min of TaskJacobian = max(|γ_A|, 1/|γ_A|); +inf when singular.
  double task_condition = 0.0;
  // σ_max/σ_min of ToolPointJacobian; +inf when singular.
  double point_condition = 0.0;
};

// Condition numbers at data (data.valid required) and, when one exceeds max_condition (> 1), which
// degeneracy causes it.
DiamondSingularityReport AnalyzeSingularity(const DiamondModel& model, const DiamondData& data,
                                            double max_condition = 1e3);

// ---------------------------------------------------------------------------------------------
// Scalar-generic maths (T = double or ceres::Jet; both tested). Functions are found by
// argument-dependent lookup, so Jets use their own sin, cos, atan2, acos, sqrt. Comparisons
// (branch and existence tests) use the value part only, as Jets do.

enum class DiamondSolve { kOk, kNoSolution, kFoldedBranchOnly };

// Seed 001 eq. (34)–(35): φ = (θ_1 + θ_2)/2 and, with A = (θ_1 − θ_2)/2, the closure
// w_i · u = cβ reads sα cA sγ + cα cγ = cβ, i.e. ρ cos(γ − γ_m) = cβ with
// ρ = sqrt((sα cA)² + c²α), γ_m = atan2(sα cA, cα). Its two roots γ_m ± acos(cβ/ρ) are eq. (35)
// (tangent half-angle form, equal for α + β < π; tested). We take γ = γ_m + acos(cβ/ρ), the "+"
// root: u and z_O are then on opposite sides of the plane of w_1 and w_2, the spherical rhombus
// z_O–w_1–u–w_2 is convex and the limbs stay apart; the "−" root folds the distal links back over
// the proximal ones (for α = β it is γ = 0, links on top of each other), which the seed excludes
// for collision. Returns kNoSolution (outputs untouched) when |cβ| > ρ, i.e. s²β < (sα sA)².
template <typename T>
DiamondSolve DiamondTaskFromThetas(const T& alpha, const T& beta, const T& theta1, const T& theta2,
                                   T* phi, T* gamma) {
  using std::acos;
  using std::atan2;
  using std::cos;
  using std::sin;
  using std::sqrt;
  const T half = (theta1 - theta2) / 2.0;
  const T a = sin(alpha) * cos(half);  // sα cA
  const T b = cos(alpha);              // cα
  const T rho = sqrt(a * a + b * b);
  const T ratio = cos(beta) / rho;
  if (ratio > 1.0 || ratio < -1.0) return DiamondSolve::kNoSolution;
  *phi = (theta1 + theta2) / 2.0;
  *gamma = atan2(a, b) + acos(ratio);
  return DiamondSolve::kOk;
}

// Inverse of DiamondTaskFromThetas on the same branch and assembly mode (θ_1 ≥ θ_2):
// cos A = (cβ − cα cγ)/(sα sγ), θ_1 = φ + A, θ_2 = φ − A. kNoSolution when sin γ <= 0 or
// |cos A| > 1; kFoldedBranchOnly when (φ, γ) is on the "−" root for that A (cα sγ < sα cA cγ);
// outputs written only for kOk.
template <typename T>
DiamondSolve DiamondThetasFromTask(const T& alpha, const T& beta, const T& phi, const T& gamma,
                                   T* theta1, T* theta2) {
  using std::acos;
  using std::cos;
  using std::sin;
  const T s_gamma = sin(gamma);
  if (!(s_gamma > 0.0)) return DiamondSolve::kNoSolution;
  const T c_gamma = cos(gamma);
  const T cos_half = (cos(beta) - cos(alpha) * c_gamma) / (sin(alpha) * s_gamma);
  if (cos_half > 1.0 || cos_half < -1.0) return DiamondSolve::kNoSolution;
  if (cos(alpha) * s_gamma - sin(alpha) * cos_half * c_gamma < 0.0) {
    return DiamondSolve::kFoldedBranchOnly;
  }
  const T half = acos(cos_half);
  *theta1 = phi + half;
  *theta2 = phi - half;
  return DiamondSolve::kOk;
}

// Unit tool axis u(φ, γ) in O.
template <typename T>
Eigen::Matrix<T, 3, 1> DiamondToolAxis(const T& phi, const T& gamma) {
  using std::cos;
  using std::sin;
  Eigen::Matrix<T, 3, 1> u;
  u << sin(gamma) * cos(phi), sin(gamma) * sin(phi), cos(gamma);
  return u;
}

// Tool point p_O_T = R u(φ, γ) (m).
template <typename T>
Eigen::Matrix<T, 3, 1> DiamondToolPoint(const T& radius, const T& phi, const T& gamma) {
  Eigen::Matrix<T, 3, 1> p = DiamondToolAxis<T>(phi, gamma);
  for (int k = 0; k < 3; ++k) p[k] = radius * p[k];
  return p;
}

// Forward kinematics from joint readings with offsets, for identification: θ_i = q_i + offset_i,
// then DiamondTaskFromThetas and DiamondToolPoint. p_O_T written only for kOk.
template <typename T>
DiamondSolve DiamondToolPointFromJoints(const T& radius, const T& alpha, const T& beta,
                                        const T& offset1, const T& offset2, const T& q1,
                                        const T& q2, T* phi, T* gamma,
                                        Eigen::Matrix<T, 3, 1>* p_O_T) {
  const DiamondSolve solve =
      DiamondTaskFromThetas<T>(alpha, beta, q1 + offset1, q2 + offset2, phi, gamma);
  if (solve == DiamondSolve::kOk) *p_O_T = DiamondToolPoint<T>(radius, *phi, *gamma);
  return solve;
}

}  // namespace kinevis::robots
