#include "vision/diamond/spherical_positioning.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <random>

#include "vision/camera/camera_file.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/render/scenes/diamond_marker_scene.h"

namespace kinevis::vision {
namespace {

using ::testing::HasSubstr;
using ::testing::MatchesRegex;

constexpr double kR = 0.2221;  // seed Table I, identified radius (m)

// The seed's camera (1280×640, f = 1000 px; as the marker detector's tests), optionally with
// Brown distortion.
std::unique_ptr<CameraModel> SeedCamera(bool distorted) {
  PinholeBrownParameters p;
  p.width = 1280;
  p.height = 640;
  p.fx = p.fy = 1000.0;
  p.cx = 639.5;
  p.cy = 319.5;
  if (distorted) p.distortion = {-0.12, 0.05, 4e-4, -3e-4, 0, 0, 0, 0};
  return std::make_unique<PinholeBrownCamera>(p);
}

// The seed's placement: 45° from z_O towards the working region's centre, looking at the RCM.
Eigen::Isometry3d SeedPose(double distance) {
  return render::DiamondCameraPose(distance).inverse();
}

Eigen::Vector3d Point(double phi, double gamma, double r) {
  return r * Eigen::Vector3d(std::sin(gamma) * std::cos(phi), std::sin(gamma) * std::sin(phi),
                             std::cos(gamma));
}

Eigen::Isometry3d Perturbed(const Eigen::Isometry3d& X, const Eigen::Matrix<double, 6, 1>& xi) {
  Eigen::Isometry3d dX = Eigen::Isometry3d::Identity();
  if (xi.head<3>().norm() > 0) {
    dX.linear() = Eigen::AngleAxisd(xi.head<3>().norm(), xi.head<3>().normalized()).matrix();
  }
  dX.translation() = xi.tail<3>();
  return X * dX;
}

// Points of the working region projected into the camera come back from their pixels, on the
// near side, for a distorted and an undistorted pinhole at several placements.
TEST(SphericalPositioningTest, RecoversProjectedPointsOfTheWorkingRegion) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> phi(60 * M_PI / 180, 120 * M_PI / 180);
  std::uniform_real_distribution<double> gamma(30 * M_PI / 180, 65 * M_PI / 180);
  for (bool distorted : {false, true}) {
    const auto camera = SeedCamera(distorted);
    for (double distance : {0.35, 0.4462, 0.6}) {
      const Eigen::Isometry3d X_OC = SeedPose(distance);
      int checked = 0;
      for (int k = 0; k < 200; ++k) {
        const Eigen::Vector3d p_O = Point(phi(rng), gamma(rng), kR);
        // Only points on the camera's side of the sphere are visible.
        if ((X_OC.translation() - p_O).dot(p_O) <= 0) continue;
        Eigen::Vector2d pixel;
        if (camera->Project(X_OC.inverse() * p_O, &pixel) != ProjectionStatus::kOk) continue;
        const SphereFix fix = LocateOnSphere(*camera, X_OC, kR, pixel);
        ASSERT_EQ(fix.status, SphereFixStatus::kOk) << ToString(fix.status);
        EXPECT_LT((fix.p_O - p_O).norm(), 1e-9);
        EXPECT_NEAR(fix.task.x(), std::atan2(p_O.y(), p_O.x()), 1e-9);
        EXPECT_NEAR(std::cos(fix.task.y()), p_O.z() / kR, 1e-9);
        EXPECT_NEAR(fix.range, (X_OC.translation() - p_O).norm(), 1e-9);
        ++checked;
      }
      EXPECT_GT(checked, 100);
    }
  }
}

// A point on the far side of the sphere projects to a pixel whose fix is the near-side point on
// the same ray, where the outward normal faces the camera.
TEST(SphericalPositioningTest, TakesTheNearIntersection) {
  const auto camera = SeedCamera(false);
  const Eigen::Isometry3d X_OC = SeedPose(0.4462);
  const Eigen::Vector3d c = X_OC.translation();
  const Eigen::Vector3d far_point = Point(M_PI / 2 + 0.2, 3 * M_PI / 4, kR);  // behind the RCM
  ASSERT_LT((c - far_point).dot(far_point), 0.0);
  Eigen::Vector2d pixel;
  ASSERT_EQ(camera->Project(X_OC.inverse() * far_point, &pixel), ProjectionStatus::kOk);
  const SphereFix fix = LocateOnSphere(*camera, X_OC, kR, pixel);
  ASSERT_EQ(fix.status, SphereFixStatus::kOk);
  EXPECT_GT((fix.p_O - far_point).norm(), 0.05);
  EXPECT_GT((c - fix.p_O).dot(fix.p_O), 0.0);
  EXPECT_NEAR(fix.p_O.norm(), kR, 1e-12);
  // The near point lies on the segment from the camera to the far point.
  const Eigen::Vector3d along = (far_point - c).normalized();
  EXPECT_LT(((fix.p_O - c) - (fix.p_O - c).dot(along) * along).norm(), 1e-9);
  EXPECT_LT(fix.range, (far_point - c).norm());
}

TEST(SphericalPositioningTest, ReportsMissGrazingInsideAndFailedBackProjection) {
  const auto camera = SeedCamera(false);
  const Eigen::Isometry3d X_OC = SeedPose(0.4462);
  // The image corner at 0.4462 m sees past a 0.05 m sphere.
  EXPECT_EQ(LocateOnSphere(*camera, X_OC, 0.05, {0.0, 0.0}).status, SphereFixStatus::kMiss);
  // Camera inside the sphere.
  EXPECT_EQ(LocateOnSphere(*camera, X_OC, 0.5, {640, 320}).status,
            SphereFixStatus::kCameraInsideSphere);
  // A ray that just touches the silhouette: the silhouette's half-angle is asin(R/D) off axis.
  const double D = 0.4462;
  const double tangent_off_axis = std::tan(std::asin(kR / D));
  const double v_edge = 319.5 + 1000.0 * tangent_off_axis;
  SphereFix graze = LocateOnSphere(*camera, X_OC, kR, {639.5, v_edge - 0.05});
  EXPECT_EQ(graze.status, SphereFixStatus::kGrazing) << graze.incidence_cosine;
  EXPECT_LT(graze.incidence_cosine, 0.05);
  EXPECT_NEAR(graze.p_O.norm(), kR, 1e-12);  // still filled in, for diagnosis
  EXPECT_EQ(LocateOnSphere(*camera, X_OC, kR, {639.5, v_edge + 0.5}).status,
            SphereFixStatus::kMiss);
  SphericalPositioningOptions lax;
  lax.min_incidence_cosine = 0.0;
  EXPECT_EQ(LocateOnSphere(*camera, X_OC, kR, {639.5, v_edge - 0.05}, lax).status,
            SphereFixStatus::kOk);
  // Strong barrel distortion folds over: far outside the image there is no preimage.
  PinholeBrownParameters p;
  p.width = 1280;
  p.height = 640;
  p.fx = p.fy = 1000.0;
  p.cx = 639.5;
  p.cy = 319.5;
  p.distortion[0] = -0.5;
  const PinholeBrownCamera barrel(p);
  const SphereFix failed = LocateOnSphere(barrel, X_OC, kR, {20000.0, 20000.0});
  EXPECT_EQ(failed.status, SphereFixStatus::kBackProjectionFailed);
  EXPECT_NE(failed.projection, ProjectionStatus::kOk);
  EXPECT_STREQ(ToString(SphereFixStatus::kGrazing), "grazing");
}

TEST(SphericalPositioningTest, RefusesBadSetUpNamingTheField) {
  const auto camera = SeedCamera(false);
  const Eigen::Isometry3d X_OC = SeedPose(0.4462);
  try {
    LocateOnSphere(*camera, X_OC, -0.1, {640, 320});
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("radius = -0.1 m"));
  }
  Eigen::Isometry3d scaled = X_OC;
  scaled.linear() *= 1.01;
  EXPECT_THROW(
      {
        try {
          LocateOnSphere(*camera, scaled, kR, {640, 320});
        } catch (const std::invalid_argument& e) {
          EXPECT_THAT(e.what(), MatchesRegex(".*X_OC's linear part is not a rotation.*"));
          throw;
        }
      },
      std::invalid_argument);
  SphericalPositioningOptions bad;
  bad.min_incidence_cosine = 1.5;
  EXPECT_THAT(bad.Validate(), HasSubstr("min_incidence_cosine = 1.5"));
  EXPECT_THROW(LocateOnSphere(*camera, X_OC, kR, {640, 320}, bad), std::invalid_argument);
}

