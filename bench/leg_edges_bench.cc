// Hexapod leg-edge extraction (issue 6): edge extraction plus the control law <= 2 ms per frame
// on one core. This measures the extraction: ObserveLegs on a rendered frame (six legs, two
// limbs each, wide + refining search, robust fits, eq. 11), with a reused workspace.
// Run: ./build/bench/leg_edges_bench --benchmark_min_time=1
// Configure with -DKINEVIS_BUILD_BENCH=ON (RelWithDebInfo, -O2, the default build type).

#include <benchmark/benchmark.h>

#include <memory>
#include <random>
#include <stdexcept>
#include <vector>

#include "robots/hexapod/hexapod_model.h"
#include "vision/camera/camera_file.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/hexapod/leg_edges.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/hexapod_scene.h"

namespace kinevis::vision::hexapod {
namespace {

// As tests/vision/hexapod/leg_edges_test.cc: 1024×768, f = 1400 px, slight barrel distortion,
// 1.45 m out and 0.9 m up, 30° round from the y axis (all six legs visible).
PinholeBrownCamera Perspective1024() {
  PinholeBrownParameters p;
  p.width = 1024;
  p.height = 768;
  p.fx = p.fy = 1400.0;
  p.cx = 511.5;
  p.cy = 383.5;
  p.distortion[0] = -0.08;
  p.distortion[1] = 0.02;
  return PinholeBrownCamera(p);
}

Eigen::Isometry3d PerspectiveX_CB() {
  return render::CameraLookingAt(Eigen::Vector3d(0.725, -1.2557, 0.9),
                                 Eigen::Vector3d(0.0, 0.0, 0.2), Eigen::Vector3d::UnitZ())
      .inverse();
}

Eigen::Isometry3d UnifiedX_CB() {
  Eigen::Isometry3d X_CB = Eigen::Isometry3d::Identity();
  X_CB.translation() = Eigen::Vector3d(0.0, 0.0, -0.03);
  return X_CB;
}

Eigen::Isometry3d TestPose() {
  Eigen::Isometry3d X_BP = robots::HexapodModel::NominalPose();
  X_BP.translation() += Eigen::Vector3d(0.02, -0.015, 0.03);
  X_BP.linear() = (Eigen::AngleAxisd(0.08, Eigen::Vector3d::UnitZ()) *
                   Eigen::AngleAxisd(-0.05, Eigen::Vector3d::UnitX()))
                      .toRotationMatrix();
  return X_BP;
}

std::vector<uint8_t> Render(const CameraModel& camera, const render::Scene& scene) {
  render::RenderOptions options;
  options.supersampling = 4;
  options.noise_sigma = 1.0;
  std::vector<uint8_t> pixels(static_cast<size_t>(camera.width()) * camera.height());
  render::Renderer renderer(camera, options);
  renderer.Render(scene, 0,
                  vision::ImageView8{pixels.data(), camera.width(), camera.height(),
                                     static_cast<size_t>(camera.width())});
  return pixels;
}

void RunObserve(benchmark::State& state, const CameraModel& camera, const Eigen::Isometry3d& X_CB,
                const render::HexapodSceneOptions& scene_options) {
  const robots::HexapodModel model = robots::HexapodModel::Default();
  const render::HexapodScene scene(model, TestPose(), X_CB, scene_options);
  std::vector<uint8_t> pixels = Render(camera, scene);
  const vision::ImageView8 image{pixels.data(), camera.width(), camera.height(),
                                 static_cast<size_t>(camera.width())};
  const auto predictions = PredictLegs(model, TestPose(), X_CB);
  const LegEdgeOptions options;
  LegEdgeWorkspace workspace;
  int visible = 0;
  for (auto _ : state) {
    const auto& obs = ObserveLegs(image, camera, predictions, options, &workspace);
    visible = 0;
    for (const LegObservation& o : obs) visible += o.visible;
    benchmark::DoNotOptimize(obs.data());
  }
  int points = 0;
  for (const auto& leg : workspace.points) points += leg[0].size() + leg[1].size();
  state.counters["visible_legs"] = visible;
  state.counters["edge_points"] = points;
  if (visible != kLegs) state.SkipWithError("not all six legs observed");
}

void BM_ObserveLegsPerspective1024(benchmark::State& state) {
  const PinholeBrownCamera camera = Perspective1024();
  RunObserve(state, camera, PerspectiveX_CB(), {});
}
BENCHMARK(BM_ObserveLegsPerspective1024)->Unit(benchmark::kMicrosecond);

void BM_ObserveLegsUnified640(benchmark::State& state) {
  const auto camera = BuiltinCameraModel("unified-default");
  render::HexapodSceneOptions scene_options;
  scene_options.base_plate = false;
  RunObserve(state, *camera, UnifiedX_CB(), scene_options);
}
BENCHMARK(BM_ObserveLegsUnified640)->Unit(benchmark::kMicrosecond);

// Stage 2 alone: one limb of 100 points with 0.5 px noise and 10 % outliers.
void BM_FitLimbPlane(benchmark::State& state) {
  const PinholeBrownCamera camera = Perspective1024();
  const auto legs = PredictLegs(robots::HexapodModel::Default(), TestPose(), PerspectiveX_CB());
  Eigen::Vector3d n1, n2;
  render::PredictCylinderLimbs(legs[0].p_C_A, legs[0].p_C_B, legs[0].radius, &n1, &n2);
  std::mt19937 rng(1);
  std::normal_distribution<double> noise(0.0, 0.5);
  std::vector<EdgePoint> points;
  for (int k = 0; k < 100; ++k) {
    const Eigen::Vector3d X =
        legs[0].p_C_A + legs[0].radius * n1 + (0.05 + 0.009 * k) * (legs[0].p_C_B - legs[0].p_C_A);
    Eigen::Vector2d pixel;
    camera.Project(X, &pixel);
    pixel += Eigen::Vector2d(noise(rng), noise(rng));
    if (k % 10 == 3) pixel.x() += 15.0;
    EdgePoint p;
    MakeEdgePoint(camera, pixel, &p);
    points.push_back(p);
  }
  const LegEdgeOptions options;
  for (auto _ : state) {
    const LimbFit fit = FitLimbPlane(&points, legs[0], options);
    benchmark::DoNotOptimize(fit.n_C.data());
  }
}
BENCHMARK(BM_FitLimbPlane)->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace kinevis::vision::hexapod
