#pragma once

// Errors of the hardware abstraction layer, in the three tiers of STYLE.md:
//  - run-time faults (timeouts, CRC errors, bus-off, a dropped link) are std::error_code values
//    of the kinevis::hal::Errc enum, returned from the cyclic calls and never thrown;
//  - bad input at set-up (a malformed backend string, a bad option) throws common::ConfigError
//    (common/config_error.h), which the CLI maps to exit code 2;
//  - a device that cannot be reached at set-up (no such port, connection refused) throws
//    HalError, which names the device, the operation and the cause; the CLI maps it to exit 3.

#include <stdexcept>
#include <string>
#include <system_error>
#include <vector>

#include "common/config_error.h"

namespace kinevis::hal {

enum class Errc {
  kTimeout = 1,      // no answer within the deadline
  kBusOff,           // CAN controller is bus-off; it sends nothing until recovered
  kClosed,           // the channel was closed (peer hung up, device unplugged)
  kIo,               // an operating-system I/O call failed (see the log for errno)
  kCrc,              // a frame arrived with a bad checksum
  kProtocol,         // a frame arrived that the protocol does not allow here
  kOverflow,         // a queue or buffer overflowed; data were lost
  kNotActive,        // the device is not in the active state; commands are refused
  kUnsupported,      // the backend cannot do this (e.g. RS485 ioctl on a pty)
  kDeviceFault,      // the device reports a fault of its own
  kInvalidArgument,  // a value out of range was passed in a cyclic call
  kModbusException,  // the Modbus server answered with an exception (see the log for which)
};

const std::error_category& HalCategory();
std::error_code make_error_code(Errc e);

// Thrown at set-up when a device cannot be opened or configured.
class HalError : public std::runtime_error {
 public:
  // device: the backend string or device name ("tty:/dev/ttyUSB0@1000000");
  // operation: what was attempted ("open", "set baud rate"); cause: why it failed.
  HalError(std::string device, std::string operation, std::string cause, std::error_code code = {});
  const std::string& device() const { return device_; }
  const std::string& operation() const { return operation_; }
  const std::string& cause() const { return cause_; }
  std::error_code code() const { return code_; }

 private:
  std::string device_, operation_, cause_;
  std::error_code code_;
};

// "strerror(errno)" with the errno name, for messages: "No such file or directory (ENOENT)".
std::string ErrnoText(int err);

}  // namespace kinevis::hal

namespace std {
template <>
struct is_error_code_enum<kinevis::hal::Errc> : true_type {};
}  // namespace std
