#pragma once

// A RoboCup middle-size-league field seen by the robot's own non-single-viewpoint catadioptric
// camera (seed 000, the CAMBADA robot; vision/camera/hyperbolic_mirror_camera.h), issue 5.
//
// Frames:
//   C  the camera model's frame: origin at the pinhole, y_C up along the mirror axis, z_C the
//      robot's forward direction (hyperbolic_mirror_camera.h).
//   G  the camera's ground frame (same header): origin where the mirror axis meets the ground,
//      x_G forward, y_G left, z_G up. X_CG is taken from the camera.
//   F  the field frame: origin at the field's centre spot, x_F along the field's length (towards
//      the "right" goal), y_F along its width, z_F up. The robot stands at X_FG = (x, y, heading):
//      p_F = R_z(heading) p_G + (x, y, 0).
//
// The field (all centre-line coordinates; every line is `line_width` wide, centred on them):
//   length 18 m × width 12 m (the MSL field of the CAMBADA era, 2008–2012), outer lines at
//   x_F = ±9, y_F = ±6; halfway line x_F = 0; centre circle radius 0.5 m (1 m diameter, issue 5;
//   the MSL's own circle is 4 m); goal areas 0.75 m deep × 3.5 m wide and penalty areas 2.25 m deep
//   × 6.5 m wide at both ends (MSL rules); lines 5 cm wide (issue 5; the MSL's are 12.5 cm). Green
//   carpet extends `carpet_border` beyond the outer lines; beyond that the hall's floor.
// The robot (all around the mirror axis, in G): a dark body, a cylinder of radius body_radius from
//   the ground to body_height with a top disc; the lens body, a cylinder of radius lens_radius from
//   the body top to the pinhole with a front disc at the pinhole's height; `post_count` mirror
//   posts, thin vertical cylinders (radius post_radius) at post_ring_radius from the mirror axis
//   from the pinhole's height up to the mirror surface, the first at azimuth post_azimuth from
//   x_G (robot forward) towards y_G, the others evenly spaced.
//
// Trace(ray): the ray is the camera's back-projected one: its origin M on the mirror and the
// reflected direction. First the segment pinhole → M is checked against the posts (a post in front
// of the mirror hides that part of it; Hit.depth is then 0); then the reflected ray meets the
// nearest of posts, lens body, robot body and ground (carpet, line or floor; Hit.depth its ray
// parameter). A reflected ray that reaches none (at or above the horizon) sees the hall's
// surroundings (`surroundings` radiance, object kFieldSurroundings, depth +inf).
// Pixels the camera cannot back-project (beyond the mirror rim: they see the rim, the lens body
// and the robot's interior) are never traced: the renderer draws them as background, radiance 0,
// which is what they look like (dark). Use SoccerFieldScene::kBackgroundRadiance when composing.
// Radiances (grey, exposure 1): line 0.85, carpet 0.3 (green's grey level), floor 0.45, body 0.06,
// lens 0.04, posts 0.12, surroundings 0.5.
//
// Trace() does not allocate; the scene is immutable and thread-safe.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "vision/camera/hyperbolic_mirror_camera.h"
#include "vision/render/renderer.h"

