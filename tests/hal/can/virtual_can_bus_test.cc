#include "hal/can/virtual_can_bus.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <atomic>
#include <thread>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using namespace std::chrono_literals;
using ::testing::ContainsRegex;

std::shared_ptr<VirtualCanNetwork> MakeNetwork(VirtualCanNetwork::Options options = {}) {
  return std::make_shared<VirtualCanNetwork>("test", options);
}

TEST(VirtualCanBusTest, EveryNodeButTheSenderSeesEveryFrame) {
  auto net = MakeNetwork();
  auto a = net->Connect(), b = net->Connect(), c = net->Connect();
  const CanFrame sent = CanFrame::Standard(0x123, {1, 2, 3});
  ASSERT_FALSE(a->Send(sent));
  CanFrame got;
  ASSERT_FALSE(b->Receive(&got, 0us));
  EXPECT_EQ(got, sent);
  ASSERT_FALSE(c->Receive(&got, 0us));
  EXPECT_EQ(got, sent);
  EXPECT_EQ(a->Receive(&got, 0us), Errc::kTimeout);
  EXPECT_EQ(a->counters().tx_frames, 1u);
  EXPECT_EQ(b->counters().rx_frames, 1u);
}

TEST(VirtualCanBusTest, ReceiveWaitsForAFrameFromAnotherThread) {
  auto net = MakeNetwork();
  auto a = net->Connect(), b = net->Connect();
  std::thread sender([&] {
    std::this_thread::sleep_for(20ms);
    a->Send(CanFrame::Standard(0x42, {7}));
  });
  CanFrame got;
  EXPECT_FALSE(b->Receive(&got, 5s));
  EXPECT_EQ(got.id, 0x42u);
  sender.join();
}

TEST(VirtualCanBusTest, ReceiveTimesOutWithoutHanging) {
  auto net = MakeNetwork();
  auto a = net->Connect();
  CanFrame got;
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_EQ(a->Receive(&got, 30ms), Errc::kTimeout);
  const auto waited = std::chrono::steady_clock::now() - t0;
  EXPECT_GE(waited, 30ms);
  EXPECT_LT(waited, 5s);
}

TEST(VirtualCanBusTest, RegistrySharesNetworksByName) {
  auto n1 = VirtualCanNetwork::Get("shared-by-name", {});
  auto n2 = VirtualCanNetwork::Get("shared-by-name", {});
  EXPECT_EQ(n1, n2);
  VirtualCanNetwork::Options fast;
  fast.bitrate = 1'000'000;
  try {
    VirtualCanNetwork::Get("shared-by-name", fast);
    FAIL() << "expected ConfigError";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("already exists with bitrate 0, asked for 1000000"));
  }
}

TEST(VirtualCanBusTest, BadOptionsAreRejected) {
  VirtualCanNetwork::Options o;
  o.bitrate = 5;
  o.rx_queue_capacity = 0;
  try {
    VirtualCanNetwork("bad", o);
    FAIL();
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("\"bad\".*bitrate 5.*rx_queue_capacity"));
  }
}

TEST(VirtualCanBusTest, InvalidFrameIsRefused) {
  auto net = MakeNetwork();
  auto a = net->Connect();
  CanFrame f;
  f.id = 0x800;  // 12 bits in a standard frame
  EXPECT_EQ(a->Send(f), Errc::kInvalidArgument);
  f.extended = true;
  f.dlc = 9;
  EXPECT_EQ(a->Send(f), Errc::kInvalidArgument);
}

TEST(VirtualCanBusTest, FiltersSelectFrames) {
  auto net = MakeNetwork();
  auto a = net->Connect(), b = net->Connect();
  ASSERT_FALSE(b->SetFilters({CanFilter::Exact(0x181), CanFilter::Exact(0x701)}));
  a->Send(CanFrame::Standard(0x181, {1}));
  a->Send(CanFrame::Standard(0x182, {2}));
  a->Send(CanFrame::Standard(0x701, {5}));
  CanFrame got;
  ASSERT_FALSE(b->Receive(&got, 0us));
  EXPECT_EQ(got.id, 0x181u);
  ASSERT_FALSE(b->Receive(&got, 0us));
  EXPECT_EQ(got.id, 0x701u);
  EXPECT_EQ(b->Receive(&got, 0us), Errc::kTimeout);
  EXPECT_EQ(b->counters().rx_filtered, 1u);
}

