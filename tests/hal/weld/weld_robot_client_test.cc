// The weld robot host driver against the simulator, over loopback Modbus TCP and over Modbus RTU
// on a pty: identity, state, lifecycle, streaming with flow control, every alarm, a dropped link,
// a robot that stops answering, cancel and the overall time bound.
//
// Most streams run on a simulator stepped from the progress callback (8 ms of robot time per
// status read): the robot then only moves when the host looks, which makes the flow control
// deterministic. The real-time executor thread is exercised too, with assertions on order and
// end state, never on speed.

#include "hal/weld/weld_robot_client.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <functional>
#include <memory>
#include <numeric>
#include <string>
#include <thread>
#include <vector>

#include "hal/common/error.h"
#include "hal/mock/weld_robot_sim.h"
#include "hal/modbus/modbus_client.h"
#include "hal/modbus/modbus_server.h"
#include "hal/serial/pty_pair.h"

namespace kinevis::hal {
namespace {

namespace wr = weld_robot;
using std::chrono::milliseconds;
using ::testing::ContainsRegex;
using ::testing::HasSubstr;

enum class Transport { kTcp, kRtu };

constexpr int kCapacity = 8;
constexpr double kSegmentTime = 0.008;  // s
// Generous: a loaded machine must not turn into a spurious link fault.
constexpr char kPatient[] = ",timeout_ms=2000,retries=1";

// 200 points of a smooth path through all five joints, starting near the power-on position
// (0, 0, 50 mm, 0, 0); at 8 ms a segment every joint stays below 0.8 rad/s and 13 mm/s.
std::vector<WeldTrajectoryPoint> Trajectory(int n = 200, bool arc = true) {
  std::vector<WeldTrajectoryPoint> points;
  for (int i = 1; i <= n; ++i) {
    const double s = static_cast<double>(i) / n;
    WeldTrajectoryPoint p;
    p.joints = {0.2 * std::sin(2 * M_PI * s), 0.15 * (1 - std::cos(2 * M_PI * s)), 0.05 + 0.02 * s,
                0.1 * std::sin(2 * M_PI * s), -0.1 * std::sin(4 * M_PI * s)};
    p.duration = kSegmentTime;
    p.arc_on = arc;
    points.push_back(p);
  }
  return points;
}

// n slow points onward from `from` (where the robot stands): θ1 +1 mrad and pz3 +0.1 mm a point.
std::vector<WeldTrajectoryPoint> Ramp(const WeldJoints& from, int n) {
  std::vector<WeldTrajectoryPoint> points;
  for (int i = 1; i <= n; ++i) {
    WeldTrajectoryPoint p;
    p.joints = from;
    p.joints[0] += 0.001 * i;
    p.joints[2] += 0.0001 * i;
    p.duration = kSegmentTime;
    points.push_back(p);
  }
  return points;
}

std::vector<uint32_t> Consecutive(uint32_t first, size_t n) {
  std::vector<uint32_t> v(n);
  std::iota(v.begin(), v.end(), first);
  return v;
}

class WeldRobotClientTest : public ::testing::TestWithParam<Transport> {
 protected:
  // real_time: the simulator's executor thread; otherwise Step() from the progress callback.
  void StartSim(bool real_time) {
    WeldRobotSim::Options o;
    o.buffer_capacity = kCapacity;
    o.run_executor = real_time;
    o.serial_number = 20240611;
    sim_ = GetParam() == Transport::kTcp ? WeldRobotSim::ListenTcp("127.0.0.1", 0, o)
                                         : WeldRobotSim::ServeRtu(o);
  }

  std::unique_ptr<WeldRobotClient> Connect(const std::string& options = kPatient) {
    auto client = WeldRobotClient::Open(sim_->backend() + options);
    client->Configure();
    EXPECT_EQ(client->Activate(), std::error_code());
    return client;
  }

