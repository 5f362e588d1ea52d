// Synthetic image rendering (issue 5): a 640×480 frame in ≤ 10 ms on one core.
// Run: ./build/bench/render_bench --benchmark_min_time=1
// Configure with -DKINEVIS_BUILD_BENCH=ON (RelWithDebInfo, -O2, the default build type).

#include <benchmark/benchmark.h>

#include <vector>

#include "robots/hexapod/hexapod_model.h"
#include "vision/camera/hyperbolic_mirror_camera.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/camera/tsai_camera.h"
#include "vision/camera/unified_camera.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/diamond_marker_scene.h"
#include "vision/render/scenes/hexapod_scene.h"
#include "vision/render/scenes/laser_scene.h"
#include "vision/render/scenes/soccer_field_scene.h"
#include "vision/render/scenes/target_scene.h"

namespace kinevis::vision::render {
namespace {

PinholeBrownCamera Pinhole640() {
  PinholeBrownParameters p;
  p.width = 640;
  p.height = 480;
  p.fx = p.fy = 500.0;
  p.cx = 319.5;
  p.cy = 239.5;
  return PinholeBrownCamera(p);
}

// The perspective camera outside the legs, 1 m from the axis, looking at mid-height.
Eigen::Isometry3d PerspectiveX_CB() {
  return CameraLookingAt(Eigen::Vector3d(1.0, 0.25, 0.3), Eigen::Vector3d(0.0, 0.0, 0.2),
                         Eigen::Vector3d::UnitZ())
      .inverse();
}

// The unified camera at the base centre, 3 cm above the base, mirror axis up.
Eigen::Isometry3d UnifiedX_CB() {
  Eigen::Isometry3d X_CB = Eigen::Isometry3d::Identity();
  X_CB.translation() = Eigen::Vector3d(0.0, 0.0, -0.03);
  return X_CB;
}

RenderOptions Options(bool sensor_effects) {
  RenderOptions options;
  if (sensor_effects) {
    options.noise_sigma = 2.0;
    options.vignetting = 0.2;
    options.exposure = 1.1;
  }
  return options;
}

void RenderLoop(benchmark::State& state, const CameraModel& camera, const Scene& scene,
                const RenderOptions& options) {
  Renderer renderer(camera, options);
  std::vector<uint8_t> pixels(static_cast<size_t>(camera.width()) * camera.height());
  const ImageView8 view{pixels.data(), camera.width(), camera.height(),
                        static_cast<size_t>(camera.width())};
  // The first frame pays the one-time costs (buffers; a camera-fixed part's answers, which
  // BM_SoccerFieldMirrorSetUp measures): outside the timed loop, so that this is the per-frame
  // time.
  renderer.Render(scene, 0, view);
  uint64_t frame = 1;
  for (auto _ : state) {
    renderer.Render(scene, frame++, view);
    benchmark::DoNotOptimize(pixels.data());
    benchmark::ClobberMemory();
  }
  state.counters["edge_px"] = renderer.last_edge_pixels();
}

void BM_HexapodPerspective(benchmark::State& state) {
  const PinholeBrownCamera camera = Pinhole640();
  const HexapodScene scene(robots::HexapodModel::Default(), robots::HexapodModel::NominalPose(),
                           PerspectiveX_CB());
  RenderLoop(state, camera, scene, Options(state.range(0) != 0));
}
BENCHMARK(BM_HexapodPerspective)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

void BM_HexapodUnified(benchmark::State& state) {
  const UnifiedCamera camera(UnifiedParameters::Default());
  const HexapodScene scene(robots::HexapodModel::Default(), robots::HexapodModel::NominalPose(),
                           UnifiedX_CB());
  RenderLoop(state, camera, scene, Options(state.range(0) != 0));
}
BENCHMARK(BM_HexapodUnified)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

void BM_ChessboardPerspective(benchmark::State& state) {
  const PinholeBrownCamera camera = Pinhole640();
  Eigen::Isometry3d X_CT = Eigen::Isometry3d::Identity();
  X_CT.translation() = Eigen::Vector3d(-0.12, -0.09, 0.6);
  const TargetScene scene(TargetSpec{}, X_CT);
  RenderLoop(state, camera, scene, Options(state.range(0) != 0));
}
BENCHMARK(BM_ChessboardPerspective)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

// Seed 000's robot camera: the soccer field through the hyperbolic mirror (640×480).
void BM_SoccerFieldMirror(benchmark::State& state) {
  const HyperbolicMirrorCamera camera(HyperbolicMirrorParameters::Seed000Lens4mm());
  SoccerFieldSceneParameters p;
  p.robot_x = 1.2;
  p.robot_y = -0.7;
  p.robot_heading = 0.4;
  const SoccerFieldScene scene(camera, p);
  RenderLoop(state, camera, scene, Options(state.range(0) != 0));
}
BENCHMARK(BM_SoccerFieldMirror)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

// What a soccer world pays once: the renderer's constructor (one BackProject per pixel, the
// interpolation checks) and the first frame, which asks the scene's camera-fixed part about every
// ray (renderer.h).
void BM_SoccerFieldMirrorSetUp(benchmark::State& state) {
  const HyperbolicMirrorCamera camera(HyperbolicMirrorParameters::Seed000Lens4mm());
  const SoccerFieldScene scene(camera, SoccerFieldSceneParameters{});
  std::vector<uint8_t> pixels(static_cast<size_t>(camera.width()) * camera.height());
  const ImageView8 view{pixels.data(), camera.width(), camera.height(),
                        static_cast<size_t>(camera.width())};
  for (auto _ : state) {
    Renderer renderer(camera, RenderOptions{});
    renderer.Render(scene, 0, view);
    benchmark::DoNotOptimize(pixels.data());
  }
}
BENCHMARK(BM_SoccerFieldMirrorSetUp)->Unit(benchmark::kMillisecond);

// Seed 004's scanner: both stripes on the blade with pits, full 1616×1216 Tsai frame.
void BM_LaserBlade1616x1216(benchmark::State& state) {
  const TsaiCamera camera(TsaiParameters::Seed004());
  LaserSceneParameters p;
  p.curvature_xx = 2.0;
  p.pits = {CavitationPit{Eigen::Vector2d(0.01, 0.0), 1.0e-3, 3e-3},
            CavitationPit{Eigen::Vector2d(-0.02, 0.015), 0.5e-3, 2e-3}};
  const LaserScene scene(p);
  RenderLoop(state, camera, scene, Options(state.range(0) != 0));
}
BENCHMARK(BM_LaserBlade1616x1216)->Arg(0)->Unit(benchmark::kMillisecond);

// Seed 001's marker camera (1280×640 pinhole, f = 1000 px) at 45°, 0.45 m from the RCM.
void BM_DiamondMarker1280x640(benchmark::State& state) {
  PinholeBrownParameters pp;
  pp.width = 1280;
  pp.height = 640;
  pp.fx = pp.fy = 1000.0;
  pp.cx = 639.5;
  pp.cy = 319.5;
  const PinholeBrownCamera camera(pp);
  DiamondMarkerSceneParameters p;
  p.X_CO = DiamondCameraPose(0.45);  // X_CO (the pose of O in C), as the header says
  p.p_O_T = Eigen::Vector3d(0.0, 0.1414, 0.1414);
  const DiamondMarkerScene scene(p);
  RenderLoop(state, camera, scene, Options(state.range(0) != 0));
}
BENCHMARK(BM_DiamondMarker1280x640)->Arg(0)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace kinevis::vision::render
