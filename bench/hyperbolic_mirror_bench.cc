// Hot paths of the non-single-viewpoint hyperbolic-mirror camera (seed 000): the 640×480
// pixel → ground map (target ≤ 15 ms on one core) and Project / BackProject per call.
//
//   hyperbolic_mirror_bench --benchmark_min_time=1

#include <benchmark/benchmark.h>

#include <cmath>
#include <vector>

#include "vision/camera/hyperbolic_mirror_camera.h"

namespace kinevis::vision {
namespace {

// The seed's 4 mm setup with every misalignment switched on (as in the tests).
HyperbolicMirrorParameters BenchParameters() {
  HyperbolicMirrorParameters p = HyperbolicMirrorParameters::Seed000Lens4mm();
  p.sensor_offset_x = 0.4e-3;
  p.sensor_offset_z = -0.3e-3;
  p.sensor_gamma = 0.03;
  p.sensor_rho = -0.02;
  p.sensor_theta = 0.015;
  p.mirror_axis_x = 1.0e-3;
  p.mirror_axis_z = -0.6e-3;
  p.ground_rho = 0.012;
  p.ground_theta = -0.009;
  return p;
}

// Valid pixels and their ground points in C, spread over the mirror image.
struct Samples {
  std::vector<Eigen::Vector2d> pixels;
  std::vector<Eigen::Vector3d> points;
};

Samples MakeSamples(const HyperbolicMirrorCamera& camera) {
  Samples samples;
  for (int v = 3; v < camera.height(); v += 17) {
    for (int u = 5; u < camera.width(); u += 19) {
      const Eigen::Vector2d pixel(u + 0.3, v + 0.6);
      Eigen::Vector2d ground;
      if (camera.BackProjectToGround(pixel, &ground) != ProjectionStatus::kOk) continue;
      samples.pixels.push_back(pixel);
      samples.points.push_back(camera.X_CG() * Eigen::Vector3d(ground.x(), ground.y(), 0.0));
    }
  }
  return samples;
}

void BM_GroundMap640x480(benchmark::State& state) {
  const HyperbolicMirrorCamera camera(BenchParameters());
  GroundMap map;
  ComputeGroundMap(camera, &map);  // the one allocating fill
  for (auto _ : state) {
    ComputeGroundMap(camera, &map);
    benchmark::DoNotOptimize(map.x_m.data());
    benchmark::ClobberMemory();
  }
  state.counters["valid_pixels"] = map.valid_count;
  state.SetItemsProcessed(state.iterations() * map.width * map.height);
}
BENCHMARK(BM_GroundMap640x480)->Unit(benchmark::kMillisecond);

void BM_BackProject(benchmark::State& state) {
  const HyperbolicMirrorCamera camera(BenchParameters());
  const Samples samples = MakeSamples(camera);
  const bool jacobian = state.range(0) != 0;
  std::size_t i = 0;
  Ray ray;
  RayJacobian J;
  for (auto _ : state) {
    benchmark::DoNotOptimize(camera.BackProject(samples.pixels[i], &ray, jacobian ? &J : nullptr));
    benchmark::DoNotOptimize(ray);
    if (++i == samples.pixels.size()) i = 0;
  }
}
BENCHMARK(BM_BackProject)->Arg(0)->Arg(1)->ArgName("jacobian");

void BM_BackProjectToGround(benchmark::State& state) {
  const HyperbolicMirrorCamera camera(BenchParameters());
  const Samples samples = MakeSamples(camera);
  std::size_t i = 0;
  Eigen::Vector2d ground;
  for (auto _ : state) {
    benchmark::DoNotOptimize(camera.BackProjectToGround(samples.pixels[i], &ground));
    benchmark::DoNotOptimize(ground);
    if (++i == samples.pixels.size()) i = 0;
  }
}
BENCHMARK(BM_BackProjectToGround);

void BM_Project(benchmark::State& state) {
  const HyperbolicMirrorCamera camera(BenchParameters());
  const Samples samples = MakeSamples(camera);
  const bool jacobian = state.range(0) != 0;
  std::size_t i = 0;
  Eigen::Vector2d pixel;
  Matrix23d J;
  for (auto _ : state) {
    benchmark::DoNotOptimize(camera.Project(samples.points[i], &pixel, jacobian ? &J : nullptr));
    benchmark::DoNotOptimize(pixel);
    if (++i == samples.points.size()) i = 0;
  }
}
BENCHMARK(BM_Project)->Arg(0)->Arg(1)->ArgName("jacobian");

}  // namespace
}  // namespace kinevis::vision