  // Weld set-points and arc enable, so that the arc burns on the arc segments.
  void PrepareToWeld(WeldRobotClient& client) {
    ASSERT_EQ(client.SetWeldParameters({180.0, 24.5, 0.15}), std::error_code());
    ASSERT_EQ(client.ArcOn(), std::error_code());
  }

  // A progress callback that lets 8 ms of robot time pass at each status read, then runs
  // `inject` once `sent` reaches `at`.
  WeldStreamProgressCallback Stepping(std::vector<WeldStreamProgress>* log, size_t at = 0,
                                      std::function<void()> inject = {}) {
    return [this, log, at, inject, done = false](const WeldStreamProgress& p) mutable {
      if (log != nullptr) log->push_back(p);
      sim_->Step(milliseconds(8));
      if (inject && !done && p.sent >= at) {
        done = true;
        inject();
      }
    };
  }

  // The robot is in the safe state: standing still, buffer empty, arc off and disabled.
  void ExpectSafe() {
    const WeldRobotSim::State s = sim_->state();
    EXPECT_NE(s.motion, wr::MotionState::kMoving);
    EXPECT_EQ(s.buffer_level, 0);
    EXPECT_FALSE(s.arc_on);
    EXPECT_FALSE(s.arc_enabled);
    // And it stays that way.
    const auto joints = s.joints;
    sim_->Step(milliseconds(100));
    EXPECT_EQ(sim_->state().joints, joints);
  }