TEST(VirtualCanBusTest, FullReceiveQueueOverflowsWithOneEvent) {
  VirtualCanNetwork::Options o;
  o.rx_queue_capacity = 4;
  auto net = MakeNetwork(o);
  auto a = net->Connect(), b = net->Connect();
  for (int i = 0; i < 10; ++i) ASSERT_FALSE(a->Send(CanFrame::Standard(0x100 + i)));
  EXPECT_EQ(b->counters().rx_overflows, 6u);
  CanErrorEvent e;
  ASSERT_TRUE(b->TakeErrorEvent(&e));
  EXPECT_EQ(e.kind, CanErrorKind::kRxOverflow);
  EXPECT_FALSE(b->TakeErrorEvent(&e));
  CanFrame got;
  ASSERT_FALSE(b->Receive(&got, 0us));
  EXPECT_EQ(got.id, 0x100u);  // the oldest frames are kept, the newest lost (like a FIFO)
}

// With a bit-rate model and a simulated clock, timing is exact and deterministic.
class TimedBusTest : public ::testing::Test {
 protected:
  TimedBusTest() {
    VirtualCanNetwork::Options o;
    o.bitrate = 500'000;
    o.clock = &clock_;
    net_ = MakeNetwork(o);
  }
  common::SimulatedClock clock_;
  std::shared_ptr<VirtualCanNetwork> net_;
};

TEST_F(TimedBusTest, FrameArrivesAfterItsWireTime) {
  auto a = net_->Connect(), b = net_->Connect();
  CanFrame f = CanFrame::Standard(0x123, {1, 2, 3, 4, 5, 6, 7, 8});
  const common::Duration wire =
      common::Duration(CanFrameWireBits(f) * 2000LL);  // 2 us per bit at 500 kbit/s
  ASSERT_FALSE(a->Send(f));
  CanFrame got;
  clock_.Advance(wire - 1ns);
  EXPECT_EQ(b->Receive(&got, 0us), Errc::kTimeout);
  clock_.Advance(1ns);
  ASSERT_FALSE(b->Receive(&got, 0us));
  EXPECT_EQ(got, f);
  EXPECT_EQ(got.timestamp, wire);
}

TEST_F(TimedBusTest, WaitingFramesAreArbitratedByIdentifier) {
  auto a = net_->Connect(), b = net_->Connect(), c = net_->Connect(), rx = net_->Connect();
  // a starts a frame at t = 0; while it is on the wire, b and c queue theirs. When the wire
  // frees, the lower identifier (c: 0x080 SYNC) wins although b queued first.
  ASSERT_FALSE(a->Send(CanFrame::Standard(0x700, {5})));
  clock_.Advance(10us);
  ASSERT_FALSE(b->Send(CanFrame::Standard(0x600, {1})));
  ASSERT_FALSE(c->Send(CanFrame::Standard(0x080)));
  clock_.Advance(1ms);
  std::vector<uint32_t> order;
  CanFrame got;
  while (!rx->Receive(&got, 0us)) order.push_back(got.id);
  EXPECT_EQ(order, (std::vector<uint32_t>{0x700, 0x080, 0x600}));
}

TEST_F(TimedBusTest, StandardBeatsExtendedWithTheSameBaseId) {
  auto a = net_->Connect(), b = net_->Connect(), busy = net_->Connect(), rx = net_->Connect();
  ASSERT_FALSE(busy->Send(CanFrame::Standard(0x001)));
  ASSERT_FALSE(a->Send(CanFrame::Extended(0x123u << 18)));  // base id 0x123
  ASSERT_FALSE(b->Send(CanFrame::Standard(0x123)));
  clock_.Advance(1ms);
  CanFrame got;
  ASSERT_FALSE(rx->Receive(&got, 0us));
  ASSERT_FALSE(rx->Receive(&got, 0us));
  EXPECT_FALSE(got.extended);
  ASSERT_FALSE(rx->Receive(&got, 0us));
  EXPECT_TRUE(got.extended);
}

