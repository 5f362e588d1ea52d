#pragma once

// Host-side CiA 402 drives.
//
// Cia402HostDrive is the transport-independent half: lifecycle, the CiA 402 power state machine
// driven through its transitions (Cia402NextCommand) with timeouts, fault reset on a rising edge
// of controlword bit 7, modes, SI <-> drive-unit conversion with DriveScaling, target checks
// against DriveLimits, and fault bookkeeping that keeps link faults apart from device faults.
// The bus that cycles the drive (CanopenMaster, Rs485DriveBus) moves the process data.
// (It is shared by the CANopen and the RS485 drive; it lives in this header because the file
// layout of the issue gave it no header of its own.)
//
// Cia402CanDrive is the CANopen half: one node on a CanopenMaster's bus. Configure() reads the
// identity (0x1000, 0x1018, 0x1008) and the supported modes (0x6502) by SDO, maps the PDOs,
// sets the mode, profile, limits and the producer heartbeat time, and starts the node (NMT).
//
// PDO layout (all synchronous, transmission type 1; docs/canopen.md):
//   RPDO1 0x200+n, 7 bytes: controlword 0x6040 u16 | mode 0x6060 i8 | target position 0x607A i32
//   RPDO2 0x300+n, 6 bytes: target velocity 0x60FF i32 | target torque 0x6071 i16
//   TPDO1 0x180+n, 7 bytes: statusword 0x6041 u16 | mode display 0x6061 i8 | position 0x6064 i32
//   TPDO2 0x280+n, 8 bytes: velocity 0x606C i32 | torque 0x6077 i16 | error code 0x603F u16
//   RPDO3/4 and TPDO3/4 are invalidated.
//
// Threading: a drive, its bus and every other drive of that bus are used from one thread (the
// control thread). The blocking calls (Configure, Enable, Disable, QuickStop, FaultReset) run bus
// cycles themselves at the bus's cycle period; the cyclic calls (SetMode, SetTarget*, status)
// do no I/O and do not allocate.

#include <chrono>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <system_error>
#include <vector>

#include "common/clock.h"
#include "hal/can/can_frame.h"
#include "hal/canopen/canopen_codec.h"
#include "hal/canopen/sdo_client.h"
#include "hal/drive/cia402.h"
#include "hal/drive/motor_drive.h"

namespace kinevis::hal {

namespace canopen {
class CanopenMaster;
}
class Cia402DriveBus;

// Target limits in SI units (see motor_drive.h). A target outside them is refused with
// Errc::kInvalidArgument; finite position limits are also written to the drive (0x607D).
struct DriveLimits {
  double min_position = -std::numeric_limits<double>::infinity();
  double max_position = std::numeric_limits<double>::infinity();
  double max_velocity = std::numeric_limits<double>::infinity();  // |target velocity|, > 0
  double max_torque = std::numeric_limits<double>::infinity();    // |target torque|, > 0
};

// What a transport-independent CiA 402 drive needs to know.
struct Cia402DriveOptions {
  // The drive's own name ("hexapod/leg3"); the driver adds the bus and the node or unit:
  // "hexapod/leg3 (virtual:hexapod node 3)". Empty: "drive".
  std::string name;
  DriveScaling scaling;
  DriveLimits limits;
  DriveMode mode = DriveMode::kCyclicSynchronousPosition;  // set at Configure()
  // Written at Configure() when > 0, else the drive keeps its own: profile velocity (SI/s) and
  // acceleration (SI/s^2) of the profile modes, converted with velocity_counts_per_unit, and the
  // following error window (SI), converted with position_counts_per_unit.
  double profile_velocity = 0.0;
  double profile_acceleration = 0.0;
  double following_error_window = 0.0;
  // How long Configure() waits for the first process data, and Disable(), QuickStop() and
  // FaultReset() for the drive to confirm; > 0.
  std::chrono::milliseconds command_timeout{1000};
};

// Empty when the options are valid; else every bad field and its value, separated by "; ".
std::string ValidateCia402DriveOptions(const Cia402DriveOptions& options);

// What Configure() read from the device.
struct DriveIdentity {
  uint32_t device_type = 0;      // 0x1000 (CANopen only)
  uint32_t vendor_id = 0;        // 0x1018.1
  uint32_t product_code = 0;     // 0x1018.2
  uint32_t revision = 0;         // 0x1018.3 (CANopen only)
  uint32_t serial_number = 0;    // 0x1018.4
  std::string device_name;       // 0x1008 (CANopen only; empty when the drive has none)
  uint32_t supported_modes = 0;  // 0x6502: bit (mode - 1) per mode
};

// "8 (cyclic synchronous position), 9, 10": the modes of a 0x6502 value, for messages.
std::string SupportedModesText(uint32_t supported_modes);

class Cia402HostDrive : public MotorDrive {
 public:
  const std::string& name() const override { return name_; }
  common::DeviceLifecycle lifecycle() const override { return lifecycle_; }

