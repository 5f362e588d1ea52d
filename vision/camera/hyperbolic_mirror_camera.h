#pragma once

// Non-single-viewpoint catadioptric camera: a hyperbolic mirror above a perspective camera whose
// pinhole is NOT at the mirror's focus (seed 000, the CAMBADA RoboCup robot). Pixels are
// back-propagated by ray tracing (seed 000 §4, eq. (2)–(32)): pixel → lens correction → ray
// through the pinhole → intersection with the mirror → reflection → ground plane.
//
// Frames (defined once, here; all lengths in metres, angles in radians):
//   C  the model frame of camera_model.h, = the seed's (X, Y, Z) system of §4.1. Origin at the
//      camera pinhole ("lens focus"); y_C parallel to the mirror axis of revolution, pointing from
//      the camera up towards the mirror (the seed's Y: its "y" is the vertical axis of the mirror
//      equation); z_C the robot's forward direction (the seed's Z, "robot centre to its front");
//      x_C = y_C × z_C (right-handed), i.e. the robot's left (the seed's X; the seed does not
//      state a handedness). Project() takes points in C; BackProject() returns rays in C.
//   mirror  the surface y = sqrt(A + (x − m_x)² + (z − m_z)²) + k_off in C (seed eq. (3)–(4)),
//      A = mirror_constant (the seed's 1000 mm² = 1e-3 m²), (m_x, m_z) = (mirror_axis_x,
//      mirror_axis_z) the seed's P_m = (m_cx, 0, m_cz), k_off = apex_distance − sqrt(A) so that
//      the apex is at y = apex_distance (the seed's mtf). Only the part within mirror_radius of
//      the axis exists (depth sqrt(A + R²) − sqrt(A) = 15.55 mm for the seed's mirror).
//      The mirror axis stays parallel to y_C: a tilt of the mirror axis is modelled, as in the
//      seed (§4.2, eq. (29)–(32)), as the opposite tilt of the ground plane.
//   S  the sensor frame. The nominal sensor lies in the plane y_C = −focal_length (the seed's
//      htf) with its centre below the pinhole. The actual sensor centre is at
//      p_C_S = (sensor_offset_x, −focal_length, sensor_offset_z) (the seed's d_x, d_z) and
//      R_CS = R_y(γ) R_x(ρ) R_z(θ) (γ = sensor_gamma about y, ρ = sensor_rho about x,
//      θ = sensor_theta about z; seed eq. (25)–(28), see the .cc for the order actually used).
//      A pixel (u, v) sits at s_S = (−(u − cx) pitch, 0, (v − cy) pitch) in S (seed eq. (5),
//      signs chosen so that the camera is a proper, non-mirrored camera looking up along y_C: a
//      pixel right of the centre looks towards +x_C, a pixel below it towards −z_C).
//   G  the ground frame: origin where the mirror axis meets the ground plane (apex_to_ground
//      below the apex along the axis, the seed's hmf), z_G the ground normal pointing up
//      (towards the mirror), x_G robot forward, y_G robot left (x forward, y left, z up). With no
//      tilt R_CG maps (x_G, y_G, z_G) to (z_C, x_C, y_C); the mirror tilt rotates it by
//      R_x(ground_rho) R_z(ground_theta) in C (seed eq. (29)–(31): g = R_x(ρ) R_z(θ) j).
//      X_CG() is the pose of G in C. The ground map gives (x_G, y_G).
//
// Lens correction (seed eq. (2)): a ray leaving the lens at angle θ from the axis of the nominal
// sensor, θ = atan(r / focal_length) with r the distance of the sensor point from the sensor
// centre, is corrected to θ + C(θ), C(θ) = k0 + k1 θ + k2 θ² + k3 θ³ (rad), keeping the azimuth.
// It is applied in S, before the sensor misalignment moves the point (seed §4.2 substitutes
// the misaligned point into eq. (5)). k0 must be 0 (an angle offset on the axis has no
// direction). Its domain is θ ≤ 1.25 × the angle of the farthest image corner.
//
// Nothing here allocates except construction, Validate() and the first ComputeGroundMap() into
// a map of a new size. Project/BackProject are const, allocation-free and thread-safe.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "vision/camera/camera_model.h"

