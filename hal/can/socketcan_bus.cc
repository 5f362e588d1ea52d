#include "hal/can/socketcan_bus.h"

#include <fcntl.h>
#include <linux/can.h>
#include <linux/can/error.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <spdlog/spdlog.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <optional>
#include <utility>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using std::chrono::microseconds;
using std::chrono::milliseconds;

static_assert(sizeof(struct can_frame) == 16, "struct can_frame is the 16-byte CAN_MTU record");

// Closes a descriptor unless released; for the set-up paths that throw.
class FdGuard {
 public:
  explicit FdGuard(int fd) : fd_(fd) {}
  ~FdGuard() {
    if (fd_ >= 0) ::close(fd_);
  }
  FdGuard(const FdGuard&) = delete;
  FdGuard& operator=(const FdGuard&) = delete;
  int fd() const { return fd_; }
  int Release() { return std::exchange(fd_, -1); }

 private:
  int fd_;
};

// Log the first occurrences of a repeating fault and then every thousandth, so that a bus that
// floods error frames cannot flood the log.
bool ShouldLog(uint64_t count) { return count <= 10 || count % 1000 == 0; }

timespec ToTimespec(common::Duration d) {
  if (d.count() < 0) d = common::Duration::zero();
  timespec ts;
  ts.tv_sec = static_cast<time_t>(d.count() / 1'000'000'000);
  ts.tv_nsec = static_cast<decltype(ts.tv_nsec)>(d.count() % 1'000'000'000);
  return ts;
}

// Waits until fd is ready for `events` or `timeout` passes; returns poll's revents, 0 on timeout
// (or EINTR: the caller re-checks its deadline) and -1 with errno on failure.
int WaitFor(int fd, decltype(pollfd::events) events, common::Duration timeout) {
  pollfd p{fd, events, 0};
  timespec ts = ToTimespec(timeout);
  int n = ::ppoll(&p, 1, &ts, nullptr);
  if (n < 0) return errno == EINTR ? 0 : -1;
  return n == 0 ? 0 : p.revents;
}

// CLOCK_REALTIME - SteadyClock, measured with the realtime read bracketed by two steady reads;
// nullopt when the thread was preempted between them (the measurement would be off).
std::optional<common::Duration> MeasureRealtimeOffset() {
  for (int attempt = 0; attempt < 3; ++attempt) {
    common::Duration before = common::SteadyClock::Instance().Now();
    timespec rt;
    ::clock_gettime(CLOCK_REALTIME, &rt);
    common::Duration after = common::SteadyClock::Instance().Now();
    if (after - before < microseconds(50)) {
      common::Duration realtime =
          std::chrono::seconds(rt.tv_sec) + std::chrono::nanoseconds(rt.tv_nsec);
      return realtime - (before + (after - before) / 2);
    }
  }
  return std::nullopt;
}

std::string Hex2(unsigned value) {
  char buf[8];
  std::snprintf(buf, sizeof buf, "0x%02X", value & 0xFFu);
  return buf;
}

// linux/can/error.h, data[2]: the kinds of protocol violation.
std::string ProtocolTypeText(uint8_t type) {
  static constexpr std::pair<uint8_t, const char*> kTypes[] = {
      {CAN_ERR_PROT_BIT, "bit error"},
      {CAN_ERR_PROT_FORM, "form error"},
      {CAN_ERR_PROT_STUFF, "stuff error"},
      {CAN_ERR_PROT_BIT0, "unable to send dominant bit"},
      {CAN_ERR_PROT_BIT1, "unable to send recessive bit"},
      {CAN_ERR_PROT_OVERLOAD, "bus overload"},
      {CAN_ERR_PROT_ACTIVE, "active error announcement"},
      {CAN_ERR_PROT_TX, "on transmission"},
  };
  std::string text;
  for (const auto& [bit, name] : kTypes) {
    if ((type & bit) == 0) continue;
    if (!text.empty()) text += ", ";
    text += name;
  }
  return text.empty() ? "unspecified" : text;
}

// linux/can/error.h, data[3]: where in the frame the violation was seen.
const char* ProtocolLocationText(uint8_t location) {
  switch (location) {
    case CAN_ERR_PROT_LOC_UNSPEC:
      return "unspecified location";
    case CAN_ERR_PROT_LOC_SOF:
      return "start of frame";
    case CAN_ERR_PROT_LOC_ID28_21:
      return "id bits 28-21";
    case CAN_ERR_PROT_LOC_ID20_18:
      return "id bits 20-18";
    case CAN_ERR_PROT_LOC_SRTR:
      return "substitute RTR";
    case CAN_ERR_PROT_LOC_IDE:
      return "identifier extension";
    case CAN_ERR_PROT_LOC_ID17_13:
      return "id bits 17-13";
    case CAN_ERR_PROT_LOC_ID12_05:
      return "id bits 12-5";
    case CAN_ERR_PROT_LOC_ID04_00:
      return "id bits 4-0";
    case CAN_ERR_PROT_LOC_RTR:
      return "RTR";
    case CAN_ERR_PROT_LOC_RES1:
      return "reserved bit 1";
    case CAN_ERR_PROT_LOC_RES0:
      return "reserved bit 0";
    case CAN_ERR_PROT_LOC_DLC:
      return "data length code";
    case CAN_ERR_PROT_LOC_DATA:
      return "data section";
    case CAN_ERR_PROT_LOC_CRC_SEQ:
      return "CRC sequence";
    case CAN_ERR_PROT_LOC_CRC_DEL:
      return "CRC delimiter";
    case CAN_ERR_PROT_LOC_ACK:
      return "ACK slot";
    case CAN_ERR_PROT_LOC_ACK_DEL:
      return "ACK delimiter";
    case CAN_ERR_PROT_LOC_EOF:
      return "end of frame";
    case CAN_ERR_PROT_LOC_INTERM:
      return "intermission";
  }
  return "unknown location";
}

// linux/can/error.h, data[4]: the transceiver's view of the wires.
std::string TransceiverText(uint8_t status) {
  std::string text;
  auto wire = [&text](const char* line, uint8_t code) {
    const char* what = nullptr;
    switch (code) {
      case 0x4:
        what = "no wire";
        break;
      case 0x5:
        what = "short to battery";
        break;
      case 0x6:
        what = "short to Vcc";
        break;
      case 0x7:
        what = "short to ground";
        break;
      default:
        break;
    }
    if (what == nullptr) return;
    if (!text.empty()) text += ", ";
    text += std::string(line) + " " + what;
  };
  wire("CANH", status & 0x0F);
  wire("CANL", (status >> 4) & 0x07);
  if ((status & CAN_ERR_TRX_CANL_SHORT_TO_CANH) == CAN_ERR_TRX_CANL_SHORT_TO_CANH) {
    if (!text.empty()) text += ", ";
    text += "CANL short to CANH";
  }
  return text.empty() ? "unspecified" : text;
}

// What one error frame says: the events to raise in order, and the state it reports.
struct ErrorFrameReport {
  struct Event {
    CanErrorKind kind;
    std::string detail;
  };
  std::vector<Event> events;
  std::optional<CanBusState> state;  // the state the controller reports now, if it says
  uint64_t rx_overflows = 0;
  uint64_t tx_errors = 0;
  std::string unreported;  // classes with no CanErrorKind (logged at debug level)
};

ErrorFrameReport DecodeErrorFrame(uint32_t error_class, const uint8_t* data) {
  ErrorFrameReport report;
  // Every driver that knows its error counters puts them in data[6..7] (CAN_ERR_CNT says so
  // explicitly on newer kernels); they are the most useful fact when debugging a bus.
  const std::string counters =
      "tx errors " + std::to_string(data[6]) + ", rx errors " + std::to_string(data[7]);
  auto add = [&report, &counters](CanErrorKind kind, const std::string& what) {
    report.events.push_back({kind, what + " (" + counters + ")"});
  };
  // Restart first and bus-off last, so that a frame reporting several classes leaves the state
  // at the most recent and most severe condition.
  if ((error_class & CAN_ERR_RESTARTED) != 0) {
    add(CanErrorKind::kRestarted, "controller restarted after bus-off");
    report.state = CanBusState::kErrorActive;
  }
  if ((error_class & CAN_ERR_CRTL) != 0) {
    const uint8_t crtl = data[1];
    if ((crtl & CAN_ERR_CRTL_RX_OVERFLOW) != 0) {
      add(CanErrorKind::kRxOverflow, "controller receive buffer overflow, frames lost");
      ++report.rx_overflows;
    }
    if ((crtl & CAN_ERR_CRTL_TX_OVERFLOW) != 0) {
      add(CanErrorKind::kRxOverflow, "controller transmit buffer overflow, frames lost");
      ++report.tx_errors;
    }
    const uint8_t passive = crtl & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE);
    const uint8_t warning = crtl & (CAN_ERR_CRTL_RX_WARNING | CAN_ERR_CRTL_TX_WARNING);
    if (passive != 0) {
      std::string which = passive == CAN_ERR_CRTL_RX_PASSIVE   ? "rx"
                          : passive == CAN_ERR_CRTL_TX_PASSIVE ? "tx"
                                                               : "rx and tx";
      add(CanErrorKind::kErrorPassive, which + " error counter reached error-passive (128)");
      report.state = CanBusState::kErrorPassive;
    } else if (warning != 0) {
      std::string which = warning == CAN_ERR_CRTL_RX_WARNING   ? "rx"
                          : warning == CAN_ERR_CRTL_TX_WARNING ? "tx"
                                                               : "rx and tx";
      add(CanErrorKind::kErrorWarning, which + " error counter reached error-warning (96)");
      report.state = CanBusState::kErrorWarning;
    } else if ((crtl & CAN_ERR_CRTL_ACTIVE) != 0) {
      report.state = CanBusState::kErrorActive;
    }
    if (crtl == CAN_ERR_CRTL_UNSPEC) report.unreported += "unspecified controller problem; ";
  }
  if ((error_class & CAN_ERR_PROT) != 0) {
    add(CanErrorKind::kProtocol, "protocol error: " + ProtocolTypeText(data[2]) + " at " +
                                     ProtocolLocationText(data[3]) + " (type " + Hex2(data[2]) +
                                     ", location " + Hex2(data[3]) + ")");
  } else if ((error_class & CAN_ERR_BUSERROR) != 0) {
    add(CanErrorKind::kProtocol, "bus error");
  }
  if ((error_class & CAN_ERR_TRX) != 0) {
    // CanErrorKind has no transceiver kind; a wiring fault shows up as protocol errors on the
    // bus, so it is reported as one, with the transceiver's words.
    add(CanErrorKind::kProtocol,
        "transceiver: " + TransceiverText(data[4]) + " (status " + Hex2(data[4]) + ")");
  }
  if ((error_class & CAN_ERR_ACK) != 0) {
    add(CanErrorKind::kNoAck,
        "transmitted frame got no acknowledgement (no other node, or a bit-rate mismatch)");
    ++report.tx_errors;
  }
  if ((error_class & CAN_ERR_TX_TIMEOUT) != 0) {
    add(CanErrorKind::kTxTimeout, "the driver timed out transmitting a frame");
    ++report.tx_errors;
  }
  if ((error_class & CAN_ERR_LOSTARB) != 0) {
    report.unreported += "lost arbitration at bit " + std::to_string(data[0]) + "; ";
  }
  if ((error_class & CAN_ERR_BUSOFF) != 0) {
    add(CanErrorKind::kBusOff, "controller is bus-off and sends nothing until restarted");
    report.state = CanBusState::kBusOff;
  }
  return report;
}

void CheckOptions(const std::string& name, const SocketCanOptions& options) {
  if (options.tx_timeout.count() < 0 || options.tx_timeout > std::chrono::seconds(1) ||
      options.max_pending_error_events == 0 || options.max_pending_error_events > 1'000'000) {
    throw common::ConfigError(
        name + ": socketcan options: tx_timeout " + std::to_string(options.tx_timeout.count()) +
        " us must be 0..1000000, max_pending_error_events " +
        std::to_string(options.max_pending_error_events) + " must be 1..1000000");
  }
}

}  // namespace

