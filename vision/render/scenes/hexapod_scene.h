#pragma once

// The Gough–Stewart platform as a camera sees it (issue 5, seed 002): six open cylinders of the
// model's leg_radius from A_j to B_j, optional base and platform plates, and a uniform background.
// Used with a perspective camera outside the legs and with a unified (central catadioptric) camera
// between them, looking up from the base.
//
// Frames as in robots/hexapod/hexapod_model.h: B the base, P the platform (pose X_BP), C the
// camera (X_CB = pose of B in C). The scene is built in C.
//
// Object ids (Hit::object and the ground truth): 0 background, 1..6 leg j = 0..5 (id = j + 1),
// kBasePlateId, kPlatformPlateId.
//
// A leg is the part of its cylinder between the base plate's plane and the platform plate's plane
// when the plates are on (it ends flush with each plate, the ends being ellipses, as where a real
// leg meets its joint housing; at a grazing angle it is also cut perpendicularly one radius beyond
// where its axis crosses the plate, instead of running along it), and ends at A_j or B_j with a
// cut perpendicular to its axis at a plate that is off. Its limbs (below) do not depend on where
// it ends.
//
// Radiance (documented choice): the legs are BRIGHTER than the background. A leg point with
// outward normal n has radiance leg_ambient + leg_diffuse · max(0, n · l) (Lambertian with an
// ambient term, l = unit direction towards the light), so a limb — where n is perpendicular to the
// viewing ray and may face away from the light — still has at least leg_ambient, well above
// background_radiance: both limb edges of every leg have contrast ≥ leg_ambient −
// background_radiance (0.4 with the defaults). Plates are flat (plate_radiance).
//
// Leg edges (limbs): for a central camera with its viewpoint at the origin of C, the two edges of
// leg j are the images of the planes through the viewpoint tangent to the cylinder (the
// interpretation planes, seed 002 eq. (3)); PredictLegLimbs() gives their unit normals, the ground
// truth for leg-edge extraction (issue 6). A point X on the image of an edge satisfies n · X = 0.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <string>

#include "robots/hexapod/hexapod_model.h"
#include "vision/render/renderer.h"

namespace kinevis::vision::render {

inline constexpr int kBasePlateId = 7;
inline constexpr int kPlatformPlateId = 8;

struct HexapodSceneOptions {
  // Plates: discs in the planes z_B = 0 and z_P = 0, centred on the frame origins, with radius
  // (largest joint radius) + plate_margin (m, >= 0). They are two-sided and flat-shaded.
  bool base_plate = true;
  bool platform_plate = true;
  double plate_margin = 0.05;
  // Radiances in [0, 1].
  double background_radiance = 0.15;
  double leg_ambient = 0.55;
  double leg_diffuse = 0.35;  // leg_ambient + leg_diffuse <= 1
  double plate_radiance = 0.35;
  // Direction towards the light, in B (need not be unit; non-zero).
  Eigen::Vector3d light_direction_B = Eigen::Vector3d(0.4, -0.3, 1.0);

  // Empty when usable, otherwise every bad field and its value.
  std::string Validate() const;
};

// The pose X_WC of a perspective-convention camera (z forward, y down in the image) at `eye_W`
// looking at `target_W`, with the image's up direction as close to `up_W` as possible. Aborts if
// eye == target or the viewing direction is parallel to up.
Eigen::Isometry3d CameraLookingAt(const Eigen::Vector3d& eye_W, const Eigen::Vector3d& target_W,
                                  const Eigen::Vector3d& up_W);

// Unit normals (in C) of the two interpretation planes tangent to a cylinder of `radius` around
// the line through p_C_A and p_C_B, for a central camera whose viewpoint is the origin of C. Seed
// 002 eq. (3). Returns false (and leaves the outputs unspecified) when the viewpoint is inside the
// cylinder or on its axis (no tangent plane), or the points coincide.
bool PredictCylinderLimbs(const Eigen::Vector3d& p_C_A, const Eigen::Vector3d& p_C_B, double radius,
                          Eigen::Vector3d* n1_C, Eigen::Vector3d* n2_C);

class HexapodScene final : public Scene {
 public:
  // Throws std::invalid_argument naming every bad field of the model (HexapodModel::Validate is
  // not called: only p_B_A, p_P_B and leg_radius are used and checked here) and of the options.
  HexapodScene(const robots::HexapodModel& model, const Eigen::Isometry3d& X_BP,
               const Eigen::Isometry3d& X_CB, const HexapodSceneOptions& options = {});

