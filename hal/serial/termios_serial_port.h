#pragma once

// SerialPort through termios + poll(2). Works on hardware UARTs, USB serial adapters and
// pseudo-terminals alike (libserialport refuses ptys, so kinevis uses it only for discovery).

#include <memory>
#include <string>

#include "hal/serial/serial_port.h"

namespace kinevis::hal {

// Opens and configures settings.device: raw mode, the baud rate (any rate the kernel's
// termios2/BOTHER accepts, standard or not), the frame format, exclusive access (TIOCEXCL), and,
// when settings.rs485 is set, kernel RS485 direction control (TIOCSRS485; RTS high while sending).
// `name` is used in messages (default: "tty:" + device).
// Throws HalError naming the device, the step and the cause: no such device, permission denied,
// device busy, or RS485 not supported by the driver (e.g. a pty or a USB adapter that switches
// direction by itself: leave rs485 off for those).
std::unique_ptr<SerialPort> OpenSerialPort(const SerialSettings& settings,
                                           const std::string& name = "");

// Wraps an already-open descriptor (the master side of a pty). If `own` is true the port closes
// the descriptor on destruction. Does not change the line settings.
std::unique_ptr<SerialPort> AdoptSerialDescriptor(int fd, const SerialSettings& settings,
                                                  const std::string& name, bool own);

}  // namespace kinevis::hal
