#include "hal/dynamixel/dynamixel_bus.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <fstream>
#include <iterator>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "hal/common/error.h"
#include "hal/mock/dynamixel_sim.h"
#include "hal/serial/pty_pair.h"

namespace kinevis::hal {
namespace {

using namespace std::chrono_literals;
using Bytes = std::vector<uint8_t>;
using ::testing::ElementsAre;
using ::testing::HasSubstr;

constexpr double kTick = 2 * M_PI / 4096;

Bytes Le(uint32_t v, int size) {
  Bytes out;
  for (int i = 0; i < size; ++i) out.push_back(static_cast<uint8_t>(v >> (8 * i)));
  return out;
}

uint32_t FromLe(const Bytes& b) {
  uint32_t v = 0;
  for (size_t i = b.size(); i-- > 0;) v = v << 8 | b[i];
  return v;
}

// The driver against DynamixelSim over a real pseudo-terminal, opened by its backend string.
class DynamixelBusTest : public ::testing::Test {
 protected:
  void StartSim(int protocol, const std::vector<uint8_t>& ids, const std::string& model,
                DynamixelBusOptions options = {}) {
    std::vector<DynamixelSim::ServoSpec> servos;
    for (uint8_t id : ids) servos.push_back({id, DxlControlTable::LoadModel(model)});
    StartSimWith(protocol, servos, options);
  }
  void StartSimWith(int protocol, std::vector<DynamixelSim::ServoSpec> servos,
                    DynamixelBusOptions options = {}) {
    bus_.reset();  // releases the port (opened exclusively) before a second start
    sim_.reset();
    DynamixelSim::Options sim_options;
    sim_options.protocol = protocol;
    sim_options.servos = std::move(servos);
    sim_ = std::make_unique<DynamixelSim>(pty_.MasterPort(), sim_options);
    sim_->Start();
    options.protocol = protocol;
    bus_ = DynamixelBus::Open(Backend(), options);
  }
  std::string Backend() const { return "tty:" + pty_.slave_path() + "@1000000"; }

