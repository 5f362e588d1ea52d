// Laser stripe extraction (issue 7): both stripes of the seed-004 scanner on a 1616×1216 frame,
// target <= 3 ms on one core. The frame is rendered once (blade with cavitation pits, both lasers,
// sensor noise σ = 1 grey level) through the built-in "tsai-seed004" camera; the extractor and
// the result are reused, as in a scan loop (no allocation per frame).
// Run: ./build/bench/laser_stripes_bench --benchmark_min_time=1
// Configure with -DKINEVIS_BUILD_BENCH=ON (RelWithDebInfo, -O2, the default build type).

#include <benchmark/benchmark.h>

#include <memory>
#include <vector>

#include "vision/camera/camera_file.h"
#include "vision/laser/laser_stripes.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/laser_scene.h"

namespace kinevis::vision::laser {
namespace {

struct Frame {
  int width = 0;
  int height = 0;
  std::vector<uint8_t> pixels;
  vision::ImageView8 view() {
    return vision::ImageView8{pixels.data(), width, height, static_cast<size_t>(width)};
  }
};

// As tests/vision/laser/laser_stripes_test.cc's PittedBlade().
Frame& BladeFrame(bool fixed_on, bool rotating_on) {
  static Frame frames[4];
  Frame& frame = frames[(fixed_on ? 2 : 0) + (rotating_on ? 1 : 0)];
  if (!frame.pixels.empty()) return frame;
  const std::unique_ptr<CameraModel> camera = BuiltinCameraModel("tsai-seed004");
  render::LaserSceneParameters p;
  p.curvature_xx = 2.0;
  p.curvature_yy = 0.5;
  p.curvature_xy = 0.3;
  p.pits = {{Eigen::Vector2d(0.02, 0.002), 1.0e-3, 3e-3},
            {Eigen::Vector2d(-0.04, 0.004), 0.5e-3, 2e-3},
            {Eigen::Vector2d(0.03, 0.03), 0.8e-3, 2.5e-3}};
  p.fixed_on = fixed_on;
  p.rotating_on = rotating_on;
  const render::LaserScene scene(p);
  render::RenderOptions options;
  options.noise_sigma = 1.0;
  render::Renderer renderer(*camera, options);
  frame.width = camera->width();
  frame.height = camera->height();
  frame.pixels.assign(static_cast<size_t>(frame.width) * frame.height, 0);
  renderer.Render(scene, 0, frame.view());
  return frame;
}

void Extract(benchmark::State& state, PeakLocator locator, bool fixed_on, bool rotating_on) {
  Frame& frame = BladeFrame(fixed_on, rotating_on);
  LaserStripeOptions options;
  options.locator = locator;
  LaserStripeExtractor extractor(options);
  LaserStripes result;
  extractor.Extract(frame.view(), &result);  // sizes the scratch and the result
  for (auto _ : state) {
    extractor.Extract(frame.view(), &result);
    benchmark::DoNotOptimize(result.crossing.pixel);
  }
  state.counters["fixed_pts"] = static_cast<double>(result.stripe(Stripe::kFixed).points.size());
  state.counters["rotating_pts"] =
      static_cast<double>(result.stripe(Stripe::kRotating).points.size());
  state.counters["crossing"] = result.crossing.found() ? 1 : 0;
}

void BM_BothStripes_Gaussian3Point(benchmark::State& state) {
  Extract(state, PeakLocator::kGaussian3Point, true, true);
}
void BM_BothStripes_CentreOfGravity(benchmark::State& state) {
  Extract(state, PeakLocator::kCentreOfGravity, true, true);
}
void BM_BothStripes_GaussianFit(benchmark::State& state) {
  Extract(state, PeakLocator::kGaussianFit, true, true);
}
// A frame with no stripe: the cost of the scan alone.
void BM_NoStripe(benchmark::State& state) {
  Extract(state, PeakLocator::kGaussian3Point, false, false);
}
BENCHMARK(BM_BothStripes_Gaussian3Point)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_BothStripes_CentreOfGravity)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_BothStripes_GaussianFit)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_NoStripe)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace kinevis::vision::laser
