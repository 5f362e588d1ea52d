#pragma once

// Dynamixel servos on a half-duplex serial bus (TTL or RS485 through a U2D2, USB2Dynamixel or any
// USB adapter that switches direction by itself), Protocol 1.0 or 2.0.
//
// Two layers:
//  - DynamixelBus: the transport and the instructions (ping, read, write, reg write + action,
//    sync write, bulk read (1.0), sync read (2.0), reboot (2.0)) with a per-request timeout,
//    bounded retries and counters. One request at a time; thread-safe.
//  - DynamixelServo: one servo on a bus, with its control table (hal/dynamixel/control_table.h),
//    the device lifecycle of STYLE.md and SI units (rad, rad/s).
//
// Run-time faults are std::error_code values (hal::Errc), never exceptions:
//   kTimeout          no (complete) status packet within the timeout, after every retry
//   kCrc              only corrupted status packets came, after every retry
//   kDeviceFault      the servo answered with a non-zero error field; the reply (and any data it
//                     carried: a servo in alarm still reports its position) is returned as well
//   kProtocol         an answer of the wrong length
//   kInvalidArgument  an id, address or length the protocol cannot carry
//   kUnsupported      an instruction the bus's protocol does not have (sync read on 1.0, ...)
//   kClosed, kIo      the serial port failed
// Each is counted and logged with the bus and the servo id. Set-up errors throw: ConfigError for
// a bad backend string or option, HalError when the port cannot be opened or a servo does not
// answer at Configure().
//
// Retries: after a timeout or a corrupted answer the request is sent again, at most `retries`
// times; a servo that does not answer at all costs timeout x (retries + 1). An answer with an
// error field is not retried (the servo heard the request). Before each attempt the input is
// flushed, so a late answer to an earlier attempt is never taken for the current one.
//
// Assumptions: status return level 2 (the factory setting: every instruction but broadcasts is
// answered) and an adapter that does not echo the host's bytes back.

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <system_error>
#include <vector>

#include "hal/drive/motor_drive.h"
#include "hal/dynamixel/control_table.h"
#include "hal/dynamixel/protocol1.h"
#include "hal/dynamixel/protocol2.h"
#include "hal/serial/serial_port.h"

namespace kinevis::hal {

struct DynamixelBusOptions {
  int protocol = 2;  // 1 or 2
  // How long to wait for each status packet after the request has been written. A status packet
  // comes after the servo's return delay time (factory setting 500 us) plus its transmission.
  std::chrono::microseconds timeout = std::chrono::milliseconds(30);
  int retries = 2;  // further attempts after a timeout or a corrupted answer, 0..10
};

struct DynamixelBusCounters {
  uint64_t requests = 0;         // instruction packets sent (retries included)
  uint64_t timeouts = 0;         // attempts that ended without the expected status packet(s)
  uint64_t crc_errors = 0;       // status packets with a bad checksum (1.0) or CRC (2.0)
  uint64_t retries = 0;          // repeated requests
  uint64_t status_errors = 0;    // status packets with a non-zero error field
  uint64_t protocol_errors = 0;  // answers of the wrong length or from an unexpected id
};

// One servo's answer.
struct DxlReply {
  uint8_t id = 0;
  uint8_t error = 0;          // the status packet's error field (Dxl1ErrorText / Dxl2ErrorText)
  std::vector<uint8_t> data;  // its parameters: read data, or ping's model number and firmware
  std::error_code ec;         // this servo's outcome (sync read, bulk read)
};

struct DxlWriteItem {
  uint8_t id = 0;
  std::vector<uint8_t> data;  // exactly `length` bytes of the sync write
};

struct DxlReadRequest {
  uint8_t id = 0;
  uint16_t address = 0;
  uint16_t length = 0;
};

class DynamixelBus {
 public:
  // Opens `backend`, "tty:/dev/ttyUSB0@1000000" (hal::ParseTtyBackend grammar). Throws
  // ConfigError for a malformed string or bad options, HalError when the port cannot be opened.
  static std::unique_ptr<DynamixelBus> Open(const std::string& backend,
                                            DynamixelBusOptions options);
  // Uses an open port; its name() names the bus. Throws ConfigError for bad options.
  DynamixelBus(std::unique_ptr<SerialPort> port, DynamixelBusOptions options);
  DynamixelBus(const DynamixelBus&) = delete;
  DynamixelBus& operator=(const DynamixelBus&) = delete;

