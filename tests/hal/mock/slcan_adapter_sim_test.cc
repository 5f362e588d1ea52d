#include "hal/mock/slcan_adapter_sim.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "hal/can/slcan_codec.h"
#include "hal/can/virtual_can_bus.h"
#include "hal/common/error.h"
#include "hal/serial/pty_pair.h"
#include "hal/serial/termios_serial_port.h"

namespace kinevis::hal {
namespace {

using namespace std::chrono_literals;
using State = SlcanAdapterSim::State;

// Generous bound for an answer on a loaded machine; a correct simulator answers in microseconds.
constexpr auto kAnswerDeadline = 5s;

// Polls `condition` until it holds or a generous deadline passes; returns whether it held.
template <typename Condition>
bool WaitFor(Condition condition, std::chrono::milliseconds deadline = kAnswerDeadline) {
  const auto end = std::chrono::steady_clock::now() + deadline;
  while (!condition()) {
    if (std::chrono::steady_clock::now() > end) return false;
    std::this_thread::sleep_for(1ms);
  }
  return true;
}

std::string TestName() { return ::testing::UnitTest::GetInstance()->current_test_info()->name(); }

// The host side: raw bytes written to and read from the pty slave, as a terminal program would.
class SlcanAdapterSimTest : public ::testing::Test {
 protected:
  void SetUp() override {
    network_ = VirtualCanNetwork::Get("slcan-sim-test-" + TestName(), {});
    adapter_node_ = network_->Connect("adapter");
    peer_ = network_->Connect("peer");
    StartSim(SlcanAdapterSim::Options{});
    SerialSettings settings;
    settings.device = pty_.slave_path();
    host_ = OpenSerialPort(settings);
  }

  void StartSim(SlcanAdapterSim::Options options) {
    sim_.reset();
    sim_ = std::make_unique<SlcanAdapterSim>(pty_.MasterPort(), adapter_node_.get(),
                                             std::move(options));
    sim_->Start();
  }

  void Write(const std::string& bytes) {
    ASSERT_FALSE(host_->WriteAll(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size(),
                                 std::chrono::microseconds(1s)));
  }

  // Reads until `terminators` '\r' or '\a' bytes have come, or the deadline.
  std::string ReadAnswer(int terminators = 1,
                         std::chrono::milliseconds deadline = kAnswerDeadline) {
    std::string out;
    const auto end = std::chrono::steady_clock::now() + deadline;
    int seen = 0;
    while (seen < terminators) {
      auto left = std::chrono::duration_cast<std::chrono::microseconds>(
          end - std::chrono::steady_clock::now());
      if (left <= 0us) break;
      uint8_t b;
      size_t n = 0;
      // One byte at a time, so that nothing after the last terminator is consumed.
      if (host_->Read(&b, 1, left, &n)) break;
      out += static_cast<char>(b);
      if (b == '\r' || b == '\a') ++seen;
    }
    return out;
  }

  std::string Exchange(const std::string& command, int terminators = 1) {
    Write(command);
    return ReadAnswer(terminators);
  }

