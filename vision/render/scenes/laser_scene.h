#pragma once

// The weld cell's laser-triangulation scanner (seed 004): a camera and two laser line projectors,
// one fixed and one rotating, lighting a surface. Rendered in the scanner camera's frame C
// (camera_model.h; the seed's camera frame: x right, y down, z along the optical axis), usually
// through the built-in "tsai-seed004" camera (issue 5).
//
// Laser planes in C (seed 004, eq. (17)–(18) and (8)), lengths in metres here (the seed's mm):
//   rotating laser, the plane "parallel to the X axis":
//     y + cot θ_y z − b_y − d_y cot θ_y = 0,  normal (0, 1, cot θ_y), through P_L^Y = (0, b_y, d_y)
//     i.e. y + cot θ_y z = b_y' with b_y' = b_y + d_y cot θ_y (eq. (8)); its image point (x_u, y_u)
//     triangulates by eq. (9): (x, y, z) = b_y' / (f cot θ_y + y_u) (x_u, y_u, f) — we checked
//     that eq. (9) is exactly this plane met by the pixel's ray (tests).
//   fixed laser, "parallel to the Y axis":
//     x + cot θ_x z − b_x' = 0,  normal (1, 0, cot θ_x), through (b_x', 0, 0).
//     The seed calibrates only b_x' = b_x + d_x cot θ_x for the fixed laser (Table 2; §3: its base
//     distance stays constant), so its emitter point is put at (b_x', 0, 0) — on the plane; which
//     point of the plane emits matters only for the shadows.
//   Seed numbers (Table 2): b_y = 101.973 mm, d_y = −16.0156 mm, b_x' = −6.6788 mm,
//   cot θ_x = −0.0922. The rotating laser's angle is the parameter rotating_cot_theta_y (the seed
//   works with cot θ_y throughout); cot θ_y = b_y'/z puts its stripe on the optical axis at depth z
//   (≈ 0.25 for 0.4 m, inside the seed's 250–650 mm working range).
//
// Surfaces, in a surface frame S with pose X_CS (z_S the surface normal out of the material,
// towards the scanner):
//   kBlade  the freeform "blade": heightfield z_S = f(x_S, y_S) over |x_S| ≤ hx, |y_S| ≤ hy,
//           f = ½ k_xx x² + ½ k_yy y² + k_xy x y − Σ_k h_k exp(−|p − c_k|² / (2 σ_k²)):
//           a gently curved sheet (curvatures k in 1/m, ~1/0.5 m for a turbine blade) with Gaussian
//           cavitation pits of depth h_k (m) and width σ_k (m) centred at c_k.
//   kBoard  the flat calibration board z_S = 0 over the same extent, optionally with the seed's
//           gauge block (100 × 50 × 10 mm, §5.2) standing on it, and optionally with the seed's
//           dot grid printed on it (§5.1, Fig. 14: 9 × 9 dots 26.5 mm apart; DotGrid): dark
//           discs whose reflectance is `albedo` times the board's, for the board pose of issue 7
//           (calibration/laser_scanner/board_pose.h). The dots darken the laser light too (the
//           whole radiance is multiplied by the albedo), as on paper. They are edges of radiance,
//           not objects: the renderer supersamples them through its radiance-step test, so they
//           are anti-aliased like every other edge; hit.object stays kLaserSurface.
// Radiance: ambient · (0.3 + 0.7 |cos|) (a matte grey surface lit from the scanner; cos between the
//   ray and the normal) + Σ lasers laser_peak · exp(−dist² / (2 σ²)), dist = distance of the hit
//   point from the laser plane, σ = stripe_sigma (half the stripe's width; 0.3 mm by default);
//   clamped to 1. Occlusion: the gauge block shadows the board from each laser (shadow ray to the
//   laser's emitter point); the blade's self-shadowing is ignored: a pit shadows itself only
//   where its wall is steeper than the laser's elevation above the surface (≈ 76° for the rotating
//   laser at cot θ_y = 0.25 on a surface facing the camera), while a Gaussian pit's steepest slope
//   is 0.61 h/σ (17° for the tests' h/σ = 0.5).
//
// Trace() allocates nothing; the scene is immutable and thread-safe after construction.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cmath>
#include <string>
#include <vector>

#include "vision/render/renderer.h"

