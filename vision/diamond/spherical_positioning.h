#pragma once

// Spherical positioning of the DIAMOND's tool marker from one camera (seed 001 §III-B, issue 8):
// the marker T is constrained to the sphere of radius R about the remote centre of motion, so the
// ray its pixel back-projects to meets that sphere where T is, and the (φ, γ) of that point are
// the robot's task coordinates. The seed's eq. (10)–(12) do this in 1-D for a camera on the
// axis of (φ, γ) = (π/2, π/4) looking at the RCM; LocateOnSphere() is the general version: any
// vision::CameraModel (central or not), any camera pose X_OC.
//
// Frames (robots/diamond/diamond_model.h, vision/camera/camera_model.h):
//   O  the RCM frame: origin at the RCM, z_O the base axis, φ the azimuth about z_O from x_O, γ
//      the polar angle from z_O. The sphere is |p_O| = R.
//   C  the camera frame of camera_model.h. X_OC is the pose of C in O (p_O = X_OC p_C).
//
// Which intersection. A ray from outside the sphere meets it twice (or not at all); T is taken at
// the first (nearest) one, where the ray enters the sphere. There the sphere's outward normal
// u = p/R faces the camera (d · u < 0), i.e. the marker, mounted on the outer end of the tool and
// facing away from the RCM, is seen from its front. At the second intersection the marker would
// face away from the camera, and the tool and links between would hide it. A camera inside the
// sphere (|c_O| <= R) cannot see an outward-facing marker: status kCameraInsideSphere.
//
// Grazing rays. With n the outward normal at the hit, cos ι = −d · n is the cosine of the angle
// of incidence; ∂p/∂pixel grows like 1/cos ι, and at cos ι = 0 the two intersections merge (the
// ray touches the sphere's silhouette). Below options.min_incidence_cosine the result is reported
// as kGrazing (the point and Jacobians are still filled in, for diagnosis, but are not a fix).
//
// Jacobians (analytic, checked against central differences in
// tests/vision/diamond/spherical_positioning_test.cc): with p = o + t d the hit (o the ray origin,
// d its unit direction, in O), |p|² = R² gives
//     dp = (I − d pᵀ / (p·d)) (do + t dd) + d R dR / (p·d),
// and φ = atan2(p_y, p_x), γ = atan2(ρ, p_z), ρ = sqrt(p_x² + p_y²):
//     dφ = (−p_y dp_x + p_x dp_y) / ρ²,   dγ = (p_z (p_x dp_x + p_y dp_y) / ρ − ρ dp_z) / R².
// The pose Jacobian is for the right perturbation X_OC ⊕ ξ = X_OC · (Exp(ω), v), ξ = (ω, v),
// ω a rotation vector (rad) and v a translation (m), both in C.
//
// LocateOnSphere() is const maths: no allocation, thread-safe if the camera model is.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cmath>
#include <string>

#include "vision/camera/camera_model.h"

