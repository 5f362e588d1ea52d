// The weld robot simulator at register level, through a plain hal::ModbusClient: the map of
// hal/weld/weld_robot_registers.h, one 0x10 write per segment, the buffer, every alarm, the arc
// interlock, and deterministic stepping with a SimulatedClock.

#include "hal/mock/weld_robot_sim.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <array>
#include <chrono>
#include <cmath>
#include <functional>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "common/clock.h"
#include "hal/common/error.h"
#include "hal/modbus/modbus_client.h"
#include "hal/weld/weld_robot_registers.h"

namespace kinevis::hal {
namespace {

namespace wr = weld_robot;
using std::chrono::milliseconds;
using ::testing::HasSubstr;

constexpr char kPatient[] = ",timeout_ms=3000,retries=0";
using Units = std::array<int32_t, wr::kJointCount>;

// Power-on position of the default options, in register units (µrad, µm).
constexpr Units kHome = {0, 0, 50000, 0, 0};

std::array<uint16_t, wr::kSegmentRegisters> SegmentRegisters(uint32_t sequence, const Units& q,
                                                             uint16_t duration_ms,
                                                             uint16_t flags = 0) {
  std::array<uint16_t, wr::kSegmentRegisters> r{};
  wr::PutU32(&r[wr::kSegmentSequenceOffset], sequence);
  for (int j = 0; j < wr::kJointCount; ++j) {
    wr::PutI32(&r[static_cast<size_t>(wr::kSegmentJointsOffset + 2 * j)],
               q[static_cast<size_t>(j)]);
  }
  r[wr::kSegmentDurationOffset] = duration_ms;
  r[wr::kSegmentFlagsOffset] = flags;
  return r;
}

Units With(Units q, int joint, int32_t value) {
  q[static_cast<size_t>(joint)] = value;
  return q;
}

// The status block as the host sees it.
struct Status {
  uint16_t motion = 0, alarm = 0, level = 0, free = 0, arc_enabled = 0, arc_on = 0;
  uint32_t last = 0, completed = 0, alarm_sequence = 0;
  Units joints{};
  uint16_t current = 0, voltage = 0, wire_feed = 0;
};

class WeldRobotSimTest : public ::testing::Test {
 protected:
  void SetUp() override { Start(Options()); }

  WeldRobotSim::Options Options() {
    WeldRobotSim::Options o;
    o.run_executor = false;  // stepped by the tests, on clock_
    o.clock = &clock_;
    o.buffer_capacity = 4;
    return o;
  }

  void Start(const WeldRobotSim::Options& o) {
    client_.reset();
    sim_ = WeldRobotSim::ListenTcp("127.0.0.1", 0, o);
    client_ = ModbusClient::Open(sim_->backend() + kPatient);
  }

  std::error_code Write(uint32_t sequence, const Units& q, uint16_t duration_ms,
                        uint16_t flags = 0) {
    auto r = SegmentRegisters(sequence, q, duration_ms, flags);
    return client_->WriteRegisters(wr::kSegmentAddress, wr::kSegmentRegisters, r.data());
  }
  std::error_code Command(wr::Command c) {
    return client_->WriteRegister(wr::kRegCommand, static_cast<uint16_t>(c));
  }

  Status Read() {
    uint16_t r[wr::kStatusRegisters];
    EXPECT_EQ(client_->ReadInputRegisters(wr::kStatusAddress, wr::kStatusRegisters, r),
              std::error_code());
    auto at = [&](int a) { return r + (a - wr::kStatusAddress); };
    Status s;
    s.motion = *at(wr::kRegMotionState);
    s.alarm = *at(wr::kRegAlarmCode);
    s.level = *at(wr::kRegBufferLevel);
    s.free = *at(wr::kRegBufferFree);
    s.arc_enabled = *at(wr::kRegArcEnabled);
    s.arc_on = *at(wr::kRegArcOn);
    s.last = wr::GetU32(at(wr::kRegLastSequence));
    s.completed = wr::GetU32(at(wr::kRegCompletedSequence));
    s.alarm_sequence = wr::GetU32(at(wr::kRegAlarmSequence));
    for (int j = 0; j < wr::kJointCount; ++j) {
      s.joints[static_cast<size_t>(j)] = wr::GetI32(at(wr::kRegActualJoints + 2 * j));
    }
    s.current = *at(wr::kRegActualCurrent);
    s.voltage = *at(wr::kRegActualVoltage);
    s.wire_feed = *at(wr::kRegActualWireFeed);
    return s;
  }