namespace kinevis::vision {

struct GroundMap;

// All SI: metres, radians. Field names are the file/CLI keys.
struct HyperbolicMirrorParameters {
  int width = 640;  // image size (pixels), > 0
  int height = 480;
  double pixel_pitch = 4.65e-6;  // sensor pixel size (m), > 0 (seed eq. (5): 4.65 µm)
  double cx = 319.5;             // pixel of the sensor centre, the lens correction's centre
  double cy = 239.5;
  double focal_length = 4.56e-3;  // pinhole to sensor (m), the seed's htf, > 0
  // C(θ) = k0 + k1 θ + k2 θ² + k3 θ³ (rad, θ in rad); k0 must be 0; 1 + C'(θ) > 0 on the domain.
  std::array<double, 4> lens_correction{0.0, 0.0, 0.001, 0.0045};
  double mirror_constant = 1e-3;  // A in y = sqrt(A + r²) + k_off (m²); seed 1000 mm², > 0
  double mirror_radius = 0.035;   // rim radius (m), > 0
  double apex_distance = 0.110;   // pinhole to mirror apex along y_C (m), the seed's mtf, > 0
  double mirror_axis_x = 0.0;     // mirror axis position (m), the seed's m_cx, m_cz;
  double mirror_axis_z = 0.0;     //   |(m_x, m_z)| < mirror_radius
  double apex_to_ground = 0.680;  // apex to ground along the axis (m), the seed's hmf,
                                  //   > apex_distance (the ground is below the pinhole)
  double sensor_offset_x = 0.0;   // sensor centre offset (m), the seed's d_x, d_z; |.| < 1 cm
  double sensor_offset_z = 0.0;
  double sensor_gamma = 0.0;  // sensor rotations (rad), the seed's γ (about y), ρ (about x),
  double sensor_rho = 0.0;    //   θ (about z); |.| ≤ 0.5
  double sensor_theta = 0.0;
  double ground_rho = 0.0;    // mirror-axis tilt as the ground normal's rotation (rad), the
  double ground_theta = 0.0;  //   seed's ρ, θ of eq. (29)–(31); |.| ≤ 0.5

  // k_off = apex_distance − sqrt(mirror_constant) (m), seed eq. (4).
  double mirror_offset() const;
  // Empty when usable, otherwise one message naming every bad field and its value.
  std::string Validate() const;

  // The seed's CAMBADA setup, 4 mm lens: htf 4.56 mm, C = [0, 0, 0.001, 0.0045], mtf 110 mm,
  // hmf 680 mm, 640×480 at 4.65 µm, centre (319.5, 239.5), no misalignment.
  static HyperbolicMirrorParameters Seed000Lens4mm();
  // 6 mm lens: htf 6.77 mm, C = [0, 0, 0.0002, 0.00075]. The seed gives no mtf for it (only
  // that it needs a larger camera–mirror distance); 0.170 m keeps the rim's image radius
  // (≈ 274 px) the same as with the 4 mm lens at 0.110 m.
  static HyperbolicMirrorParameters Seed000Lens6mm();
};

// The camera. Name "hyperbolic-mirror"; non-central (the reflected rays do not share a point).
class HyperbolicMirrorCamera final : public CameraModel {
 public:
  // Throws std::invalid_argument naming every bad parameter (see Validate()).
  explicit HyperbolicMirrorCamera(const HyperbolicMirrorParameters& parameters);

  const HyperbolicMirrorParameters& parameters() const { return parameters_; }

  std::string_view Name() const override { return "hyperbolic-mirror"; }
  int width() const override { return parameters_.width; }
  int height() const override { return parameters_.height; }
  bool IsCentral() const override { return false; }

  // Forward: finds the mirror point M whose reflection sends the pinhole's ray to p_C (law of
  // reflection, as the minimum of the path length |M| + |p_C − M| over the mirror surface: the
  // mirror is convex, so the reflection point is unique) by damped Newton in the mirror's
  // (x − m_x, z − m_z), then projects M through the pinhole and the inverse lens correction.
  // kBehindCamera when p_C is not on the reflecting side of the mirror (above or inside it) or
  // M is behind the sensor; kOutsideDomain when M is beyond the rim (points beyond the mirror's
  // horizon, including those high above it whose path minimum runs off past the rim) or the
  // ray beyond the lens correction's domain; kNoConvergence when Newton fails (50 iterations,
  // step 1e-12 m).
  // J_pixel_point = ∂(u, v)/∂p_C (px/m), exact by the implicit-function theorem.
  ProjectionStatus Project(const Eigen::Vector3d& p_C, Eigen::Vector2d* pixel,
                           Matrix23d* J_pixel_point = nullptr) const override;
  // Back-propagation (seed eq. (5)–(23)): ray.p_C_O is the reflection point on the mirror, ray.d_C
  // the reflected unit direction. kOutsideDomain when the pinhole ray misses the mirror (beyond
  // the rim) or the pixel is beyond the lens correction's domain.
  ProjectionStatus BackProject(const Eigen::Vector2d& pixel, Ray* ray,
                               RayJacobian* J = nullptr) const override;
  std::string Validate() const override { return parameters_.Validate(); }

