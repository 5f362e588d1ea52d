#include "hal/can/slcan_bus.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "hal/can/virtual_can_bus.h"
#include "hal/common/error.h"
#include "hal/mock/slcan_adapter_sim.h"
#include "hal/serial/pty_pair.h"
#include "hal/serial/termios_serial_port.h"

namespace kinevis::hal {
namespace {

using namespace std::chrono_literals;
using ::testing::ContainsRegex;
using ::testing::HasSubstr;
using SimState = SlcanAdapterSim::State;

// Bounds for things that take microseconds when all is well; generous for a loaded machine.
constexpr auto kDeadline = 5s;
constexpr std::chrono::microseconds kReceiveTimeout = kDeadline;

template <typename Condition>
bool WaitFor(Condition condition, std::chrono::milliseconds deadline = kDeadline) {
  const auto end = std::chrono::steady_clock::now() + deadline;
  while (!condition()) {
    if (std::chrono::steady_clock::now() > end) return false;
    std::this_thread::sleep_for(1ms);
  }
  return true;
}

std::string TestName() { return ::testing::UnitTest::GetInstance()->current_test_info()->name(); }

// SlcanBus opened through the normal backend-string path on the slave of a pty, whose master is
// served by SlcanAdapterSim, bridged to a virtual CAN bus on which `peer_` is another node.
class SlcanBusTest : public ::testing::Test {
 protected:
  void SetUp() override {
    pty_ = std::make_unique<PtyPair>();
    network_ = VirtualCanNetwork::Get("slcan-bus-test-" + TestName(), {});
    adapter_node_ = network_->Connect("adapter");
    peer_ = network_->Connect("peer");
    sim_ = std::make_unique<SlcanAdapterSim>(pty_->MasterPort(), adapter_node_.get(),
                                             SlcanAdapterSim::Options{});
    sim_->Start();
  }

  CanBackendSpec Spec(const std::string& options = ",bitrate=500000") const {
    return ParseCanBackend("slcan:" + pty_->slave_path() + "@115200" + options);
  }

  void OpenBus(const std::string& options = ",bitrate=500000",
               const SlcanBusOptions& bus_options = {}) {
    bus_ = SlcanBus::Open(Spec(options), bus_options);
  }

  // Takes error events until one of `kind` comes; false when none came within the deadline.
  bool WaitForEvent(CanErrorKind kind, CanErrorEvent* found = nullptr) {
    return WaitFor([&] {
      CanErrorEvent e;
      while (bus_->TakeErrorEvent(&e)) {
        if (e.kind == kind) {
          if (found != nullptr) *found = e;
          return true;
        }
      }
      return false;
    });
  }

  std::unique_ptr<PtyPair> pty_;
  std::shared_ptr<VirtualCanNetwork> network_;
  std::unique_ptr<VirtualCanBus> adapter_node_;
  std::unique_ptr<VirtualCanBus> peer_;
  std::unique_ptr<SlcanAdapterSim> sim_;
  std::unique_ptr<SlcanBus> bus_;
};

TEST_F(SlcanBusTest, SetsTheAdapterUpAndOpensIt) {
  OpenBus();
  EXPECT_EQ(sim_->state(), SimState::kOpen);
  EXPECT_EQ(sim_->bitrate_code(), 6);
  EXPECT_FALSE(sim_->timestamps());
  EXPECT_EQ(bus_->adapter_version(), "1013");
  EXPECT_EQ(bus_->name(), "slcan:" + pty_->slave_path() + "@115200,bitrate=500000");
  EXPECT_FALSE(bus_->listen_only());
  EXPECT_EQ(bus_->state(), CanBusState::kErrorActive);
}

TEST_F(SlcanBusTest, KeepsTheAdapterBitRateWhenNoneIsGiven) {
  OpenBus("");
  EXPECT_EQ(sim_->state(), SimState::kOpen);
  EXPECT_EQ(sim_->bitrate_code(), -1);
}

TEST_F(SlcanBusTest, ClosesAChannelLeftOpenBeforeSettingUp) {
  {
    SerialSettings settings;
    settings.device = pty_->slave_path();
    auto raw = OpenSerialPort(settings);
    const std::string open = "O\r";
    ASSERT_FALSE(raw->WriteAll(reinterpret_cast<const uint8_t*>(open.data()), open.size(),
                               std::chrono::microseconds(1s)));
    ASSERT_TRUE(WaitFor([&] { return sim_->state() == SimState::kOpen; }));
  }
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x7AA)));  // traffic of the channel left open
  OpenBus();  // S6 would be refused on an open channel: C must have closed it first
  EXPECT_EQ(sim_->state(), SimState::kOpen);
  EXPECT_EQ(sim_->bitrate_code(), 6);
}

