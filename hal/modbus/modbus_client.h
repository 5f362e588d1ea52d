#pragma once

// A Modbus client (master) over libmodbus, for Modbus TCP and Modbus RTU, opened from a backend
// string ("modbus-tcp:192.168.0.10:502", "modbus-rtu:/dev/ttyUSB0@115200,8E1,unit=3"; see
// hal/common/backend_spec.h and docs/modbus.md).
//
// Faults at run time come back as std::error_code, never as exceptions, and are counted:
//  - a Modbus exception response: a ModbusErrc code carrying the exception's name
//    ("ILLEGAL DATA ADDRESS (Modbus exception 2)"); never retried;
//  - no complete answer within spec.timeout_ms: hal::Errc::kTimeout, after spec.retries further
//    attempts;
//  - a dropped link (peer closed, connection reset, device unplugged, reconnect refused):
//    hal::Errc::kClosed, after spec.retries further attempts, each of which first reconnects;
//  - a corrupt or mismatched answer: ModbusErrc::kBadCrc, kBadData, kBadSlave, ...; not retried.
// An operation therefore returns within about (spec.retries + 1) x 2 x spec.timeout_ms in the
// worst case (each attempt may have to connect, then wait for the answer).
//
// A late answer must never be taken for the answer to the next request. On TCP the client
// therefore closes the connection after a timeout and reconnects for the next attempt (counted
// in reconnects). On RTU it discards the input received so far before the next request; serial
// Modbus has no transaction id, so an answer arriving later than that, during the next request
// of the same shape, cannot be told apart: choose timeout_ms above the device's slowest answer.
//
// Every failure is counted (counters()) and logged with the device name: as a warning, except
// that the same error again within 10 s is logged at debug level only, so that a device failing
// every cycle neither floods the log nor costs an allocation per cycle. A dropped link is a
// warning too (at most one per 10 s), even when the retry on a new connection succeeds.
//
// Threading: a ModbusClient owns one libmodbus context and must be used from one thread at a
// time (libmodbus contexts are not thread-safe). Give each thread its own client if several
// threads talk to the same device.
//
// The operations do not throw and do not allocate (only the warning for a new kind of failure
// does); Open() throws at set-up.

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <system_error>

#include "hal/common/backend_spec.h"

namespace kinevis::hal {

// Modbus-specific faults. Values 1..11 are the exception codes of the Modbus Application Protocol
// Specification V1.1b3, section 7; the others are failures libmodbus detects in a response.
// Timeouts and link failures are hal::Errc::kTimeout and hal::Errc::kClosed instead.
enum class ModbusErrc {
  kNone = 0,                           // not an error; a server hook returns it to accept a request
  kIllegalFunction = 1,                // ILLEGAL FUNCTION
  kIllegalDataAddress = 2,             // ILLEGAL DATA ADDRESS
  kIllegalDataValue = 3,               // ILLEGAL DATA VALUE
  kServerDeviceFailure = 4,            // SERVER DEVICE FAILURE
  kAcknowledge = 5,                    // ACKNOWLEDGE
  kServerDeviceBusy = 6,               // SERVER DEVICE BUSY
  kNegativeAcknowledge = 7,            // NEGATIVE ACKNOWLEDGE
  kMemoryParityError = 8,              // MEMORY PARITY ERROR
  kGatewayPathUnavailable = 10,        // GATEWAY PATH UNAVAILABLE
  kGatewayTargetFailedToRespond = 11,  // GATEWAY TARGET DEVICE FAILED TO RESPOND
  kBadCrc = 101,                       // response with a bad CRC (RTU; libmodbus EMBBADCRC)
  kBadData,                            // response does not match the request (EMBBADDATA)
  kBadException,                       // malformed exception response (EMBBADEXC)
  kUnknownException,                   // exception code outside the specification (EMBUNKEXC)
  kTooManyData,                        // more values than one frame can carry (EMBMDATA)
  kBadSlave,                           // response from another unit (EMBBADSLAVE)
};

const std::error_category& ModbusCategory();
std::error_code make_error_code(ModbusErrc e);

// True when `ec` is a Modbus exception response (ModbusCategory, codes 1..11).
bool IsModbusException(std::error_code ec);

struct ModbusClientCounters {
  uint64_t requests = 0;    // operations called (one per call, however many attempts it took)
  uint64_t failures = 0;    // operations that returned an error
  uint64_t timeouts = 0;    // attempts that got no complete answer within timeout_ms
  uint64_t crc_errors = 0;  // answers with a bad CRC
  uint64_t exceptions = 0;  // Modbus exception responses
  uint64_t retries = 0;     // attempts after the first one of an operation
  uint64_t reconnects = 0;  // connections made after Open()'s: after a dropped link, and on TCP
                            // after a timeout
};

class ModbusClient {
 public:
  // Limits of one request (Modbus Application Protocol V1.1b3, section 6).
  static constexpr int kMaxReadRegisters = 125;
  static constexpr int kMaxWriteRegisters = 123;
  static constexpr int kMaxReadBits = 2000;
  static constexpr int kMaxWriteBits = 1968;
  static constexpr int kMaxWriteAndReadWriteRegisters = 121;
  static constexpr int kMaxWriteAndReadReadRegisters = 125;

