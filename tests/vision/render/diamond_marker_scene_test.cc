#include "vision/render/scenes/diamond_marker_scene.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "robots/diamond/diamond_model.h"
#include "vision/camera/pinhole_camera.h"

namespace kinevis::vision::render {
namespace {

// The seed's camera (seed 001 §VI): PS3 Eye at 1280×640 with a 6 mm lens. Pixel pitch 6 µm
// (the OV7720's) is our assumption, the seed gives none: f = 1000 px.
PinholeBrownCamera SeedCamera() {
  PinholeBrownParameters p;
  p.width = 1280;
  p.height = 640;
  p.fx = p.fy = 1000.0;
  p.cx = 639.5;
  p.cy = 319.5;
  return PinholeBrownCamera(p);
}

// Intensity centroid (radiance above the background) of the marker in a window around `centre`,
// each pixel the mean of s×s Trace() samples, one at a random place in each cell of an s×s
// sub-pixel grid (stratified area sampling: unbiased, where a regular grid would quantise the
// plate's edges, which run nearly along the pixel grid, to 1/s px).
Eigen::Vector2d MarkerCentroid(const CameraModel& camera, const DiamondMarkerScene& scene,
                               const Eigen::Vector2d& centre, int half_window, int s) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> jitter(0.0, 1.0);
  double sum = 0.0, su = 0.0, sv = 0.0;
  const int u0 = static_cast<int>(std::lround(centre.x()));
  const int v0 = static_cast<int>(std::lround(centre.y()));
  for (int v = v0 - half_window; v <= v0 + half_window; ++v) {
    for (int u = u0 - half_window; u <= u0 + half_window; ++u) {
      double value = 0.0;
      for (int j = 0; j < s; ++j) {
        for (int i = 0; i < s; ++i) {
          const Eigen::Vector2d pixel(u - 0.5 + (i + jitter(rng)) / s,
                                      v - 0.5 + (j + jitter(rng)) / s);
          Ray ray;
          if (camera.BackProject(pixel, &ray) != ProjectionStatus::kOk) continue;
          value += scene.Trace(ray).radiance - scene.parameters().background;
        }
      }
      value /= s * s;
      sum += value;
      su += value * u;
      sv += value * v;
    }
  }
  return {su / sum, sv / sum};
}

// The exact intensity centroid of the plate's image: the integral over the plate of
// pixel(p) (radiance − background) |det ∂pixel/∂(a, b)| da db, by the midpoint rule on an n×n grid
// per quadrant. It differs from the projected centre by the second-order perspective bias.
Eigen::Vector2d ExactMarkerCentroid(const CameraModel& camera, const DiamondMarkerScene& scene,
                                    int n) {
  const DiamondMarkerSceneParameters& p = scene.parameters();
  const Eigen::Isometry3d& X_CP = scene.X_CP();
  Eigen::Matrix<double, 3, 2> plate_axes;
  plate_axes << X_CP.linear().col(0), X_CP.linear().col(1);
  double sum = 0.0;
  Eigen::Vector2d first = Eigen::Vector2d::Zero();
  const double step = 2.0 * p.half_side / n;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const double a = -p.half_side + (i + 0.5) * step;
      const double b = -p.half_side + (j + 0.5) * step;
      const double value = ((a >= 0) == (b >= 0) ? p.white : p.black) - p.background;
      Eigen::Vector2d pixel;
      Matrix23d J;
      EXPECT_EQ(camera.Project(X_CP * Eigen::Vector3d(a, b, 0.0), &pixel, &J),
                ProjectionStatus::kOk);
      const double area = std::abs((J * plate_axes).determinant());
      sum += value * area;
      first += value * area * pixel;
    }
  }
  return first / sum;
}

TEST(DiamondMarkerScene, CameraPoseIsAt45DegreesLookingAtTheRcm) {
  const Eigen::Isometry3d X_CO = DiamondCameraPose(0.4462);
  // The RCM is on the optical axis at the given distance.
  EXPECT_LT((X_CO * Eigen::Vector3d::Zero() - Eigen::Vector3d(0, 0, 0.4462)).norm(), 1e-12);
  // The optical axis makes 45° with the base axis z_O.
  const Eigen::Vector3d z_C_in_O = X_CO.linear().transpose().col(2);
  EXPECT_NEAR(std::acos(-z_C_in_O.z()), M_PI / 4, 1e-12);
  EXPECT_NEAR(X_CO.linear().determinant(), 1.0, 1e-12);
}