// Analytic ∂(φ,γ)/∂pixel, ∂(φ,γ)/∂pose and ∂(φ,γ)/∂R against central differences, for the
// distorted pinhole and for non-central and catadioptric models (their ray origins move with the
// pixel, exercising ∂o/∂pixel).
void CheckJacobians(const CameraModel& camera, const Eigen::Isometry3d& X_OC, double radius,
                    const Eigen::Vector2d& pixel) {
  const SphereFix fix = LocateOnSphere(camera, X_OC, radius, pixel);
  ASSERT_EQ(fix.status, SphereFixStatus::kOk) << ToString(fix.status);
  const auto task_at = [&](const Eigen::Isometry3d& X, double r, const Eigen::Vector2d& px) {
    const SphereFix f = LocateOnSphere(camera, X, r, px);
    EXPECT_NE(f.status, SphereFixStatus::kMiss);
    return f.task;
  };
  const double h_px = 1e-4;
  Eigen::Matrix2d num_px;
  Eigen::Matrix<double, 3, 2> num_point_px;
  for (int k = 0; k < 2; ++k) {
    Eigen::Vector2d e = Eigen::Vector2d::Zero();
    e[k] = h_px;
    num_px.col(k) =
        (task_at(X_OC, radius, pixel + e) - task_at(X_OC, radius, pixel - e)) / (2 * h_px);
    num_point_px.col(k) = (LocateOnSphere(camera, X_OC, radius, pixel + e).p_O -
                           LocateOnSphere(camera, X_OC, radius, pixel - e).p_O) /
                          (2 * h_px);
  }
  const double scale_px = fix.J_task_pixel.cwiseAbs().maxCoeff();
  EXPECT_LT((num_px - fix.J_task_pixel).cwiseAbs().maxCoeff(), 1e-6 * scale_px)
      << "analytic\n"
      << fix.J_task_pixel << "\nnumeric\n"
      << num_px;
  EXPECT_LT((num_point_px - fix.J_point_pixel).cwiseAbs().maxCoeff(),
            1e-6 * fix.J_point_pixel.cwiseAbs().maxCoeff());
  const double h = 1e-6;
  Eigen::Matrix<double, 2, 6> num_pose;
  for (int k = 0; k < 6; ++k) {
    Eigen::Matrix<double, 6, 1> xi = Eigen::Matrix<double, 6, 1>::Zero();
    xi[k] = h;
    num_pose.col(k) = (task_at(Perturbed(X_OC, xi), radius, pixel) -
                       task_at(Perturbed(X_OC, -xi), radius, pixel)) /
                      (2 * h);
  }
  EXPECT_LT((num_pose - fix.J_task_pose).cwiseAbs().maxCoeff(),
            1e-6 * fix.J_task_pose.cwiseAbs().maxCoeff())
      << "analytic\n"
      << fix.J_task_pose << "\nnumeric\n"
      << num_pose;
  const Eigen::Vector2d num_r =
      (task_at(X_OC, radius + h, pixel) - task_at(X_OC, radius - h, pixel)) / (2 * h);
  // (Zero at the pixel whose ray passes through the RCM: R moves the hit along the ray.)
  EXPECT_LE((num_r - fix.J_task_radius).cwiseAbs().maxCoeff(),
            1e-6 * fix.J_task_radius.cwiseAbs().maxCoeff() + 1e-12);
}

