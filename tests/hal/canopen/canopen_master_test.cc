#include "hal/canopen/canopen_master.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <functional>
#include <memory>
#include <new>
#include <string>
#include <vector>

#include "common/units.h"
#include "hal/can/virtual_can_bus.h"
#include "hal/common/error.h"
#include "hal/drive/cia402_can_drive.h"
#include "hal/mock/canopen_drive_sim.h"
#include "tests/utilities/allocation_counter.h"

namespace kinevis::hal::canopen {
namespace {

using namespace std::chrono_literals;
using ::testing::ContainsRegex;
using ::testing::HasSubstr;
using ::testing::MatchesRegex;
using S = Cia402State;

constexpr double kCountsPerRad = 65536.0 / (2 * common::kPi);

std::string TestName() { return ::testing::UnitTest::GetInstance()->current_test_info()->name(); }

// A clock whose time passes only when the code under test sleeps on it; while it passes, the
// simulated drives are serviced, in steps no longer than `step`.
class ServicedClock final : public common::Clock {
 public:
  explicit ServicedClock(common::Duration step = 50us) : step_(step) {}
  common::Duration Now() const override { return time_.Now(); }
  void SleepUntil(common::Duration deadline) override {
    kinevis::testing::UncountedAllocations not_counted;  // the simulators are not under test
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

Cia402CanDriveConfig DriveConfig(uint8_t node) {
  Cia402CanDriveConfig c;
  c.node = node;
  c.drive.name = "leg" + std::to_string(node);
  c.drive.scaling.position_counts_per_unit = kCountsPerRad;
  c.drive.scaling.velocity_counts_per_unit = kCountsPerRad;
  c.drive.scaling.torque_per_mille_per_unit = 100.0;
  c.drive.limits.min_position = -5.0;
  c.drive.limits.max_position = 5.0;
  c.drive.command_timeout = 200ms;
  c.heartbeat_producer = 10ms;
  c.heartbeat_consumer = 30ms;
  return c;
}

class CanopenMasterTest : public ::testing::Test {
 protected:
  void SetUp() override {
    VirtualCanNetwork::Options options;
    options.clock = &clock_;
    network_ = std::make_shared<VirtualCanNetwork>(TestName(), options);
    peer_ = network_->Connect("peer");
  }

  // `count` simulated drives, nodes 1..count, and the master with their host drives.
  void MakeBus(int count, CanopenMasterOptions options = {}) {
    options.clock = &clock_;
    auto host = network_->Connect("virtual:hexapod");
    host_node_ = host.get();
    master_ = std::make_unique<CanopenMaster>(std::move(host), options);
    for (int i = 1; i <= count; ++i) {
      const auto node = static_cast<uint8_t>(i);
      CanopenDriveSim::Options o;
      o.node = node;
      o.serial_number = 100 + node;
      sim_nodes_.push_back(network_->Connect("sim" + std::to_string(i)));
      sims_.push_back(std::make_unique<CanopenDriveSim>(sim_nodes_.back().get(), &clock_, o));
      CanopenDriveSim* sim = sims_.back().get();
      clock_.AddService([sim] { sim->Service(); });
      drives_.push_back(master_->AddDrive(DriveConfig(node)));
    }
  }

  void Cycles(int n) {
    for (int i = 0; i < n; ++i) {
      clock_.SleepFor(1ms);
      master_->Cycle();
    }
  }

  std::vector<CanFrame> PeerFrames() {
    std::vector<CanFrame> frames;
    CanFrame f;
    while (!peer_->Receive(&f, 0us)) frames.push_back(f);
    return frames;
  }

  ServicedClock clock_;
  std::shared_ptr<VirtualCanNetwork> network_;
  std::unique_ptr<VirtualCanBus> peer_;
  VirtualCanBus* host_node_ = nullptr;
  std::vector<std::unique_ptr<VirtualCanBus>> sim_nodes_;
  std::vector<std::unique_ptr<CanopenDriveSim>> sims_;
  std::unique_ptr<CanopenMaster> master_;
  std::vector<Cia402CanDrive*> drives_;
};

TEST_F(CanopenMasterTest, NmtCommandsHaveTheSpecificationsBytesAndTakeEffect) {
  MakeBus(2);
  sims_[0]->Service();
  sims_[1]->Service();
  PeerFrames();
  ASSERT_FALSE(master_->SendNmt(NmtCommand::kStart, 1));
  ASSERT_FALSE(master_->SendNmt(NmtCommand::kStop, 2));
  ASSERT_FALSE(master_->SendNmt(NmtCommand::kEnterPreOperational, 0));
  ASSERT_FALSE(master_->SendNmt(NmtCommand::kResetCommunication, 2));
  ASSERT_FALSE(master_->SendNmt(NmtCommand::kResetNode, 1));
  std::vector<CanFrame> frames = PeerFrames();
  ASSERT_EQ(frames.size(), 5u);
  EXPECT_EQ(frames[0], CanFrame::Standard(0x000, {0x01, 0x01}));
  EXPECT_EQ(frames[1], CanFrame::Standard(0x000, {0x02, 0x02}));
  EXPECT_EQ(frames[2], CanFrame::Standard(0x000, {0x80, 0x00}));
  EXPECT_EQ(frames[3], CanFrame::Standard(0x000, {0x82, 0x02}));
  EXPECT_EQ(frames[4], CanFrame::Standard(0x000, {0x81, 0x01}));
  clock_.SleepFor(1ms);
  // Both nodes rebooted (boot-up message) into pre-operational.
  EXPECT_EQ(sims_[0]->nmt_state(), NmtState::kPreOperational);
  EXPECT_EQ(sims_[1]->nmt_state(), NmtState::kPreOperational);
  frames = PeerFrames();
  EXPECT_NE(std::find(frames.begin(), frames.end(), CanFrame::Standard(0x701, {0x00})),
            frames.end());
  ASSERT_FALSE(master_->SendNmt(NmtCommand::kStart, 0));
  clock_.SleepFor(1ms);
  EXPECT_EQ(sims_[0]->nmt_state(), NmtState::kOperational);
  EXPECT_EQ(sims_[1]->nmt_state(), NmtState::kOperational);
}

TEST_F(CanopenMasterTest, EachCycleSendsTheRpdosThenOneSyncAndCollectsBothTpdos) {
  MakeBus(2);
  master_->ConfigureAll();
  PeerFrames();
  const CanopenMasterCounters before = master_->counters();
  ASSERT_FALSE(master_->Cycle());
  const std::vector<CanFrame> frames = PeerFrames();
  std::vector<uint32_t> ids;
  for (const CanFrame& f : frames) ids.push_back(f.id);
  // Host frames in order (RPDO1, RPDO2 per node, then SYNC), then the TPDOs of both nodes.
  ASSERT_GE(ids.size(), 9u);
  EXPECT_EQ(std::vector<uint32_t>(ids.begin(), ids.begin() + 5),
            (std::vector<uint32_t>{0x201, 0x301, 0x202, 0x302, 0x080}));
  EXPECT_EQ(frames[4].dlc, 0);
  std::vector<uint32_t> tpdos(ids.begin() + 5, ids.end());
  std::sort(tpdos.begin(), tpdos.end());
  tpdos.erase(std::remove_if(tpdos.begin(), tpdos.end(), [](uint32_t id) { return id >= 0x700; }),
              tpdos.end());
  EXPECT_EQ(tpdos, (std::vector<uint32_t>{0x181, 0x182, 0x281, 0x282}));
  const CanopenMasterCounters after = master_->counters();
  EXPECT_EQ(after.syncs - before.syncs, 1u);
  EXPECT_EQ(after.rpdos - before.rpdos, 4u);
  EXPECT_EQ(after.tpdos - before.tpdos, 4u);
  EXPECT_EQ(after.missing_tpdos, 0u);
  // The RPDO contents: controlword 0 (disable voltage), mode 8, target = actual position.
  EXPECT_EQ(frames[0].dlc, 7);
  EXPECT_EQ(frames[0].data[0], 0x00);
  EXPECT_EQ(frames[0].data[2], 8);
  EXPECT_EQ(frames[1].dlc, 6);
}

TEST_F(CanopenMasterTest, SixDrivesTrackATrajectoryInCspAtOneKilohertz) {
  peer_.reset();
  MakeBus(6);
  master_->ConfigureAll();
  ASSERT_FALSE(master_->EnableAll(1000ms));
  for (Cia402CanDrive* d : drives_) ASSERT_EQ(d->lifecycle(), common::DeviceLifecycle::kActive);
  const CanopenMasterCounters before = master_->counters();
  // q_i(t) = a_i (1 - cos(2 pi f t)): from rest, 1 Hz, amplitudes 0.1 .. 0.6 rad.
  auto q = [](int i, double t) {
    return 0.1 * (i + 1) * (1 - std::cos(2 * common::kPi * 1.0 * t));
  };
  const common::Duration t0 = clock_.Now();
  constexpr int kCycles = 2000;
  double worst = 0;
  for (int k = 1; k <= kCycles; ++k) {
    const double t = k * 1e-3;
    for (int i = 0; i < 6; ++i) ASSERT_FALSE(drives_[i]->SetTargetPosition(q(i, t)));
    clock_.SleepUntil(t0 + k * common::Duration(1ms));
    ASSERT_FALSE(master_->Cycle()) << "cycle " << k;
    if (k < 10) continue;
    for (int i = 0; i < 6; ++i) {
      worst = std::max(worst, std::fabs(drives_[i]->status().position - q(i, t)));
    }
  }
  // Following within a few counts: the drives interpolate the set-points of a 1 kHz SYNC.
  EXPECT_LT(worst, 20.0 / kCountsPerRad) << "worst tracking error " << worst << " rad";
  const CanopenMasterCounters after = master_->counters();
  EXPECT_EQ(after.syncs - before.syncs, static_cast<uint64_t>(kCycles));
  EXPECT_EQ(after.rpdos - before.rpdos, 12u * kCycles);
  EXPECT_EQ(after.tpdos - before.tpdos, 12u * kCycles);
  EXPECT_EQ(after.missing_tpdos, 0u);
  EXPECT_EQ(after.late_tpdos, before.late_tpdos);
  for (int i = 0; i < 6; ++i) {
    EXPECT_EQ(drives_[i]->lifecycle(), common::DeviceLifecycle::kActive);
    EXPECT_EQ(sims_[i]->statistics().syncs >= static_cast<uint64_t>(kCycles), true);
    EXPECT_NEAR(drives_[i]->status().position, q(i, kCycles * 1e-3), 20.0 / kCountsPerRad);
  }
  ASSERT_FALSE(master_->DisableAll());
  for (auto& sim : sims_) EXPECT_EQ(sim->device().state(), S::kSwitchOnDisabled);
}

TEST_F(CanopenMasterTest, SteadyStateCycleDoesNotAllocate) {
  peer_.reset();  // a node nobody reads would overflow, and its overflow report allocates
  MakeBus(6);
  master_->ConfigureAll();
  ASSERT_FALSE(master_->EnableAll(1000ms));
  Cycles(50);  // warm-up: queues and buffers reach their working size
  const common::Duration t0 = clock_.Now();
  long allocations = 0;
  for (int k = 1; k <= 1000; ++k) {
    const double target = 0.2 * std::sin(2 * common::kPi * k * 1e-3);
    {
      kinevis::testing::UncountedAllocations not_counted;  // the simulators are not under test
      clock_.SleepUntil(t0 + k * common::Duration(1ms));
    }
    const long before = kinevis::testing::ThreadAllocations();
    for (Cia402CanDrive* d : drives_) (void)d->SetTargetPosition(target);
    const std::error_code ec = master_->Cycle();
    for (Cia402CanDrive* d : drives_) (void)d->status();
    allocations += kinevis::testing::ThreadAllocations() - before;
    ASSERT_FALSE(ec);
  }
  EXPECT_EQ(allocations, 0);
  // The counter itself works.
  const long before_probe = kinevis::testing::ThreadAllocations();
  auto* probe = new int(1);
  EXPECT_EQ(kinevis::testing::ThreadAllocations() - before_probe, 1);
  delete probe;
}

TEST_F(CanopenMasterTest, HeartbeatLossFaultsThatDriveAndQuickStopsTheOthers) {
  MakeBus(3);
  master_->ConfigureAll();
  ASSERT_FALSE(master_->EnableAll(1000ms));
  Cycles(50);
  sims_[1]->StopHeartbeat(true);
  const common::Duration stopped = clock_.Now();
  common::Duration detected{0};
  std::error_code ec;
  for (int i = 0; i < 100 && drives_[1]->lifecycle() != common::DeviceLifecycle::kFault; ++i) {
    clock_.SleepFor(1ms);
    ec = master_->Cycle();
    detected = clock_.Now();
  }
  ASSERT_EQ(drives_[1]->lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_EQ(ec, Errc::kTimeout);
  EXPECT_LE(detected - stopped, common::Duration(30ms + 1ms));  // consumer time + one cycle
  EXPECT_EQ(drives_[1]->status().fault_source, DriveFaultSource::kLink);
  EXPECT_THAT(drives_[1]->last_error_text(),
              MatchesRegex("leg2 \\(virtual:hexapod node 2\\): link lost: heartbeat lost: .*"));
  EXPECT_EQ(master_->counters().heartbeat_losses, 1u);
  // The others were quick-stopped by the bus and named the cause.
  for (int i : {0, 2}) {
    EXPECT_EQ(drives_[i]->lifecycle(), common::DeviceLifecycle::kConfigured);
    EXPECT_THAT(drives_[i]->last_error_text(),
                HasSubstr("quick stop: leg2 (virtual:hexapod node 2) faulted"));
  }
  Cycles(30);
  for (auto& sim : sims_) {
    const S s = sim->device().state();
    EXPECT_TRUE(s == S::kQuickStopActive || s == S::kSwitchOnDisabled) << ToString(s);
  }
  EXPECT_EQ(master_->Cycle(), Errc::kTimeout);  // a drive is still in fault
}

TEST_F(CanopenMasterTest, WithoutTheQuickStopPolicyTheOthersKeepRunning) {
  CanopenMasterOptions options;
  options.quick_stop_all_on_fault = false;
  MakeBus(2, options);
  master_->ConfigureAll();
  ASSERT_FALSE(master_->EnableAll(1000ms));
  sims_[0]->StopHeartbeat(true);
  Cycles(60);
  EXPECT_EQ(drives_[0]->lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_EQ(drives_[1]->lifecycle(), common::DeviceLifecycle::kActive);
  EXPECT_EQ(sims_[1]->device().state(), S::kOperationEnabled);
}

TEST_F(CanopenMasterTest, EmcyFaultsTheDriveWithTheErrorText) {
  MakeBus(2);
  master_->ConfigureAll();
  ASSERT_FALSE(master_->EnableAll(1000ms));
  // An EMCY without a fault in the statusword still faults the drive.
  EmcyMessage emcy;
  emcy.node = 2;
  emcy.error_code = 0x3210;
  emcy.error_register = 0x05;
  ASSERT_FALSE(peer_->Send(EncodeEmcy(emcy)));
  Cycles(1);
  EXPECT_EQ(drives_[1]->lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_EQ(drives_[1]->status().fault_source, DriveFaultSource::kDevice);
  EXPECT_EQ(drives_[1]->status().error_code, 0x3210);
  EXPECT_THAT(drives_[1]->last_error_text(),
              MatchesRegex("leg2 \\(virtual:hexapod node 2\\): EMCY 0x3210 \\(DC link "
                           "over-voltage\\), error register 0x05"));
  EXPECT_EQ(master_->counters().emergencies, 1u);
  EXPECT_EQ(drives_[1]->counters().emergencies, 1u);
  Cycles(20);
  // Device fault: held with "disable voltage"; the drive that was fine is quick-stopped.
  EXPECT_EQ(drives_[1]->last_controlword(), 0x00);
  EXPECT_EQ(sims_[1]->device().state(), S::kSwitchOnDisabled);
  EXPECT_EQ(drives_[0]->lifecycle(), common::DeviceLifecycle::kConfigured);
  // An "error reset" EMCY (code 0) is no fault.
  ASSERT_FALSE(master_->EnableAll(1000ms, /*reset_fault=*/true));
  emcy.error_code = 0;
  ASSERT_FALSE(peer_->Send(EncodeEmcy(emcy)));
  Cycles(2);
  EXPECT_EQ(drives_[1]->lifecycle(), common::DeviceLifecycle::kActive);
  // A real fault of the simulator: first the statusword, then its EMCY.
  sims_[0]->RaiseFault(0x7121);
  Cycles(40);
  EXPECT_EQ(drives_[0]->lifecycle(), common::DeviceLifecycle::kFault);
  EXPECT_THAT(drives_[0]->last_error_text(),
              MatchesRegex("leg1 \\(virtual:hexapod node 1\\): EMCY 0x7121 \\(motor blocked\\), "
                           "error register 0x21"));
  EXPECT_EQ(master_->counters().emergencies, 3u);
}

TEST_F(CanopenMasterTest, MissingTpdoIsATimeoutOfThatCycleOnly) {
  MakeBus(2);
  master_->ConfigureAll();
  ASSERT_FALSE(master_->EnableAll(1000ms));
  Cycles(5);
  sims_[1]->DropNextReplies(1);  // TPDO1 of the next SYNC
  clock_.SleepFor(1ms);
  const common::Duration start = clock_.Now();
  EXPECT_EQ(master_->Cycle(), Errc::kTimeout);
  // The cycle waited cycle_timeout (800 us) for it, not longer.
  EXPECT_GE(clock_.Now() - start, common::Duration(800us));
  EXPECT_LE(clock_.Now() - start, common::Duration(900us));
  EXPECT_EQ(master_->counters().missing_tpdos, 1u);
  EXPECT_EQ(drives_[1]->counters().timeouts, 1u);
  EXPECT_EQ(drives_[0]->counters().timeouts, 0u);
  clock_.SleepFor(1ms);
  EXPECT_FALSE(master_->Cycle());
  EXPECT_EQ(drives_[1]->lifecycle(), common::DeviceLifecycle::kActive);
}

TEST_F(CanopenMasterTest, BusOffIsALinkErrorAndTheDrivesEndSafe) {
  MakeBus(2);
  master_->ConfigureAll();
  ASSERT_FALSE(master_->EnableAll(1000ms));
  host_node_->InjectBusOff();
  std::error_code ec;
  for (int i = 0; i < 40; ++i) {
    clock_.SleepFor(1ms);
    ec = master_->Cycle();
    if (i == 0) {
      EXPECT_EQ(ec, Errc::kBusOff);
    }
  }
  EXPECT_GE(master_->counters().send_errors, 3u);
  EXPECT_GE(master_->counters().bus_error_events, 1u);
  for (Cia402CanDrive* d : drives_) {
    EXPECT_EQ(d->lifecycle(), common::DeviceLifecycle::kFault);
    EXPECT_EQ(d->status().fault_source, DriveFaultSource::kLink);
  }
  host_node_->Recover();
  Cycles(30);
  for (auto& sim : sims_) {
    const S s = sim->device().state();
    EXPECT_TRUE(s == S::kQuickStopActive || s == S::kSwitchOnDisabled) << ToString(s);
  }
  ASSERT_FALSE(master_->EnableAll(1000ms, /*reset_fault=*/true));
}

TEST_F(CanopenMasterTest, FramesOfNoConfiguredNodeAreCountedAndIgnored) {
  MakeBus(1);
  master_->ConfigureAll();
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x123, {1, 2})));
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x709, {0x05})));  // heartbeat of node 9
  ASSERT_FALSE(peer_->Send(CanFrame::Extended(0x18FF0001, {1})));
  Cycles(1);
  EXPECT_GE(master_->counters().unknown_frames, 3u);
  EXPECT_EQ(drives_[0]->lifecycle(), common::DeviceLifecycle::kConfigured);
}

TEST_F(CanopenMasterTest, ShortTpdoIsAProtocolErrorNotData) {
  MakeBus(1);
  master_->ConfigureAll();
  Cycles(2);
  const uint64_t errors = drives_[0]->counters().protocol_errors;
  ASSERT_FALSE(peer_->Send(CanFrame::Standard(0x181, {0x27, 0x02})));
  Cycles(1);
  EXPECT_EQ(drives_[0]->counters().protocol_errors, errors + 1);
  EXPECT_EQ(drives_[0]->status().state, S::kSwitchOnDisabled);
}

TEST(CanopenMasterConfigTest, InvalidOptionsAreAConfigError) {
  auto network = std::make_shared<VirtualCanNetwork>("master-config", VirtualCanNetwork::Options{});
  CanopenMasterOptions options;
  options.cycle_period = 0us;
  options.sdo.timeout = 0ms;
  try {
    CanopenMaster master(network->Connect("virtual:master-config"), options);
    FAIL() << "no ConfigError";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), MatchesRegex("CANopen master on virtual:master-config: cycle_period 0 "
                                       "us must be > 0; sdo.timeout 0 ms must be > 0"));
  }
}

}  // namespace
}  // namespace kinevis::hal::canopen