std::unique_ptr<SocketCanBus> SocketCanBus::Open(const std::string& interface,
                                                 const std::string& name,
                                                 const SocketCanOptions& options) {
  if (interface.empty() || interface.size() >= IFNAMSIZ ||
      interface.find_first_of(" \t/:") != std::string::npos) {
    throw common::ConfigError(name + ": socketcan interface \"" + interface +
                              "\" is not a valid interface name (1.." +
                              std::to_string(IFNAMSIZ - 1) + " characters, no blanks, '/' or ':')");
  }
  CheckOptions(name, options);
  const int fd = ::socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
  if (fd < 0) {
    const int err = errno;
    const std::error_code code(err, std::system_category());
    if (err == EAFNOSUPPORT || err == EPROTONOSUPPORT) {
      throw HalError(name, "open",
                     "interface \"" + interface +
                         "\": the kernel has no SocketCAN (PF_CAN) support: " + ErrnoText(err) +
                         "; load it with `modprobe can_raw` or use a kernel built with CONFIG_CAN "
                         "and CONFIG_CAN_RAW",
                     code);
    }
    throw HalError(
        name, "open",
        "interface \"" + interface + "\": socket(PF_CAN, SOCK_RAW, CAN_RAW): " + ErrnoText(err),
        code);
  }
  FdGuard guard(fd);
  const unsigned index = ::if_nametoindex(interface.c_str());
  if (index == 0) {
    const int err = errno;
    if (err == ENODEV || err == ENXIO) {
      throw HalError(name, "open",
                     "no network interface \"" + interface + "\" (" + ErrnoText(err) +
                         "); list the interfaces with `ip link`; create a virtual CAN "
                         "interface with `ip link add dev vcan0 type vcan && ip link set up vcan0`",
                     std::error_code(err, std::system_category()));
    }
    throw HalError(name, "open",
                   "interface \"" + interface + "\": if_nametoindex: " + ErrnoText(err),
                   std::error_code(err, std::system_category()));
  }
  sockaddr_can address{};
  address.can_family = AF_CAN;
  address.can_ifindex = static_cast<int>(index);
  if (::bind(fd, reinterpret_cast<const sockaddr*>(&address), sizeof address) != 0) {
    const int err = errno;
    if (err == ENODEV) {
      throw HalError(name, "open",
                     "interface \"" + interface +
                         "\" exists but is not a CAN interface (see `ip -details link show " +
                         interface + "`)",
                     std::error_code(err, std::system_category()));
    }
    throw HalError(name, "open", "bind to interface \"" + interface + "\": " + ErrnoText(err),
                   std::error_code(err, std::system_category()));
  }
  ifreq request{};
  std::strncpy(request.ifr_name, interface.c_str(), IFNAMSIZ - 1);
  if (::ioctl(fd, SIOCGIFFLAGS, &request) == 0 && (request.ifr_flags & IFF_UP) == 0) {
    spdlog::warn(
        "{}: interface {} is down; sends fail until `ip link set up {}` (real CAN "
        "hardware also needs `type can bitrate N`)",
        name, interface, interface);
  }
  std::unique_ptr<SocketCanBus> bus(new SocketCanBus(guard.fd(), name, interface, options));
  guard.Release();
  return bus;
}