TEST_F(SlcanBusTest, DestructorClosesTheChannel) {
  OpenBus();
  ASSERT_EQ(sim_->state(), SimState::kOpen);
  bus_.reset();
  EXPECT_TRUE(WaitFor([&] { return sim_->state() == SimState::kClosed; }));
  OpenBus();  // and it can be opened again
  EXPECT_EQ(sim_->state(), SimState::kOpen);
}

TEST_F(SlcanBusTest, SendsFramesOntoTheBus) {
  OpenBus();
  CanFrame remote = CanFrame::Extended(0x1ABCDEF0);
  remote.rtr = true;
  remote.dlc = 3;
  const std::vector<CanFrame> frames = {CanFrame::Standard(0x123, {0xAA, 0xBB}),
                                        CanFrame::Extended(0x12345678, {1, 2, 3, 4, 5, 6, 7, 8}),
                                        CanFrame::Standard(0x000), remote};
  for (const CanFrame& f : frames) ASSERT_FALSE(bus_->Send(f));
  for (const CanFrame& expected : frames) {
    CanFrame got;
    ASSERT_FALSE(peer_->Receive(&got, kReceiveTimeout));
    EXPECT_EQ(got, expected);
  }
  EXPECT_EQ(bus_->counters().tx_frames, frames.size());
  EXPECT_TRUE(WaitFor([&] { return sim_->statistics().frames_to_bus == frames.size(); }));
  EXPECT_EQ(bus_->counters().tx_errors, 0u);
}

TEST_F(SlcanBusTest, RefusesAnInvalidFrame) {
  OpenBus();
  CanFrame bad = CanFrame::Standard(0x1);
  bad.id = 0x800;
  EXPECT_EQ(bus_->Send(bad), Errc::kInvalidArgument);
  EXPECT_EQ(bus_->counters().tx_frames, 0u);
}

TEST_F(SlcanBusTest, ReceivesFramesWithTheHostArrivalTime) {
  OpenBus();
  const common::Duration before = common::SteadyClock::Instance().Now();
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x321, {0xDE, 0xAD})));
  ASSERT_FALSE(peer_->Send(CanFrame::Extended(0x1FFFFFFF, {0x01})));
  CanFrame got;
  ASSERT_FALSE(bus_->Receive(&got, kReceiveTimeout));
  const common::Duration after = common::SteadyClock::Instance().Now();
  EXPECT_EQ(got, CanFrame::Standard(0x321, {0xDE, 0xAD}));
  EXPECT_GE(got.timestamp, before);
  EXPECT_LE(got.timestamp, after);
  EXPECT_FALSE(bus_->last_adapter_timestamp_ms().has_value());
  ASSERT_FALSE(bus_->Receive(&got, kReceiveTimeout));
  EXPECT_EQ(got, CanFrame::Extended(0x1FFFFFFF, {0x01}));
  EXPECT_EQ(bus_->counters().rx_frames, 2u);
}

TEST_F(SlcanBusTest, ReceiveTimesOutWhenNothingComes) {
  OpenBus();
  CanFrame got;
  const auto start = std::chrono::steady_clock::now();
  EXPECT_EQ(bus_->Receive(&got, 50ms), Errc::kTimeout);
  EXPECT_GE(std::chrono::steady_clock::now() - start, 45ms);
  EXPECT_EQ(bus_->Receive(&got, 0us), Errc::kTimeout);
}

