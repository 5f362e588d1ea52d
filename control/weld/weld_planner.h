#pragma once

// Weld repair path planning from a scanned map (issue 7; seed 004 §1, §5.3: a map in the robot
// base frame, then "offline programming of robot welding tasks" filling cavitation damage in
// layers). docs/weld-paths.md describes the method, the output file and the defaults.
//
//   map (points in 0) → reference surface (reference_surface.h, robust, pits excluded)
//     → depth grid in R → damaged regions (depth > threshold, 8-connected, tiny ones rejected)
//     → layers of layer_height per region, bottom first → beads per layer (raster or zig-zag at a
//       step-over of (1 − overlap)·bead_width, optional contour pass), footprint extended by
//       margin → ordered (nearest neighbour + 2-opt) → lead-in, lead-out, approach, retract,
//       transits → inverse kinematics (robots/weld5) with limit and joint-speed checks → a timed
//       joint trajectory in the robot's segment format (hal/weld/weld_robot_client.h).
//
// Frames: 0 the robot base, R the reference surface's frame (reference_surface.h), T the torch
// (weld5_model.h: z_T along the torch axis, out of the torch towards the work).
// Torch targets: a bead point lies on the DEPOSITION SURFACE of its layer, at depth
//   δ = min(layer bottom depth, substrate depth)        (both below the reference, ≥ 0)
// under the reference point P(u, v), with the substrate depth from the smoothed depth grid (the
// cavity floor, or the reference outside the damage). The torch tip is at stand-off along the
// reference normal n(u, v) above it and the torch axis is −n (pointing into the work):
//   p_0T = P(u, v) + (stand_off − δ) · n(u, v),    u_0T = −n(u, v).
// Roll about the torch axis is free (5 axes): IK chooses it.
//
// Errors (STYLE.md): bad options or a malformed map throw std::invalid_argument at set-up, naming
// every bad field and value. Everything the data can make go wrong — nothing to repair, a
// degenerate map, unreachable beads, joint-speed limits — is data in WeldPlan::summary.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cmath>
#include <cstddef>
#include <string>
#include <vector>

#include "control/weld/reference_surface.h"
#include "control/weld/torch_ik.h"
#include "hal/weld/weld_robot_client.h"
#include "robots/weld5/weld5_model.h"

namespace kinevis::control {

// A scanned map: points in the robot base frame 0 (m), optionally with unit normals out of the
// material (empty, or one per point).
struct WeldMap {
  std::vector<Eigen::Vector3d> p_0;
  std::vector<Eigen::Vector3d> n_0;
};

enum class BeadPattern {
  kRaster,  // one straight bead per pass, arc off between passes (stringer beads)
  kZigZag,  // consecutive passes joined at their ends into one continuous bead where possible
};
const char* ToString(BeadPattern pattern);  // "raster", "zigzag"

// The GMAW set-points written with the plan (and streamed by weld-run). Used by the planner only
// to check that the deposit they imply matches the layer height (a warning otherwise).
struct WeldProcess {
  double wire_diameter = 1.0e-3;        // m, (0, 3 mm]
  double wire_feed_speed = 0.058;       // m/s (3.5 m/min), > 0
  double current = 140.0;               // A, > 0
  double voltage = 21.0;                // V, > 0
  double deposition_efficiency = 0.95;  // fraction of the wire that stays in the bead, (0, 1]
};

struct WeldPlanOptions {
  // Reference surface fit (degree, robust constants, out-of-material side).
  ReferenceFitOptions reference;
  // Depth grid in R: cell size (m), [0.05, 5] mm; each cell's depth is the median of its points.
  double grid_cell = 0.5e-3;
  // Damage: depth below the reference beyond this (m), [0.05, 10] mm.
  double depth_threshold = 0.5e-3;
  // Regions smaller than this area (m²) are rejected with a reason (noise, outliers, pitting too
  // small to weld: blend it by grinding), >= 0.
  double min_region_area = 2e-6;