std::unique_ptr<SocketCanBus> SocketCanBus::FromDescriptor(int fd, const std::string& name,
                                                           const SocketCanOptions& options) {
  FdGuard guard(fd);
  const int flags = fd < 0 ? -1 : ::fcntl(fd, F_GETFL);
  if (flags < 0) {
    guard.Release();  // not ours to close: it is not open
    throw HalError(name, "adopt descriptor",
                   "fd " + std::to_string(fd) + " is not an open descriptor",
                   std::error_code(EBADF, std::system_category()));
  }
  CheckOptions(name, options);
  if (::fcntl(fd, F_SETFL, flags | O_NONBLOCK) != 0 || ::fcntl(fd, F_SETFD, FD_CLOEXEC) != 0) {
    const int err = errno;
    throw HalError(name, "adopt descriptor",
                   "fd " + std::to_string(fd) + ": fcntl: " + ErrnoText(err),
                   std::error_code(err, std::system_category()));
  }
  std::unique_ptr<SocketCanBus> bus(new SocketCanBus(guard.fd(), name, "", options));
  guard.Release();
  return bus;
}

SocketCanBus::SocketCanBus(int fd, std::string name, std::string interface,
                           const SocketCanOptions& options)
    : name_(std::move(name)), interface_(std::move(interface)), fd_(fd), options_(options) {
  std::string refused;
  auto set = [this, &refused](int level, int option, const void* value, socklen_t size,
                              const char* what) {
    if (::setsockopt(fd_, level, option, value, size) == 0) return true;
    const int err = errno;
    refused += std::string(refused.empty() ? "" : ", ") + what + " (" + ErrnoText(err) + ")";
    return false;
  };
  const can_err_mask_t error_mask = CAN_ERR_MASK;
  features_.error_frames =
      set(SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &error_mask, sizeof error_mask, "CAN_RAW_ERR_FILTER");
  const int on = 1;
  features_.timestamps = set(SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof on, "SO_TIMESTAMPNS");
  features_.drop_counts = set(SOL_SOCKET, SO_RXQ_OVFL, &on, sizeof on, "SO_RXQ_OVFL");
  // Probing with the kernel's own default (one filter that passes everything) tells whether
  // kernel filtering is available without changing what is received.
  const can_filter pass_all{0, 0};
  features_.kernel_filters =
      set(SOL_CAN_RAW, CAN_RAW_FILTER, &pass_all, sizeof pass_all, "CAN_RAW_FILTER");
  if (std::optional<common::Duration> offset = MeasureRealtimeOffset()) realtime_offset_ = *offset;
  if (refused.empty()) {
    spdlog::info("{}: SocketCAN bus on {} (fd {})", name_,
                 interface_.empty() ? "an adopted descriptor" : interface_, fd_);
  } else {
    spdlog::warn("{}: SocketCAN bus on {} (fd {}): the socket refused {}{}", name_,
                 interface_.empty() ? "an adopted descriptor" : interface_, fd_, refused,
                 features_.kernel_filters ? "" : "; acceptance filters run in software");
  }
}