  // Pixel → ground point (x_G, y_G) (m) (seed eq. (24), (32)). kOutsideDomain when BackProject()
  // fails or the reflected ray does not reach the ground in front of it (at or above the
  // horizon). J_ground_pixel = ∂(x_G, y_G)/∂(u, v) (m/px).
  ProjectionStatus BackProjectToGround(const Eigen::Vector2d& pixel, Eigen::Vector2d* p_G_xy,
                                       Eigen::Matrix2d* J_ground_pixel = nullptr) const;
  // Ground point (x_G, y_G, 0) → pixel, i.e. Project(X_CG() * (x, y, 0)).
  ProjectionStatus ProjectGroundPoint(const Eigen::Vector2d& p_G_xy, Eigen::Vector2d* pixel) const;
  // Direct view, no mirror: a point seen straight through the lens (e.g. the mirror's apex or
  // rim, seed §5) → pixel. kBehindCamera when the point is not above the sensor plane.
  ProjectionStatus ProjectDirect(const Eigen::Vector3d& p_C, Eigen::Vector2d* pixel,
                                 Matrix23d* J_pixel_point = nullptr) const;

  const Eigen::Isometry3d& X_CG() const { return X_CG_; }
  // Apex (m_x, apex_distance, m_z) in C.
  Eigen::Vector3d MirrorApex() const;

  // The seed's P_p' (eq. (26)–(28)): where the pixel, after the lens correction, lies on the
  // misaligned sensor, in C (m). The pinhole ray of the pixel has direction −P_p'. NaN beyond the
  // lens correction's domain.
  Eigen::Vector3d PixelOnSensor(const Eigen::Vector2d& pixel) const;

 private:
  friend void ComputeGroundMap(const HyperbolicMirrorCamera& camera, GroundMap* map);

  // Nominal sensor point s_S = (x, z) (m) of a pixel (seed eq. (5)).
  Eigen::Vector2d SensorPoint(const Eigen::Vector2d& pixel) const;
  // Lens correction in S: sensor radius r → corrected radius r_c and dr_c/dr (false beyond the
  // domain). Inverse: r_c → r and dr/dr_c.
  bool LensForward(double r, double* r_c, double* dr_c_dr) const;
  bool LensInverse(double r_c, double* r, double* dr_dr_c) const;
  // Gain r_c / r of the lens correction at sensor radius r (exact), and from the Hermite table.
  bool LensGain(double r, double* gain) const;
  bool LensGainFromTable(double r, double* gain) const;
  // Lens-corrected point on the misaligned sensor, in C, and its Jacobian (3×2) with respect to
  // s_S (when not null). False beyond the lens correction's domain.
  bool CorrectedSensorPoint(double s_x, double s_z, Eigen::Vector3d* p_C_P,
                            Matrix32d* J_p_s = nullptr) const;
  // First intersection of the ray t d_C (t > 0, from the pinhole) with the mirror within its rim.
  bool HitMirror(const Eigen::Vector3d& d_C, double* t, Eigen::Vector3d* p_C_M) const;
  // The lens-corrected sensor point (gain s_S) traced to the ground (x_G, y_G); false when the
  // pinhole ray misses the mirror or the reflected ray misses the ground.
  bool TraceToGround(double s_x, double s_z, double gain, double* x_G, double* y_G) const;

  HyperbolicMirrorParameters parameters_;
  Eigen::Matrix3d R_CS_;      // sensor orientation
  Eigen::Vector3d p_C_S_;     // sensor centre
  Eigen::Vector3d n_C_S_;     // sensor normal R_CS e_y
  Eigen::Vector3d p_C_H_;     // centre of the hyperbola (m_x, k_off, m_z)
  Eigen::Isometry3d X_CG_;    // ground frame
  double quadratic_c_ = 0.0;  // F(pinhole), constant term of the ray–mirror quadratic
  double theta_max_ = 0.0;    // lens correction domain (rad)
  double theta_c_max_ = 0.0;  // θ_max + C(θ_max)
  double r_max_ = 0.0;        // sensor radius of θ_max (m)
  // Cubic Hermite table of the lens gain r_c / r over [0, r_max_]: (gain, step · d gain/dr) per
  // node; ComputeGroundMap() uses it instead of atan/tan (its result is tested against the
  // exact trace).
  std::vector<double> lens_table_;
  double lens_table_inverse_step_ = 0.0;
};

// Pixel → ground (x_G, y_G) for every pixel (seed §5, the distance map). Row-major, index
// v * width + u. x_m, y_m are NaN and valid is 0 where the pixel does not see the ground.
struct GroundMap {
  int width = 0;
  int height = 0;
  std::vector<double> x_m;
  std::vector<double> y_m;
  std::vector<std::uint8_t> valid;
  int valid_count = 0;
};

// Fills *map for `camera`. Allocates only when the map's size differs from the camera's image.
// Each entry is BackProjectToGround() of its pixel, with the lens correction's gain read from a
// cubic Hermite table (agreement better than 1e-9 m, tested). map must not be null.
void ComputeGroundMap(const HyperbolicMirrorCamera& camera, GroundMap* map);

}  // namespace kinevis::vision
