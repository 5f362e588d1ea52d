#pragma once

// An in-process CAN bus with the semantics of a real one, for simulators and tests.
//
// A VirtualCanNetwork is the wire; each VirtualCanBus connected to it is one node (one controller
// with its own receive queue, acceptance filters and error counters), so any number of drivers and
// device simulators can share a bus. Semantics kept from ISO 11898:
//  - every node except the sender receives every frame (like SocketCAN with loopback on and
//    recv_own_msgs off);
//  - with a bit-rate model (bitrate > 0) a frame occupies the wire for CanFrameWireBits() bit
//    times; frames waiting when the wire becomes free are arbitrated by identifier (lowest wins,
//    standard before extended on equal base id), so a busy bus delays high ids, and the network
//    reports its load; without one (bitrate == 0) the wire is infinitely fast;
//  - a corrupted frame is a CRC error for the receivers: every node gets a protocol error event,
//    the sender's transmit error counter rises by 8 and the receivers' by 1, and the frame is sent
//    again; counters fall by 1 on every good frame; nodes pass through error-warning (96),
//    error-passive (128) and bus-off (256) with events, and a bus-off node sends nothing until
//    Recover().
// Fault injection (SetFaults) drops, corrupts or delays frames with a seeded generator, so a
// failing test can be replayed exactly.
//
// Time comes from the network's Clock. With the default SteadyClock, Receive() waits in real time.
// With a SimulatedClock, frames become visible as the simulated time passes their delivery time;
// Receive() then re-checks the clock every millisecond of wall time while it waits.

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <random>
#include <string>
#include <vector>

#include "common/clock.h"
#include "hal/can/can_bus.h"

namespace kinevis::hal {

class VirtualCanBus;

class VirtualCanNetwork : public std::enable_shared_from_this<VirtualCanNetwork> {
 public:
  struct Options {
    int bitrate = 0;                  // bit/s, 0 = no bit-rate model; else 10'000..1'000'000
    common::Clock* clock = nullptr;   // nullptr = SteadyClock::Instance()
    size_t rx_queue_capacity = 4096;  // frames per node before rx-overflow
    size_t tx_queue_capacity = 256;   // frames a node may have waiting for the wire
  };
  struct Faults {
    double drop_probability = 0.0;     // a frame vanishes (no node sees it, sender sees success)
    double corrupt_probability = 0.0;  // a transmission attempt fails with a CRC error
    common::Duration delay{0};         // extra latency added to every delivery
    uint32_t seed = 1;
  };
  struct Statistics {
    uint64_t frames = 0;          // frames delivered
    uint64_t bits = 0;            // wire bits of those frames (including retransmissions)
    uint64_t error_frames = 0;    // transmission attempts destroyed by injected corruption
    uint64_t dropped = 0;         // frames dropped by fault injection
    common::Duration busy{0};     // time the wire was occupied (bit-rate model only)
    common::Duration elapsed{0};  // time since construction or ResetStatistics()
    double load() const {         // busy / elapsed, 0..1
      return elapsed.count() > 0 ? static_cast<double>(busy.count()) / elapsed.count() : 0.0;
    }
  };

  // Throws ConfigError for a bit rate out of range or zero queue capacities.
  VirtualCanNetwork(std::string name, Options options);
  ~VirtualCanNetwork();

  // The network registered under `name` in this process (the X of "virtual:X"), created with
  // `options` on first use. The registry holds networks weakly: a network lives while a node or
  // another shared_ptr holds it. Throws ConfigError when it exists with a different bit rate.
  static std::shared_ptr<VirtualCanNetwork> Get(const std::string& name, const Options& options);

  // A new node on this network. `node_name` appears in messages; default "virtual:NAME#k".
  std::unique_ptr<VirtualCanBus> Connect(std::string node_name = "");

  const std::string& name() const { return name_; }
  int bitrate() const { return options_.bitrate; }
  common::Clock& clock() const { return *clock_; }

  void SetFaults(const Faults& faults);
  Statistics statistics() const;
  void ResetStatistics();

 private:
  friend class VirtualCanBus;
  struct Pending {
    CanFrame frame;
    VirtualCanBus* sender;
    common::Duration submitted;
    uint64_t sequence;  // tie-break: first come, first served among equal ids
  };
  struct InFlight {
    CanFrame frame;
    VirtualCanBus* sender;
    common::Duration deliver_at;
  };

  // All below require mutex_ held.
  void PumpLocked(common::Duration now);
  void DeliverLocked(const CanFrame& frame, VirtualCanBus* sender, common::Duration at);
  void AbandonPendingLocked(VirtualCanBus* node);
  void Detach(VirtualCanBus* node);

  const std::string name_;
  const Options options_;
  common::Clock* clock_;
  mutable std::mutex mutex_;
  std::vector<VirtualCanBus*> nodes_;
  std::vector<Pending> pending_;    // waiting for the wire (bit-rate model or delay)
  std::deque<InFlight> in_flight_;  // sent, delivered at deliver_at
  common::Duration bus_free_at_{0};
  uint64_t sequence_ = 0;
  int node_count_ = 0;
  Faults faults_;
  bool faults_active_ = false;
  std::mt19937 rng_;
  Statistics stats_;
  common::Duration stats_start_{0};
};

class VirtualCanBus final : public CanBus {
 public:
  ~VirtualCanBus() override;

  const std::string& name() const override { return name_; }
  std::error_code Send(const CanFrame& frame) override;
  std::error_code Receive(CanFrame* frame, std::chrono::microseconds timeout) override;
  std::error_code SetFilters(const std::vector<CanFilter>& filters) override;
  bool TakeErrorEvent(CanErrorEvent* event) override;
  CanBusState state() const override;
  CanCounters counters() const override;

  // Fault injection on this node: drives its transmit error counter past 255 (bus-off, with the
  // event). Send() returns Errc::kBusOff until Recover().
  void InjectBusOff();
  // Bus-off recovery (what `ip link set canX type can restart` does): counters to zero,
  // error-active, a kRestarted event.
  void Recover();
  int tx_error_counter() const;
  int rx_error_counter() const;
  VirtualCanNetwork& network() const { return *network_; }

 private:
  friend class VirtualCanNetwork;
  VirtualCanBus(std::shared_ptr<VirtualCanNetwork> network, std::string name);

  // All below require the network mutex held.
  void EnqueueLocked(const CanFrame& frame);
  void RaiseLocked(CanErrorKind kind, common::Duration at, std::string detail);
  void AdjustCountersLocked(int tec_delta, int rec_delta, common::Duration at);
  bool PassesFiltersLocked(const CanFrame& frame) const;

  std::shared_ptr<VirtualCanNetwork> network_;
  std::string name_;
  std::condition_variable rx_cv_;
  int waiting_receivers_ = 0;
  // Receive ring: fixed capacity, no allocation per frame.
  std::vector<CanFrame> ring_;
  size_t ring_head_ = 0;
  size_t ring_size_ = 0;
  size_t tx_pending_ = 0;
  std::vector<CanFilter> filters_;
  std::deque<CanErrorEvent> errors_;
  CanCounters counters_;
  int tec_ = 0;
  int rec_ = 0;
  CanBusState state_ = CanBusState::kErrorActive;
};

}  // namespace kinevis::hal
