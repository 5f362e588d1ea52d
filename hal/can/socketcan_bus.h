#pragma once

// Linux SocketCAN backend ("socketcan:IFACE"): a PF_CAN / SOCK_RAW / CAN_RAW socket bound to one
// interface (can0, vcan0), speaking `struct can_frame` records of 16 bytes.
//
// What the socket is asked for, and what happens when the kernel refuses (each refusal is logged
// once at set-up and reported by features()):
//  - CAN_RAW_ERR_FILTER = CAN_ERR_MASK: every class of error frame. Error frames become
//    CanErrorEvents (TakeErrorEvent) and drive state(); Receive() never returns them.
//  - SO_TIMESTAMPNS: the kernel's reception time of every frame. The kernel stamps with
//    CLOCK_REALTIME; the bus converts it to the SteadyClock time base (the clock of every other
//    kinevis timestamp) with the REALTIME-MONOTONIC offset, which it re-measures so that a wall
//    clock step is followed. Without it frames are stamped with SteadyClock::Now() on reading.
//    Either way frame.timestamp never decreases from one Receive() to the next.
//  - SO_RXQ_OVFL: the count of frames the kernel dropped because the socket's receive queue was
//    full; every increase adds to counters().rx_overflows and raises a kRxOverflow event.
//  - CAN_RAW_FILTER for SetFilters(); refused -> the filters are applied in software only
//    (counted in rx_filtered). The software check also runs behind the kernel filter, so
//    frames queued before a SetFilters() call are filtered too.
//
// Bus state: error frames read by Receive() update state() (bus-off, error-passive, ...); while it
// is bus-off Send() refuses with Errc::kBusOff until a "restarted" or "back to error-active"
// error frame has been read. Recovery itself is the kernel's (`ip link set IFACE type can
// restart-ms 100`, or `... type can restart`).
//
// FromDescriptor() adopts any descriptor that carries struct can_frame records, so the whole I/O
// path can be exercised without PF_CAN, e.g. over socketpair(AF_UNIX, SOCK_SEQPACKET, 0, fds).
//
// Threading and the cyclic path as in can_bus.h: Send() and Receive() may run on two threads;
// neither throws nor allocates for data frames. Decoding an error frame allocates its event.

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <system_error>
#include <vector>

#include "common/clock.h"
#include "hal/can/can_bus.h"

namespace kinevis::hal {

struct SocketCanOptions {
  // How long Send() waits for room when the socket or the interface's transmit queue is full,
  // before it gives up with Errc::kOverflow. 0 (do not wait) .. 1 s.
  std::chrono::microseconds tx_timeout{10'000};
  // Error events kept for TakeErrorEvent(); when more arrive the oldest are dropped (and
  // logged). 1 .. 1'000'000.
  size_t max_pending_error_events = 256;
};

// What the kernel accepted when the socket was set up (see the top of this file).
struct SocketCanFeatures {
  bool kernel_filters = false;  // CAN_RAW_FILTER (otherwise software filtering only)
  bool error_frames = false;    // CAN_RAW_ERR_FILTER
  bool timestamps = false;      // SO_TIMESTAMPNS
  bool drop_counts = false;     // SO_RXQ_OVFL
};

class SocketCanBus final : public CanBus {
 public:
  // Opens a CAN_RAW socket bound to `interface` ("can0", "vcan0"; 1..15 characters). `name` is
  // the backend string used in messages and logs ("socketcan:can0").
  // Throws ConfigError for a bad interface name or options; HalError (device `name`, naming the
  // interface) when the kernel has no SocketCAN support (EAFNOSUPPORT), when there is no such
  // interface (ENODEV, with a hint how to list and create interfaces), when the interface is
  // not a CAN interface, or when the socket cannot be bound.
  static std::unique_ptr<SocketCanBus> Open(const std::string& interface, const std::string& name,
                                            const SocketCanOptions& options = {});

  // Adopts `fd`, an open descriptor carrying struct can_frame records (a CAN_RAW socket, or one
  // end of an AF_UNIX SOCK_SEQPACKET socketpair in tests). The bus owns it from the call on
  // and closes it, also when this throws. Sets O_NONBLOCK and FD_CLOEXEC on it. Socket options
  // the descriptor refuses are tolerated (see features()). Throws HalError when fd is not an
  // open descriptor and ConfigError for bad options.
  static std::unique_ptr<SocketCanBus> FromDescriptor(int fd, const std::string& name,
                                                      const SocketCanOptions& options = {});

  ~SocketCanBus() override;
  SocketCanBus(const SocketCanBus&) = delete;
  SocketCanBus& operator=(const SocketCanBus&) = delete;

  const std::string& name() const override { return name_; }
  // {} when the kernel took the frame; Errc::kInvalidArgument (frame.Validate() fails),
  // kBusOff (state() is bus-off), kOverflow (queue still full after tx_timeout), kIo (interface
  // down: ENETDOWN, or another errno, logged), kClosed (peer or device gone).
  std::error_code Send(const CanFrame& frame) override;
  // Waits at most `timeout` (microsecond resolution) for a data or remote frame that passes the
  // filters; error frames, filtered frames and undecodable records read meanwhile are handled
  // and the wait goes on until the same deadline. {} and *frame filled, or Errc::kTimeout,
  // kClosed (peer closed, interface removed), kIo (interface down, or another errno, logged).
  std::error_code Receive(CanFrame* frame, std::chrono::microseconds timeout) override;
  // At most 512 filters (CAN_RAW_FILTER_MAX); id and mask must fit in 29 bits, else
  // Errc::kInvalidArgument and the filters stay as they were.
  std::error_code SetFilters(const std::vector<CanFilter>& filters) override;
  bool TakeErrorEvent(CanErrorEvent* event) override;
  CanBusState state() const override;
  CanCounters counters() const override;

  // "can0" for Open(); empty for an adopted descriptor.
  const std::string& interface() const { return interface_; }
  int fd() const { return fd_; }
  SocketCanFeatures features() const;

 private:
  SocketCanBus(int fd, std::string name, std::string interface, const SocketCanOptions& options);

  enum class ReadOutcome { kFrame, kConsumed, kEmpty, kClosed, kIo };
  // One non-blocking recvmsg: a data frame for the caller (kFrame), a record that was handled
  // here (kConsumed: error frame, filtered, undecodable), nothing queued (kEmpty), or a failure.
  ReadOutcome ReadOne(CanFrame* frame);
  // The timestamp of a record: kernel time converted to the SteadyClock base, or now.
  common::Duration ConvertTimestamp(bool have_kernel_time, int64_t realtime_ns);
  void HandleDropCount(uint32_t drop_count, common::Duration at);
  void HandleErrorFrame(uint32_t error_class, const uint8_t* data, common::Duration at);
  // Requires mutex_ held.
  void RaiseLocked(CanErrorKind kind, common::Duration at, std::string detail);

  const std::string name_;
  const std::string interface_;
  const int fd_;
  const SocketCanOptions options_;
  bool use_write_ = false;  // Send() only: the descriptor is not a socket (ENOTSOCK seen)

  // Receive() only.
  common::Duration realtime_offset_{0};  // CLOCK_REALTIME - SteadyClock, as last measured
  common::Duration last_timestamp_{0};
  uint32_t last_drop_count_ = 0;

  mutable std::mutex mutex_;  // guards everything below
  SocketCanFeatures features_;
  std::vector<CanFilter> filters_;
  std::deque<CanErrorEvent> events_;
  uint64_t events_dropped_ = 0;
  CanCounters counters_;
  CanBusState state_ = CanBusState::kErrorActive;
};

}  // namespace kinevis::hal
