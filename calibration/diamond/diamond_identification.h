#pragma once

// Kinematic identification of the DIAMOND from one camera (seed 001 §II, §V-B, eq. 2–7 and
// 34–35; issue 8): Levenberg–Marquardt (Ceres) of the radius R, the link arcs α, β, the joint
// offsets and the camera pose relative to the RCM frame O, from joint readings q and the marker's
// measured pixels. calibration/diamond/README.md derives the model, the gauges and the weights.
//
// Model of one sample k (frames: robots/diamond/diamond_model.h, vision/camera/camera_model.h):
//   θ_i = q_i + o_i, (φ, γ) = eq. (34)–(35) on the "+" branch, p_O_T = R u(φ, γ),
//   p_C = X_OC⁻¹ p_O_T, pixel = camera.Project(p_C).
// Residuals (DiamondResidual):
//   kPixel      (measured pixel − predicted pixel) / σ_px: the measurement's own space, the
//               maximum-likelihood choice for Gaussian marker noise (default);
//   kSpherical  the seed's eq. (6): (φ, γ) measured by spherical positioning of the pixel
//               (vision/diamond/spherical_positioning.h, with the current camera pose and R)
//               minus (φ, γ) of eq. (34)–(35), whitened by the 2×2 covariance σ_px² J Jᵀ that
//               the pixel noise gives them (J = ∂(φ,γ)/∂pixel at the initial parameters).
//
// Parameters x (kDiamondParameterCount, in this order; SI):
//   radius R (m), alpha α (rad), beta β (rad),
//   mean_offset m, half_offset_difference h (rad): o_1 = m + h, o_2 = m − h,
//   camera_rotation ω (3, rad): the camera turned about its own centre, in C,
//   camera_direction a, b (rad): its centre moved on the sphere about O, carrying its orientation,
//   camera_distance d (m): |c_O|, the centre's distance from the RCM.
// With X⁰_OC the initial pose, c⁰ its centre, ĉ⁰ = c⁰/|c⁰|, e_1 = unit(z_O × ĉ⁰) (x_O if
// parallel), e_2 = ĉ⁰ × e_1 and G = Exp(a e_1 + b e_2):
//   c_O = d G ĉ⁰,   R_OC = G R⁰_OC Exp(ω).
//
// Gauges (exact symmetries of the measurement; README.md proves them):
//   scale   (R, c_O) → (s R, s c_O) leaves every pixel unchanged (a perspective camera cannot
//           tell a big sphere far away from a small one near): R is identifiable only relative to
//           the camera's distance. Default: d fixed at |c⁰| — the distance must be known (from
//           the camera's extrinsic calibration or measured); an error of ε % in it is an error of
//           exactly ε % in R.
//   azimuth rotating O about z_O by ψ with both offsets +ψ leaves every pixel unchanged: the
//           mean offset m and the camera's azimuth about z_O are one unknown. Default: m fixed at
//           its initial value (the offsets' difference, which moves γ, is identified).
// Freeing a gauge (estimate_camera_distance, estimate_mean_offset) is allowed: the
// identifiability report then finds the rank deficiency and names the combination.
//
// Column scaling (the seed's "extremal scaling", §V-B): the solver works in z with
// x = x⁰ + s ⊙ z, s_j = 1 / max_k |∂r_k/∂x_j| at the start, so that every column of the
// identification Jacobian has the same largest entry and Marquardt's μI damping (eq. 7) treats
// the parameters alike (metres and radians, camera and robot). The identifiability report uses the
// same scaling, recomputed at the solution.
//
// Expected problems (too few samples, no convergence, a rank-deficient or ill-conditioned
// problem, samples that cannot be predicted) are data in the summary; malformed input throws.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <limits>
#include <string>
#include <vector>

#include "calibration/common/estimation.h"
#include "robots/diamond/diamond_model.h"
#include "vision/camera/camera_model.h"

