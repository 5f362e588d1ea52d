#pragma once

// Backend strings: one line of a deployment file or one command-line argument says which
// transport a device is reached through. The grammar and every option are documented in
// docs/backends.md; in short
//
//   socketcan:IFACE                                  Linux SocketCAN raw socket (can0, vcan0)
//   slcan:DEVICE[@BAUD][,bitrate=N][,listen][,timestamps]   Lawicel ASCII adapter on a serial port
//   virtual:NAME[,bitrate=N]                         in-process virtual CAN bus shared by NAME
//   tty:DEVICE[@BAUD][,8N1][,rs485]                  serial port through termios
//   modbus-tcp:HOST:PORT[,unit=N][,timeout_ms=N][,retries=N]
//   modbus-rtu:DEVICE[@BAUD][,8E1][,rs485][,unit=N][,timeout_ms=N][,retries=N]
//
// Parsers throw common::ConfigError naming the backend string, every bad field and its value.

#include <string>
#include <string_view>

namespace kinevis::hal {

// Serial line settings (termios or libmodbus RTU).
struct SerialSettings {
  std::string device;  // "/dev/ttyUSB0", "/dev/pts/5"
  int baud = 115200;   // bit/s
  int data_bits = 8;   // 5..8
  char parity = 'N';   // 'N', 'E' or 'O'
  int stop_bits = 1;   // 1 or 2
  bool rs485 = false;  // ask the kernel for RS485 direction control (TIOCSRS485)
};

struct CanBackendSpec {
  enum class Kind { kSocketCan, kSlcan, kVirtual };
  Kind kind = Kind::kVirtual;
  std::string text;          // the backend string as given
  std::string interface;     // socketcan interface name, or the virtual bus name
  SerialSettings serial;     // slcan: the serial port of the adapter
  int bitrate = 0;           // CAN bit rate in bit/s; 0 = keep the adapter's / no bit-rate model
  bool listen_only = false;  // slcan: open with 'L' (no ACKs, no transmission)
  bool timestamps = false;   // slcan: ask the adapter for millisecond timestamps ('Z1')
};

struct ModbusBackendSpec {
  enum class Kind { kTcp, kRtu };
  Kind kind = Kind::kTcp;
  std::string text;
  std::string host;       // tcp: host name or address (IPv6 in brackets in the string)
  int port = 502;         // tcp
  SerialSettings serial;  // rtu
  int unit = 1;           // Modbus unit (slave) id, 0..247 (0 = broadcast)
  int timeout_ms = 500;   // per-request response timeout
  int retries = 2;  // extra attempts after a timeout or a dropped link (not after an exception)
};

// "socketcan", "tty", ... ; throws ConfigError when there is no "scheme:".
std::string BackendScheme(std::string_view text);

CanBackendSpec ParseCanBackend(std::string_view text);
SerialSettings ParseTtyBackend(std::string_view text);
ModbusBackendSpec ParseModbusBackend(std::string_view text);

// The CAN bit rates a Lawicel adapter knows, S0..S8; returns -1 for any other rate.
int SlcanBitrateCode(int bitrate);

}  // namespace kinevis::hal
