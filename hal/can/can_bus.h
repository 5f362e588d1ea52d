#pragma once

// The CAN bus interface every CAN backend implements (SocketCAN, slcan, virtual) and every CAN
// protocol (CANopen) uses. Backends are opened from a backend string by OpenCanBus()
// (hal/can/can_bus_factory.h).
//
// Threading: Send() and Receive() may be called from different threads; each one from one
// thread at a time. The calls in the cyclic path (Send, Receive, TakeErrorEvent) do not throw and
// do not allocate in steady state: faults come back as std::error_code values of hal::Errc.

#include <chrono>
#include <string>
#include <system_error>
#include <vector>

#include "hal/can/can_frame.h"

namespace kinevis::hal {

class CanBus {
 public:
  virtual ~CanBus() = default;

  // The backend string this bus was opened with ("socketcan:can0"); used in every log line.
  virtual const std::string& name() const = 0;

  // Queues one frame for transmission. Returns {} when the frame was accepted by the backend,
  // Errc::kInvalidArgument for a malformed frame, Errc::kBusOff when the controller is bus-off,
  // Errc::kOverflow when the transmit queue is full, Errc::kIo/kClosed when the link is gone.
  virtual std::error_code Send(const CanFrame& frame) = 0;

  // Waits at most `timeout` (zero: do not wait) for the next received frame that passes the
  // acceptance filters. Returns {} and fills *frame, or Errc::kTimeout, Errc::kClosed, Errc::kIo.
  virtual std::error_code Receive(CanFrame* frame, std::chrono::microseconds timeout) = 0;

  // Replaces the acceptance filters; an empty list passes every frame. A frame passes when any
  // filter matches. Errors only at set-up level (bad filter): returns Errc::kInvalidArgument.
  virtual std::error_code SetFilters(const std::vector<CanFilter>& filters) = 0;

  // Pops the oldest pending error event; false when there is none. Events are also counted.
  virtual bool TakeErrorEvent(CanErrorEvent* event) = 0;

  virtual CanBusState state() const = 0;
  virtual CanCounters counters() const = 0;
};

}  // namespace kinevis::hal
