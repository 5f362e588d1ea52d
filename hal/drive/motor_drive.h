#pragma once

// The one interface of every motor drive kinevis controls (CiA 402 over CANopen, the RS485/Modbus
// drives of the DIAMOND), and of the bus that cycles a group of them.
//
// Units: SI at this interface. Position in rad (rotary) or m (linear), velocity in rad/s or m/s,
// torque in N·m or N. The driver converts to the drive's counts with the DriveScaling of its
// configuration, at this edge only.
//
// Lifecycle (STYLE.md): unconfigured -> Configure() -> configured (state readable) ->
// Enable() -> active (targets accepted) -> fault (a drive fault, a lost heartbeat, a dead link).
// Commands are refused with Errc::kNotActive unless active. Nothing in the cycle throws.
//
// The cycle: the controller sets targets on each drive (no I/O), calls DriveBus::Cycle() once
// per period (which exchanges targets and actual values with every drive of the bus: PDOs and
// SYNC on CANopen, register transfers on Modbus), then reads status().

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <system_error>
#include <vector>

#include "common/clock.h"
#include "common/lifecycle.h"
#include "hal/drive/cia402.h"

namespace kinevis::hal {

// Conversion between SI and the drive's units. counts = si * counts_per_unit.
struct DriveScaling {
  double position_counts_per_unit = 1.0;   // counts per rad (or per m), != 0
  double velocity_counts_per_unit = 1.0;   // (counts/s) per (rad/s), != 0
  double torque_per_mille_per_unit = 1.0;  // per mille of rated torque per N·m (or N), != 0
};

// Why a drive is in fault, kept apart: a link fault (the host lost the device) or a device fault
// (the device reports one).
enum class DriveFaultSource { kNone, kLink, kDevice };

struct DriveStatus {
  Cia402State state = Cia402State::kNotReadyToSwitchOn;
  uint16_t statusword = 0;
  std::optional<DriveMode> mode;  // modes of operation display, when known
  double position = 0.0;          // SI, see the top of this file
  double velocity = 0.0;
  double torque = 0.0;
  uint16_t error_code = 0;  // CiA 402 error code (0x603F / EMCY), 0 = none
  bool target_reached = false;
  bool following_error = false;
  DriveFaultSource fault_source = DriveFaultSource::kNone;
  common::Duration timestamp{0};  // when these values were sampled (bus clock)
  uint64_t cycle = 0;             // bus cycle that brought them
};

struct DriveCounters {
  uint64_t cycles = 0;           // exchanges completed
  uint64_t timeouts = 0;         // answers that did not come in time
  uint64_t crc_errors = 0;       // frames with a bad checksum (Modbus RTU, Dynamixel)
  uint64_t retries = 0;          // repeated requests
  uint64_t protocol_errors = 0;  // aborts, exception responses, malformed answers
  uint64_t emergencies = 0;      // EMCY messages (CANopen) or fault reports
  uint64_t link_losses = 0;      // heartbeat losses or dropped links
};

class MotorDrive {
 public:
  virtual ~MotorDrive() = default;

  // "hexapod/leg3 (socketcan:can0 node 3)": used in every log line and error.
  virtual const std::string& name() const = 0;
  virtual common::DeviceLifecycle lifecycle() const = 0;

  // Set-up (not in the cycle): reads the device's identity and configures it (PDO mapping, mode,
  // limits) -> configured. Throws HalError naming the drive and the step that failed.
  virtual void Configure() = 0;

  // Drives the CiA 402 state machine to Operation enabled through its transitions, clearing a
  // fault first if `reset_fault`, and waits at most `timeout` -> active. Returns
  // Errc::kTimeout naming nothing (the log names the state it stuck in), Errc::kDeviceFault when
  // the drive faults on the way, Errc::kNotActive before Configure().
  virtual std::error_code Enable(std::chrono::milliseconds timeout, bool reset_fault = false) = 0;
  // Disable voltage (-> Switch on disabled): the safe state. Allowed in every lifecycle but
  // unconfigured; the drive stops applying torque.
  virtual std::error_code Disable() = 0;
  // Quick stop: decelerates with the quick stop ramp, then (option code 0..4) disables.
  virtual std::error_code QuickStop() = 0;
  // Fault reset (rising edge of controlword bit 7); the drive goes to Switch on disabled.
  virtual std::error_code FaultReset() = 0;

  // Operation mode; takes effect at the next cycle. Errc::kUnsupported when the drive does not
  // list the mode in 0x6502.
  virtual std::error_code SetMode(DriveMode mode) = 0;
  // Targets in SI units for the next cycle (no I/O). Errc::kNotActive unless active,
  // Errc::kInvalidArgument when the value is not finite or out of the configured limits.
  virtual std::error_code SetTargetPosition(double position) = 0;
  virtual std::error_code SetTargetVelocity(double velocity) = 0;
  virtual std::error_code SetTargetTorque(double torque) = 0;

  // The values of the last completed cycle.
  virtual DriveStatus status() const = 0;
  virtual DriveCounters counters() const = 0;
  // Why the last command failed or the drive faulted, in one line naming the drive and the
  // cause; empty while nothing has gone wrong.
  virtual std::string last_error_text() const = 0;
};

// A group of drives exchanged together in one cycle (one CAN bus with a SYNC, one RS485 line).
class DriveBus {
 public:
  virtual ~DriveBus() = default;
  virtual const std::string& name() const = 0;
  // One exchange with every drive: sends the targets set since the last cycle, reads the actual
  // values, supervises heartbeats and links. Returns {} or the first fault of this cycle (each
  // drive's status says which); a faulted drive is put in a safe state by the bus itself.
  // Never throws, never allocates in steady state.
  virtual std::error_code Cycle() = 0;
  virtual std::vector<MotorDrive*> drives() = 0;
};

}  // namespace kinevis::hal
