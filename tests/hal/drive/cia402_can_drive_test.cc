#include "hal/drive/cia402_can_drive.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <functional>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "common/units.h"
#include "hal/can/can_bus_factory.h"
#include "hal/can/slcan_bus.h"
#include "hal/can/virtual_can_bus.h"
#include "hal/canopen/canopen_master.h"
#include "hal/common/backend_spec.h"
#include "hal/common/error.h"
#include "hal/mock/canopen_drive_sim.h"
#include "hal/mock/slcan_adapter_sim.h"
#include "hal/serial/pty_pair.h"

namespace kinevis::hal {
namespace {

using namespace std::chrono_literals;
using canopen::CanopenMaster;
using canopen::CanopenMasterOptions;
using ::testing::ContainsRegex;
using ::testing::HasSubstr;
using ::testing::MatchesRegex;
using S = Cia402State;
using C = Cia402Command;

// 2^16 counts per revolution.
constexpr double kCountsPerRad = 65536.0 / (2 * common::kPi);

std::string TestName() { return ::testing::UnitTest::GetInstance()->current_test_info()->name(); }

// A clock whose time passes only when the code under test sleeps on it; while it passes, the
// simulated drives are serviced, in steps no longer than `step`. So the host, the bus and the
// simulators run deterministically on one thread.
class ServicedClock final : public common::Clock {
 public:
  explicit ServicedClock(common::Duration step = 50us) : step_(step) {}
  common::Duration Now() const override { return time_.Now(); }
  void SleepUntil(common::Duration deadline) override {
    while (time_.Now() < deadline) {
      time_.AdvanceTo(std::min(deadline, time_.Now() + step_));
      for (const auto& service : services_) service();
    }
  }
  void AddService(std::function<void()> service) { services_.push_back(std::move(service)); }

 private:
  common::SimulatedClock time_;
  common::Duration step_;
  std::vector<std::function<void()>> services_;
};

CanopenDriveSim::Options SimOptions(uint8_t node) {
  CanopenDriveSim::Options o;
  o.node = node;
  o.serial_number = 1000 + node;
  return o;
}

Cia402CanDriveConfig DriveConfig(uint8_t node) {
  Cia402CanDriveConfig c;
  c.node = node;
  c.drive.name = "axis" + std::to_string(node);
  c.drive.scaling.position_counts_per_unit = kCountsPerRad;
  c.drive.scaling.velocity_counts_per_unit = kCountsPerRad;
  c.drive.scaling.torque_per_mille_per_unit = 100.0;  // 10 N·m rated
  c.drive.limits.min_position = -10.0;
  c.drive.limits.max_position = 10.0;
  c.drive.limits.max_velocity = 20.0;
  c.drive.limits.max_torque = 5.0;
  c.drive.command_timeout = 200ms;
  c.heartbeat_producer = 10ms;
  c.heartbeat_consumer = 30ms;
  return c;
}

// The host (CanopenMaster) and simulated drives on one virtual bus, all on a ServicedClock.
class CanDriveTest : public ::testing::Test {
 protected:
  void SetUp() override {
    VirtualCanNetwork::Options options;
    options.clock = &clock_;
    network_ = std::make_shared<VirtualCanNetwork>(TestName(), options);
    sniffer_ = network_->Connect("sniffer");
  }

  CanopenDriveSim* AddSim(CanopenDriveSim::Options options) {
    sim_nodes_.push_back(network_->Connect("sim" + std::to_string(options.node)));
    sims_.push_back(std::make_unique<CanopenDriveSim>(sim_nodes_.back().get(), &clock_, options));
    CanopenDriveSim* sim = sims_.back().get();
    clock_.AddService([sim] { sim->Service(); });
    return sim;
  }

  CanopenMaster& Master(CanopenMasterOptions options = {}) {
    if (!master_) {
      options.clock = &clock_;
      master_ =
          std::make_unique<CanopenMaster>(network_->Connect("virtual:" + TestName()), options);
    }
    return *master_;
  }

  // A simulated drive at `node` and its host drive, configured.
  Cia402CanDrive* ConfiguredDrive(uint8_t node, CanopenDriveSim::Options sim_options,
                                  Cia402CanDriveConfig config) {
    sim_options.node = node;
    config.node = node;
    AddSim(sim_options);
    Cia402CanDrive* drive = Master().AddDrive(config);
    drive->Configure();
    return drive;
  }
  Cia402CanDrive* ConfiguredDrive(uint8_t node = 1) {
    return ConfiguredDrive(node, SimOptions(node), DriveConfig(node));
  }

  void RunCycles(int n) {
    for (int i = 0; i < n; ++i) {
      clock_.SleepFor(1ms);
      master_->Cycle();
    }
  }

  // Controlwords of RPDO1 frames of `node` seen on the bus since the last call, without repeats.
  std::vector<uint16_t> ControlwordChanges(uint8_t node) {
    std::vector<uint16_t> words;
    CanFrame f;
    while (!sniffer_->Receive(&f, 0us)) {
      if (f.id != canopen::kRpdoBase[0] + node) continue;
      const auto cw = static_cast<uint16_t>(canopen::GetLe(&f.data[0], 2));
      if (words.empty() || words.back() != cw) words.push_back(cw);
    }
    return words;
  }
  void ClearSniffer() {
    CanFrame f;
    while (!sniffer_->Receive(&f, 0us)) {
    }
  }