TEST_F(SlcanBusTest, AppliesSoftwareFilters) {
  OpenBus();
  ASSERT_FALSE(bus_->SetFilters({CanFilter::Exact(0x100), CanFilter::Exact(0x1234567, true)}));
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x200)));
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x100, {1})));
  ASSERT_FALSE(peer_->Send(CanFrame::Extended(0x100)));  // same id, but extended
  ASSERT_FALSE(peer_->Send(CanFrame::Extended(0x1234567, {2})));
  CanFrame got;
  ASSERT_FALSE(bus_->Receive(&got, kReceiveTimeout));
  EXPECT_EQ(got, CanFrame::Standard(0x100, {1}));
  ASSERT_FALSE(bus_->Receive(&got, kReceiveTimeout));
  EXPECT_EQ(got, CanFrame::Extended(0x1234567, {2}));
  EXPECT_EQ(bus_->counters().rx_filtered, 2u);

  ASSERT_FALSE(bus_->SetFilters({}));  // passes everything again
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x200)));
  ASSERT_FALSE(bus_->Receive(&got, kReceiveTimeout));
  EXPECT_EQ(got, CanFrame::Standard(0x200));

  CanFilter bad;
  bad.mask = 0x3FFFFFFF;
  EXPECT_EQ(bus_->SetFilters({bad}), Errc::kInvalidArgument);
}

TEST_F(SlcanBusTest, ListenOnlyReceivesButRefusesToSend) {
  OpenBus(",bitrate=500000,listen");
  EXPECT_EQ(sim_->state(), SimState::kListenOnly);
  EXPECT_TRUE(bus_->listen_only());
  EXPECT_EQ(bus_->Send(CanFrame::Standard(0x1)), Errc::kUnsupported);
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x2)));
  CanFrame got;
  ASSERT_FALSE(bus_->Receive(&got, kReceiveTimeout));
  EXPECT_EQ(got, CanFrame::Standard(0x2));
}

TEST_F(SlcanBusTest, KeepsTheAdapterTimestamp) {
  OpenBus(",bitrate=500000,timestamps");
  EXPECT_TRUE(sim_->timestamps());
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x5)));
  CanFrame got;
  ASSERT_FALSE(bus_->Receive(&got, kReceiveTimeout));
  ASSERT_TRUE(bus_->last_adapter_timestamp_ms().has_value());
  const uint16_t adapter_ms = *bus_->last_adapter_timestamp_ms();
  EXPECT_LE(adapter_ms, kSlcanMaxTimestampMs);
  // The simulator's counter is the bus time modulo 60 s, and the bus runs on the same steady
  // clock as the host: the adapter stamp is a little before the host's arrival time.
  const auto host_ms = std::chrono::duration_cast<std::chrono::milliseconds>(got.timestamp).count();
  const auto host_mod = static_cast<uint16_t>(host_ms % (kSlcanMaxTimestampMs + 1));
  EXPECT_LT(SlcanTimestampDeltaMs(adapter_ms, host_mod), 5000);
}

TEST_F(SlcanBusTest, AdapterRefusingASetUpCommandThrowsNamingTheCommand) {
  sim_->RefuseCommands("S");
  try {
    OpenBus();
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("^slcan:/dev/pts/[0-9]+@115200,bitrate=500000: "
                                        "set-up command \"S6\" \\(CAN bit rate 500000 bit/s\\) "
                                        "failed: the adapter answered BEL"));
    EXPECT_EQ(e.code(), Errc::kDeviceFault);
  }
  sim_->RefuseCommands("O");
  try {
    OpenBus("");
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("set-up command \"O\" \\(open the channel\\) failed: "
                                        "the adapter answered BEL"));
  }
  sim_->RefuseCommands("Z");
  EXPECT_THROW(OpenBus(",timestamps"), HalError);
}

TEST_F(SlcanBusTest, AdapterNotAnsweringTheVersionIsStillUsed) {
  sim_->RefuseCommands("V");
  OpenBus();
  EXPECT_EQ(bus_->adapter_version(), "");
  EXPECT_EQ(sim_->state(), SimState::kOpen);
}

