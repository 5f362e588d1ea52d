// Host cost of one CANopen CiA 402 cycle: six drives in cyclic synchronous position mode at a
// 1 kHz SYNC on the in-process virtual bus (issue target: <= 20 us per cycle).
//
// What is timed: CanopenMaster::Cycle() on the calling thread: draining the receive queue,
// heartbeat supervision, composing and sending 12 RPDOs and the SYNC, receiving and decoding the
// 12 TPDOs, the state machine and SI conversion of every drive, plus the six SetTargetPosition()
// calls of the control loop. What is not timed: the six CanopenDriveSim, which run on the same
// thread (deterministic, no scheduler noise) inside the clock's SleepUntil() while the master
// waits for its TPDOs; the time spent in them is measured and subtracted from each iteration
// (manual timing). The wall-clock cost including the simulators is reported as the counter
// `with_sims_us`. The virtual bus has no bit-rate model here: wire time is not host cost.

#include <benchmark/benchmark.h>

#include <chrono>
#include <cmath>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "common/clock.h"
#include "hal/can/virtual_can_bus.h"
#include "hal/canopen/canopen_master.h"
#include "hal/drive/cia402_can_drive.h"
#include "hal/mock/canopen_drive_sim.h"

namespace kinevis::hal {
namespace {

using namespace std::chrono_literals;

// Simulated time that passes when the master sleeps on it; meanwhile the simulators are
// serviced, and the wall time they take is accumulated so that it can be left out.
class BenchClock final : public common::Clock {
 public:
  common::Duration Now() const override { return time_.Now(); }
  void SleepUntil(common::Duration deadline) override {
    const auto start = std::chrono::steady_clock::now();
    while (time_.Now() < deadline) {
      time_.AdvanceTo(std::min(deadline, time_.Now() + common::Duration(50us)));
      for (CanopenDriveSim* sim : sims_) sim->Service();
    }
    excluded_ += std::chrono::steady_clock::now() - start;
  }
  void Add(CanopenDriveSim* sim) { sims_.push_back(sim); }
  std::chrono::steady_clock::duration TakeExcluded() {
    auto e = excluded_;
    excluded_ = {};
    return e;
  }

 private:
  common::SimulatedClock time_;
  std::vector<CanopenDriveSim*> sims_;
  std::chrono::steady_clock::duration excluded_{};
};

void BM_Cia402CspCycleSixDrives(benchmark::State& state) {
  constexpr int kDrives = 6;
  constexpr double kCountsPerRad = 65536.0 / (2 * 3.14159265358979323846);
  BenchClock clock;
  VirtualCanNetwork::Options net_options;
  net_options.clock = &clock;
  auto network = std::make_shared<VirtualCanNetwork>("cia402-bench", net_options);
  std::vector<std::unique_ptr<VirtualCanBus>> sim_nodes;
  std::vector<std::unique_ptr<CanopenDriveSim>> sims;
  canopen::CanopenMasterOptions options;
  options.clock = &clock;
  canopen::CanopenMaster master(network->Connect("virtual:bench"), options);
  std::vector<Cia402CanDrive*> drives;
  for (int i = 1; i <= kDrives; ++i) {
    CanopenDriveSim::Options o;
    o.node = static_cast<uint8_t>(i);
    sim_nodes.push_back(network->Connect("sim" + std::to_string(i)));
    sims.push_back(std::make_unique<CanopenDriveSim>(sim_nodes.back().get(), &clock, o));
    clock.Add(sims.back().get());
    Cia402CanDriveConfig c;
    c.node = static_cast<uint8_t>(i);
    c.drive.scaling.position_counts_per_unit = kCountsPerRad;
    c.drive.scaling.velocity_counts_per_unit = kCountsPerRad;
    drives.push_back(master.AddDrive(c));
  }
  master.ConfigureAll();
  if (master.EnableAll(1000ms)) {
    state.SkipWithError("the drives did not enable");
    return;
  }
  common::Duration next = clock.Now();
  uint64_t k = 0;
  double total_with_sims_s = 0;
  for (auto _ : state) {
    ++k;
    next += 1ms;
    clock.SleepUntil(next);  // the rest of the period: simulators only, not timed
    clock.TakeExcluded();
    const double target = 0.3 * std::sin(2 * 3.14159265358979323846 * 1e-3 * k);
    const auto start = std::chrono::steady_clock::now();
    for (Cia402CanDrive* d : drives) (void)d->SetTargetPosition(target);
    const std::error_code ec = master.Cycle();
    const auto wall = std::chrono::steady_clock::now() - start;
    const auto sims_time = clock.TakeExcluded();
    if (ec) {
      state.SkipWithError(("cycle failed: " + ec.message()).c_str());
      break;
    }
    total_with_sims_s += std::chrono::duration<double>(wall).count();
    state.SetIterationTime(std::chrono::duration<double>(wall - sims_time).count());
  }
  state.counters["with_sims_us"] =
      benchmark::Counter(total_with_sims_s * 1e6 / static_cast<double>(std::max<uint64_t>(k, 1)));
  state.counters["tpdos_per_cycle"] = benchmark::Counter(
      static_cast<double>(master.counters().tpdos) / static_cast<double>(master.cycle_count()));
}
BENCHMARK(BM_Cia402CspCycleSixDrives)->UseManualTime()->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace kinevis::hal
