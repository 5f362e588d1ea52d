#include "hal/can/slcan_bus.h"

#include <spdlog/spdlog.h>

#include <cstdio>

#include "hal/common/error.h"
#include "hal/serial/termios_serial_port.h"

namespace kinevis::hal {
namespace {

using std::chrono::duration_cast;
using std::chrono::microseconds;
using std::chrono::milliseconds;

// The reader thread looks at the stop flag (and the status poll) at least this often.
constexpr milliseconds kReadPoll{50};
constexpr size_t kExpectedCapacity = 1024;
constexpr int kMaxLogsPerSecond = 20;

std::string BusName(const CanBackendSpec& spec) {
  return spec.text.empty() ? "slcan:" + spec.serial.device : spec.text;
}

CanBackendSpec CheckedSpec(const CanBackendSpec& spec, const SlcanBusOptions& options) {
  std::vector<std::string> problems;
  if (spec.kind != CanBackendSpec::Kind::kSlcan) problems.push_back("not an slcan: backend");
  if (spec.bitrate != 0 && SlcanBitrateCode(spec.bitrate) < 0) {
    problems.push_back("bitrate " + std::to_string(spec.bitrate) + " has no Lawicel code (S0..S8)");
  }
  if (options.setup_timeout <= milliseconds::zero()) {
    problems.push_back("setup_timeout " + std::to_string(options.setup_timeout.count()) +
                       " ms is not positive");
  }
  if (options.rx_queue_capacity == 0) problems.push_back("rx_queue_capacity is 0");
  if (options.max_error_events == 0) problems.push_back("max_error_events is 0");
  if (!problems.empty()) {
    std::string message = "backend \"" + BusName(spec) + "\": ";
    for (size_t i = 0; i < problems.size(); ++i) message += (i ? "; " : "") + problems[i];
    throw common::ConfigError(message);
  }
  return spec;
}

// "S6\r" -> "S6", for messages.
std::string Printable(const std::string& line) { return line.substr(0, line.find('\r')); }

std::string StatusText(uint8_t flags) {
  static constexpr struct {
    uint8_t bit;
    const char* text;
  } kNames[] = {{kSlcanRxFifoFull, "receive FIFO full"},
                {kSlcanTxFifoFull, "transmit FIFO full"},
                {kSlcanErrorWarning, "error warning"},
                {kSlcanDataOverrun, "data overrun"},
                {kSlcanErrorPassive, "error passive"},
                {kSlcanArbitrationLost, "arbitration lost"},
                {kSlcanBusError, "bus error"}};
  char head[16];
  std::snprintf(head, sizeof head, "F%02X", flags);
  std::string text = head;
  const char* sep = ": ";
  for (const auto& n : kNames) {
    if ((flags & n.bit) != 0) {
      text += sep;
      text += n.text;
      sep = ", ";
    }
  }
  return text;
}

}  // namespace

std::unique_ptr<SlcanBus> SlcanBus::Open(const CanBackendSpec& spec,
                                         const SlcanBusOptions& options) {
  CheckedSpec(spec, options);
  return std::make_unique<SlcanBus>(OpenSerialPort(spec.serial, BusName(spec)), spec, options);
}

SlcanBus::SlcanBus(std::unique_ptr<SerialPort> port, const CanBackendSpec& spec,
                   const SlcanBusOptions& options)
    : spec_(CheckedSpec(spec, options)),
      options_(options),
      name_(BusName(spec)),
      port_(std::move(port)),
      ring_(options.rx_queue_capacity),
      expected_(kExpectedCapacity, Expect::kNone) {
  SetUp();
  reader_ = std::thread([this] { ReaderLoop(); });
}

SlcanBus::~SlcanBus() {
  bool alive;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    alive = !link_closed_;
  }
  if (alive) {
    // Leave the adapter closed, as a fresh one is. No drain: on a pty whose other side is not
    // read, tcdrain would wait for ever.
    std::lock_guard<std::mutex> lock(write_mutex_);
    static constexpr char kClose[] = "C\r";
    port_->WriteAll(reinterpret_cast<const uint8_t*>(kClose), 2, options_.write_timeout);
  }
  stop_ = true;
  if (reader_.joinable()) reader_.join();
  spdlog::debug("{}: closed", name_);
}