TEST_F(SlcanBusTest, SilentAdapterThrowsWithinTheTimeout) {
  sim_->SetSilent(true);
  SlcanBusOptions options;
  options.setup_timeout = 200ms;
  const auto start = std::chrono::steady_clock::now();
  try {
    OpenBus(",bitrate=500000", options);
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("set-up command \"S6\" .* failed: no answer within "
                                        "200 ms; is /dev/pts/[0-9]+ a Lawicel"));
    EXPECT_EQ(e.code(), Errc::kTimeout);
  }
  // C, V and S6 each wait 200 ms: a hang would be far beyond this bound.
  EXPECT_LT(std::chrono::steady_clock::now() - start, 30s);
}

TEST_F(SlcanBusTest, BadSpecsAndMissingDevicesThrow) {
  EXPECT_THROW(SlcanBus::Open(ParseCanBackend("virtual:x")), common::ConfigError);
  CanBackendSpec no_code = Spec();
  no_code.bitrate = 33333;
  EXPECT_THROW(SlcanBus::Open(no_code), common::ConfigError);
  try {
    SlcanBus::Open(ParseCanBackend("slcan:/dev/kinevis-no-such-adapter@115200"));
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("/dev/kinevis-no-such-adapter.*ENOENT"));
  }
}

TEST_F(SlcanBusTest, GarbageIsCountedReportedAndRecovered) {
  OpenBus();
  sim_->InjectGarbage("\x01garbage\r");
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x111)));
  CanFrame got;
  ASSERT_FALSE(bus_->Receive(&got, kReceiveTimeout));
  EXPECT_EQ(got, CanFrame::Standard(0x111));
  EXPECT_EQ(bus_->counters().decode_errors, 1u);
  CanErrorEvent event;
  ASSERT_TRUE(WaitForEvent(CanErrorKind::kAdapter, &event));
  EXPECT_THAT(event.detail, HasSubstr("\\x01garbage"));

  // Garbage without a terminator runs into the next line: that line is lost too, no more.
  sim_->InjectGarbage("junk");
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x222)));
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x333)));
  ASSERT_FALSE(bus_->Receive(&got, kReceiveTimeout));
  EXPECT_EQ(got, CanFrame::Standard(0x333));
  EXPECT_EQ(bus_->counters().decode_errors, 2u);
  ASSERT_TRUE(WaitForEvent(CanErrorKind::kAdapter, &event));
  EXPECT_THAT(event.detail, HasSubstr("junkt2220"));
}

TEST_F(SlcanBusTest, LostBytesCostOneFrame) {
  OpenBus();
  sim_->DropBytesToHost(1);  // the 't' of the next line
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x123, {0xAA, 0xBB})));
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x456)));
  CanFrame got;
  ASSERT_FALSE(bus_->Receive(&got, kReceiveTimeout));
  EXPECT_EQ(got, CanFrame::Standard(0x456));
  EXPECT_EQ(bus_->counters().decode_errors, 1u);
  EXPECT_EQ(sim_->statistics().bytes_dropped, 1u);
}

TEST_F(SlcanBusTest, AdapterNakIsCountedAsATransmitError) {
  OpenBus();
  sim_->RefuseCommands("t");
  EXPECT_FALSE(bus_->Send(CanFrame::Standard(0x10)));  // does not wait for the answer
  ASSERT_TRUE(WaitFor([&] { return bus_->counters().tx_errors == 1; }));
  CanErrorEvent event;
  ASSERT_TRUE(WaitForEvent(CanErrorKind::kAdapter, &event));
  EXPECT_THAT(event.detail, HasSubstr("refused a frame"));
  sim_->RefuseCommands("");
  ASSERT_FALSE(bus_->Send(CanFrame::Standard(0x11)));
  CanFrame got;
  ASSERT_FALSE(peer_->Receive(&got, kReceiveTimeout));
  EXPECT_EQ(got, CanFrame::Standard(0x11));
  EXPECT_EQ(bus_->counters().tx_frames, 2u);
}