  std::unique_ptr<WeldRobotSim> sim_;
};

INSTANTIATE_TEST_SUITE_P(Transports, WeldRobotClientTest,
                         ::testing::Values(Transport::kTcp, Transport::kRtu),
                         [](const ::testing::TestParamInfo<Transport>& info) {
                           return info.param == Transport::kTcp ? "Tcp" : "Rtu";
                         });

// ---- Identity, state, lifecycle ---------------------------------------------------------------

TEST_P(WeldRobotClientTest, ConfigureReadsTheIdentityAndLimitsInSiUnits) {
  StartSim(false);
  auto client = WeldRobotClient::Open(sim_->backend() + kPatient);
  EXPECT_EQ(client->lifecycle(), common::DeviceLifecycle::kUnconfigured);
  EXPECT_EQ(client->name(), "weld-robot (" + sim_->backend() + kPatient + ")");
  client->Configure();
  EXPECT_EQ(client->lifecycle(), common::DeviceLifecycle::kConfigured);
  const WeldRobotIdentity& id = client->identity();
  EXPECT_EQ(id.map_version, 1);
  EXPECT_EQ(id.joint_count, 5);
  EXPECT_EQ(id.buffer_capacity, kCapacity);
  EXPECT_EQ(id.serial_number, 20240611u);
  EXPECT_DOUBLE_EQ(id.max_segment_duration, 60.0);
  EXPECT_DOUBLE_EQ(id.max_current, 400.0);
  EXPECT_DOUBLE_EQ(id.max_voltage, 45.0);
  EXPECT_DOUBLE_EQ(id.max_wire_feed_speed, 0.4);
  const double deg = M_PI / 180;
  EXPECT_NEAR(id.joints[0].min, -170 * deg, 1e-6);
  EXPECT_NEAR(id.joints[1].max, 120 * deg, 1e-6);
  EXPECT_DOUBLE_EQ(id.joints[2].min, 0.0);
  EXPECT_DOUBLE_EQ(id.joints[2].max, 0.5);
  EXPECT_DOUBLE_EQ(id.joints[2].max_speed, 0.05);
  EXPECT_NEAR(id.joints[3].max, 180 * deg, 1e-6);
  EXPECT_NEAR(id.joints[4].max_speed, 90 * deg, 1e-6);
}

TEST_P(WeldRobotClientTest, ReadStateReportsJointsSetPointsAndArcInSiUnits) {
  StartSim(false);
  auto client = Connect();
  WeldRobotState s;
  ASSERT_EQ(client->ReadState(&s), std::error_code());
  EXPECT_EQ(s.motion, wr::MotionState::kIdle);
  EXPECT_FALSE(s.alarm());
  EXPECT_STREQ(s.alarm_name, "NONE");
  EXPECT_EQ(s.buffer_level, 0);
  EXPECT_EQ(s.buffer_capacity, kCapacity);
  EXPECT_EQ(s.joints, (WeldJoints{0, 0, 0.05, 0, 0}));
  EXPECT_FALSE(s.arc_enabled);
  PrepareToWeld(*client);
  ASSERT_EQ(client->ReadState(&s), std::error_code());
  EXPECT_DOUBLE_EQ(s.weld.current, 180.0);
  EXPECT_DOUBLE_EQ(s.weld.voltage, 24.5);
  EXPECT_DOUBLE_EQ(s.weld.wire_feed_speed, 0.15);
  EXPECT_TRUE(s.arc_enabled);
  EXPECT_FALSE(s.arc_on);  // the interlock: no arc while standing still
  ASSERT_EQ(client->ArcOff(), std::error_code());
  ASSERT_EQ(client->ReadState(&s), std::error_code());
  EXPECT_FALSE(s.arc_enabled);
}

TEST_P(WeldRobotClientTest, CommandsAreRefusedUnlessActive) {
  StartSim(false);
  auto client = WeldRobotClient::Open(sim_->backend() + kPatient);
  WeldRobotState s;
  EXPECT_EQ(client->ReadState(&s), Errc::kNotActive);
  EXPECT_EQ(client->Stop(), Errc::kNotActive);
  client->Configure();
  EXPECT_EQ(client->ReadState(&s), std::error_code());
  EXPECT_EQ(client->ArcOn(), Errc::kNotActive);
  EXPECT_EQ(client->SetWeldParameters({100, 20, 0.1}), Errc::kNotActive);
  EXPECT_EQ(client->StreamTrajectory(Trajectory(), {}, nullptr), Errc::kNotActive);
  EXPECT_THAT(client->last_error_text(), HasSubstr("configured, not active"));
  EXPECT_EQ(client->Stop(), std::error_code());  // the safe state is always allowed
  EXPECT_EQ(sim_->statistics().segments_accepted, 0u);
}

TEST_P(WeldRobotClientTest, BadWeldParametersAndArcWithoutSetPointsAreRefused) {
  StartSim(false);
  auto client = Connect();
  EXPECT_EQ(client->ArcOn(), Errc::kInvalidArgument);
  EXPECT_THAT(client->last_error_text(), HasSubstr("interlock"));
  EXPECT_EQ(client->SetWeldParameters({500.0, 24.0, 0.1}), Errc::kInvalidArgument);
  EXPECT_THAT(client->last_error_text(), HasSubstr("current 500 A is not in 0..400"));
  EXPECT_EQ(client->SetWeldParameters({100.0, NAN, 0.1}), Errc::kInvalidArgument);
  EXPECT_EQ(sim_->state().current, 0.0);
  EXPECT_EQ(client->lifecycle(), common::DeviceLifecycle::kActive);  // bad arguments are no fault
}

TEST_P(WeldRobotClientTest, LimitsAreCheckedBeforeAnythingIsSent) {
  StartSim(false);
  auto client = Connect();
  auto points = Trajectory();
  points[120].joints[1] = 2.2;  // θ2 beyond 120°
  WeldStreamReport report;
  EXPECT_EQ(client->StreamTrajectory(points, {}, nullptr, {}, &report), Errc::kInvalidArgument);
  EXPECT_THAT(report.message, HasSubstr("segment 120: joint θ2 target 126.051° is outside"));
  points = Trajectory();
  points[30].joints[0] += 0.1;  // 0.1 rad in 8 ms
  EXPECT_EQ(client->StreamTrajectory(points, {}, nullptr, {}, &report), Errc::kInvalidArgument);
  EXPECT_THAT(report.message, HasSubstr("segment 30: joint θ1 would move at"));
  EXPECT_THAT(report.message, HasSubstr("above its speed limit 90.000°/s"));
  points = Trajectory();
  points[3].duration = 0;
  EXPECT_EQ(client->StreamTrajectory(points, {}, nullptr, {}, &report), Errc::kInvalidArgument);
  EXPECT_EQ(sim_->statistics().segments_accepted, 0u);
  EXPECT_EQ(client->lifecycle(), common::DeviceLifecycle::kActive);
}

TEST_P(WeldRobotClientTest, ConfigureRefusesADeviceThatIsNoWeldRobot) {
  std::unique_ptr<PtyPair> pty;  // outlives the server that serves on it
  std::unique_ptr<ModbusServer> other;
  if (GetParam() == Transport::kTcp) {
    other = ModbusServer::ListenTcp("127.0.0.1", 0);
  } else {
    pty = std::make_unique<PtyPair>();
    other = ModbusServer::ServeRtu(pty->master_fd(), pty->slave_path());
  }
  auto client = WeldRobotClient::Open(other->backend() + kPatient);
  try {
    client->Configure();
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_EQ(e.device(), client->name());
    EXPECT_THAT(e.what(), HasSubstr("identity magic 0x0000 (expected 0x4b57)"));
  }
  EXPECT_EQ(client->lifecycle(), common::DeviceLifecycle::kUnconfigured);
}

TEST(WeldRobotAlarmCategoryTest, AlarmCodesAreErrorCodesNamingTheAlarm) {
  std::error_code ec = wr::Alarm::kSequenceGap;
  EXPECT_EQ(ec.value(), 2);
  EXPECT_EQ(ec.category(), WeldRobotAlarmCategory());
  EXPECT_EQ(ec.message(), "SEQUENCE GAP (weld robot alarm 2)");
  EXPECT_EQ(WeldRobotAlarmError(17).message(), "ARC FAULT (weld robot alarm 17)");
  EXPECT_EQ(WeldRobotAlarmError(77).message(), "UNKNOWN ALARM (weld robot alarm 77)");
}

// ---- Streaming --------------------------------------------------------------------------------

TEST_P(WeldRobotClientTest, StreamsTwoHundredPointsWithFlowControlInOrder) {
  StartSim(false);
  auto client = Connect();
  PrepareToWeld(*client);
  const auto points = Trajectory();
  const uint32_t first = sim_->state().last_sequence + 1;
  std::vector<WeldStreamProgress> log;
  WeldStreamReport report;
  ASSERT_EQ(client->StreamTrajectory(points, Stepping(&log), nullptr, {}, &report),
            std::error_code())
      << report.message;
  EXPECT_EQ(report.sent, 200u);
  EXPECT_EQ(report.executed, 200u);
  EXPECT_TRUE(report.message.empty());
  // Flow control: the buffer was filled to capacity and the host waited, but never overflowed.
  const WeldRobotSim::Statistics stats = sim_->statistics();
  EXPECT_EQ(stats.max_buffer_level, kCapacity);
  EXPECT_EQ(report.max_buffer_level, kCapacity);
  EXPECT_GE(report.buffer_full_waits, 1u);
  EXPECT_EQ(stats.alarms_raised, 0u);
  EXPECT_EQ(stats.segments_accepted, 200u);
  // Every segment executed, in order, each with the arc burning.
  EXPECT_EQ(sim_->completed_sequences(), Consecutive(first, 200));
  EXPECT_EQ(stats.arc_segments, 200u);
  // The robot stands at the last target.
  WeldRobotState s;
  ASSERT_EQ(client->ReadState(&s), std::error_code());
  for (size_t j = 0; j < 5; ++j) EXPECT_NEAR(s.joints[j], points.back().joints[j], 1e-6) << j;
  EXPECT_EQ(s.motion, wr::MotionState::kIdle);
  EXPECT_FALSE(s.arc_on);  // the buffer ran empty: the interlock put the arc out
  // Progress: reported at every status read, monotonic, consistent, ending at 200 of 200.
  ASSERT_GE(log.size(), 200u / kCapacity);
  for (size_t i = 0; i < log.size(); ++i) {
    EXPECT_EQ(log[i].total, 200u);
    EXPECT_LE(log[i].executed, log[i].sent);
    EXPECT_LE(log[i].buffer_level, kCapacity);
    if (i > 0) {
      EXPECT_GE(log[i].sent, log[i - 1].sent);
      EXPECT_GE(log[i].executed, log[i - 1].executed);
    }
  }
  EXPECT_EQ(log.back().executed, 200u);
  EXPECT_EQ(client->counters().segments_sent, 200u);
  // A second stream continues the sequence numbers where the first ended.
  ASSERT_EQ(client->StreamTrajectory(Ramp(s.joints, 10), Stepping(nullptr), nullptr, {}, &report),
            std::error_code())
      << report.message;
  EXPECT_EQ(sim_->completed_sequences(), Consecutive(first, 210));
}

TEST_P(WeldRobotClientTest, StreamsOnTheRealTimeExecutor) {
  StartSim(true);
  auto client = Connect();
  const auto points = Trajectory(200, false);
  const uint32_t first = sim_->state().last_sequence + 1;
  size_t reports = 0;
  WeldStreamReport report;
  ASSERT_EQ(client->StreamTrajectory(
                points, [&](const WeldStreamProgress&) { ++reports; }, nullptr, {}, &report),
            std::error_code())
      << report.message;
  EXPECT_EQ(report.executed, 200u);
  EXPECT_GT(reports, 0u);
  EXPECT_LE(sim_->statistics().max_buffer_level, kCapacity);
  EXPECT_LE(report.max_buffer_level, kCapacity);
  EXPECT_EQ(sim_->statistics().alarms_raised, 0u);
  EXPECT_EQ(sim_->completed_sequences(), Consecutive(first, 200));
  const WeldRobotSim::State s = sim_->state();
  for (size_t j = 0; j < 5; ++j) EXPECT_NEAR(s.joints[j], points.back().joints[j], 1e-6) << j;
}

TEST_P(WeldRobotClientTest, CancelStopsTheRobot) {
  StartSim(false);
  auto client = Connect();
  PrepareToWeld(*client);
  std::atomic<bool> cancel{false};
  WeldStreamReport report;
  std::error_code ec = client->StreamTrajectory(
      Trajectory(), Stepping(nullptr, 50, [&] { cancel = true; }), &cancel, {}, &report);
  EXPECT_EQ(ec, std::errc::operation_canceled);
  EXPECT_TRUE(report.safe_state_confirmed);
  EXPECT_LT(report.executed, 200u);
  EXPECT_THAT(report.message, HasSubstr("canceled"));
  ExpectSafe();
  EXPECT_EQ(client->lifecycle(), common::DeviceLifecycle::kActive);  // a cancel is no fault
}

TEST_P(WeldRobotClientTest, WholeStreamIsBoundedInTime) {
  StartSim(false);  // and never stepped: the robot does not move, the buffer stays full
  auto client = Connect();
  WeldStreamOptions options;
  options.timeout = milliseconds(300);
  WeldStreamReport report;
  const auto start = std::chrono::steady_clock::now();
  EXPECT_EQ(client->StreamTrajectory(Trajectory(), {}, nullptr, options, &report), Errc::kTimeout);
  EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(10));
  EXPECT_EQ(report.sent, static_cast<size_t>(kCapacity));
  EXPECT_GE(report.buffer_full_waits, 1u);
  EXPECT_THAT(report.message, HasSubstr("not finished within 0.300 s"));
  EXPECT_TRUE(report.safe_state_confirmed);
  ExpectSafe();
  EXPECT_EQ(client->lifecycle(), common::DeviceLifecycle::kFault);
}

// ---- Alarms -----------------------------------------------------------------------------------

// Each alarm ends the stream with its name, its code and the device name, and leaves the robot
// stopped with the arc off; AlarmReset() then makes the driver active again.
void ExpectAlarmReport(const WeldRobotClient& client, const WeldStreamReport& report,
                       std::error_code ec, wr::Alarm alarm, const std::string& name) {
  EXPECT_EQ(ec, alarm);
  EXPECT_EQ(report.alarm_code, static_cast<uint16_t>(alarm));
  EXPECT_THAT(report.message, HasSubstr(client.name()));
  EXPECT_THAT(report.message, HasSubstr("alarm " + name + " (code " +
                                        std::to_string(static_cast<int>(alarm)) + ")"));
  EXPECT_TRUE(report.safe_state_confirmed);
  EXPECT_THAT(report.message, HasSubstr("safe state confirmed"));
  EXPECT_LT(report.executed, report.total);
  EXPECT_EQ(client.lifecycle(), common::DeviceLifecycle::kFault);
}

TEST_P(WeldRobotClientTest, OutOfRangeTargetAlarmIsReported) {
  StartSim(false);
  auto client = Connect();
  PrepareToWeld(*client);
  auto points = Trajectory();
  points[50].joints[1] = 2.2;  // beyond θ2's 120°; only the robot checks it here
  WeldStreamOptions options;
  options.check_limits = false;
  bool arc_was_on = false;
  WeldStreamReport report;
  std::error_code ec = client->StreamTrajectory(
      points, Stepping(nullptr, 45, [&] { arc_was_on = sim_->state().arc_on; }), nullptr, options,
      &report);
  EXPECT_TRUE(arc_was_on);
  ExpectAlarmReport(*client, report, ec, wr::Alarm::kTargetOutOfRange, "TARGET OUT OF RANGE");
  EXPECT_THAT(report.message, HasSubstr("(segment 50)"));
  EXPECT_EQ(report.sent, 50u);
  ExpectSafe();
  EXPECT_EQ(sim_->state().alarm_code, 1);
  // Until reset the driver refuses to move; the reset makes it active again.
  EXPECT_EQ(client->StreamTrajectory(Trajectory(5), {}, nullptr), Errc::kNotActive);
  ASSERT_EQ(client->AlarmReset(), std::error_code());
  EXPECT_EQ(client->lifecycle(), common::DeviceLifecycle::kActive);
  EXPECT_EQ(sim_->state().alarm_code, 0);
}

TEST_P(WeldRobotClientTest, SpeedLimitAlarmIsReported) {
  StartSim(false);
  auto client = Connect();
  PrepareToWeld(*client);
  auto points = Trajectory();
  points[80].joints[0] += 0.05;  // 0.05 rad more in 8 ms: above 90°/s
  WeldStreamOptions options;
  options.check_limits = false;
  WeldStreamReport report;
  std::error_code ec =
      client->StreamTrajectory(points, Stepping(nullptr), nullptr, options, &report);
  ExpectAlarmReport(*client, report, ec, wr::Alarm::kSpeedLimit, "SPEED LIMIT");
  EXPECT_THAT(report.message, HasSubstr("(segment 80)"));
  ExpectSafe();
}

TEST_P(WeldRobotClientTest, InjectedAlarmIsReported) {
  StartSim(false);
  auto client = Connect();
  PrepareToWeld(*client);
  WeldStreamReport report;
  std::error_code ec = client->StreamTrajectory(
      Trajectory(),
      Stepping(nullptr, 100,
               [&] { sim_->RaiseAlarm(static_cast<uint16_t>(wr::Alarm::kEmergencyStop)); }),
      nullptr, {}, &report);
  ExpectAlarmReport(*client, report, ec, wr::Alarm::kEmergencyStop, "EMERGENCY STOP");
  ExpectSafe();
  WeldRobotState s;
  EXPECT_EQ(client->ReadState(&s), std::error_code());
  EXPECT_EQ(s.alarm_code, 16);
  EXPECT_STREQ(s.alarm_name, "EMERGENCY STOP");
  EXPECT_EQ(s.motion, wr::MotionState::kAlarm);
}

// A second master writes into the stream (TCP: several clients at once).
class WeldRobotClientTcpTest : public WeldRobotClientTest {};
INSTANTIATE_TEST_SUITE_P(Tcp, WeldRobotClientTcpTest, ::testing::Values(Transport::kTcp));

TEST_P(WeldRobotClientTcpTest, SequenceGapAlarmIsReported) {
  StartSim(false);
  auto client = Connect();
  PrepareToWeld(*client);
  auto raw = ModbusClient::Open(sim_->backend() + kPatient);
  const auto points = Trajectory();
  WeldStreamReport report;
  std::error_code ec = client->StreamTrajectory(
      points,
      Stepping(nullptr, 40,
               [&] {
                 // A segment that skips four sequence numbers.
                 const uint32_t last = sim_->state().last_sequence;
                 uint16_t r[wr::kSegmentRegisters] = {};
                 wr::PutU32(r, last + 5);
                 r[wr::kSegmentDurationOffset] = 100;
                 EXPECT_EQ(raw->WriteRegisters(wr::kSegmentAddress, wr::kSegmentRegisters, r),
                           ModbusErrc::kIllegalDataValue);
               }),
      nullptr, {}, &report);
  ExpectAlarmReport(*client, report, ec, wr::Alarm::kSequenceGap, "SEQUENCE GAP");
  EXPECT_THAT(report.message, HasSubstr("(not written by this stream)"));
  ExpectSafe();
}

TEST_P(WeldRobotClientTcpTest, BufferOverflowForcedByARawWriterIsReported) {
  StartSim(false);
  auto client = Connect();
  PrepareToWeld(*client);
  auto raw = ModbusClient::Open(sim_->backend() + kPatient);
  const auto points = Trajectory();
  int raw_accepted = 0;
  std::error_code raw_last;
  WeldStreamReport report;
  std::error_code ec = client->StreamTrajectory(
      points,
      Stepping(nullptr, 60,
               [&] {
                 // Well-formed segments that hold the last target for a minute, written
                 // without looking at the buffer level, until the robot refuses one.
                 const WeldRobotSim::State s = sim_->state();
                 uint32_t sequence = s.last_sequence;
                 for (int k = 0; k <= kCapacity && !raw_last; ++k) {
                   uint16_t r[wr::kSegmentRegisters] = {};
                   wr::PutU32(r, ++sequence);
                   for (int j = 0; j < 5; ++j) {
                     wr::PutI32(r + 2 + 2 * j,
                                static_cast<int32_t>(
                                    std::lround(points[59].joints[static_cast<size_t>(j)] * 1e6)));
                   }
                   r[wr::kSegmentDurationOffset] = 60000;
                   raw_last = raw->WriteRegisters(wr::kSegmentAddress, wr::kSegmentRegisters, r);
                   if (!raw_last) ++raw_accepted;
                 }
               }),
      nullptr, {}, &report);
  EXPECT_EQ(raw_last, ModbusErrc::kIllegalDataValue);
  EXPECT_GE(raw_accepted, 1);
  ExpectAlarmReport(*client, report, ec, wr::Alarm::kBufferOverflow, "BUFFER OVERFLOW");
  EXPECT_EQ(sim_->statistics().max_buffer_level, kCapacity);
  ExpectSafe();
}

TEST_P(WeldRobotClientTcpTest, StopFromAnotherMasterEndsTheStream) {
  StartSim(false);
  auto client = Connect();
  PrepareToWeld(*client);
  auto raw = ModbusClient::Open(sim_->backend() + kPatient);
  WeldStreamReport report;
  std::error_code ec = client->StreamTrajectory(
      // Once everything is sent: a STOP earlier would make the robot refuse the next segment
      // (it would start from where the robot stopped, too fast: SPEED LIMIT), also safe.
      Trajectory(),
      Stepping(nullptr, 200,
               [&] {
                 EXPECT_EQ(
                     raw->WriteRegister(wr::kRegCommand, static_cast<uint16_t>(wr::Command::kStop)),
                     std::error_code());
               }),
      nullptr, {}, &report);
  EXPECT_EQ(ec, Errc::kDeviceFault);
  EXPECT_THAT(report.message, HasSubstr(client->name()));
  EXPECT_THAT(report.message, HasSubstr("the robot discarded"));
  EXPECT_TRUE(report.safe_state_confirmed);
  ExpectSafe();
}

// ---- Link faults ------------------------------------------------------------------------------

TEST_P(WeldRobotClientTcpTest, DroppedLinkMidStreamIsReportedAndTheRobotStopped) {
  for (const char* options : {",timeout_ms=2000,retries=0", ",timeout_ms=2000,retries=2"}) {
    SCOPED_TRACE(options);
    StartSim(false);
    auto client = Connect(options);
    PrepareToWeld(*client);
    int dropped = -1;
    WeldStreamReport report;
    std::error_code ec = client->StreamTrajectory(
        Trajectory(), Stepping(nullptr, 60, [&] { dropped = sim_->DropLink(); }), nullptr, {},
        &report);
    EXPECT_EQ(dropped, 1);
    EXPECT_EQ(ec, Errc::kClosed);
    EXPECT_THAT(report.message, HasSubstr(client->name()));
    EXPECT_THAT(report.message, ContainsRegex("link (failed|interrupted)"));
    EXPECT_TRUE(report.safe_state_confirmed) << report.message;
    EXPECT_LT(report.executed, 200u);
    EXPECT_EQ(client->lifecycle(), common::DeviceLifecycle::kFault);
    ExpectSafe();
    // Once the link is back, the fault is cleared and the robot streams again.
    ASSERT_EQ(client->AlarmReset(), std::error_code());
    ASSERT_EQ(client->StreamTrajectory(Ramp(sim_->state().joints, 20), Stepping(nullptr), nullptr,
                                       {}, &report),
              std::error_code())
        << report.message;
  }
}

TEST_P(WeldRobotClientTest, RobotThatStopsAnsweringTimesOutWithinBounds) {
  StartSim(true);  // the robot keeps executing what it has while it does not answer
  auto client = Connect(",timeout_ms=200,retries=1");
  PrepareToWeld(*client);
  WeldStreamReport report;
  const auto start = std::chrono::steady_clock::now();
  std::error_code ec = client->StreamTrajectory(
      Trajectory(),
      [&, injected = false](const WeldStreamProgress& p) mutable {
        if (!injected && p.sent >= 60) {
          injected = true;
          sim_->StopAnswering(milliseconds::max());
        }
      },
      nullptr, {}, &report);
  const auto elapsed = std::chrono::steady_clock::now() - start;
  EXPECT_EQ(ec, Errc::kTimeout);
  // Two attempts of 200 ms for the failed request, two for the STOP: far below this bound.
  EXPECT_LT(elapsed, std::chrono::seconds(15));
  EXPECT_THAT(report.message, HasSubstr(client->name()));
  EXPECT_THAT(report.message, HasSubstr("timed out"));
  EXPECT_FALSE(report.safe_state_confirmed);
  EXPECT_THAT(report.message, HasSubstr("could NOT be confirmed"));
  EXPECT_EQ(client->lifecycle(), common::DeviceLifecycle::kFault);
  // Meanwhile the robot ran its buffer empty, and the interlock put the arc out.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (sim_->state().motion == wr::MotionState::kMoving &&
         std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(milliseconds(5));
  }
  EXPECT_EQ(sim_->state().motion, wr::MotionState::kIdle);
  EXPECT_FALSE(sim_->state().arc_on);
  // It answers again: the host reaches the safe state.
  sim_->ResumeAnswering();
  EXPECT_EQ(client->Stop(), std::error_code());
  ExpectSafe();
  EXPECT_EQ(client->AlarmReset(), std::error_code());
  EXPECT_EQ(client->lifecycle(), common::DeviceLifecycle::kActive);
}

}  // namespace
}  // namespace kinevis::hal