namespace kinevis::vision::render {

enum SoccerFieldObject : int {
  kFieldBackground = 0,
  kFieldCarpet = 1,
  kFieldLine = 2,
  kFieldFloor = 3,         // the hall's floor beyond the carpet
  kFieldSurroundings = 4,  // nothing on the ground: at or above the horizon
  kFieldRobotBody = 5,
  kFieldLensBody = 6,
  kFieldMirrorPost = 7,
};

struct SoccerFieldSceneParameters {
  // Field (m).
  double field_length = 18.0;
  double field_width = 12.0;
  double line_width = 0.05;
  double centre_circle_radius = 0.5;  // to the line's centre
  double goal_area_depth = 0.75;
  double goal_area_width = 3.5;
  double penalty_area_depth = 2.25;
  double penalty_area_width = 6.5;
  double carpet_border = 1.0;
  // Robot pose on the field: G's origin in F (m) and heading of x_G from x_F (rad).
  double robot_x = 0.0;
  double robot_y = 0.0;
  double robot_heading = 0.0;
  // Robot (m), around the mirror axis.
  double body_radius = 0.22;  // CAMBADA: ≈ 0.485 m across
  double body_height = 0.30;  // < the pinhole's height; the ground is then seen from ≈ 0.38 m
  double lens_radius = 0.025;
  int post_count = 3;  // 0..8
  double post_radius = 0.0025;
  double post_ring_radius = 0.033;  // must leave the posts outside the lens body
  double post_azimuth = M_PI / 2;
  // Radiances in [0, 1].
  double line_radiance = 0.85;
  double carpet_radiance = 0.3;
  double floor_radiance = 0.45;
  double body_radiance = 0.06;
  double lens_radiance = 0.04;
  double post_radiance = 0.12;
  double surroundings_radiance = 0.5;

  // Empty when usable, otherwise every bad field and its value.
  std::string Validate() const;
};

// What the ground truth says about one ground point.
struct FieldPoint {
  Eigen::Vector2d p_F = Eigen::Vector2d::Zero();  // (x_F, y_F) (m)
  double line_distance = 0.0;  // distance from the nearest line's centre-line (m)
  bool on_line = false;        // line_distance ≤ line_width / 2
  bool on_carpet = false;      // within the carpet (else the floor)
};

class SoccerFieldScene final : public Scene {
 public:
  static constexpr double kBackgroundRadiance = 0.0;

  // Copies what it needs of `camera` (X_CG, the mirror's geometry). Throws std::invalid_argument
  // naming every bad field, also when the body reaches above the pinhole or the posts cut the
  // lens body.
  SoccerFieldScene(const HyperbolicMirrorCamera& camera,
                   const SoccerFieldSceneParameters& parameters);

  Hit Trace(const Ray& ray_C) const override;
  void TraceBatch(const RayBatch& rays, Hit* hits) const override;  // exactly Trace() per ray
  // The camera-fixed part (renderer.h): the robot's body, lens body and mirror posts ride with the
  // camera, and the robot moves in the ground plane, so every ray sees the same part of the robot,
  // or meets the ground at the same point of G, in every frame. The key is a hash of that geometry
  // in C and of the robot's radiances; a ray that sees the robot, or nothing, is kConstant, one
  // that meets the ground is kSurface with surface = (x_G, y_G) (m); ShadeSurface() says what lies
  // at a ground point for this scene's robot pose (line, carpet or floor).
  uint64_t CameraFixedKey() const override { return camera_fixed_key_; }
  void TraceCameraFixed(const RayBatch& rays, CameraFixedHit* out) const override;
  void ShadeSurface(const Eigen::Vector2d* points_G, int count, Hit* hits) const override;

  const SoccerFieldSceneParameters& parameters() const { return parameters_; }
  const Eigen::Isometry3d& X_CG() const { return X_CG_; }
  // Pose of G in F (planar).
  const Eigen::Isometry3d& X_FG() const { return X_FG_; }

  // Ground truth of a ground point given in G (x_G, y_G).
  FieldPoint ClassifyGround(const Eigen::Vector2d& p_G_xy) const;
  // Distance (m) of a field point from the nearest line's centre-line.
  double LineDistance(const Eigen::Vector2d& p_F) const;
  // The posts' axes in C: bottom and top points of post i (0 ≤ i < post_count).
  void PostAxis(int i, Eigen::Vector3d* bottom_C, Eigen::Vector3d* top_C) const;

 private:
  SoccerFieldSceneParameters parameters_;
  Eigen::Isometry3d X_CG_;
  Eigen::Isometry3d X_GC_;
  Eigen::Isometry3d X_FG_;
  double pinhole_height_ = 0.0;  // above ground along z_G (m)
  std::array<Eigen::Vector3d, 8> post_bottom_C_;
  std::array<Eigen::Vector3d, 8> post_top_C_;
  Eigen::Vector3d lens_bottom_C_;
  // Field line centre-line segments in F (outer lines, halfway line, goal and penalty areas).
  std::array<Eigen::Vector4d, 17> segments_F_;  // (x0, y0, x1, y1)