  std::error_code Enable(std::chrono::milliseconds timeout, bool reset_fault = false) override;
  std::error_code Disable() override;
  std::error_code QuickStop() override;
  std::error_code FaultReset() override;
  std::error_code SetMode(DriveMode mode) override;
  std::error_code SetTargetPosition(double position) override;
  std::error_code SetTargetVelocity(double velocity) override;
  std::error_code SetTargetTorque(double torque) override;
  DriveStatus status() const override { return status_; }
  DriveCounters counters() const override { return counters_; }

  // Bring-up and tests: sends the controlword of one state machine command as it is (a fault
  // reset as its rising edge, 0x00 then 0x80), cycle after cycle, until the drive reports a state
  // other than the one it was in, or `timeout` passes; then holds the state reached. Unlike
  // Enable() it does not choose the path (Cia402NextCommand), so any row of kCia402Transitions
  // can be exercised (3 with "enable operation" from Ready to switch on, 16 from Quick stop
  // active). Returns {} with *reached set, Errc::kTimeout when the state did not change (the
  // command does not apply there), Errc::kNotActive before Configure(). Reaching Operation
  // enabled makes the drive active; leaving it this way is not a fault.
  std::error_code SendCommand(Cia402Command command, std::chrono::milliseconds timeout,
                              Cia402State* reached = nullptr);

  // Why the last command failed or the drive faulted, naming the drive:
  // "leg3 (virtual:hexapod node 3): heartbeat lost: none for 60 ms (consumer time 60 ms)".
  // Empty while nothing has gone wrong.
  std::string last_error_text() const override { return last_error_text_; }
  const DriveIdentity& identity() const { return identity_; }
  const Cia402DriveOptions& options() const { return options_; }
  // The mode sent to the drive (status().mode is what the drive reports).
  DriveMode requested_mode() const { return mode_; }
  // The controlword sent in the last cycle.
  uint16_t last_controlword() const { return last_controlword_; }

 protected:
  friend class Cia402DriveBus;  // group enable/disable, fault policy
  // Process data of one cycle in drive units (the register / PDO contents).
  struct ProcessOutputs {
    uint16_t controlword = 0;
    int8_t mode = 0;
    int32_t target_position = 0;  // counts
    int32_t target_velocity = 0;  // counts/s
    int16_t target_torque = 0;    // per mille
  };
  struct ProcessInputs {
    uint16_t statusword = 0;
    int8_t mode_display = 0;
    int32_t position = 0;  // counts
    int32_t velocity = 0;  // counts/s
    int16_t torque = 0;    // per mille
    uint16_t error_code = 0;
  };

  // options must be valid (the bus validates them and throws ConfigError).
  Cia402HostDrive(Cia402DriveOptions options, std::string name);

  // ---- transport hooks
  // Runs bus cycles at the bus's period until done() or the clock passes deadline; at least one.
  // Returns done().
  virtual bool RunCyclesUntil(common::Duration deadline, const std::function<bool()>& done) = 0;
  virtual common::Clock& clock() const = 0;
  // Before a fault reset: make the link usable again (CANopen: heartbeat present, NMT start).
  // Returns {} or the reason it cannot (and sets the error text through SetError).
  virtual std::error_code RestoreLink() = 0;

