#pragma once

// CanBus over a Lawicel ASCII (slcan) adapter on a serial port: most USB-CAN adapters (CANable,
// CANUSB, USBtin, ...) and the SlcanAdapterSim of hal/mock. Backend string, see
// hal/common/backend_spec.h:  slcan:DEVICE[@BAUD][,bitrate=N][,listen][,timestamps]
//
// Set-up (in the constructor): "C\r" closes a channel left open (its answer is ignored and the
// input flushed), "V\r" asks the version (optional: an adapter that does not answer it is still
// used), then "Sn\r" when a bit rate is given, "Z1\r" when timestamps are asked for, and "O\r"
// (or "L\r" for listen-only). Each of those must be answered '\r' within
// SlcanBusOptions::setup_timeout, else HalError.
//
// Run time: a reader thread decodes the adapter's output into a bounded receive queue. Send()
// writes the line and returns without waiting for the adapter's "z\r"; a '\a' (NAK) that comes
// back for a frame counts as tx_errors and raises a kAdapter event. An undecodable line counts as
// decode_errors and raises a kAdapter event carrying the line. When the serial link dies (adapter
// unplugged, pty closed) Receive() returns the frames already queued and then Errc::kClosed, with
// a kAdapter event. The Lawicel status flags (answer to "F\r", see RequestStatus()) become error
// events: error warning -> kErrorWarning, error passive -> kErrorPassive, bus error -> kProtocol,
// data overrun or receive FIFO full -> kRxOverflow; and state() follows them.
//
// Timestamps: frame.timestamp is the host's steady-clock time (SteadyClock::Instance().Now())
// when the reader thread got the bytes of the frame. With the `timestamps` option the adapter's
// own millisecond stamp of the frame last returned by Receive() is last_adapter_timestamp_ms():
// it counts 0..59999 and wraps to 0 every 60 s, so the time between two frames is
// SlcanTimestampDeltaMs(a, b) (hal/can/slcan_codec.h) as long as they are less than 60 s apart,
// which their host timestamps tell.
//
// Acceptance filters are applied in software by the reader thread (Lawicel has no standard
// filter command; the adapter-specific M/m acceptance registers are not used).
// Threading as CanBus: Send() and Receive() may run on different threads.

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "common/clock.h"
#include "hal/can/can_bus.h"
#include "hal/can/slcan_codec.h"
#include "hal/common/backend_spec.h"
#include "hal/serial/serial_port.h"

namespace kinevis::hal {

struct SlcanBusOptions {
  std::chrono::milliseconds setup_timeout{1000};  // per set-up command, > 0
  std::chrono::milliseconds write_timeout{100};   // per Send(); then Errc::kOverflow
  size_t rx_queue_capacity = 4096;                // received frames kept for Receive(), > 0
  size_t max_error_events = 256;                  // pending error events; older ones are dropped
  // Sends "F\r" this often while the channel is open, so that adapter errors are noticed
  // without RequestStatus() calls; zero = never. An adapter that refuses F is not asked again.
  std::chrono::milliseconds status_poll_interval{0};
};

class SlcanBus final : public CanBus {
 public:
  // Opens spec.serial with OpenSerialPort() and sets the adapter up. Throws ConfigError when spec
  // is not an slcan backend, has a bit rate without a Lawicel code or bad options, and HalError
  // when the port cannot be opened or the adapter refuses ('\a') or does not answer a set-up
  // command (the message names the backend and the command).
  static std::unique_ptr<SlcanBus> Open(const CanBackendSpec& spec,
                                        const SlcanBusOptions& options = {});

  // Sets up the adapter on an already-open port (spec.serial is then only informational).
  // Throws as Open().
  SlcanBus(std::unique_ptr<SerialPort> port, const CanBackendSpec& spec,
           const SlcanBusOptions& options = {});
  // Sends "C\r" (closes the channel) when the link is alive, and joins the reader thread.
  ~SlcanBus() override;
  SlcanBus(const SlcanBus&) = delete;
  SlcanBus& operator=(const SlcanBus&) = delete;