  const std::string& name() const { return name_; }
  int protocol() const { return options_.protocol; }
  const DynamixelBusOptions& options() const { return options_; }
  DynamixelBusCounters counters() const;

  // id: 0..253 (1.0) or 0..252 (2.0); the broadcast id only where said.
  std::error_code Ping(uint8_t id, DxlReply* reply = nullptr);
  // Ping, and the model number and firmware version: from the ping answer (2.0), or read from
  // addresses 0..2 after the ping (1.0, whose ping answer is empty).
  std::error_code PingModel(uint8_t id, uint16_t* model_number, uint8_t* firmware = nullptr);
  // Reads `length` bytes (1..) from `address` into reply->data.
  std::error_code Read(uint8_t id, uint16_t address, uint16_t length, DxlReply* reply);
  // Writes `data` at `address`. With the broadcast id every servo executes it and none answers.
  std::error_code Write(uint8_t id, uint16_t address, const std::vector<uint8_t>& data,
                        DxlReply* reply = nullptr);
  // Like Write(), but the servo keeps the write until Action().
  std::error_code RegWrite(uint8_t id, uint16_t address, const std::vector<uint8_t>& data,
                           DxlReply* reply = nullptr);
  // Executes registered writes: of one servo (answered) or of all (broadcast, not answered).
  std::error_code Action(uint8_t id = kDxlBroadcastId);
  // Writes `length` bytes at `address` of several servos in one broadcast packet (no answer).
  std::error_code SyncWrite(uint16_t address, uint16_t length,
                            const std::vector<DxlWriteItem>& items);
  // Protocol 2.0: reads `length` bytes at `address` of each id; replies in the order of `ids`.
  std::error_code SyncRead(uint16_t address, uint16_t length, const std::vector<uint8_t>& ids,
                           std::vector<DxlReply>* replies);
  // Protocol 1.0: reads a different span of each servo; replies in the order of `requests`.
  std::error_code BulkRead(const std::vector<DxlReadRequest>& requests,
                           std::vector<DxlReply>* replies);
  // Protocol 2.0: the servo answers, then restarts (RAM to power-on values, torque off, hardware
  // error cleared); it does not answer while it restarts.
  std::error_code Reboot(uint8_t id);

 private:
  // Throws ConfigError naming the bus and every bad option.
  static void CheckOptions(const std::string& name, const DynamixelBusOptions& options);

  // Fills tx_ with the request for the ids still waiting for an answer (all of them at the first
  // attempt); false when the request cannot be encoded.
  using Encoder = std::function<bool(const std::vector<uint8_t>& pending)>;

  // One request with retries. `expected` lists the ids whose status packets answer it, in order
  // (empty: a broadcast nobody answers); *replies gets one DxlReply per expected id. Returns the
  // first failing reply's code, or {}.
  std::error_code TransactLocked(const char* what, const std::vector<uint8_t>& expected,
                                 const Encoder& encode, std::vector<DxlReply>* replies);
  // Waits for the status packets of `pending` ids and moves each id that answered out of it.
  // Each packet restarts the timeout. Returns a link error of the port, or {}; *crc_errors
  // counts corrupted packets seen.
  std::error_code CollectLocked(std::vector<uint8_t>* pending, std::vector<DxlReply>* replies,
                                const std::vector<uint8_t>& expected, uint64_t* crc_errors);
  // Encodes an instruction packet of params_ into tx_.
  bool EncodeLocked(uint8_t id, DxlInstruction instruction);
  // A single-servo request (or a broadcast without answer when id is the broadcast id).
  std::error_code SimpleRequest(const char* what, uint8_t id, DxlInstruction instruction,
                                std::vector<uint8_t> params, DxlReply* reply);
  std::error_code CheckId(uint8_t id, bool broadcast_ok) const;
  std::error_code CheckLength(DxlReply* reply, size_t length);
  void Count(uint64_t DynamixelBusCounters::*field, uint64_t n = 1);

  const std::unique_ptr<SerialPort> port_;
  const DynamixelBusOptions options_;
  const std::string name_;

  std::mutex mutex_;  // one request at a time; guards everything below but the counters
  std::vector<uint8_t> params_;
  std::vector<uint8_t> tx_;
  std::vector<uint8_t> rx_;
  Dxl1Decoder decoder1_{DxlPacketKind::kStatus};
  Dxl2Decoder decoder2_{DxlPacketKind::kStatus};