  // ---- the blocking commands in three steps, so that a bus can run them for all its drives at
  // once: Begin*() refuses (error) or sets the goal; *Settled() is the predicate to run cycles
  // until; Finish*() decides the outcome once the cycles stopped.
  std::error_code BeginEnable(bool reset_fault);
  bool EnableSettled() const;
  std::error_code FinishEnable(common::Duration started);
  std::error_code BeginDisable();
  bool DisableSettled() const;
  std::error_code FinishDisable();
  std::error_code BeginQuickStop();
  bool QuickStopSettled() const;
  std::error_code FinishQuickStop();
  std::error_code BeginFaultReset(bool* nothing_to_do);
  bool FaultResetSettled() const;
  std::error_code FinishFaultReset();

  // ---- for the bus (called on the bus's thread, no allocation unless something goes wrong)
  // The outputs of the coming cycle; also marks the inputs as not yet fresh.
  void ComposeOutputs(ProcessOutputs* out);
  // Inputs received in this cycle.
  void ApplyInputs(const ProcessInputs& in, common::Duration timestamp, uint64_t cycle);
  // The host lost the drive (heartbeat, link): fault with DriveFaultSource::kLink.
  void OnLinkLost(const std::string& cause);
  // The link works again; the drive stays in fault until FaultReset().
  void OnLinkRestored();
  bool link_lost() const { return link_lost_; }
  // The drive reported a fault by itself (EMCY): fault with DriveFaultSource::kDevice.
  void OnDeviceFault(uint16_t error_code, const std::string& cause);
  // Another drive of the bus faulted: quick stop this one (if it is active).
  void SafeStop(const std::string& reason);
  // True once per new fault (for the bus's quick-stop-all policy).
  bool TakeNewFault();
  // After a successful configuration: -> configured, state unknown until the first inputs.
  void SetConfigured(DriveIdentity identity);
  void SetUnconfigured();
  // Records a failure text "<name>: <cause>" and logs it at `level` (spdlog level number).
  void SetError(const std::string& cause, int level);
  bool inputs_fresh() const { return fresh_; }

  DriveCounters counters_;
  DriveIdentity identity_;

 private:
  uint16_t NextControlword();
  void EnterFault(DriveFaultSource source, uint16_t error_code, const std::string& cause);
  void HoldTargets();
  std::error_code FaultError() const;
  bool Supported(DriveMode mode) const;
  std::error_code CheckedCounts(double value, double scale, double limit_lo, double limit_hi,
                                int64_t type_min, int64_t type_max, int64_t* counts) const;

  const std::string name_;
  const Cia402DriveOptions options_;
  common::DeviceLifecycle lifecycle_ = common::DeviceLifecycle::kUnconfigured;
  DriveStatus status_;
  bool fresh_ = false;  // inputs arrived in the current cycle
  bool state_known_ = false;
  std::string last_error_text_;

  // Command side.
  Cia402State goal_ = Cia402State::kSwitchOnDisabled;
  bool allow_fault_reset_ = false;
  bool forcing_ = false;  // SendCommand() in progress
  Cia402Command forced_command_ = Cia402Command::kNone;
  uint16_t fault_word_ = 0x00;  // controlword sent while in fault: 0x00 or 0x02 (quick stop)
  uint16_t last_controlword_ = 0;
  DriveMode mode_ = DriveMode::kCyclicSynchronousPosition;
  int32_t target_position_ = 0;
  int32_t target_velocity_ = 0;
  int16_t target_torque_ = 0;
  bool pp_request_ = false;  // a new profile-position set-point waits for its bit 4 edge
  int pp_hold_cycles_ = 0;
  int32_t actual_position_counts_ = 0;
  bool link_lost_ = false;
  bool new_fault_ = false;
};

struct Cia402CanDriveConfig {
  uint8_t node = 1;  // 1..127, unique on the bus
  Cia402DriveOptions drive;
  // Producer heartbeat time written to 0x1017 at Configure(), ms; 0 = no heartbeat (and no
  // supervision: a dead node is then noticed only by missing TPDOs, which do not fault it).
  std::chrono::milliseconds heartbeat_producer{20};
  // The host's consumer time: no heartbeat for this long -> link fault. 0 = 3 x producer.
  // Must exceed the producer time.
  std::chrono::milliseconds heartbeat_consumer{0};
};

class Cia402CanDrive final : public Cia402HostDrive {
 public:
  ~Cia402CanDrive() override;