SocketCanBus::~SocketCanBus() { ::close(fd_); }

SocketCanFeatures SocketCanBus::features() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return features_;
}

std::error_code SocketCanBus::Send(const CanFrame& frame) {
  std::string invalid = frame.Validate();
  if (!invalid.empty()) {
    spdlog::warn("{}: refusing to send an invalid frame: {}", name_, invalid);
    return Errc::kInvalidArgument;
  }
  auto fail = [this, &frame](Errc code, const std::string& why) {
    uint64_t count;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      count = ++counters_.tx_errors;
    }
    if (ShouldLog(count)) {
      spdlog::warn("{}: send {} failed: {} (tx errors {})", name_, FormatCanFrame(frame), why,
                   count);
    }
    return make_error_code(code);
  };
  if (state() == CanBusState::kBusOff) {
    return fail(Errc::kBusOff, "the controller is bus-off; waiting for it to restart");
  }
  can_frame record;
  std::memset(&record, 0, sizeof record);
  record.can_id = frame.id | (frame.extended ? CAN_EFF_FLAG : 0u) | (frame.rtr ? CAN_RTR_FLAG : 0u);
  record.can_dlc = frame.dlc;
  if (!frame.rtr) std::memcpy(record.data, frame.data.data(), frame.dlc);

  common::SteadyClock& clock = common::SteadyClock::Instance();
  std::optional<common::Duration> deadline;
  while (true) {
    ssize_t n = use_write_ ? ::write(fd_, &record, sizeof record)
                           : ::send(fd_, &record, sizeof record, MSG_NOSIGNAL | MSG_DONTWAIT);
    if (n == static_cast<ssize_t>(sizeof record)) {
      std::lock_guard<std::mutex> lock(mutex_);
      ++counters_.tx_frames;
      return {};
    }
    if (n >= 0) return fail(Errc::kIo, "short write of " + std::to_string(n) + " bytes");
    const int err = errno;
    if (err == EINTR) continue;
    if (err == ENOTSOCK && !use_write_) {
      use_write_ = true;
      continue;
    }
    if (err == EAGAIN || err == EWOULDBLOCK || err == ENOBUFS) {
      // EAGAIN: the socket's send buffer is full, POLLOUT says when it has room. ENOBUFS: the
      // interface's transmit queue is full, which poll cannot see; retry every 100 us.
      const common::Duration now = clock.Now();
      if (!deadline) deadline = now + options_.tx_timeout;
      const common::Duration remaining = *deadline - now;
      if (remaining <= common::Duration::zero()) {
        return fail(Errc::kOverflow, "transmit queue still full after " +
                                         std::to_string(options_.tx_timeout.count()) + " us (" +
                                         ErrnoText(err) + ")");
      }
      if (err == ENOBUFS) {
        clock.SleepFor(std::min<common::Duration>(remaining, microseconds(100)));
      } else if (WaitFor(fd_, POLLOUT, remaining) < 0) {
        return fail(Errc::kIo, "poll: " + ErrnoText(errno));
      }
      continue;
    }
    if (err == ENETDOWN) {
      return fail(Errc::kIo, "interface is down (" + ErrnoText(err) + ")");
    }
    if (err == EPIPE || err == ECONNRESET || err == ENOTCONN || err == ENODEV || err == ENXIO) {
      return fail(Errc::kClosed, "channel closed (" + ErrnoText(err) + ")");
    }
    return fail(Errc::kIo, ErrnoText(err));
  }
}

