#include "hal/drive/rs485_drive.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "common/units.h"
#include "hal/common/error.h"
#include "hal/drive/rs485_drive_registers.h"
#include "hal/mock/rs485_drive_sim.h"
#include "hal/modbus/modbus_client.h"
#include "hal/serial/pty_pair.h"

namespace kinevis::hal {
namespace {

using namespace std::chrono_literals;
using namespace rs485_drive;
using ::testing::ContainsRegex;
using ::testing::HasSubstr;
using ::testing::MatchesRegex;
using S = Cia402State;
using C = Cia402Command;

constexpr double kCountsPerRad = 10000.0 / (2 * common::kPi);

// Simulated time that passes only when the host sleeps on it; meanwhile the simulated drives
// are stepped. (The Modbus exchanges themselves run in real time on the pty.)
class ServicedClock final : public common::Clock {
 public:
  common::Duration Now() const override { return time_.Now(); }
  void SleepUntil(common::Duration deadline) override {
    while (time_.Now() < deadline) {
      time_.AdvanceTo(std::min(deadline, time_.Now() + common::Duration(500us)));
      for (const auto& service : services_) service();
    }
  }
  void AddService(std::function<void()> service) { services_.push_back(std::move(service)); }

 private:
  common::SimulatedClock time_;
  std::vector<std::function<void()>> services_;
};

Rs485DriveConfig DriveConfig(int unit) {
  Rs485DriveConfig c;
  c.unit = unit;
  c.drive.name = "arm" + std::to_string(unit);
  c.drive.scaling.position_counts_per_unit = kCountsPerRad;
  c.drive.scaling.velocity_counts_per_unit = kCountsPerRad;
  c.drive.scaling.torque_per_mille_per_unit = 50.0;
  c.drive.limits.min_position = -3.0;
  c.drive.limits.max_position = 3.0;
  c.drive.command_timeout = 200ms;
  c.watchdog = 100ms;
  return c;
}

class Rs485DriveTest : public ::testing::Test {
 protected:
  // link: the Modbus client's options; generous by default (the exchanges run in real time and
  // a loaded machine may not schedule the simulator's thread for a while).
  void MakeLine(std::vector<int> units, Rs485DriveBusOptions options = {},
                std::function<void(Rs485DriveSim::DriveOptions*)> tweak = {},
                const std::string& link = ",timeout_ms=500,retries=1") {
    Rs485DriveSim::Options sim_options;
    sim_options.drives.clear();
    for (int unit : units) {
      Rs485DriveSim::DriveOptions d;
      d.unit = unit;
      d.serial_number = 500 + static_cast<uint32_t>(unit);
      if (tweak) tweak(&d);
      sim_options.drives.push_back(d);
    }
    sim_ =
        std::make_unique<Rs485DriveSim>(pty_.master_fd(), pty_.slave_path(), &clock_, sim_options);
    clock_.AddService([this] { sim_->Step(); });
    options.clock = &clock_;
    // The simulator's own backend string (8E1): one ModbusClient serves the whole line.
    backend_ = sim_->backend() + link;
    bus_ = std::make_unique<Rs485DriveBus>(backend_, options);
    for (int unit : units) drives_.push_back(bus_->AddDrive(DriveConfig(unit)));
  }

  void Cycles(int n) {
    for (int i = 0; i < n; ++i) {
      clock_.SleepFor(2ms);
      bus_->Cycle();
    }
  }

  PtyPair pty_;
  ServicedClock clock_;
  std::unique_ptr<Rs485DriveSim> sim_;
  std::string backend_;
  std::unique_ptr<Rs485DriveBus> bus_;
  std::vector<Rs485Drive*> drives_;
};

TEST_F(Rs485DriveTest, ConfigureReadsTheIdentityAndSetsTheWatchdog) {
  MakeLine({3});
  Rs485Drive* drive = drives_[0];
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kUnconfigured);
  drive->Configure();
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kConfigured);
  EXPECT_EQ(drive->name(), "arm3 (" + backend_ + " unit 3)");
  EXPECT_THAT(backend_, ContainsRegex("^modbus-rtu:/dev/pts/[0-9]+@3000000,8E1,"));
  EXPECT_EQ(drive->identity().vendor_id, kSimulatorVendorId);
  EXPECT_EQ(drive->identity().product_code, 0x0485u);
  EXPECT_EQ(drive->identity().serial_number, 503u);
  EXPECT_EQ(drive->identity().supported_modes, 0x38Du);
  EXPECT_EQ(drive->status().state, S::kSwitchOnDisabled);
  uint16_t regs[2] = {0, 0};
  ASSERT_FALSE(drive->client().ReadHoldingRegisters(kRegWatchdogMs, 1, regs));
  EXPECT_EQ(regs[0], 100);
  ASSERT_FALSE(drive->client().ReadHoldingRegisters(kRegPositionLimitMax, 2, regs));
  EXPECT_EQ(static_cast<int32_t>(JoinHighFirst(regs[0], regs[1])),
            static_cast<int32_t>(std::lround(3.0 * kCountsPerRad)));
}

