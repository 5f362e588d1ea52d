// The kinevis program as a user runs it: exit codes, messages, and CAN commands against a
// simulated USB-CAN adapter on a pseudo-terminal (the real slcan driver over the real transport).

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <fstream>
#include <thread>

#include "hal/can/virtual_can_bus.h"
#include "hal/mock/slcan_adapter_sim.h"
#include "hal/serial/pty_pair.h"
#include "tests/utilities/subprocess.h"

namespace kinevis {
namespace {

using testing::RunKinevis;

using namespace std::chrono_literals;
using testing::BackgroundProcess;
using ::testing::ContainsRegex;
using ::testing::HasSubstr;
using testing::KinevisCliPath;
using testing::ProcessResult;

TEST(CliTest, HelpListsTheCommandsAndExitsZero) {
  ProcessResult r = RunKinevis({"--help"});
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_THAT(r.out, HasSubstr("demo"));
  EXPECT_THAT(r.out, HasSubstr("ports"));
  EXPECT_THAT(r.out, HasSubstr("can"));
  EXPECT_THAT(r.out, HasSubstr("Exit codes"));
  ProcessResult sub = RunKinevis({"can", "dump", "--help"});
  EXPECT_EQ(sub.exit_code, 0);
  EXPECT_THAT(sub.out, HasSubstr("--count"));
}

TEST(CliTest, UsageErrorsExitTwo) {
  EXPECT_EQ(RunKinevis({}).exit_code, 2);
  EXPECT_EQ(RunKinevis({"no-such-command"}).exit_code, 2);
  EXPECT_EQ(RunKinevis({"--log-level", "loud", "ports"}).exit_code, 2);
  EXPECT_EQ(RunKinevis({"can", "dump"}).exit_code, 2);  // missing backend
}

TEST(CliTest, MalformedBackendNamesTheFieldAndExitsTwo) {
  ProcessResult r = RunKinevis({"can", "dump", "slcan:/dev/ttyACM0,bitrate=333"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, ContainsRegex("kinevis can dump: backend \"slcan:/dev/ttyACM0,bitrate=333\": "
                                   "bitrate \"333\""));
  ProcessResult s = RunKinevis({"can", "send", "virtual:x", "12#00"});
  EXPECT_EQ(s.exit_code, 2);
  EXPECT_THAT(s.err, HasSubstr("frame id \"12\""));
}

TEST(CliTest, AbsentDeviceIsAHardwareErrorWithinTheTimeout) {
  ProcessResult r = RunKinevis({"can", "dump", "slcan:/dev/kinevis-no-such-adapter"});
  EXPECT_FALSE(r.timed_out);
  EXPECT_EQ(r.exit_code, 3);
  EXPECT_THAT(r.err, ContainsRegex("/dev/kinevis-no-such-adapter.*No such file or directory"));
}

TEST(CliTest, SocketCanWithoutKernelSupportOrInterfaceIsAHardwareError) {
  // On a kernel without PF_CAN the message says so; with PF_CAN, the interface does not exist.
  ProcessResult r = RunKinevis({"can", "dump", "socketcan:kvnope0", "--duration", "0.1"});
  EXPECT_EQ(r.exit_code, 3);
  EXPECT_THAT(r.err, ContainsRegex("socketcan:kvnope0.*(PF_CAN|no such interface|No such device)"));
}

TEST(CliTest, DumpOnAQuietVirtualBusEndsAfterItsDuration) {
  ProcessResult r = RunKinevis({"can", "dump", "virtual:x", "--duration", "0.2"});
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_EQ(r.out, "");
  EXPECT_THAT(r.err, HasSubstr("0 frames received"));
}

TEST(CliTest, SendOnVirtualBusSucceeds) {
  ProcessResult r =
      RunKinevis({"can", "send", "virtual:x", "123#DEADBEEF", "701#R", "--repeat", "3"});
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.err, HasSubstr("sent 6 frames"));
}

TEST(CliTest, PortsListsOrSaysNone) {
  ProcessResult r = RunKinevis({"ports"});
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, ContainsRegex("PATH|no serial ports found"));
  ProcessResult j = RunKinevis({"ports", "--json"});
  EXPECT_EQ(j.exit_code, 0);
  EXPECT_THAT(j.out, ContainsRegex("^\\["));
}

// A simulated USB-CAN adapter on a pty, bridged to a virtual bus inside the test process.
class SlcanCliTest : public ::testing::Test {
 protected:
  SlcanCliTest()
      : net_(std::make_shared<hal::VirtualCanNetwork>("cli", hal::VirtualCanNetwork::Options{})),
        adapter_side_(net_->Connect("adapter")),
        node_(net_->Connect("node")),
        adapter_(pty_.MasterPort(), adapter_side_.get(), {}) {
    adapter_.Start();
  }
  std::string Backend() const { return "slcan:" + pty_.slave_path() + "@115200,bitrate=500000"; }