std::error_code SocketCanBus::Receive(CanFrame* frame, std::chrono::microseconds timeout) {
  common::SteadyClock& clock = common::SteadyClock::Instance();
  const common::Duration deadline =
      clock.Now() + std::clamp(timeout, microseconds::zero(), microseconds(std::chrono::hours(24)));
  while (true) {
    switch (ReadOne(frame)) {
      case ReadOutcome::kFrame:
        return {};
      case ReadOutcome::kConsumed:
        continue;
      case ReadOutcome::kClosed:
        return Errc::kClosed;
      case ReadOutcome::kIo:
        return Errc::kIo;
      case ReadOutcome::kEmpty:
        break;
    }
    const common::Duration remaining = deadline - clock.Now();
    if (remaining <= common::Duration::zero()) return Errc::kTimeout;
    const int revents = WaitFor(fd_, POLLIN, remaining);
    if (revents < 0) {
      spdlog::error("{}: poll: {}", name_, ErrnoText(errno));
      return Errc::kIo;
    }
    if ((revents & POLLNVAL) != 0) {
      spdlog::error("{}: poll: descriptor {} is not open", name_, fd_);
      return Errc::kIo;
    }
  }
}

SocketCanBus::ReadOutcome SocketCanBus::ReadOne(CanFrame* frame) {
  can_frame record;
  iovec iov{&record, sizeof record};
  alignas(cmsghdr) char control[CMSG_SPACE(sizeof(timespec)) + CMSG_SPACE(sizeof(uint32_t)) + 64];
  msghdr message{};
  message.msg_iov = &iov;
  message.msg_iovlen = 1;
  message.msg_control = control;
  message.msg_controllen = sizeof control;
  ssize_t n;
  do {
    n = ::recvmsg(fd_, &message, MSG_DONTWAIT);
  } while (n < 0 && errno == EINTR);

  if (n < 0) {
    const int err = errno;
    if (err == EAGAIN || err == EWOULDBLOCK) return ReadOutcome::kEmpty;
    if (err == ENETDOWN) {
      // The kernel reports it once when the interface goes down; the socket stays bound and
      // works again when the interface comes back up.
      spdlog::error("{}: receive: interface is down ({})", name_, ErrnoText(err));
      return ReadOutcome::kIo;
    }
    if (err == ENODEV || err == ECONNRESET || err == EPIPE) {
      spdlog::error("{}: receive: channel gone ({})", name_, ErrnoText(err));
      return ReadOutcome::kClosed;
    }
    spdlog::error("{}: receive: {}", name_, ErrnoText(err));
    return ReadOutcome::kIo;
  }
  if (n == 0) {
    // On a SOCK_SEQPACKET peer, 0 is the end of the stream; an empty record reads the same but
    // leaves the peer connected.
    pollfd p{fd_, POLLRDHUP, 0};
    if (::poll(&p, 1, 0) > 0 && (p.revents & (POLLHUP | POLLRDHUP)) != 0) {
      spdlog::info("{}: the peer closed the channel", name_);
      return ReadOutcome::kClosed;
    }
  }

  bool have_kernel_time = false;
  int64_t realtime_ns = 0;
  std::optional<uint32_t> drop_count;
  for (cmsghdr* c = CMSG_FIRSTHDR(&message); c != nullptr; c = CMSG_NXTHDR(&message, c)) {
    if (c->cmsg_level != SOL_SOCKET) continue;
    if (c->cmsg_type == SCM_TIMESTAMPNS && c->cmsg_len >= CMSG_LEN(sizeof(timespec))) {
      timespec ts;
      std::memcpy(&ts, CMSG_DATA(c), sizeof ts);
      realtime_ns = static_cast<int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
      have_kernel_time = true;
    } else if (c->cmsg_type == SO_RXQ_OVFL && c->cmsg_len >= CMSG_LEN(sizeof(uint32_t))) {
      uint32_t count;
      std::memcpy(&count, CMSG_DATA(c), sizeof count);
      drop_count = count;
    }
  }
  const common::Duration at = ConvertTimestamp(have_kernel_time, realtime_ns);
  if (drop_count) HandleDropCount(*drop_count, at);

  const bool truncated = (message.msg_flags & MSG_TRUNC) != 0;
  const bool error_frame =
      n == static_cast<ssize_t>(sizeof record) && !truncated && (record.can_id & CAN_ERR_FLAG) != 0;
  const bool extended = (record.can_id & CAN_EFF_FLAG) != 0;
  std::string bad;
  if (n != static_cast<ssize_t>(sizeof record) || truncated) {
    bad = truncated ? "a record longer than struct can_frame (a CAN FD frame?)"
                    : "a short record of " + std::to_string(n) + " bytes";
  } else if (!error_frame && record.can_dlc > CAN_MAX_DLEN) {
    bad = "a frame with dlc " + std::to_string(record.can_dlc);
  } else if (!error_frame && !extended && (record.can_id & CAN_EFF_MASK) > CAN_SFF_MASK) {
    char id[16];
    std::snprintf(id, sizeof id, "0x%X", record.can_id & CAN_EFF_MASK);
    bad = std::string("a standard frame with id ") + id + " over 11 bits";
  }
  if (!bad.empty()) {
    uint64_t count;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      count = ++counters_.decode_errors;
    }
    if (ShouldLog(count)) {
      spdlog::warn("{}: skipped {} (decode errors {})", name_, bad, count);
    }
    return ReadOutcome::kConsumed;
  }
  if (error_frame) {
    HandleErrorFrame(record.can_id & CAN_ERR_MASK, record.data, at);
    return ReadOutcome::kConsumed;
  }

  CanFrame received;
  received.extended = extended;
  received.rtr = (record.can_id & CAN_RTR_FLAG) != 0;
  received.id = record.can_id & (extended ? CAN_EFF_MASK : CAN_SFF_MASK);
  received.dlc = record.can_dlc;
  if (!received.rtr) std::memcpy(received.data.data(), record.data, record.can_dlc);
  received.timestamp = at;
  std::lock_guard<std::mutex> lock(mutex_);
  if (!filters_.empty()) {
    bool pass = false;
    for (const CanFilter& filter : filters_) {
      if (filter.Matches(received)) {
        pass = true;
        break;
      }
    }
    if (!pass) {
      ++counters_.rx_filtered;
      return ReadOutcome::kConsumed;
    }
  }
  ++counters_.rx_frames;
  *frame = received;
  return ReadOutcome::kFrame;
}