TEST_F(Rs485DriveTest, EnableAndFollowARampInCsp) {
  MakeLine({1});
  Rs485Drive* drive = drives_[0];
  drive->Configure();
  ASSERT_FALSE(drive->Enable(500ms)) << drive->last_error_text();
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kActive);
  EXPECT_EQ(sim_->device(1).state(), S::kOperationEnabled);
  const double start = drive->status().position;
  for (int i = 1; i <= 100; ++i) {
    ASSERT_FALSE(drive->SetTargetPosition(start + 0.5 * i / 100.0));
    clock_.SleepFor(2ms);
    ASSERT_FALSE(bus_->Cycle());
  }
  Cycles(10);
  EXPECT_EQ(sim_->device(1).snapshot().target_position,
            static_cast<int32_t>(std::lround((start + 0.5) * kCountsPerRad)));
  EXPECT_NEAR(drive->status().position, start + 0.5, 2.0 / kCountsPerRad);
  EXPECT_EQ(drive->status().mode, DriveMode::kCyclicSynchronousPosition);
  EXPECT_GE(drive->counters().cycles, 110u);
  EXPECT_EQ(drive->counters().timeouts, 0u);
  ASSERT_FALSE(drive->Disable());
  EXPECT_EQ(sim_->device(1).state(), S::kSwitchOnDisabled);
}

TEST_F(Rs485DriveTest, EveryTransitionTheHostCanCommandLeadsWhereTheTableSays) {
  MakeLine({1}, {}, [](Rs485DriveSim::DriveOptions* d) { d->device.quick_stop_option_code = 6; });
  Rs485Drive* drive = drives_[0];
  drive->Configure();
  std::function<void(S)> reach = [&](S state) {
    if (drive->lifecycle() == common::DeviceLifecycle::kFault ||
        drive->status().state == S::kFault) {
      ASSERT_FALSE(drive->FaultReset()) << drive->last_error_text();
    }
    switch (state) {
      case S::kSwitchOnDisabled:
        ASSERT_FALSE(drive->Disable()) << drive->last_error_text();
        break;
      case S::kReadyToSwitchOn:
        reach(S::kSwitchOnDisabled);
        ASSERT_FALSE(drive->SendCommand(C::kShutdown, 200ms));
        break;
      case S::kSwitchedOn:
        reach(S::kReadyToSwitchOn);
        ASSERT_FALSE(drive->SendCommand(C::kSwitchOn, 200ms));
        break;
      case S::kOperationEnabled:
        reach(S::kSwitchOnDisabled);
        ASSERT_FALSE(drive->Enable(500ms)) << drive->last_error_text();
        break;
      case S::kQuickStopActive:
        reach(S::kOperationEnabled);
        ASSERT_FALSE(drive->SendCommand(C::kQuickStop, 200ms));
        break;
      case S::kFault:
        reach(S::kSwitchOnDisabled);
        sim_->RaiseFault(1, 0x5530);
        for (int i = 0; i < 100 && drive->status().state != S::kFault; ++i) Cycles(1);
        break;
      default:
        FAIL() << "cannot reach " << ToString(state);
    }
    ASSERT_EQ(sim_->device(1).state(), state);
  };
  int rows = 0;
  for (const Cia402Transition& row : kCia402Transitions) {
    if (row.automatic) continue;
    SCOPED_TRACE("transition " + std::to_string(row.number) + ": '" + ToString(row.from) + "' + " +
                 ToString(row.command));
    ASSERT_NO_FATAL_FAILURE(reach(row.from));
    Cia402State reached = row.from;
    const std::error_code ec = drive->SendCommand(row.command, 50ms, &reached);
    if (row.to == row.from) {
      EXPECT_EQ(ec, Errc::kTimeout);
    } else {
      EXPECT_FALSE(ec) << drive->last_error_text();
    }
    EXPECT_EQ(reached, row.to);
    EXPECT_EQ(sim_->device(1).state(), row.to);
    ++rows;
  }
  EXPECT_EQ(rows, 18);
}

