// The drive supervision every control loop shares (control/common/drive_supervisor.h), on real
// drives: two Rs485Drive hosts on an Rs485DriveBus talking Modbus RTU over a pty to the drive
// simulator, stepped with the host's waits. Faults are raised in the simulator, never faked on
// the host side.

#include "control/common/drive_supervisor.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <memory>
#include <stdexcept>
#include <string>

#include "hal/drive/rs485_drive.h"
#include "hal/mock/rs485_drive_sim.h"
#include "hal/serial/pty_pair.h"
#include "tests/utilities/sim_step_clock.h"

namespace kinevis::control {
namespace {

using namespace std::chrono_literals;
using ::testing::HasSubstr;
using ::testing::Not;

constexpr double kCountsPerUnit = 10000.0;  // counts per rad (or m)
// CSV (mode 9, bit 8) is not among the second drive's modes.
constexpr uint32_t kModesWithoutCsv = 0x38D & ~(1u << 8);

class Line {
 public:
  explicit Line(int timeout_ms = 30, uint32_t second_drive_modes = 0) {
    hal::Rs485DriveSim::Options o;
    o.drives.clear();
    for (int unit : {1, 2}) {
      hal::Rs485DriveSim::DriveOptions d;
      d.unit = unit;
      if (unit == 2 && second_drive_modes != 0) d.device.supported_modes = second_drive_modes;
      o.drives.push_back(d);
    }
    sim_ =
        std::make_unique<hal::Rs485DriveSim>(pty_.master_fd(), pty_.slave_path(), &clock_.time, o);
    clock_.sim = sim_.get();
    hal::Rs485DriveBusOptions b;
    b.clock = &clock_;
    b.cycle_period = 1000us;
    b.max_missed_cycles = 3;
    bus_ = std::make_unique<hal::Rs485DriveBus>(
        sim_->backend() + ",timeout_ms=" + std::to_string(timeout_ms) + ",retries=0", b);
    for (int unit : {1, 2}) {
      hal::Rs485DriveConfig c;
      c.unit = unit;
      c.drive.name = "arm" + std::to_string(unit);
      c.drive.scaling.position_counts_per_unit = kCountsPerUnit;
      c.drive.scaling.velocity_counts_per_unit = kCountsPerUnit;
      c.drive.mode = hal::DriveMode::kCyclicSynchronousPosition;
      c.drive.command_timeout = 1000ms;
      bus_->AddDrive(c);
    }
    bus_->ConfigureAll();
    EXPECT_FALSE(bus_->EnableAll(1000ms));
  }
  ~Line() { sim_->Stop(); }

  DriveSupervisor Supervisor(DriveSupervisorOptions o = {}) {
    return DriveSupervisor(bus_.get(), &clock_, 2, o);
  }
  hal::Rs485DriveSim& sim() { return *sim_; }
  hal::Rs485DriveBus& bus() { return *bus_; }
  kinevis::testing::SimStepClock& clock() { return clock_; }