TEST(DiamondMarkerScene, MarkerCentroidIsTheProjectedToolPointOverConfigurations) {
  const PinholeBrownCamera camera = SeedCamera();
  const robots::DiamondModel model = robots::DiamondModel::SeedIdentified();
  DiamondMarkerSceneParameters parameters;
  parameters.X_CO = DiamondCameraPose(0.4462);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> dphi(-0.35, 0.35), dgamma(-0.25, 0.25);
  int checked = 0;
  double worst = 0.0, worst_bias = 0.0;
  for (int k = 0; k < 8; ++k) {
    const Eigen::Vector2d task(M_PI / 2 + dphi(rng), M_PI / 4 + dgamma(rng));
    Eigen::Vector2d q;
    ASSERT_TRUE(robots::InverseKinematics(model, task, &q).ok()) << task.transpose();
    robots::DiamondData data;
    ASSERT_TRUE(robots::ForwardKinematics(model, q, &data).ok());
    parameters.p_O_T = data.p_O_T;
    const DiamondMarkerScene scene(parameters);
    Eigen::Vector2d expected;
    ASSERT_EQ(camera.Project(scene.p_C_T(), &expected), ProjectionStatus::kOk);
    ASSERT_TRUE(camera.InImage(expected));
    // Ground truth: the ray through the projected centre hits the plate at T.
    Ray ray;
    ASSERT_EQ(camera.BackProject(expected, &ray), ProjectionStatus::kOk);
    const Hit centre = scene.Trace(ray);
    EXPECT_NE(centre.object, kDiamondBackground);
    EXPECT_LT((ray.p_C_O + centre.depth * ray.d_C - scene.p_C_T()).norm(), 1e-9);
    // Window: the plate's half side is < 30 px at these distances.
    const Eigen::Vector2d measured = MarkerCentroid(camera, scene, expected, 40, 8);
    const Eigen::Vector2d exact = ExactMarkerCentroid(camera, scene, 400);
    // The rendered centroid is the exact one (area sampling error only) ...
    const double error = (measured - exact).norm();
    worst = std::max(worst, error);
    EXPECT_LT(error, 0.02) << "task " << task.transpose() << " measured " << measured.transpose()
                           << " exact " << exact.transpose();
    // ... and both are within the perspective bias of the projected tool point.
    const double bias = (exact - expected).norm();
    worst_bias = std::max(worst_bias, bias);
    EXPECT_LT(bias, 0.4) << "task " << task.transpose();
    ++checked;
  }
  EXPECT_EQ(checked, 8);
  std::printf("centroid: rendered vs exact worst %.4f px; perspective bias worst %.4f px\n", worst,
              worst_bias);
}

TEST(DiamondMarkerScene, RenderedImageCentroidIsTheExactOne) {
  // Through the Renderer (edge supersampling, 8-bit output).
  const PinholeBrownCamera camera = SeedCamera();
  DiamondMarkerSceneParameters parameters;
  parameters.X_CO = DiamondCameraPose(0.4462);
  parameters.p_O_T = 0.2222 * Eigen::Vector3d(0.25, 0.65, 0.72).normalized();
  const DiamondMarkerScene scene(parameters);
  RenderOptions options;
  options.supersampling = 8;
  Renderer renderer(camera, options);
  std::vector<uint8_t> image(camera.width() * camera.height());
  renderer.Render(scene, 0,
                  ImageView8{image.data(), camera.width(), camera.height(),
                             static_cast<size_t>(camera.width())});
  Eigen::Vector2d expected;
  ASSERT_EQ(camera.Project(scene.p_C_T(), &expected), ProjectionStatus::kOk);
  const double background = std::round(255.0 * parameters.background);
  double sum = 0.0, su = 0.0, sv = 0.0;
  const int u0 = static_cast<int>(std::lround(expected.x()));
  const int v0 = static_cast<int>(std::lround(expected.y()));
  for (int v = v0 - 40; v <= v0 + 40; ++v) {
    for (int u = u0 - 40; u <= u0 + 40; ++u) {
      const double w = image[v * camera.width() + u] - background;
      sum += w;
      su += w * u;
      sv += w * v;
    }
  }
  const Eigen::Vector2d measured(su / sum, sv / sum);
  const Eigen::Vector2d exact = ExactMarkerCentroid(camera, scene, 400);
  std::printf("rendered: centroid - exact = %.4f px\n", (measured - exact).norm());
  // Regular-grid supersampling (1/16 px per straight edge at s = 8) and 8-bit rounding.
  EXPECT_LT((measured - exact).norm(), 0.06);
  EXPECT_LT((measured - expected).norm(), 0.4);
}

TEST(DiamondMarkerScene, QuadrantsAlternateAroundTheCentre) {
  DiamondMarkerSceneParameters parameters;
  parameters.X_CO = DiamondCameraPose(0.4462);
  parameters.p_O_T = Eigen::Vector3d(0.0, 0.2 * std::sqrt(0.5), 0.2 * std::sqrt(0.5));
  const DiamondMarkerScene scene(parameters);
  const Eigen::Isometry3d& X_CP = scene.X_CP();
  auto trace_at = [&](double a, double b) {
    Ray ray;
    ray.d_C = (X_CP * Eigen::Vector3d(a, b, 0.0)).normalized();
    return scene.Trace(ray);
  };
  EXPECT_EQ(trace_at(0.002, 0.002).object, kDiamondMarkerWhite);
  EXPECT_EQ(trace_at(-0.002, -0.002).object, kDiamondMarkerWhite);
  EXPECT_EQ(trace_at(0.002, -0.002).object, kDiamondMarkerBlack);
  EXPECT_EQ(trace_at(-0.002, 0.002).object, kDiamondMarkerBlack);
  EXPECT_EQ(trace_at(0.0051, 0.002).object, kDiamondBackground);
  EXPECT_DOUBLE_EQ(trace_at(0.0051, 0.002).radiance, parameters.background);
  // The plate faces the camera: its normal is along the line of sight to T.
  EXPECT_NEAR(X_CP.linear().col(2).dot(-scene.p_C_T().normalized()), 1.0, 1e-12);
}

TEST(DiamondMarkerScene, BadParametersAreNamedInOneMessage) {
  DiamondMarkerSceneParameters parameters;
  parameters.half_side = -1.0;
  parameters.white = 1.5;
  EXPECT_THAT(parameters.Validate(),
              ::testing::MatchesRegex(".*half_side: [^;]*, got -1.*white: [^;]*, got 1.5.*"));
  EXPECT_THROW(DiamondMarkerScene{parameters}, std::invalid_argument);
  DiamondMarkerSceneParameters behind;
  behind.p_O_T = Eigen::Vector3d(0, 0, -0.2);  // X_CO identity: T behind the camera
  EXPECT_THROW(DiamondMarkerScene{behind}, std::invalid_argument);
}

}  // namespace
}  // namespace kinevis::vision::render
