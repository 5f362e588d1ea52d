// Issue 7: a 1,000,000-point scanned map to a weld plan (target <= 1 s on one core).
// The map: the test blade (tests/control/weld/synthetic_blade.h) widened to the weld cell's
// 200 × 160 mm, sampled every 0.179 mm (1.0 M points, 0.02 mm noise, 1 % outliers), in the robot
// base frame. Timed: the whole PlanWeldRepair (reference fit, depth grid, regions, layers,
// passes, ordering, torch IK of every point, timing of the trajectory), and its parts.

#include <benchmark/benchmark.h>

#include "control/weld/weld_plan_io.h"
#include "control/weld/weld_planner.h"
#include "tests/control/weld/synthetic_blade.h"

namespace {

using namespace kinevis;

const control::WeldMap& Map() {
  static const control::WeldMap map = [] {
    control::testing::SyntheticBlade blade = control::testing::DefaultTestBlade();
    blade.scene.half_extent = Eigen::Vector2d(0.10, 0.08);
    blade.spacing = 0.179e-3;
    return blade.Make();
  }();
  return map;
}

robots::Weld5Model Robot() {
  return robots::Weld5Model::Seed(robots::Weld5TorchTransform(0.025, 0.250, 0.0));
}

void BM_PlanWeldRepair(benchmark::State& state) {
  const control::WeldMap& map = Map();
  const robots::Weld5Model robot = Robot();
  control::WeldPlan plan;
  for (auto _ : state) {
    plan = control::PlanWeldRepair(map, robot);
    benchmark::DoNotOptimize(plan.trajectory.data());
  }
  state.counters["map_points"] = static_cast<double>(map.p_0.size());
  state.counters["beads"] = plan.summary.beads;
  state.counters["executable"] = plan.summary.executable_beads;
  state.counters["plan_points"] = plan.summary.points;
  state.counters["segments"] = static_cast<double>(plan.trajectory.size());
  state.counters["coverage"] = plan.summary.coverage_executable;
  state.SetLabel(control::ToString(plan.summary.status));
}
BENCHMARK(BM_PlanWeldRepair)->Unit(benchmark::kMillisecond)->MinTime(3.0);

void BM_FitReferenceSurface(benchmark::State& state) {
  const control::WeldMap& map = Map();
  for (auto _ : state) {
    const control::ReferenceFit fit = control::FitReferenceSurface(map.p_0, map.n_0);
    benchmark::DoNotOptimize(fit.surface.coefficients.data());
  }
}
BENCHMARK(BM_FitReferenceSurface)->Unit(benchmark::kMillisecond);

void BM_WriteWeldPlan(benchmark::State& state) {
  const control::WeldPlan plan = control::PlanWeldRepair(Map(), Robot());
  for (auto _ : state) control::WriteWeldPlan("/tmp/weld_plan_bench.yaml", plan);
}
BENCHMARK(BM_WriteWeldPlan)->Unit(benchmark::kMillisecond);

}  // namespace