  ServicedClock clock_;
  std::shared_ptr<VirtualCanNetwork> network_;
  std::unique_ptr<VirtualCanBus> sniffer_;
  std::vector<std::unique_ptr<VirtualCanBus>> sim_nodes_;
  std::vector<std::unique_ptr<CanopenDriveSim>> sims_;
  std::unique_ptr<CanopenMaster> master_;
};

TEST_F(CanDriveTest, ConfigureReadsTheIdentityAndLeavesTheDriveConfigured) {
  Cia402CanDrive* drive = ConfiguredDrive(3);
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kConfigured);
  EXPECT_EQ(drive->name(), "axis3 (virtual:" + TestName() + " node 3)");
  const DriveIdentity& id = drive->identity();
  EXPECT_EQ(id.device_type, 0x00020192u);
  EXPECT_EQ(id.vendor_id, 0x004B5653u);
  EXPECT_EQ(id.product_code, 0x0402u);
  EXPECT_EQ(id.revision, 1u);
  EXPECT_EQ(id.serial_number, 1003u);
  EXPECT_EQ(id.device_name, "kinevis simulated drive");  // a segmented upload
  EXPECT_EQ(id.supported_modes, 0x38Du);
  EXPECT_EQ(sims_[0]->nmt_state(), canopen::NmtState::kOperational);
  const DriveStatus s = drive->status();
  EXPECT_EQ(s.state, S::kSwitchOnDisabled);
  EXPECT_EQ(s.mode, DriveMode::kCyclicSynchronousPosition);
  EXPECT_GT(s.cycle, 0u);
  RunCycles(15);  // a heartbeat period
  EXPECT_EQ(drive->nmt_state(), canopen::NmtState::kOperational);
}

TEST_F(CanDriveTest, ConfigureMapsThePdosOfTheHeader) {
  Cia402CanDrive* drive = ConfiguredDrive(2);
  canopen::SdoClient& sdo = drive->sdo();
  auto entries = [&](uint16_t mapping) {
    std::vector<uint32_t> out;
    uint8_t count = 0;
    EXPECT_FALSE(sdo.UploadValue(mapping, 0, &count));
    for (uint8_t i = 1; i <= count; ++i) {
      uint32_t e = 0;
      EXPECT_FALSE(sdo.UploadValue(mapping, i, &e));
      out.push_back(e);
    }
    return out;
  };
  EXPECT_EQ(entries(0x1600), (std::vector<uint32_t>{0x60400010, 0x60600008, 0x607A0020}));
  EXPECT_EQ(entries(0x1601), (std::vector<uint32_t>{0x60FF0020, 0x60710010}));
  EXPECT_EQ(entries(0x1A00), (std::vector<uint32_t>{0x60410010, 0x60610008, 0x60640020}));
  EXPECT_EQ(entries(0x1A01), (std::vector<uint32_t>{0x606C0020, 0x60770010, 0x603F0010}));
  for (uint16_t comm : {0x1400, 0x1401, 0x1800, 0x1801}) {
    uint8_t type = 0;
    EXPECT_FALSE(sdo.UploadValue(comm, 2, &type));
    EXPECT_EQ(type, 1) << std::hex << comm;  // synchronous
  }
  for (uint16_t comm : {0x1402, 0x1403, 0x1802, 0x1803}) {
    uint32_t cob = 0;
    EXPECT_FALSE(sdo.UploadValue(comm, 1, &cob));
    EXPECT_NE(cob & 0x80000000u, 0u) << std::hex << comm;  // disabled
  }
  uint16_t heartbeat = 0;
  EXPECT_FALSE(sdo.UploadValue(canopen::kProducerHeartbeatTime, 0, &heartbeat));
  EXPECT_EQ(heartbeat, 10);
  int32_t limit = 0;
  EXPECT_FALSE(sdo.UploadValue(cia402::kSoftwarePositionLimit, 2, &limit));
  EXPECT_EQ(limit, static_cast<int32_t>(std::lround(10.0 * kCountsPerRad)));
}

TEST_F(CanDriveTest, EnableWalksTheTransitionsShutdownSwitchOnEnableOperation) {
  Cia402CanDrive* drive = ConfiguredDrive();
  ClearSniffer();
  ASSERT_FALSE(drive->Enable(500ms)) << drive->last_error_text();
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kActive);
  EXPECT_EQ(drive->status().state, S::kOperationEnabled);
  EXPECT_EQ(sims_[0]->device().state(), S::kOperationEnabled);
  EXPECT_EQ(ControlwordChanges(1), (std::vector<uint16_t>{0x06, 0x07, 0x0F}));
  // Enabling holds the position: the target is the actual position.
  EXPECT_EQ(sims_[0]->device().snapshot().target_position, sims_[0]->device().position());
}

