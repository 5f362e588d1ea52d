#include "calibration/diamond/camera_placement.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>

#include "vision/camera/pinhole_camera.h"

namespace kinevis::calibration {
namespace {

using ::testing::HasSubstr;

constexpr double kR = 0.2;

// The seed's tan θ that puts the eq. (32) optimum at 44.62 cm for R = 20 cm, q = 5, β = π (from
// eq. 33 at r = 0.4462: tan²θ = 2qR³/(π A r²) − R⁴/A⁴).
double SeedTanTheta() {
  const double r = 0.4462, A = std::sqrt(r * r - kR * kR);
  return std::sqrt(2 * 5 * kR * kR * kR / (M_PI * A * r * r) - std::pow(kR / A, 4));
}

TEST(SphereSensitivityTest, ViewAngleRateIsTheDerivativeAndTheSeedsEq27) {
  for (double D : {0.3, 0.4462, 0.8}) {
    for (double delta : {0.0, 0.05, 0.3, 0.7, 1.0}) {
      const double h = 1e-6;
      const double numeric =
          (SphereViewAngle(kR, D, delta + h) - SphereViewAngle(kR, D, std::max(0.0, delta - h))) /
          (delta + h - std::max(0.0, delta - h));
      const double rate = SphereViewAngleRate(kR, D, delta);
      EXPECT_NEAR(rate, numeric, 1e-6) << D << " " << delta;
      // Seed eq. (25)–(27) at dδ → 0: (R/r) cos(θ + δ)(cos θ − tan(δ/2) sin θ), r = D − R.
      const double theta = SphereViewAngle(kR, D, delta);
      const double seed = kR / (D - kR) * std::cos(theta + delta) *
                          (std::cos(theta) - std::tan(delta / 2) * std::sin(theta));
      EXPECT_NEAR(rate, seed, 1e-12);
      // Eq. (28) with ε = 0 is the exact elasticity; ε > 0 lowers it.
      EXPECT_NEAR(SeedSensitivityEq28(kR, D, delta, 0.0), SphereViewElasticity(kR, D, delta),
                  1e-12);
      if (delta > 0.1) {
        EXPECT_LT(SeedSensitivityEq28(kR, D, delta, 0.05), SphereViewElasticity(kR, D, delta));
      }
      // Seed eq. (20): sin θ / sin δ = (R/r)(cos θ − tan(δ/2) sin θ).
      if (delta > 0) {
        EXPECT_NEAR(std::sin(theta) / std::sin(delta),
                    kR / (D - kR) * (std::cos(theta) - std::tan(delta / 2) * std::sin(theta)),
                    1e-12);
      }
    }
    // The silhouette: the rate vanishes at δ_max = acos(R/D) and the elasticity starts at 1.
    EXPECT_NEAR(SphereViewAngleRate(kR, D, MaxVisibleCentralAngle(kR, D)), 0.0, 1e-12);
    EXPECT_DOUBLE_EQ(SphereViewElasticity(kR, D, 0.0), 1.0);
    EXPECT_NEAR(SphereViewAngleRate(kR, D, 0.0), kR / (D - kR), 1e-12);
  }
  EXPECT_THROW(SphereViewAngle(kR, 0.1, 0.2), std::invalid_argument);
  EXPECT_THROW(SeedSensitivityEq28(kR, 0.5, 0.2, -1), std::invalid_argument);
}

TEST(CameraPlacementTest, DerivativeMatchesCentralDifferencesAndEq33) {
  CameraPlacementOptions o;
  o.half_view_angle = std::atan(0.5);
  for (double beta : {M_PI, M_PI / 2}) {
    o.roi_polar_extent = beta;
    for (double r : {0.25, 0.4, 0.7, 1.5}) {
      const double h = 1e-7;
      const double numeric =
          (EvaluateBenefit(o, r + h).benefit - EvaluateBenefit(o, r - h).benefit) / (2 * h);
      const BenefitTerms b = EvaluateBenefit(o, r);
      EXPECT_NEAR(b.derivative, numeric, 1e-6 * std::max(1.0, std::abs(numeric)));
      EXPECT_NEAR(b.benefit, o.weight * b.roi - b.waste, 1e-15);
    }
  }
  // Eq. (33) as printed (β = π) holds at the optimum.
  o.roi_polar_extent = M_PI;
  const CameraPlacement plan = PlanCameraPlacement(o);
  ASSERT_TRUE(plan.found);
  const double r = plan.best_distance, A = std::sqrt(r * r - kR * kR);
  EXPECT_NEAR(0.25 * std::pow(kR, -4), 2 * 5 / (M_PI * A * kR * r * r) - std::pow(A, -4),
              1e-6 * std::pow(kR, -4));
  EXPECT_NEAR(plan.at_best.derivative, 0.0, 1e-9);
  // A maximum: lower on both sides.
  EXPECT_GT(plan.at_best.benefit, EvaluateBenefit(o, r * 0.98).benefit);
  EXPECT_GT(plan.at_best.benefit, EvaluateBenefit(o, r * 1.02).benefit);
}

TEST(CameraPlacementTest, ReproducesTheSeeds4462cmForItsViewAngle) {
  CameraPlacementOptions o;
  o.weight = 5;
  o.half_view_angle = std::atan(SeedTanTheta());
  const CameraPlacement plan = PlanCameraPlacement(o);
  ASSERT_TRUE(plan.found);
  EXPECT_NEAR(plan.best_distance, 0.4462, 1e-6);
  EXPECT_NEAR(o.half_view_angle * 180 / M_PI, 26.90, 0.01);
  // The seed's camera (1280×640, f = 1000 px) has other half-angles: 17.7° vertically gives a
  // farther optimum (61.4 cm) and 32.6° horizontally a nearer one (37.6 cm).
  vision::PinholeBrownParameters p;
  p.width = 1280;
  p.height = 640;
  p.fx = p.fy = 1000;
  p.cx = 639.5;
  p.cy = 319.5;
  const vision::PinholeBrownCamera camera(p);
  const double vertical = HalfViewAngle(camera, ViewAxis::kVertical);
  const double horizontal = HalfViewAngle(camera, ViewAxis::kHorizontal);
  EXPECT_NEAR(std::tan(vertical), 0.32, 1e-12);
  EXPECT_NEAR(std::tan(horizontal), 0.64, 1e-12);
  EXPECT_NEAR(HalfViewAngle(camera, ViewAxis::kSmallest), vertical, 1e-15);
  o.half_view_angle = vertical;
  EXPECT_NEAR(PlanCameraPlacement(o).best_distance, 0.6137, 5e-4);
  o.half_view_angle = horizontal;
  EXPECT_NEAR(PlanCameraPlacement(o).best_distance, 0.3762, 5e-4);
  // The quarter sphere of §V-B (β = π/2) halves S_ROI: with the vertical angle, 43.5 cm.
  o.half_view_angle = vertical;
  o.roi_polar_extent = M_PI / 2;
  const CameraPlacement quarter = PlanCameraPlacement(o);
  ASSERT_TRUE(quarter.found);
  EXPECT_NEAR(quarter.best_distance, 0.4349, 5e-4);
  // That maximum lies where the sphere overflows the view (R / sin θ = 65.6 cm): noted.
  EXPECT_NEAR(quarter.full_view_distance, kR / std::sin(vertical), 1e-12);
  EXPECT_LT(quarter.at_best.waste, 0);
  EXPECT_THAT(quarter.notes, testing::Contains(HasSubstr("S_waste < 0")));
}

TEST(CameraPlacementTest, NoInteriorMaximumIsReported) {
  CameraPlacementOptions o;
  o.half_view_angle = std::atan(1.0);  // a wide lens: J only falls
  const CameraPlacement plan = PlanCameraPlacement(o);
  EXPECT_FALSE(plan.found);
  ASSERT_EQ(plan.notes.size(), 1u);
  EXPECT_THAT(plan.notes[0], HasSubstr("no interior maximum"));
  EXPECT_EQ(static_cast<int>(plan.curve.size()), o.curve_points);
}

TEST(CameraPlacementTest, RefusesBadOptions) {
  CameraPlacementOptions o;
  o.half_view_angle = 2.0;
  o.weight = -1;
  o.curve_points = 3;
  const std::string v = o.Validate();
  EXPECT_THAT(v, HasSubstr("half_view_angle = 2 rad"));
  EXPECT_THAT(v, HasSubstr("weight = -1"));
  EXPECT_THAT(v, HasSubstr("curve_points = 3"));
  EXPECT_THROW(PlanCameraPlacement(o), std::invalid_argument);
  CameraPlacementOptions ok;
  ok.half_view_angle = 0.4;
  EXPECT_THROW(EvaluateBenefit(ok, 0.1), std::invalid_argument);  // inside the sphere
}

TEST(CameraPlacementTest, WritesTheBenefitPlot) {
  CameraPlacementOptions o;
  o.half_view_angle = std::atan(SeedTanTheta());
  const std::string path =
      (std::filesystem::temp_directory_path() / "kinevis_diamond_benefit_test.png").string();
  std::filesystem::remove(path);
  WriteBenefitPlot(path, o, {3, 5, 8});
  const cv::Mat image = cv::imread(path);
  ASSERT_FALSE(image.empty());
  EXPECT_EQ(image.cols, 900);
  std::filesystem::remove(path);
  EXPECT_THROW(WriteBenefitPlot(path, o, {}), std::invalid_argument);
  EXPECT_THROW(WriteBenefitPlot("/nonexistent-dir/x.png", o, {5}), std::runtime_error);
}

}  // namespace
}  // namespace kinevis::calibration
