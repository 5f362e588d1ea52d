#pragma once

// A simulated RS485 motor drive (the DIAMOND's motor arms): a Modbus RTU slave on a serial line
// (the master side of a hal::PtyPair) with the register map of hal/drive/rs485_drive_registers.h,
// driving a Cia402Device. Several drives may share one line (multi-drop), each with its own unit
// id, as on a real RS485 bus.
//
// The Modbus RTU slave is implemented here (not with libmodbus, which serves one unit per
// context): frames are delimited by the length their function code implies (0x03, 0x06, 0x10,
// 0x17) or, for other function codes, by 2 ms of silence on the line; a frame with a bad CRC is
// discarded with everything received with it. Frames for units not on this line are ignored, a
// broadcast (unit 0) write is executed by every drive and never answered. Exceptions: 1 ILLEGAL
// FUNCTION (any other function code), 2 ILLEGAL DATA ADDRESS (a range not wholly inside the
// output block 0x0000.. or the input block 0x0100..; any write touching the read-only input
// block), 3 ILLEGAL DATA VALUE (a quantity or byte count out of the protocol's range, a mode the
// drive does not support, position limit min > max, quick stop option code outside 0..8; the
// whole request is then not applied). A 0x17 request writes first, then reads. Written
// registers are applied in the order mode, parameters, targets, controlword. Each unit has a
// communication watchdog (rs485_drive_registers.h) measured on the Clock. The input block also
// carries kRegProductCode = 0x0485.
//
// Threads: the line is served on a thread of its own from construction until Stop(); Start()
// adds a thread that steps the devices every step_period_s of wall time to clock->Now() (real
// time on a SteadyClock). For deterministic tests do not Start(): call Step() after advancing a
// SimulatedClock (the Modbus server still answers requests on its own thread, under the same
// mutex).

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "common/clock.h"
#include "hal/mock/cia402_device.h"

namespace kinevis::hal {

class Rs485DriveSim {
 public:
  struct DriveOptions {
    int unit = 1;  // Modbus unit id, 1..247, unique on the line
    uint32_t serial_number = 1;
    Cia402Device::Options device;
  };
  struct Options {
    std::vector<DriveOptions> drives = {DriveOptions{}};
    int baud = 3'000'000;           // what backend() tells hosts; a pty carries any rate
    double step_period_s = 0.0005;  // device stepping period of the real-time thread
  };

  // master_fd: the pty master (PtyPair::master_fd()), which must stay open until Stop();
  // device_path: the path hosts open (slave path or a link), used in backend() and logs.
  // Throws ConfigError for duplicate or out-of-range unit ids.
  Rs485DriveSim(int master_fd, std::string device_path, common::Clock* clock, Options options);
  ~Rs485DriveSim();
  Rs485DriveSim(const Rs485DriveSim&) = delete;
  Rs485DriveSim& operator=(const Rs485DriveSim&) = delete;

  void Start();  // the stepping thread; does nothing when running
  void Stop();   // stops both threads (idempotent); the line is no longer served afterwards
  void Step();   // deterministic mode: steps every device to clock->Now(), checks the watchdogs

  // "modbus-rtu:/dev/pts/5@3000000,8E1" (the unit is chosen per drive by the host).
  const std::string& backend() const;
  // The drive with Modbus unit `unit`; throws ConfigError when there is none.
  Cia402Device& device(int unit);

  // Fault injection (per unit; ConfigError for a unit that is not on the line).
  // The drive is silent: requests to it are neither executed nor answered (host times out; its
  // watchdog, when set, trips as for a cut cable).
  void StopAnswering(int unit, bool stopped);
  void CorruptNextReplies(int unit, int n);  // replies with a bad CRC
  void RaiseFault(int unit, uint16_t error_code);

  struct Statistics {
    uint64_t requests = 0;        // well-formed frames for a unit of this line (or broadcast)
    uint64_t replies = 0;         // normal responses sent
    uint64_t exceptions = 0;      // exception responses sent
    uint64_t framing_errors = 0;  // frames discarded: bad CRC, truncated, garbage
    uint64_t ignored = 0;         // frames for other units
    uint64_t watchdog_trips = 0;  // watchdog faults raised
  };
  Statistics statistics() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace kinevis::hal
