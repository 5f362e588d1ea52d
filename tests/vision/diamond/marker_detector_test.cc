#include "vision/diamond/marker_detector.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "common/units.h"
#include "robots/diamond/diamond_model.h"
#include "vision/camera/camera_file.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/render/scenes/diamond_marker_scene.h"

namespace kinevis::vision {
namespace {

using ::testing::ContainsRegex;
using ::testing::HasSubstr;

// The seed's camera (seed 001 §V-A: PS3 Eye, 1280×640, 6 mm lens; 6 µm pixels assumed, as in
// diamond_marker_scene_test.cc): f = 1000 px.
std::unique_ptr<CameraModel> SeedCamera() {
  PinholeBrownParameters p;
  p.width = 1280;
  p.height = 640;
  p.fx = p.fy = 1000.0;
  p.cx = 639.5;
  p.cy = 319.5;
  return std::make_unique<PinholeBrownCamera>(p);
}

struct Frame {
  std::vector<uint8_t> pixels;
  vision::ImageView8 view;
  Eigen::Vector2d truth = Eigen::Vector2d::Zero();  // projection of T
};

// Renders the marker at task point (φ, γ) of the true robot for a camera at the seed's placement
// (45°, 0.4462 m from the RCM), through `renderer` (its options set the supersampling, noise).
Frame Render(render::Renderer& renderer, const Eigen::Vector2d& task, uint64_t frame_index,
             double white = 0.9) {
  const CameraModel& camera = renderer.camera();
  const robots::DiamondModel model = robots::DiamondModel::SeedIdentified();
  render::DiamondMarkerSceneParameters p;
  p.X_CO = render::DiamondCameraPose(0.4462);
  p.p_O_T = robots::DiamondToolPoint(model.radius, task[0], task[1]);
  p.white = white;
  const render::DiamondMarkerScene scene(p);
  Frame f;
  f.pixels.assign(static_cast<size_t>(camera.width()) * camera.height(), 0);
  f.view = vision::ImageView8{f.pixels.data(), camera.width(), camera.height(),
                              static_cast<size_t>(camera.width())};
  renderer.Render(scene, frame_index, f.view);
  EXPECT_EQ(camera.Project(scene.p_C_T(), &f.truth), ProjectionStatus::kOk);
  return f;
}

render::RenderOptions Options(int supersampling, double noise_sigma) {
  render::RenderOptions o;
  o.supersampling = supersampling;
  o.noise_sigma = noise_sigma;
  o.seed = 7;
  return o;
}

// Task points spread over the seed's working region around the camera's axis.
std::vector<Eigen::Vector2d> TaskGrid() {
  std::vector<Eigen::Vector2d> points;
  for (double phi = 70; phi <= 110; phi += 10) {
    for (double gamma = 35; gamma <= 55; gamma += 5) {
      points.emplace_back(phi * common::kDeg, gamma * common::kDeg);
    }
  }
  return points;
}

struct ErrorStats {
  double mean = 0, max = 0;
  int found = 0, total = 0;
};

ErrorStats Measure(const CameraModel& camera, const MarkerDetectorOptions& options,
                   int supersampling, double noise_sigma) {
  render::Renderer renderer(camera, Options(supersampling, noise_sigma));
  MarkerDetector detector(options);
  ErrorStats stats;
  uint64_t index = 0;
  for (const Eigen::Vector2d& task : TaskGrid()) {
    const Frame f = Render(renderer, task, ++index);
    const MarkerDetection d = detector.Detect(f.view);
    ++stats.total;
    if (!d.found()) continue;
    ++stats.found;
    const double e = (d.pixel - f.truth).norm();
    stats.mean += e;
    stats.max = std::max(stats.max, e);
  }
  stats.mean /= std::max(1, stats.found);
  std::printf("%s, supersampling %d, noise %.0f: found %d/%d, mean %.4f px, max %.4f px\n",
              std::string(camera.Name()).c_str(), supersampling, noise_sigma, stats.found,
              stats.total, stats.mean, stats.max);
  return stats;
}

// Sub-pixel accuracy against the scene's ground truth (the projection of T), over 25 positions
// across the working region, on images rendered with 16×16 edge supersampling, so that the
// renderer's own edge quantisation (≤ 1/(2·16) px per edge) is below the detector's error.
// Measured (printed): seed camera (plate ~40 px wide) mean 0.018 px, max 0.037 px at σ = 1
// grey level; the world's Tsai camera (~85 px; larger windows) similar. Bound 0.08 px: twice
// the worst measured; the errors a regression makes (a half-pixel convention slip, the
// unrefined Harris peak, cornerSubPix alone: 0.07 px mean, 0.11 px worst on ideal corners) are
// above it.
TEST(MarkerDetectorTest, FindsTheMarkerCentreToFewHundredthsOfAPixelOverTheWorkingRegion) {
  const auto seed = SeedCamera();
  const ErrorStats s = Measure(*seed, MarkerDetectorOptions{}, 16, 1.0);
  EXPECT_EQ(s.found, s.total);
  EXPECT_LT(s.max, 0.08);

  const auto tsai = OpenCameraModel("builtin:tsai-seed004");
  MarkerDetectorOptions large;
  large.refine_half_window_px = 8;
  large.ring_radius_px = 12;
  large.search_half_window_px = 60;
  const ErrorStats t = Measure(*tsai, large, 16, 1.0);
  EXPECT_EQ(t.found, t.total);
  EXPECT_LT(t.max, 0.08);
}

// With the worlds' 4×4 supersampling (config/diamond-sim.yaml) the image itself carries the
// renderer's quantisation of the two nearly axis-aligned edges through T (≤ 1/8 px each, so
// ≤ 0.18 px): measured mean 0.064 px, max 0.128 px. Bound 0.2 px = that quantisation + the
// detector's 0.04 px; this is the floor the visual servo sees in the simulated world.
TEST(MarkerDetectorTest, OnTheWorldsRenderingTheErrorIsTheRenderersEdgeQuantisation) {
  const auto seed = SeedCamera();
  const ErrorStats s = Measure(*seed, MarkerDetectorOptions{}, 4, 1.0);
  EXPECT_EQ(s.found, s.total);
  EXPECT_LT(s.max, 0.2);
}

// σ = 5 grey levels (a dim, gained-up sensor): still found everywhere; measured max 0.06 px.
// Bound 0.15 px.
TEST(MarkerDetectorTest, StaysSubPixelWithStrongNoise) {
  const auto seed = SeedCamera();
  const ErrorStats s = Measure(*seed, MarkerDetectorOptions{}, 16, 5.0);
  EXPECT_EQ(s.found, s.total);
  EXPECT_LT(s.max, 0.15);
}

TEST(MarkerDetectorTest, SearchesAroundThePredictionOnly) {
  const auto camera = SeedCamera();
  render::Renderer renderer(*camera, Options(16, 1.0));
  const Frame f = Render(renderer, {95 * common::kDeg, 40 * common::kDeg}, 1);
  MarkerDetector detector;
  const Eigen::Vector2d near = f.truth + Eigen::Vector2d(18, -12);
  const MarkerDetection d = detector.Detect(f.view, &near);
  ASSERT_TRUE(d.found()) << ToString(d.status);
  EXPECT_LT((d.pixel - f.truth).norm(), 0.08);
  EXPECT_GT(d.confidence, 0.8);

  // A prediction 200 px away: the window holds only background, so nothing is reported.
  const Eigen::Vector2d far = f.truth + Eigen::Vector2d(200, 0);
  const MarkerDetection none = detector.Detect(f.view, &far);
  EXPECT_FALSE(none.found());
  EXPECT_EQ(none.confidence, 0.0);

  const Eigen::Vector2d outside(-500, 100);
  EXPECT_EQ(detector.Detect(f.view, &outside).status, MarkerStatus::kOutsideImage);
}

TEST(MarkerDetectorTest, ReportsNoMarkerInAnImageWithoutOne) {
  const auto camera = SeedCamera();
  // Background and noise only: the rendered frame's noise bits without the marker.
  render::Renderer renderer(*camera, Options(4, 2.0));
  Frame f = Render(renderer, {90 * common::kDeg, 45 * common::kDeg}, 3);
  for (uint8_t& p : f.pixels) p = static_cast<uint8_t>(5 + (p & 3));
  MarkerDetector detector;
  EXPECT_FALSE(detector.Detect(f.view).found());
  std::vector<uint8_t> flat(static_cast<size_t>(camera->width()) * camera->height(), 5);
  const vision::ImageView8 v{flat.data(), camera->width(), camera->height(),
                             static_cast<size_t>(camera->width())};
  EXPECT_EQ(detector.Detect(v).status, MarkerStatus::kNoCorner);
  EXPECT_EQ(detector.Detect(vision::ImageView8{}).status, MarkerStatus::kInvalidImage);
}

// Occlusion: a tool or a hand over the plate. Over an outer part (the centre and the ring clear)
// the marker is still found, as accurately; over half the plate through the centre it is not
// (the X pattern is broken): never a guess.
TEST(MarkerDetectorTest, PartialOcclusionAwayFromTheCentreIsToleratedAcrossItIsNotFound) {
  const auto camera = SeedCamera();
  render::Renderer renderer(*camera, Options(16, 1.0));
  MarkerDetector detector;
  const int w = camera->width();
  {
    Frame f = Render(renderer, {85 * common::kDeg, 45 * common::kDeg}, 4);
    // Occluder (grey 120) over the plate's right part, from 8 px right of the centre.
    const int u0 = static_cast<int>(f.truth.x()) + 8;
    for (int v = 0; v < camera->height(); ++v) {
      for (int u = u0; u < w; ++u) f.pixels[v * w + u] = 120;
    }
    const MarkerDetection d = detector.Detect(f.view);
    ASSERT_TRUE(d.found()) << ToString(d.status);
    EXPECT_LT((d.pixel - f.truth).norm(), 0.08);
  }
  for (const uint8_t grey : {200, 120, 3}) {
    Frame f = Render(renderer, {85 * common::kDeg, 45 * common::kDeg}, 5);
    // An occluder over the upper half of the plate, 1 px past the centre.
    const int uc = static_cast<int>(std::lround(f.truth.x()));
    const int vc = static_cast<int>(std::lround(f.truth.y()));
    for (int v = vc - 40; v <= vc + 1; ++v) {
      for (int u = uc - 40; u <= uc + 40; ++u) f.pixels[v * w + u] = grey;
    }
    const MarkerDetection d = detector.Detect(f.view);
    EXPECT_FALSE(d.found()) << "occluder " << int(grey) << ": " << d.pixel.transpose() << " vs "
                            << f.truth.transpose();
  }
}

// A marker whose centre is too close to (or beyond) the image border is not reported.
TEST(MarkerDetectorTest, MarkerAtOrBeyondTheImageBorderIsNotReported) {
  PinholeBrownParameters p;
  p.width = 1280;
  p.height = 640;
  p.fx = p.fy = 1000.0;
  p.cy = 319.5;
  MarkerDetector detector;
  // Shift the principal point so that the marker centre falls 3 px inside the left border, then
  // 6 px beyond it.
  for (const double inside : {3.0, -6.0}) {
    p.cx = 639.5;
    const PinholeBrownCamera centred(p);
    render::Renderer r0(centred, Options(4, 0.0));
    const Frame f0 = Render(r0, {90 * common::kDeg, 45 * common::kDeg}, 6);
    p.cx = 639.5 - (f0.truth.x() - inside);
    const PinholeBrownCamera shifted(p);
    render::Renderer r1(shifted, Options(4, 1.0));
    const Frame f = Render(r1, {90 * common::kDeg, 45 * common::kDeg}, 6);
    ASSERT_NEAR(f.truth.x(), inside, 1e-6);
    const MarkerDetection d = detector.Detect(f.view);
    EXPECT_FALSE(d.found()) << "centre at u = " << inside << ": " << d.pixel.transpose();
  }
}

TEST(MarkerDetectorTest, AWeakMarkerIsNotFound) {
  const auto camera = SeedCamera();
  // White quadrants at 0.12 against black 0.05: ~18 grey levels, below min_contrast.
  render::Renderer renderer(*camera, Options(4, 1.0));
  const Frame f = Render(renderer, {90 * common::kDeg, 45 * common::kDeg}, 8, 0.12);
  MarkerDetector detector;
  const MarkerDetection d = detector.Detect(f.view);
  EXPECT_FALSE(d.found());
  EXPECT_LT(d.contrast, 30.0);
}

TEST(MarkerDetectorTest, BadOptionsAreRefusedNamingTheField) {
  MarkerDetectorOptions o;
  o.harris_block_size = 4;
  o.ring_radius_px = 1;
  o.min_confidence = 2;
  try {
    MarkerDetector d(o);
    FAIL() << "accepted bad options";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), ContainsRegex("harris_block_size: [^;]*, got 4"));
    EXPECT_THAT(e.what(), ContainsRegex("ring_radius_px: [^;]*, got 1"));
    EXPECT_THAT(e.what(), ContainsRegex("min_confidence: [^;]*, got 2"));
  }
}

}  // namespace
}  // namespace kinevis::vision