void SlcanBus::SetUp() {
  // A channel left open by an earlier program keeps sending frames; close it, ignore whether it
  // was open ('\r') or not ('\a'), and throw away what it sent.
  SetUpCommand("C\r", /*want_version=*/false, /*final=*/false);
  port_->FlushInput();
  decoder_.Reset();

  if (SetUpCommand("V\r", /*want_version=*/true, /*final=*/false) != Reply::kVersion) {
    spdlog::info("{}: the adapter did not report a version; continuing", name_);
  }

  if (spec_.bitrate != 0) {
    const std::string line = EncodeSlcanBitrate(spec_.bitrate);
    Reply r = SetUpCommand(line, false, false);
    if (r != Reply::kOk) {
      ThrowSetUpError(line, "CAN bit rate " + std::to_string(spec_.bitrate) + " bit/s", r);
    }
  }
  if (spec_.timestamps) {
    const std::string line = EncodeSlcanCommand(SlcanCommand::Timestamps(true));
    Reply r = SetUpCommand(line, false, false);
    if (r != Reply::kOk) ThrowSetUpError(line, "millisecond timestamps on", r);
  }
  const std::string open = EncodeSlcanCommand(SlcanCommand::Simple(
      spec_.listen_only ? SlcanCommand::Kind::kListenOnly : SlcanCommand::Kind::kOpen));
  Reply r = SetUpCommand(open, false, /*final=*/true);
  if (r != Reply::kOk) {
    ThrowSetUpError(open, spec_.listen_only ? "open the channel listen-only" : "open the channel",
                    r);
  }
  spdlog::info("{}: adapter {}open{}{}{}", name_,
               adapter_version_.empty() ? "" : "version " + adapter_version_ + " ",
               spec_.listen_only ? " listen-only" : "",
               spec_.bitrate != 0 ? " at " + std::to_string(spec_.bitrate) + " bit/s" : "",
               spec_.timestamps ? " with timestamps" : "");
}

SlcanBus::Reply SlcanBus::SetUpCommand(const std::string& line, bool want_version, bool final) {
  {
    std::lock_guard<std::mutex> lock(write_mutex_);
    std::error_code ec = port_->WriteAll(reinterpret_cast<const uint8_t*>(line.data()), line.size(),
                                         options_.setup_timeout);
    if (ec) {
      throw HalError(name_, "set-up command \"" + Printable(line) + "\"",
                     "writing to the serial port failed: " + ec.message(), ec);
    }
  }
  const auto deadline = std::chrono::steady_clock::now() + options_.setup_timeout;
  Reply reply = Reply::kNone;
  bool frames_queued = false;
  uint8_t buffer[256];
  while (reply == Reply::kNone) {
    const auto left = duration_cast<microseconds>(deadline - std::chrono::steady_clock::now());
    if (left <= microseconds::zero()) break;
    size_t n = 0;
    std::error_code ec = port_->Read(buffer, sizeof buffer, left, &n);
    if (ec == Errc::kTimeout) break;
    if (ec) {
      throw HalError(name_, "set-up command \"" + Printable(line) + "\"",
                     "reading from the serial port failed: " + ec.message(), ec);
    }
    const common::Duration arrival = common::SteadyClock::Instance().Now();
    std::lock_guard<std::mutex> lock(mutex_);
    decoder_.Feed(buffer, n, [&](const SlcanEvent& e) {
      if (reply == Reply::kNone) {
        // Before the answer: frames of a channel that was still open, noise. Ignored.
        if (e.kind == SlcanEvent::Kind::kOk) reply = Reply::kOk;
        if (e.kind == SlcanEvent::Kind::kError) reply = Reply::kError;
        if (want_version && e.kind == SlcanEvent::Kind::kVersion) {
          reply = Reply::kVersion;
          adapter_version_ = e.text;
        }
      } else if (final && e.kind == SlcanEvent::Kind::kFrame) {
        // The channel is open: frames right behind the answer are real traffic.
        QueueFrameLocked(e, arrival, &frames_queued);
      }
    });
  }
  return reply;
}

