#pragma once

// A chain of simulated Dynamixel servos on one half-duplex bus: it serves the servo side of a
// serial line (usually the master of a hal::PtyPair, so that the host opens pty.slave_path()
// exactly as it would open /dev/ttyUSB0) and answers Protocol 1.0 or 2.0 instruction packets the
// way the servos of the given control tables do.
//
// Instructions: ping, read, write, reg write, action, sync write, and bulk read (1.0) or sync
// read and reboot (2.0); every other instruction addressed to one servo is answered with an
// instruction error, and broadcasts are never answered (except the 2.0 ping, which every servo
// answers in id order). Sync and bulk reads are answered in the order of the ids in the request.
//
// The control table (hal/dynamixel/control_table.h) decides the rest:
//  - power-on values are the registers' initial values; reads may span gaps (read as 0);
//  - writes must cover whole registers of access rw with values in range; EEPROM (below
//    eeprom_end) is refused while the torque is on when the table says so; a goal position
//    outside the min/max position limits is refused. Refusals are answered with the error of
//    the protocol: 1.0 range / angle limit error bit, 2.0 access / data length / data range /
//    data limit error code; nothing is written;
//  - turning the torque on sets the goal position to the present position (the servo holds).
// Motion model: with the torque on, the position moves towards the goal at the profile velocity
// (1.0: moving speed), or at the table's no-load speed when that is 0 or faster, and stops at
// the goal; acceleration is infinite. Present position, velocity, load (a viscous-friction
// model: proportional to speed, 0.2 of full scale at no-load speed; no external load), moving and
// the realtime tick follow the clock, evaluated whenever an instruction or an accessor looks.
//
// Not modelled: return delay time (answers go out at once), status return level (always 2),
// baud rate and id changes' effect on the line (the id register is honoured: a servo answers
// to its new id), wheel and multi-turn modes, temperatures and voltages (constant), and the
// answer to an instruction packet with a bad checksum or CRC (real servos answer with a
// checksum/CRC error; here the packet is dropped and counted, so the host sees a timeout).
//
// Fault injection: CorruptNextReplies() damages the checksum/CRC of the next status packets;
// SetNoReply() makes a servo ignore everything (as if unplugged); InjectOverload() raises the
// overload alarm: torque off, motion stops, every status packet of the servo carries the alarm
// (1.0: the overload bit; 2.0: the alert bit, with the overload bit in Hardware Error Status),
// and a write of torque enable = 1 is refused (1.0: answered with the overload bit only, as the
// error field has no better bit; 2.0: alert + result fail). Only a reboot instruction (2.0) or
// PowerCycle() (either protocol; 1.0 has no other way) clears it.
//
// Threads: Start() runs one thread serving the port. All public methods are thread-safe.

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "common/clock.h"
#include "hal/dynamixel/control_table.h"
#include "hal/serial/serial_port.h"

namespace kinevis::hal {

class DynamixelSim {
 public:
  struct ServoSpec {
    uint8_t id = 1;
    DxlControlTable table;  // the servo's model; its protocol must be the simulator's
  };
  struct Options {
    int protocol = 2;  // 1 or 2
    std::vector<ServoSpec> servos;
    // How long a servo stays silent after a reboot instruction.
    std::chrono::milliseconds reboot_time{30};
  };
  struct Statistics {
    uint64_t instructions = 0;       // valid instruction packets received (any id)
    uint64_t replies = 0;            // status packets sent
    uint64_t corrupted_replies = 0;  // status packets sent with a damaged checksum/CRC
    uint64_t checksum_errors = 0;    // instruction packets dropped for a bad checksum/CRC
    uint64_t refused = 0;            // instructions answered with an error code / refusing bit
  };

  // port: the servos' end of the line. clock: the time of the motion model (must outlive the
  // simulator); a SimulatedClock makes motion deterministic. Throws ConfigError naming the
  // problem: no servos, a protocol that is not 1 or 2, an id out of range or given twice, a table
  // of the other protocol.
  DynamixelSim(std::unique_ptr<SerialPort> port, Options options,
               common::Clock* clock = &common::SteadyClock::Instance());
  ~DynamixelSim();  // Stop()
  DynamixelSim(const DynamixelSim&) = delete;
  DynamixelSim& operator=(const DynamixelSim&) = delete;

  // Starts serving; does nothing when already running.
  void Start();
  // Stops serving and joins the thread (within about 50 ms). The servos keep their state.
  void Stop();

  const std::string& name() const { return name_; }
  int protocol() const { return protocol_; }
  Statistics statistics() const;

  // The raw value of a register of servo `id` (the id it had at construction), as the servo
  // would report it now. Throws ConfigError for an unknown servo or register.
  int64_t Register(uint8_t id, const std::string& register_name) const;
  // Sets a register as the servo's firmware would (no access or range check).
  void SetRegister(uint8_t id, const std::string& register_name, int64_t raw);
  // The exact present position, rad (not rounded to a tick).
  double Position(uint8_t id) const;

  // Fault injection (see the top of this file).
  void CorruptNextReplies(size_t n);
  void SetNoReply(uint8_t id, bool no_reply);
  void InjectOverload(uint8_t id);
  bool Overloaded(uint8_t id) const;
  // Power off and on: RAM registers back to their power-on values (the goal to the present
  // position), alarms cleared, pending reg write dropped; EEPROM and the position are kept.
  void PowerCycle(uint8_t id);

 private:
  struct Servo;

  void Serve();
  // Handles one instruction packet; appends status packets to out_.
  void HandleLocked(uint8_t id, uint8_t instruction, const uint8_t* params, size_t size);
  struct WriteCheck {
    bool allowed = true;
    uint8_t error = 0;  // the error field to answer with (the alarm is added on sending)
  };

  // The servo that answers to `current_id` now, or nullptr.
  Servo* FindLocked(uint8_t current_id) const;
  // The servo constructed with `original_id`; throws ConfigError when there is none.
  Servo& At(uint8_t original_id) const;
  bool ListeningLocked(const Servo& s) const;
  // Moves the motion model to the clock's present time.
  void UpdateLocked(Servo& s) const;
  uint8_t AlarmLocked(const Servo& s) const;
  WriteCheck CheckWriteLocked(const Servo& s, uint16_t address, const uint8_t* data,
                              size_t size) const;
  void ApplyWriteLocked(Servo& s, uint16_t address, const uint8_t* data, size_t size);
  void ResetRamLocked(Servo& s);
  void ReplyLocked(const Servo& s, uint8_t error, const uint8_t* params, size_t size);
  // Answers a read of servo s: data, or the error.
  void ReplyReadLocked(Servo& s, uint16_t address, uint16_t length);
  int64_t GetLocked(const Servo& s, const DxlRegister& reg) const;
  void SetLocked(Servo& s, const DxlRegister& reg, int64_t raw) const;
  uint8_t ErrorCode(uint8_t code_2, uint8_t bit_1) const;

  const std::unique_ptr<SerialPort> port_;
  const int protocol_;
  const std::chrono::milliseconds reboot_time_;
  common::Clock* const clock_;
  const std::string name_;

  std::atomic<bool> running_{false};
  std::thread thread_;

  mutable std::mutex mutex_;
  std::vector<std::unique_ptr<Servo>> servos_;
  std::vector<uint8_t> out_;  // status packets to send after the current instruction
  size_t corrupt_remaining_ = 0;
  Statistics stats_;
};

}  // namespace kinevis::hal
