// A third-party Modbus client, mbpoll (Debian package "mbpoll"), reads the simulated weld robot's
// registers over loopback Modbus TCP: proves that the register map of docs/weld-robot-modbus.md
// (32-bit values high word first, fixed units) reads the same with another implementation.

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "common/clock.h"
#include "hal/mock/weld_robot_sim.h"
#include "hal/modbus/modbus_client.h"
#include "hal/weld/weld_robot_registers.h"
#include "tests/utilities/subprocess.h"

namespace kinevis::hal {
namespace {

namespace wr = weld_robot;
using kinevis::testing::HaveProgram;
using kinevis::testing::ProcessResult;
using kinevis::testing::RunProcess;

// mbpoll prints one value a line, "[REFERENCE]: \tVALUE" (16-bit registers above 32767 with the
// signed reading appended, "65535 (-1)"); returns reference -> value. sscanf, as in mbpoll_test.cc.
std::map<int, long> ParseValues(const std::string& out) {
  std::map<int, long> values;
  std::istringstream lines(out);
  std::string line;
  while (std::getline(lines, line)) {
    int reference = 0;
    long value = 0;
    if (std::sscanf(line.c_str(), "[%d]: %ld", &reference, &value) == 2) {
      values[reference] = value;
    }
  }
  return values;
}

class WeldRobotMbpollTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!HaveProgram("mbpoll")) GTEST_SKIP() << "mbpoll is not on PATH (apt install mbpoll)";
    WeldRobotSim::Options o;
    o.run_executor = false;  // stepped here: the values mbpoll reads are known exactly
    o.clock = &clock_;
    o.buffer_capacity = 12;
    o.serial_number = 123456789;
    sim_ = WeldRobotSim::ListenTcp("127.0.0.1", 0, o);
  }

  // mbpoll over Modbus TCP, unit 1, PDU addressing, one poll, its own 5 s timeout; `values`
  // (after the host) makes it a write.
  ProcessResult Mbpoll(std::vector<std::string> args, std::vector<std::string> values = {}) {
    std::vector<std::string> argv = {
        "mbpoll", "-m", "tcp", "-p", std::to_string(sim_->server().port()), "-a", "1",
        "-0",     "-1", "-o",  "5"};
    argv.insert(argv.end(), args.begin(), args.end());
    argv.push_back("127.0.0.1");
    argv.insert(argv.end(), values.begin(), values.end());
    return RunProcess(argv, std::chrono::seconds(30));
  }

  common::SimulatedClock clock_;
  std::unique_ptr<WeldRobotSim> sim_;
};

TEST_F(WeldRobotMbpollTest, ReadsTheIdentityRegisters) {
  ProcessResult r = Mbpoll({"-t", "3", "-r", "0", "-c", "8"});
  ASSERT_FALSE(r.timed_out);
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  const std::map<int, long> v = ParseValues(r.out);
  EXPECT_EQ(v.at(wr::kRegMagic), 0x4B57) << r.out;
  EXPECT_EQ(v.at(wr::kRegMapVersion), 1);
  EXPECT_EQ(v.at(wr::kRegJointCount), 5);
  EXPECT_EQ(v.at(wr::kRegBufferCapacity), 12);
  EXPECT_EQ(v.at(wr::kRegMaxSegmentDurationMs), 60000);
  EXPECT_EQ(v.at(wr::kRegMaxCurrent), 4000);
}

TEST_F(WeldRobotMbpollTest, ReadsThirtyTwoBitValuesHighWordFirst) {
  // mbpoll's -B: big-endian word order, the map's order. Serial number and θ1's limits.
  ProcessResult serial = Mbpoll({"-t", "3:int", "-B", "-r", "8", "-c", "1"});
  ASSERT_EQ(serial.exit_code, 0) << serial.out << serial.err;
  EXPECT_EQ(ParseValues(serial.out).at(8), 123456789L) << serial.out;
  ProcessResult limits = Mbpoll({"-t", "3:int", "-B", "-r", "10", "-c", "3"});
  ASSERT_EQ(limits.exit_code, 0) << limits.out << limits.err;
  const std::map<int, long> v = ParseValues(limits.out);
  EXPECT_EQ(v.at(10), -2967060L) << limits.out;  // -170° in µrad
  EXPECT_EQ(v.at(12), 2967060L);
  EXPECT_EQ(v.at(14), 1570796L);  // 90°/s in µrad/s
}