void SlcanBus::ThrowSetUpError(const std::string& line, const std::string& what,
                               Reply reply) const {
  std::string cause;
  if (reply == Reply::kError) {
    cause = "the adapter answered BEL (\\a, error)";
  } else {
    cause = "no answer within " + std::to_string(options_.setup_timeout.count()) + " ms; is " +
            spec_.serial.device + " a Lawicel (slcan) adapter at " +
            std::to_string(spec_.serial.baud) + " bit/s?";
  }
  throw HalError(name_, "set-up command \"" + Printable(line) + "\" (" + what + ")", cause,
                 make_error_code(reply == Reply::kError ? Errc::kDeviceFault : Errc::kTimeout));
}

void SlcanBus::ReaderLoop() {
  uint8_t buffer[512];
  auto next_poll = std::chrono::steady_clock::now() + options_.status_poll_interval;
  while (!stop_.load()) {
    if (options_.status_poll_interval > milliseconds::zero() &&
        std::chrono::steady_clock::now() >= next_poll) {
      bool refused;
      {
        std::lock_guard<std::mutex> lock(mutex_);
        refused = status_refused_;
      }
      if (!refused) RequestStatus();
      next_poll = std::chrono::steady_clock::now() + options_.status_poll_interval;
    }
    size_t n = 0;
    std::error_code ec = port_->Read(buffer, sizeof buffer, kReadPoll, &n);
    if (ec == Errc::kTimeout) continue;
    const common::Duration arrival = common::SteadyClock::Instance().Now();
    if (ec) {
      spdlog::error("{}: serial link lost: {}", name_, ec.message());
      {
        std::lock_guard<std::mutex> lock(mutex_);
        link_closed_ = true;
        RaiseLocked(CanErrorKind::kAdapter, arrival, "serial link lost: " + ec.message());
      }
      rx_cv_.notify_all();
      return;
    }
    // One pointer captured: the callback fits std::function's inline storage, so a read does not
    // allocate.
    struct Context {
      SlcanBus* bus;
      common::Duration arrival;
      bool frames_queued;
    } context{this, arrival, false};
    {
      std::lock_guard<std::mutex> lock(mutex_);
      decoder_.Feed(buffer, n, [c = &context](const SlcanEvent& e) {
        c->bus->HandleEventLocked(e, c->arrival, &c->frames_queued);
      });
    }
    if (context.frames_queued) rx_cv_.notify_one();
  }
}

void SlcanBus::HandleEventLocked(const SlcanEvent& event, common::Duration arrival,
                                 bool* frames_queued) {
  using Kind = SlcanEvent::Kind;
  switch (event.kind) {
    case Kind::kFrame:
      QueueFrameLocked(event, arrival, frames_queued);
      return;
    case Kind::kTxAck:
    case Kind::kOk:
      PopExpectedLocked();
      return;
    case Kind::kStatus:
      PopExpectedLocked();
      HandleStatusLocked(event.status, arrival);
      return;
    case Kind::kError: {
      const Expect what = PopExpectedLocked();
      if (what == Expect::kStatus) {
        if (!status_refused_) {
          spdlog::warn("{}: the adapter refused the status request F; not asking again", name_);
        }
        status_refused_ = true;
        RaiseLocked(CanErrorKind::kAdapter, arrival, "the adapter refused the status request F");
        return;
      }
      ++counters_.tx_errors;
      RaiseLocked(CanErrorKind::kAdapter, arrival,
                  what == Expect::kFrame ? "the adapter refused a frame (BEL)"
                                         : "the adapter sent an unsolicited BEL (error)");
      return;
    }
    case Kind::kVersion:
    case Kind::kSerialNumber:
      spdlog::info("{}: adapter {} {}", name_, ToString(event.kind), event.text);
      return;
    case Kind::kInvalid:
      ++counters_.decode_errors;
      RaiseLocked(CanErrorKind::kAdapter, arrival,
                  "undecodable line from the adapter: \"" + event.text + "\"");
      return;
  }
}