TEST(SphericalPositioningTest, JacobiansMatchCentralDifferencesPinhole) {
  const auto camera = SeedCamera(true);
  const Eigen::Isometry3d X_OC = SeedPose(0.4462);
  for (const Eigen::Vector2d& px : {Eigen::Vector2d(639.5, 319.5), Eigen::Vector2d(900, 100),
                                    Eigen::Vector2d(300, 500), Eigen::Vector2d(1100, 600)}) {
    SCOPED_TRACE(px.transpose());
    CheckJacobians(*camera, X_OC, kR, px);
  }
}

// For any camera: back-project a pixel, put the sphere's centre where the ray enters a sphere of
// radius R obliquely at range 0.4 m, and rotate O arbitrarily.
TEST(SphericalPositioningTest, JacobiansMatchCentralDifferencesOtherModels) {
  for (const char* name :
       {"hyperbolic-mirror-6mm", "unified-default", "scaramuzza-default", "tsai-seed004"}) {
    SCOPED_TRACE(name);
    const auto camera = BuiltinCameraModel(name);
    const Eigen::Vector2d pixel(0.37 * camera->width(), 0.41 * camera->height());
    Ray ray;
    ASSERT_EQ(camera->BackProject(pixel, &ray), ProjectionStatus::kOk);
    const double radius = 0.15;
    Eigen::Vector3d n = -ray.d_C + 0.6 * ray.d_C.unitOrthogonal();  // outward normal at the hit
    n.normalize();
    const Eigen::Vector3d c_C = ray.p_C_O + 0.4 * ray.d_C - radius * n;  // the sphere's centre
    Eigen::Isometry3d X_OC = Eigen::Isometry3d::Identity();
    X_OC.linear() =
        Eigen::AngleAxisd(0.7, Eigen::Vector3d(0.3, -0.5, 0.8).normalized()).toRotationMatrix();
    X_OC.translation() = -(X_OC.linear() * c_C);
    if (!camera->IsCentral()) {
      RayJacobian J;
      camera->BackProject(pixel, &ray, &J);
      EXPECT_GT(J.d_origin_d_pixel.norm(), 0.0);
    }
    CheckJacobians(*camera, X_OC, radius, pixel);
    EXPECT_GT(LocateOnSphere(*camera, X_OC, radius, pixel).J_task_radius.norm(), 1.0);
    EXPECT_NEAR(LocateOnSphere(*camera, X_OC, radius, pixel).range, 0.4, 1e-9);
  }
}