TEST_F(Rs485DriveTest, SeveralDrivesOnOneLineMoveIndependently) {
  MakeLine({1, 2, 5});
  bus_->ConfigureAll();
  ASSERT_FALSE(bus_->EnableAll(1000ms));
  const double targets[3] = {0.2, -0.3, 0.4};
  for (int step = 1; step <= 100; ++step) {
    for (int i = 0; i < 3; ++i) {
      ASSERT_FALSE(drives_[i]->SetTargetPosition(targets[i] * step / 100.0));
    }
    clock_.SleepFor(2ms);
    ASSERT_FALSE(bus_->Cycle());
  }
  Cycles(10);
  const int units[3] = {1, 2, 5};
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(drives_[i]->status().position, targets[i], 2.0 / kCountsPerRad);
    EXPECT_EQ(sim_->device(units[i]).snapshot().target_position,
              static_cast<int32_t>(std::lround(targets[i] * kCountsPerRad)));
  }
  ASSERT_FALSE(bus_->DisableAll());
  for (int unit : units) EXPECT_EQ(sim_->device(unit).state(), S::kSwitchOnDisabled);
}

TEST_F(Rs485DriveTest, SilentDriveIsALinkFaultAndTheOthersQuickStop) {
  MakeLine({1, 2}, {}, {}, ",timeout_ms=200,retries=0");
  bus_->ConfigureAll();
  ASSERT_FALSE(bus_->EnableAll(1000ms));
  const uint64_t timeouts_before = drives_[1]->counters().timeouts;
  const uint64_t other_timeouts_before = drives_[0]->counters().timeouts;
  sim_->StopAnswering(2, true);
  std::error_code ec;
  int cycles = 0;
  while (drives_[1]->lifecycle() != common::DeviceLifecycle::kFault && cycles < 10) {
    clock_.SleepFor(2ms);
    ec = bus_->Cycle();
    ++cycles;
  }
  EXPECT_EQ(ec, Errc::kTimeout);
  EXPECT_EQ(cycles, 3);  // max_missed_cycles
  EXPECT_EQ(drives_[1]->lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_EQ(drives_[1]->status().fault_source, DriveFaultSource::kLink);
  EXPECT_EQ(drives_[1]->counters().timeouts - timeouts_before, 3u);
  // The line's client is shared: its timeouts are counted on the drive that made the request.
  EXPECT_EQ(drives_[0]->counters().timeouts, other_timeouts_before);
  EXPECT_EQ(drives_[1]->counters().link_losses, 1u);
  EXPECT_THAT(drives_[1]->last_error_text(),
              ContainsRegex("^arm2 \\(modbus-rtu:.* unit 2\\): link lost: 3 consecutive "
                            "exchanges failed, the last: .*unit 2: .*timed out"));
  // Link errors are not device errors.
  EXPECT_EQ(drives_[1]->status().error_code, 0);
  EXPECT_EQ(drives_[0]->lifecycle(), common::DeviceLifecycle::kConfigured);
  EXPECT_THAT(drives_[0]->last_error_text(), HasSubstr("quick stop: arm2"));
  // A dead drive is polled every faulted_poll_cycles (50) cycles only.
  const uint64_t timeouts = drives_[1]->counters().timeouts;
  Cycles(60);
  EXPECT_LE(drives_[1]->counters().timeouts - timeouts, 2u);
  EXPECT_EQ(sim_->device(1).state(), S::kSwitchOnDisabled);  // quick stop completed
  // Back on the line: its watchdog had tripped meanwhile (a device fault, 0x8130); a fault
  // reset clears both.
  const uint64_t last_cycle = drives_[1]->status().cycle;
  sim_->StopAnswering(2, false);
  Cycles(60);
  EXPECT_GT(drives_[1]->status().cycle, last_cycle);  // it answers again
  ASSERT_FALSE(bus_->EnableAll(1000ms, /*reset_fault=*/true)) << drives_[1]->last_error_text();
  EXPECT_EQ(sim_->device(2).state(), S::kOperationEnabled);
}

TEST_F(Rs485DriveTest, BadCrcIsACountedLinkErrorNotAFault) {
  MakeLine({1});
  drives_[0]->Configure();
  ASSERT_FALSE(drives_[0]->Enable(500ms));
  sim_->CorruptNextReplies(1, 1);
  clock_.SleepFor(2ms);
  EXPECT_EQ(bus_->Cycle(), ModbusErrc::kBadCrc);
  EXPECT_EQ(drives_[0]->counters().crc_errors, 1u);
  clock_.SleepFor(2ms);
  EXPECT_FALSE(bus_->Cycle());
  EXPECT_EQ(drives_[0]->lifecycle(), common::DeviceLifecycle::kActive);
  EXPECT_EQ(drives_[0]->status().fault_source, DriveFaultSource::kNone);
}

TEST_F(Rs485DriveTest, DeviceFaultIsReportedWithItsCodeApartFromLinkErrors) {
  MakeLine({1, 2});
  bus_->ConfigureAll();
  ASSERT_FALSE(bus_->EnableAll(1000ms));
  sim_->RaiseFault(1, 0x7121);
  Cycles(20);
  Rs485Drive* drive = drives_[0];
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_EQ(drive->status().fault_source, DriveFaultSource::kDevice);
  EXPECT_EQ(drive->status().error_code, 0x7121);
  EXPECT_THAT(drive->last_error_text(),
              ContainsRegex("^arm1 \\(modbus-rtu:.* unit 1\\): drive fault: state '.*', error "
                            "code 0x7121 \\(motor blocked\\)"));
  EXPECT_EQ(drive->counters().timeouts, 0u);
  EXPECT_EQ(drive->counters().crc_errors, 0u);
  EXPECT_EQ(sim_->device(1).state(), S::kFault);
  EXPECT_EQ(drive->last_controlword(), 0x00);
  EXPECT_NE(sim_->device(2).state(), S::kOperationEnabled);  // quick-stopped by the bus
  ASSERT_FALSE(drive->FaultReset()) << drive->last_error_text();
  EXPECT_EQ(sim_->device(1).state(), S::kSwitchOnDisabled);
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kConfigured);
}

