#pragma once

// The RS485 motor drives of the DIAMOND's motor arms: Modbus RTU at up to 3 Mbit/s, with the
// register map of hal/drive/rs485_drive_registers.h, which carries the CiA 402 semantics
// (controlword, statusword, modes, targets and actual values), so the state machine, the modes
// and the lifecycle are those of Cia402HostDrive (hal/drive/cia402_can_drive.h).
//
// Rs485DriveBus is one line ("modbus-rtu:/dev/ttyUSB0@3000000,8E1,timeout_ms=20,retries=0") with
// several drives, each at its own unit id. Cycle() makes one function-0x17 transaction
// (write-and-read) per drive: it writes the 7 cyclic outputs kRegControlword..kRegTargetTorque and
// reads the 10 cyclic inputs from kRegStatusword.
//
// Faults, kept apart:
//  - link errors: no answer (timeout), a dead line (closed), a bad CRC or a mismatched answer.
//    They are counted (DriveCounters::timeouts, crc_errors, retries) and returned by Cycle();
//    max_missed_cycles consecutive failed exchanges -> the drive faults with
//    DriveFaultSource::kLink. A drive in link fault is then polled only every
//    faulted_poll_cycles cycles (with "quick stop" as its controlword), so that a dead drive does
//    not cost a timeout in every cycle of the others.
//  - device errors: the statusword reports Fault (error code from kRegErrorCode, with its text),
//    or the drive answers with a Modbus exception (counted as a protocol error; the outputs of
//    that cycle were not applied).
// The drive's communication watchdog (kRegWatchdogMs) is set at Configure(): a drive that hears
// nothing for that long faults by itself (error code 0x8130) and stops, so the host must keep
// cycling once a drive is configured.
//
// Transport: one hal::ModbusClient per line, shared by the drives of the bus; each drive
// addresses it with its unit id (ModbusClient::SetUnit) before every request, one after the
// other from the bus's thread, so requests never overlap on the line. Client counters are
// attributed to the drive that made the requests.
// Threading as for the CANopen drives: everything on one thread.

#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <system_error>
#include <vector>

#include "common/clock.h"
#include "hal/common/backend_spec.h"
#include "hal/drive/cia402_can_drive.h"
#include "hal/drive/cia402_drive_bus.h"
#include "hal/drive/motor_drive.h"
#include "hal/modbus/modbus_client.h"

namespace kinevis::hal {

class Rs485DriveBus;

struct Rs485DriveConfig {
  int unit = 1;  // Modbus unit id, 1..247, unique on the line
  Cia402DriveOptions drive;
  // Written to kRegWatchdogMs at Configure(), 0..65535 ms; 0 = the drive does not supervise.
  std::chrono::milliseconds watchdog{200};
};

class Rs485Drive final : public Cia402HostDrive {
 public:
  ~Rs485Drive() override;

  // Reads the identity and supported modes (kRegVendorId..kRegSupportedModes), writes the mode,
  // profile, following error window, position limits and the watchdog, then runs bus cycles until
  // the first inputs came. Throws HalError naming the drive, the step and the Modbus cause.
  void Configure() override;

  int unit() const { return config_.unit; }
  const Rs485DriveConfig& config() const { return config_; }
  // The line's client, addressed to this drive's unit.
  ModbusClient& client() { return Client(); }
  // The following error the drive reported in the last cycle (kRegFollowingErrorActual), SI.
  double following_error_actual() const { return following_error_actual_; }

 private:
  friend class Rs485DriveBus;
  Rs485Drive(Rs485DriveBus* bus, Rs485DriveConfig config, std::string name,
             std::shared_ptr<ModbusClient> client);

  bool RunCyclesUntil(common::Duration deadline, const std::function<bool()>& done) override;
  common::Clock& clock() const override;
  std::error_code RestoreLink() override;

  // One write-and-read exchange; called by the bus. Returns {} or the exchange's error.
  std::error_code Exchange(common::Duration now, uint64_t cycle);
  [[noreturn]] void ThrowModbusFailure(const std::string& step, std::error_code ec);
  void WriteU32(uint16_t address, uint32_t value, const char* what);
  void WriteU16(uint16_t address, uint16_t value, const char* what);
  // The shared client, addressed to this drive; attributes the counters of the previous user.
  ModbusClient& Client();
  // Adds the client counters since this drive took the client to this drive's counters.
  void SyncClientCounters();

  Rs485DriveBus* const bus_;
  const Rs485DriveConfig config_;
  std::shared_ptr<ModbusClient> client_;
  bool exchanging_ = false;  // configured: exchanged in every cycle
  int missed_cycles_ = 0;    // consecutive failed exchanges
  double following_error_actual_ = 0.0;
  ModbusClientCounters client_base_;  // client counters when this drive last took the client
};

struct Rs485DriveBusOptions {
  common::Clock* clock = nullptr;  // nullptr: SteadyClock::Instance()
  // Period of the cycles the bus runs itself (Configure, Enable, ...), > 0.
  std::chrono::microseconds cycle_period{2000};
  int max_missed_cycles = 3;            // consecutive failed exchanges before a link fault, >= 1
  int faulted_poll_cycles = 50;         // a drive in link fault is exchanged every N cycles, >= 1
  bool quick_stop_all_on_fault = true;  // as CanopenMasterOptions
};

class Rs485DriveBus final : public Cia402DriveBus {
 public:
  // backend: a "modbus-rtu:" backend string (its unit option is ignored: each drive has its own).
  // Throws ConfigError for a malformed string, another scheme, or invalid options. The line is
  // opened by AddDrive().
  explicit Rs485DriveBus(std::string backend, Rs485DriveBusOptions options = {});
  ~Rs485DriveBus() override;
  Rs485DriveBus(const Rs485DriveBus&) = delete;
  Rs485DriveBus& operator=(const Rs485DriveBus&) = delete;

  // Opens the drive's Modbus client. Throws ConfigError (bad or duplicate unit, invalid
  // options) or HalError (the serial device cannot be opened).
  Rs485Drive* AddDrive(const Rs485DriveConfig& config);
  Rs485Drive* AddDrive(int unit, const DriveScaling& scaling, const DriveLimits& limits = {});

  const std::string& name() const override { return name_; }
  std::error_code Cycle() override;
  std::vector<MotorDrive*> drives() override;
  Rs485Drive* drive(int unit) const;

  // ConfigureAll, EnableAll, DisableAll, RunCyclesUntil, clock(): see Cia402DriveBus.
  // The orderly end of the host: disables every configured drive, then switches its watchdog
  // off (a disabled drive needs no supervision, and the next host then finds it without a
  // watchdog fault) and stops exchanging with it (Configure() again to use it). Returns the
  // first error; every drive is attempted.
  std::error_code Close();

  const ModbusBackendSpec& spec() const { return spec_; }
  const Rs485DriveBusOptions& options() const { return options_; }
  uint64_t cycle_count() const { return cycles_; }

 private:
  friend class Rs485Drive;

  const std::string name_;
  ModbusBackendSpec spec_;
  const Rs485DriveBusOptions options_;
  // The line's client, opened by the first AddDrive and shared by every drive; the drive that
  // used it last (for counter attribution, see Rs485Drive::Client()).
  std::shared_ptr<ModbusClient> client_;
  Rs485Drive* client_user_ = nullptr;
  std::vector<std::unique_ptr<Rs485Drive>> drives_;
  uint64_t cycles_ = 0;
};

}  // namespace kinevis::hal
