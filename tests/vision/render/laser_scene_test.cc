#include "vision/render/scenes/laser_scene.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <random>
#include <vector>

#include "vision/camera/camera_file.h"
#include "vision/camera/tsai_camera.h"
#include "vision/render/primitives.h"

namespace kinevis::vision::render {
namespace {

// The scanner camera of seed 004.
std::unique_ptr<CameraModel> ScannerCamera() { return BuiltinCameraModel("tsai-seed004"); }

// Centre of gravity (v, px) of the laser stripe in column u, from Trace() at the pixel centres of
// rows v_guess ± half_window: weights are the radiance above the window's minimum (the surface's
// ambient), as a stripe extractor would use. NaN when the column holds no stripe.
double ColumnCentroid(const CameraModel& camera, const Scene& scene, int u, double v_guess,
                      int half_window) {
  const int v0 = static_cast<int>(std::lround(v_guess));
  std::vector<double> radiance;
  for (int v = v0 - half_window; v <= v0 + half_window; ++v) {
    Ray ray;
    double value = 0.0;
    if (camera.BackProject(Eigen::Vector2d(u, v), &ray) == ProjectionStatus::kOk) {
      value = scene.Trace(ray).radiance;
    }
    radiance.push_back(value);
  }
  const double floor = *std::min_element(radiance.begin(), radiance.end());
  double sum = 0.0, first = 0.0;
  for (size_t i = 0; i < radiance.size(); ++i) {
    const double w = radiance[i] - floor;
    sum += w;
    first += w * (v0 - half_window + static_cast<int>(i));
  }
  return sum > 0.3 ? first / sum : std::nan("");
}

// The projected exact stripe, interpolated at column u: v of the segment of the projected curve
// that crosses u. NaN when none does or when the crossing segment jumps by more than 1 px in v
// (a step of the surface, e.g. the gauge block's edge).
double CurveRowAtColumn(const std::vector<Eigen::Vector2d>& curve_px, double u) {
  for (size_t i = 1; i < curve_px.size(); ++i) {
    const Eigen::Vector2d& a = curve_px[i - 1];
    const Eigen::Vector2d& b = curve_px[i];
    if ((a.x() - u) * (b.x() - u) > 0.0 || a.x() == b.x()) continue;
    if (std::abs(b.y() - a.y()) > 1.0) return std::nan("");
    const double s = (u - a.x()) / (b.x() - a.x());
    return a.y() + s * (b.y() - a.y());
  }
  return std::nan("");
}

std::vector<Eigen::Vector2d> ProjectCurve(const CameraModel& camera,
                                          const std::vector<Eigen::Vector3d>& curve) {
  std::vector<Eigen::Vector2d> out;
  for (const Eigen::Vector3d& p : curve) {
    Eigen::Vector2d px;
    if (camera.Project(p, &px) == ProjectionStatus::kOk) out.push_back(px);
  }
  return out;
}

// Per-column stripe centroids against the projected exact stripe; returns the largest |error|
// over the columns that have both, and how many there were.
double WorstColumnError(const CameraModel& camera, const LaserScene& scene, int u_begin, int u_end,
                        int u_step, int* columns) {
  const std::vector<Eigen::Vector2d> curve =
      ProjectCurve(camera, scene.StripeCurve(LaserId::kRotating, 2e-5));
  double worst = 0.0;
  *columns = 0;
  for (int u = u_begin; u < u_end; u += u_step) {
    const double v_exact = CurveRowAtColumn(curve, u);
    if (std::isnan(v_exact)) continue;
    // Skip columns near a step of the curve (the window would see both sides).
    if (std::isnan(CurveRowAtColumn(curve, u - 8)) || std::isnan(CurveRowAtColumn(curve, u + 8))) {
      continue;
    }
    const double v = ColumnCentroid(camera, scene, u, v_exact, 12);
    if (std::isnan(v)) continue;
    worst = std::max(worst, std::abs(v - v_exact));
    ++*columns;
  }
  return worst;
}

LaserSceneParameters FixedLaserOff() {
  LaserSceneParameters p;
  p.fixed_on = false;  // keep the vertical stripe out of the rotating stripe's columns
  return p;
}

TEST(LaserScene, PlanesAreTheSeedsEquations) {
  const LaserScannerGeometry g;
  const double cot = 0.27;
  const LaserPlane r = g.RotatingPlane(cot);
  // Seed 004 eq. (17): y + cot θ_y z − b_y − d_y cot θ_y = 0, for points spanning the plane.
  const Eigen::Vector3d e1 = Eigen::Vector3d::UnitX();
  const Eigen::Vector3d e2 = r.normal.cross(e1);
  for (double a : {-0.1, 0.0, 0.2}) {
    for (double b : {-0.3, 0.4}) {
      const Eigen::Vector3d p = r.point + a * e1 + b * e2;
      EXPECT_NEAR(p.y() + cot * p.z() - g.rotating_b_y - g.rotating_d_y * cot, 0.0, 1e-15);
    }
  }
  const LaserPlane f = g.FixedPlane();
  const Eigen::Vector3d e3 = f.normal.cross(Eigen::Vector3d::UnitY());
  for (double a : {-0.1, 0.3}) {
    const Eigen::Vector3d p = f.point + a * Eigen::Vector3d::UnitY() + 0.5 * a * e3;
    // Seed eq. (18) with b_x' = b_x + d_x cot θ_x.
    EXPECT_NEAR(p.x() + g.fixed_cot_theta_x * p.z() - g.fixed_b_x_prime, 0.0, 1e-15);
  }
  EXPECT_NEAR(r.normal.norm(), 1.0, 1e-15);
  EXPECT_NEAR(f.normal.norm(), 1.0, 1e-15);
}

TEST(LaserScene, Equation9TriangulatesTheRenderedStripe) {
  // The rotating stripe's lit points, triangulated by seed eq. (9) from their undistorted image
  // coordinates, are the 3-D points the scene reports (the scene's plane is the seed's).
  const auto camera = ScannerCamera();
  const double f_mm = dynamic_cast<const TsaiCamera&>(*camera).parameters().focal_length_mm;
  LaserSceneParameters p = FixedLaserOff();
  p.surface = LaserSurfaceKind::kBlade;
  p.curvature_xx = 2.0;
  p.curvature_yy = -1.0;
  const LaserScene scene(p);
  const std::vector<Eigen::Vector3d> curve = scene.StripeCurve(LaserId::kRotating, 5e-3);
  ASSERT_GT(curve.size(), 20u);
  const double cot = p.rotating_cot_theta_y;
  const double b_prime_mm = 1e3 * (p.scanner.rotating_b_y + p.scanner.rotating_d_y * cot);  // (8)
  for (const Eigen::Vector3d& point : curve) {
    Eigen::Vector2d pixel;
    ASSERT_EQ(camera->Project(point, &pixel), ProjectionStatus::kOk);
    Ray ray;
    ASSERT_EQ(camera->BackProject(pixel, &ray), ProjectionStatus::kOk);
    const LaserHit hit = scene.TraceDetailed(ray);
    ASSERT_EQ(hit.hit.object, kLaserSurface);
    EXPECT_TRUE(hit.Lit(LaserId::kRotating));
    EXPECT_FALSE(hit.Lit(LaserId::kFixed));  // switched off
    const double x_u = f_mm * ray.d_C.x() / ray.d_C.z();
    const double y_u = f_mm * ray.d_C.y() / ray.d_C.z();
    const Eigen::Vector3d p_mm = b_prime_mm / (f_mm * cot + y_u) * Eigen::Vector3d(x_u, y_u, f_mm);
    EXPECT_LT((1e-3 * p_mm - point).norm(), 1e-7) << point.transpose();
    EXPECT_LT((hit.p_C - point).norm(), 1e-7);
  }
}

TEST(LaserScene, StripeCurveLiesOnThePlaneAndTheSurface) {
  LaserSceneParameters p;
  p.curvature_xx = 3.0;
  p.curvature_yy = 1.5;
  p.curvature_xy = -1.0;
  p.pits = {{Eigen::Vector2d(0.01, 0.0), 0.8e-3, 2.5e-3},
            {Eigen::Vector2d(-0.03, 0.0), 0.4e-3, 1.5e-3}};
  const LaserScene scene(p);
  for (LaserId id : {LaserId::kFixed, LaserId::kRotating}) {
    const std::vector<Eigen::Vector3d> curve = scene.StripeCurve(id, 1e-3);
    ASSERT_GT(curve.size(), 100u);
    for (const Eigen::Vector3d& point : curve) {
      EXPECT_NEAR(scene.plane(id).SignedDistance(point), 0.0, 1e-12);
      const Eigen::Vector3d p_S = p.X_CS.inverse() * point;
      EXPECT_NEAR(p_S.z(), scene.Height(p_S.x(), p_S.y()), 1e-10);
    }
  }
}

TEST(LaserScene, ColumnCentroidsFollowTheExactStripeOnTheBoard) {
  const auto camera = ScannerCamera();
  LaserSceneParameters p = FixedLaserOff();
  p.surface = LaserSurfaceKind::kBoard;
  // Tilt the board so that the stripe is slanted in the image.
  p.X_CS = Eigen::Translation3d(0.0, 0.0, 0.42) *
           Eigen::AngleAxisd(0.3, Eigen::Vector3d(0.3, 1.0, 0.2).normalized()) *
           Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX());
  const LaserScene scene(p);
  int columns = 0;
  const double worst = WorstColumnError(*camera, scene, 20, 1600, 7, &columns);
  std::printf("board: %d columns, worst |centroid - exact| = %.4f px\n", columns, worst);
  EXPECT_GT(columns, 120);  // the board spans ≈ 1000 px
  EXPECT_LT(worst, 0.05);
}

TEST(LaserScene, ColumnCentroidsFollowTheExactStripeOnTheBladeWithPits) {
  const auto camera = ScannerCamera();
  LaserSceneParameters p = FixedLaserOff();
  p.curvature_xx = 2.0;  // R = 0.5 m across, like a turbine blade
  p.curvature_yy = 0.5;
  p.curvature_xy = 0.3;
  // Pits on and next to the stripe (it crosses y_S ≈ 2 mm at x_S = 0).
  p.pits = {{Eigen::Vector2d(0.02, 0.002), 1.0e-3, 3e-3},
            {Eigen::Vector2d(-0.04, 0.004), 0.5e-3, 2e-3},
            {Eigen::Vector2d(0.06, -0.001), 0.3e-3, 1.5e-3}};
  const LaserScene scene(p);
  int columns = 0;
  const double worst = WorstColumnError(*camera, scene, 20, 1600, 5, &columns);
  std::printf("blade: %d columns, worst |centroid - exact| = %.4f px\n", columns, worst);
  EXPECT_GT(columns, 180);
  EXPECT_LT(worst, 0.05);
}

TEST(LaserScene, RowCentroidsFollowTheExactFixedStripeOnTheBlade) {
  // The fixed laser's stripe runs down the image: centroid per row against the projected curve
  // (the same helpers with u and v swapped).
  const auto camera = ScannerCamera();
  LaserSceneParameters p;
  p.rotating_on = false;
  p.curvature_xx = -1.5;
  p.curvature_yy = 2.5;
  p.pits = {{Eigen::Vector2d(0.029, 0.01), 0.8e-3, 2e-3}};  // on the stripe (x_S ≈ 30 mm)
  const LaserScene scene(p);
  std::vector<Eigen::Vector2d> curve =
      ProjectCurve(*camera, scene.StripeCurve(LaserId::kFixed, 2e-5));
  for (Eigen::Vector2d& px : curve) px = Eigen::Vector2d(px.y(), px.x());  // (v, u)
  int rows = 0;
  double worst = 0.0;
  for (int v = 20; v < camera->height() - 20; v += 5) {
    const double u_exact = CurveRowAtColumn(curve, v);
    if (std::isnan(u_exact)) continue;
    const int u0 = static_cast<int>(std::lround(u_exact));
    std::vector<double> radiance;
    for (int u = u0 - 12; u <= u0 + 12; ++u) {
      Ray ray;
      ASSERT_EQ(camera->BackProject(Eigen::Vector2d(u, v), &ray), ProjectionStatus::kOk);
      radiance.push_back(scene.Trace(ray).radiance);
    }
    const double floor = *std::min_element(radiance.begin(), radiance.end());
    double sum = 0.0, first = 0.0;
    for (size_t i = 0; i < radiance.size(); ++i) {
      sum += radiance[i] - floor;
      first += (radiance[i] - floor) * (u0 - 12 + static_cast<int>(i));
    }
    if (sum < 0.3) continue;
    worst = std::max(worst, std::abs(first / sum - u_exact));
    ++rows;
  }
  std::printf("fixed stripe: %d rows, worst |centroid - exact| = %.4f px\n", rows, worst);
  EXPECT_GT(rows, 150);
  EXPECT_LT(worst, 0.08);  // 0.040 measured: the pit skews the profile
}

TEST(LaserScene, RenderedImageStripeFollowsTheExactCurve) {
  // Through the Renderer (full 1616×1216 frame, 8-bit): board with the gauge block, both lasers.
  const auto camera = ScannerCamera();
  LaserSceneParameters p;
  p.surface = LaserSurfaceKind::kBoard;
  p.gauge_block = true;
  p.gauge_centre_S = Eigen::Vector2d(-0.03, 0.0);
  p.gauge_heading = 0.2;
  const LaserScene scene(p);
  Renderer renderer(*camera, RenderOptions{});
  const int width = camera->width(), height = camera->height();
  std::vector<uint8_t> image(static_cast<size_t>(width) * height);
  GroundTruth truth;
  renderer.Render(scene, 0, ImageView8{image.data(), width, height, static_cast<size_t>(width)},
                  &truth);
  const std::vector<Eigen::Vector2d> curve =
      ProjectCurve(*camera, scene.StripeCurve(LaserId::kRotating, 2e-5));
  const double fixed_u = [&] {
    Eigen::Vector2d px;
    const LaserPlane& f = scene.plane(LaserId::kFixed);
    // The fixed stripe on the board near the optical axis: x = b_x' − cot θ_x z at z ≈ 0.4.
    EXPECT_EQ(camera->Project(
                  Eigen::Vector3d(f.point.x() - p.scanner.fixed_cot_theta_x * 0.4, 0, 0.4), &px),
              ProjectionStatus::kOk);
    return px.x();
  }();
  int columns = 0, block_columns = 0;
  double worst = 0.0;
  for (int u = 40; u < width - 40; u += 3) {
    if (std::abs(u - fixed_u) < 20) continue;  // the crossing with the fixed stripe
    const double v_exact = CurveRowAtColumn(curve, u);
    if (std::isnan(v_exact) || std::isnan(CurveRowAtColumn(curve, u - 8)) ||
        std::isnan(CurveRowAtColumn(curve, u + 8))) {
      continue;
    }
    // Only where the camera sees the exact stripe lit (not hidden by the block nor in its laser
    // shadow), and the window holds no other surface.
    Ray centre_ray;
    ASSERT_EQ(camera->BackProject(Eigen::Vector2d(u, v_exact), &centre_ray), ProjectionStatus::kOk);
    const int centre_object = scene.TraceDetailed(centre_ray).hit.object;
    bool clean = true;
    for (int dv = -12; dv <= 12 && clean; dv += 3) {
      Ray ray;
      ASSERT_EQ(camera->BackProject(Eigen::Vector2d(u, v_exact + dv), &ray), ProjectionStatus::kOk);
      const LaserHit hit = scene.TraceDetailed(ray);
      clean = hit.reached[1] && hit.hit.object == centre_object;
    }
    if (!clean) continue;
    const int v0 = static_cast<int>(std::lround(v_exact));
    int floor = 255;
    for (int v = v0 - 12; v <= v0 + 12; ++v) floor = std::min<int>(floor, image[v * width + u]);
    double sum = 0.0, first = 0.0;
    for (int v = v0 - 12; v <= v0 + 12; ++v) {
      const double w = image[v * width + u] - floor;
      sum += w;
      first += w * v;
    }
    if (sum < 50.0) continue;
    worst = std::max(worst, std::abs(first / sum - v_exact));
    ++columns;
    block_columns += truth.object[v0 * width + u] == kLaserGaugeBlock;
  }
  std::printf("rendered: %d columns (%d on the block), worst |centroid - exact| = %.4f px\n",
              columns, block_columns, worst);
  EXPECT_GT(columns, 250);
  EXPECT_GT(block_columns, 100);
  EXPECT_LT(worst, 0.1);  // 8-bit rounding of a σ ≈ 1.6 px profile
}

TEST(LaserScene, PitDeviatesTheStripeByTheGeometricAmount) {
  // A flat blade facing the camera at Z0, a pit of depth h and width σ centred on the nominal
  // stripe at x_C = 0. Column u = c_x sees exactly the points with x_C = 0 (radial distortion keeps
  // them there). Along it the stripe point solves y = b' − cot z, z = Z0 + h exp(−(y − y_0)²/2σ²)
  // (y_S = −y_C), i.e. the fixed point z = Z0 + h exp(−(cot (z − Z0))² / 2σ²).
  const auto camera = ScannerCamera();
  const auto& tsai = dynamic_cast<const TsaiCamera&>(*camera);
  const int u = static_cast<int>(tsai.parameters().cx);
  ASSERT_EQ(u, tsai.parameters().cx);
  LaserSceneParameters p = FixedLaserOff();
  const double Z0 = p.X_CS.translation().z();
  const double cot = p.rotating_cot_theta_y;
  const double b_prime = p.scanner.rotating_b_y + p.scanner.rotating_d_y * cot;
  const double y0 = b_prime - cot * Z0;
  const double h = 1.5e-3, sigma = 3e-3;
  LaserSceneParameters flat_p = p;
  const LaserScene flat(flat_p);
  p.pits = {{Eigen::Vector2d(0.0, -y0), h, sigma}};
  const LaserScene pitted(p);

  double z = Z0 + h;
  for (int k = 0; k < 100; ++k) {
    z = Z0 + h * std::exp(-std::pow(cot * (z - Z0), 2) / (2 * sigma * sigma));
  }
  Eigen::Vector2d v_flat, v_pit;
  ASSERT_EQ(camera->Project(Eigen::Vector3d(0, y0, Z0), &v_flat), ProjectionStatus::kOk);
  ASSERT_EQ(camera->Project(Eigen::Vector3d(0, b_prime - cot * z, z), &v_pit),
            ProjectionStatus::kOk);
  const double predicted = v_pit.y() - v_flat.y();
  const double measured = ColumnCentroid(*camera, pitted, u, v_pit.y(), 12) -
                          ColumnCentroid(*camera, flat, u, v_flat.y(), 12);
  std::printf("pit: predicted deviation %.4f px, measured %.4f px\n", predicted, measured);
  EXPECT_LT(predicted, -1.5);  // deeper → the stripe moves up the image (towards −y)
  // The centre of gravity sees the pit's slopes asymmetrically (the stripe's profile across the
  // pit is skewed), measured 0.04 px (2 %) short of the peak's exact deviation.
  EXPECT_NEAR(measured, predicted, 0.1);
}

// The first root of z_S − f(x_S, y_S) along a ray by brute force: march with steps of 10 µm of
// ray length (far below any pit's σ) through the slab |z_S| ≤ 3 cm, then bisect to 1e-14 m; only
// roots over the extent count. Independent of the scene's analytic quadric, pit culling and
// bracketing (issue 5's speed-up).
double ReferenceHeightfieldHit(const LaserScene& scene, const Ray& ray_C) {
  const LaserSceneParameters& p = scene.parameters();
  const Eigen::Isometry3d X_SC = p.X_CS.inverse();
  const Eigen::Vector3d o = X_SC * ray_C.p_C_O, d = X_SC.linear() * ray_C.d_C;
  auto g = [&](double t) {
    const Eigen::Vector3d q = o + t * d;
    return q.z() - scene.Height(q.x(), q.y());
  };
  double t0 = (0.03 - o.z()) / d.z(), t1 = (-0.03 - o.z()) / d.z();
  if (t0 > t1) std::swap(t0, t1);
  t0 = std::max(t0, 1e-9);
  const double step = 1e-5;
  double ta = t0, ga = g(ta);
  for (double tb = t0 + step; ta < t1; tb += step) {
    const double gb = g(tb);
    if ((ga > 0.0) != (gb > 0.0)) {
      double a = ta, b = tb;
      while (b - a > 1e-14) {
        const double c = 0.5 * (a + b);
        ((g(c) > 0.0) == (ga > 0.0) ? a : b) = c;
      }
      const Eigen::Vector3d q = o + a * d;
      if (std::abs(q.x()) <= p.half_extent.x() && std::abs(q.y()) <= p.half_extent.y()) return a;
    }
    ta = tb;
    ga = gb;
  }
  return kNoHit;
}

TEST(LaserScene, HeightfieldHitEqualsABruteForceMarchNearAndFarFromPits) {
  // The bench's blade (curved, two pits of different depth and width), rays from around the
  // scanner to random blade points — a third of them within 3σ of a pit — and some beyond the
  // blade's edge.
  LaserSceneParameters p;
  p.curvature_xx = 2.0;
  p.curvature_xy = -0.7;
  p.pits = {CavitationPit{Eigen::Vector2d(0.01, 0.0), 1.0e-3, 3e-3},
            CavitationPit{Eigen::Vector2d(-0.02, 0.015), 0.5e-3, 2e-3}};
  const LaserScene scene(p);
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  int hits = 0, near_pits = 0, misses = 0, worst_index = -1;
  double worst = 0.0, worst_normal = 0.0;
  for (int k = 0; k < 600; ++k) {
    Eigen::Vector2d xy(1.15 * p.half_extent.x() * unit(rng), 1.15 * p.half_extent.y() * unit(rng));
    if (k % 3 == 0) {
      const CavitationPit& pit = p.pits[k % 2];
      xy = pit.centre_S + 3.0 * pit.sigma * Eigen::Vector2d(unit(rng), unit(rng));
      ++near_pits;
    }
    const Eigen::Vector3d target_C =
        p.X_CS * Eigen::Vector3d(xy.x(), xy.y(), scene.Height(xy.x(), xy.y()));
    Ray ray;
    ray.p_C_O = Eigen::Vector3d(0.05 * unit(rng), 0.05 * unit(rng), 0.0);
    ray.d_C = (target_C - ray.p_C_O).normalized();
    const double expected = ReferenceHeightfieldHit(scene, ray);
    int object = -1;
    Eigen::Vector3d n_C;
    const double t = scene.IntersectSurface(ray, &object, &n_C);
    if (expected == kNoHit) {
      ++misses;
      EXPECT_EQ(t, kNoHit) << k;
      EXPECT_EQ(object, kLaserBackground) << k;
      continue;
    }
    ++hits;
    ASSERT_NE(t, kNoHit) << k;
    EXPECT_EQ(object, kLaserSurface);
    if (std::abs(t - expected) > worst) {
      worst = std::abs(t - expected);
      worst_index = k;
    }
    // The normal: −∇(z − f) normalised, by central differences of Height() (step 1 µm).
    const Eigen::Vector3d p_S = p.X_CS.inverse() * (ray.p_C_O + t * ray.d_C);
    const double e = 1e-6;
    const double fx =
        (scene.Height(p_S.x() + e, p_S.y()) - scene.Height(p_S.x() - e, p_S.y())) / (2 * e);
    const double fy =
        (scene.Height(p_S.x(), p_S.y() + e) - scene.Height(p_S.x(), p_S.y() - e)) / (2 * e);
    Eigen::Vector3d n_fd = p.X_CS.linear() * Eigen::Vector3d(-fx, -fy, 1.0).normalized();
    if (n_fd.dot(ray.d_C) > 0.0) n_fd = -n_fd;
    worst_normal = std::max(worst_normal, (n_C - n_fd).norm());
  }
  std::printf(
      "heightfield: %d hits (%d aimed at pits), %d misses; worst |t - t_ref| = %.2e m "
      "(ray %d), worst normal error %.2e\n",
      hits, near_pits, misses, worst, worst_index, worst_normal);
  EXPECT_LT(worst, 1e-11);
  EXPECT_LT(worst_normal, 1e-6);
  EXPECT_GT(hits, 450);
  EXPECT_GT(misses, 20);
}

TEST(LaserScene, GaugeBlockShadowsTheBoardFromTheRotatingLaser) {
  // cot θ_y chosen so that the rotating plane meets the board (z = 0.4) at y = −26 mm, 1 mm past
  // the block's edge (its 50 mm side along y): the light to that point grazes the block's top.
  const auto camera = ScannerCamera();
  LaserSceneParameters p = FixedLaserOff();
  p.surface = LaserSurfaceKind::kBoard;
  p.gauge_block = true;
  const double y_board = -0.026;
  p.rotating_cot_theta_y = (p.scanner.rotating_b_y - y_board) / (0.4 - p.scanner.rotating_d_y);
  const LaserScene with_shadows(p);
  p.laser_shadows = false;
  const LaserScene without(p);
  Eigen::Vector2d pixel;
  ASSERT_EQ(camera->Project(Eigen::Vector3d(0.0, y_board, 0.4), &pixel), ProjectionStatus::kOk);
  Ray ray;
  ASSERT_EQ(camera->BackProject(pixel, &ray), ProjectionStatus::kOk);
  const LaserHit shadowed = with_shadows.TraceDetailed(ray);
  const LaserHit lit = without.TraceDetailed(ray);
  ASSERT_EQ(shadowed.hit.object, kLaserSurface);  // the camera sees the board past the block
  EXPECT_NEAR(shadowed.plane_distance[1], 0.0, 1e-9);
  EXPECT_FALSE(shadowed.reached[1]);
  EXPECT_TRUE(lit.Lit(LaserId::kRotating));
  EXPECT_GT(lit.hit.radiance - shadowed.hit.radiance, 0.8);
  // The block's top carries the stripe 10 mm nearer: y = b' − cot (0.4 − 0.01).
  const double b_prime = p.scanner.rotating_b_y + p.scanner.rotating_d_y * p.rotating_cot_theta_y;
  const Eigen::Vector3d on_top(0.01, b_prime - p.rotating_cot_theta_y * 0.39, 0.39);
  ASSERT_EQ(camera->Project(on_top, &pixel), ProjectionStatus::kOk);
  ASSERT_EQ(camera->BackProject(pixel, &ray), ProjectionStatus::kOk);
  const LaserHit top = with_shadows.TraceDetailed(ray);
  EXPECT_EQ(top.hit.object, kLaserGaugeBlock);
  EXPECT_TRUE(top.Lit(LaserId::kRotating));
  EXPECT_LT((top.p_C - on_top).norm(), 1e-9);
}

TEST(LaserScene, BadParametersAreNamedInOneMessage) {
  LaserSceneParameters p;
  p.stripe_sigma = 0.01;
  p.pits = {{Eigen::Vector2d::Zero(), -1.0, 2e-3}};
  p.scanner.rotating_b_y = std::nan("");
  EXPECT_THAT(
      p.Validate(),
      ::testing::MatchesRegex(
          ".*rotating_b_y: must be finite, got nan.*pits\\[0\\]\\.depth: must be .*, got -1.*"
          "stripe_sigma: must be .*, got 0.01"));
  EXPECT_THROW(LaserScene{p}, std::invalid_argument);
  EXPECT_EQ(LaserSceneParameters().Validate(), "");
}

// Issue 7's calibration board: the seed's 9 × 9 dots at 26.5 mm darken the board (and the laser
// light) by their albedo, inside their radius only; the rendered dots are anti-aliased (edge pixels
// take intermediate grey levels) and their darkness centroids are the projected discs' centroids.
TEST(LaserScene, DotGridDarkensTheBoardInsideTheDots) {
  LaserSceneParameters p;
  p.surface = LaserSurfaceKind::kBoard;
  p.half_extent = Eigen::Vector2d(0.15, 0.15);
  p.dot_grid = true;
  p.ambient = 0.6;
  p.rotating_on = false;
  p.fixed_on = false;
  p.X_CS = Eigen::Translation3d(0.0, 0.0, 0.5) * Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX());
  const LaserScene scene(p);
  LaserSceneParameters plain_parameters = p;
  plain_parameters.dot_grid = false;
  const LaserScene plain(plain_parameters);
  const DotGrid& dots = p.dots;
  EXPECT_NEAR(dots.DotCentre_S(8, 8).x(), 4 * 0.0265, 1e-15);
  EXPECT_NEAR(dots.DotCentre_S(0, 0).y(), -4 * 0.0265, 1e-15);
  auto radiance_at = [&](const Eigen::Vector2d& p_S) {
    Ray ray;
    ray.d_C = (p.X_CS * Eigen::Vector3d(p_S.x(), p_S.y(), 0.0)).normalized();
    const LaserHit hit = scene.TraceDetailed(ray);
    EXPECT_EQ(hit.hit.object, kLaserSurface);
    // Relative to the same ray on the board without dots (the shading varies with the angle).
    return std::make_pair(hit.hit.radiance / plain.Trace(ray).radiance, hit.reflectance);
  };
  const auto [board_ratio, board_reflectance] = radiance_at(Eigen::Vector2d(0.013, 0.013));
  EXPECT_EQ(board_reflectance, 1.0);
  EXPECT_EQ(board_ratio, 1.0);
  for (const Eigen::Vector2d& offset :
       {Eigen::Vector2d(0.0, 0.0), Eigen::Vector2d(0.0049, 0.0), Eigen::Vector2d(0.0, -0.0049)}) {
    const auto [r, reflectance] = radiance_at(dots.DotCentre_S(3, 5) + offset);
    EXPECT_EQ(reflectance, dots.albedo);
    EXPECT_NEAR(r, dots.albedo, 1e-15);
  }
  EXPECT_EQ(radiance_at(dots.DotCentre_S(3, 5) + Eigen::Vector2d(0.0051, 0.0)).second, 1.0);
  // Rendered: the dot at the grid's centre, its darkness centroid on its centre's image.
  const auto camera = ScannerCamera();
  Renderer renderer(*camera, RenderOptions{});
  std::vector<uint8_t> image(static_cast<size_t>(camera->width()) * camera->height());
  renderer.Render(scene, 0,
                  ImageView8{image.data(), camera->width(), camera->height(),
                             static_cast<size_t>(camera->width())});
  Eigen::Vector2d centre;
  ASSERT_EQ(camera->Project(p.X_CS * Eigen::Vector3d::Zero(), &centre), ProjectionStatus::kOk);
  const int level = image[static_cast<size_t>(centre.y() + 40) * camera->width() + centre.x()];
  double sum = 0.0;
  Eigen::Vector2d first = Eigen::Vector2d::Zero();
  int intermediate = 0;
  for (int v = static_cast<int>(centre.y()) - 30; v <= centre.y() + 30; ++v) {
    for (int u = static_cast<int>(centre.x()) - 30; u <= centre.x() + 30; ++u) {
      const int g = image[static_cast<size_t>(v) * camera->width() + u];
      sum += std::max(0, level - g);
      first += std::max(0, level - g) * Eigen::Vector2d(u, v);
      intermediate += g > 0.25 * level && g < 0.75 * level;
    }
  }
  EXPECT_LT((first / sum - centre).norm(), 0.02);
  EXPECT_GT(intermediate, 40);  // anti-aliased rim (≈ 2π · 21 px)
  // The grid must fit the board, and only the board has one.
  LaserSceneParameters small = p;
  small.half_extent = Eigen::Vector2d(0.1, 0.15);
  EXPECT_THAT(small.Validate(),
              ::testing::ContainsRegex("dots \\(x reach\\): must be <= half_extent.x \\(the grid "
                                       "must fit the board\\), got 0.111"));
  LaserSceneParameters blade = p;
  blade.surface = LaserSurfaceKind::kBlade;
  EXPECT_THAT(blade.Validate(), ::testing::ContainsRegex("dot_grid: only on the board"));
  LaserSceneParameters bad = p;
  bad.dots.dot_radius = 0.02;
  EXPECT_THAT(bad.Validate(), ::testing::ContainsRegex(
                                  "dots.dot_radius: must be in \\(0, pitch / 2\\) m, got 0.02"));
}