  // Connects to the device and returns the client.
  //  - TCP: resolves spec.host (name, IPv4 or IPv6 address) and connects to spec.port, waiting at
  //    most spec.timeout_ms. Throws HalError naming "HOST:PORT" and the errno text when the
  //    connection is refused, times out or the host does not resolve.
  //  - RTU: opens spec.serial.device with spec.serial's baud rate and frame format. Throws
  //    ConfigError for a baud rate libmodbus cannot set (it knows the standard termios rates,
  //    110..4000000 bit/s except 2000000), and HalError when the device cannot be opened, or when
  //    spec.serial.rs485 is set and the driver has no kernel RS485 direction control (a pty, most
  //    USB adapters: leave rs485 off for those).
  // spec.unit is the unit (slave) id every request is addressed to. Unit 0 on RTU is the
  // broadcast address: writes are sent without waiting for an answer (none comes), reads are
  // refused with Errc::kInvalidArgument. On TCP unit 0 is an ordinary unit id.
  static std::unique_ptr<ModbusClient> Open(const ModbusBackendSpec& spec);
  // Parses `backend` with ParseModbusBackend (throws ConfigError), then opens it as above.
  static std::unique_ptr<ModbusClient> Open(std::string_view backend);

  ~ModbusClient();
  ModbusClient(const ModbusClient&) = delete;
  ModbusClient& operator=(const ModbusClient&) = delete;

  // The backend string the client was opened with; used in every log line.
  const std::string& name() const;
  const ModbusBackendSpec& spec() const;
  // False after a dropped link (and on TCP after a timeout) until the next operation has
  // reconnected.
  bool connected() const;
  // Addresses the following requests to `unit` (0..247; RTU unit 0 = broadcast), so that one
  // client serves every device of a multi-drop line. No I/O; Errc::kInvalidArgument when out of
  // range.
  std::error_code SetUnit(int unit);

  // Every operation below: `address` is the protocol (PDU) address of the first item, 0..65535,
  // and address + count must not exceed 65536; counts are limited as the constants above say.
  // A bad address or count returns Errc::kInvalidArgument and sends nothing. Otherwise the
  // result is {} or one of the faults listed at the top of this file. Output buffers are written
  // only on success.

  // Function 0x03: `count` holding registers into out[0..count).
  std::error_code ReadHoldingRegisters(int address, int count, uint16_t* out);
  // Function 0x04: `count` input registers into out[0..count).
  std::error_code ReadInputRegisters(int address, int count, uint16_t* out);
  // Function 0x06: one holding register.
  std::error_code WriteRegister(int address, uint16_t value);
  // Function 0x10: values[0..count) into `count` holding registers.
  std::error_code WriteRegisters(int address, int count, const uint16_t* values);
  // Function 0x16: register = (register AND and_mask) OR (or_mask AND NOT and_mask).
  std::error_code MaskWriteRegister(int address, uint16_t and_mask, uint16_t or_mask);
  // Function 0x01: `count` coils into out[0..count), one byte per coil, 0 or 1.
  std::error_code ReadCoils(int address, int count, uint8_t* out);
  // Function 0x02: `count` discrete inputs into out[0..count), one byte per input, 0 or 1.
  std::error_code ReadDiscreteInputs(int address, int count, uint8_t* out);
  // Function 0x05: one coil.
  std::error_code WriteCoil(int address, bool value);
  // Function 0x0F: values[0..count) into `count` coils, one byte per coil, non-zero = on.
  std::error_code WriteCoils(int address, int count, const uint8_t* values);
  // Function 0x17: writes values[0..write_count) at write_address, then reads read_count
  // holding registers from read_address into out[0..read_count), in one transaction.
  std::error_code WriteAndReadRegisters(int write_address, int write_count, const uint16_t* values,
                                        int read_address, int read_count, uint16_t* out);

  ModbusClientCounters counters() const;
  // The error of the last operation that failed ({} if none has).
  std::error_code last_error() const;
  // That error for a log line: device, operation, address, count, cause and attempts, e.g.
  // "modbus-tcp:127.0.0.1:502 unit 1: write register 0x00c8: ILLEGAL DATA ADDRESS (Modbus
  // exception 2) after 1 attempt". Allocates; call it from logging, not from the cyclic path.
  std::string last_error_text() const;

 private:
  struct Impl;
  explicit ModbusClient(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace kinevis::hal

namespace std {
template <>
struct is_error_code_enum<kinevis::hal::ModbusErrc> : true_type {};
}  // namespace std