common::Duration SocketCanBus::ConvertTimestamp(bool have_kernel_time, int64_t realtime_ns) {
  common::Duration t;
  if (have_kernel_time) {
    // The offset stays put while the wall clock runs (NTP slews both clocks alike); a jump of
    // more than a millisecond is a wall-clock step, which the offset must follow.
    if (std::optional<common::Duration> measured = MeasureRealtimeOffset()) {
      const common::Duration change = *measured - realtime_offset_;
      if (change > milliseconds(1) || change < -milliseconds(1)) {
        if (last_timestamp_ != common::Duration::zero()) {
          spdlog::info("{}: the wall clock stepped by {} us; kernel timestamps follow", name_,
                       std::chrono::duration_cast<microseconds>(change).count());
        }
        realtime_offset_ = *measured;
      }
    }
    t = common::Duration(realtime_ns) - realtime_offset_;
  } else {
    t = common::SteadyClock::Instance().Now();
  }
  if (t < last_timestamp_) t = last_timestamp_;
  last_timestamp_ = t;
  return t;
}

void SocketCanBus::HandleDropCount(uint32_t drop_count, common::Duration at) {
  // The kernel's count is cumulative for the socket and wraps at 2^32.
  const uint32_t dropped = drop_count - last_drop_count_;
  last_drop_count_ = drop_count;
  if (dropped == 0) return;
  std::lock_guard<std::mutex> lock(mutex_);
  counters_.rx_overflows += dropped;
  RaiseLocked(CanErrorKind::kRxOverflow, at,
              std::to_string(dropped) +
                  " frames dropped by the kernel: the socket receive queue "
                  "was full (" +
                  std::to_string(drop_count) + " in total)");
}