TEST_F(CanDriveTest, CommandsAreRefusedUnlessActive) {
  AddSim(SimOptions(1));
  Cia402CanDrive* drive = Master().AddDrive(DriveConfig(1));
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kUnconfigured);
  EXPECT_EQ(drive->Enable(100ms), Errc::kNotActive);
  EXPECT_THAT(drive->last_error_text(), MatchesRegex("axis1 \\(.* node 1\\): enable refused: "
                                                     "not configured"));
  EXPECT_EQ(drive->Disable(), Errc::kNotActive);
  EXPECT_EQ(drive->SetMode(DriveMode::kCyclicSynchronousVelocity), Errc::kNotActive);
  drive->Configure();
  EXPECT_EQ(drive->SetTargetPosition(1.0), Errc::kNotActive);
  EXPECT_EQ(drive->SetTargetVelocity(1.0), Errc::kNotActive);
  EXPECT_EQ(drive->SetTargetTorque(1.0), Errc::kNotActive);
  ASSERT_FALSE(drive->Enable(500ms));
  EXPECT_FALSE(drive->SetTargetPosition(1.0));
  // Targets outside the configured limits, or not finite, are refused.
  EXPECT_EQ(drive->SetTargetPosition(10.5), Errc::kInvalidArgument);
  EXPECT_EQ(drive->SetTargetPosition(std::nan("")), Errc::kInvalidArgument);
  EXPECT_EQ(drive->SetTargetVelocity(-20.5), Errc::kInvalidArgument);
  EXPECT_EQ(drive->SetTargetTorque(5.01), Errc::kInvalidArgument);
  EXPECT_EQ(drive->SetTargetTorque(INFINITY), Errc::kInvalidArgument);
}

// Drives the simulated drive of `drive` into `state` through the host.
void Reach(Cia402CanDrive* drive, CanopenDriveSim* sim, S state) {
  if (drive->lifecycle() == common::DeviceLifecycle::kFault || drive->status().state == S::kFault) {
    ASSERT_FALSE(drive->FaultReset()) << drive->last_error_text();
  }
  switch (state) {
    case S::kSwitchOnDisabled:
      ASSERT_FALSE(drive->Disable()) << drive->last_error_text();
      break;
    case S::kReadyToSwitchOn:
      ASSERT_NO_FATAL_FAILURE(Reach(drive, sim, S::kSwitchOnDisabled));
      ASSERT_FALSE(drive->SendCommand(C::kShutdown, 200ms));
      break;
    case S::kSwitchedOn:
      ASSERT_NO_FATAL_FAILURE(Reach(drive, sim, S::kReadyToSwitchOn));
      ASSERT_FALSE(drive->SendCommand(C::kSwitchOn, 200ms));
      break;
    case S::kOperationEnabled:
      ASSERT_NO_FATAL_FAILURE(Reach(drive, sim, S::kSwitchOnDisabled));
      ASSERT_FALSE(drive->Enable(500ms)) << drive->last_error_text();
      break;
    case S::kQuickStopActive:
      ASSERT_NO_FATAL_FAILURE(Reach(drive, sim, S::kOperationEnabled));
      ASSERT_FALSE(drive->SendCommand(C::kQuickStop, 200ms));
      break;
    case S::kFault: {
      ASSERT_NO_FATAL_FAILURE(Reach(drive, sim, S::kSwitchOnDisabled));
      sim->RaiseFault(0x5530);
      // Holding "disable voltage" until the drive reports Fault (through Fault reaction active).
      for (int i = 0; i < 100 && drive->status().state != S::kFault; ++i) {
        (void)drive->SendCommand(C::kDisableVoltage, 5ms);
      }
      break;
    }
    default:
      FAIL() << "cannot reach " << ToString(state);
  }
  ASSERT_EQ(sim->device().state(), state) << "wanted " << ToString(state);
  ASSERT_EQ(drive->status().state, state);
}

TEST_F(CanDriveTest, EveryTransitionTheHostCanCommandLeadsWhereTheTableSays) {
  CanopenDriveSim::Options sim_options = SimOptions(1);
  // Option code 6: the drive stays in Quick stop active, so that rows 12 and 16 can be walked.
  sim_options.device.quick_stop_option_code = 6;
  Cia402CanDrive* drive = ConfiguredDrive(1, sim_options, DriveConfig(1));
  CanopenDriveSim* sim = sims_[0].get();
  int rows = 0;
  for (const Cia402Transition& row : kCia402Transitions) {
    if (row.automatic) continue;
    SCOPED_TRACE("transition " + std::to_string(row.number) + ": '" + ToString(row.from) + "' + " +
                 ToString(row.command));
    ASSERT_NO_FATAL_FAILURE(Reach(drive, sim, row.from));
    const uint64_t rpdos = sim->statistics().rpdos;
    Cia402State reached = row.from;
    const std::error_code ec = drive->SendCommand(row.command, 100ms, &reached);
    if (row.to == row.from) {
      EXPECT_EQ(ec, Errc::kTimeout);  // the command does not change the state
    } else {
      EXPECT_FALSE(ec) << drive->last_error_text();
    }
    EXPECT_EQ(reached, row.to);
    EXPECT_EQ(sim->device().state(), row.to);
    EXPECT_EQ(drive->status().state, row.to);
    EXPECT_GT(sim->statistics().rpdos, rpdos);  // the command went by RPDO
    EXPECT_EQ(drive->lifecycle(), row.to == S::kOperationEnabled
                                      ? common::DeviceLifecycle::kActive
                                      : common::DeviceLifecycle::kConfigured);
    ++rows;
  }
  EXPECT_EQ(rows, 18);
}