  PtyPair pty_;
  std::shared_ptr<VirtualCanNetwork> network_;
  std::unique_ptr<VirtualCanBus> adapter_node_;
  std::unique_ptr<VirtualCanBus> peer_;
  std::unique_ptr<SlcanAdapterSim> sim_;
  std::unique_ptr<SerialPort> host_;
};

TEST_F(SlcanAdapterSimTest, AnswersVersionAndSerialNumberInEveryState) {
  EXPECT_EQ(Exchange("V\r"), "V1013\r");
  EXPECT_EQ(Exchange("N\r"), "NKV01\r");
  EXPECT_EQ(Exchange("O\r"), "\r");
  EXPECT_EQ(Exchange("V\r"), "V1013\r");
  EXPECT_EQ(Exchange("N\r"), "NKV01\r");
}

TEST_F(SlcanAdapterSimTest, AnswersWithTheConfiguredVersionAndSerialNumber) {
  StartSim(SlcanAdapterSim::Options{"2A05", "X123"});
  EXPECT_EQ(Exchange("V\r"), "V2A05\r");
  EXPECT_EQ(Exchange("N\r"), "NX123\r");
}

TEST_F(SlcanAdapterSimTest, RejectsAVersionThatIsNotFourCharacters) {
  EXPECT_THROW(SlcanAdapterSim(pty_.MasterPort(), adapter_node_.get(),
                               SlcanAdapterSim::Options{"12345", "KV01"}),
               common::ConfigError);
  EXPECT_THROW(SlcanAdapterSim(pty_.MasterPort(), adapter_node_.get(),
                               SlcanAdapterSim::Options{"1013", "A B1"}),
               common::ConfigError);
}

// The Lawicel state rules, one row per command and state.
TEST_F(SlcanAdapterSimTest, FollowsTheLawicelStateRules) {
  struct Row {
    const char* command;
    const char* answer;
    State state_after;
  };
  const Row rows[] = {
      // closed
      {"t1230\r", "\a", State::kClosed},  // a frame before O
      {"F\r", "\a", State::kClosed},
      {"C\r", "\a", State::kClosed},
      {"S6\r", "\r", State::kClosed},
      {"Z1\r", "\r", State::kClosed},
      {"Z0\r", "\r", State::kClosed},
      {"O\r", "\r", State::kOpen},
      // open
      {"O\r", "\a", State::kOpen},
      {"L\r", "\a", State::kOpen},
      {"S4\r", "\a", State::kOpen},  // S while open
      {"Z1\r", "\a", State::kOpen},
      {"F\r", "F00\r", State::kOpen},
      {"t1230\r", "z\r", State::kOpen},
      {"T000001230\r", "Z\r", State::kOpen},
      {"r1234\r", "z\r", State::kOpen},
      {"R1FFFFFFF8\r", "Z\r", State::kOpen},
      {"C\r", "\r", State::kClosed},
      // listen-only
      {"L\r", "\r", State::kListenOnly},
      {"t1230\r", "\a", State::kListenOnly},
      {"S6\r", "\a", State::kListenOnly},
      {"F\r", "F00\r", State::kListenOnly},
      {"C\r", "\r", State::kClosed},
      // malformed or unknown, in any state
      {"X\r", "\a", State::kClosed},
      {"S9\r", "\a", State::kClosed},
      {"\r", "\a", State::kClosed},
      {"O\r", "\r", State::kOpen},
      {"t12\r", "\a", State::kOpen},
      {"t8000\r", "\a", State::kOpen},
      {"t1232AAB\r", "\a", State::kOpen},
      {"C\r", "\r", State::kClosed},
  };
  for (const Row& row : rows) {
    SCOPED_TRACE(::testing::PrintToString(std::string(row.command)));
    EXPECT_EQ(Exchange(row.command), row.answer);
    EXPECT_EQ(sim_->state(), row.state_after);
  }
  EXPECT_EQ(sim_->bitrate_code(), 6);
  EXPECT_FALSE(sim_->timestamps());
  const auto stats = sim_->statistics();
  EXPECT_EQ(stats.commands, std::size(rows));
  size_t refused_rows = 0;
  for (const Row& row : rows) refused_rows += std::string(row.answer) == "\a" ? 1 : 0;
  EXPECT_EQ(refused_rows, 15u);
  EXPECT_EQ(stats.refused, refused_rows);
  EXPECT_EQ(stats.frames_to_bus, 4u);
}

TEST_F(SlcanAdapterSimTest, OverlongLineIsRefusedOnce) {
  EXPECT_EQ(Exchange(std::string(500, 'O') + "\r"), "\a");
  EXPECT_EQ(sim_->state(), State::kClosed);
  EXPECT_EQ(Exchange("V\r"), "V1013\r");  // and the next line is served normally
}

TEST_F(SlcanAdapterSimTest, SendsHostFramesOntoTheBus) {
  ASSERT_EQ(Exchange("O\r"), "\r");
  ASSERT_EQ(Exchange("t1232AABB\r"), "z\r");
  ASSERT_EQ(Exchange("T1234567821122\r"), "Z\r");
  CanFrame f;
  ASSERT_FALSE(peer_->Receive(&f, std::chrono::microseconds(kAnswerDeadline)));
  EXPECT_EQ(f, CanFrame::Standard(0x123, {0xAA, 0xBB}));
  ASSERT_FALSE(peer_->Receive(&f, std::chrono::microseconds(kAnswerDeadline)));
  EXPECT_EQ(f, CanFrame::Extended(0x12345678, {0x11, 0x22}));
}

TEST_F(SlcanAdapterSimTest, ForwardsBusFramesOnlyWhileOpen) {
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x321, {1})));  // closed: not forwarded
  ASSERT_TRUE(WaitFor([&] { return adapter_node_->counters().rx_frames == 1; }));
  EXPECT_EQ(ReadAnswer(1, 300ms), "");
  ASSERT_EQ(Exchange("O\r"), "\r");
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x123, {0xAA, 0xBB})));
  EXPECT_EQ(ReadAnswer(), "t1232AABB\r");
  ASSERT_FALSE(peer_->Send(CanFrame::Extended(0x12345678, {0x11, 0x22})));
  EXPECT_EQ(ReadAnswer(), "T1234567821122\r");
  CanFrame remote = CanFrame::Standard(0x7FF);
  remote.rtr = true;
  remote.dlc = 2;
  ASSERT_FALSE(peer_->Send(remote));
  EXPECT_EQ(ReadAnswer(), "r7FF2\r");
  ASSERT_EQ(Exchange("C\r"), "\r");
  ASSERT_EQ(Exchange("L\r"), "\r");  // listen-only receives too
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x001)));
  EXPECT_EQ(ReadAnswer(), "t0010\r");
  EXPECT_EQ(sim_->statistics().frames_to_host, 4u);
}

