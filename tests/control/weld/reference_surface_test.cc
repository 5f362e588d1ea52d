#include "control/weld/reference_surface.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <random>

#include "tests/control/weld/synthetic_blade.h"

namespace kinevis::control {
namespace {

using ::testing::HasSubstr;
using ::testing::MatchesRegex;

ReferenceSurface SomeSurface() {
  ReferenceSurface s;
  s.degree = 3;
  s.length_scale = 0.05;
  s.coefficients.resize(ReferenceSurface::CoefficientCount(3));
  s.coefficients << 1e-3, 2e-4, -3e-4, 1.5e-3, 4e-4, -8e-4, 2e-4, -1e-4, 3e-4, 5e-5;
  s.X_0R.linear() = Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 2, 3).normalized()).matrix();
  s.X_0R.translation() = Eigen::Vector3d(0.7, 0.05, 0.3);
  return s;
}

TEST(ReferenceSurface, GradientMatchesFiniteDifferences) {
  const ReferenceSurface s = SomeSurface();
  const double e = 1e-7;
  for (double u : {-0.04, 0.0, 0.013, 0.05}) {
    for (double v : {-0.03, 0.0, 0.021}) {
      const Eigen::Vector2d g = s.Gradient(u, v);
      EXPECT_NEAR(g.x(), (s.Height(u + e, v) - s.Height(u - e, v)) / (2 * e), 1e-8);
      EXPECT_NEAR(g.y(), (s.Height(u, v + e) - s.Height(u, v - e)) / (2 * e), 1e-8);
      // The normal is ⊥ to both tangents of the surface in 0.
      const Eigen::Vector3d tu = (s.Point0(u + e, v) - s.Point0(u - e, v)) / (2 * e);
      const Eigen::Vector3d tv = (s.Point0(u, v + e) - s.Point0(u, v - e)) / (2 * e);
      EXPECT_NEAR(s.Normal0(u, v).dot(tu), 0.0, 1e-7);
      EXPECT_NEAR(s.Normal0(u, v).dot(tv), 0.0, 1e-7);
      EXPECT_GT(s.Normal0(u, v).dot(s.X_0R.linear().col(2)), 0.0);
    }
  }
}

TEST(ReferenceSurface, DepthAndLineIntersection) {
  const ReferenceSurface s = SomeSurface();
  const Eigen::Vector3d P = s.Point0(0.01, -0.02), n = s.Normal0(0.01, -0.02);
  EXPECT_NEAR(s.Depth(P), 0.0, 1e-15);
  EXPECT_NEAR(s.Depth(P - 1e-3 * s.X_0R.linear().col(2)), 1e-3, 1e-12);
  const Eigen::Vector3d dir = (-n + Eigen::Vector3d(0.05, -0.03, 0.02)).normalized();
  const Eigen::Vector3d start = P - 0.015 * dir;
  double t = 0.0;
  ASSERT_TRUE(s.IntersectLine(start, dir, &t));
  EXPECT_NEAR(t, 0.015, 1e-9);
  EXPECT_FALSE(s.IntersectLine(start, s.X_0R.linear().col(0), &t));  // parallel to the surface
}

