#include "vision/laser/scanner_model.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <random>
#include <vector>

#include "vision/camera/camera_file.h"
#include "vision/render/scenes/laser_scene.h"

namespace kinevis::vision::laser {
namespace {

using render::LaserId;
using render::LaserScene;
using render::LaserSceneParameters;

std::unique_ptr<CameraModel> ScannerCamera() { return BuiltinCameraModel("tsai-seed004"); }

// A curved blade with a pit, both lasers on (the planes are what matter here).
LaserSceneParameters Blade(double cot_theta_y) {
  LaserSceneParameters p;
  p.rotating_cot_theta_y = cot_theta_y;
  p.curvature_xx = 2.0;
  p.curvature_yy = -1.0;
  p.curvature_xy = 0.4;
  p.pits = {{Eigen::Vector2d(0.01, 0.0), 1.0e-3, 3e-3}};
  return p;
}

TEST(ScannerModel, PlanesAreTheLaserScenesPlanes) {
  const ScannerGeometry g;
  const render::LaserScannerGeometry scene_geometry = ToSceneGeometry(g);
  for (double cot : {0.1, 0.25, 0.6}) {
    const Eigen::Vector4d plane = g.RotatingPlane(cot);
    const render::LaserPlane scene = scene_geometry.RotatingPlane(cot);
    EXPECT_LT((plane.head<3>().normalized() - scene.normal).norm(), 1e-15);
    EXPECT_NEAR(plane.head<3>().dot(scene.point), plane.w(), 1e-15);
  }
  const Eigen::Vector4d fixed = g.FixedPlane();
  EXPECT_LT((fixed.head<3>().normalized() - scene_geometry.FixedPlane().normal).norm(), 1e-15);
  EXPECT_NEAR(fixed.head<3>().dot(scene_geometry.FixedPlane().point), fixed.w(), 1e-15);
  const ScannerGeometry back = FromSceneGeometry(scene_geometry);
  EXPECT_EQ(back.rotating_b_y, g.rotating_b_y);
  EXPECT_EQ(back.rotating_d_y, g.rotating_d_y);
  EXPECT_EQ(back.fixed_b_x_prime, g.fixed_b_x_prime);
  EXPECT_EQ(back.fixed_cot_theta_x, g.fixed_cot_theta_x);
}

// Eq. 9 and 10 through the Tsai camera give back the scene's exact stripe points (seen at their
// projected pixels), for several angles of the rotating laser, over the whole stripe.
TEST(ScannerModel, TriangulationRecoversTheScenesStripePoints) {
  const auto camera = ScannerCamera();
  const ScannerModel model(*camera, ScannerGeometry::Seed004());
  for (double cot : {0.18, 0.25, 0.4}) {
    const LaserScene scene(Blade(cot));
    int checked = 0;
    for (LaserId id : {LaserId::kRotating, LaserId::kFixed}) {
      for (const Eigen::Vector3d& truth : scene.StripeCurve(id, 2e-3)) {
        Eigen::Vector2d pixel;
        if (camera->Project(truth, &pixel) != ProjectionStatus::kOk || !camera->InImage(pixel)) {
          continue;
        }
        Eigen::Vector3d p;
        const TriangulationStatus status = id == LaserId::kRotating
                                               ? model.TriangulateRotating(pixel, cot, &p)
                                               : model.TriangulateFixed(pixel, &p);
        ASSERT_EQ(status, TriangulationStatus::kOk);
        EXPECT_LT((p - truth).norm(), 1e-9) << truth.transpose();
        ++checked;
      }
    }
    EXPECT_GT(checked, 150);
  }
}

// Eq. 11: the image of the stripes' intersection gives the rotating laser's angle.
TEST(ScannerModel, IntersectionGivesTheRotatingLasersAngle) {
  const auto camera = ScannerCamera();
  const ScannerGeometry g;
  const ScannerModel model(*camera, g);
  for (double cot : {0.15, 0.25, 0.45}) {
    for (double depth : {0.25, 0.4, 0.65}) {
      // The intersection line of the two planes, at z = depth: x = b_x' − cot θ_x z,
      // y = b_y' − cot θ_y z.
      const Eigen::Vector3d p(g.fixed_b_x_prime - g.fixed_cot_theta_x * depth,
                              g.RotatingBPrime(cot) - cot * depth, depth);
      Eigen::Vector2d pixel;
      ASSERT_EQ(camera->Project(p, &pixel), ProjectionStatus::kOk);
      double estimate = 0.0;
      ASSERT_EQ(model.CotThetaYFromIntersection(pixel, &estimate), TriangulationStatus::kOk);
      EXPECT_NEAR(estimate, cot, 1e-10) << "depth " << depth;
    }
  }
}

// Central differences of a vector function of a few scalars.
template <typename F>
Eigen::MatrixXd NumericJacobian(F f, const Eigen::VectorXd& x, double step) {
  const Eigen::VectorXd f0 = f(x);
  Eigen::MatrixXd J(f0.size(), x.size());
  for (int i = 0; i < x.size(); ++i) {
    Eigen::VectorXd xp = x, xm = x;
    xp(i) += step;
    xm(i) -= step;
    J.col(i) = (f(xp) - f(xm)) / (2.0 * step);
  }
  return J;
}

ScannerGeometry WithParameters(const Eigen::VectorXd& q) {
  ScannerGeometry g;
  g.rotating_b_y = q(kRotatingBy);
  g.rotating_d_y = q(kRotatingDy);
  g.fixed_b_x_prime = q(kFixedBxPrime);
  g.fixed_cot_theta_x = q(kFixedCotThetaX);
  return g;
}

TEST(ScannerModel, JacobiansMatchCentralDifferences) {
  const auto camera = ScannerCamera();
  const ScannerGeometry g0;
  const ScannerModel model(*camera, g0);
  Eigen::VectorXd q0(kScannerParameters);
  q0 << g0.rotating_b_y, g0.rotating_d_y, g0.fixed_b_x_prime, g0.fixed_cot_theta_x, 0.27;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(40.0, 1570.0), v(40.0, 1170.0);
  int checked[3] = {0, 0, 0};
  for (int trial = 0; trial < 20; ++trial) {
    const Eigen::Vector2d pixel(u(rng), v(rng));
    for (int laser = 0; laser < 3; ++laser) {  // rotating, fixed, eq. 11
      auto evaluate = [&](const ScannerModel& m, const Eigen::Vector2d& px, double cot,
                          Eigen::VectorXd* out) {
        Eigen::Vector3d p;
        TriangulationStatus status;
        if (laser == 0) {
          status = m.TriangulateRotating(px, cot, &p);
          *out = p;
        } else if (laser == 1) {
          status = m.TriangulateFixed(px, &p);
          *out = p;
        } else {
          double c = 0.0;
          status = m.CotThetaYFromIntersection(px, &c);
          *out = Eigen::VectorXd::Constant(1, c);
        }
        return status;
      };
      Eigen::VectorXd value;
      if (evaluate(model, pixel, q0(kRotatingCotThetaY), &value) != TriangulationStatus::kOk) {
        continue;  // e.g. the fixed laser's plane met behind the camera for this pixel
      }
      ++checked[laser];
      Eigen::MatrixXd J_pixel, J_parameters;
      if (laser < 2) {
        TriangulationJacobian J;
        Eigen::Vector3d p;
        if (laser == 0) {
          model.TriangulateRotating(pixel, q0(kRotatingCotThetaY), &p, &J);
        } else {
          model.TriangulateFixed(pixel, &p, &J);
        }
        J_pixel = J.d_point_d_pixel;
        J_parameters = J.d_point_d_parameters;
      } else {
        double c = 0.0;
        Eigen::RowVector2d Jp;
        RowVector5d Jq;
        model.CotThetaYFromIntersection(pixel, &c, &Jp, &Jq);
        J_pixel = Jp;
        J_parameters = Jq;
      }
      const Eigen::MatrixXd numeric_pixel = NumericJacobian(
          [&](const Eigen::VectorXd& x) {
            Eigen::VectorXd out;
            evaluate(model, Eigen::Vector2d(x(0), x(1)), q0(kRotatingCotThetaY), &out);
            return out;
          },
          Eigen::VectorXd(pixel), 1e-3);
      const Eigen::MatrixXd numeric_parameters = NumericJacobian(
          [&](const Eigen::VectorXd& q) {
            const ScannerModel perturbed(*camera, WithParameters(q));
            Eigen::VectorXd out;
            evaluate(perturbed, pixel, q(kRotatingCotThetaY), &out);
            return out;
          },
          q0, 1e-7);
      const double scale_pixel = std::max(1e-9, numeric_pixel.norm());
      const double scale_parameters = std::max(1e-9, numeric_parameters.norm());
      EXPECT_LT((J_pixel - numeric_pixel).norm() / scale_pixel, 1e-6)
          << "laser " << laser << " pixel " << pixel.transpose() << "\n"
          << J_pixel << "\n"
          << numeric_pixel;
      EXPECT_LT((J_parameters - numeric_parameters).norm() / scale_parameters, 1e-6)
          << "laser " << laser << " pixel " << pixel.transpose() << "\n"
          << J_parameters << "\n"
          << numeric_parameters;
      if (laser == 0) {
        EXPECT_EQ(J_parameters.col(kFixedBxPrime).norm(), 0.0);
      } else {
        EXPECT_EQ(J_parameters.col(kRotatingCotThetaY).norm(), 0.0);
      }
    }
  }
  EXPECT_GE(checked[0], 15);
  EXPECT_GE(checked[1], 5);  // the fixed plane is met in front only left of u ≈ 936 px
  EXPECT_GE(checked[2], 5);
}

TEST(ScannerModel, RaysThatCannotMeetThePlaneAreReported) {
  const auto camera = ScannerCamera();
  const ScannerGeometry g;
  const ScannerModel model(*camera, g);
  Eigen::Vector3d p;
  // The rotating plane y + c z = b_y' meets the rays with b = −c (parallel): pick a pixel on that
  // image row.
  const double cot = 0.05;
  Eigen::Vector2d pixel;
  ASSERT_EQ(camera->Project(Eigen::Vector3d(0.0, -cot, 1.0), &pixel), ProjectionStatus::kOk);
  EXPECT_EQ(model.TriangulateRotating(pixel, cot, &p), TriangulationStatus::kParallelToPlane);
  // Rays above that row (b < −c) meet the plane behind the camera.
  EXPECT_EQ(model.TriangulateRotating(pixel - Eigen::Vector2d(0.0, 50.0), cot, &p),
            TriangulationStatus::kBehindCamera);
  // The fixed plane x + cot θ_x z = b_x' < 0 is met in front only where a < −cot θ_x ... − x: the
  // image's right edge lies beyond it.
  EXPECT_EQ(model.TriangulateFixed(Eigen::Vector2d(1600.0, 600.0), &p),
            TriangulationStatus::kBehindCamera);
  // Outside the Tsai model's domain nothing is back-projected.
  EXPECT_EQ(model.TriangulateFixed(Eigen::Vector2d(1e6, 1e6), &p),
            TriangulationStatus::kCameraFailed);
  EXPECT_EQ(ToString(TriangulationStatus::kParallelToPlane), "ray parallel to the laser plane");
}

TEST(ScannerModel, BadGeometryAndNonCentralCamerasAreRefusedByName) {
  const auto camera = ScannerCamera();
  ScannerGeometry g;
  g.rotating_b_y = std::nan("");
  g.fixed_b_x_prime = 0.0;
  try {
    const ScannerModel model(*camera, g);
    FAIL() << "accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), ::testing::ContainsRegex("rotating_b_y: [^;]*, got nan"));
    EXPECT_THAT(e.what(), ::testing::ContainsRegex("fixed_b_x_prime: must be finite[^;]*, got 0"));
  }
  const auto mirror = BuiltinCameraModel("hyperbolic-mirror-4mm");
  ASSERT_FALSE(mirror->IsCentral());
  EXPECT_THROW(
      {
        try {
          const ScannerModel model(*mirror, ScannerGeometry{});
        } catch (const std::invalid_argument& e) {
          EXPECT_THAT(e.what(), ::testing::ContainsRegex("not central"));
          throw;
        }
      },
      std::invalid_argument);
}

}  // namespace
}  // namespace kinevis::vision::laser