TEST_F(SlcanBusTest, StatusFlagsBecomeErrorEventsAndState) {
  OpenBus();
  sim_->SetStatusFlags(kSlcanErrorWarning | kSlcanErrorPassive | kSlcanBusError |
                       kSlcanDataOverrun);
  ASSERT_FALSE(bus_->RequestStatus());
  std::vector<CanErrorKind> kinds;
  ASSERT_TRUE(WaitFor([&] {
    CanErrorEvent e;
    while (bus_->TakeErrorEvent(&e)) kinds.push_back(e.kind);
    return kinds.size() >= 4;
  }));
  EXPECT_THAT(kinds, ::testing::UnorderedElementsAre(
                         CanErrorKind::kErrorWarning, CanErrorKind::kErrorPassive,
                         CanErrorKind::kProtocol, CanErrorKind::kRxOverflow));
  EXPECT_EQ(bus_->state(), CanBusState::kErrorPassive);
  EXPECT_EQ(bus_->counters().rx_overflows, 1u);
  EXPECT_EQ(bus_->counters().tx_errors, 0u);

  ASSERT_FALSE(bus_->RequestStatus());  // the flags were cleared by the first F
  EXPECT_TRUE(WaitFor([&] { return bus_->state() == CanBusState::kErrorActive; }));
}

TEST_F(SlcanBusTest, PollsTheStatusWhenAsked) {
  sim_->SetStatusFlags(kSlcanErrorWarning);
  SlcanBusOptions options;
  options.status_poll_interval = 20ms;
  OpenBus(",bitrate=500000", options);
  EXPECT_TRUE(WaitForEvent(CanErrorKind::kErrorWarning));
}

TEST_F(SlcanBusTest, RefusedStatusRequestIsNotATransmitError) {
  OpenBus();
  sim_->RefuseCommands("F");
  ASSERT_FALSE(bus_->Send(CanFrame::Standard(0x1)));
  ASSERT_FALSE(bus_->RequestStatus());
  ASSERT_FALSE(bus_->Send(CanFrame::Standard(0x2)));
  CanErrorEvent event;
  ASSERT_TRUE(WaitForEvent(CanErrorKind::kAdapter, &event));
  EXPECT_THAT(event.detail, HasSubstr("refused the status request"));
  CanFrame got;
  ASSERT_FALSE(peer_->Receive(&got, kReceiveTimeout));
  ASSERT_FALSE(peer_->Receive(&got, kReceiveTimeout));
  EXPECT_EQ(got, CanFrame::Standard(0x2));
  EXPECT_EQ(bus_->counters().tx_errors, 0u);
}

TEST_F(SlcanBusTest, FullReceiveQueueCountsLostFramesAndRaisesOneEvent) {
  SlcanBusOptions options;
  options.rx_queue_capacity = 4;
  OpenBus(",bitrate=500000", options);
  for (uint32_t id = 0; id < 10; ++id) ASSERT_FALSE(peer_->Send(CanFrame::Standard(id)));
  ASSERT_TRUE(WaitFor([&] { return bus_->counters().rx_overflows == 6; }));
  CanFrame got;
  for (uint32_t id = 0; id < 4; ++id) {
    ASSERT_FALSE(bus_->Receive(&got, kReceiveTimeout));
    EXPECT_EQ(got.id, id);
  }
  EXPECT_EQ(bus_->Receive(&got, 0us), Errc::kTimeout);
  int overflow_events = 0;
  CanErrorEvent e;
  while (bus_->TakeErrorEvent(&e)) overflow_events += e.kind == CanErrorKind::kRxOverflow;
  EXPECT_EQ(overflow_events, 1);
}

TEST_F(SlcanBusTest, DeadLinkMakesReceiveAndSendReturnClosed) {
  OpenBus();
  sim_.reset();
  pty_.reset();  // the adapter is unplugged: the master side of the pty closes
  CanFrame got;
  EXPECT_EQ(bus_->Receive(&got, kReceiveTimeout), Errc::kClosed);
  EXPECT_EQ(bus_->Receive(&got, 0us), Errc::kClosed);
  CanErrorEvent event;
  ASSERT_TRUE(WaitForEvent(CanErrorKind::kAdapter, &event));
  EXPECT_THAT(event.detail, HasSubstr("serial link lost"));
  EXPECT_EQ(bus_->Send(CanFrame::Standard(0x1)), Errc::kClosed);
  EXPECT_EQ(bus_->RequestStatus(), Errc::kClosed);
  bus_.reset();  // and the destructor does not hang
}

}  // namespace
}  // namespace kinevis::hal
