// Frames through the in-process virtual CAN bus. Target (issue 2): >= 1,000,000 frames/s
// send->receive on one core; a 1 Mbit/s wire carries at most ~8,800 frames/s.
#include <benchmark/benchmark.h>

#include "hal/can/virtual_can_bus.h"

namespace kinevis::hal {
namespace {

// One sender, one receiver, a frame sent and received per iteration.
void BM_VirtualCanSendReceive(benchmark::State& state) {
  auto net = std::make_shared<VirtualCanNetwork>("bench", VirtualCanNetwork::Options{});
  auto a = net->Connect(), b = net->Connect();
  const CanFrame f = CanFrame::Standard(0x181, {1, 2, 3, 4, 5, 6, 7, 8});
  CanFrame got;
  for (auto _ : state) {
    a->Send(f);
    b->Receive(&got, std::chrono::microseconds(0));
    benchmark::DoNotOptimize(got);
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_VirtualCanSendReceive);

// A hexapod-sized bus: host + N drives; one frame from the host reaches N receivers.
void BM_VirtualCanFanOut(benchmark::State& state) {
  auto net = std::make_shared<VirtualCanNetwork>("bench", VirtualCanNetwork::Options{});
  auto host = net->Connect();
  std::vector<std::unique_ptr<VirtualCanBus>> drives;
  for (int i = 0; i < state.range(0); ++i) drives.push_back(net->Connect());
  const CanFrame f = CanFrame::Standard(0x080);
  CanFrame got;
  for (auto _ : state) {
    host->Send(f);
    for (auto& d : drives) d->Receive(&got, std::chrono::microseconds(0));
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}
BENCHMARK(BM_VirtualCanFanOut)->Arg(6);

// With the 1 Mbit/s bit-rate model on a simulated clock: the cost of arbitration and wire-time
// bookkeeping per frame.
void BM_VirtualCanBitRateModel(benchmark::State& state) {
  common::SimulatedClock clock;
  VirtualCanNetwork::Options o;
  o.bitrate = 1'000'000;
  o.clock = &clock;
  auto net = std::make_shared<VirtualCanNetwork>("bench", o);
  auto a = net->Connect(), b = net->Connect();
  const CanFrame f = CanFrame::Standard(0x181, {1, 2, 3, 4, 5, 6, 7, 8});
  CanFrame got;
  for (auto _ : state) {
    a->Send(f);
    clock.Advance(std::chrono::microseconds(200));
    b->Receive(&got, std::chrono::microseconds(0));
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_VirtualCanBitRateModel);

}  // namespace
}  // namespace kinevis::hal