namespace kinevis::calibration {

inline constexpr int kDiamondParameterCount = 11;

enum DiamondParameter : int {
  kDiamondRadius = 0,
  kDiamondAlpha,
  kDiamondBeta,
  kDiamondMeanOffset,
  kDiamondHalfOffsetDifference,
  kDiamondCameraRotationX,
  kDiamondCameraRotationY,
  kDiamondCameraRotationZ,
  kDiamondCameraDirection1,
  kDiamondCameraDirection2,
  kDiamondCameraDistance,
};
// "radius", "alpha", "beta", "mean_offset", "half_offset_difference", "camera_rotation_x",
// "camera_rotation_y", "camera_rotation_z", "camera_direction_1", "camera_direction_2",
// "camera_distance"; "?" outside [0, kDiamondParameterCount).
const char* DiamondParameterName(int parameter);
// "m" or "rad".
const char* DiamondParameterUnit(int parameter);

// One calibration sample: the joint readings and where the marker was seen.
struct DiamondSample {
  Eigen::Vector2d q = Eigen::Vector2d::Zero();      // joint readings q_1, q_2 (rad)
  Eigen::Vector2d pixel = Eigen::Vector2d::Zero();  // marker pixel (px, camera_model.h)
};

enum class DiamondResidual { kPixel, kSpherical };
const char* ToString(DiamondResidual residual);  // "pixel", "spherical"

enum class ColumnScaling {
  kNone,       // x = x⁰ + z (Ceres's own Jacobi scaling on)
  kExtremal,   // s_j = 1 / max_k |J_kj|: the seed's extremal scaling (default)
  kColumnNorm  // s_j = 1 / |J_j|₂
};
const char* ToString(ColumnScaling scaling);  // "none", "extremal", "column-norm"

struct DiamondIdentificationOptions {
  DiamondResidual residual = DiamondResidual::kPixel;
  ColumnScaling scaling = ColumnScaling::kExtremal;
  // A-priori marker noise σ (px), > 0: the residuals' weight. The covariance is scaled by the
  // a-posteriori variance factor, so a wrong σ does not make it wrong, only the cost's units.
  double pixel_sigma = 0.3;
  // Which parameters are estimated (the others stay at their initial values).
  bool estimate_radius = true;
  bool estimate_alpha = true;
  bool estimate_beta = true;
  bool estimate_mean_offset = false;  // azimuth gauge (see the header comment)
  bool estimate_offset_difference = true;
  bool estimate_camera_rotation = true;
  bool estimate_camera_direction = true;
  bool estimate_camera_distance = false;  // scale gauge (see the header comment)
  // Levenberg–Marquardt (Ceres): iterations >= 1, tolerances >= 0.
  int max_iterations = 100;
  double function_tolerance = 1e-12;
  double parameter_tolerance = 1e-12;
  double gradient_tolerance = 1e-14;
  // Identifiability: singular values of the scaled Jacobian below rank_tolerance · σ_max count as
  // zero, in (0, 1); a condition number σ_max/σ_min above warn_condition_number (>= 1) is warned
  // about; |correlations| above warn_correlation (in (0, 1]) are listed.
  double rank_tolerance = 1e-7;
  double warn_condition_number = 1e3;
  double warn_correlation = 0.99;
  // kSpherical: rays at an incidence cosine below this are not used, in [0, 1).
  double min_incidence_cosine = 0.05;
  // Samples needed (after rejections), >= 1; the problem also needs 2·samples >= free parameters.
  int min_samples = 10;

  // Empty when usable, otherwise every bad field and its value.
  std::string Validate() const;
};

// One parameter's estimate.
struct DiamondParameterEstimate {
  double initial = 0.0;
  double value = 0.0;
  // Standard deviation (SI) from the covariance; 0 when not estimated, +inf when estimated but
  // not identified (it has a component in the Jacobian's null space).
  double sigma = 0.0;
  bool estimated = false;
  bool identified = false;
};

// Mean, RMS and largest |value| of residuals per axis ((u, v) in px, or (φ, γ) in rad) over the
// samples used: the seed's Table II.
struct ResidualStatistics {
  int count = 0;
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  Eigen::Vector2d rms = Eigen::Vector2d::Zero();
  Eigen::Vector2d sup = Eigen::Vector2d::Zero();
  double rms_norm = 0.0;  // sqrt(mean of |r|²)
};

// The identifiability of the free parameters (calibration/common/estimation.h), analysed on the
// Jacobian with columns scaled by their largest |entry|; `gauges` names what the options fixed.
using IdentifiabilityReport = Identifiability;

enum class DiamondIdentificationStatus {
  kConverged,
  kNoConvergence,  // iteration limit or the solver stopped without meeting a tolerance
  kTooFewSamples,  // fewer than min_samples usable, or fewer residuals than free parameters
  kNothingToEstimate,
  kSolverFailed,  // Ceres reported failure (e.g. no sample could be predicted)
};
const char* ToString(DiamondIdentificationStatus status);

struct DiamondIdentificationSummary {
  DiamondIdentificationStatus status = DiamondIdentificationStatus::kSolverFailed;
  std::string solver_message;  // Ceres's termination message
  int iterations = 0;
  double initial_cost = 0.0;  // ½ Σ r² of the weighted residuals
  double final_cost = 0.0;
  DiamondResidual residual = DiamondResidual::kPixel;
  ColumnScaling scaling = ColumnScaling::kExtremal;
  double pixel_sigma = 0.0;  // the σ used