  // Set-up over SDO, then NMT start; runs bus cycles until the first TPDOs came (state
  // readable). Throws HalError naming the drive, the step ("configure: read supported modes
  // 0x6502") and the SDO cause (abort code and text, timeout). Unconfigured -> configured (or
  // fault, when the drive already reports one).
  void Configure() override;

  uint8_t node() const { return config_.node; }
  const Cia402CanDriveConfig& config() const { return config_; }
  canopen::SdoClient& sdo() { return sdo_; }
  // The NMT state of the last heartbeat (nullopt before the first).
  std::optional<canopen::NmtState> nmt_state() const { return nmt_state_; }
  std::chrono::milliseconds heartbeat_consumer_time() const { return consumer_time_; }

 private:
  friend class canopen::CanopenMaster;
  Cia402CanDrive(canopen::CanopenMaster* master, Cia402CanDriveConfig config, std::string name);

  bool RunCyclesUntil(common::Duration deadline, const std::function<bool()>& done) override;
  common::Clock& clock() const override;
  std::error_code RestoreLink() override;

  // Configure() steps; each throws HalError on failure.
  template <typename T>
  void Write(uint16_t index, uint8_t subindex, T value, const char* what);
  template <typename T>
  bool Read(uint16_t index, uint8_t subindex, T* value, const char* what, bool optional);
  void MapPdo(uint16_t communication, uint16_t mapping, uint32_t cob_id,
              const canopen::PdoMappingEntry* entries, int count, const char* what);
  void DisablePdo(uint16_t communication, uint32_t cob_id, const char* what);
  [[noreturn]] void ThrowSdoFailure(const std::string& step, std::error_code ec);

  // ---- called by the master
  void EncodeRpdos(CanFrame* rpdo1, CanFrame* rpdo2);
  // A TPDO (0 or 1) arrived; false when its length does not fit the mapping.
  bool OnTpdo(int pdo, const CanFrame& frame);
  void OnHeartbeat(canopen::NmtState state, common::Duration now);
  void OnEmergency(const canopen::EmcyMessage& emcy);
  // Heartbeat supervision at `now`; true when the heartbeat was lost just now.
  bool SuperviseHeartbeat(common::Duration now);

  canopen::CanopenMaster* const master_;
  const Cia402CanDriveConfig config_;
  std::chrono::milliseconds consumer_time_;
  canopen::SdoClient sdo_;

  // PDO exchange state (master-owned logic).
  bool pdo_active_ = false;  // configured and started: RPDOs sent, TPDOs expected
  uint8_t tpdo_mask_ = 0;    // TPDOs received in the current cycle (bit 0 TPDO1, bit 1 TPDO2)
  ProcessInputs inputs_;     // the latest TPDO contents
  // Heartbeat consumer.
  bool heartbeat_supervised_ = false;
  bool heartbeat_lost_ = false;  // silent for the consumer time (a cause of link_lost())
  // An operational heartbeat came since NMT start: only then does a heartbeat with another
  // state mean the node left Operational (one sent before the start may still be on its way).
  bool seen_operational_ = false;
  common::Duration last_heartbeat_{0};
  std::optional<canopen::NmtState> nmt_state_;
  bool needs_configure_ = false;  // the node rebooted: its configuration is gone
};

}  // namespace kinevis::hal
