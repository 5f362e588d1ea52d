#pragma once

// A Modbus server (slave) over libmodbus: the helper the Modbus device simulators build on. It
// holds a register map (coils, discrete inputs, holding registers, input registers, each starting
// at address 0) and serves it on its own thread, either
//  - over Modbus TCP on a listening socket (ListenTcp), to any number of clients at once, or
//  - over Modbus RTU on the master side of a pseudo-terminal (ServeRtu), whose slave path the
//    host opens exactly as it would open /dev/ttyUSB0 (hal/serial/pty_pair.h).
// backend() is the backend string a host passes to ModbusClient::Open() to reach it.
//
// A simulator reads and changes the map with WithRegisters(), refuses requests with a request
// hook (answering a Modbus exception instead), and reacts to writes with a write hook. Faults are
// injected with DropConnections(), StopAnswering() and SetReplyDelay(). Timing here is wall time
// (std::chrono::steady_clock): the peer is a real socket or tty whose timeouts are wall time too.
//
// Requests are served one at a time in arrival order on the server thread; a reply delay
// therefore delays every client.
//
// Supported function codes: 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x0F, 0x10, 0x11 (report server
// id, answered by libmodbus), 0x16, 0x17. Anything else is answered with ILLEGAL FUNCTION; a
// quantity out of the protocol's range or a malformed request with ILLEGAL DATA VALUE; an
// address range outside the map with ILLEGAL DATA ADDRESS.
//
// Unit ids: the server is one unit (Options::unit).
//  - RTU: frames for other units are ignored (no answer, as on a shared bus); a broadcast
//    (unit 0) write is executed and never answered; a broadcast read is ignored.
//  - TCP: requests for unit 0, 0xFF ("not used" in Modbus TCP) and Options::unit are served;
//    any other unit is answered with GATEWAY TARGET DEVICE FAILED TO RESPOND, as a gateway does
//    for a unit that is not there.

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "hal/modbus/modbus_client.h"

namespace kinevis::hal {

// The data a server exposes. Index i is protocol address i. Bits are one byte each, 0 or 1.
// A simulator may resize the vectors inside WithRegisters(); the server checks every request
// against the sizes in force when the request is served.
struct ModbusRegisterMap {
  std::vector<uint8_t> coils;               // read/write bits (0x01, 0x05, 0x0F)
  std::vector<uint8_t> discrete_inputs;     // read-only bits (0x02)
  std::vector<uint16_t> holding_registers;  // read/write registers (0x03, 0x06, 0x10, 0x16, 0x17)
  std::vector<uint16_t> input_registers;    // read-only registers (0x04)
};

// One decoded, valid request, as the hooks see it.
struct ModbusRequest {
  int unit = 0;          // the unit id it was addressed to (0: RTU broadcast)
  int function = 0;      // function code
  int address = 0;       // first address read, or written (0x17: the write address)
  int count = 0;         // number of bits or registers read, or written (0x17: written)
  int read_address = 0;  // 0x17 only: first register read
  int read_count = 0;    // 0x17 only: number of registers read
  // Writes only (nullptr for reads): the `count` values the request stores at address,
  // address + 1, ... (bits as 0 or 1; for 0x16 the masked result). Valid during the hook call.
  const uint16_t* values = nullptr;

  bool is_write() const { return values != nullptr; }
};

struct ModbusServerStats {
  uint64_t requests = 0;              // complete, well-formed frames received (any unit)
  uint64_t replies = 0;               // normal responses sent
  uint64_t exceptions = 0;            // exception responses sent
  uint64_t swallowed = 0;             // requests discarded unanswered by StopAnswering()
  uint64_t ignored = 0;               // RTU: frames for other units, broadcast reads
  uint64_t broadcasts = 0;            // RTU: broadcast writes executed (never answered)
  uint64_t framing_errors = 0;        // RTU: bad CRC, truncated frame; TCP: malformed MBAP header
  uint64_t connections_accepted = 0;  // TCP
  uint64_t connections_dropped = 0;   // TCP: closed by DropConnections()
  uint64_t connections_open = 0;      // TCP: open right now
};

// CRC-16/MODBUS of `size` bytes (reflected polynomial 0xA001, initial value 0xFFFF), as an RTU
// frame carries it after the data, low byte first.
uint16_t ModbusRtuCrc(const uint8_t* data, size_t size);

class ModbusServer {
 public:
  struct Options {
    // Map sizes, 0..65536 each (addresses 0 .. size - 1).
    int coils = 256;
    int discrete_inputs = 256;
    int holding_registers = 256;
    int input_registers = 256;
    int unit = 1;  // the unit id served, 1..247
    // RTU only: the line settings backend() tells hosts to use (a pty carries bytes at any
    // rate; a host's ModbusClient needs a rate libmodbus knows, e.g. 9600, 115200).
    int baud = 115200;
    char parity = 'E';  // 'N', 'E' or 'O'
    int data_bits = 8;  // 5..8
    int stop_bits = 1;  // 1 or 2
  };

