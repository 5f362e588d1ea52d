#pragma once

// Edges (limbs) of the cylindrical legs of a Gough–Stewart platform in a grey image, for leg-
// direction visual servoing and for calibration (issue 6 "Vision", seed 002 §II-C, §IV-A).
//
// One algorithm for every central camera (pinhole/Brown, Tsai, unified catadioptric): the edges
// are searched in the image around the PREDICTED limb curve, along the image rows or columns of a
// fixed pixel grid that cross it, located to sub-pixel by a model of a cylinder's limb (a step
// with the √ shading ramp inside it), every edge point is back-projected to a unit ray, and the
// limb is fitted as a plane through the viewpoint — a great circle on the unit sphere, normal =
// smallest eigenvector of Σ w_i r_i r_iᵀ — robustly (RANSAC start, then IRLS with Tukey or Huber
// weights on the point-to-curve distance in pixels).
// For a perspective camera this is a straight-line fit; for the unified model it is the fit of the
// line's conic (seed eq. 1–2) done on the sphere, so eq. (10) is never inverted on noisy conics.
//
// Frames and conventions (shared by the issue-6 helpers, see README.md):
//   C  the camera frame of the CameraModel, its viewpoint at the origin (for the unified model the
//      mirror frame, the seed's F_m). A central model whose rays do not start at the origin of C
//      is refused.
//   Limb normals n1_C, n2_C: unit normals of the two interpretation planes tangent to the leg
//      cylinder, oriented so that the leg's axis lies on their NEGATIVE side (n_i · p_C_A = −R,
//      seed eq. 12–13): each normal points away from the leg. Limb 0 is eq. (3)'s first line,
//      limb 1 the second, exactly as render::PredictCylinderLimbs() labels them.
//   Leg direction u_C: unit vector from A_j towards B_j (eq. 11 up to sign; with eq. 3's labels
//      n1 × n2 ∝ −u, and the sign is taken from the prediction, never from the image).
//   Pixels as in camera_model.h: (0, 0) is the centre of the top-left pixel.
//
// Cost and allocation: FitLimbPlane() does not allocate. FindLimbEdgePoints() appends to a
// caller-owned vector (no allocation once its capacity suffices). ObserveLegs() with a
// LegEdgeWorkspace does not allocate after the first frame (the workspace keeps its buffers and
// the reason strings their capacity).

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cstddef>
#include <string>
#include <vector>

#include "vision/camera/camera_model.h"
#include "vision/image/image_view.h"