// TraceBatch (issue 5's two-rays-at-a-time path) gives exactly Trace()'s hits, bit for bit: every
// third pixel-centre ray of the scanner camera row by row (shared origin), and random rays from
// random origins (one origin per ray), on the blade with pits (the fast path, with its fall-backs),
// a flat blade, the board with the gauge block and the board with the dot grid (Trace()
// throughout).
TEST(LaserScene, TraceBatchEqualsTraceBitForBit) {
  const std::unique_ptr<CameraModel> camera = ScannerCamera();
  LaserSceneParameters pitted;
  pitted.curvature_xx = 2.0;
  pitted.curvature_xy = -0.7;
  pitted.pits = {CavitationPit{Eigen::Vector2d(0.01, 0.0), 1.0e-3, 3e-3},
                 CavitationPit{Eigen::Vector2d(-0.02, 0.015), 0.5e-3, 2e-3}};
  LaserSceneParameters flat;
  LaserSceneParameters board;
  board.surface = LaserSurfaceKind::kBoard;
  board.gauge_block = true;
  board.gauge_centre_S = Eigen::Vector2d(0.01, -0.005);
  LaserSceneParameters dotted = board;  // issue 7's calibration board: the dot grid
  dotted.gauge_block = false;
  dotted.dot_grid = true;
  dotted.half_extent = Eigen::Vector2d(0.15, 0.15);
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  for (const LaserSceneParameters& p : {pitted, flat, board, dotted}) {
    const LaserScene scene(p);
    int compared = 0, lit = 0, surface = 0, different = 0;
    auto compare = [&](const Eigen::Vector3d& o, const Eigen::Vector3d& d, const Hit& batch) {
      Ray ray;
      ray.p_C_O = o;
      ray.d_C = d;
      const Hit one = scene.Trace(ray);
      // Bits, not values: == would let −0.0 pass for 0.0 (and the depths may be +inf).
      if (std::memcmp(&one.radiance, &batch.radiance, sizeof(double)) != 0 ||
          std::memcmp(&one.depth, &batch.depth, sizeof(double)) != 0 ||
          one.object != batch.object) {
        ++different;
      }
      ++compared;
      surface += one.object == kLaserSurface ? 1 : 0;
      lit += one.radiance > 0.3 ? 1 : 0;
    };
    std::vector<Eigen::Vector3d> directions, origins;
    std::vector<Hit> hits;
    for (int v = 0; v < camera->height(); v += 3) {
      directions.clear();
      Eigen::Vector3d origin = Eigen::Vector3d::Zero();
      for (int u = v % 2; u < camera->width(); u += 3) {  // odd and even batch lengths
        Ray ray;
        ASSERT_EQ(camera->BackProject(Eigen::Vector2d(u, v), &ray), ProjectionStatus::kOk);
        origin = ray.p_C_O;
        directions.push_back(ray.d_C);
      }
      hits.assign(directions.size(), Hit{});
      RayBatch batch;
      batch.origins = &origin;
      batch.shared_origin = true;
      batch.directions = directions.data();
      batch.count = static_cast<int>(directions.size());
      scene.TraceBatch(batch, hits.data());
      for (size_t k = 0; k < directions.size(); ++k) compare(origin, directions[k], hits[k]);
    }
    directions.clear();
    for (int k = 0; k < 20001; ++k) {
      origins.push_back(Eigen::Vector3d(0.05 * unit(rng), 0.05 * unit(rng), 0.1 * unit(rng)));
      directions.push_back(Eigen::Vector3d(0.3 * unit(rng), 0.3 * unit(rng), 1.0).normalized());
    }
    hits.assign(directions.size(), Hit{});
    RayBatch batch;
    batch.origins = origins.data();
    batch.directions = directions.data();
    batch.count = static_cast<int>(directions.size());
    scene.TraceBatch(batch, hits.data());
    for (size_t k = 0; k < directions.size(); ++k) compare(origins[k], directions[k], hits[k]);
    std::printf("TraceBatch: %d rays, %d on the surface, %d lit, %d different\n", compared, surface,
                lit, different);
    EXPECT_EQ(different, 0);
    EXPECT_GT(surface, compared / 4);
    EXPECT_GT(lit, 500);
  }
}

// X_SB (the gauge block's frame, shared by the scene, the weld cell's truth and the mount
// calibration): worked by hand for a block at (10, −5) mm turned by 90°: its +x face centre
// (50, 0, 5) mm in B is 50 mm along y_S from the centre, on top of the 5 mm half height.
TEST(LaserScene, GaugeBlockFrameIsItsCentreTurnedByTheHeading) {
  LaserSceneParameters p;
  p.surface = LaserSurfaceKind::kBoard;
  p.gauge_block = true;
  p.gauge_centre_S = Eigen::Vector2d(0.010, -0.005);
  p.gauge_heading = M_PI / 2;
  const Eigen::Vector3d p_S = p.X_SB() * Eigen::Vector3d(0.050, 0.0, 0.005);
  EXPECT_NEAR(p_S.x(), 0.010, 1e-12);
  EXPECT_NEAR(p_S.y(), 0.045, 1e-12);
  EXPECT_NEAR(p_S.z(), 0.010, 1e-12);
}

}  // namespace
}  // namespace kinevis::vision::render