void SlcanBus::QueueFrameLocked(const SlcanEvent& event, common::Duration arrival,
                                bool* frames_queued) {
  if (!filters_.empty()) {
    bool pass = false;
    for (const CanFilter& f : filters_) pass = pass || f.Matches(event.frame);
    if (!pass) {
      ++counters_.rx_filtered;
      return;
    }
  }
  if (ring_size_ == ring_.size()) {
    ++counters_.rx_overflows;
    if (!overflowing_) {
      overflowing_ = true;
      RaiseLocked(CanErrorKind::kRxOverflow, arrival,
                  "receive queue full (" + std::to_string(ring_.size()) +
                      " frames); received frames are being lost");
    }
    return;
  }
  overflowing_ = false;
  RxEntry& slot = ring_[(ring_head_ + ring_size_) % ring_.size()];
  slot.frame = event.frame;
  slot.frame.timestamp = arrival;
  slot.adapter_ms = event.has_timestamp ? event.timestamp_ms : -1;
  ++ring_size_;
  *frames_queued = true;
}

void SlcanBus::HandleStatusLocked(uint8_t flags, common::Duration at) {
  const std::string text = StatusText(flags);
  if ((flags & kSlcanErrorWarning) != 0) {
    RaiseLocked(CanErrorKind::kErrorWarning, at, "adapter status " + text);
  }
  if ((flags & kSlcanErrorPassive) != 0) {
    RaiseLocked(CanErrorKind::kErrorPassive, at, "adapter status " + text);
  }
  if ((flags & kSlcanBusError) != 0) {
    RaiseLocked(CanErrorKind::kProtocol, at, "adapter status " + text);
  }
  if ((flags & (kSlcanDataOverrun | kSlcanRxFifoFull)) != 0) {
    // The adapter does not say how many frames it lost: at least one.
    ++counters_.rx_overflows;
    RaiseLocked(CanErrorKind::kRxOverflow, at, "adapter status " + text);
  }
  if ((flags & kSlcanErrorPassive) != 0) {
    state_ = CanBusState::kErrorPassive;
  } else if ((flags & kSlcanErrorWarning) != 0) {
    state_ = CanBusState::kErrorWarning;
  } else {
    state_ = CanBusState::kErrorActive;  // the flags are latched: none set since the last F
  }
}

void SlcanBus::RaiseLocked(CanErrorKind kind, common::Duration at, std::string detail) {
  ++counters_.error_events;
  if (kind == CanErrorKind::kBusOff) ++counters_.bus_off_events;
  // A line spewing garbage would otherwise flood the log: at most kMaxLogsPerSecond lines, and
  // the number left out is told with the next one.
  if (at - log_window_start_ >= std::chrono::seconds(1)) {
    log_window_start_ = at;
    logged_in_window_ = 0;
  }
  if (logged_in_window_ < kMaxLogsPerSecond) {
    ++logged_in_window_;
    if (logs_suppressed_ > 0) {
      spdlog::warn("{}: {}: {} ({} earlier error events not logged)", name_, ToString(kind), detail,
                   logs_suppressed_);
      logs_suppressed_ = 0;
    } else {
      spdlog::warn("{}: {}: {}", name_, ToString(kind), detail);
    }
  } else {
    ++logs_suppressed_;
  }
  if (errors_.size() == options_.max_error_events) errors_.pop_front();
  errors_.push_back(CanErrorEvent{kind, at, std::move(detail)});
}

void SlcanBus::PushExpectedLocked(Expect expect) {
  if (expected_size_ == expected_.size()) {
    // An adapter that does not ack frames: forget the oldest.
    expected_head_ = (expected_head_ + 1) % expected_.size();
    --expected_size_;
  }
  expected_[(expected_head_ + expected_size_) % expected_.size()] = expect;
  ++expected_size_;
}