namespace kinevis::vision::hexapod {

inline constexpr int kLegs = 6;

// A prediction of one leg, in C: from the nominal model and the commanded pose, or from the
// previous frame. May be off by a few centimetres / degrees (the search window must cover it).
struct LegPrediction {
  Eigen::Vector3d p_C_A = Eigen::Vector3d::Zero();  // base joint centre A_j (m)
  Eigen::Vector3d p_C_B = Eigen::Vector3d::Zero();  // platform joint centre B_j (m)
  double radius = 0.0;                              // leg radius R (m), > 0
};

// The six legs of `model` with the platform at X_BP (pose of P in B) seen from a camera at X_CB
// (pose of B in C): A_j = X_CB p_B_A[j], B_j = X_CB X_BP p_P_B[j], R = model.leg_radius.
// LegModel: any type with p_B_A and p_P_B (six points each, m, in B and in P) and leg_radius (m),
// e.g. robots::HexapodModel; vision/ knows legs only as cylinders between two points.
template <typename LegModel>
std::array<LegPrediction, kLegs> PredictLegs(const LegModel& model, const Eigen::Isometry3d& X_BP,
                                             const Eigen::Isometry3d& X_CB) {
  static_assert(std::tuple_size_v<decltype(model.p_B_A)> == kLegs, "six legs");
  std::array<LegPrediction, kLegs> legs;
  const Eigen::Isometry3d X_CP = X_CB * X_BP;
  for (int j = 0; j < kLegs; ++j) {
    legs[j].p_C_A = X_CB * model.p_B_A[j];
    legs[j].p_C_B = X_CP * model.p_P_B[j];
    legs[j].radius = model.leg_radius;
  }
  return legs;
}

// Which way the grey level steps across a limb, seen from outside the leg.
enum class EdgePolarity {
  kBrightLeg,  // the leg is brighter than what is beside it (the simulator's legs)
  kDarkLeg,    // the leg is darker
  kEither,
};

enum class RobustLoss { kTukey, kHuber };

// How an edge is located to sub-pixel along its search line (README "Edge locator").
enum class EdgeLocator {
  // Least-squares fit of a pixel-integrated step with the √(distance) shading ramp every cylinder
  // has just inside its limb, blurred by LegEdgeOptions::edge_blur_px: unbiased when that blur is
  // the image's (0 for the renderer's sharp images).
  kStepRamp,
  // Vertex of the parabola through the central-difference gradient peak: exact for a bare
  // anti-aliased step, but pulled up to ~0.1 px into a shaded leg. Insensitive to blur: the
  // choice when the image's blur is not known.
  kParabola,
};

struct LegEdgeOptions {
  // Stage 1 (search). Half-length (px, measured across the predicted limb curve; the row or column
  // searched is longer by 1/cos) of the search segment in the first pass: 48 px covers a 2 cm
  // prediction error at 1 m with f ≈ 2000 px plus some orientation error. (0, 256].
  double search_half_width_px = 48.0;
  // Second pass: the search is repeated around the curve of the first fit over ± this (px);
  // 0 = single pass. [0, search_half_width_px].
  double refine_half_width_px = 4.0;
  // Spacing of the search lines (px), > 0, rounded to a whole number >= 1: the edges are searched
  // along the image rows (where the limb curve is closer to vertical) or columns whose index is a
  // multiple of it, on whole pixels, so the edge points do not move with the prediction.
  double sample_step_px = 4.0;
  // Length at each end of the predicted leg not searched (m, >= 0): the ends (joints, plates,
  // the open end of the tube) are not limbs, and the prediction of A_j, B_j may be off.
  double end_margin = 0.03;
  // Smallest accepted grey-level gradient along the search line (grey levels per px, > 0).
  double min_gradient = 8.0;
  // Sub-pixel locator of the final pass (the first, wide pass of a two-pass ObserveLegs only
  // guides the second and always uses kParabola).
  EdgeLocator locator = EdgeLocator::kStepRamp;
  // kStepRamp: σ (px) of the optics' Gaussian blur (point spread function) the model includes, in
  // [0, 3]; 0 = a sharp image (the renderer's default). Set it to the camera's: left at 0 on an
  // image blurred by σ = 1 px the edges come out ~0.3 px too far out (README "Edge locator").
  double edge_blur_px = 0.0;
  EdgePolarity polarity = EdgePolarity::kBrightLeg;
  // Other legs' silhouettes, widened by this margin (px, >= 0), are kept out of the search: a
  // search position on another leg's silhouette is skipped (occluded when that leg is nearer,
  // "against another leg" when it is behind, where the limb's contrast is leg against leg), and
  // the search segment is cut where it enters another silhouette.
  double occlusion_margin_px = 3.0;
  // Stage 2 (fit). A limb needs at least this many edge points, and this many inliers (>= 3).
  int min_points = 10;
  RobustLoss loss = RobustLoss::kTukey;
  // RANSAC start: hypotheses from point pairs (>= 0; 0 = start from the plain least squares)
  // and the inlier threshold (px, > 0) used to score them.
  int ransac_hypotheses = 48;
  double ransac_threshold_px = 2.0;
  // IRLS: robust scale σ = max(1.4826 · MAD, min_scale_px) of the pixel residuals; the Tukey
  // cut-off is 4.685 σ, the Huber corner 1.345 σ (95 % efficiency at Gaussian noise).
  double min_scale_px = 0.25;  // > 0
  int max_iterations = 20;     // >= 1
  // A fit is rejected when more than this fraction of the points are outliers ([0, 1)) or the
  // inlier RMS distance to the fitted curve exceeds max_rms_px (> 0).
  double max_outlier_fraction = 0.5;
  double max_rms_px = 1.5;
  // Leg level (ObserveLegs). A limb is "occluded" when more than this fraction of its in-view
  // search positions are on other legs' silhouettes (occluded or against_leg) ((0, 1]).
  double max_occluded_fraction = 0.5;
  // The two fitted limbs must subtend the angle a cylinder of the predicted radius and distance
  // would, within this relative error (> 0): catches a limb fitted to a neighbour's edge.
  double max_width_error = 0.35;
  // eq. (11) is refused when |n1 × n2| is below this (the limb planes are nearly parallel: the
  // leg is seen end-on or is far away), in (0, 1).
  double min_limb_separation = 1e-3;