namespace kinevis::vision::render {

inline constexpr int kLaserBackground = 0;
inline constexpr int kLaserSurface = 1;  // blade or board
inline constexpr int kLaserGaugeBlock = 2;

// A laser plane in C: points p with n · (p − point) = 0; n unit. `emitter` is the point the light
// comes from (for shadows), on the plane.
struct LaserPlane {
  Eigen::Vector3d point = Eigen::Vector3d::Zero();
  Eigen::Vector3d normal = Eigen::Vector3d::UnitY();
  Eigen::Vector3d emitter = Eigen::Vector3d::Zero();
  double SignedDistance(const Eigen::Vector3d& p_C) const { return normal.dot(p_C - point); }
};

enum class LaserId { kFixed = 0, kRotating = 1 };

// The scanner's geometry (seed 004, Table 2), metres.
struct LaserScannerGeometry {
  double rotating_b_y = 0.101973;
  double rotating_d_y = -0.0160156;
  double fixed_b_x_prime = -0.0066788;
  double fixed_cot_theta_x = -0.0922;

  // Seed eq. (17) with eq. (8), normalised.
  LaserPlane RotatingPlane(double cot_theta_y) const;
  // Seed eq. (18) with b_x' (see the header comment).
  LaserPlane FixedPlane() const;
  std::string Validate() const;
};

enum class LaserSurfaceKind { kBlade, kBoard };

struct CavitationPit {
  Eigen::Vector2d centre_S = Eigen::Vector2d::Zero();  // (x_S, y_S) (m)
  double depth = 0.5e-3;                               // h (m), > 0
  double sigma = 2e-3;                                 // Gaussian width σ (m), > 0
};

// The calibration board's dot grid (seed 004 §5.1, Fig. 14), in the board frame S (z_S = 0):
// dot (row, col) is centred at centre_S + ((col − (cols − 1)/2) pitch, (row − (rows − 1)/2) pitch),
// so columns run along x_S and rows along y_S. A square grid looks the same after a quarter turn
// about z_S: calibration/laser_scanner/board_pose.h says how it picks one of the four poses.
struct DotGrid {
  int rows = 9;               // >= 2
  int cols = 9;               // >= 2
  double pitch = 0.0265;      // centre-to-centre distance (m), > 0
  double dot_radius = 0.005;  // (m), in (0, pitch / 2)
  double albedo = 0.15;       // a dot's reflectance relative to the board, [0, 1)
  Eigen::Vector2d centre_S = Eigen::Vector2d::Zero();  // grid centre on the board (m)

  Eigen::Vector2d DotCentre_S(int row, int col) const {
    return centre_S + pitch * Eigen::Vector2d(col - 0.5 * (cols - 1), row - 0.5 * (rows - 1));
  }
  // The reflectance factor at (x_S, y_S): albedo inside a dot, 1 elsewhere.
  double Reflectance(double x_S, double y_S) const;
  // Empty when usable, otherwise every bad field (prefixed by `prefix`) and its value.
  std::string Validate(const std::string& prefix = "dots.") const;
};

struct LaserSceneParameters {
  LaserScannerGeometry scanner;
  double rotating_cot_theta_y = 0.25;  // the rotating laser's angle, as cot θ_y; finite
  bool fixed_on = true;
  bool rotating_on = true;

  LaserSurfaceKind surface = LaserSurfaceKind::kBlade;
  Eigen::Isometry3d X_CS = Eigen::Translation3d(0.0, 0.0, 0.4) *
                           Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX());  // faces the camera
  Eigen::Vector2d half_extent = Eigen::Vector2d(0.1, 0.08);                    // hx, hy (m), > 0
  double curvature_xx = 0.0;  // blade k_xx, k_yy, k_xy (1/m), |.| ≤ 20
  double curvature_yy = 0.0;
  double curvature_xy = 0.0;
  std::vector<CavitationPit> pits;                           // blade only, at most 64
  bool gauge_block = false;                                  // board only
  Eigen::Vector2d gauge_centre_S = Eigen::Vector2d::Zero();  // block centre on the board (m)
  double gauge_heading = 0.0;  // rotation of its 100 mm side from x_S about z_S (rad)
  Eigen::Vector3d gauge_size = Eigen::Vector3d(0.100, 0.050, 0.010);  // (m), > 0
  // The gauge block's frame B in S (calibration/weld_mount/mount_calibration.h): origin at its
  // centre, gauge_size.z()/2 above the board at gauge_centre_S, x_B turned by gauge_heading from
  // x_S.
  Eigen::Isometry3d X_SB() const;
  // Board only: print the dot grid `dots` on it; the grid (dots and their radius) must lie
  // inside the board's extent.
  bool dot_grid = false;
  DotGrid dots;

  double ambient = 0.08;         // radiance of the unlit surface (facing the ray), [0, 1]
  double background = 0.0;       // radiance where nothing is hit, [0, 1]
  double laser_peak = 0.85;      // radiance added at a stripe's centre, [0, 1]
  double stripe_sigma = 0.3e-3;  // σ of the stripe's profile (m), in [0.05, 2] mm
  bool laser_shadows = true;     // the gauge block's shadows on the board

