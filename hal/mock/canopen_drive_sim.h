#pragma once

// A simulated CiA 402 servo drive on a CAN bus: a CANopen slave (CiA 301 + CiA 402) with an
// object dictionary, NMT, an SDO server (expedited and segmented), PDOs configured by SDO,
// SYNC-driven cyclic modes (CSP, CSV, CST) and profile modes (PP, PV, PT), a heartbeat producer
// (0x1017) and EMCY messages, driving a Cia402Device (state machine + motion model). It talks
// only through a CanBus (usually a VirtualCanBus node; or the far side of an slcan adapter
// simulator), exactly as a real drive does, so the host driver under test is the real one.
//
// Default object dictionary (what a host may read and configure):
//   0x1000 device type (0x00020192: CiA 402 servo), 0x1001 error register, 0x1017 producer
//   heartbeat time (ms, default 0 = off until the host sets it), 0x1018 identity (1 vendor,
//   2 product, 3 revision, 4 serial), 0x1400..0x1403 / 0x1600..0x1603 RPDO communication and
//   mapping, 0x1800..0x1803 / 0x1A00..0x1A03 TPDO communication and mapping (defaults: RPDO1 =
//   controlword + target position, TPDO1 = statusword + position actual, both synchronous),
//   0x603F, 0x6040, 0x6041, 0x605A, 0x6060, 0x6061, 0x6064, 0x6065, 0x606C, 0x6071, 0x6077,
//   0x607A, 0x607D, 0x607F, 0x6081, 0x6083, 0x60F4, 0x60FF, 0x6502, and a VISIBLE_STRING
//   0x1008 manufacturer device name ("kinevis simulated drive") that needs a segmented upload.
//
// Besides, 0x2000 is a read/write VISIBLE_STRING "application tag" (up to 64 bytes, empty by
// default) so that hosts can exercise segmented downloads. docs/canopen-drive-sim.md lists every
// object with its type, access and default, and the SDO abort code of each refusal.
//
// Protocol behaviour:
//  - NMT: the first Service() (or Start()) sends the boot-up message (when enabled) and enters
//    Pre-operational. SDO is served in Pre-operational and Operational; PDOs are exchanged in
//    Operational only; in Stopped only NMT is served (the heartbeat goes on). Reset node brings
//    the device and the whole dictionary back to power-on values, reset communication the
//    communication objects (0x1000..0x1FFF); both send a new boot-up message.
//  - PDOs: received synchronous RPDOs (transmission type 0..240) are applied at the next SYNC,
//    event-driven ones (254, 255) at once; a controlword mapped into an RPDO is applied after
//    the other mapped objects of the same PDO. On SYNC the drive applies its RPDOs, steps the
//    device with the time since its last step, then sends its synchronous TPDOs (type 1..240:
//    every n-th SYNC; 0: on a SYNC when the data changed). Event-driven TPDOs are sent when their
//    data change (respecting the inhibit time, sub 3, in 100 us) and on their event timer
//    (sub 5, ms). Remapping follows CiA 301: invalidate the PDO (COB-ID bit 31), write mapping
//    sub 0 = 0, the entries, sub 0 = n, then validate the PDO.
//  - Motion: in a cyclic mode with operation enabled the device is stepped on SYNC only (so that
//    one set-point per SYNC is followed exactly); otherwise, or when no SYNC came for 50 ms, it
//    is stepped on the clock in Service().
//  - EMCY: a fault that reaches the Fault state sends one EMCY (its error code, the error
//    register 0x1001) and a fault reset one with error code 0, in Pre-operational and
//    Operational (an EMCY is lost in Stopped or while disconnected).
//
// Threads: Start() runs one thread that serves the bus in real time on the given Clock; for
// deterministic tests, leave it stopped and call Service() after advancing a SimulatedClock.

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>

#include "common/clock.h"
#include "hal/can/can_bus.h"
#include "hal/canopen/canopen_codec.h"
#include "hal/mock/cia402_device.h"

namespace kinevis::hal {

class CanopenDriveSim {
 public:
  struct Options {
    uint8_t node = 1;                 // 1..127
    uint32_t vendor_id = 0x004B5653;  // "KVS"
    uint32_t product_code = 0x0402;
    uint32_t revision = 1;
    uint32_t serial_number = 1;
    Cia402Device::Options device;  // motion limits, supported modes, ...
    bool boot_up_message = true;   // send the boot-up heartbeat on Start()/reset
  };

  // bus and clock must outlive the simulator. Throws ConfigError for a bad node id or options.
  CanopenDriveSim(CanBus* bus, common::Clock* clock, Options options);
  ~CanopenDriveSim();  // Stop()
  CanopenDriveSim(const CanopenDriveSim&) = delete;
  CanopenDriveSim& operator=(const CanopenDriveSim&) = delete;

  void Start();  // serve in a thread (real time on the clock)
  void Stop();
  // Deterministic mode: handles every frame waiting on the bus and every time-based event
  // (heartbeat, profile motion, watchdogs) due at clock->Now(). Not to be mixed with Start().
  void Service();

  uint8_t node() const;
  canopen::NmtState nmt_state() const;
  Cia402Device& device();  // the drive behind the protocol (thread-safe itself)

  // Fault injection.
  void DropNextReplies(int n);                          // SDO responses and TPDOs not sent
  void SetReplyDelay(std::chrono::microseconds delay);  // SDO responses and TPDOs, 0 = none
  void SendMalformedSdoReplies(int n);                  // next n SDO responses with dlc 5 (invalid)
  void StopHeartbeat(bool stopped);  // heartbeat producer silent (node looks dead)
  // Deaf and mute: frames are read and discarded, nothing is sent (the device keeps running).
  void Disconnect(bool disconnected);
  void RaiseFault(uint16_t error_code);  // -> Fault reaction active -> Fault, EMCY sent

  struct Statistics {
    uint64_t sdo_requests = 0, sdo_aborts_sent = 0, syncs = 0, rpdos = 0, tpdos = 0, heartbeats = 0,
             emcys = 0, nmt_commands = 0;
  };
  Statistics statistics() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace kinevis::hal