  // Empty when usable, otherwise one message naming every bad field and its value.
  std::string Validate() const;
};

// One edge point: where it is in the image and the ray it sees. ray_C and d_ray_d_pixel must be
// those of `pixel` (use MakeEdgePoint() after moving a pixel).
struct EdgePoint {
  Eigen::Vector2d pixel = Eigen::Vector2d::Zero();
  Eigen::Vector3d ray_C = Eigen::Vector3d::UnitZ();  // unit direction of the pixel's ray, in C
  Matrix32d d_ray_d_pixel = Matrix32d::Zero();       // ∂ray_C/∂(u, v) (per px)
  double gradient = 0.0;                             // gradient across the edge (grey levels/px)
  // Written by FitLimbPlane(): the final robust weight (0 = rejected as an outlier) and whether
  // the point counts as an inlier.
  double weight = 0.0;
  bool inlier = false;
};

// Back-projects `pixel` into *point (pixel, ray, Jacobian; gradient kept). False when the camera
// cannot back-project the pixel or the model is not central at the origin of C.
bool MakeEdgePoint(const CameraModel& camera, const Eigen::Vector2d& pixel, EdgePoint* point);

// Another leg, as occluder or background of the limb searched: its prediction and, when it has
// been measured in this frame, its fitted limb normals (then its silhouette is taken from them,
// which is sub-pixel; from the prediction it is off by the prediction's error).
struct OtherLeg {
  LegPrediction prediction;
  bool measured = false;
  Eigen::Vector3d n1_C = Eigen::Vector3d::Zero();  // outward limb normals (the conventions above)
  Eigen::Vector3d n2_C = Eigen::Vector3d::Zero();
};
inline constexpr size_t kMaxOtherLegs = 15;

// What stage 1 did at the search positions of one limb.
struct LimbSearchStats {
  int samples = 0;      // search positions along the predicted limb
  int out_of_view = 0;  // outside the image or the camera model's domain, or behind the camera
  int occluded = 0;     // behind another leg
  int against_leg = 0;  // in front of another leg, or boxed in between other legs' silhouettes
  int no_edge = 0;      // no gradient peak of the right polarity above min_gradient
  int found = 0;        // edge points appended
};

// Stage 1: edge points of limb `limb` (0 or 1) of the leg `prediction`, appended to *points.
// The search lines are the image rows (where the curve is closer to vertical) or columns whose
// index is a multiple of sample_step_px (rounded) that cross the projection of the predicted limb
// generator A + R n_i + t (B − A) (t in the leg minus end_margin at each end); on each the edge is
// the largest gradient of the right polarity within ± search_half_width_px / cos θ of the crossing
// (θ <= 45°: the line's angle to the curve's normal), read at whole pixels and located to
// sub-pixel by options.locator (README "Edge locator"). Positions
// on the silhouette of one of the `others` (count `other_count` <= kMaxOtherLegs; must not
// include the leg itself) or whose search segment leaves the image or the model's domain are
// skipped; the segment is cut where it enters another leg's silhouette.
// refine_n_C: when not null, a limb-plane normal from a previous fit: the search positions are
// moved onto that plane's curve and searched over ± refine_half_width_px only.
// Throws std::invalid_argument for invalid options, an image that is null or not camera-sized,
// a non-central camera, limb not in {0, 1}, or too many others. An unusable prediction
// (non-finite, radius <= 0, viewpoint inside the cylinder) gives no points and stats.samples = 0.
LimbSearchStats FindLimbEdgePoints(const vision::ImageView8& image, const CameraModel& camera,
                                   const LegPrediction& prediction, int limb,
                                   const OtherLeg* others, size_t other_count,
                                   const LegEdgeOptions& options, std::vector<EdgePoint>* points,
                                   const Eigen::Vector3d* refine_n_C = nullptr);

struct LimbFit {
  bool ok = false;
  Eigen::Vector3d n_C = Eigen::Vector3d::Zero();  // unit; predicted axis on its negative side
  int points = 0;                                 // edge points given
  int inliers = 0;                                // points within the robust cut-off
  double rms_px = 0.0;      // RMS distance (px) of the inliers to the fitted curve
  double scale_px = 0.0;    // final robust scale σ (px)
  int iterations = 0;       // IRLS iterations
  const char* reason = "";  // why not ok (static text), "" when ok
};

// Stage 2: the interpretation plane of one limb from its edge points, robustly. The residual of a
// point is its distance (px) to the fitted curve, to first order (n · r_i) / |d_ray_d_pixelᵀ n|.
// The sign of n is fixed so that the midpoint of the predicted axis is on its negative side.
// Start: n_start when not null (a previous fit; the RANSAC start is skipped), else the best of
// options.ransac_hypotheses point-pair planes, else plain least squares.
// Writes each point's weight and inlier flag. Does not allocate (up to 1024 points; more use a
// slower median). Not ok (with a reason) when there are fewer than min_points points or inliers,
// too many outliers, or the inlier RMS is above max_rms_px. Throws std::invalid_argument for
// invalid options or a null `points`.
LimbFit FitLimbPlane(std::vector<EdgePoint>* points, const LegPrediction& prediction,
                     const LegEdgeOptions& options, const Eigen::Vector3d* n_start = nullptr);

// Seed 002 eq. (11): the leg direction from its two limb normals, u = ±(n1 × n2)/|n1 × n2|, the
// sign chosen so that u · u_pred > 0 (u_pred: the predicted A → B direction, need not be unit).
// False (and *u untouched) when |n1 × n2| < min_separation or u_pred is zero/orthogonal.
bool LegDirectionFromLimbs(const Eigen::Vector3d& n1_C, const Eigen::Vector3d& n2_C,
                           const Eigen::Vector3d& u_pred_C, Eigen::Vector3d* u_C,
                           double min_separation = 1e-3);

enum class LegStatus {
  kVisible,
  kBadPrediction,     // prediction not finite, radius <= 0, or viewpoint inside the cylinder
  kOutOfView,         // too few search positions in the image / model domain
  kOccluded,          // mostly behind (or seen against) other legs
  kTooFewEdgePoints,  // the edge was not found at enough positions
  kFitRejected,       // the robust fit failed (too many outliers, RMS too large)
  kInconsistent,      // the two limbs do not bound a cylinder of the predicted apparent width
  kParallelLimbs,     // eq. (11) undefined: the limb planes are (nearly) parallel
};
std::string_view ToString(LegStatus status);

struct LegObservation {
  bool visible = false;
  LegStatus status = LegStatus::kBadPrediction;
  // Names the leg and why it is not visible, e.g. "leg 3: occluded (limb 0: of 108 search
  // positions in view, 108 behind other legs, 0 against another leg)"; empty when visible.
  std::string reason;
  std::array<LimbSearchStats, 2> search{};
  std::array<LimbFit, 2> limbs{};
  Eigen::Vector3d u_C = Eigen::Vector3d::Zero();  // A → B, unit, when visible
};

// Buffers reused from frame to frame (ObserveLegs does not allocate once they have grown).
struct LegEdgeWorkspace {
  LegEdgeWorkspace();
  std::array<std::array<std::vector<EdgePoint>, 2>, kLegs> points;
  std::array<LegObservation, kLegs> observations;
};

// Both stages for the six legs in two rounds: (1) per limb a wide search around the prediction
// (other legs' silhouettes from their predictions) and a robust fit; (2) per limb a narrow search
// around that fit (other legs' silhouettes from their round-1 fits where they have one) and the
// final fit; then the width check and eq. (11). Throws std::invalid_argument as
// FindLimbEdgePoints(). The result lives in *workspace (also returned).
const std::array<LegObservation, kLegs>& ObserveLegs(
    const vision::ImageView8& image, const CameraModel& camera,
    const std::array<LegPrediction, kLegs>& predictions, const LegEdgeOptions& options,
    LegEdgeWorkspace* workspace);

// Stage 2 and the leg checks again on the edge points now held in *workspace, after the caller
// edited them (removed clutter, or — issue 6's accuracy experiment — added noise and outliers):
// for every leg that ObserveLegs() reported visible, both limbs are refitted from scratch (MSAC
// start, not the previous fit), then the apparent-width check and eq. (11) as in ObserveLegs().
// Legs not visible are left as they are; a leg can become not visible (with a reason). The
// points' rays must match their pixels (MakeEdgePoint). Does not allocate while the reasons fit
// their capacity. Throws std::invalid_argument for invalid options or a null workspace.
const std::array<LegObservation, kLegs>& RefitObservedLegs(
    const std::array<LegPrediction, kLegs>& predictions, const LegEdgeOptions& options,
    LegEdgeWorkspace* workspace);

// Convenience form (allocates its own workspace).
std::array<LegObservation, kLegs> ObserveLegs(const vision::ImageView8& image,
                                              const CameraModel& camera,
                                              const std::array<LegPrediction, kLegs>& predictions,
                                              const LegEdgeOptions& options = {});

}  // namespace kinevis::vision::hexapod