namespace kinevis::vision {

enum class SphereFixStatus {
  kOk,
  kBackProjectionFailed,  // the camera model could not back-project the pixel (see projection)
  kCameraInsideSphere,    // the ray origin is not outside the sphere: |o_O| <= R
  kMiss,                  // the ray passes the sphere (or its line meets it only behind)
  kGrazing,               // it meets it at incidence cosine < min_incidence_cosine
  kOnBaseAxis,            // the hit is on z_O (sin γ ≈ 0): φ is undefined there
};
// "ok", "back-projection failed", "camera inside sphere", "miss", "grazing", "on base axis".
const char* ToString(SphereFixStatus status);

struct SphericalPositioningOptions {
  // Smallest accepted cosine of the incidence angle at the hit, in [0, 1). The default 0.05
  // (87°) accepts everything but the last ~0.1 % of the silhouette radius, where ∂(φ,γ)/∂pixel
  // is 20× its value at normal incidence.
  double min_incidence_cosine = 0.05;
  // Empty when usable, otherwise every bad field and its value.
  std::string Validate() const;
};

// The result for one pixel. Everything but status/projection is filled in for kOk, kGrazing and
// kOnBaseAxis (the Jacobians of φ are not finite for kOnBaseAxis); otherwise left at defaults.
struct SphereFix {
  SphereFixStatus status = SphereFixStatus::kMiss;
  ProjectionStatus projection = ProjectionStatus::kOk;  // of the back-projection
  Eigen::Vector2d task = Eigen::Vector2d::Zero();       // (φ, γ) (rad), φ in (−π, π]
  Eigen::Vector3d p_O = Eigen::Vector3d::Zero();        // the hit, on the sphere (m)
  double range = 0.0;             // t: distance from the ray origin to the hit (m)
  double incidence_cosine = 0.0;  // −d·n at the hit, in [0, 1]
  Eigen::Matrix2d J_task_pixel = Eigen::Matrix2d::Zero();  // ∂(φ, γ)/∂(u, v) (rad/px)
  Eigen::Matrix<double, 2, 6> J_task_pose =
      Eigen::Matrix<double, 2, 6>::Zero();  // ∂(φ, γ)/∂(ω, v) (rad/rad, rad/m)
  Eigen::Vector2d J_task_radius = Eigen::Vector2d::Zero();  // ∂(φ, γ)/∂R (rad/m)
  Eigen::Matrix<double, 3, 2> J_point_pixel = Eigen::Matrix<double, 3, 2>::Zero();  // ∂p_O/∂(u,v)
  bool ok() const { return status == SphereFixStatus::kOk; }
};

// Locates the marker seen at `pixel` (px, camera_model.h convention) on the sphere of radius
// `radius` (m, about O's origin) for a camera at X_OC (pose of C in O). Throws
// std::invalid_argument when radius is not finite and > 0, X_OC is not finite or its linear part
// is not a rotation (|RᵀR − I| > 1e-9, det < 0), or the options are invalid; everything about
// the pixel is a status.
SphereFix LocateOnSphere(const CameraModel& camera, const Eigen::Isometry3d& X_OC, double radius,
                         const Eigen::Vector2d& pixel,
                         const SphericalPositioningOptions& options = {});

// ---------------------------------------------------------------------------------------------
// Scalar-generic core (T = double or ceres::Jet; identification in calibration/diamond uses it
// with the ray fixed and the pose and R as parameters). Comparisons use the value part only.

enum class RaySphereHit { kOk, kOriginInside, kMiss };

// First intersection of the ray o + t d (t > 0, d unit, in O) with |p| = R (see "Which
// intersection" above): t = −o·d − sqrt((o·d)² − |o|² + R²). kOriginInside when |o| <= R, kMiss
// when the discriminant is negative or t <= 0. p and incidence cosine (= sqrt(disc)/R) written
// for kOk only.
template <typename T>
RaySphereHit IntersectRaySphere(const Eigen::Matrix<T, 3, 1>& o, const Eigen::Matrix<T, 3, 1>& d,
                                const T& radius, Eigen::Matrix<T, 3, 1>* p, T* incidence_cosine) {
  using std::sqrt;
  const T b = o.dot(d);
  const T c = o.squaredNorm() - radius * radius;
  if (!(c > 0.0)) return RaySphereHit::kOriginInside;
  const T disc = b * b - c;
  if (disc < 0.0) return RaySphereHit::kMiss;
  const T root = sqrt(disc);
  const T t = -b - root;
  if (!(t > 0.0)) return RaySphereHit::kMiss;
  *p = o + t * d;
  *incidence_cosine = root / radius;
  return RaySphereHit::kOk;
}

// (φ, γ) of a point p in O (azimuth about z_O from x_O, polar angle from z_O), as
// robots::DiamondToolAxis defines them.
template <typename T>
Eigen::Matrix<T, 2, 1> TaskFromPoint(const Eigen::Matrix<T, 3, 1>& p) {
  using std::atan2;
  using std::sqrt;
  const T rho = sqrt(p[0] * p[0] + p[1] * p[1]);
  Eigen::Matrix<T, 2, 1> task;
  task << atan2(p[1], p[0]), atan2(rho, p[2]);
  return task;
}

// ---------------------------------------------------------------------------------------------
// The seed's 1-D formula (eq. 10–12), kept for its configuration: a camera at distance D from the
// RCM on the axis of the working region's centre, looking at the RCM, image axes along the
// meridian and the parallel through that centre (vision/render DiamondCameraPose(D)).
//
// As printed, eq. (11) reads T(x) = π/2 + asin(((R+r)/R) sin a − a) and eq. (12)
// a = atan(tan(a_max) (x − n_x) / (n_x r²)). From the triangle RCM–camera–T (sine rule, the
// derivation of eq. 13), a ray at angle a from the optical axis meets the sphere (near side) at
// the central angle
//     δ = asin((D/R) sin a) − a,      D = R + r the camera's distance from the RCM,
// the "− a" outside the arcsine, and a = atan(tan(a_max) (x − n_x) / n_x) = atan((x − c_x)/f):
// the printed "n_x r²" is garbled (tan(a_max) = n_x / f, eq. 15). Verified against
// LocateOnSphere(): exact along the central column, where the image's v axis runs along the
// meridian φ = π/2 (γ = π/4 ∓ δ). Along the central row δ is exact as the great-circle angle from
// the axis point, but that great circle is not a parallel: the point is (sin δ, cos δ/√2,
// cos δ/√2), so the true azimuth is φ = π/2 − atan(√2 tan δ), not π/2 − δ (≈ √2 δ near the
// centre: T_φ under-reads φ by ~30 %), and γ = acos(cos δ/√2) ≠ π/4. Off the centre lines the two
// 1-D maps are worse (0.17 rad in φ at pixel (900, 450) of the seed's camera at 0.4462 m). The
// general LocateOnSphere() has none of this; the seed's formula is kept for comparison only.
//
// SeedCentralAngle: δ (rad) for tan a (any finite value; the ray's tangent off the axis), D (m)
// and R (m), 0 < R < D. NaN when the ray misses the sphere (|(D/R) sin a| > 1).
double SeedCentralAngle(double tan_ray_angle, double camera_distance, double radius);

// (φ, γ) by the seed's eq. (10)–(12) (corrected as above) for a pinhole without distortion with
// focal lengths fx, fy (px) and principal point (cx, cy) (px), at distance D from the RCM in the
// DiamondCameraPose(D) orientation (x_C = x_O, v growing towards z_O): φ = π/2 − δ_u,
// γ = π/4 − δ_v (the seed's signs depend on its image axes, which are not given). NaN
// components where SeedCentralAngle() is NaN.
Eigen::Vector2d SeedSphericalPositioning(const Eigen::Vector2d& pixel, double fx, double fy,
                                         double cx, double cy, double camera_distance,
                                         double radius);

}  // namespace kinevis::vision