  // Conservative culls for Trace() (issue 5's frame-time target; each only skips a test whose
  // exact primitive would report no hit, so the result is unchanged):
  // the pinhole → mirror segment can meet a post only if the mirror point is at least this far
  // (squared, m²) from y_C; a ray meets a post only if it comes within post_cull_radius2_ of its
  // axis, the lens body (or its disc) only if its part below the pinhole comes within
  // lens_cull_radius2_ of y_C, the robot body (cylinder and top disc) only if its part below the
  // body's top comes within body_cull_radius2_ of the body's axis.
  std::array<double, 8> post_length_{};  // post axes' lengths along y_C (m), lens body's
  double lens_length_ = 0.0;
  // The body's axis is exactly y_C (untilted ground): IntersectCylinderAlongY gives the same bits.
  bool body_along_y_ = false;
  double body_length_ = 0.0;
  std::array<double, 8> post_x_{};  // post axes' x_C and z_C (m)
  std::array<double, 8> post_z_{};
  double incoming_post_cull_radius2_ = 0.0;
  double post_cull_radius2_ = 0.0;
  double lens_cull_radius2_ = 0.0;
  double body_cull_radius2_ = 0.0;
  Eigen::Matrix<double, 2, 3> R_GC_xy_ = Eigen::Matrix<double, 2, 3>::Zero();  // x, y rows of X_GC
  Eigen::Vector2d t_GC_xy_ = Eigen::Vector2d::Zero();
  Eigen::Matrix2d R_FG_xy_ = Eigen::Matrix2d::Identity();   // X_FG's rotation (about z_F)
  Eigen::Vector3d body_axis_C_ = Eigen::Vector3d::UnitY();  // z_G in C, unit
  Eigen::Vector3d body_bottom_C_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d body_top_C_ = Eigen::Vector3d::Zero();
  // A uniform grid over the carpet in F: per cell, bit k set when segment k may lie within half a
  // line width of the cell, bit 17 likewise for the centre circle. Only those are measured. All
  // segments are parallel to x_F or y_F (the field's lines).
  static constexpr int kCircleBit = 17;
  static constexpr double kLineCellSize = 0.125;     // m
  std::array<Eigen::Vector4d, 17> segment_boxes_F_;  // (x_min, y_min, x_max, y_max) of each
  double circle_inner2_ = 0.0;  // (centre_circle_radius ∓ line_width / 2)², inner clamped at 0
  double circle_outer2_ = 0.0;
  std::vector<uint32_t> line_cells_;
  int line_cells_x_ = 0;
  int line_cells_y_ = 0;
  double line_cells_x0_ = 0.0;  // F coordinates of the grid's lower corner (m)
  double line_cells_y0_ = 0.0;

  // on_line of ClassifyGround() for a point on the carpet, through the grid.
  bool OnLine(const Eigen::Vector2d& p_F) const;
  uint64_t camera_fixed_key_ = 0;
  // The robot's part of Trace(): the nearest hit of posts, lens body and robot body on the
  // reflected ray (*t, *object; kNoHit and kFieldSurroundings for none). True when a post hides
  // the mirror point (the pinhole → mirror segment meets it): the hit is then that post.
  bool TraceRobot(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double* t, int* object) const;
  // The camera-fixed part of Trace() of the ray from o along d (both in C): the robot's hit, the
  // surroundings, or the ground point (x_G, y_G).
  CameraFixedHit TraceFixed(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const;
  // Radiance and object of the ground at (x_G, y_G) for this robot pose (hit->depth untouched).
  void ShadeGround(const Eigen::Vector2d& p_G, Hit* hit) const;
};

}  // namespace kinevis::vision::render
