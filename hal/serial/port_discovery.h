#pragma once

// Serial port discovery through libserialport: what `kinevis ports` lists, and what a
// deployment file's "tty:/dev/ttyUSB0" can be checked against.
//
// libserialport 0.1.1 finds ports through /sys/class/tty metadata, so pseudo-terminals
// (/dev/pts/N, including the PtyPair of simulators) are not listed; kinevis opens every port,
// pty or not, with OpenSerialPort() (hal/serial/termios_serial_port.h) and uses libserialport
// for discovery only.

#include <string>
#include <vector>

namespace kinevis::hal {

struct SerialPortInfo {
  std::string path;           // "/dev/ttyUSB0", as OpenSerialPort() takes it
  std::string description;    // libserialport's one-line description ("FT232R USB UART - FT232R")
  std::string transport;      // "usb", "native" (on-board UART) or "bluetooth"
  std::string manufacturer;   // USB only; empty when unknown
  std::string product;        // USB only; empty when unknown
  std::string serial_number;  // USB only; empty when unknown
  int usb_vid = -1;           // USB vendor id 0..0xFFFF; -1 when not USB or unknown
  int usb_pid = -1;           // USB product id 0..0xFFFF; -1 when not USB or unknown
};

// Every serial port of the machine, sorted by path. A machine without serial hardware gives an
// empty list, which is not an error. Throws HalError (device "serial ports") when libserialport
// itself fails (SP_ERR_FAIL, SP_ERR_MEM, SP_ERR_SUPP), with its message.
std::vector<SerialPortInfo> ListSerialPorts();

}  // namespace kinevis::hal