TEST_F(TimedBusTest, BusLoadIsBusyTimeOverElapsedTime) {
  auto a = net_->Connect(), b = net_->Connect();
  net_->ResetStatistics();
  const CanFrame f = CanFrame::Standard(0x181, {0, 1, 2, 3, 4, 5, 6, 7});
  const int bits = CanFrameWireBits(f);
  // 1000 frames in one second at 500 kbit/s: load = 1000 * bits * 2 us / 1 s.
  for (int i = 0; i < 1000; ++i) {
    ASSERT_FALSE(a->Send(f));
    clock_.Advance(1ms);
  }
  auto s = net_->statistics();
  EXPECT_EQ(s.frames, 1000u);
  EXPECT_EQ(s.bits, 1000u * bits);
  EXPECT_NEAR(s.load(), 1000.0 * bits * 2e-6, 1e-9);
}

TEST_F(TimedBusTest, SaturatedSenderGetsOverflowFromItsTransmitQueue) {
  VirtualCanNetwork::Options o;
  o.bitrate = 125'000;
  o.clock = &clock_;
  o.tx_queue_capacity = 8;
  auto net = MakeNetwork(o);
  auto a = net->Connect(), b = net->Connect();
  int accepted = 0;
  std::error_code last;
  for (int i = 0; i < 20; ++i) {
    last = a->Send(CanFrame::Standard(0x200, {1, 2, 3, 4, 5, 6, 7, 8}));
    if (!last) ++accepted;
  }
  EXPECT_EQ(accepted, 8);
  EXPECT_EQ(last, Errc::kOverflow);
  EXPECT_EQ(a->counters().tx_errors, 12u);
}

TEST_F(TimedBusTest, DelayFaultPostponesDelivery) {
  auto a = net_->Connect(), b = net_->Connect();
  VirtualCanNetwork::Faults faults;
  faults.delay = 5ms;
  net_->SetFaults(faults);
  ASSERT_FALSE(a->Send(CanFrame::Standard(0x10)));
  CanFrame got;
  clock_.Advance(4ms);
  EXPECT_EQ(b->Receive(&got, 0us), Errc::kTimeout);
  clock_.Advance(2ms);
  EXPECT_FALSE(b->Receive(&got, 0us));
}

TEST(VirtualCanFaultTest, DropProbabilityLosesThatShareOfFrames) {
  auto net = MakeNetwork();
  auto a = net->Connect(), b = net->Connect();
  VirtualCanNetwork::Faults faults;
  faults.drop_probability = 0.25;
  faults.seed = 42;
  net->SetFaults(faults);
  const int n = 4000;
  for (int i = 0; i < n; ++i) ASSERT_FALSE(a->Send(CanFrame::Standard(0x100)));
  int received = 0;
  CanFrame got;
  while (!b->Receive(&got, 0us)) ++received;
  // Binomial(4000, 0.75): mean 3000, sd 27; the bounds are > 7 sd away.
  EXPECT_GT(received, 2800);
  EXPECT_LT(received, 3200);
  EXPECT_EQ(net->statistics().dropped, static_cast<uint64_t>(n - received));
}

TEST(VirtualCanFaultTest, DropIsReproducibleFromTheSeed) {
  auto run = [](uint32_t seed) {
    auto net = MakeNetwork();
    auto a = net->Connect(), b = net->Connect();
    VirtualCanNetwork::Faults faults;
    faults.drop_probability = 0.5;
    faults.seed = seed;
    net->SetFaults(faults);
    std::vector<uint32_t> ids;
    for (uint32_t i = 0; i < 64; ++i) a->Send(CanFrame::Standard(i));
    CanFrame got;
    while (!b->Receive(&got, 0us)) ids.push_back(got.id);
    return ids;
  };
  EXPECT_EQ(run(9), run(9));
  EXPECT_NE(run(9), run(10));
}

TEST(VirtualCanFaultTest, CorruptionRetransmitsAndRaisesErrorCounters) {
  auto net = MakeNetwork();
  auto a = net->Connect(), b = net->Connect();
  VirtualCanNetwork::Faults faults;
  faults.corrupt_probability = 0.5;
  faults.seed = 3;
  net->SetFaults(faults);
  for (int i = 0; i < 20; ++i) ASSERT_FALSE(a->Send(CanFrame::Standard(0x300 + i)));
  // Every frame arrives (CAN retransmits automatically), in order, but errors were signalled.
  CanFrame got;
  for (int i = 0; i < 20; ++i) {
    ASSERT_FALSE(b->Receive(&got, 0us)) << i;
    EXPECT_EQ(got.id, 0x300u + i);
  }
  const auto stats = net->statistics();
  EXPECT_GT(stats.error_frames, 0u);
  CanErrorEvent e;
  ASSERT_TRUE(b->TakeErrorEvent(&e));
  EXPECT_EQ(e.kind, CanErrorKind::kProtocol);
  EXPECT_THAT(e.detail, ContainsRegex("CRC error on frame 3"));
}