TEST_F(CanDriveTest, QuickStopWithOptionCodeTwoEndsSwitchOnDisabled) {
  Cia402CanDrive* drive = ConfiguredDrive();
  ASSERT_FALSE(drive->Enable(500ms));
  ASSERT_FALSE(drive->SetTargetVelocity(0.0));
  ASSERT_FALSE(drive->QuickStop()) << drive->last_error_text();
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kConfigured);
  RunCycles(20);
  // Transition 12 (automatic): the quick stop completed, the drive disabled itself.
  EXPECT_EQ(sims_[0]->device().state(), S::kSwitchOnDisabled);
  EXPECT_EQ(drive->status().state, S::kSwitchOnDisabled);
  EXPECT_EQ(drive->last_controlword(), 0x02);
  EXPECT_EQ(drive->SetTargetPosition(0.0), Errc::kNotActive);
}

TEST_F(CanDriveTest, DeviceFaultIsReportedWithNameCodeAndTextAndTheDriveStaysOff) {
  Cia402CanDrive* drive = ConfiguredDrive();
  ASSERT_FALSE(drive->Enable(500ms));
  sims_[0]->RaiseFault(0x2310);
  RunCycles(30);
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kFault);
  const DriveStatus s = drive->status();
  EXPECT_EQ(s.fault_source, DriveFaultSource::kDevice);
  EXPECT_EQ(s.state, S::kFault);
  EXPECT_EQ(s.error_code, 0x2310);
  EXPECT_THAT(drive->last_error_text(),
              ContainsRegex("^axis1 \\(virtual:.* node 1\\): .*0x2310 \\(continuous "
                            "over-current\\)"));
  EXPECT_GE(drive->counters().emergencies, 1u);  // the EMCY came
  EXPECT_EQ(drive->last_controlword(), 0x00);    // disable voltage, bit 7 low
  EXPECT_EQ(sims_[0]->device().state(), S::kFault);
  EXPECT_EQ(drive->SetTargetPosition(0.0), Errc::kNotActive);
  // Enable without reset is refused; with reset it recovers.
  EXPECT_EQ(drive->Enable(200ms), Errc::kDeviceFault);
  EXPECT_THAT(drive->last_error_text(), HasSubstr("reset the fault first"));
  ASSERT_FALSE(drive->Enable(500ms, /*reset_fault=*/true)) << drive->last_error_text();
  EXPECT_EQ(sims_[0]->device().state(), S::kOperationEnabled);
  EXPECT_EQ(drive->status().error_code, 0);
}

TEST_F(CanDriveTest, FaultResetIsARisingEdgeOfBit7) {
  Cia402CanDrive* drive = ConfiguredDrive();
  sims_[0]->RaiseFault(0x4310);
  RunCycles(30);
  ASSERT_EQ(drive->lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_EQ(drive->last_controlword(), 0x00);  // in fault: bit 7 low ...
  ClearSniffer();
  ASSERT_FALSE(drive->FaultReset()) << drive->last_error_text();
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kConfigured);
  EXPECT_EQ(sims_[0]->device().state(), S::kSwitchOnDisabled);
  const std::vector<uint16_t> words = ControlwordChanges(1);
  ASSERT_GE(words.size(), 1u);
  EXPECT_EQ(words[0], 0x80);  // ... then the rising edge
}

TEST_F(CanDriveTest, FaultThatPersistsIsNotResetAndEnableTimesOutInBound) {
  Cia402CanDriveConfig config = DriveConfig(1);
  Cia402CanDrive* drive = ConfiguredDrive(1, SimOptions(1), config);
  ASSERT_FALSE(drive->Enable(500ms));
  sims_[0]->RaiseFault(0x5530);
  RunCycles(30);
  ASSERT_EQ(drive->lifecycle(), common::DeviceLifecycle::kFault);
  // The cause persists: the drive faults again as soon as a reset clears it.
  clock_.AddService([this] {
    if (sims_[0]->device().state() == S::kSwitchOnDisabled) sims_[0]->RaiseFault(0x5530);
  });
  const common::Duration start = clock_.Now();
  const std::error_code ec = drive->Enable(300ms, /*reset_fault=*/true);
  EXPECT_EQ(ec, Errc::kDeviceFault);
  EXPECT_LE(clock_.Now() - start, common::Duration(350ms));
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_THAT(drive->last_error_text(), ContainsRegex("axis1 .*0x5530"));
  EXPECT_NE(sims_[0]->device().state(), S::kOperationEnabled);
}