  const std::string& name() const override { return name_; }
  // Errc::kUnsupported when listen-only, kInvalidArgument for an invalid frame, kClosed when the
  // link is gone, kOverflow when the serial line did not take the line within write_timeout.
  std::error_code Send(const CanFrame& frame) override;
  std::error_code Receive(CanFrame* frame, std::chrono::microseconds timeout) override;
  // Software filters; Errc::kInvalidArgument when an id or mask exceeds 29 bits.
  std::error_code SetFilters(const std::vector<CanFilter>& filters) override;
  bool TakeErrorEvent(CanErrorEvent* event) override;
  // From the last status reply: error-passive, error-warning or error-active (Lawicel has no
  // bus-off flag).
  CanBusState state() const override;
  CanCounters counters() const override;

  // Sends "F\r"; the answer turns into error events and state() when the reader thread gets it.
  // Returns Errc::kClosed when the link is gone, kOverflow when the line was not taken in time.
  std::error_code RequestStatus();

  // The adapter's answer to "V" (4 characters, e.g. "1013"); empty when it gave none.
  const std::string& adapter_version() const { return adapter_version_; }
  bool listen_only() const { return spec_.listen_only; }
  // The adapter timestamp (0..59999 ms) of the frame last returned by Receive(); nullopt when
  // that frame carried none (timestamps off). An adapter that keeps Z1 in its EEPROM sends them
  // even without the `timestamps` option; they are kept all the same. Call from the thread that
  // calls Receive().
  std::optional<uint16_t> last_adapter_timestamp_ms() const { return last_adapter_ms_; }

 private:
  enum class Expect : uint8_t { kNone, kFrame, kStatus };
  enum class Reply { kOk, kError, kVersion, kNone };
  struct RxEntry {
    CanFrame frame;
    int adapter_ms = -1;  // -1: none
  };

  void SetUp();
  // Sends a set-up line and waits for '\r' / '\a' (or a version line when want_version).
  // Frames that follow the reply in the same read are queued when `final` (the O/L answer).
  Reply SetUpCommand(const std::string& line, bool want_version, bool final);
  [[noreturn]] void ThrowSetUpError(const std::string& line, const std::string& what,
                                    Reply reply) const;
  void ReaderLoop();
  // Require mutex_ held.
  void HandleEventLocked(const SlcanEvent& event, common::Duration arrival, bool* frames_queued);
  void QueueFrameLocked(const SlcanEvent& event, common::Duration arrival, bool* frames_queued);
  void HandleStatusLocked(uint8_t flags, common::Duration at);
  void RaiseLocked(CanErrorKind kind, common::Duration at, std::string detail);
  void PushExpectedLocked(Expect expect);
  Expect PopExpectedLocked();
  // Writes one line to the adapter and remembers which reply it expects.
  std::error_code WriteLine(const char* data, size_t size, Expect expect);

  const CanBackendSpec spec_;
  const SlcanBusOptions options_;
  const std::string name_;
  std::unique_ptr<SerialPort> port_;
  std::string adapter_version_;
  SlcanDecoder decoder_;  // set-up, then the reader thread only

  std::mutex write_mutex_;  // one line at a time to the adapter

  mutable std::mutex mutex_;
  std::condition_variable rx_cv_;
  std::vector<RxEntry> ring_;  // receive queue: fixed capacity, no allocation per frame
  size_t ring_head_ = 0;
  size_t ring_size_ = 0;
  bool overflowing_ = false;  // one kRxOverflow event per run of lost frames
  std::vector<CanFilter> filters_;
  std::deque<CanErrorEvent> errors_;
  CanCounters counters_;
  CanBusState state_ = CanBusState::kErrorActive;
  bool link_closed_ = false;
  bool send_failing_ = false;  // logged once per run of failures
  bool status_refused_ = false;
  common::Duration log_window_start_{0};  // error-event log rate limit
  int logged_in_window_ = 0;
  uint64_t logs_suppressed_ = 0;
  // What each line sent is waiting for, oldest first: replies come back in order, which tells a
  // NAK of a frame from a refused status request. Fixed capacity; an adapter that never acks
  // frames just overwrites the oldest entries.
  std::vector<Expect> expected_;
  size_t expected_head_ = 0;
  size_t expected_size_ = 0;

  std::optional<uint16_t> last_adapter_ms_;  // Receive() thread only
  std::atomic<bool> stop_{false};
  std::thread reader_;
};

}  // namespace kinevis::hal
