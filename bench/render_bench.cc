// Synthetic image rendering (issue 5): a 640×480 frame in ≤ 10 ms on one core.
// Run: ./build/bench/render_bench --benchmark_repetitions=5 (pin with taskset -c 0; this machine's
// timings vary by 20–50 % with the host's load: build/bench/render_frames counts instructions).
// Built with the default build type (RelWithDebInfo; the renderer's sources at -O3).

#include <benchmark/benchmark.h>

#include <vector>

#include "bench/render_scenes.h"

namespace kinevis::vision::render {
namespace {

void RenderLoop(benchmark::State& state, const char* name) {
  const bench::BenchScene s = bench::MakeBenchScene(name);
  Renderer renderer(*s.camera, bench::BenchOptions(state.range(0) != 0));
  const int width = s.camera->width(), height = s.camera->height();
  std::vector<uint8_t> pixels(static_cast<size_t>(width) * height);
  const ImageView8 view{pixels.data(), width, height, static_cast<size_t>(width)};
  // The first frame pays the one-time costs (buffers; a camera-fixed part's answers, which
  // BM_SoccerFieldMirrorSetUp measures): outside the timed loop, so that this is the per-frame
  // time.
  renderer.Render(*s.scene, 0, view);
  uint64_t frame = 1;
  for (auto _ : state) {
    renderer.Render(*s.scene, frame++, view);
    benchmark::DoNotOptimize(pixels.data());
    benchmark::ClobberMemory();
  }
  state.counters["edge_px"] = renderer.last_edge_pixels();
}

void BM_HexapodPerspective(benchmark::State& state) { RenderLoop(state, "hexapod-perspective"); }
BENCHMARK(BM_HexapodPerspective)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

void BM_HexapodUnified(benchmark::State& state) { RenderLoop(state, "hexapod-unified"); }
BENCHMARK(BM_HexapodUnified)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

void BM_ChessboardPerspective(benchmark::State& state) { RenderLoop(state, "chessboard"); }
BENCHMARK(BM_ChessboardPerspective)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

void BM_SoccerFieldMirror(benchmark::State& state) { RenderLoop(state, "soccer"); }
BENCHMARK(BM_SoccerFieldMirror)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

// What a soccer world pays once: the renderer's constructor (one BackProject per pixel, the
// interpolation checks) and the first frame, which asks the scene's camera-fixed part about every
// ray (renderer.h).
void BM_SoccerFieldMirrorSetUp(benchmark::State& state) {
  const bench::BenchScene s = bench::MakeBenchScene("soccer");
  std::vector<uint8_t> pixels(static_cast<size_t>(s.camera->width()) * s.camera->height());
  const ImageView8 view{pixels.data(), s.camera->width(), s.camera->height(),
                        static_cast<size_t>(s.camera->width())};
  for (auto _ : state) {
    Renderer renderer(*s.camera, RenderOptions{});
    renderer.Render(*s.scene, 0, view);
    benchmark::DoNotOptimize(pixels.data());
  }
}
BENCHMARK(BM_SoccerFieldMirrorSetUp)->Unit(benchmark::kMillisecond);

void BM_LaserBlade1616x1216(benchmark::State& state) { RenderLoop(state, "laser"); }
BENCHMARK(BM_LaserBlade1616x1216)->Arg(0)->Unit(benchmark::kMillisecond);

void BM_DiamondMarker1280x640(benchmark::State& state) { RenderLoop(state, "diamond"); }
BENCHMARK(BM_DiamondMarker1280x640)->Arg(0)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace kinevis::vision::render