  // Beads and layers.
  double bead_width = 6e-3;  // m, [1, 30] mm
  double overlap = 0.4;      // fraction of the bead width two neighbouring passes share, [0, 0.8]
  double layer_height = 1.5e-3;  // m, [0.2, 10] mm
  double margin = 3e-3;          // footprint extension beyond the damage (m), [0, 50] mm
  BeadPattern pattern = BeadPattern::kRaster;
  bool contour_pass = true;  // one pass along each layer footprint's boundary, inset w/2
  // Pass direction in R (rad about z_R from x_R); NaN: along each layer footprint's long axis.
  double raster_angle = std::nan("");
  bool alternate_layers = true;  // turn the pass direction 90° from one layer to the next
  bool allow_reversal = true;    // the ordering may weld a pass either way

  // Torch motion.
  double stand_off = 15e-3;     // contact-tip-to-work distance along the torch axis (m), [3, 40] mm
  double travel_speed = 8e-3;   // welding speed (m/s), [1, 30] mm/s
  double air_speed = 50e-3;     // speed of the arc-off moves (m/s), [5, 500] mm/s
  double clearance = 20e-3;     // retract height above the stand-off for air moves (m), [2, 200] mm
  double lead_in = 4e-3;        // arc-on run-up before a pass (m), [0, 30] mm
  double lead_out = 4e-3;       // arc-on run-out after a pass (crater fill) (m), [0, 30] mm
  double point_spacing = 1e-3;  // distance between points along a pass (m), [0.2, 10] mm
  double transit_spacing = 10e-3;  // distance between waypoints of air moves (m), [1, 100] mm

  WeldProcess process;

  // Robot. The torch IK (torch_ik.h: tolerances, and the largest torch tilt from the normal the
  // arm may use where it cannot hold the normal exactly) and the robot's joints when the plan
  // starts (rad, rad, m, rad, rad; within the model's limits).
  TorchIkOptions ik;
  robots::Vector5d q_start = (robots::Vector5d() << 0.0, 0.0, 0.2, 0.0, 0.0).finished();
  // Air moves run at most at this fraction of each joint's qd_max, (0, 1].
  double air_joint_speed_fraction = 0.5;
  // Longest segment the robot accepts (s), [0.01, 60] (hal::WeldRobotIdentity::
  // max_segment_duration); longer air segments are split (in joint space).
  double max_segment_duration = 1.0;
  // Largest deviation (m) of the joint-space interpolated torch tip from the straight segment
  // between two arc-on points before it is reported, > 0.
  double max_interpolation_error = 0.2e-3;

