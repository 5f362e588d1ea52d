#include "hal/mock/cia402_device.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <vector>

#include "hal/common/error.h"
#include "tests/hal/drive/cia402_spec_table.h"

namespace kinevis::hal {
namespace {

using S = Cia402State;
using C = Cia402Command;

constexpr double kCycle = 0.001;

Cia402Device::Options TestOptions() {
  Cia402Device::Options o;
  o.limits.max_velocity = 100000;
  o.limits.max_acceleration = 1000000;
  o.limits.min_position = -1e7;
  o.limits.max_position = 1e7;
  o.fault_reaction_time_s = 0.01;
  o.following_error_window = 10000;
  return o;
}

void Send(Cia402Device& d, C command) { d.SetControlword(Cia402Controlword(command)); }

// Brings a fresh device into `state` by the host commands and device events a real drive sees.
void BringTo(Cia402Device& d, S state) {
  if (state == S::kNotReadyToSwitchOn) return;
  d.Step(0);  // transition 1
  if (state == S::kSwitchOnDisabled) return;
  if (state == S::kFault || state == S::kFaultReactionActive) {
    BringTo(d, S::kOperationEnabled);
    d.RaiseFault(0x2310);
    if (state == S::kFault) d.Step(0.02);
    return;
  }
  Send(d, C::kShutdown);
  if (state == S::kReadyToSwitchOn) return;
  Send(d, C::kSwitchOn);
  if (state == S::kSwitchedOn) return;
  Send(d, C::kEnableOperation);
  if (state == S::kOperationEnabled) return;
  Send(d, C::kQuickStop);  // kQuickStopActive
}

void Enable(Cia402Device& d, DriveMode mode) {
  ASSERT_TRUE(d.SetModeOfOperation(static_cast<int8_t>(mode)));
  BringTo(d, S::kOperationEnabled);
  ASSERT_EQ(d.state(), S::kOperationEnabled);
}

// A CSP trajectory with integer set-points every 2 ms, within the drive's limits: accelerates
// at 500000 counts/s^2 (increments of 1, 3, ..., 49 counts per cycle), cruises at 25000
// counts/s (50 per cycle) and decelerates symmetrically to rest at 6250 counts.
std::vector<int32_t> Trajectory() {
  std::vector<int32_t> p{0};
  for (int i = 1; i <= 25; ++i) p.push_back(p.back() + 2 * i - 1);
  for (int i = 0; i < 100; ++i) p.push_back(p.back() + 50);
  for (int i = 25; i >= 1; --i) p.push_back(p.back() + 2 * i - 1);
  return p;
}

TEST(Cia402DeviceTest, EveryRowOfTheTransitionTable) {
  for (const Cia402Transition& row : kCia402Transitions) {
    SCOPED_TRACE(::testing::Message()
                 << "transition " << row.number << ": " << ToString(row.from) << " --"
                 << ToString(row.command) << "--> " << ToString(row.to));
    Cia402Device::Options options = TestOptions();
    // Transition 16 exists with quick stop option codes 5..8 only.
    if (row.number == 16) options.quick_stop_option_code = 6;
    Cia402Device d(options);
    BringTo(d, row.from);
    ASSERT_EQ(d.state(), row.from);
    if (!row.automatic) {
      Send(d, row.command);
    } else if (row.number == 1) {
      d.Step(0);
    } else if (row.number == 12) {
      d.Step(kCycle);  // at rest already: the quick stop is complete at once
    } else if (row.number == 13) {
      d.RaiseFault(0x5530);
    } else if (row.number == 14) {
      d.Step(options.fault_reaction_time_s);
    } else {
      FAIL() << "no trigger for automatic transition " << row.number;
    }
    EXPECT_EQ(d.state(), row.to);
    EXPECT_EQ(DecodeCia402Statusword(d.statusword()), row.to);
  }
}

// The simulator against the specification's tables (cia402_spec_table.h, not the library's
// kCia402Transitions): every state a host can reach, every controlword with bit 7 clear, both
// quick stop option regimes; the state is read back through the statusword as a host would.
TEST(Cia402DeviceTest, EveryControlwordInEveryStateAsTheSpecificationSays) {
  for (S from : {S::kSwitchOnDisabled, S::kReadyToSwitchOn, S::kSwitchedOn, S::kOperationEnabled,
                 S::kQuickStopActive, S::kFault}) {
    for (bool resume : {false, true}) {
      for (uint16_t cw = 0; cw < 16; ++cw) {
        Cia402Device::Options options = TestOptions();
        options.quick_stop_option_code = resume ? 6 : 2;
        Cia402Device d(options);
        BringTo(d, from);
        ASSERT_EQ(d.state(), from);
        d.SetControlword(cw);
        const S expected = spec::After(from, spec::Classify(cw), resume).value_or(from);
        EXPECT_EQ(DecodeCia402Statusword(d.statusword()), expected)
            << spec::Describe(from, cw, resume);
      }
    }
  }
}

TEST(Cia402DeviceTest, StatuswordOfEveryState) {
  struct Expected {
    S state;
    uint16_t mask, value;
  };
  const Expected expected[] = {
      {S::kNotReadyToSwitchOn, 0x4F, 0x00},  {S::kSwitchOnDisabled, 0x4F, 0x40},
      {S::kReadyToSwitchOn, 0x6F, 0x21},     {S::kSwitchedOn, 0x6F, 0x23},
      {S::kOperationEnabled, 0x6F, 0x27},    {S::kQuickStopActive, 0x6F, 0x07},
      {S::kFaultReactionActive, 0x4F, 0x0F}, {S::kFault, 0x4F, 0x08},
  };
  for (const Expected& e : expected) {
    Cia402Device d(TestOptions());
    BringTo(d, e.state);
    ASSERT_EQ(d.state(), e.state) << ToString(e.state);
    const uint16_t sw = d.statusword();
    EXPECT_EQ(sw & e.mask, e.value) << ToString(e.state) << " statusword 0x" << std::hex << sw;
    EXPECT_NE(sw & cia402::kSwRemote, 0) << ToString(e.state);
    EXPECT_EQ(d.snapshot().statusword, sw);
  }
}

TEST(Cia402DeviceTest, AFaultInAnyStateGoesThroughFaultReaction) {
  for (S from : {S::kSwitchOnDisabled, S::kReadyToSwitchOn, S::kSwitchedOn, S::kQuickStopActive}) {
    Cia402Device d(TestOptions());
    BringTo(d, from);
    d.RaiseFault(0x4310);
    EXPECT_EQ(d.state(), S::kFaultReactionActive) << ToString(from);
    EXPECT_EQ(d.error_code(), 0x4310);
    d.Step(0.005);
    EXPECT_EQ(d.state(), S::kFaultReactionActive) << "the reaction takes 10 ms";
    d.Step(0.005);
    EXPECT_EQ(d.state(), S::kFault) << ToString(from);
  }
}

TEST(Cia402DeviceTest, FaultReportsItsCodeOnceAndResetReportsZero) {
  Cia402Device d(TestOptions());
  Enable(d, DriveMode::kCyclicSynchronousVelocity);
  std::vector<uint16_t> reported;
  d.SetFaultCallback([&reported](uint16_t code) { reported.push_back(code); });
  d.RaiseFault(0x3210);
  d.RaiseFault(0x4310);  // a second fault during the reaction does not replace the first
  for (int i = 0; i < 30; ++i) d.Step(kCycle);
  EXPECT_EQ(d.state(), S::kFault);
  EXPECT_EQ(d.error_code(), 0x3210);
  ASSERT_EQ(reported, std::vector<uint16_t>{0x3210});

  // Rising edge of bit 7 (the previous word was 0x0F): fault reset.
  d.SetControlword(0x80);
  EXPECT_EQ(d.state(), S::kSwitchOnDisabled);
  ASSERT_EQ(reported, (std::vector<uint16_t>{0x3210, 0}));
  EXPECT_EQ(d.error_code(), 0);

  d.RaiseFault(0x3210);
  for (int i = 0; i < 30; ++i) d.Step(kCycle);
  d.SetControlword(0x80);  // 0x80 -> 0x80: not an edge
  EXPECT_EQ(d.state(), S::kFault);
  d.SetControlword(0x00);
  d.SetControlword(0x80);
  EXPECT_EQ(d.state(), S::kSwitchOnDisabled);
}

TEST(Cia402DeviceTest, FollowingErrorBeyondTheWindowFaults8611) {
  Cia402Device d(TestOptions());
  Enable(d, DriveMode::kCyclicSynchronousPosition);
  std::vector<uint16_t> reported;
  d.SetFaultCallback([&reported](uint16_t code) { reported.push_back(code); });
  // A set-point step beyond the window: the demand jumps, the axis cannot.
  d.SetTargetPosition(50000);
  d.Step(kCycle);
  EXPECT_EQ(d.state(), S::kFaultReactionActive);
  EXPECT_EQ(d.error_code(), 0x8611);
  EXPECT_NE(d.statusword() & cia402::kSwFollowingError, 0);
  for (int i = 0; i < 20; ++i) d.Step(kCycle);
  EXPECT_EQ(d.state(), S::kFault);
  EXPECT_EQ(reported, std::vector<uint16_t>{0x8611});
}

TEST(Cia402DeviceTest, FollowingErrorWindowDisabledNeverFaults) {
  Cia402Device::Options o = TestOptions();
  o.following_error_window = 0xFFFFFFFFu;
  Cia402Device d(o);
  Enable(d, DriveMode::kCyclicSynchronousPosition);
  d.SetTargetPosition(50000);
  for (int i = 0; i < 1000; ++i) d.Step(kCycle);
  EXPECT_EQ(d.state(), S::kOperationEnabled);
  EXPECT_EQ(d.position(), 50000);
}

TEST(Cia402DeviceTest, CspTracksOneSetPointPerCycleWithoutFollowingError) {
  Cia402Device d(TestOptions());
  Enable(d, DriveMode::kCyclicSynchronousPosition);
  const std::vector<int32_t> trajectory = Trajectory();
  int worst = 0;
  bool follows = true;
  for (size_t i = 1; i < trajectory.size(); ++i) {
    d.SetTargetPosition(trajectory[i]);
    d.Step(0.002);
    worst = std::max(worst, std::abs(d.following_error()));
    ASSERT_EQ(d.position(), trajectory[i]) << "cycle " << i;
    if (i == 60) {
      EXPECT_NEAR(d.velocity(), 25000, 1);
    }
    follows = follows && (d.statusword() & cia402::kSwOpModeSpecific12) != 0;
  }
  d.Step(0.002);
  EXPECT_EQ(d.state(), S::kOperationEnabled);
  EXPECT_LE(worst, 1);
  EXPECT_TRUE(follows);  // statusword bit 12: the drive follows the command value
  EXPECT_EQ(d.position(), 6250);
  EXPECT_EQ(d.velocity(), 0);
}

TEST(Cia402DeviceTest, CspInterpolatesSetPointsSlowerThanTheSteps) {
  Cia402Device d(TestOptions());
  Enable(d, DriveMode::kCyclicSynchronousPosition);
  const std::vector<int32_t> trajectory = Trajectory();
  int worst = 0;
  for (size_t i = 1; i < trajectory.size(); ++i) {
    d.SetTargetPosition(trajectory[i]);  // every 2 ms, stepped every 0.5 ms
    for (int k = 0; k < 4; ++k) {
      d.Step(0.0005);
      worst = std::max(worst, std::abs(d.following_error()));
    }
  }
  for (int i = 0; i < 100; ++i) d.Step(0.0005);
  EXPECT_EQ(d.state(), S::kOperationEnabled);
  EXPECT_LE(worst, 50);
  EXPECT_EQ(d.position(), 6250);
  EXPECT_EQ(d.velocity(), 0);
}

TEST(Cia402DeviceTest, ProfilePositionNeedsTheNewSetPointEdge) {
  Cia402Device d(TestOptions());
  Enable(d, DriveMode::kProfilePosition);
  d.SetProfile(20000, 200000);
  d.SetTargetPosition(4000);
  for (int i = 0; i < 100; ++i) d.Step(kCycle);
  EXPECT_EQ(d.position(), 0) << "no new set-point yet";
  d.SetControlword(0x1F);                                      // enable operation + new set-point
  EXPECT_NE(d.statusword() & cia402::kSwOpModeSpecific12, 0);  // set-point acknowledge
  d.Step(kCycle);
  EXPECT_EQ(d.statusword() & cia402::kSwTargetReached, 0);
  d.SetControlword(0x0F);
  EXPECT_EQ(d.statusword() & cia402::kSwOpModeSpecific12, 0);
  for (int i = 0; i < 1000; ++i) d.Step(kCycle);
  EXPECT_EQ(d.position(), 4000);
  EXPECT_NE(d.statusword() & cia402::kSwTargetReached, 0);
}

TEST(Cia402DeviceTest, HaltStopsAProfileVelocityMove) {
  Cia402Device d(TestOptions());
  Enable(d, DriveMode::kProfileVelocity);
  d.SetProfile(0, 500000);
  d.SetTargetVelocity(30000);
  for (int i = 0; i < 100; ++i) d.Step(kCycle);
  EXPECT_EQ(d.velocity(), 30000);
  EXPECT_NE(d.statusword() & cia402::kSwTargetReached, 0);
  d.SetControlword(0x0F | cia402::kCwHalt);
  for (int i = 0; i < 100; ++i) d.Step(kCycle);
  EXPECT_EQ(d.velocity(), 0);
  EXPECT_EQ(d.state(), S::kOperationEnabled);
  EXPECT_NE(d.statusword() & cia402::kSwTargetReached, 0);
}

TEST(Cia402DeviceTest, TorqueModeFollowsTheTorqueSetPoint) {
  Cia402Device::Options o = TestOptions();
  o.limits.inertia = 100;
  Cia402Device d(o);
  Enable(d, DriveMode::kCyclicSynchronousTorque);
  d.SetTargetTorque(200);
  for (int i = 0; i < 100; ++i) d.Step(kCycle);
  EXPECT_EQ(d.torque(), 200);
  EXPECT_EQ(d.velocity(), 2000);  // 200 * 100 counts/s^2 for 0.1 s
}

TEST(Cia402DeviceTest, QuickStopRampsDownThenDisables) {
  Cia402Device d(TestOptions());
  Enable(d, DriveMode::kCyclicSynchronousVelocity);
  d.SetTargetVelocity(80000);
  for (int i = 0; i < 200; ++i) d.Step(kCycle);
  ASSERT_EQ(d.velocity(), 80000);
  Send(d, C::kQuickStop);
  EXPECT_EQ(d.state(), S::kQuickStopActive);
  int steps = 0;
  int previous = d.velocity();
  while (d.state() == S::kQuickStopActive && steps < 1000) {
    d.Step(kCycle);
    ++steps;
    const int v = d.velocity();
    EXPECT_LE(v, previous);
    EXPECT_LE(previous - v, 1000) << "quick stop ramp is the acceleration limit";
    previous = v;
  }
  EXPECT_EQ(steps, 80);  // 80000 counts/s at 1e6 counts/s^2
  EXPECT_EQ(d.state(), S::kSwitchOnDisabled);
  EXPECT_EQ(d.velocity(), 0);
}

TEST(Cia402DeviceTest, SlowDownRampAndStayingInQuickStop) {
  Cia402Device::Options o = TestOptions();
  o.quick_stop_option_code = 5;  // slow down ramp, stay in quick stop active
  Cia402Device d(o);
  Enable(d, DriveMode::kCyclicSynchronousVelocity);
  d.SetProfile(0, 100000);
  d.SetTargetVelocity(20000);
  for (int i = 0; i < 100; ++i) d.Step(kCycle);
  Send(d, C::kQuickStop);
  int steps = 0;
  while (d.velocity() != 0 && steps < 1000) {
    d.Step(kCycle);
    ++steps;
  }
  EXPECT_EQ(steps, 200);  // 20000 counts/s at the profile's 100000 counts/s^2
  d.Step(kCycle);
  EXPECT_EQ(d.state(), S::kQuickStopActive);
  EXPECT_NE(d.statusword() & cia402::kSwTargetReached, 0);
  Send(d, C::kEnableOperation);  // transition 16
  EXPECT_EQ(d.state(), S::kOperationEnabled);
}

TEST(Cia402DeviceTest, PositionLimitInVelocityModeFaults8612) {
  Cia402Device d(TestOptions());
  Enable(d, DriveMode::kCyclicSynchronousVelocity);
  d.SetPositionLimits(-1000, 5000);
  d.SetTargetVelocity(50000);
  for (int i = 0; i < 500 && d.state() == S::kOperationEnabled; ++i) d.Step(kCycle);
  EXPECT_EQ(d.state(), S::kFaultReactionActive);
  EXPECT_EQ(d.error_code(), 0x8612);
  for (int i = 0; i < 500; ++i) d.Step(kCycle);
  EXPECT_EQ(d.state(), S::kFault);
  EXPECT_LE(d.position(), 5000);
}

TEST(Cia402DeviceTest, PositionTargetBeyondALimitIsClampedWithInternalLimitBit) {
  Cia402Device d(TestOptions());
  Enable(d, DriveMode::kProfilePosition);
  d.SetPositionLimits(-1000, 3000);
  d.SetTargetPosition(9000);
  d.SetControlword(0x1F);
  bool internal_limit = false;
  for (int i = 0; i < 1000; ++i) {
    d.Step(kCycle);
    internal_limit = internal_limit || (d.statusword() & cia402::kSwInternalLimit) != 0;
  }
  EXPECT_EQ(d.state(), S::kOperationEnabled);
  EXPECT_EQ(d.position(), 3000);
  EXPECT_TRUE(internal_limit);
  // Ignored: min > max.
  d.SetPositionLimits(10, 0);
  EXPECT_EQ(d.snapshot().position_limit_min, -1000);
}

TEST(Cia402DeviceTest, PlantHookIsTheActualAndCanCauseAFollowingError) {
  Cia402Device d(TestOptions());
  std::vector<double> commanded;
  double plant_position = 0;
  bool blocked = false;
  d.SetPlantHook([&](const AxisState& c, double dt) {
    EXPECT_DOUBLE_EQ(dt, kCycle);
    commanded.push_back(c.position);
    if (!blocked) plant_position = c.position;
    PlantFeedback fb;
    fb.position = static_cast<int32_t>(std::lround(plant_position));
    fb.velocity = blocked ? 0 : static_cast<int32_t>(std::lround(c.velocity));
    fb.torque = 77;
    return fb;
  });
  ASSERT_TRUE(d.SetModeOfOperation(static_cast<int8_t>(DriveMode::kCyclicSynchronousPosition)));
  BringTo(d, S::kOperationEnabled);
  for (int i = 1; i <= 100; ++i) {
    d.SetTargetPosition(i * 20);
    d.Step(kCycle);
  }
  EXPECT_EQ(d.position(), 2000);
  EXPECT_EQ(d.torque(), 77);  // the plant's, not the model's
  EXPECT_EQ(commanded.size(), 100u);
  // The leg jams: the demand runs on, the actual stays; past the window the drive faults.
  blocked = true;
  int cycles = 0;
  for (int i = 101; d.state() == S::kOperationEnabled && i < 2000; ++i, ++cycles) {
    d.SetTargetPosition(i * 20);
    d.Step(kCycle);
  }
  EXPECT_EQ(d.state(), S::kFaultReactionActive);
  EXPECT_EQ(d.error_code(), 0x8611);
  EXPECT_EQ(d.position(), 2000);
  EXPECT_NEAR(cycles, 10000 / 20, 2);  // window 10000 counts at 20 counts per cycle
}

TEST(Cia402DeviceTest, PowerOffStatesHoldTheAxisAndFollowThePlant) {
  Cia402Device d(TestOptions());
  Enable(d, DriveMode::kCyclicSynchronousVelocity);
  d.SetTargetVelocity(50000);
  for (int i = 0; i < 100; ++i) d.Step(kCycle);
  Send(d, C::kDisableVoltage);
  for (int i = 0; i < 100; ++i) d.Step(kCycle);
  EXPECT_EQ(d.velocity(), 0);  // braked to standstill with the acceleration limit
  // With a plant, the drive reports what the plant does while disabled (gravity, a push).
  d.SetPlantHook([](const AxisState&, double) { return PlantFeedback{123456, 0, 0}; });
  d.Step(kCycle);
  EXPECT_EQ(d.position(), 123456);
  EXPECT_DOUBLE_EQ(d.commanded().position, 123456);
}

TEST(Cia402DeviceTest, ModesOfOperation) {
  Cia402Device::Options o = TestOptions();
  o.supported_modes = 0x180;  // CSP and CSV only
  Cia402Device d(o);
  EXPECT_EQ(d.mode_display(), 8);  // default: CSP, matching the default PDO mapping
  EXPECT_TRUE(d.SetModeOfOperation(9));
  EXPECT_EQ(d.mode_display(), 9);
  EXPECT_FALSE(d.SetModeOfOperation(1));  // not supported by this drive
  EXPECT_FALSE(d.SetModeOfOperation(6));  // homing: not a mode the simulator has
  EXPECT_FALSE(d.SetModeOfOperation(0));
  EXPECT_EQ(d.mode_display(), 9);
  EXPECT_EQ(d.snapshot().supported_modes, 0x180u);
  // Bits of modes the simulator does not implement are left out of 0x6502.
  Cia402Device::Options wide = TestOptions();
  wide.supported_modes = 0x3ED;
  EXPECT_EQ(Cia402Device(wide).snapshot().supported_modes, 0x38Du);
}

TEST(Cia402DeviceTest, ParametersAndTheirRanges) {
  Cia402Device d(TestOptions());
  EXPECT_TRUE(d.SetQuickStopOptionCode(6));
  EXPECT_FALSE(d.SetQuickStopOptionCode(9));
  EXPECT_FALSE(d.SetQuickStopOptionCode(-1));
  EXPECT_FALSE(d.SetMaxVelocity(0));
  EXPECT_TRUE(d.SetMaxVelocity(1234));
  d.SetFollowingErrorWindow(55);
  const Cia402Device::Snapshot s = d.snapshot();
  EXPECT_EQ(s.quick_stop_option_code, 6);
  EXPECT_EQ(s.max_velocity, 1234u);
  EXPECT_EQ(s.following_error_window, 55u);
}

TEST(Cia402DeviceTest, ResetIsPowerOnButKeepsThePosition) {
  Cia402Device d(TestOptions());
  Enable(d, DriveMode::kCyclicSynchronousVelocity);
  d.SetTargetVelocity(10000);
  for (int i = 0; i < 200; ++i) d.Step(kCycle);
  d.RaiseFault(0x1000);
  for (int i = 0; i < 200; ++i) d.Step(kCycle);
  const int32_t position = d.position();
  ASSERT_NE(position, 0);
  d.Reset();
  EXPECT_EQ(d.state(), S::kNotReadyToSwitchOn);
  EXPECT_EQ(d.error_code(), 0);
  EXPECT_EQ(d.mode_display(), 8);
  EXPECT_EQ(d.position(), position);
  EXPECT_EQ(d.snapshot().target_position, position);  // enabling CSP now holds the axis
  BringTo(d, S::kOperationEnabled);
  d.Step(kCycle);
  EXPECT_EQ(d.state(), S::kOperationEnabled);
}

TEST(Cia402DeviceTest, BadOptionsThrowNamingEachProblem) {
  Cia402Device::Options o = TestOptions();
  o.limits.max_velocity = -1;
  o.quick_stop_option_code = 12;
  o.supported_modes = 0x20;
  try {
    Cia402Device d(o);
    FAIL() << "no exception";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(std::string(e.what()), ::testing::ContainsRegex("max_velocity -1"));
    EXPECT_THAT(std::string(e.what()), ::testing::ContainsRegex("quick_stop_option_code 12"));
    EXPECT_THAT(std::string(e.what()), ::testing::ContainsRegex("supported_modes 0x20"));
  }
}

}  // namespace
}  // namespace kinevis::hal