TEST(FitReferenceSurface, IgnoresPitsAndOutliers) {
  testing::SyntheticBlade blade = testing::DefaultTestBlade();
  blade.spacing = 0.4e-3;
  blade.outlier_fraction = 0.02;
  const WeldMap map = blade.Make();
  const ReferenceFit fit = FitReferenceSurface(map.p_0, {});
  ASSERT_TRUE(fit.ok()) << fit.message;
  EXPECT_EQ(fit.points, static_cast<int>(map.p_0.size()));
  // The pits and the outliers are what the fit rejects: a few %.
  EXPECT_LT(fit.inlier_fraction, 0.99);
  EXPECT_GT(fit.inlier_fraction, 0.9);
  EXPECT_NEAR(fit.inlier_rms, blade.noise, 0.3 * blade.noise);
  // z_R faces the robot (the default hint, the base origin): z_S.
  EXPECT_GT(fit.surface.X_0R.linear().col(2).dot(blade.X_0S.linear().col(2)), 0.99);
  double worst = 0.0;
  for (double x = -0.055; x <= 0.055; x += 0.005) {
    for (double y = -0.045; y <= 0.045; y += 0.005) {
      const Eigen::Vector3d p = blade.X_0S * Eigen::Vector3d(x, y, blade.ReferenceHeight(x, y));
      worst = std::max(worst, std::abs(fit.surface.Depth(p)));
    }
  }
  EXPECT_LT(worst, 0.02e-3) << "the robust reference follows the undamaged sheet";

  // Plain least squares on the same data is pulled by the pits: the robust estimator matters.
  const Eigen::Isometry3d X_R0 = fit.surface.X_0R.inverse();
  Eigen::MatrixXd A(map.p_0.size(), 6);
  Eigen::VectorXd b(map.p_0.size());
  const double L = fit.surface.length_scale;
  for (size_t k = 0; k < map.p_0.size(); ++k) {
    const Eigen::Vector3d q = X_R0 * map.p_0[k];
    const double x = q.x() / L, y = q.y() / L;
    A.row(k) << 1, x, y, x * x, x * y, y * y;
    b(k) = q.z();
  }
  ReferenceSurface ls = fit.surface;
  ls.coefficients = A.colPivHouseholderQr().solve(b);
  double ls_worst = 0.0;
  for (double x = -0.055; x <= 0.055; x += 0.005) {
    for (double y = -0.045; y <= 0.045; y += 0.005) {
      const Eigen::Vector3d p = blade.X_0S * Eigen::Vector3d(x, y, blade.ReferenceHeight(x, y));
      ls_worst = std::max(ls_worst, std::abs(ls.Depth(p)));
    }
  }
  EXPECT_GT(ls_worst, 5 * worst);
}

TEST(FitReferenceSurface, NormalsOrientTheFrame) {
  testing::SyntheticBlade blade = testing::DefaultTestBlade();
  blade.spacing = 1e-3;
  blade.normals = true;
  WeldMap map = blade.Make();
  for (auto& n : map.n_0) n = -n;  // a map whose normals point away from the robot
  const ReferenceFit fit = FitReferenceSurface(map.p_0, map.n_0);
  ASSERT_TRUE(fit.ok());
  EXPECT_LT(fit.surface.X_0R.linear().col(2).dot(blade.X_0S.linear().col(2)), -0.99);
  EXPECT_NEAR(fit.surface.X_0R.linear().determinant(), 1.0, 1e-12);
}

TEST(FitReferenceSurface, DegenerateDataIsReportedNotFitted) {
  std::vector<Eigen::Vector3d> line;
  for (int i = 0; i < 100; ++i) line.emplace_back(0.7, 0.001 * i, 0.3);
  const ReferenceFit a = FitReferenceSurface(line, {});
  EXPECT_EQ(a.status, ReferenceFitStatus::kDegenerate);
  EXPECT_THAT(a.message, HasSubstr("line"));
  const ReferenceFit b = FitReferenceSurface({Eigen::Vector3d(1, 2, 3)}, {});
  EXPECT_EQ(b.status, ReferenceFitStatus::kTooFewPoints);
  EXPECT_THAT(b.message, MatchesRegex("1 finite points, .* needs at least 18"));
}

TEST(FitReferenceSurface, BadInputThrows) {
  ReferenceFitOptions o;
  o.degree = 7;
  o.tukey_c = -1;
  EXPECT_THAT(o.Validate(), MatchesRegex(".*degree \\(1..4\\) = 7.*tukey_c.*= -1.*"));
  EXPECT_THROW(FitReferenceSurface({Eigen::Vector3d::Zero()}, {}, o), std::invalid_argument);
  try {
    FitReferenceSurface({Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones()},
                        {Eigen::Vector3d::UnitZ()});
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("1 normals for 2 points"));
  }
}

}  // namespace
}  // namespace kinevis::control