void SocketCanBus::HandleErrorFrame(uint32_t error_class, const uint8_t* data,
                                    common::Duration at) {
  ErrorFrameReport report = DecodeErrorFrame(error_class, data);
  if (!report.unreported.empty()) {
    spdlog::debug("{}: error frame class {:#x}: {}", name_, error_class, report.unreported);
  }
  std::lock_guard<std::mutex> lock(mutex_);
  counters_.rx_overflows += report.rx_overflows;
  counters_.tx_errors += report.tx_errors;
  for (ErrorFrameReport::Event& event : report.events) {
    RaiseLocked(event.kind, at, std::move(event.detail));
  }
  if (report.state && *report.state != state_) {
    spdlog::info("{}: bus state {} -> {}", name_, ToString(state_), ToString(*report.state));
    state_ = *report.state;
  }
}

void SocketCanBus::RaiseLocked(CanErrorKind kind, common::Duration at, std::string detail) {
  const uint64_t count = ++counters_.error_events;
  if (kind == CanErrorKind::kBusOff) {
    ++counters_.bus_off_events;
    spdlog::error("{}: {}: {}", name_, ToString(kind), detail);
  } else if (ShouldLog(count)) {
    spdlog::warn("{}: {}: {} (error events {})", name_, ToString(kind), detail, count);
  }
  if (events_.size() >= options_.max_pending_error_events) {
    events_.pop_front();
    if (ShouldLog(++events_dropped_)) {
      spdlog::warn("{}: {} error events dropped: nobody takes them (TakeErrorEvent)", name_,
                   events_dropped_);
    }
  }
  events_.push_back(CanErrorEvent{kind, at, std::move(detail)});
}