  mutable std::mutex counters_mutex_;
  DynamixelBusCounters counters_;
};

// The state of a servo as last read, in SI units.
struct DxlServoState {
  double position = 0.0;       // rad, 0 at tick 0
  double velocity = 0.0;       // rad/s, positive counter-clockwise
  std::optional<double> load;  // in the unit of the table's present_load register (1.0: ratio
                               // of the maximum torque; XM430: A); absent when not in the table
  bool moving = false;
  bool torque_enabled = false;
  uint8_t status_error = 0;    // error field of the last status packet
  uint8_t hardware_error = 0;  // 2.0: Hardware Error Status; 1.0: the alarm bits of the error
                               // field (input voltage, overheating, overload)
};

struct DynamixelServoOptions {
  // How long Reboot() waits for the servo to answer pings again.
  std::chrono::milliseconds reboot_timeout{1000};
};

// One servo. Lifecycle (STYLE.md): unconfigured -> Configure() -> configured (state readable) ->
// Enable() -> active (torque on; goal position and profile velocity accepted) -> fault (the servo
// reports a hardware alarm: overload, overheating, input voltage, ...). Commands are refused with
// Errc::kNotActive unless active. Disable() (torque off) is the safe state. Leaving the fault
// state: ClearFault(), which reboots a 2.0 servo; a 1.0 servo must be power-cycled first.
// Not thread-safe: use one servo object from one thread; servos of one bus may live in different
// threads (the bus serialises their requests).
class DynamixelServo {
 public:
  // `bus` must outlive the servo. Throws ConfigError when the table's protocol differs from the
  // bus's or the id is out of range.
  DynamixelServo(DynamixelBus* bus, uint8_t id, DxlControlTable table,
                 DynamixelServoOptions options = {});

  // "tty:/dev/ttyUSB0@1000000 servo 1 (mx-12w)": in every log line and error.
  const std::string& name() const { return name_; }
  uint8_t id() const { return id_; }
  const DxlControlTable& table() const { return table_; }
  common::DeviceLifecycle lifecycle() const { return lifecycle_; }
  // Joint limits read at Configure(), rad.
  double min_position() const { return min_position_; }
  double max_position() const { return max_position_; }
  const DxlServoState& state() const { return state_; }

  // Pings the servo, checks its model number against the table, reads its angle limits and its
  // state -> configured (or fault when the servo reports an alarm). Does not change the torque.
  // Throws HalError naming the servo, the step and the cause: no answer, another model, or limits
  // that put it in wheel or multi-turn mode (kinevis drives joint mode only).
  void Configure();
  // Sets the goal to the present position (no jump), then torque on -> active. kNotActive before
  // Configure(), kDeviceFault in fault.
  std::error_code Enable();
  // Torque off, the safe state: active -> configured; a faulted servo stays in fault.
  std::error_code Disable();
  // Goal position, rad, within [min_position(), max_position()]; kInvalidArgument outside or not
  // finite, kNotActive unless active.
  std::error_code SetGoalPosition(double position);
  // Speed towards the goal, rad/s >= 0; 0 = as fast as the servo can. kInvalidArgument beyond
  // the register's range.
  std::error_code SetProfileVelocity(double velocity);
  // Reads position, velocity, load, moving, torque and alarms (configured, active or fault);
  // an alarm moves the servo to fault and turns its torque off.
  std::error_code ReadState(DxlServoState* state = nullptr);
  // 2.0 only (kUnsupported on 1.0): reboots and waits for the servo to answer again ->
  // configured (torque off after a reboot).
  std::error_code Reboot();
  // Fault -> configured: 2.0 reboots; 1.0 checks that the alarm is gone (after a power cycle),
  // else kDeviceFault.
  std::error_code ClearFault();

 private:
  std::error_code WriteRegister(DxlRole role, int64_t raw);
  // Looks at a status error field; an alarm sends the servo to fault.
  void CheckAlarm(uint8_t status_error, uint8_t hardware_error);
  void EnterFault(const std::string& why);
  uint8_t AlarmBits(uint8_t status_error) const;

  DynamixelBus* const bus_;
  const uint8_t id_;
  const DxlControlTable table_;
  const DynamixelServoOptions options_;
  const std::string name_;
  // The span ReadState() reads: from the lowest to the highest state register.
  uint16_t state_address_ = 0;
  uint16_t state_length_ = 0;

  common::DeviceLifecycle lifecycle_ = common::DeviceLifecycle::kUnconfigured;
  double min_position_ = 0.0;
  double max_position_ = 0.0;
  DxlServoState state_;
};

}  // namespace kinevis::hal