TEST_F(CanDriveTest, FollowingErrorFaultsTheDrive) {
  CanopenDriveSim::Options sim_options = SimOptions(1);
  sim_options.device.following_error_window = 500;  // counts
  Cia402CanDrive* drive = ConfiguredDrive(1, sim_options, DriveConfig(1));
  ASSERT_FALSE(drive->Enable(500ms));
  // A step of 2 rad in CSP: the axis cannot follow within 500 counts.
  ASSERT_FALSE(drive->SetTargetPosition(2.0));
  RunCycles(60);
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_EQ(drive->status().error_code, 0x8611);
  EXPECT_EQ(drive->status().fault_source, DriveFaultSource::kDevice);
  EXPECT_THAT(drive->last_error_text(), ContainsRegex("^axis1 .*0x8611 \\(following error\\)"));
  EXPECT_EQ(sims_[0]->device().state(), S::kFault);
}

TEST_F(CanDriveTest, PositionsVelocitiesAndTorquesAreSiAndScaled) {
  Cia402CanDrive* drive = ConfiguredDrive();
  ASSERT_FALSE(drive->Enable(500ms));
  // CSP: a ramp to 0.5 rad over 0.5 s.
  for (int i = 1; i <= 500; ++i) {
    ASSERT_FALSE(drive->SetTargetPosition(0.5 * i / 500.0));
    clock_.SleepFor(1ms);
    master_->Cycle();
  }
  RunCycles(20);
  const int32_t counts = static_cast<int32_t>(std::lround(0.5 * kCountsPerRad));
  EXPECT_EQ(sims_[0]->device().snapshot().target_position, counts);
  EXPECT_NEAR(drive->status().position, 0.5, 2.0 / kCountsPerRad);
  EXPECT_EQ(drive->status().mode, DriveMode::kCyclicSynchronousPosition);

  ASSERT_FALSE(drive->SetMode(DriveMode::kCyclicSynchronousVelocity));
  ASSERT_FALSE(drive->SetTargetVelocity(2.0));
  RunCycles(200);
  EXPECT_EQ(drive->status().mode, DriveMode::kCyclicSynchronousVelocity);
  EXPECT_EQ(sims_[0]->device().snapshot().target_velocity,
            static_cast<int32_t>(std::lround(2.0 * kCountsPerRad)));
  EXPECT_NEAR(drive->status().velocity, 2.0, 0.01);

  ASSERT_FALSE(drive->SetTargetVelocity(0.0));
  RunCycles(200);
  ASSERT_FALSE(drive->SetMode(DriveMode::kCyclicSynchronousTorque));
  ASSERT_FALSE(drive->SetTargetTorque(0.25));  // 25 per mille
  RunCycles(3);
  EXPECT_EQ(sims_[0]->device().snapshot().target_torque, 25);
  EXPECT_EQ(drive->status().mode, DriveMode::kCyclicSynchronousTorque);
  ASSERT_FALSE(drive->Disable());
}

TEST_F(CanDriveTest, ProfilePositionHandsTheSetPointOverWithBit4) {
  Cia402CanDriveConfig config = DriveConfig(1);
  config.drive.mode = DriveMode::kProfilePosition;
  config.drive.profile_velocity = 5.0;       // rad/s
  config.drive.profile_acceleration = 50.0;  // rad/s^2
  Cia402CanDrive* drive = ConfiguredDrive(1, SimOptions(1), config);
  EXPECT_EQ(sims_[0]->device().snapshot().profile_velocity,
            static_cast<uint32_t>(std::lround(5.0 * kCountsPerRad)));
  ASSERT_FALSE(drive->Enable(500ms));
  ClearSniffer();
  ASSERT_FALSE(drive->SetTargetPosition(1.0));
  bool reached = false;
  for (int i = 0; i < 1000 && !reached; ++i) {
    clock_.SleepFor(1ms);
    master_->Cycle();
    reached = i > 5 && drive->status().target_reached;
  }
  EXPECT_TRUE(reached);
  EXPECT_NEAR(drive->status().position, 1.0, 2.0 / kCountsPerRad);
  const std::vector<uint16_t> words = ControlwordChanges(1);
  // 0x2F: enable operation + change set immediately; 0x3F: with new set-point (bit 4), which
  // falls again once the drive acknowledged.
  ASSERT_GE(words.size(), 2u);
  EXPECT_EQ(words[0], 0x3F);
  EXPECT_EQ(words[1], 0x2F);
}

TEST_F(CanDriveTest, ProfileVelocityAndProfileTorqueModes) {
  Cia402CanDriveConfig config = DriveConfig(1);
  config.drive.mode = DriveMode::kProfileVelocity;
  config.drive.profile_acceleration = 20.0;  // rad/s^2
  Cia402CanDrive* drive = ConfiguredDrive(1, SimOptions(1), config);
  ASSERT_FALSE(drive->Enable(500ms));
  ASSERT_FALSE(drive->SetTargetVelocity(-1.5));
  RunCycles(300);
  EXPECT_EQ(drive->status().mode, DriveMode::kProfileVelocity);
  EXPECT_NEAR(drive->status().velocity, -1.5, 0.01);
  EXPECT_LT(drive->status().position, -0.1);
  ASSERT_FALSE(drive->SetTargetVelocity(0.0));
  RunCycles(300);
  EXPECT_NEAR(drive->status().velocity, 0.0, 0.01);
  ASSERT_FALSE(drive->SetMode(DriveMode::kProfileTorque));
  ASSERT_FALSE(drive->SetTargetTorque(-0.3));  // -30 per mille
  RunCycles(3);
  EXPECT_EQ(drive->status().mode, DriveMode::kProfileTorque);
  EXPECT_EQ(sims_[0]->device().snapshot().target_torque, -30);
  ASSERT_FALSE(drive->SetTargetTorque(0.0));
  ASSERT_FALSE(drive->Disable());
}