  hal::PtyPair pty_;
  std::shared_ptr<hal::VirtualCanNetwork> net_;
  std::unique_ptr<hal::VirtualCanBus> adapter_side_, node_;
  hal::SlcanAdapterSim adapter_;
};

TEST_F(SlcanCliTest, SendReachesTheBus) {
  ProcessResult r = RunKinevis({"can", "send", Backend(), "123#DEADBEEF", "12345678#01"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  hal::CanFrame f;
  ASSERT_FALSE(node_->Receive(&f, 5s));
  EXPECT_EQ(f, hal::CanFrame::Standard(0x123, {0xDE, 0xAD, 0xBE, 0xEF}));
  ASSERT_FALSE(node_->Receive(&f, 5s));
  EXPECT_EQ(f, hal::CanFrame::Extended(0x12345678, {0x01}));
  EXPECT_EQ(adapter_.bitrate_code(), 6);
}

TEST_F(SlcanCliTest, DumpPrintsBusFramesInCandumpFormatAndLogsThem) {
  const std::string log = ::testing::TempDir() + "/kinevis_cli_dump.log";
  BackgroundProcess dump({KinevisCliPath(), "can", "dump", Backend(), "--count", "3", "--filter",
                          "100:700", "--log", log});
  // Wait until the adapter channel is open, then send: two frames pass the filter 0x100..0x1FF.
  for (int i = 0; i < 500 && adapter_.state() != hal::SlcanAdapterSim::State::kOpen; ++i) {
    std::this_thread::sleep_for(10ms);
  }
  ASSERT_EQ(adapter_.state(), hal::SlcanAdapterSim::State::kOpen);
  node_->Send(hal::CanFrame::Standard(0x181, {1, 2}));
  node_->Send(hal::CanFrame::Standard(0x281, {9}));  // filtered out
  node_->Send(hal::CanFrame::Standard(0x1FF, {}));
  node_->Send(hal::CanFrame::Extended(0x100, {0xAA}));  // extended: the filter is standard-only
  node_->Send(hal::CanFrame::Standard(0x100, {3}));
  std::vector<std::string> lines(3);
  for (auto& line : lines) ASSERT_TRUE(dump.ReadLine(&line, 10s));
  EXPECT_THAT(lines[0], ContainsRegex("^\\([0-9]+\\.[0-9]{6}\\) [^ ]+ 181#0102$"));
  EXPECT_THAT(lines[1], ContainsRegex(" 1FF#$"));
  EXPECT_THAT(lines[2], ContainsRegex(" 100#03$"));
  EXPECT_EQ(dump.Stop(SIGTERM, 10s), 0);
  std::ifstream in(log);
  std::string first;
  ASSERT_TRUE(std::getline(in, first));
  EXPECT_EQ(first, lines[0]);
}

TEST_F(SlcanCliTest, ReplaySendsTheFramesOfALog) {
  const std::string log = ::testing::TempDir() + "/kinevis_cli_replay.log";
  {
    std::ofstream out(log);
    out << "# recorded on the bench\n"
        << "(1700000000.000000) can0 080#\n"
        << "(1700000000.001000) can0 181#0011223344556677\n"
        << "(1700000000.002000) can0 20000004#0004000000000000\n"  // error frame: skipped
        << "(1700000000.003000) can0 701#R\n";
  }
  ProcessResult r = RunKinevis({"can", "replay", Backend(), log, "--realtime"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.err, HasSubstr("replayed 3 frames"));
  std::vector<std::string> got;
  hal::CanFrame f;
  while (!node_->Receive(&f, 2s)) got.push_back(hal::FormatCanFrame(f));
  EXPECT_EQ(got, (std::vector<std::string>{"080#", "181#0011223344556677", "701#R"}));
}

// The host timing check: whatever this machine holds, it measures, says so and exits 0 (steady)
// or 1 (not); a request the machine cannot take is a usage error naming it.
TEST(CliTest, CheckTimingMeasuresTheHostAndGivesAVerdict) {
  const ProcessResult r = RunKinevis({"check", "timing", "--rate", "500", "--seconds", "0.2"});
  EXPECT_TRUE(r.exit_code == 0 || r.exit_code == 1) << r.out << r.err;
  EXPECT_THAT(r.out, HasSubstr("timer slack 1 ns: set"));
  EXPECT_THAT(r.out, HasSubstr("periods: "));
  EXPECT_THAT(r.out, HasSubstr("wake-ups: lateness p50 "));
  EXPECT_THAT(r.out, HasSubstr(r.exit_code == 0 ? "steady: this host holds 500.0 Hz"
                                                : "NOT steady at 500.0 Hz"));
  const ProcessResult bad = RunKinevis({"check", "timing", "--seconds", "0.1", "--rt-cpu", "1000"});
  EXPECT_EQ(bad.exit_code, 2) << bad.out << bad.err;
  EXPECT_THAT(bad.err, HasSubstr("cpu = 1000"));
}

TEST(CliTest, ReplayOfABadLogNamesFileAndLine) {
  const std::string log = ::testing::TempDir() + "/kinevis_cli_bad.log";
  {
    std::ofstream out(log);
    out << "(1700000000.000000) can0 080#\n"
        << "garbage here\n";
  }
  ProcessResult r = RunKinevis({"can", "replay", "virtual:x", log});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr(log + ":2:"));
}

TEST(CliTest, DemoPassesEveryCheck) {
  // The hexapod part records 60 poses and servoes (about 25 s on a quiet machine), the weld chain
  // about 45 s, the DIAMOND part about 25 s.
  const std::string out = ::testing::TempDir() + "/kinevis-demo-" + std::to_string(::getpid());
  ProcessResult r = RunKinevis({"demo", "--out", out}, std::chrono::seconds(280));
  EXPECT_EQ(r.exit_code, 0) << r.out << r.err;
  EXPECT_THAT(r.out, ContainsRegex("demo: [0-9]+ checks passed, 0 failed"));
  EXPECT_THAT(r.out, HasSubstr("servo from the leg edges: converged"));
  EXPECT_THAT(r.out, HasSubstr("executed stand-off against the true blade"));
  EXPECT_THAT(r.out, HasSubstr("straightness a priori -> identified"));
  EXPECT_THAT(r.out, ::testing::Not(HasSubstr("FAIL")));
}

}  // namespace
}  // namespace kinevis

namespace kinevis {
namespace {

// Two processes, as an engineer runs them at bring-up: the CANopen drive simulator behind its
// simulated slcan adapter, and `kinevis drive` reaching it through the pty the simulator printed.
TEST(DriveCliTest, MovesSimulatedCanopenDrivesInAnotherProcess) {
  testing::BackgroundProcess sim({testing::KinevisCliPath(), "sim", "drive", "--nodes", "1,2"});
  std::string backend;
  ASSERT_TRUE(sim.ReadLine(&backend, 20s));
  ASSERT_THAT(backend, ::testing::StartsWith("slcan:/dev/pts/"));
  testing::ProcessResult status = RunKinevis({"drive", backend, "--nodes", "1,2", "status"});
  ASSERT_EQ(status.exit_code, 0) << status.err;
  EXPECT_THAT(status.out, ContainsRegex("node 1.*Switch on disabled"));
  testing::ProcessResult move =
      RunKinevis({"drive", backend, "--nodes", "1,2", "--counts-per-rad", "10000", "move",
                  "--position", "0.5", "--duration", "0.5"});
  EXPECT_EQ(move.exit_code, 0) << move.out << move.err;
  EXPECT_THAT(move.out, ContainsRegex("position 0\\.5"));
  // A node that is not on the bus: a hardware error naming it, within the SDO timeout.
  testing::ProcessResult absent = RunKinevis({"drive", backend, "--nodes", "9", "status"});
  EXPECT_FALSE(absent.timed_out);
  EXPECT_EQ(absent.exit_code, 3);
  EXPECT_THAT(absent.err, HasSubstr("node 9"));
  EXPECT_EQ(sim.Stop(SIGTERM, 10s), 0);
}

}  // namespace
}  // namespace kinevis