 private:
  hal::PtyPair pty_;
  kinevis::testing::SimStepClock clock_;
  std::unique_ptr<hal::Rs485DriveSim> sim_;
  std::unique_ptr<hal::Rs485DriveBus> bus_;
};

// Cycles at 1 ms with the drives' targets as they are.
void RunCycles(DriveSupervisor* s, kinevis::testing::SimStepClock* clock, int n) {
  for (int k = 0; k < n; ++k) {
    clock->SleepUntil(clock->Now() + 1ms);
    ASSERT_FALSE(s->Cycle().fault) << s->DriveFaults();
  }
}

// Cycles at 1 ms until the supervisor sees a fault (at most 20 cycles); the last cycle.
SupervisedCycle CycleUntilFault(DriveSupervisor* s, kinevis::testing::SimStepClock* clock) {
  SupervisedCycle cycle;
  for (int k = 0; k < 20 && !cycle.fault; ++k) {
    clock->SleepUntil(clock->Now() + 1ms);
    cycle = s->Cycle();
  }
  return cycle;
}

TEST(DriveSupervisorTest, SelectingTheModeNeverMovesTheAxes) {
  Line line;
  DriveSupervisor s = line.Supervisor();
  // Move drive 1 away from zero first, so that "where it is" is not the default target.
  ASSERT_EQ(s.SelectMode(hal::DriveMode::kCyclicSynchronousPosition), "");
  ASSERT_FALSE(line.bus().drives()[0]->SetTargetPosition(0.05));
  RunCycles(&s, &line.clock(), 300);
  double before[2];
  s.Positions(before);
  ASSERT_NEAR(before[0], 0.05, 1e-3);
  // Selecting CSV starts at zero velocity, CSP again at the current position: no motion.
  ASSERT_EQ(s.SelectMode(hal::DriveMode::kCyclicSynchronousVelocity), "");
  RunCycles(&s, &line.clock(), 100);
  ASSERT_EQ(s.SelectMode(hal::DriveMode::kCyclicSynchronousPosition), "");
  RunCycles(&s, &line.clock(), 100);
  double after[2];
  s.Positions(after);
  for (int i = 0; i < 2; ++i) {
    EXPECT_NEAR(after[i], before[i], 2.0 / kCountsPerUnit) << "drive " << i;
    EXPECT_EQ(line.bus().drives()[i]->status().mode, hal::DriveMode::kCyclicSynchronousPosition);
  }
  EXPECT_TRUE(s.AllAtRest());
}

TEST(DriveSupervisorTest, AModeADriveDoesNotListIsRefusedNamingTheDrive) {
  Line line(30, kModesWithoutCsv);
  DriveSupervisor s = line.Supervisor();
  int failed = -7;
  const std::string message = s.SelectMode(hal::DriveMode::kCyclicSynchronousVelocity, &failed);
  EXPECT_EQ(failed, 1);
  EXPECT_THAT(message, HasSubstr("joint 2 drive arm2"));
  EXPECT_THAT(message, HasSubstr("cannot select"));
}

TEST(DriveSupervisorTest, ADeviceFaultIsAFaultNamingTheDriveTheCodeAndTheTime) {
  Line line;
  DriveSupervisorOptions o;
  o.axis_name = "leg";
  o.first_axis_number = 0;
  DriveSupervisor s = line.Supervisor(o);
  ASSERT_EQ(s.SelectMode(hal::DriveMode::kCyclicSynchronousPosition), "");
  RunCycles(&s, &line.clock(), 10);
  line.sim().RaiseFault(2, 0x2310);  // over-current on unit 2, i.e. drive index 1
  const SupervisedCycle cycle = CycleUntilFault(&s, &line.clock());
  ASSERT_TRUE(cycle.fault);
  int faulted = -7;
  const std::string message = s.FaultMessage(cycle, 1.25, &faulted);
  EXPECT_EQ(faulted, 1);
  EXPECT_THAT(message, HasSubstr("drive fault at t = 1.25 s (bus "));
  // The drive's name carries its line and unit: "arm2 (modbus-rtu:... unit 2)".
  EXPECT_THAT(message, HasSubstr("leg 1 drive arm2 ("));
  EXPECT_THAT(message, HasSubstr("unit 2): device fault, error code 0x2310"));
  EXPECT_THAT(message, Not(HasSubstr("unit 1)")));
}

TEST(DriveSupervisorTest, LateCyclesAreToleratedUpToTheLimitThenAFaultThatSaysSo) {
  Line line;
  DriveSupervisorOptions o;
  o.max_consecutive_cycle_timeouts = 1;
  DriveSupervisor s = line.Supervisor(o);
  ASSERT_EQ(s.SelectMode(hal::DriveMode::kCyclicSynchronousPosition), "");
  RunCycles(&s, &line.clock(), 5);
  line.sim().StopAnswering(1, true);
  // First late cycle: tolerated. Second in a row: a fault, before the bus's own link supervision
  // (3 missed exchanges) declares the link lost.
  line.clock().SleepUntil(line.clock().Now() + 1ms);
  const SupervisedCycle first = s.Cycle();
  EXPECT_TRUE(first.late);
  EXPECT_FALSE(first.fault);
  line.clock().SleepUntil(line.clock().Now() + 1ms);
  const SupervisedCycle second = s.Cycle();
  EXPECT_TRUE(second.late);
  ASSERT_TRUE(second.fault);
  EXPECT_EQ(s.cycle_timeouts(), 2u);
  EXPECT_EQ(s.consecutive_timeouts(), 2);
  EXPECT_THAT(s.FaultMessage(second, 0.5),
              HasSubstr("2 cycles in a row without every drive's answer"));
  // Answering again: the count starts over.
  line.sim().StopAnswering(1, false);
  line.clock().SleepUntil(line.clock().Now() + 1ms);
  const SupervisedCycle back = s.Cycle();
  EXPECT_FALSE(back.late);
  EXPECT_EQ(s.consecutive_timeouts(), 0);
  EXPECT_EQ(s.cycle_timeouts(), 2u);
  // A new run starts counting from zero.
  s.ResetCounts();
  EXPECT_EQ(s.cycle_timeouts(), 0u);
}

TEST(DriveSupervisorTest, ALostLinkNamesTheDriveAndCarriesTheDrivesOwnCause) {
  Line line;
  DriveSupervisorOptions o;
  o.max_consecutive_cycle_timeouts = 100;  // leave it to the bus's link supervision
  DriveSupervisor s = line.Supervisor(o);
  ASSERT_EQ(s.SelectMode(hal::DriveMode::kCyclicSynchronousPosition), "");
  RunCycles(&s, &line.clock(), 5);
  line.sim().StopAnswering(2, true);
  const SupervisedCycle cycle = CycleUntilFault(&s, &line.clock());
  ASSERT_TRUE(cycle.fault);
  int faulted = -7;
  const std::string faults = s.DriveFaults(&faulted);
  EXPECT_EQ(faulted, 1);
  EXPECT_THAT(faults, HasSubstr("joint 2 drive arm2 ("));
  EXPECT_THAT(faults, HasSubstr("unit 2): link lost"));
  EXPECT_THAT(faults, HasSubstr("consecutive exchanges failed"));  // the drive's own text
}

TEST(DriveSupervisorTest, SafeStopBringsMovingDrivesToRestOutOfOperation) {
  for (const StopAction action : {StopAction::kQuickStop, StopAction::kDisable}) {
    SCOPED_TRACE(ToString(action));
    Line line;
    DriveSupervisorOptions o;
    o.stop_action = action;
    DriveSupervisor s = line.Supervisor(o);
    ASSERT_EQ(s.SelectMode(hal::DriveMode::kCyclicSynchronousVelocity), "");
    for (hal::MotorDrive* d : line.bus().drives()) ASSERT_FALSE(d->SetTargetVelocity(0.5));
    RunCycles(&s, &line.clock(), 200);
    ASSERT_FALSE(s.AllAtRest());
    EXPECT_EQ(s.SafeStop(), "");
    for (hal::MotorDrive* d : line.bus().drives()) {
      EXPECT_NE(d->lifecycle(), common::DeviceLifecycle::kActive) << d->name();
      EXPECT_LT(std::abs(d->status().velocity), 1e-6) << d->name();
    }
    // At rest for good: the simulated axes do not move on.
    double p0[2], p1[2];
    s.Positions(p0);
    for (int k = 0; k < 100; ++k) {
      line.clock().SleepUntil(line.clock().Now() + 1ms);
      line.bus().Cycle();
    }
    s.Positions(p1);
    EXPECT_NEAR(p1[0], p0[0], 1.0 / kCountsPerUnit);
    EXPECT_NEAR(p1[1], p0[1], 1.0 / kCountsPerUnit);
  }
}

TEST(DriveSupervisorTest, SettleCyclesAtThePeriodUntilTheStepSaysItIsDone) {
  Line line;
  DriveSupervisorOptions o;
  o.cycle_period_s = 0.002;
  DriveSupervisor s = line.Supervisor(o);
  ASSERT_EQ(s.SelectMode(hal::DriveMode::kCyclicSynchronousPosition), "");
  const common::Duration start = line.clock().Now();
  int steps = 0;
  EXPECT_TRUE(s.Settle([&] { return ++steps <= 25; }));
  EXPECT_EQ(steps, 26);
  EXPECT_NEAR(common::ToSeconds(line.clock().Now() - start), 25 * 0.002, 1e-9);
  // A step that never finishes ends at settle_timeout_s.
  const common::Duration again = line.clock().Now();
  EXPECT_TRUE(s.Settle([] { return true; }));
  EXPECT_NEAR(common::ToSeconds(line.clock().Now() - again), o.settle_timeout_s, 0.0021);
}

TEST(DriveSupervisorTest, BadArgumentsAreNamed) {
  Line line;
  try {
    DriveSupervisor s(&line.bus(), &line.clock(), 6);
    FAIL() << "six drives expected, two on the bus";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), HasSubstr("has 2 drives, expected 6"));
  }
  EXPECT_THROW(DriveSupervisor(nullptr, &line.clock(), 2), std::invalid_argument);
  DriveSupervisorOptions o;
  o.cycle_period_s = 0;
  o.max_consecutive_cycle_timeouts = -1;
  o.settle_timeout_s = -2;
  const std::string message = o.Validate();
  EXPECT_THAT(message, HasSubstr("cycle_period_s"));
  EXPECT_THAT(message, HasSubstr("max_consecutive_cycle_timeouts"));
  EXPECT_THAT(message, HasSubstr("settle_timeout_s"));
  EXPECT_THROW(DriveSupervisor(&line.bus(), &line.clock(), 2, o), std::invalid_argument);
}

}  // namespace
}  // namespace kinevis::control