TEST_F(CanDriveTest, UnsupportedModeIsRefused) {
  CanopenDriveSim::Options sim_options = SimOptions(1);
  sim_options.device.supported_modes = 0x380;  // CSP, CSV, CST only
  Cia402CanDrive* drive = ConfiguredDrive(1, sim_options, DriveConfig(1));
  EXPECT_EQ(drive->SetMode(DriveMode::kProfileTorque), Errc::kUnsupported);
  EXPECT_FALSE(drive->SetMode(DriveMode::kCyclicSynchronousTorque));
  // A configured mode the drive lacks fails Configure() with the modes it has.
  AddSim([] {
    CanopenDriveSim::Options o = SimOptions(2);
    o.device.supported_modes = 0x380;
    return o;
  }());
  Cia402CanDriveConfig config = DriveConfig(2);
  config.drive.mode = DriveMode::kProfileVelocity;
  Cia402CanDrive* other = Master().AddDrive(config);
  try {
    other->Configure();
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("^axis2 \\(virtual:.* node 2\\): configure: check modes "
                                        "failed: mode profile velocity \\(3\\) is not supported "
                                        "\\(0x6502 = 0x00000380: cyclic synchronous position "
                                        "\\(8\\), cyclic synchronous velocity \\(9\\), cyclic "
                                        "synchronous torque \\(10\\)\\)"));
  }
  EXPECT_EQ(other->lifecycle(), common::DeviceLifecycle::kUnconfigured);
}

TEST_F(CanDriveTest, DroppedSdoRepliesFailConfigureWithATimeoutInBound) {
  CanopenMasterOptions options;
  options.sdo.timeout = 50ms;
  Master(options);
  CanopenDriveSim* sim = AddSim(SimOptions(1));
  Cia402CanDrive* drive = Master().AddDrive(DriveConfig(1));
  sim->Service();  // boot
  sim->DropNextReplies(1);
  const common::Duration start = clock_.Now();
  try {
    drive->Configure();
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), MatchesRegex("axis1 \\(virtual:.* node 1\\): configure: read device "
                                       "type 0x1000:00 failed: SDO upload 0x1000:00 failed: "
                                       "timed out after 50 ms: no response to the initiate "
                                       "request \\(abort 0x05040000 sent\\)"));
    EXPECT_EQ(e.code(), Errc::kTimeout);
  }
  EXPECT_LE(clock_.Now() - start, common::Duration(55ms));
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kUnconfigured);
  EXPECT_EQ(drive->sdo().counters().timeouts, 1u);
  // The next attempt works.
  drive->Configure();
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kConfigured);
}

TEST_F(CanDriveTest, MalformedSdoReplyFailsConfigureWithAProtocolError) {
  CanopenDriveSim* sim = AddSim(SimOptions(1));
  Cia402CanDrive* drive = Master().AddDrive(DriveConfig(1));
  sim->Service();
  sim->SendMalformedSdoReplies(1);
  try {
    drive->Configure();
    FAIL() << "no HalError";
  } catch (const HalError& e) {
    EXPECT_THAT(e.what(), ContainsRegex("^axis1 \\(virtual:.* node 1\\): configure: read device "
                                        "type 0x1000:00 failed: .*malformed response"));
    EXPECT_EQ(e.code(), Errc::kProtocol);
  }
  EXPECT_EQ(drive->sdo().counters().aborts_sent, 1u);
}

TEST_F(CanDriveTest, SdoAbortsOfTheDriveComeWithCodeAndText) {
  Cia402CanDrive* drive = ConfiguredDrive();
  canopen::SdoClient& sdo = drive->sdo();
  uint32_t value = 0;
  std::error_code ec = sdo.UploadValue<uint32_t>(0x2345, 0, &value);
  EXPECT_EQ(canopen::SdoAbortCode(ec), canopen::sdo_abort::kObjectDoesNotExist);
  EXPECT_THAT(sdo.last_error_text(),
              MatchesRegex("axis1 \\(virtual:.* node 1\\): SDO upload 0x2345:00 failed: abort "
                           "0x06020000 from the server \\(Object does not exist in the object "
                           "dictionary\\)"));
  ec = sdo.DownloadValue<uint16_t>(cia402::kStatusword, 0, 1);
  EXPECT_EQ(canopen::SdoAbortCode(ec), canopen::sdo_abort::kReadOnly);
  EXPECT_THAT(sdo.last_error_text(), HasSubstr("Attempt to write a read only object"));
  ec = sdo.UploadValue<uint32_t>(canopen::kIdentity, 9, &value);
  EXPECT_EQ(canopen::SdoAbortCode(ec), canopen::sdo_abort::kSubindexDoesNotExist);
  ec = sdo.DownloadValue<uint32_t>(canopen::kProducerHeartbeatTime, 0, 1);
  EXPECT_EQ(canopen::SdoAbortCode(ec), canopen::sdo_abort::kLengthTooHigh);
  ec = sdo.DownloadValue<int8_t>(cia402::kModesOfOperation, 0, 2);  // mode 2 unsupported
  EXPECT_EQ(canopen::SdoAbortCode(ec), canopen::sdo_abort::kInvalidValue);
  EXPECT_THAT(sdo.last_error_text(), HasSubstr("Invalid value for parameter"));
  // Segmented download and upload of the simulator's string object 0x2000.
  const std::string tag = "a tag longer than four bytes";
  ASSERT_FALSE(sdo.Download(0x2000, 0, std::vector<uint8_t>(tag.begin(), tag.end())));
  std::string back;
  ASSERT_FALSE(sdo.UploadString(0x2000, 0, &back));
  EXPECT_EQ(back, tag);
}