TEST(VirtualCanFaultTest, PersistentCorruptionDrivesTheSenderBusOff) {
  auto net = MakeNetwork();
  auto a = net->Connect(), b = net->Connect();
  VirtualCanNetwork::Faults faults;
  faults.corrupt_probability = 1.0;
  net->SetFaults(faults);
  ASSERT_FALSE(a->Send(CanFrame::Standard(0x123)));
  // 32 failed attempts: TEC 256 -> bus-off; the frame is abandoned, nothing hangs.
  EXPECT_EQ(a->state(), CanBusState::kBusOff);
  EXPECT_EQ(a->Send(CanFrame::Standard(0x123)), Errc::kBusOff);
  std::vector<CanErrorKind> kinds;
  CanErrorEvent e;
  while (a->TakeErrorEvent(&e)) {
    if (e.kind != CanErrorKind::kProtocol) kinds.push_back(e.kind);
  }
  EXPECT_EQ(kinds, (std::vector<CanErrorKind>{CanErrorKind::kErrorWarning,
                                              CanErrorKind::kErrorPassive, CanErrorKind::kBusOff}));
  EXPECT_EQ(a->counters().bus_off_events, 1u);
  CanFrame got;
  EXPECT_EQ(b->Receive(&got, 0us), Errc::kTimeout);
  // Receivers stay error-active: their counter rose by only one per error frame.
  EXPECT_EQ(b->rx_error_counter(), 32);
  EXPECT_EQ(b->state(), CanBusState::kErrorActive);
  net->SetFaults({});
  a->Recover();
  EXPECT_EQ(a->state(), CanBusState::kErrorActive);
  ASSERT_TRUE(a->TakeErrorEvent(&e));
  EXPECT_EQ(e.kind, CanErrorKind::kRestarted);
  EXPECT_FALSE(a->Send(CanFrame::Standard(0x124)));
  ASSERT_FALSE(b->Receive(&got, 0us));
  EXPECT_EQ(got.id, 0x124u);
}

TEST(VirtualCanFaultTest, InjectedBusOffStopsTransmissionAndReception) {
  auto net = MakeNetwork();
  auto a = net->Connect(), b = net->Connect();
  a->InjectBusOff();
  EXPECT_EQ(a->state(), CanBusState::kBusOff);
  EXPECT_EQ(a->Send(CanFrame::Standard(1)), Errc::kBusOff);
  ASSERT_FALSE(b->Send(CanFrame::Standard(2)));
  CanFrame got;
  EXPECT_EQ(a->Receive(&got, 0us), Errc::kTimeout);
  CanErrorEvent e;
  ASSERT_TRUE(a->TakeErrorEvent(&e));
  EXPECT_EQ(e.kind, CanErrorKind::kBusOff);
}

TEST(VirtualCanBusTest, ManyThreadsManyNodesNoFrameLost) {
  VirtualCanNetwork::Options o;
  o.rx_queue_capacity = 100'000;
  auto net = MakeNetwork(o);
  constexpr int kSenders = 4, kFrames = 5000;
  std::vector<std::unique_ptr<VirtualCanBus>> senders;
  for (int i = 0; i < kSenders; ++i) senders.push_back(net->Connect());
  auto rx = net->Connect();
  std::vector<std::thread> threads;
  for (int i = 0; i < kSenders; ++i) {
    threads.emplace_back([&, i] {
      for (int k = 0; k < kFrames; ++k) senders[i]->Send(CanFrame::Standard(0x100 + i));
    });
  }
  int received = 0;
  CanFrame got;
  while (received < kSenders * kFrames && !rx->Receive(&got, 2s)) ++received;
  for (auto& t : threads) t.join();
  EXPECT_EQ(received, kSenders * kFrames);
}

}  // namespace
}  // namespace kinevis::hal