  PtyPair pty_;
  std::unique_ptr<DynamixelSim> sim_;
  std::unique_ptr<DynamixelBus> bus_;
};

// -------------------------------------------------------------------------- instructions, 2.0

TEST_F(DynamixelBusTest, Protocol2PingReportsModelAndFirmware) {
  StartSim(2, {1}, "xm430-w350");
  EXPECT_EQ(bus_->name(), Backend());
  DxlReply reply;
  ASSERT_FALSE(bus_->Ping(1, &reply));
  EXPECT_EQ(reply.id, 1);
  EXPECT_THAT(reply.data, ElementsAre(0xFC, 0x03, 46));
  uint16_t model = 0;
  uint8_t firmware = 0;
  ASSERT_FALSE(bus_->PingModel(1, &model, &firmware));
  EXPECT_EQ(model, 1020);
  EXPECT_EQ(firmware, 46);
  EXPECT_EQ(bus_->counters().requests, 2u);
  EXPECT_EQ(bus_->counters().retries, 0u);
}

TEST_F(DynamixelBusTest, Protocol2ReadAndWrite) {
  StartSim(2, {1}, "xm430-w350");
  ASSERT_FALSE(bus_->Write(1, 112, Le(77, 4)));
  EXPECT_EQ(sim_->Register(1, "profile_velocity"), 77);
  DxlReply reply;
  ASSERT_FALSE(bus_->Read(1, 112, 4, &reply));
  EXPECT_EQ(FromLe(reply.data), 77u);
  ASSERT_FALSE(bus_->Read(1, 132, 4, &reply));
  EXPECT_EQ(FromLe(reply.data), 2048u);
}

TEST_F(DynamixelBusTest, Protocol2RegWriteAndAction) {
  StartSim(2, {1, 2}, "xm430-w350");
  ASSERT_FALSE(bus_->RegWrite(1, 116, Le(1000, 4)));
  ASSERT_FALSE(bus_->RegWrite(2, 116, Le(3000, 4)));
  EXPECT_EQ(sim_->Register(1, "goal_position"), 2048);
  ASSERT_FALSE(bus_->Action());  // broadcast: both at once, no answer
  // The servos handle packets in order: once a ping is answered, the action has been executed.
  ASSERT_FALSE(bus_->Ping(1));
  EXPECT_EQ(sim_->Register(1, "goal_position"), 1000);
  EXPECT_EQ(sim_->Register(2, "goal_position"), 3000);
  ASSERT_FALSE(bus_->RegWrite(2, 65, {1}));
  ASSERT_FALSE(bus_->Action(2));  // one servo, answered
  EXPECT_EQ(sim_->Register(2, "led"), 1);
  // Nothing registered any more: the servo answers with an instruction error.
  EXPECT_EQ(bus_->Action(2), Errc::kDeviceFault);
}

TEST_F(DynamixelBusTest, Protocol2SyncWriteAndSyncReadOfSeveralServos) {
  StartSim(2, {1, 2, 3}, "xm430-w350");
  ASSERT_FALSE(bus_->SyncWrite(112, 4, {{1, Le(10, 4)}, {2, Le(20, 4)}, {3, Le(30, 4)}}));
  sim_->SetRegister(2, "present_position", 1111);
  sim_->SetRegister(3, "present_position", 3333);
  std::vector<DxlReply> replies;
  ASSERT_FALSE(bus_->SyncRead(112, 4, {3, 1, 2}, &replies));
  ASSERT_EQ(replies.size(), 3u);
  EXPECT_EQ(replies[0].id, 3);
  EXPECT_EQ(FromLe(replies[0].data), 30u);
  EXPECT_EQ(FromLe(replies[1].data), 10u);
  EXPECT_EQ(FromLe(replies[2].data), 20u);
  ASSERT_FALSE(bus_->SyncRead(132, 4, {1, 2, 3}, &replies));
  EXPECT_EQ(FromLe(replies[0].data), 2048u);
  EXPECT_EQ(FromLe(replies[1].data), 1111u);
  EXPECT_EQ(FromLe(replies[2].data), 3333u);
}

TEST_F(DynamixelBusTest, Protocol2RebootIsAnswered) {
  StartSim(2, {1}, "xm430-w350");
  ASSERT_FALSE(bus_->Write(1, 65, {1}));
  ASSERT_FALSE(bus_->Reboot(1));
  std::this_thread::sleep_for(100ms);  // the simulator's reboot takes 30 ms
  EXPECT_EQ(sim_->Register(1, "led"), 0);
}

TEST_F(DynamixelBusTest, StatusErrorIsReturnedWithTheErrorFieldAndNotRetried) {
  StartSim(2, {1}, "xm430-w350");
  DxlReply reply;
  EXPECT_EQ(bus_->Write(1, 116, Le(9999, 4), &reply), Errc::kDeviceFault);
  EXPECT_EQ(reply.error, static_cast<uint8_t>(Dxl2ErrorCode::kDataRangeError));
  EXPECT_EQ(bus_->counters().status_errors, 1u);
  EXPECT_EQ(bus_->counters().retries, 0u);
  EXPECT_EQ(bus_->Read(1, 140, 20, &reply), Errc::kDeviceFault);  // beyond the table
  EXPECT_EQ(reply.error, static_cast<uint8_t>(Dxl2ErrorCode::kAccessError));
}

TEST_F(DynamixelBusTest, ArgumentsTheProtocolCannotCarryAreRefusedWithoutIo) {
  StartSim(2, {1}, "xm430-w350");
  DxlReply reply;
  EXPECT_EQ(bus_->Ping(253), Errc::kInvalidArgument);
  EXPECT_EQ(bus_->Ping(kDxlBroadcastId), Errc::kInvalidArgument);
  EXPECT_EQ(bus_->Read(1, 0, 0, &reply), Errc::kInvalidArgument);
  EXPECT_EQ(bus_->Write(1, 0, {}), Errc::kInvalidArgument);
  EXPECT_EQ(bus_->SyncWrite(116, 4, {{1, Le(1, 2)}}), Errc::kInvalidArgument);
  std::vector<DxlReply> replies;
  EXPECT_EQ(bus_->SyncRead(132, 4, {1, 1}, &replies), Errc::kInvalidArgument);
  EXPECT_EQ(bus_->BulkRead({{1, 36, 2}}, &replies), Errc::kUnsupported);
  EXPECT_EQ(bus_->counters().requests, 0u);
}

// -------------------------------------------------------------------------- instructions, 1.0

TEST_F(DynamixelBusTest, Protocol1PingReadsTheModelNumber) {
  StartSim(1, {1}, "mx-12w");
  DxlReply reply;
  ASSERT_FALSE(bus_->Ping(1, &reply));
  EXPECT_TRUE(reply.data.empty());
  uint16_t model = 0;
  uint8_t firmware = 0;
  ASSERT_FALSE(bus_->PingModel(1, &model, &firmware));
  EXPECT_EQ(model, 360);
  EXPECT_EQ(firmware, 41);
}

TEST_F(DynamixelBusTest, Protocol1SyncWriteAndBulkRead) {
  StartSim(1, {1, 2}, "mx-12w");
  ASSERT_FALSE(bus_->SyncWrite(32, 2, {{1, Le(100, 2)}, {2, Le(200, 2)}}));
  sim_->SetRegister(2, "present_position", 0x123);
  std::vector<DxlReply> replies;
  ASSERT_FALSE(bus_->BulkRead({{2, 36, 2}, {1, 32, 4}}, &replies));
  ASSERT_EQ(replies.size(), 2u);
  EXPECT_EQ(replies[0].id, 2);
  EXPECT_EQ(FromLe(replies[0].data), 0x123u);
  EXPECT_EQ(replies[1].id, 1);
  EXPECT_THAT(replies[1].data, ElementsAre(100, 0, 1023 & 0xFF, 1023 >> 8));
  EXPECT_EQ(bus_->SyncRead(36, 2, {1}, &replies), Errc::kUnsupported);
  EXPECT_EQ(bus_->Reboot(1), Errc::kUnsupported);
  EXPECT_EQ(bus_->Read(1, 250, 10, nullptr), Errc::kInvalidArgument);  // beyond 256 bytes
}

TEST_F(DynamixelBusTest, Protocol1RegWriteActionAndStatusErrorBits) {
  StartSim(1, {1}, "mx-12w");
  ASSERT_FALSE(bus_->RegWrite(1, 25, {1}));
  EXPECT_EQ(sim_->Register(1, "led"), 0);
  ASSERT_FALSE(bus_->Action(1));
  EXPECT_EQ(sim_->Register(1, "led"), 1);
  DxlReply reply;
  ASSERT_FALSE(bus_->Write(1, 8, Le(3000, 2)));
  EXPECT_EQ(bus_->Write(1, 30, Le(3500, 2), &reply), Errc::kDeviceFault);
  EXPECT_EQ(reply.error, kDxl1AngleLimitError);
}

// -------------------------------------------------------------------------- faults and retries

TEST_F(DynamixelBusTest, CorruptedAnswerIsRetriedAndCounted) {
  for (int protocol : {1, 2}) {
    SCOPED_TRACE(protocol);
    sim_.reset();
    StartSim(protocol, {1}, protocol == 1 ? "mx-12w" : "xm430-w350");
    sim_->CorruptNextReplies(1);
    DxlReply reply;
    ASSERT_FALSE(bus_->Read(1, protocol == 1 ? 36 : 132, 2, &reply));
    EXPECT_EQ(FromLe(reply.data), 2048u);
    const DynamixelBusCounters c = bus_->counters();
    EXPECT_EQ(c.crc_errors, 1u);
    EXPECT_EQ(c.retries, 1u);
    EXPECT_EQ(c.requests, 2u);
    EXPECT_EQ(c.timeouts, 0u);
  }
}

TEST_F(DynamixelBusTest, OnlyCorruptedAnswersGiveKCrcAfterEveryRetry) {
  DynamixelBusOptions options;
  options.retries = 2;
  StartSim(2, {1}, "xm430-w350", options);
  sim_->CorruptNextReplies(3);
  EXPECT_EQ(bus_->Ping(1), Errc::kCrc);
  EXPECT_EQ(bus_->counters().crc_errors, 3u);
  EXPECT_EQ(bus_->counters().retries, 2u);
  EXPECT_FALSE(bus_->Ping(1));  // the line is fine again
}

TEST_F(DynamixelBusTest, SilentServoTimesOutWithinTimeoutTimesAttempts) {
  DynamixelBusOptions options;
  options.timeout = 50ms;
  options.retries = 2;
  StartSim(2, {1, 2}, "xm430-w350", options);
  sim_->SetNoReply(2, true);
  const auto start = std::chrono::steady_clock::now();
  EXPECT_EQ(bus_->Ping(2), Errc::kTimeout);
  const auto elapsed = std::chrono::steady_clock::now() - start;
  // Each of the 3 attempts waits the whole timeout; the margin only absorbs a loaded machine.
  EXPECT_GE(elapsed, 150ms);
  EXPECT_LT(elapsed, 150ms + 2s);
  const DynamixelBusCounters c = bus_->counters();
  EXPECT_EQ(c.timeouts, 3u);
  EXPECT_EQ(c.retries, 2u);
  EXPECT_EQ(c.requests, 3u);
  EXPECT_FALSE(bus_->Ping(1));
}

TEST_F(DynamixelBusTest, SyncReadRetriesOnlyTheMissingServo) {
  DynamixelBusOptions options;
  options.timeout = 40ms;
  options.retries = 1;
  StartSim(2, {1, 2, 3}, "xm430-w350", options);
  sim_->SetNoReply(2, true);
  std::vector<DxlReply> replies;
  EXPECT_EQ(bus_->SyncRead(132, 4, {1, 2, 3}, &replies), Errc::kTimeout);
  ASSERT_EQ(replies.size(), 3u);
  EXPECT_FALSE(replies[0].ec);
  EXPECT_EQ(replies[1].ec, Errc::kTimeout);
  EXPECT_FALSE(replies[2].ec);
  EXPECT_EQ(FromLe(replies[2].data), 2048u);
  EXPECT_EQ(bus_->counters().requests, 2u);
  EXPECT_EQ(sim_->statistics().replies, 2u);  // the retry asked servo 2 only
}

TEST_F(DynamixelBusTest, BadBackendOrOptionsAreConfigErrorsAndAMissingPortAHalError) {
  EXPECT_THROW(DynamixelBus::Open("socketcan:can0", {}), common::ConfigError);
  EXPECT_THROW(DynamixelBus::Open("tty:", {}), common::ConfigError);
  EXPECT_THROW(DynamixelBus::Open("tty:/dev/kinevis-no-such-port@1000000", {}), HalError);
  DynamixelBusOptions bad;
  bad.protocol = 3;
  bad.retries = 11;
  try {
    DynamixelBus::Open("tty:" + pty_.slave_path(), bad);
    FAIL() << "no exception";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), HasSubstr("protocol 3"));
    EXPECT_THAT(e.what(), HasSubstr("retries 11"));
  }
}