TEST_F(CanDriveTest, HeartbeatLossFaultsTheDriveWithinTheConsumerTime) {
  Cia402CanDrive* drive = ConfiguredDrive();
  ASSERT_FALSE(drive->Enable(500ms));
  RunCycles(50);
  ASSERT_EQ(drive->lifecycle(), common::DeviceLifecycle::kActive);
  sims_[0]->StopHeartbeat(true);
  const common::Duration stopped = clock_.Now();
  common::Duration detected{0};
  for (int i = 0; i < 200 && drive->lifecycle() == common::DeviceLifecycle::kActive; ++i) {
    clock_.SleepFor(1ms);
    master_->Cycle();
    detected = clock_.Now();
  }
  ASSERT_EQ(drive->lifecycle(), common::DeviceLifecycle::kFault);
  // The last heartbeat came at most one producer period (10 ms) before the stop; the loss is
  // noticed after the consumer time (30 ms), at the latest one cycle later.
  EXPECT_GE(detected - stopped, common::Duration(30ms - 10ms));
  EXPECT_LE(detected - stopped, common::Duration(30ms + 1ms));
  EXPECT_EQ(drive->status().fault_source, DriveFaultSource::kLink);
  EXPECT_THAT(drive->last_error_text(),
              MatchesRegex("axis1 \\(virtual:.* node 1\\): link lost: heartbeat lost: none for "
                           "3[01] ms \\(consumer time 30 ms\\)"));
  EXPECT_EQ(drive->counters().link_losses, 1u);
  // The drive itself still listens: the host's quick stop brings it to rest.
  RunCycles(20);
  EXPECT_EQ(drive->last_controlword(), 0x02);
  const S sim_state = sims_[0]->device().state();
  EXPECT_TRUE(sim_state == S::kQuickStopActive || sim_state == S::kSwitchOnDisabled)
      << ToString(sim_state);
  // Reset needs the heartbeat back.
  EXPECT_EQ(drive->FaultReset(), Errc::kTimeout);
  EXPECT_THAT(drive->last_error_text(), HasSubstr("no heartbeat"));
  sims_[0]->StopHeartbeat(false);
  RunCycles(20);
  ASSERT_FALSE(drive->FaultReset()) << drive->last_error_text();
  ASSERT_FALSE(drive->Enable(500ms)) << drive->last_error_text();
}

TEST_F(CanDriveTest, DisconnectedNodeIsALinkFaultAndEndsQuickStoppedOnReconnect) {
  Cia402CanDrive* drive = ConfiguredDrive();
  ASSERT_FALSE(drive->Enable(500ms));
  sims_[0]->Disconnect(true);
  const common::Duration start = clock_.Now();
  RunCycles(40);
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_EQ(drive->status().fault_source, DriveFaultSource::kLink);
  EXPECT_THAT(drive->last_error_text(), ContainsRegex("^axis1 .*heartbeat lost"));
  EXPECT_GE(drive->counters().timeouts, 1u);  // TPDOs missed before the loss was declared
  // Cycles do not wait for a node known dead: 40 cycles took 40 periods and a bit.
  EXPECT_LE(clock_.Now() - start, common::Duration(41ms + 30 * 800us));
  sims_[0]->Disconnect(false);
  RunCycles(30);
  const S sim_state = sims_[0]->device().state();
  EXPECT_TRUE(sim_state == S::kQuickStopActive || sim_state == S::kSwitchOnDisabled)
      << ToString(sim_state);
  ASSERT_FALSE(drive->Enable(500ms, /*reset_fault=*/true)) << drive->last_error_text();
}

TEST_F(CanDriveTest, RebootedNodeMustBeConfiguredAgain) {
  Cia402CanDrive* drive = ConfiguredDrive();
  ASSERT_FALSE(drive->Enable(500ms));
  // Somebody resets the node.
  ASSERT_FALSE(master_->SendNmt(canopen::NmtCommand::kResetNode, 1));
  RunCycles(5);
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_EQ(drive->status().fault_source, DriveFaultSource::kLink);
  EXPECT_THAT(drive->last_error_text(), HasSubstr("rebooted"));
  EXPECT_EQ(drive->FaultReset(), Errc::kNotActive);
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kUnconfigured);
  drive->Configure();
  ASSERT_FALSE(drive->Enable(500ms)) << drive->last_error_text();
}