TEST_F(WeldRobotMbpollTest, ReadsTheActualJointsWhileTheRobotMoves) {
  auto client = ModbusClient::Open(sim_->backend() + ",timeout_ms=3000,retries=0");
  uint16_t segment[wr::kSegmentRegisters] = {};
  wr::PutU32(segment + wr::kSegmentSequenceOffset, 1);
  const int32_t target[wr::kJointCount] = {400000, -200000, 80000, 100000, -300000};
  for (int j = 0; j < wr::kJointCount; ++j) {
    wr::PutI32(segment + wr::kSegmentJointsOffset + 2 * j, target[j]);
  }
  segment[wr::kSegmentDurationOffset] = 1000;
  ASSERT_EQ(client->WriteRegisters(wr::kSegmentAddress, wr::kSegmentRegisters, segment),
            std::error_code());
  clock_.Advance(std::chrono::milliseconds(250));
  sim_->Update();  // a quarter of the way from (0, 0, 50 mm, 0, 0)

  ProcessResult joints = Mbpoll({"-t", "3:int", "-B", "-r", "112", "-c", "5"});
  ASSERT_EQ(joints.exit_code, 0) << joints.out << joints.err;
  EXPECT_THAT(ParseValues(joints.out),
              ::testing::ElementsAre(std::make_pair(112, 100000L), std::make_pair(114, -50000L),
                                     std::make_pair(116, 57500L), std::make_pair(118, 25000L),
                                     std::make_pair(120, -75000L)))
      << joints.out;
  ProcessResult status = Mbpoll({"-t", "3", "-r", "100", "-c", "4"});
  ASSERT_EQ(status.exit_code, 0) << status.out << status.err;
  const std::map<int, long> s = ParseValues(status.out);
  EXPECT_EQ(s.at(wr::kRegMotionState), static_cast<long>(wr::MotionState::kMoving));
  EXPECT_EQ(s.at(wr::kRegAlarmCode), 0);
  EXPECT_EQ(s.at(wr::kRegBufferLevel), 1);
  EXPECT_EQ(s.at(wr::kRegBufferFree), 11);
}

TEST_F(WeldRobotMbpollTest, CommandWrittenByMbpollStopsTheRobot) {
  auto client = ModbusClient::Open(sim_->backend() + ",timeout_ms=3000,retries=0");
  uint16_t segment[wr::kSegmentRegisters] = {};
  wr::PutU32(segment, 1);
  wr::PutI32(segment + wr::kSegmentJointsOffset + 4, 50000);  // pz3 stays at 50 mm
  wr::PutI32(segment + wr::kSegmentJointsOffset, 100000);
  segment[wr::kSegmentDurationOffset] = 1000;
  ASSERT_EQ(client->WriteRegisters(wr::kSegmentAddress, wr::kSegmentRegisters, segment),
            std::error_code());
  ASSERT_EQ(sim_->state().motion, wr::MotionState::kMoving);
  // Holding register 200 := 1 (STOP), written by mbpoll.
  ProcessResult r = Mbpoll({"-t", "4", "-r", "200"}, {"1"});
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  EXPECT_EQ(sim_->state().motion, wr::MotionState::kIdle);
  EXPECT_EQ(sim_->state().buffer_level, 0);
  // An unknown command is refused with ILLEGAL DATA VALUE, which mbpoll reports.
  ProcessResult bad = Mbpoll({"-t", "4", "-r", "200"}, {"99"});
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_THAT(bad.out + bad.err, ::testing::ContainsRegex("[Ii]llegal data value"));
}

}  // namespace
}  // namespace kinevis::hal
