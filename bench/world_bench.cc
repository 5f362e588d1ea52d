// World step time (issue 5): one Step of the plant and the device simulators, no host traffic
// (the cost a world adds to every simulated step_period), and a step while the legs move.

#include <benchmark/benchmark.h>

#include <chrono>

#include "sim/diamond_world.h"
#include "sim/hexapod_world.h"

namespace {

using namespace std::chrono_literals;

// Six CanopenDriveSim serviced and the plant updated (FK only when a leg moved).
void BM_HexapodWorldStepIdle(benchmark::State& state) {
  kinevis::sim::HexapodWorldConfig c;
  c.network = "bench-idle";
  kinevis::sim::HexapodWorld world(c);
  world.Step(10ms);
  for (auto _ : state) world.Step(500us);
}
BENCHMARK(BM_HexapodWorldStepIdle);

// One warm-started forward-kinematics solve per step: the legs are commanded (by the drives'
// plant hooks) to a slowly moving configuration.
void BM_HexapodWorldStepMoving(benchmark::State& state) {
  kinevis::sim::HexapodWorldConfig c;
  c.network = "bench-moving";
  kinevis::sim::HexapodWorld world(c);
  world.Step(10ms);
  // Enable the drives through their device API (no host) and move every leg by a few counts
  // around where it is, within the following error window.
  int32_t start[6];
  for (int j = 0; j < 6; ++j) {
    kinevis::hal::Cia402Device& d = world.drive_device(j);
    start[j] = d.position();
    d.SetTargetPosition(start[j]);
    d.SetControlword(0x06);
    d.SetControlword(0x07);
    d.SetControlword(0x0F);
  }
  int k = 0;
  for (auto _ : state) {
    for (int j = 0; j < 6; ++j) {
      world.drive_device(j).SetTargetPosition(start[j] + (k % 200 < 100 ? k % 100 : 100 - k % 100));
    }
    ++k;
    world.Step(500us);
  }
  const auto plant = world.plant();
  if (plant.held || world.drive_device(0).state() != kinevis::hal::Cia402State::kOperationEnabled) {
    state.SkipWithError("the legs did not move (drive not enabled or plant held)");
  }
  state.counters["holds"] = static_cast<double>(plant.holds);
}
BENCHMARK(BM_HexapodWorldStepMoving);

void BM_DiamondWorldStepIdle(benchmark::State& state) {
  kinevis::sim::DiamondWorld world{kinevis::sim::DiamondWorldConfig{}};
  world.Step(10ms);
  for (auto _ : state) world.Step(500us);
}
BENCHMARK(BM_DiamondWorldStepIdle);

}  // namespace