  Hit Trace(const Ray& ray_C) const override;
  void TraceBatch(const RayBatch& rays, Hit* hits) const override;  // exactly Trace() per ray

  // Leg j's end points in C (m), j = 0..5.
  const Eigen::Vector3d& p_C_A(int leg) const { return legs_[leg].a; }
  const Eigen::Vector3d& p_C_B(int leg) const { return legs_[leg].b; }
  double leg_radius() const { return radius_; }
  const HexapodSceneOptions& options() const { return options_; }

  // The two limb planes of leg j seen from the origin of C (PredictCylinderLimbs).
  bool PredictLegLimbs(int leg, Eigen::Vector3d* n1_C, Eigen::Vector3d* n2_C) const;

 private:
  struct Leg {
    Eigen::Vector3d a, b;  // end points in C
    Eigen::Vector3d w;     // unit axis a -> b
    double length = 0.0;
    Eigen::Vector3d m0;  // w × (0 − a): moment of the axis about the origin of C
    // For rays from the origin of C: o_perp = component of (0 − a) normal to the axis,
    // c0 = |o_perp|² − R², along0 = (0 − a) · w.
    Eigen::Vector3d o_perp;
    double c0 = 0.0, along0 = 0.0;
    // Bounding cone from the origin of C (apex there, around the leg's bounding sphere): a ray
    // from the origin with d · cone_axis < cone_cos misses the leg. cone_cos = -1 (no culling)
    // when the origin is inside the sphere.
    Eigen::Vector3d cone_axis = Eigen::Vector3d::UnitZ();
    double cone_cos = -1.0;
    // The leg is the part of its cylinder inside two half-spaces cut_normal[k] · p ≤ cut_offset[k]
    // (p in C): k = 0 the base end, k = 1 the platform end. With the plate on, the half-space is
    // the plate plane's side the leg is on (the leg ends flush with the plate); with it off, the
    // plane through A_j (B_j) perpendicular to the axis. The clipped leg lies within
    // along_lo ≤ (p − a) · w ≤ along_hi (a cheap test before the half-spaces).
    Eigen::Vector3d cut_normal[2];
    double cut_offset[2] = {0.0, 0.0};
    double along_lo = 0.0, along_hi = 0.0;
  };
  struct Plate {
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();  // in C
    Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
    double radius = 0.0;
    double n_dot_c = 0.0;                                  // normal · centre
    Eigen::Vector3d cone_axis = Eigen::Vector3d::UnitZ();  // bounding cone, as for Leg
    double cone_cos = -1.0;
  };
  // Whether a point on leg's cylinder lies within the leg's ends.
  static bool InsideCuts(const Leg& leg, const Eigen::Vector3d& p_C);
  // Nearest plate hit with t < *t_best (updates it) of the ray from o along d (in C); returns the
  // plate's id or 0. central_at_origin: o is the origin of C.
  int TracePlate(const Plate& plate, int id, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                 bool central_at_origin, double* t_best) const;
  // Trace() of the ray from o along d (in C).
  Hit TraceRay(const Eigen::Vector3d& o, const Eigen::Vector3d& d, bool central_at_origin) const;
  HexapodSceneOptions options_;
  double radius_ = 0.0;
  std::array<Leg, robots::kHexapodLegs> legs_;
  Eigen::Vector3d light_C_;
  Plate base_, platform_;
  // The eight bounding cones (legs 0..5, base, platform) as structure-of-arrays, so that a ray
  // from the origin of C tests all of them in one branch-free loop.
  static constexpr int kCones = robots::kHexapodLegs + 2;
  alignas(16) std::array<double, kCones> cone_x_{}, cone_y_{}, cone_z_{}, cone_cos_{};
};

}  // namespace kinevis::vision::render