// -------------------------------------------------------------------------- DynamixelServo

TEST_F(DynamixelBusTest, ServoLifecycleRefusesCommandsUnlessActive) {
  StartSim(2, {1}, "xm430-w350");
  DynamixelServo servo(bus_.get(), 1, DxlControlTable::LoadModel("xm430-w350"));
  EXPECT_EQ(servo.name(), Backend() + " servo 1 (xm430-w350)");
  EXPECT_EQ(servo.lifecycle(), common::DeviceLifecycle::kUnconfigured);
  EXPECT_EQ(servo.SetGoalPosition(1.0), Errc::kNotActive);
  EXPECT_EQ(servo.ReadState(), Errc::kNotActive);
  EXPECT_EQ(servo.Enable(), Errc::kNotActive);
  servo.Configure();
  EXPECT_EQ(servo.lifecycle(), common::DeviceLifecycle::kConfigured);
  EXPECT_DOUBLE_EQ(servo.min_position(), 0.0);
  EXPECT_DOUBLE_EQ(servo.max_position(), 4095 * kTick);
  EXPECT_NEAR(servo.state().position, M_PI, 1e-12);
  EXPECT_EQ(servo.SetGoalPosition(1.0), Errc::kNotActive);
  ASSERT_FALSE(servo.Enable());
  EXPECT_EQ(servo.lifecycle(), common::DeviceLifecycle::kActive);
  EXPECT_EQ(sim_->Register(1, "torque_enable"), 1);
  EXPECT_EQ(sim_->Register(1, "goal_position"), 2048);  // holds where it was
  EXPECT_EQ(servo.SetGoalPosition(-0.1), Errc::kInvalidArgument);
  EXPECT_EQ(servo.SetGoalPosition(2 * M_PI), Errc::kInvalidArgument);
  EXPECT_EQ(servo.SetGoalPosition(std::nan("")), Errc::kInvalidArgument);
  EXPECT_EQ(servo.SetProfileVelocity(-1.0), Errc::kInvalidArgument);
  ASSERT_FALSE(servo.SetGoalPosition(M_PI / 2));
  EXPECT_EQ(sim_->Register(1, "goal_position"), 1024);
  ASSERT_FALSE(servo.Disable());
  EXPECT_EQ(servo.lifecycle(), common::DeviceLifecycle::kConfigured);
  EXPECT_EQ(sim_->Register(1, "torque_enable"), 0);
  EXPECT_EQ(servo.SetGoalPosition(1.0), Errc::kNotActive);
}