  // Empty when usable, else every bad field and its value ("bead_width = 0.0001 m (1..30 mm)").
  std::string Validate() const;
};

// The depth grid in R: cell (i, j) covers u ∈ [u0 + i·cell, u0 + (i+1)·cell), v likewise.
struct DepthGrid {
  double u0 = 0.0, v0 = 0.0, cell = 0.0;  // m
  int nu = 0, nv = 0;
  std::vector<float> depth;     // median depth of the cell's points (m), NaN: no data; nu·nv
  std::vector<float> smoothed;  // 3×3 mean of the finite depths around (m), NaN: none; nu·nv
  std::vector<int> count;       // points per cell
  std::vector<int> region;      // region id (>= 0) of a damaged cell, −1 otherwise
  int index(int i, int j) const { return j * nu + i; }
  Eigen::Vector2d Centre(int i, int j) const {
    return Eigen::Vector2d(u0 + (i + 0.5) * cell, v0 + (j + 0.5) * cell);
  }
  // Bilinear in the smoothed depth, 0 outside the grid or where it has no data.
  double SubstrateDepth(double u, double v) const;
};

struct DamageRegion {
  int id = 0;
  int cells = 0;
  double area = 0.0;       // m²
  double max_depth = 0.0;  // m (of the cell medians)
  double mean_depth = 0.0;
  double volume = 0.0;  // Σ depth · cell area (m³): what the layers must fill
  Eigen::Vector3d centroid_0 = Eigen::Vector3d::Zero();  // on the reference surface (m, in 0)
  Eigen::Vector2d deepest_uv = Eigen::Vector2d::Zero();  // the deepest cell's centre in R (m)
  bool touches_map_edge = false;                         // the damage may continue beyond the scan
};

struct RejectedRegion {
  int cells = 0;
  double area = 0.0;  // m²
  double max_depth = 0.0;
  Eigen::Vector3d centroid_0 = Eigen::Vector3d::Zero();
  std::string reason;  // "area 0.75 mm² < min_region_area 2 mm²"
};

enum class WeldPointKind {
  kTransit,   // air move between passes, at clearance
  kApproach,  // above the start of the pass, at clearance
  kLeadIn,    // arc on, run-up
  kWeld,      // arc on, the pass itself
  kLeadOut,   // arc on, run-out
  kRetract,   // above the end of the pass, at clearance
};
const char* ToString(WeldPointKind kind);  // "transit", "approach", "lead_in", ...

struct WeldPoint {
  WeldPointKind kind = WeldPointKind::kWeld;
  Eigen::Vector2d uv_R = Eigen::Vector2d::Zero();  // where on the reference (m, in R)
  double depth = 0.0;  // depth δ of the deposition surface below the reference (m)
  Eigen::Vector3d p_0S = Eigen::Vector3d::Zero();  // the deposition surface point (m, in 0)
  // The planned torch axis: −n, the reference normal into the work (unit, in 0).
  Eigen::Vector3d u_0T = Eigen::Vector3d::UnitZ();
  // Tip-to-work distance along the torch axis (m): stand_off, or stand_off + clearance for the
  // arc-off points above the work.
  double stand_off = 0.0;
  // The torch tip (m, in 0): before IK p_0S − stand_off · u_0T; after IK (when reachable) the
  // tip the arm holds, p_0S − stand_off · u_0T_achieved (the wire still hits p_0S).
  Eigen::Vector3d p_0T = Eigen::Vector3d::Zero();
  Eigen::Vector3d u_0T_achieved = Eigen::Vector3d::UnitZ();  // the arm's torch axis at q
  double tilt = 0.0;    // angle between u_0T_achieved and u_0T (rad), <= ik.max_tilt
  bool arc_on = false;  // the arc burns on the way to this point from the previous one
  double speed = 0.0;   // planned tool speed to this point (m/s): travel_speed or air_speed
  // Torch IK (SolveTorchIk, warm-started along the path).
  robots::Weld5IkStatus ik = robots::Weld5IkStatus::kNotReachable;
  robots::Vector5d q = robots::Vector5d::Zero();  // rad, rad, m, rad, rad
  double ik_position_error = 0.0;                 // |wire point − p_0S| (m)
  std::string limiting_joint;                     // for kJointLimit: "theta1", ..., "theta5"
  bool reachable() const { return ik == robots::Weld5IkStatus::kConverged; }
};

enum class BeadKind { kRaster, kZigZag, kContour };
const char* ToString(BeadKind kind);  // "raster", "zigzag", "contour"

struct WeldBead {
  int id = 0;  // unique in the plan, in welding order of its layer
  BeadKind kind = BeadKind::kRaster;
  // Approach … retract (preceded by the transits from the previous executed bead, if any).
  std::vector<WeldPoint> points;
  double weld_length = 0.0;  // arc-on path length (m)
  bool reachable = false;    // every point reached by IK within the limits
  bool executable = false;   // reachable and in the trajectory
  std::string problem;       // why not executable, naming the point, place and joint
};

struct WeldLayer {
  int index = 0;           // 0 = the bottom layer (welded first)
  double depth_top = 0.0;  // the slice it fills: depths [depth_top, depth_bottom] (m)
  double depth_bottom = 0.0;
  double footprint_area = 0.0;  // m², with the margin
  std::vector<WeldBead> beads;  // in welding order
};

struct WeldRegionPlan {
  DamageRegion region;
  std::vector<WeldLayer> layers;  // bottom first
};

// Where a trajectory segment's target came from.
struct TrajectorySource {
  int region = -1, layer = -1, bead = -1, point = -1;  // indices into WeldPlan::regions etc.
};

enum class WeldPlanStatus {
  kPlanned,          // every bead reachable and in the trajectory
  kPartial,          // some beads unreachable: listed in summary.problems, not in the trajectory
  kNothingToRepair,  // empty map, or no region deeper than the threshold that is big enough
  kFailed,           // the map does not determine a reference surface (degenerate), or no bead
                     // is reachable
};
const char* ToString(WeldPlanStatus status);  // "planned", "partial", "nothing to repair", ...

struct WeldPlanSummary {
  WeldPlanStatus status = WeldPlanStatus::kFailed;
  std::string message;  // one line: what was planned, or why nothing
  size_t map_points = 0;
  int regions = 0, rejected_regions = 0, layers = 0, beads = 0, executable_beads = 0;
  int points = 0, unreachable_points = 0;
  double damaged_area = 0.0;           // m², accepted regions
  double coverage = 0.0;               // FillCoverage over all beads, accepted regions
  double coverage_executable = 0.0;    // over the executable beads only
  double weld_length = 0.0;            // m, executable beads
  double arc_time = 0.0;               // s
  double total_time = 0.0;             // s, the whole trajectory
  double max_joint_speed_ratio = 0.0;  // max over segments and joints of |q̇| / qd_max
  double max_tilt = 0.0;   // largest torch tilt from the normal over the executable beads (rad)
  double mean_tilt = 0.0;  // mean over their points (rad)
  double max_interpolation_error = 0.0;  // m, arc-on segments
  int speed_limited_segments = 0;        // arc-on segments slowed below travel_speed by qd_max
  std::vector<std::string> problems;     // unreachable beads, each naming where and why
  std::vector<std::string> warnings;     // fit warnings, edge regions, speed limits, process, ...
};

struct WeldPlan {
  WeldPlanOptions options;
  robots::Weld5Model model;  // the robot the IK used
  ReferenceFit reference;
  DepthGrid grid;
  std::vector<WeldRegionPlan> regions;
  std::vector<RejectedRegion> rejected;
  // What the robot consumes (hal::WeldRobotClient::StreamTrajectory), from options.q_start, and
  // where each segment's target came from (same size; point −1 for split pieces' inner targets
  // keep the source of the target they lead to).
  std::vector<hal::WeldTrajectoryPoint> trajectory;
  std::vector<TrajectorySource> trajectory_source;
  WeldPlanSummary summary;
};

// Plans the repair of `map` for `model`. Throws std::invalid_argument with options.Validate()'s
// message, for a model whose limits are not usable (q_min >= q_max, qd_max <= 0), for q_start
// outside the limits, or when map.n_0 is neither empty nor of map.p_0's size.
// Allocates; a million-point map takes well under a second (bench/weld_plan_bench.cc).
WeldPlan PlanWeldRepair(const WeldMap& map, const robots::Weld5Model& model,
                        const WeldPlanOptions& options = {});

// Fill coverage (issue 7, experiment 3): the fraction of the damaged cells of the accepted
// regions (depth > threshold) whose centre lies within bead_width/2 of an arc-on segment of at
// least one bead (executable beads only when `executable_only`). 1 when there is no damage.
double FillCoverage(const WeldPlan& plan, bool executable_only = false);

// Executed-versus-planned stand-off. One executed torch pose per trajectory target (e.g. the
// joints read back from the robot after each segment, through the TRUE forward kinematics).
struct ExecutedTorchPose {
  size_t trajectory_index = 0;  // into WeldPlan::trajectory
  Eigen::Isometry3d X_0T = Eigen::Isometry3d::Identity();
};
struct StandOffSample {
  size_t trajectory_index = 0;
  double path_position = 0.0;  // arc-on path length from the first compared sample (m)
  double stand_off = 0.0;      // executed: along the executed torch axis to the deposition
                               // surface (the reference offset by the planned δ) (m)
  double error = 0.0;          // stand_off − options.stand_off (m)
  double axis_error = 0.0;     // angle between the executed and the planned torch axis (rad)
};
struct StandOffComparison {
  std::vector<StandOffSample> samples;  // arc-on targets only, in trajectory order
  double mean_abs_error = 0.0, rms_error = 0.0, max_abs_error = 0.0;  // m
  double path_length = 0.0;                                           // m
  int skipped = 0;  // poses that were not arc-on targets or whose axis missed the surface
};
// Throws std::invalid_argument when a trajectory_index is out of range.
StandOffComparison CompareStandOff(const WeldPlan& plan,
                                   const std::vector<ExecutedTorchPose>& executed);

}  // namespace kinevis::control