  // The identified robot (limits copied from the initial model) and camera pose in O.
  robots::DiamondModel model;
  Eigen::Isometry3d X_OC = Eigen::Isometry3d::Identity();
  std::array<DiamondParameterEstimate, kDiamondParameterCount> parameters{};
  // Covariance of x (SI), kDiamondParameterCount², zero rows/columns for fixed parameters:
  // v̂ (Jᵀ J)⁺ with J the Jacobian of the weighted residuals at the solution and
  // v̂ = 2 final_cost / (residuals − rank) the a-posteriori variance factor.
  Eigen::MatrixXd covariance;
  double variance_factor = 0.0;  // v̂ (≈ 1 when pixel_sigma is the true noise)
  // σ of the joint offsets o_1, o_2 (rad), from the covariance of (m, h).
  std::array<double, robots::kDiamondJoints> offset_sigma{};
  std::array<double, kDiamondParameterCount> column_scale{};  // s used by the solver

  int samples = 0;                    // given
  int samples_used = 0;               // with a prediction at the initial parameters
  std::vector<int> rejected_samples;  // indices into the input
  std::vector<std::string> rejected_reasons;

  ResidualStatistics pixel_residuals;  // measured − predicted pixel (px)
  // Seed Table II: (φ, γ) by spherical positioning of the measured pixel with the identified
  // camera pose and R, minus (φ, γ) of the identified kinematics (rad). Samples whose pixel ray
  // does not meet the sphere are left out (counted in task_residuals.count).
  ResidualStatistics task_residuals;
  std::vector<Eigen::Vector2d> per_sample_pixel_residuals;  // for samples_used, in order

  IdentifiabilityReport identifiability;
  std::vector<std::string> warnings;
  // The same in the estimator contract's shape (parameters named and with units, residuals in
  // px and rad, status converged only when every estimated parameter is identified).
  EstimationReport estimation;

  bool ok() const { return status == DiamondIdentificationStatus::kConverged; }
};

// Identifies the parameters from `samples` seen by `camera` (its intrinsics are known and fixed),
// starting from `initial_model` (R, α, β, joint offsets; its limits are kept) and the camera pose
// X_OC_initial (pose of C in O; with the default gauge its distance from the RCM is kept).
// Throws std::invalid_argument for invalid options or initial model, an X_OC_initial that is not
// a rigid transform or has its centre at the RCM, or a sample with non-finite q or pixel (naming
// its index). Allocates; not for a control cycle.
DiamondIdentificationSummary IdentifyDiamond(const std::vector<DiamondSample>& samples,
                                             const vision::CameraModel& camera,
                                             const robots::DiamondModel& initial_model,
                                             const Eigen::Isometry3d& X_OC_initial,
                                             const DiamondIdentificationOptions& options = {});

// The estimator contract's report of a summary (what IdentifyDiamond puts in `estimation`; the
// file reader uses it for files written before the contract).
EstimationReport DiamondEstimationReport(const DiamondIdentificationSummary& summary);

// The camera pose of parameters x (SI, the order above) for initial pose X_OC_initial.
Eigen::Isometry3d DiamondCameraPoseFromParameters(
    const std::array<double, kDiamondParameterCount>& x, const Eigen::Isometry3d& X_OC_initial);
// x at the initial values: (R, α, β, m, h, 0, 0, 0, 0, 0, |c⁰|).
std::array<double, kDiamondParameterCount> DiamondInitialParameters(
    const robots::DiamondModel& model, const Eigen::Isometry3d& X_OC_initial);

// --- synthetic data, for tests, experiments, benches and a simulated `calibrate` ---------------

// Task points (φ, γ) of a n_phi × n_gamma grid over the model's workspace box (inset by `inset`
// rad on every side) that are in the workspace (robots::CheckWorkspace), whose marker is on the
// camera's side of the sphere and projects into the image at least margin_px from its border.
// n_phi, n_gamma >= 2; throws std::invalid_argument otherwise.
std::vector<Eigen::Vector2d> DiamondVisibleTaskGrid(const robots::DiamondModel& model,
                                                    const vision::CameraModel& camera,
                                                    const Eigen::Isometry3d& X_OC, int n_phi,
                                                    int n_gamma, double inset = 0.02,
                                                    double margin_px = 20.0);

struct DiamondSimulationOptions {
  double pixel_noise_sigma = 0.3;  // Gaussian marker noise per axis (px), >= 0
  double joint_noise_sigma = 0.0;  // Gaussian joint-reading noise (rad), >= 0
  uint64_t seed = 1;
  std::string Validate() const;
};

// Samples of a simulated calibration run: the robot is commanded to each task point with the
// *nominal* model (inverse kinematics gives the joint readings q), the *true* model puts the
// marker where it really is, and the camera at X_OC sees it (true projection + noise). Points
// the nominal model cannot reach, the true model cannot assemble, or that project outside the
// image are skipped. Throws std::invalid_argument for bad options.
std::vector<DiamondSample> SimulateDiamondSamples(const robots::DiamondModel& nominal,
                                                  const robots::DiamondModel& truth,
                                                  const vision::CameraModel& camera,
                                                  const Eigen::Isometry3d& X_OC,
                                                  const std::vector<Eigen::Vector2d>& tasks,
                                                  const DiamondSimulationOptions& options = {});

}  // namespace kinevis::calibration
