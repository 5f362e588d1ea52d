#include "vision/laser/scan_lines.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <vector>

#include "vision/camera/camera_file.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/laser_scene.h"

namespace kinevis::vision::laser {
namespace {

using render::LaserScene;
using render::LaserSceneParameters;
using render::LaserSurfaceKind;

const CameraModel& Camera() {
  static const std::unique_ptr<CameraModel> camera = BuiltinCameraModel("tsai-seed004");
  return *camera;
}

render::Renderer& Renderer() {
  static render::Renderer renderer(Camera(), render::RenderOptions());
  return renderer;
}

struct Frame {
  std::vector<uint8_t> pixels;
  vision::ImageView8 view() {
    return vision::ImageView8{pixels.data(), Camera().width(), Camera().height(),
                              static_cast<size_t>(Camera().width())};
  }
};

Frame Render(const LaserScene& scene) {
  Frame f;
  f.pixels.assign(static_cast<size_t>(Camera().width()) * Camera().height(), 0);
  Renderer().Render(scene, 0, f.view());
  return f;
}

// A flat board tilted 15° about x_C, its centre `depth` in front of the camera.
LaserSceneParameters TiltedBoard(double depth) {
  LaserSceneParameters p;
  p.surface = LaserSurfaceKind::kBoard;
  p.half_extent = Eigen::Vector2d(0.3, 0.3);
  p.X_CS = Eigen::Translation3d(0.0, 0.0, depth) *
           Eigen::AngleAxisd(M_PI + 15.0 * M_PI / 180.0, Eigen::Vector3d::UnitX());
  return p;
}

// Distance (m) of p_C from the board plane z_S = 0.
double PlaneDistance(const LaserSceneParameters& p, const Eigen::Vector3d& p_C) {
  return (p.X_CS.inverse() * p_C).z();
}

// Every frame of a sweep over the board: eq. (11)'s angle matches the one rendered, and the
// triangulated points lie on the board (exact scanner geometry: the error is the stripe
// extraction's and that of eq. (11)'s angle from the crossing; measured 0.03-0.08 mm RMS, the
// largest at the ends of the sweep).
TEST(ScanLineTriangulator, SweepOverABoardGivesPointsOnIt) {
  const ScannerModel model(Camera(), ScannerGeometry::Seed004());
  ScanLineTriangulator triangulator(model);
  const std::vector<double> sweep = PlanSweep(model, 0.4, 5);
  ASSERT_EQ(sweep.size(), 5u);
  ScanLineResult r;
  for (const double cot : sweep) {
    LaserSceneParameters p = TiltedBoard(0.4);
    p.rotating_cot_theta_y = cot;
    const LaserScene scene(p);
    Frame f = Render(scene);
    triangulator.Process(f.view(), &r, cot);
    ASSERT_TRUE(r.ok()) << ToString(r.status) << " crossing " << ToString(r.crossing) << " at "
                        << cot;
    EXPECT_NEAR(r.cot_theta_y, cot, 2e-4);
    EXPECT_GT(r.cot_theta_y_sigma, 0.0);
    EXPECT_GT(r.p_C.size(), 800u);
    EXPECT_EQ(r.p_C.size(), r.confidence.size());
    double worst = 0.0, sum2 = 0.0;
    for (const Eigen::Vector3d& q : r.p_C) {
      const double d = PlaneDistance(p, q);
      worst = std::max(worst, std::abs(d));
      sum2 += d * d;
    }
    EXPECT_LT(std::sqrt(sum2 / r.p_C.size()), 0.15e-3) << "cot " << cot;
    EXPECT_LT(worst, 0.6e-3) << "cot " << cot;
  }
}

// The planned sweep puts the stripe on the rows asked for, at the planned depth: on the central
// column of a fronto-parallel board, first and last line at 5 % and 95 % of the height.
TEST(PlanSweep, StripeLandsOnThePlannedRows) {
  const ScannerModel model(Camera(), ScannerGeometry::Seed004());
  const std::vector<double> sweep = PlanSweep(model, 0.45, 3, 0.05);
  const double rows[] = {0.05 * (Camera().height() - 1), 0.5 * (Camera().height() - 1),
                         0.95 * (Camera().height() - 1)};
  for (int k = 0; k < 3; ++k) {
    // The rotating plane at the planned angle, met by the central column's ray at depth 0.45.
    const ScannerGeometry g = ScannerGeometry::Seed004();
    const double c = sweep[static_cast<size_t>(k)];
    const double y = g.RotatingBPrime(c) - c * 0.45;  // y on the plane at z = 0.45
    Eigen::Vector2d px;
    ASSERT_EQ(Camera().Project(Eigen::Vector3d(0.0, y, 0.45), &px), ProjectionStatus::kOk);
    EXPECT_NEAR(px.y(), rows[k], 1.0) << k;
  }
  // Rows move down the image with the sweep: cot θ_y decreases monotonically.
  EXPECT_GT(sweep[0], sweep[1]);
  EXPECT_GT(sweep[1], sweep[2]);
}

TEST(ScanLineTriangulator, ReportsWhatWentWrong) {
  const ScannerModel model(Camera(), ScannerGeometry::Seed004());
  ScanLineTriangulator triangulator(model);
  ScanLineResult r;
  // Lasers off: no crossing.
  LaserSceneParameters p = TiltedBoard(0.4);
  p.fixed_on = false;
  p.rotating_on = false;
  Frame dark = Render(LaserScene(p));
  triangulator.Process(dark.view(), &r);
  EXPECT_EQ(r.status, ScanLineStatus::kNoCrossing);
  EXPECT_TRUE(r.p_C.empty());
  // A commanded angle the image contradicts (a skipped stepper step).
  p = TiltedBoard(0.4);
  p.rotating_cot_theta_y = 0.25;
  Frame f = Render(LaserScene(p));
  triangulator.Process(f.view(), &r, 0.30);
  EXPECT_EQ(r.status, ScanLineStatus::kAngleInconsistent);
  EXPECT_NEAR(r.cot_theta_y, 0.25, 2e-4);
  // Wrong image size, bad options, bad sweeps.
  std::vector<uint8_t> small(100 * 100, 0);
  EXPECT_THAT(
      [&] {
        triangulator.Process(vision::ImageView8{small.data(), 100, 100, 100}, &r);
      },
      ::testing::ThrowsMessage<std::invalid_argument>(::testing::HasSubstr("100 x 100")));
  ScanLineOptions bad;
  bad.min_points = 0;
  bad.min_confidence = 1.5;
  EXPECT_THAT([&] { ScanLineTriangulator t(model, bad); },
              ::testing::ThrowsMessage<std::invalid_argument>(::testing::AllOf(
                  ::testing::HasSubstr("min_points = 0"), ::testing::HasSubstr("min_confidence"))));
  EXPECT_THROW(PlanSweep(model, 0.4, 1), std::invalid_argument);
  EXPECT_THROW(PlanSweep(model, 0.01, 10), std::invalid_argument);
  EXPECT_THROW(PlanSweep(model, 0.4, 10, 0.6), std::invalid_argument);
}

}  // namespace
}  // namespace kinevis::vision::laser
