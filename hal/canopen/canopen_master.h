#pragma once

// CANopen master for CiA 402 drives on one CAN bus (SocketCAN, slcan or virtual): NMT commands,
// the SYNC producer, a heartbeat consumer per node, the EMCY consumer, SDO clients (one per
// node, fed by the master's dispatcher) and the cyclic PDO exchange.
//
// One thread owns the bus: every call of the master and of its drives runs on the caller's
// thread, and the master is the only reader of CanBus::Receive(). SDO transfers and the blocking
// drive commands read the bus through the master (PumpUntil), so heartbeats, EMCYs and TPDOs are
// handled while they wait.
//
// Cycle(), once per control period:
//   1. handles what arrived since the last cycle (heartbeats, EMCY, late TPDOs, bus errors) and
//      supervises the heartbeats: a node silent for its consumer time -> that drive faults with
//      DriveFaultSource::kLink, logged with its name;
//   2. sends RPDO1 and RPDO2 of every started drive (controlword, mode, targets);
//   3. sends SYNC: the drives apply the RPDOs and answer with TPDO1 and TPDO2;
//   4. collects the TPDOs until every started drive has answered or cycle_timeout has passed;
//   5. updates every drive's status (SI units) and lifecycle; a drive reporting a fault, an
//      EMCY or a lost heartbeat goes to fault and is held disabled (device fault: controlword
//      "disable voltage") or quick-stopped (link fault: "quick stop", in case it still listens).
// With quick_stop_all_on_fault, a new fault of one drive also quick-stops the other active
// drives of the bus, so that the machine comes to rest. Cycle() does not throw and does not
// allocate in steady state (only logging a fault does).
//
// Time: everything is measured on options.clock; use the clock of the bus (a VirtualCanNetwork
// made with a SimulatedClock, for deterministic tests). On a SteadyClock the master blocks in
// CanBus::Receive(); on any other clock it polls and sleeps on the clock (see ReceiveFrameUntil).

#include <array>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <system_error>
#include <vector>

#include "common/clock.h"
#include "hal/can/can_bus.h"
#include "hal/canopen/canopen_codec.h"
#include "hal/canopen/sdo_client.h"
#include "hal/drive/cia402_can_drive.h"
#include "hal/drive/cia402_drive_bus.h"
#include "hal/drive/motor_drive.h"

namespace kinevis::hal::canopen {

struct CanopenMasterOptions {
  common::Clock* clock = nullptr;  // nullptr: SteadyClock::Instance()
  // Period of the cycles the master runs itself (Configure, Enable, Disable, ...), > 0. The
  // control loop paces its own Cycle() calls.
  std::chrono::microseconds cycle_period{1000};
  // How long Cycle() waits for the TPDOs after SYNC, > 0 (keep it below the period).
  std::chrono::microseconds cycle_timeout{800};
  // A new fault of one drive quick-stops the other active drives of the bus.
  bool quick_stop_all_on_fault = true;
  SdoClientOptions sdo;  // for every node's SDO client; sdo.poll_period is also the master's
};

struct CanopenMasterCounters {
  uint64_t cycles = 0;
  uint64_t syncs = 0;          // SYNC frames sent
  uint64_t rpdos = 0;          // RPDOs sent
  uint64_t tpdos = 0;          // TPDOs received in time
  uint64_t late_tpdos = 0;     // TPDOs that came after their cycle ended
  uint64_t missing_tpdos = 0;  // TPDOs that did not come within cycle_timeout
  uint64_t send_errors = 0;    // frames the bus refused (bus-off, overflow, closed)
  uint64_t heartbeats = 0;
  uint64_t heartbeat_losses = 0;
  uint64_t emergencies = 0;
  uint64_t bus_error_events = 0;  // CanBus error events (bus-off, error-passive, overflow, ...)
  uint64_t unknown_frames = 0;    // frames of no configured node or service
};

class CanopenMaster final : public Cia402DriveBus, public CanFrameSource {
 public:
  // Takes the bus (opened with OpenCanBus()). Throws ConfigError for invalid options.
  explicit CanopenMaster(std::unique_ptr<CanBus> bus, CanopenMasterOptions options = {});
  ~CanopenMaster() override;
  CanopenMaster(const CanopenMaster&) = delete;
  CanopenMaster& operator=(const CanopenMaster&) = delete;

  // Adds the drive of `config.node`. Throws ConfigError naming the bus, the node and every bad
  // field (node out of range or already added, invalid options, consumer <= producer time).
  // The drive lives as long as the master.
  Cia402CanDrive* AddDrive(const Cia402CanDriveConfig& config);
  Cia402CanDrive* AddDrive(uint8_t node, const DriveScaling& scaling,
                           const DriveLimits& limits = {});

  // The bus's name ("socketcan:can0").
  const std::string& name() const override { return bus_->name(); }
  std::error_code Cycle() override;
  std::vector<MotorDrive*> drives() override;
  // nullptr when no drive has that node id.
  Cia402CanDrive* drive(uint8_t node) const;
  const std::vector<std::unique_ptr<Cia402CanDrive>>& can_drives() const { return drives_; }

  // ConfigureAll, EnableAll, DisableAll, RunCyclesUntil, clock(): see Cia402DriveBus.

  // NMT command to `node` (0: all nodes). Returns the bus's error when it could not be sent.
  std::error_code SendNmt(NmtCommand command, uint8_t node);

  // CanFrameSource: reads and dispatches frames (SDO responses, heartbeats, EMCY, TPDOs) until
  // done() or deadline, supervising the heartbeats meanwhile. No SYNC, no RPDO.
  void PumpUntil(common::Duration deadline, const std::function<bool()>& done) override;

  CanBus& bus() const { return *bus_; }
  const CanopenMasterOptions& options() const { return options_; }
  CanopenMasterCounters counters() const { return counters_; }
  uint64_t cycle_count() const { return counters_.cycles; }

 private:
  void Dispatch(const CanFrame& frame, bool in_cycle);
  void DrainReceived();
  void DrainErrorEvents();
  void SuperviseHeartbeats(common::Duration now);

  std::unique_ptr<CanBus> bus_;
  const CanopenMasterOptions options_;
  std::vector<std::unique_ptr<Cia402CanDrive>> drives_;
  std::array<Cia402CanDrive*, kMaxNodeId + 1> by_node_{};  // node id -> drive
  CanopenMasterCounters counters_;
  int outstanding_tpdos_ = 0;  // during collection: drives that have not sent both TPDOs
  bool collecting_ = false;
  common::Duration last_error_event_log_{0};
};

}  // namespace kinevis::hal::canopen