TEST_F(SlcanAdapterSimTest, AppendsTimestampsAfterZ1) {
  ASSERT_EQ(Exchange("Z1\r"), "\r");
  ASSERT_EQ(Exchange("O\r"), "\r");
  EXPECT_TRUE(sim_->timestamps());
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x123, {0xAA, 0xBB})));
  const std::string line = ReadAnswer();
  ASSERT_EQ(line.size(), 14u) << line;
  EXPECT_EQ(line.substr(0, 9), "t1232AABB");
  SlcanDecoder decoder;
  std::vector<SlcanEvent> events;
  decoder.Feed(line, [&](const SlcanEvent& e) { events.push_back(e); });
  ASSERT_EQ(events.size(), 1u);
  EXPECT_EQ(events[0].kind, SlcanEvent::Kind::kFrame);
  EXPECT_TRUE(events[0].has_timestamp);
  EXPECT_LE(events[0].timestamp_ms, kSlcanMaxTimestampMs);
}

TEST_F(SlcanAdapterSimTest, RefusesAFrameTheBusRefuses) {
  adapter_node_->InjectBusOff();
  ASSERT_EQ(Exchange("O\r"), "\r");
  EXPECT_EQ(Exchange("t1230\r"), "\a");
  EXPECT_EQ(sim_->statistics().frames_to_bus, 0u);
}

TEST_F(SlcanAdapterSimTest, ReportsAndClearsInjectedStatusFlags) {
  ASSERT_EQ(Exchange("O\r"), "\r");
  sim_->SetStatusFlags(kSlcanErrorWarning | kSlcanErrorPassive);
  EXPECT_EQ(Exchange("F\r"), "F24\r");
  EXPECT_EQ(Exchange("F\r"), "F00\r");
  sim_->SetStatusFlags(kSlcanBusError);
  sim_->SetStatusFlags(kSlcanDataOverrun);
  EXPECT_EQ(Exchange("F\r"), "F88\r");
}

TEST_F(SlcanAdapterSimTest, DropsTheNextBytesToTheHost) {
  sim_->DropBytesToHost(2);
  EXPECT_EQ(Exchange("V\r"), "013\r");
  EXPECT_EQ(Exchange("V\r"), "V1013\r");
  sim_->DropBytesToHost(6);  // the whole answer, across two answers
  Write("V\r");
  Write("N\r");
  EXPECT_EQ(ReadAnswer(), "NKV01\r");
  EXPECT_EQ(sim_->statistics().bytes_dropped, 8u);
}

TEST_F(SlcanAdapterSimTest, InjectsGarbage) {
  sim_->InjectGarbage("\x01garbage\r");
  EXPECT_EQ(ReadAnswer(), "\x01garbage\r");
  EXPECT_EQ(Exchange("V\r"), "V1013\r");
}

TEST_F(SlcanAdapterSimTest, SilentAdapterAnswersNothingUntilItTalksAgain) {
  sim_->SetSilent(true);
  Write("V\r");
  Write("O\r");
  ASSERT_TRUE(WaitFor([&] { return sim_->statistics().commands == 2; }));
  EXPECT_EQ(ReadAnswer(1, 300ms), "");
  EXPECT_EQ(sim_->state(), State::kClosed);  // commands are ignored, not executed
  sim_->SetSilent(false);
  EXPECT_EQ(Exchange("V\r"), "V1013\r");
}

TEST_F(SlcanAdapterSimTest, RefusesChosenCommandsInAnyState) {
  sim_->RefuseCommands("S");
  EXPECT_EQ(Exchange("S6\r"), "\a");
  EXPECT_EQ(sim_->bitrate_code(), -1);
  EXPECT_EQ(Exchange("O\r"), "\r");
  sim_->RefuseCommands("tT");
  EXPECT_EQ(Exchange("t1230\r"), "\a");
  EXPECT_EQ(Exchange("T000000010\r"), "\a");
  sim_->RefuseCommands("");
  EXPECT_EQ(Exchange("t1230\r"), "z\r");
}

TEST_F(SlcanAdapterSimTest, StopsServingAndStartsAgain) {
  sim_->Stop();
  Write("V\r");
  EXPECT_EQ(ReadAnswer(1, 300ms), "");
  sim_->Start();
  // The command written while stopped waits in the line and is answered now.
  EXPECT_EQ(ReadAnswer(), "V1013\r");
}

}  // namespace
}  // namespace kinevis::hal