TEST_F(DynamixelBusTest, SeveralServosOnOneBusMoveToTheirGoals) {
  for (int protocol : {1, 2}) {
    SCOPED_TRACE(protocol);
    sim_.reset();
    const std::string model = protocol == 1 ? "mx-12w" : "xm430-w350";
    StartSim(protocol, {1, 2}, model);
    std::vector<std::unique_ptr<DynamixelServo>> servos;
    for (uint8_t id : {1, 2}) {
      servos.push_back(
          std::make_unique<DynamixelServo>(bus_.get(), id, DxlControlTable::LoadModel(model)));
      servos.back()->Configure();
      ASSERT_FALSE(servos.back()->Enable());
      ASSERT_FALSE(servos.back()->SetProfileVelocity(2.0));  // rad/s
    }
    const double goals[2] = {M_PI / 2, M_PI + 0.75};
    for (int i = 0; i < 2; ++i) ASSERT_FALSE(servos[i]->SetGoalPosition(goals[i]));
    // Both move at about 2 rad/s: 1.6 rad takes 0.8 s. The bound only guards against a hang.
    const auto deadline = std::chrono::steady_clock::now() + 10s;
    bool arrived = false;
    bool seen_moving = false;
    while (!arrived && std::chrono::steady_clock::now() < deadline) {
      arrived = true;
      for (int i = 0; i < 2; ++i) {
        DxlServoState state;
        ASSERT_FALSE(servos[i]->ReadState(&state));
        seen_moving = seen_moving || state.moving;
        arrived = arrived && !state.moving && std::abs(state.position - goals[i]) < kTick;
      }
      std::this_thread::sleep_for(20ms);
    }
    EXPECT_TRUE(arrived);
    EXPECT_TRUE(seen_moving);
    EXPECT_NEAR(sim_->Position(1), goals[0], kTick);
    EXPECT_NEAR(sim_->Position(2), goals[1], kTick);
  }
}