  std::string Validate() const;
};

// What a pixel's ray sees, in full (ground truth).
struct LaserHit {
  Hit hit;
  Eigen::Vector3d p_C = Eigen::Vector3d::Constant(std::nan(""));  // hit point (NaN: background)
  Eigen::Vector3d n_C = Eigen::Vector3d::Zero();                  // unit normal, towards the ray
  // Signed distance from each laser plane (m), indexed by LaserId; whether each laser reaches the
  // point (switched on and not shadowed; the shadow ray is cast only within 8 σ of the plane,
  // `reached` is true farther away, where the laser adds nothing).
  double plane_distance[2] = {0.0, 0.0};
  bool reached[2] = {false, false};
  // Lit by laser i: reached and within 3 σ of its plane.
  bool Lit(LaserId id) const;
  double stripe_sigma = 0.0;
  double reflectance = 1.0;  // the dot grid's factor at the hit point (1 off the dots)
};

class LaserScene final : public Scene {
 public:
  // Throws std::invalid_argument naming every bad field (Validate()).
  explicit LaserScene(const LaserSceneParameters& parameters);

  Hit Trace(const Ray& ray_C) const override;
  // Exactly Trace() for each ray (bit for bit); the blade's pit-free rays two at a time (SSE2),
  // in stages over chunks of rays, the others through Trace().
  void TraceBatch(const RayBatch& rays, Hit* hits) const override;
  LaserHit TraceDetailed(const Ray& ray_C) const;

  const LaserSceneParameters& parameters() const { return parameters_; }
  const LaserPlane& plane(LaserId id) const { return planes_[static_cast<int>(id)]; }

  // The surface height f(x_S, y_S) (m) of the blade (0 for the board; the block not included).
  double Height(double x_S, double y_S) const;
  // First hit of the ray with the surface (blade or board, and the block), or kNoHit; the object
  // and the normal in C when not null.
  double IntersectSurface(const Ray& ray_C, int* object, Eigen::Vector3d* n_C) const;

  // The exact stripe of laser `id`: the points (in C) where its plane meets the surface, as seen
  // from the scanner's side (the first surface point along the plane's in-plane direction closest
  // to −z_S), sampled every `spacing` m along the plane's trace on the plane z_S = 0, across the
  // surface's extent; gaps (where the plane misses the surface) are left out. Points are in
  // order along the stripe. Issue 7's stripe extraction is checked against it. Allocates.
  std::vector<Eigen::Vector3d> StripeCurve(LaserId id, double spacing) const;

 private:
  double IntersectHeightfield(const Ray& ray_S, Eigen::Vector3d* n_S) const;
  bool Shadowed(const Eigen::Vector3d& p_C, const LaserPlane& laser) const;

  LaserSceneParameters parameters_;
  LaserPlane planes_[2];
  Eigen::Isometry3d X_SC_;
  Eigen::Matrix3d R_SC_ = Eigen::Matrix3d::Identity();  // X_SC_'s rotation, as a plain matrix
  Eigen::Vector3d p_S_C_ = Eigen::Vector3d::Zero();     // X_SC_'s translation
  Eigen::Matrix3d R_CS_ = Eigen::Matrix3d::Identity();  // X_CS's rotation
  Eigen::Isometry3d X_CB_;                              // gauge block centre frame
  // A pit's term is left out of a ray's heightfield where it stays below this height (m): far
  // below the 1e-13 m the roots are refined to. pit_cutoff2_[k]: the squared horizontal distance
  // from pit k's centre beyond which its term is below it.
  static constexpr double kNegligiblePitHeight = 1e-15;
  std::vector<double> pit_cutoff2_;
  std::vector<double> pit_reach_;  // √pit_cutoff2_, rounded up (TraceChunk's square test)
  double height_bound_ = 0.0;      // |f| ≤ height_bound_ + Σ h_k over the extent
  double pit_depth_sum_ = 0.0;
  double min_pit_sigma_ = 0.0;
  // TraceBatch's two-ray path is used for the blade (no gauge block) with curvature (its
  // quadric's leading coefficient is then non-zero for most rays).
  bool batch_fast_path_ = false;

  // Trace() of rays [first, first + count) of `rays` (count ≤ kChunkRays) whose quadric-only
  // intersection settles them (see TraceBatch); done[k] false for a ray it could not settle (a pit
  // within reach, a degenerate quadric).
  static constexpr int kChunkRays = 64;
  void TraceChunk(const RayBatch& rays, int first, int count, Hit* hits, bool* done) const;
};

}  // namespace kinevis::vision::render