TEST_F(Rs485DriveTest, DriveWatchdogTripsWhenTheHostStopsCycling) {
  MakeLine({1});
  drives_[0]->Configure();
  ASSERT_FALSE(drives_[0]->Enable(500ms));
  clock_.SleepFor(150ms);  // no exchange for longer than the 100 ms watchdog
  Cycles(20);
  EXPECT_EQ(drives_[0]->lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_EQ(drives_[0]->status().error_code, 0x8130);
  EXPECT_THAT(drives_[0]->last_error_text(), HasSubstr("0x8130 (life guard or heartbeat error)"));
  EXPECT_EQ(sim_->device(1).state(), S::kFault);
}

TEST_F(Rs485DriveTest, UnsupportedModesAreRefused) {
  MakeLine({1}, {}, [](Rs485DriveSim::DriveOptions* d) { d->device.supported_modes = 0x380; });
  drives_[0]->Configure();
  EXPECT_EQ(drives_[0]->SetMode(DriveMode::kProfilePosition), Errc::kUnsupported);
  EXPECT_FALSE(drives_[0]->SetMode(DriveMode::kCyclicSynchronousVelocity));
  ASSERT_FALSE(drives_[0]->Enable(500ms));
  ASSERT_FALSE(drives_[0]->SetTargetVelocity(1.0));
  Cycles(200);
  EXPECT_EQ(drives_[0]->status().mode, DriveMode::kCyclicSynchronousVelocity);
  EXPECT_NEAR(drives_[0]->status().velocity, 1.0, 0.01);
}

TEST_F(Rs485DriveTest, ConfigureFailsNamingTheDriveWhenItDoesNotAnswer) {
  MakeLine({1}, {}, {}, ",timeout_ms=100,retries=0");
  sim_->StopAnswering(1, true);
  try {
    drives_[0]->Configure();
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("^arm1 \\(modbus-rtu:.* unit 1\\): configure: read "
                                        "identity and supported modes failed: .*timed out"));
    EXPECT_EQ(e.code(), Errc::kTimeout);
  }
  EXPECT_EQ(drives_[0]->lifecycle(), common::DeviceLifecycle::kUnconfigured);
}

TEST(Rs485DriveBusConfigTest, BadBackendsAndUnitsAreConfigErrors) {
  EXPECT_THROW(Rs485DriveBus("modbus-tcp:127.0.0.1:502"), common::ConfigError);
  try {
    Rs485DriveBus bus("modbus-rtu:/dev/null@115200", [] {
      Rs485DriveBusOptions o;
      o.max_missed_cycles = 0;
      return o;
    }());
    FAIL() << "no ConfigError";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), MatchesRegex("RS485 drive bus \"modbus-rtu:/dev/null@115200\": "
                                       "max_missed_cycles 0 must be >= 1"));
  }
  Rs485DriveBus bus("modbus-rtu:/dev/null@115200");
  Rs485DriveConfig c = DriveConfig(0);
  EXPECT_THROW(bus.AddDrive(c), common::ConfigError);
  c = DriveConfig(1);
  c.watchdog = 70000ms;
  EXPECT_THROW(bus.AddDrive(c), common::ConfigError);
}

}  // namespace
}  // namespace kinevis::hal