TEST_F(DynamixelBusTest, Protocol2OverloadFaultsTheServoTurnsTorqueOffAndRebootClearsIt) {
  StartSim(2, {1, 2}, "xm430-w350");
  DynamixelServo servo(bus_.get(), 1, DxlControlTable::LoadModel("xm430-w350"));
  DynamixelServo other(bus_.get(), 2, DxlControlTable::LoadModel("xm430-w350"));
  servo.Configure();
  other.Configure();
  ASSERT_FALSE(servo.Enable());
  ASSERT_FALSE(other.Enable());
  sim_->InjectOverload(1);
  DxlServoState state;
  EXPECT_EQ(servo.ReadState(&state), Errc::kDeviceFault);
  EXPECT_EQ(servo.lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_EQ(state.hardware_error, kDxl2HwOverload);
  EXPECT_FALSE(state.torque_enabled);
  EXPECT_EQ(sim_->Register(1, "torque_enable"), 0);
  EXPECT_EQ(servo.SetGoalPosition(1.0), Errc::kNotActive);
  EXPECT_EQ(servo.Enable(), Errc::kDeviceFault);
  // The other servo on the bus carries on.
  EXPECT_FALSE(other.SetGoalPosition(3.0));
  EXPECT_EQ(other.lifecycle(), common::DeviceLifecycle::kActive);
  ASSERT_FALSE(servo.ClearFault());  // reboot
  EXPECT_EQ(servo.lifecycle(), common::DeviceLifecycle::kConfigured);
  EXPECT_FALSE(sim_->Overloaded(1));
  ASSERT_FALSE(servo.Enable());
  ASSERT_FALSE(servo.SetGoalPosition(1.0));
}

TEST_F(DynamixelBusTest, Protocol1OverloadNeedsAPowerCycle) {
  StartSim(1, {1}, "mx-12w");
  DynamixelServo servo(bus_.get(), 1, DxlControlTable::LoadModel("mx-12w"));
  servo.Configure();
  ASSERT_FALSE(servo.Enable());
  sim_->InjectOverload(1);
  EXPECT_EQ(servo.SetGoalPosition(2.0), Errc::kDeviceFault);  // the answer has the alarm
  EXPECT_EQ(servo.lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_EQ(servo.state().status_error & kDxl1OverloadError, kDxl1OverloadError);
  EXPECT_EQ(servo.Reboot(), Errc::kUnsupported);
  EXPECT_EQ(servo.ClearFault(), Errc::kDeviceFault);  // still overloaded
  EXPECT_EQ(servo.lifecycle(), common::DeviceLifecycle::kFault);
  sim_->PowerCycle(1);
  ASSERT_FALSE(servo.ClearFault());
  EXPECT_EQ(servo.lifecycle(), common::DeviceLifecycle::kConfigured);
  ASSERT_FALSE(servo.Enable());
}

TEST_F(DynamixelBusTest, ConfigureNamesTheServoAndTheCause) {
  // A servo that reports another model number than the table.
  std::string yaml;
  {
    const DxlControlTable shipped = DxlControlTable::LoadModel("xm430-w350");
    std::ifstream in(shipped.source());
    yaml.assign(std::istreambuf_iterator<char>(in), {});
  }
  for (const char* from : {"model_number: 1020", "initial: 1020"}) {
    const std::string f(from);
    yaml.replace(yaml.find(f), f.size(), f.substr(0, f.size() - 4) + "1030");
  }
  DynamixelBusOptions options;
  options.timeout = 20ms;
  options.retries = 0;
  StartSimWith(2,
               {{1, DxlControlTable::Parse(yaml, "w210.yaml")},
                {2, DxlControlTable::LoadModel("xm430-w350")}},
               options);
  const DxlControlTable table = DxlControlTable::LoadModel("xm430-w350");
  try {
    DynamixelServo(bus_.get(), 1, table).Configure();
    FAIL() << "no exception";
  } catch (const HalError& e) {
    EXPECT_EQ(e.device(), Backend() + " servo 1 (xm430-w350)");
    EXPECT_EQ(e.operation(), "check the model");
    EXPECT_THAT(e.cause(), HasSubstr("reports model number 1030"));
  }
  try {
    DynamixelServo(bus_.get(), 9, table).Configure();
    FAIL() << "no exception";
  } catch (const HalError& e) {
    EXPECT_EQ(e.device(), Backend() + " servo 9 (xm430-w350)");
    EXPECT_EQ(e.operation(), "ping");
    EXPECT_THAT(e.cause(), HasSubstr("no answer within 20 ms in 1 attempts"));
    EXPECT_EQ(e.code(), Errc::kTimeout);
  }
  // Equal limits: wheel mode.
  sim_->SetRegister(2, "min_position_limit", 0);
  sim_->SetRegister(2, "max_position_limit", 0);
  try {
    DynamixelServo(bus_.get(), 2, table).Configure();
    FAIL() << "no exception";
  } catch (const HalError& e) {
    EXPECT_THAT(e.cause(), HasSubstr("wheel or multi-turn mode"));
  }
  EXPECT_THROW(DynamixelServo(bus_.get(), 1, DxlControlTable::LoadModel("mx-12w")),
               common::ConfigError);
}

}  // namespace
}  // namespace kinevis::hal