TEST_F(CanDriveTest, HeartbeatSentBeforeTheNmtStartIsNoFault) {
  Cia402CanDrive* drive = ConfiguredDrive();
  // A "pre-operational" heartbeat the node sent just before it processed NMT start arrives
  // after the host has configured it.
  ASSERT_FALSE(sniffer_->Send(canopen::EncodeHeartbeat(1, canopen::NmtState::kPreOperational)));
  RunCycles(30);
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kConfigured) << drive->last_error_text();
  EXPECT_EQ(drive->nmt_state(), canopen::NmtState::kOperational);
}

TEST_F(CanDriveTest, NodeLeavingOperationalIsALinkFault) {
  Cia402CanDrive* drive = ConfiguredDrive();
  ASSERT_FALSE(drive->Enable(500ms));
  RunCycles(20);  // an operational heartbeat came
  ASSERT_FALSE(master_->SendNmt(canopen::NmtCommand::kEnterPreOperational, 1));
  RunCycles(30);
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_THAT(drive->last_error_text(),
              HasSubstr("the node left Operational: NMT state 'pre-operational'"));
  // A fault reset starts the node again.
  ASSERT_FALSE(drive->Enable(500ms, /*reset_fault=*/true)) << drive->last_error_text();
  EXPECT_EQ(sims_[0]->nmt_state(), canopen::NmtState::kOperational);
}

TEST(CanDriveConfigTest, BadOptionsAreAConfigErrorNamingEveryField) {
  auto network = std::make_shared<VirtualCanNetwork>("drive-config", VirtualCanNetwork::Options{});
  CanopenMaster master(network->Connect("virtual:drive-config"));
  Cia402CanDriveConfig c = DriveConfig(1);
  c.drive.scaling.position_counts_per_unit = 0;
  c.drive.limits.min_position = 2;
  c.drive.limits.max_position = 1;
  c.heartbeat_consumer = 5ms;
  try {
    master.AddDrive(c);
    FAIL() << "no ConfigError";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(),
                ContainsRegex("CANopen master on virtual:drive-config, drive \"axis1\" \\(node "
                              "1\\): scaling.position_counts_per_unit 0.000000 must be finite "
                              "and non-zero; limits.min_position 2.000000 must not exceed "
                              "limits.max_position 1.000000; heartbeat_consumer 5 ms must "
                              "exceed heartbeat_producer 10 ms"));
  }
  master.AddDrive(DriveConfig(1));
  EXPECT_THROW(master.AddDrive(DriveConfig(1)), common::ConfigError);
  EXPECT_THROW(master.AddDrive(DriveConfig(0)), common::ConfigError);
}

// The same driver over slcan: SlcanBus -> pty -> SlcanAdapterSim -> virtual bus -> drive
// simulator, all in real time (generous bounds, no timing asserted).
TEST(CanDriveSlcanTest, ConfigureEnableMoveAndDisableOverSlcan) {
  PtyPair pty;
  auto network = VirtualCanNetwork::Get("cia402-slcan", {});
  auto adapter_node = network->Connect("adapter");
  auto sim_node = network->Connect("sim");
  SlcanAdapterSim adapter(pty.MasterPort(), adapter_node.get(), {});
  adapter.Start();
  CanopenDriveSim sim(sim_node.get(), &common::SteadyClock::Instance(), SimOptions(4));
  sim.Start();
  CanopenMasterOptions options;
  options.cycle_period = 10ms;
  options.cycle_timeout = 8ms;
  options.sdo.timeout = 1000ms;
  CanopenMaster master(OpenCanBus("slcan:" + pty.slave_path() + "@115200,bitrate=1000000"),
                       options);
  Cia402CanDriveConfig config = DriveConfig(4);
  config.heartbeat_producer = 50ms;
  config.heartbeat_consumer = 1000ms;
  config.drive.command_timeout = 2000ms;
  Cia402CanDrive* drive = master.AddDrive(config);
  drive->Configure();
  EXPECT_EQ(drive->identity().device_name, "kinevis simulated drive");
  EXPECT_THAT(drive->name(), MatchesRegex("axis4 \\(slcan:/dev/pts/[0-9]+@115200,"
                                          "bitrate=1000000 node 4\\)"));
  ASSERT_FALSE(drive->Enable(5000ms)) << drive->last_error_text();
  const double start = drive->status().position;
  for (int i = 1; i <= 50; ++i) {
    ASSERT_FALSE(drive->SetTargetPosition(start + 0.2 * i / 50.0));
    std::this_thread::sleep_for(10ms);
    master.Cycle();
  }
  for (int i = 0; i < 20; ++i) {
    std::this_thread::sleep_for(10ms);
    master.Cycle();
  }
  EXPECT_NEAR(drive->status().position, start + 0.2, 0.01);
  EXPECT_EQ(drive->lifecycle(), common::DeviceLifecycle::kActive) << drive->last_error_text();
  ASSERT_FALSE(drive->Disable()) << drive->last_error_text();
  EXPECT_EQ(sim.device().state(), S::kSwitchOnDisabled);
}

}  // namespace
}  // namespace kinevis::hal
