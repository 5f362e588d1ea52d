#pragma once

// A serial line (RS232, RS485, USB CDC, or a pseudo-terminal) as a byte stream with deadlines.
// The one implementation does its I/O through termios and poll(2), which works alike on
// hardware UARTs, USB adapters and ptys (hal/serial/termios_serial_port.h).

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <string>
#include <system_error>

#include "hal/common/backend_spec.h"

namespace kinevis::hal {

class SerialPort {
 public:
  virtual ~SerialPort() = default;

  // "tty:/dev/ttyUSB0@1000000": the backend string or device path; used in every log line.
  virtual const std::string& name() const = 0;

  // Reads up to `size` bytes into `buffer`. Waits at most `timeout` for the first byte, then
  // returns what is available without further waiting. *n_read is set in every case.
  // Returns {} (with *n_read > 0), Errc::kTimeout (*n_read == 0), Errc::kClosed or Errc::kIo.
  virtual std::error_code Read(uint8_t* buffer, size_t size, std::chrono::microseconds timeout,
                               size_t* n_read) = 0;

  // Writes all `size` bytes, waiting at most `timeout` in total for the line to take them.
  // Returns {}, Errc::kTimeout (some bytes may have been written), Errc::kClosed or Errc::kIo.
  virtual std::error_code WriteAll(const uint8_t* data, size_t size,
                                   std::chrono::microseconds timeout) = 0;

  // Discards bytes received but not yet read.
  virtual std::error_code FlushInput() = 0;
  // Waits until every written byte has left the UART (tcdrain).
  virtual std::error_code Drain() = 0;

  // The settings in force (device, baud, frame format, rs485).
  virtual const SerialSettings& settings() const = 0;
};

}  // namespace kinevis::hal