  // Decides whether a valid request is served: return ModbusErrc::kNone to serve it, or an
  // exception code (1..11, e.g. ModbusErrc::kIllegalDataValue) to answer that instead; the map
  // is then left unchanged.
  using RequestHook = std::function<ModbusErrc(const ModbusRequest&, const ModbusRegisterMap&)>;
  // Called after a write was applied to the map (and answered), with mutable access to the map.
  using WriteHook = std::function<void(const ModbusRequest&, ModbusRegisterMap&)>;

  // Serves Modbus TCP on host:port (port 0: an ephemeral port, see port()). host is a numeric
  // address or a name ("127.0.0.1", "::1", "localhost"; "0.0.0.0" for every interface).
  // Throws ConfigError for bad options, HalError naming host:port when it cannot listen (address
  // in use, permission denied).
  static std::unique_ptr<ModbusServer> ListenTcp(const std::string& host, int port,
                                                 const Options& options);
  static std::unique_ptr<ModbusServer> ListenTcp(const std::string& host, int port) {
    return ListenTcp(host, port, Options());
  }

  // Serves Modbus RTU on an open pty master descriptor (PtyPair::master_fd()). The descriptor
  // stays the caller's: it is never closed here and must stay open until Stop() has returned.
  // device_path is the path hosts open (PtyPair::slave_path() or a link to it), used in
  // backend() and the logs. Throws ConfigError for bad options or a negative descriptor.
  static std::unique_ptr<ModbusServer> ServeRtu(int master_fd, const std::string& device_path,
                                                const Options& options);
  static std::unique_ptr<ModbusServer> ServeRtu(int master_fd, const std::string& device_path) {
    return ServeRtu(master_fd, device_path, Options());
  }

  // Stops serving and joins the server thread (closes TCP connections and the listening socket).
  ~ModbusServer();
  ModbusServer(const ModbusServer&) = delete;
  ModbusServer& operator=(const ModbusServer&) = delete;

  // Idempotent; call it from one thread at a time. Returns promptly even while a reply is being
  // delayed (the delayed reply is not sent).
  void Stop();

  // "modbus-tcp:127.0.0.1:40123" or "modbus-rtu:/dev/pts/5@115200,8E1", with ",unit=N" appended
  // when the unit is not 1. A server listening on 0.0.0.0 (::) names 127.0.0.1 (::1).
  const std::string& backend() const;
  // TCP: the port actually bound. RTU: 0.
  int port() const;

  // Runs fn(ModbusRegisterMap&) under the server's register mutex and returns its result. The
  // server thread holds the same mutex while it serves a request and runs the hooks, so fn sees
  // every request either wholly applied (with the write hook's reaction) or not at all.
  // The mutex is recursive: hooks may call WithRegisters() too. Do not block inside fn.
  template <typename Fn>
  auto WithRegisters(Fn&& fn) {
    std::lock_guard<std::recursive_mutex> lock(registers_mutex_);
    return fn(registers_);
  }

  // Replace the hooks (an empty function removes one); callable at any time, from any thread.
  // They run on the server thread under the register mutex. An exception thrown by the request
  // hook is logged and answered with SERVER DEVICE FAILURE; one thrown by the write hook (the
  // answer has gone) is logged.
  void SetRequestHook(RequestHook hook);
  void SetWriteHook(WriteHook hook);

  // Fault injection.
  // Closes every TCP connection now and returns how many were closed (waits until the server
  // thread has done it). Clients see a dropped link. RTU: a serial line has no connection to
  // drop; returns 0.
  int DropConnections();
  // Reads and discards every request for `duration` from now (the clients time out).
  // std::chrono::milliseconds::max() means until ResumeAnswering().
  void StopAnswering(std::chrono::milliseconds duration);
  void ResumeAnswering();
  // Waits `delay` before answering each request (0: answer at once).
  void SetReplyDelay(std::chrono::milliseconds delay);

  ModbusServerStats stats() const;

 private:
  struct Impl;
  ModbusServer();

  std::recursive_mutex registers_mutex_;
  ModbusRegisterMap registers_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace kinevis::hal