std::error_code SocketCanBus::SetFilters(const std::vector<CanFilter>& filters) {
  if (filters.size() > CAN_RAW_FILTER_MAX) {
    spdlog::error("{}: {} acceptance filters; SocketCAN takes at most {}", name_, filters.size(),
                  CAN_RAW_FILTER_MAX);
    return Errc::kInvalidArgument;
  }
  std::vector<can_filter> kernel;
  kernel.reserve(filters.empty() ? 1 : filters.size());
  for (const CanFilter& f : filters) {
    if (f.id > CAN_EFF_MASK || f.mask > CAN_EFF_MASK) {
      spdlog::error("{}: acceptance filter id {:#x} mask {:#x} does not fit in 29 bits", name_,
                    f.id, f.mask);
      return Errc::kInvalidArgument;
    }
    can_filter k;
    k.can_id = f.id | (f.extended ? CAN_EFF_FLAG : 0u) | (f.rtr ? CAN_RTR_FLAG : 0u) |
               (f.invert ? CAN_INV_FILTER : 0u);
    k.can_mask =
        f.mask | (f.match_extended ? CAN_EFF_FLAG : 0u) | (f.match_rtr ? CAN_RTR_FLAG : 0u);
    kernel.push_back(k);
  }
  // No filter at all would make the kernel pass nothing; the interface means "pass everything".
  if (kernel.empty()) kernel.push_back(can_filter{0, 0});

  std::lock_guard<std::mutex> lock(mutex_);
  if (features_.kernel_filters &&
      ::setsockopt(fd_, SOL_CAN_RAW, CAN_RAW_FILTER, kernel.data(),
                   static_cast<socklen_t>(kernel.size() * sizeof(can_filter))) != 0) {
    spdlog::warn("{}: the kernel refused {} acceptance filters ({}); filtering in software", name_,
                 filters.size(), ErrnoText(errno));
    features_.kernel_filters = false;
    // Filters installed earlier would still hide frames the new ones pass.
    const can_filter pass_all{0, 0};
    if (::setsockopt(fd_, SOL_CAN_RAW, CAN_RAW_FILTER, &pass_all, sizeof pass_all) != 0) {
      spdlog::error(
          "{}: cannot reset the kernel acceptance filters ({}); frames the earlier "
          "filters rejected stay hidden",
          name_, ErrnoText(errno));
    }
  }
  filters_ = filters;
  return {};
}

bool SocketCanBus::TakeErrorEvent(CanErrorEvent* event) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (events_.empty()) return false;
  *event = std::move(events_.front());
  events_.pop_front();
  return true;
}

CanBusState SocketCanBus::state() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return state_;
}

CanCounters SocketCanBus::counters() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return counters_;
}

}  // namespace kinevis::hal