// Seed eq. (10)–(12), corrected (header): exact along the central column (the meridian φ = π/2),
// exact as a great-circle angle along the central row, an approximation elsewhere; the printed
// form of eq. (11) is not.
TEST(SphericalPositioningTest, SeedFormulaHoldsInItsConfiguration) {
  const auto camera = SeedCamera(false);
  const double D = 0.4462;
  const Eigen::Isometry3d X_OC = SeedPose(D);
  const Eigen::Vector3d axis_point = Point(M_PI / 2, M_PI / 4, kR);
  // (The silhouette is 574 px off the centre: the whole column sees the sphere.)
  for (double v = 20; v <= 620; v += 50) {
    const Eigen::Vector2d px(639.5, v);
    const SphereFix fix = LocateOnSphere(*camera, X_OC, kR, px);
    ASSERT_EQ(fix.status, SphereFixStatus::kOk);
    const Eigen::Vector2d seed = SeedSphericalPositioning(px, 1000, 1000, 639.5, 319.5, D, kR);
    EXPECT_NEAR(fix.task.x(), M_PI / 2, 1e-12);
    EXPECT_NEAR(fix.task.y(), seed.y(), 1e-12) << v;
    EXPECT_NEAR(seed.x(), M_PI / 2, 1e-15);
  }
  for (double u = 90; u <= 1190; u += 100) {
    const Eigen::Vector2d px(u, 319.5);
    const SphereFix fix = LocateOnSphere(*camera, X_OC, kR, px);
    ASSERT_EQ(fix.status, SphereFixStatus::kOk);
    const double great_circle = std::acos(fix.p_O.normalized().dot(axis_point.normalized()));
    EXPECT_NEAR(great_circle, std::abs(SeedCentralAngle((u - 639.5) / 1000, D, kR)), 1e-9) << u;
  }
  // Along the central row the seed's T_φ = π/2 − δ is the great-circle angle, not the azimuth:
  // the point is (sin δ, cos δ/√2, cos δ/√2), so φ = π/2 − atan(√2 tan δ), γ = acos(cos δ/√2).
  for (double u : {200.0, 500.0, 800.0, 1100.0}) {
    const Eigen::Vector2d px(u, 319.5);
    const SphereFix fix = LocateOnSphere(*camera, X_OC, kR, px);
    const double delta = SeedCentralAngle((u - 639.5) / 1000, D, kR);
    EXPECT_NEAR(fix.task.x(), M_PI / 2 - std::atan(std::sqrt(2.0) * std::tan(delta)), 1e-12);
    EXPECT_NEAR(fix.task.y(), std::acos(std::cos(delta) / std::sqrt(2.0)), 1e-12);
    const Eigen::Vector2d seed = SeedSphericalPositioning(px, 1000, 1000, 639.5, 319.5, D, kR);
    EXPECT_NEAR(seed.x(), M_PI / 2 - delta, 1e-15);
    EXPECT_GT(std::abs(seed.x() - fix.task.x()), 0.2 * std::abs(delta));  // (√2 − 1) δ near 0
  }
  // Off the centre lines the two 1-D maps are worse still: 0.17 rad in φ at (900, 450).
  const Eigen::Vector2d corner(900, 450);
  const SphereFix fix = LocateOnSphere(*camera, X_OC, kR, corner);
  ASSERT_EQ(fix.status, SphereFixStatus::kOk);
  const Eigen::Vector2d seed = SeedSphericalPositioning(corner, 1000, 1000, 639.5, 319.5, D, kR);
  EXPECT_GT((seed - fix.task).cwiseAbs().maxCoeff(), 0.1) << (seed - fix.task).transpose();
  // Eq. (11) as printed, asin((D/R) sin a − a), is a different (wrong) angle.
  const double a = std::atan(0.25);
  const double printed = std::asin(D / kR * std::sin(a) - a);
  EXPECT_GT(std::abs(printed - SeedCentralAngle(0.25, D, kR)), 0.01);
  EXPECT_TRUE(std::isnan(SeedCentralAngle(10.0, D, kR)));  // misses the sphere
}

}  // namespace
}  // namespace kinevis::vision