SlcanBus::Expect SlcanBus::PopExpectedLocked() {
  if (expected_size_ == 0) return Expect::kNone;
  const Expect e = expected_[expected_head_];
  expected_head_ = (expected_head_ + 1) % expected_.size();
  --expected_size_;
  return e;
}

std::error_code SlcanBus::WriteLine(const char* data, size_t size, Expect expect) {
  std::lock_guard<std::mutex> write_lock(write_mutex_);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (link_closed_) return Errc::kClosed;
    // Before writing: the reply may be read before WriteAll returns.
    PushExpectedLocked(expect);
  }
  std::error_code ec =
      port_->WriteAll(reinterpret_cast<const uint8_t*>(data), size, options_.write_timeout);
  if (ec) {
    std::lock_guard<std::mutex> lock(mutex_);
    // Take back this line's entry: it is the newest unless its reply already came, in which case
    // (replies being in order) the queue is empty.
    if (expected_size_ > 0) --expected_size_;
    if (ec == Errc::kTimeout) return Errc::kOverflow;
  }
  return ec;
}

std::error_code SlcanBus::Send(const CanFrame& frame) {
  if (spec_.listen_only) return Errc::kUnsupported;
  char line[kSlcanMaxLineSize];
  const size_t size = EncodeSlcanFrame(frame, line);
  if (size == 0) return Errc::kInvalidArgument;
  std::error_code ec = WriteLine(line, size, Expect::kFrame);
  std::lock_guard<std::mutex> lock(mutex_);
  if (ec) {
    ++counters_.tx_errors;
    if (!send_failing_) spdlog::warn("{}: send failed: {}", name_, ec.message());
    send_failing_ = true;
    return ec;
  }
  if (send_failing_) spdlog::info("{}: sending again", name_);
  send_failing_ = false;
  ++counters_.tx_frames;
  return {};
}

std::error_code SlcanBus::RequestStatus() {
  static constexpr char kStatus[] = "F\r";
  return WriteLine(kStatus, 2, Expect::kStatus);
}

std::error_code SlcanBus::Receive(CanFrame* frame, microseconds timeout) {
  std::unique_lock<std::mutex> lock(mutex_);
  if (ring_size_ == 0 && !link_closed_ && timeout > microseconds::zero()) {
    rx_cv_.wait_for(lock, std::min(timeout, microseconds(std::chrono::hours(24))),
                    [this] { return ring_size_ > 0 || link_closed_; });
  }
  if (ring_size_ == 0) return link_closed_ ? Errc::kClosed : Errc::kTimeout;
  const RxEntry& entry = ring_[ring_head_];
  *frame = entry.frame;
  last_adapter_ms_ =
      entry.adapter_ms >= 0 ? std::optional<uint16_t>(entry.adapter_ms) : std::nullopt;
  ring_head_ = (ring_head_ + 1) % ring_.size();
  --ring_size_;
  ++counters_.rx_frames;
  return {};
}

std::error_code SlcanBus::SetFilters(const std::vector<CanFilter>& filters) {
  for (const CanFilter& f : filters) {
    if (f.id > CanFrame::kMaxExtendedId || f.mask > CanFrame::kMaxExtendedId) {
      spdlog::error("{}: filter id 0x{:X} mask 0x{:X} exceeds 29 bits", name_, f.id, f.mask);
      return Errc::kInvalidArgument;
    }
  }
  std::lock_guard<std::mutex> lock(mutex_);
  filters_ = filters;
  return {};
}

bool SlcanBus::TakeErrorEvent(CanErrorEvent* event) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (errors_.empty()) return false;
  *event = std::move(errors_.front());
  errors_.pop_front();
  return true;
}

CanBusState SlcanBus::state() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return state_;
}

CanCounters SlcanBus::counters() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return counters_;
}

}  // namespace kinevis::hal