  // Simulated time passes; the simulator catches up with the clock.
  void Advance(milliseconds dt) {
    clock_.Advance(dt);
    sim_->Update();
  }

  common::SimulatedClock clock_;
  std::unique_ptr<WeldRobotSim> sim_;
  std::unique_ptr<ModbusClient> client_;
};

// ---- Identity and status ----------------------------------------------------------------------

TEST_F(WeldRobotSimTest, IdentityRegistersDescribeTheRobotAndItsLimits) {
  uint16_t r[wr::kIdentityRegisters];
  ASSERT_EQ(client_->ReadInputRegisters(wr::kIdentityAddress, wr::kIdentityRegisters, r),
            std::error_code());
  EXPECT_EQ(r[wr::kRegMagic], 0x4B57);
  EXPECT_EQ(r[wr::kRegMapVersion], 1);
  EXPECT_EQ(r[wr::kRegJointCount], 5);
  EXPECT_EQ(r[wr::kRegBufferCapacity], 4);
  EXPECT_EQ(r[wr::kRegMaxSegmentDurationMs], 60000);
  EXPECT_EQ(r[wr::kRegMaxCurrent], 4000);   // 400 A in 0.1 A
  EXPECT_EQ(r[wr::kRegMaxVoltage], 450);    // 45 V in 0.1 V
  EXPECT_EQ(r[wr::kRegMaxWireFeed], 4000);  // 0.4 m/s in 0.1 mm/s
  EXPECT_EQ(wr::GetU32(r + wr::kRegSerialNumber), 4u);
  auto limit = [&](int joint, int offset) {
    return r + wr::kRegJointLimits + wr::kJointLimitRegisters * joint + offset;
  };
  // θ1 ±170° = ±2.967060 rad, 90°/s = 1.570796 rad/s, in µrad.
  EXPECT_EQ(wr::GetI32(limit(0, wr::kJointLimitMinOffset)), -2967060);
  EXPECT_EQ(wr::GetI32(limit(0, wr::kJointLimitMaxOffset)), 2967060);
  EXPECT_EQ(wr::GetU32(limit(0, wr::kJointLimitSpeedOffset)), 1570796u);
  EXPECT_EQ(wr::GetI32(limit(1, wr::kJointLimitMaxOffset)), 2094395);  // 120°
  // pz3 0..500 mm at 50 mm/s, in µm.
  EXPECT_EQ(wr::GetI32(limit(2, wr::kJointLimitMinOffset)), 0);
  EXPECT_EQ(wr::GetI32(limit(2, wr::kJointLimitMaxOffset)), 500000);
  EXPECT_EQ(wr::GetU32(limit(2, wr::kJointLimitSpeedOffset)), 50000u);
  EXPECT_EQ(wr::GetI32(limit(3, wr::kJointLimitMinOffset)), -3141593);  // -180°
  EXPECT_EQ(wr::GetI32(limit(4, wr::kJointLimitMinOffset)), -2094395);  // -120°
}

TEST_F(WeldRobotSimTest, PowersOnIdleAtTheInitialJointsWithAnEmptyBuffer) {
  Status s = Read();
  EXPECT_EQ(s.motion, static_cast<uint16_t>(wr::MotionState::kIdle));
  EXPECT_EQ(s.alarm, 0);
  EXPECT_EQ(s.level, 0);
  EXPECT_EQ(s.free, 4);
  EXPECT_EQ(s.arc_on, 0);
  EXPECT_EQ(s.joints, kHome);
}

// ---- Segments ---------------------------------------------------------------------------------

TEST_F(WeldRobotSimTest, SegmentInOneWriteIsInterpolatedLinearlyOverItsDuration) {
  // θ1 to 0.1 rad and pz3 to 60 mm in 200 ms: 0.5 rad/s and 50 mm/s, both within the limits.
  const Units target = {100000, 0, 60000, 0, -20000};
  ASSERT_EQ(Write(7, target, 200), std::error_code());
  Status s = Read();
  EXPECT_EQ(s.motion, static_cast<uint16_t>(wr::MotionState::kMoving));
  EXPECT_EQ(s.level, 1);
  EXPECT_EQ(s.free, 3);
  EXPECT_EQ(s.last, 7u);
  EXPECT_EQ(s.joints, kHome);  // no time has passed

  Advance(milliseconds(50));
  EXPECT_EQ(Read().joints, (Units{25000, 0, 52500, 0, -5000}));
  Advance(milliseconds(100));
  EXPECT_EQ(Read().joints, (Units{75000, 0, 57500, 0, -15000}));
  Advance(milliseconds(50));
  s = Read();
  EXPECT_EQ(s.joints, target);
  EXPECT_EQ(s.motion, static_cast<uint16_t>(wr::MotionState::kIdle));
  EXPECT_EQ(s.level, 0);
  EXPECT_EQ(s.completed, 7u);
  // The segment block reads back what was written.
  uint16_t back[wr::kSegmentRegisters];
  ASSERT_EQ(client_->ReadHoldingRegisters(wr::kSegmentAddress, wr::kSegmentRegisters, back),
            std::error_code());
  EXPECT_EQ(wr::GetI32(back + wr::kSegmentJointsOffset), 100000);
  EXPECT_EQ(back[wr::kSegmentDurationOffset], 200);
}

TEST_F(WeldRobotSimTest, BufferedSegmentsRunBackToBackAndTheLevelCountsThem) {
  ASSERT_EQ(Write(1, With(kHome, 0, 10000), 100), std::error_code());
  ASSERT_EQ(Write(2, With(kHome, 0, 20000), 100), std::error_code());
  ASSERT_EQ(Write(3, With(kHome, 0, 30000), 100), std::error_code());
  Status s = Read();
  EXPECT_EQ(s.level, 3);
  EXPECT_EQ(s.free, 1);
  EXPECT_EQ(s.last, 3u);
  // One update across a segment boundary carries the rest of the time into the next segment.
  Advance(milliseconds(150));
  s = Read();
  EXPECT_EQ(s.level, 2);
  EXPECT_EQ(s.completed, 1u);
  EXPECT_EQ(s.joints[0], 15000);
  Advance(milliseconds(150));
  s = Read();
  EXPECT_EQ(s.level, 0);
  EXPECT_EQ(s.completed, 3u);
  EXPECT_EQ(s.joints[0], 30000);
  EXPECT_THAT(sim_->completed_sequences(), ::testing::ElementsAre(1u, 2u, 3u));
  EXPECT_EQ(sim_->statistics().max_buffer_level, 3);
}

TEST_F(WeldRobotSimTest, SteppingIsDeterministicWhateverTheStepSize) {
  auto run = [&](milliseconds step) {
    Start(Options());
    for (uint32_t k = 1; k <= 4; ++k) {
      EXPECT_EQ(Write(k, With(With(kHome, 0, static_cast<int32_t>(k) * 7919), 2, 50000 + 1000 * k),
                      static_cast<uint16_t>(30 + 10 * k)),
                std::error_code());
    }
    std::vector<Units> trace;
    for (int t = 0; t < 12; ++t) {
      for (milliseconds done{0}; done < milliseconds(20); done += step) sim_->Step(step);
      trace.push_back(Read().joints);
    }
    return trace;
  };
  EXPECT_EQ(run(milliseconds(1)), run(milliseconds(20)));
}

TEST_F(WeldRobotSimTest, UpdateFollowsTheSimulatedClock) {
  ASSERT_EQ(Write(1, With(kHome, 4, -40000), 400), std::error_code());
  sim_->Update();  // no time has passed on the clock
  EXPECT_EQ(Read().joints[4], 0);
  clock_.Advance(milliseconds(100));
  sim_->Update();
  EXPECT_EQ(Read().joints[4], -10000);
  sim_->Update();  // the clock has not moved since
  EXPECT_EQ(Read().joints[4], -10000);
  Advance(milliseconds(1000));
  EXPECT_EQ(Read().joints[4], -40000);
  EXPECT_EQ(Read().motion, static_cast<uint16_t>(wr::MotionState::kIdle));
}

TEST_F(WeldRobotSimTest, ARepeatedLastSegmentIsAcknowledgedAndIgnored) {
  ASSERT_EQ(Write(1, With(kHome, 0, 10000), 100), std::error_code());
  ASSERT_EQ(Write(1, With(kHome, 0, 10000), 100), std::error_code());  // a retried request
  Status s = Read();
  EXPECT_EQ(s.level, 1);
  EXPECT_EQ(s.alarm, 0);
  EXPECT_EQ(sim_->statistics().duplicates_ignored, 1u);
  EXPECT_EQ(sim_->statistics().segments_accepted, 1u);
}

TEST_F(WeldRobotSimTest, SegmentBlockTakesOnlyOneWholeWriteMultipleRegisters) {
  auto r = SegmentRegisters(1, kHome, 100);
  EXPECT_EQ(client_->WriteRegisters(wr::kSegmentAddress, wr::kSegmentRegisters - 1, r.data()),
            ModbusErrc::kIllegalDataAddress);
  EXPECT_EQ(client_->WriteRegisters(wr::kSegmentAddress + 1, 2, r.data()),
            ModbusErrc::kIllegalDataAddress);
  EXPECT_EQ(client_->WriteRegister(wr::kSegmentAddress + wr::kSegmentDurationOffset, 100),
            ModbusErrc::kIllegalFunction);
  EXPECT_EQ(client_->MaskWriteRegister(wr::kRegSetCurrent, 0, 1), ModbusErrc::kIllegalFunction);
  // Nothing outside the documented registers is writable.
  EXPECT_EQ(client_->WriteRegister(205, 1), ModbusErrc::kIllegalDataAddress);
  EXPECT_EQ(client_->WriteRegisters(wr::kRegCommand, 2, r.data()), ModbusErrc::kIllegalDataAddress);
  // No coils on this controller.
  uint8_t bit = 0;
  EXPECT_EQ(client_->ReadCoils(0, 1, &bit), ModbusErrc::kIllegalDataAddress);
  Status s = Read();
  EXPECT_EQ(s.level, 0);
  EXPECT_EQ(s.alarm, 0);  // protocol refusals are not alarms
  EXPECT_EQ(sim_->statistics().segments_accepted, 0u);
}

// ---- Alarms -----------------------------------------------------------------------------------

struct AlarmCase {
  const char* name;
  wr::Alarm alarm;
  // Writes that end with the one raising the alarm (its sequence number is `culprit`).
  std::function<void(WeldRobotSimTest*, std::error_code*)> provoke;
  uint32_t culprit;
};

class WeldRobotSimAlarmTest : public WeldRobotSimTest,
                              public ::testing::WithParamInterface<AlarmCase> {
 public:
  using WeldRobotSimTest::Write;
};

TEST_P(WeldRobotSimAlarmTest, BadSegmentRaisesItsAlarmStopsEverythingUntilReset) {
  const AlarmCase& c = GetParam();
  // The arc burns on a first segment, so that the alarm has something to put out.
  ASSERT_EQ(client_->WriteRegister(wr::kRegSetCurrent, 1500), std::error_code());
  ASSERT_EQ(client_->WriteRegister(wr::kRegSetVoltage, 220), std::error_code());
  ASSERT_EQ(client_->WriteRegister(wr::kRegSetWireFeed, 1000), std::error_code());
  ASSERT_EQ(Command(wr::Command::kArcOn), std::error_code());
  ASSERT_EQ(Write(1, With(kHome, 0, 100000), 1000, wr::kSegmentFlagArcOn), std::error_code());
  Advance(milliseconds(500));
  ASSERT_EQ(Read().arc_on, 1);
  const Units where = Read().joints;
  EXPECT_EQ(where[0], 50000);

  std::error_code last;
  c.provoke(this, &last);
  EXPECT_EQ(last, ModbusErrc::kIllegalDataValue) << c.name;
  Status s = Read();
  EXPECT_EQ(s.alarm, static_cast<uint16_t>(c.alarm)) << c.name;
  EXPECT_EQ(s.alarm_sequence, c.culprit);
  EXPECT_EQ(s.motion, static_cast<uint16_t>(wr::MotionState::kAlarm));
  EXPECT_EQ(s.level, 0);
  EXPECT_EQ(s.arc_on, 0);
  EXPECT_EQ(s.arc_enabled, 0);
  // Motion stopped where it was: time passes, the joints stay.
  Advance(milliseconds(500));
  EXPECT_EQ(Read().joints, where);
  EXPECT_EQ(Read().completed, 0u);
  // Refused until reset: segments and ARC ON, with SERVER DEVICE FAILURE.
  EXPECT_EQ(Write(2, where, 100), ModbusErrc::kServerDeviceFailure);
  EXPECT_EQ(Command(wr::Command::kArcOn), ModbusErrc::kServerDeviceFailure);
  EXPECT_EQ(Command(wr::Command::kStop), std::error_code());  // STOP keeps the alarm
  EXPECT_EQ(Read().alarm, static_cast<uint16_t>(c.alarm));

  ASSERT_EQ(Command(wr::Command::kAlarmReset), std::error_code());
  s = Read();
  EXPECT_EQ(s.alarm, 0);
  EXPECT_EQ(s.motion, static_cast<uint16_t>(wr::MotionState::kIdle));
  // After the reset a new stream starts with any sequence number, from where the robot stands.
  ASSERT_EQ(Write(500, With(where, 0, 60000), 100), std::error_code());
  Advance(milliseconds(100));
  EXPECT_EQ(Read().joints[0], 60000);
  EXPECT_EQ(sim_->statistics().alarms_raised, 1u);
}

INSTANTIATE_TEST_SUITE_P(
    EveryInputAlarm, WeldRobotSimAlarmTest,
    ::testing::Values(AlarmCase{"target out of range", wr::Alarm::kTargetOutOfRange,
                                [](WeldRobotSimTest* t, std::error_code* ec) {
                                  // θ2 beyond +120° (2.094395 rad).
                                  auto* self = static_cast<WeldRobotSimAlarmTest*>(t);
                                  *ec = self->Write(2, With(With(kHome, 0, 100000), 1, 2094396),
                                                    60000);
                                },
                                2},
                      AlarmCase{"pz3 below zero", wr::Alarm::kTargetOutOfRange,
                                [](WeldRobotSimTest* t, std::error_code* ec) {
                                  auto* self = static_cast<WeldRobotSimAlarmTest*>(t);
                                  *ec = self->Write(2, With(With(kHome, 0, 100000), 2, -1), 60000);
                                },
                                2},
                      AlarmCase{"sequence gap", wr::Alarm::kSequenceGap,
                                [](WeldRobotSimTest* t, std::error_code* ec) {
                                  auto* self = static_cast<WeldRobotSimAlarmTest*>(t);
                                  EXPECT_EQ(self->Write(2, With(kHome, 0, 110000), 100),
                                            std::error_code());
                                  *ec = self->Write(4, With(kHome, 0, 120000), 100);
                                },
                                4},
                      AlarmCase{"speed limit", wr::Alarm::kSpeedLimit,
                                [](WeldRobotSimTest* t, std::error_code* ec) {
                                  // From 0.1 rad to 0.3 rad in 100 ms: 2 rad/s > 90°/s (1.5708
                                  // rad/s).
                                  auto* self = static_cast<WeldRobotSimAlarmTest*>(t);
                                  *ec = self->Write(2, With(kHome, 0, 300000), 100);
                                },
                                2},
                      AlarmCase{"pz3 speed limit", wr::Alarm::kSpeedLimit,
                                [](WeldRobotSimTest* t, std::error_code* ec) {
                                  // pz3 from 50 mm to 56 mm in 100 ms: 60 mm/s > 50 mm/s.
                                  auto* self = static_cast<WeldRobotSimAlarmTest*>(t);
                                  *ec = self->Write(2, With(With(kHome, 0, 100000), 2, 56000), 100);
                                },
                                2},
                      AlarmCase{"zero duration", wr::Alarm::kBadSegment,
                                [](WeldRobotSimTest* t, std::error_code* ec) {
                                  auto* self = static_cast<WeldRobotSimAlarmTest*>(t);
                                  *ec = self->Write(2, With(kHome, 0, 100000), 0);
                                },
                                2},
                      AlarmCase{"buffer overflow", wr::Alarm::kBufferOverflow,
                                [](WeldRobotSimTest* t, std::error_code* ec) {
                                  // Capacity 4: the executing segment and three more fill it.
                                  auto* self = static_cast<WeldRobotSimAlarmTest*>(t);
                                  for (uint32_t k = 2; k <= 4; ++k) {
                                    EXPECT_EQ(self->Write(k, With(kHome, 0, 100000), 100),
                                              std::error_code());
                                  }
                                  *ec = self->Write(5, With(kHome, 0, 100000), 100);
                                },
                                5}),
    [](const ::testing::TestParamInfo<AlarmCase>& info) {
      std::string name = info.param.name;
      for (char& ch : name) {
        if (ch == ' ') ch = '_';
      }
      return name;
    });

TEST_F(WeldRobotSimTest, InjectedAlarmStopsMotionAndCarriesItsCode) {
  ASSERT_EQ(Write(1, With(kHome, 3, 200000), 1000), std::error_code());
  Advance(milliseconds(250));
  sim_->RaiseAlarm(static_cast<uint16_t>(wr::Alarm::kWireStuck));
  Status s = Read();
  EXPECT_EQ(s.alarm, 18);
  EXPECT_EQ(s.alarm_sequence, 0u);
  EXPECT_EQ(s.level, 0);
  EXPECT_EQ(s.joints[3], 50000);
  Advance(milliseconds(500));
  EXPECT_EQ(Read().joints[3], 50000);
  EXPECT_STREQ(wr::AlarmName(s.alarm), "WIRE STUCK");
  EXPECT_STREQ(wr::AlarmName(999), "UNKNOWN ALARM");
  EXPECT_THROW(sim_->RaiseAlarm(0), common::ConfigError);
}

// ---- Commands, set-points and the arc interlock -----------------------------------------------

TEST_F(WeldRobotSimTest, StopHaltsWhereTheRobotIsClearsTheBufferAndOpensANewStream) {
  ASSERT_EQ(Write(10, With(kHome, 0, 100000), 200), std::error_code());
  ASSERT_EQ(Write(11, With(kHome, 0, 200000), 200), std::error_code());
  Advance(milliseconds(100));
  ASSERT_EQ(Command(wr::Command::kStop), std::error_code());
  Status s = Read();
  EXPECT_EQ(s.motion, static_cast<uint16_t>(wr::MotionState::kIdle));
  EXPECT_EQ(s.level, 0);
  EXPECT_EQ(s.joints[0], 50000);
  EXPECT_EQ(s.last, 11u);
  EXPECT_EQ(s.completed, 0u);
  uint16_t command = 99;
  ASSERT_EQ(client_->ReadHoldingRegisters(wr::kRegCommand, 1, &command), std::error_code());
  EXPECT_EQ(command, 0);  // executed commands read back 0
  // Any sequence number starts the next stream; the one after must follow it.
  EXPECT_EQ(Write(3, With(kHome, 0, 60000), 100), std::error_code());
  EXPECT_EQ(Write(4, With(kHome, 0, 70000), 100), std::error_code());
  EXPECT_EQ(Read().alarm, 0);
}

TEST_F(WeldRobotSimTest, UnknownCommandAndOversizedSetPointsAreRefused) {
  EXPECT_EQ(client_->WriteRegister(wr::kRegCommand, 77), ModbusErrc::kIllegalDataValue);
  const uint16_t too_much[3] = {4001, 100, 100};  // 400.1 A > 400 A
  EXPECT_EQ(client_->WriteRegisters(wr::kRegSetCurrent, 3, too_much),
            ModbusErrc::kIllegalDataValue);
  const uint16_t good[3] = {1805, 241, 1333};  // 180.5 A, 24.1 V, 133.3 mm/s
  ASSERT_EQ(client_->WriteRegisters(wr::kRegSetCurrent, 3, good), std::error_code());
  Status s = Read();
  EXPECT_EQ(s.current, 1805);
  EXPECT_EQ(s.voltage, 241);
  EXPECT_EQ(s.wire_feed, 1333);
  EXPECT_DOUBLE_EQ(sim_->state().current, 180.5);
  EXPECT_DOUBLE_EQ(sim_->state().wire_feed_speed, 0.1333);
  EXPECT_EQ(sim_->statistics().writes_refused, 2u);
}

TEST_F(WeldRobotSimTest, ArcBurnsOnlyWhileEnabledOnAnArcSegmentWithSetPoints) {
  // No set-points: ARC ON is refused by the interlock.
  EXPECT_EQ(Command(wr::Command::kArcOn), ModbusErrc::kIllegalDataValue);
  const uint16_t weld[3] = {1500, 220, 1000};
  ASSERT_EQ(client_->WriteRegisters(wr::kRegSetCurrent, 3, weld), std::error_code());
  ASSERT_EQ(Command(wr::Command::kArcOn), std::error_code());
  Status s = Read();
  EXPECT_EQ(s.arc_enabled, 1);
  EXPECT_EQ(s.arc_on, 0);  // standing still: no arc
  ASSERT_EQ(Write(1, With(kHome, 0, 10000), 100, 0), std::error_code());
  ASSERT_EQ(Write(2, With(kHome, 0, 20000), 100, wr::kSegmentFlagArcOn), std::error_code());
  EXPECT_EQ(Read().arc_on, 0);  // segment 1 is not an arc segment
  Advance(milliseconds(150));
  EXPECT_EQ(Read().arc_on, 1);
  // A zero set-point puts it out, restoring it relights it.
  ASSERT_EQ(client_->WriteRegister(wr::kRegSetVoltage, 0), std::error_code());
  EXPECT_EQ(Read().arc_on, 0);
  ASSERT_EQ(client_->WriteRegister(wr::kRegSetVoltage, 220), std::error_code());
  EXPECT_EQ(Read().arc_on, 1);
  // The buffer runs empty: the arc goes out by itself, still enabled.
  Advance(milliseconds(100));
  s = Read();
  EXPECT_EQ(s.arc_on, 0);
  EXPECT_EQ(s.arc_enabled, 1);
  EXPECT_EQ(sim_->statistics().arc_segments, 1u);
  EXPECT_NEAR(sim_->statistics().arc_time, 0.1, 1e-9);
  ASSERT_EQ(Command(wr::Command::kArcOff), std::error_code());
  EXPECT_EQ(Read().arc_enabled, 0);
}

// ---- Transports, the executor thread and fault injection --------------------------------------

TEST(WeldRobotSimRtuTest, ServesTheSameMapOverRtuOnAPty) {
  common::SimulatedClock clock;
  WeldRobotSim::Options o;
  o.run_executor = false;
  o.clock = &clock;
  auto sim = WeldRobotSim::ServeRtu(o);
  EXPECT_THAT(sim->backend(), ::testing::StartsWith("modbus-rtu:/dev/pts/"));
  auto client = ModbusClient::Open(sim->backend() + kPatient);
  uint16_t id[wr::kIdentityRegisters];
  ASSERT_EQ(client->ReadInputRegisters(0, wr::kIdentityRegisters, id), std::error_code());
  EXPECT_EQ(id[wr::kRegMagic], wr::kIdentityMagic);
  auto r = SegmentRegisters(1, With(kHome, 1, -30000), 100);
  ASSERT_EQ(client->WriteRegisters(wr::kSegmentAddress, wr::kSegmentRegisters, r.data()),
            std::error_code());
  clock.Advance(milliseconds(100));
  sim->Update();
  uint16_t q[2];
  ASSERT_EQ(client->ReadInputRegisters(wr::kRegActualJoints + 2, 2, q), std::error_code());
  EXPECT_EQ(wr::GetI32(q), -30000);
}

TEST(WeldRobotSimThreadTest, ExecutorThreadRunsSegmentsInRealTime) {
  auto sim = WeldRobotSim::ListenTcp("127.0.0.1", 0);  // default: executor on the steady clock
  auto client = ModbusClient::Open(sim->backend() + kPatient);
  auto r = SegmentRegisters(1, With(kHome, 2, 51000), 20);
  ASSERT_EQ(client->WriteRegisters(wr::kSegmentAddress, wr::kSegmentRegisters, r.data()),
            std::error_code());
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (sim->state().completed_sequence != 1 && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(milliseconds(2));
  }
  EXPECT_EQ(sim->state().completed_sequence, 1u);
  EXPECT_NEAR(sim->state().joints[2], 0.051, 1e-9);
}

TEST_F(WeldRobotSimTest, DropLinkAndStopAnsweringAreSeenByTheClient) {
  auto fragile = ModbusClient::Open(sim_->backend() + ",timeout_ms=200,retries=0");
  uint16_t v = 0;
  ASSERT_EQ(fragile->ReadInputRegisters(0, 1, &v), std::error_code());
  EXPECT_EQ(sim_->DropLink(), 2);  // client_ and fragile
  EXPECT_EQ(fragile->ReadInputRegisters(0, 1, &v), Errc::kClosed);
  EXPECT_EQ(fragile->ReadInputRegisters(0, 1, &v), std::error_code());  // reconnects
  sim_->StopAnswering(milliseconds::max());
  EXPECT_EQ(fragile->ReadInputRegisters(0, 1, &v), Errc::kTimeout);
  sim_->ResumeAnswering();
  EXPECT_EQ(fragile->ReadInputRegisters(0, 1, &v), std::error_code());
  EXPECT_EQ(v, wr::kIdentityMagic);
}

TEST(WeldRobotSimOptionsTest, BadOptionsThrowNamingEveryField) {
  WeldRobotSim::Options o;
  o.joints[1].min = 1.0;
  o.joints[1].max = -1.0;
  o.buffer_capacity = 0;
  o.max_segment_duration = 100.0;
  try {
    WeldRobotSim::ListenTcp("127.0.0.1", 0, o);
    FAIL() << "no ConfigError";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), HasSubstr("joint θ2 limits"));
    EXPECT_THAT(e.what(), HasSubstr("buffer_capacity 0"));
    EXPECT_THAT(e.what(), HasSubstr("max_segment_duration"));
  }
}

}  // namespace
}  // namespace kinevis::hal
