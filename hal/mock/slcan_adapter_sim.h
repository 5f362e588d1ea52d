#pragma once

// A simulated USB-CAN adapter speaking the Lawicel ASCII protocol (slcan): it serves the adapter
// side of a serial line (usually the master of a hal::PtyPair, so that the host opens
// pty.slave_path() exactly as it would open /dev/ttyACM0) and bridges to a CAN bus (usually a
// VirtualCanBus node).
//
// Protocol rules, as a Lawicel CAN232/CANUSB enforces them (the answer is '\a' when a rule is
// broken, '\r' otherwise):
//   Sn, Zn       only while the channel is closed
//   O, L         only while closed; O opens normally, L listen-only (frames received, none sent)
//   C            only while open (or listen-only)
//   t T r R      only while open (not listen-only); answered "z\r" (t, r) or "Z\r" (T, R), and
//                '\a' when the bus refuses the frame
//   F            only while open; answered "FXX\r" and the flags are cleared
//   V, N         always; answered "V" + version, "N" + serial number
//   anything else, or a malformed line: '\a'
// While open, every frame received from the bus goes to the host as a t/T/r/R line, with a
// millisecond timestamp (the frame's bus time modulo 60000 ms) when Z1 was set.
//
// Threads: Start() runs two threads, one serving the serial side and one forwarding bus frames;
// they share the state under a mutex and take turns writing to the port. All public methods are
// thread-safe.

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>

#include "hal/can/can_bus.h"
#include "hal/serial/serial_port.h"

namespace kinevis::hal {

class SlcanAdapterSim {
 public:
  struct Options {
    std::string version = "1013";        // answer to V: exactly 4 printable characters
    std::string serial_number = "KV01";  // answer to N: exactly 4 printable characters
  };
  enum class State { kClosed, kOpen, kListenOnly };
  struct Statistics {
    uint64_t commands = 0;        // lines received from the host
    uint64_t refused = 0;         // lines answered with '\a'
    uint64_t frames_to_bus = 0;   // t/T/r/R lines sent on the bus
    uint64_t frames_to_host = 0;  // bus frames written to the host
    uint64_t bytes_dropped = 0;   // bytes to the host removed by DropBytesToHost()
  };

  // port: the adapter's end of the serial line; bus: the CAN side, which must outlive the
  // simulator. Throws ConfigError when the version or serial number is not 4 printable characters.
  SlcanAdapterSim(std::unique_ptr<SerialPort> port, CanBus* bus, Options options);
  ~SlcanAdapterSim();  // Stop()
  SlcanAdapterSim(const SlcanAdapterSim&) = delete;
  SlcanAdapterSim& operator=(const SlcanAdapterSim&) = delete;

  // Starts serving; does nothing when already running.
  void Start();
  // Stops serving and joins the threads (within about 50 ms). The adapter state is kept.
  void Stop();

  State state() const;
  // The code of the last accepted Sn (0..8), or -1 when none was given.
  int bitrate_code() const;
  bool timestamps() const;
  Statistics statistics() const;

  // Fault injection.
  // The next n bytes bound for the host are lost (as on a noisy line or an overrun UART).
  void DropBytesToHost(size_t n);
  // Writes bytes to the host now, between two lines.
  void InjectGarbage(std::string_view bytes);
  // A silent adapter reads and ignores everything and sends nothing (hung firmware).
  void SetSilent(bool silent);
  // Commands whose first letter is in `letters` ("S", "tT", "O") are answered '\a' in any state.
  void RefuseCommands(std::string letters);
  // ORs flags (SlcanStatusFlag bits) into the status reported by the next F.
  void SetStatusFlags(uint8_t flags);

 private:
  void SerialLoop();
  void BusLoop();
  void HandleLine(std::string_view line);
  // Writes to the host, applying DropBytesToHost(). Requires write_mutex_ held.
  void WriteToHostLocked(const char* data, size_t size);

  const std::unique_ptr<SerialPort> port_;
  CanBus* const bus_;
  const Options options_;
  const std::string name_;

  std::atomic<bool> running_{false};
  std::thread serial_thread_;
  std::thread bus_thread_;

  // Lock order: write_mutex_ before mutex_.
  std::mutex write_mutex_;
  size_t drop_remaining_ = 0;  // guarded by write_mutex_

  mutable std::mutex mutex_;
  State state_ = State::kClosed;
  int bitrate_code_ = -1;
  bool timestamps_ = false;
  bool silent_ = false;
  std::string refused_letters_;
  uint8_t status_flags_ = 0;
  Statistics stats_;
};

const char* ToString(SlcanAdapterSim::State state);

}  // namespace kinevis::hal
