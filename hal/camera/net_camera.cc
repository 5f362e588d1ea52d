#include "hal/camera/net_camera.h"

#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <spdlog/spdlog.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cstdio>
#include <cstring>
#include <set>
#include <thread>
#include <utility>
#include <vector>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using SteadyTime = std::chrono::steady_clock;

bool ParseInt(std::string_view s, int min, int max, int* out) {
  if (s.empty()) return false;
  int value = 0;
  auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), value);
  if (ec != std::errc() || ptr != s.data() + s.size() || value < min || value > max) return false;
  *out = value;
  return true;
}

bool HostIsLittleEndian() {
  const uint16_t probe = 1;
  uint8_t first = 0;
  std::memcpy(&first, &probe, 1);
  return first == 1;
}

// Milliseconds left until `deadline`, rounded up, clamped to [0, 60 s].
int MillisecondsLeft(SteadyTime::time_point deadline) {
  const auto left = deadline - SteadyTime::now();
  if (left <= SteadyTime::duration::zero()) return 0;
  const auto ms = std::chrono::ceil<std::chrono::milliseconds>(left).count();
  return static_cast<int>(std::min<int64_t>(ms, 60'000));
}

std::string Hex32(uint32_t v) {
  char text[16];
  std::snprintf(text, sizeof text, "0x%08x", v);
  return text;
}

}  // namespace

NetCameraOptions ParseNetCameraSource(std::string_view source) {
  common::Problems problems("camera source \"" + std::string(source) + "\"");
  NetCameraOptions options;
  const size_t colon = source.find(':');
  if (colon == std::string_view::npos || source.substr(0, colon) != "net") {
    problems.Add("not a net: source; expected net:HOST:PORT[,timeout_ms=N][,intrinsics=ID]");
    problems.ThrowIfAny();
  }
  std::vector<std::string_view> fields;
  for (std::string_view rest = source.substr(colon + 1);;) {
    const size_t comma = rest.find(',');
    fields.push_back(rest.substr(0, comma));
    if (comma == std::string_view::npos) break;
    rest = rest.substr(comma + 1);
  }
  const std::string_view target = fields.front();
  std::string_view host, port;
  if (!target.empty() && target.front() == '[') {
    const size_t close = target.find(']');
    if (close == std::string_view::npos || close + 1 >= target.size() || target[close + 1] != ':') {
      problems.Add("address \"" + std::string(target) + "\" is not [IPV6]:PORT");
    } else {
      host = target.substr(1, close - 1);
      port = target.substr(close + 2);
    }
  } else {
    const size_t last = target.rfind(':');
    if (last == std::string_view::npos) {
      problems.Add("address \"" + std::string(target) + "\" has no port; expected HOST:PORT");
    } else {
      host = target.substr(0, last);
      port = target.substr(last + 1);
      if (host.find(':') != std::string_view::npos) {
        problems.Add("host \"" + std::string(host) + "\" has a ':'; write IPv6 as [ADDR]:PORT");
      }
    }
  }
  options.host = std::string(host);
  if (!host.empty() || !port.empty()) {
    if (host.empty()) problems.Add("host is empty");
    if (!ParseInt(port, 1, 65535, &options.port)) {
      problems.Add("port \"" + std::string(port) + "\" is not an integer in 1..65535");
    }
  }
  std::set<std::string_view> seen;
  for (size_t i = 1; i < fields.size(); ++i) {
    const std::string_view item = fields[i];
    const size_t eq = item.find('=');
    const std::string_view key = item.substr(0, eq);
    const std::string_view value =
        eq == std::string_view::npos ? std::string_view() : item.substr(eq + 1);
    if (key != "timeout_ms" && key != "intrinsics") {
      problems.Add("unknown option \"" + std::string(item) +
                   "\" for net (allowed: timeout_ms=N, intrinsics=ID)");
    } else if (!seen.insert(key).second) {
      problems.Add("option \"" + std::string(key) + "\" given twice");
    } else if (eq == std::string_view::npos) {
      problems.Add("option \"" + std::string(key) + "\" needs a value (" + std::string(key) +
                   "=...)");
    } else if (key == "timeout_ms") {
      if (!ParseInt(value, 1, 600'000, &options.timeout_ms)) {
        problems.Add("timeout_ms \"" + std::string(value) +
                     "\" is not an integer in 1..600000 milliseconds");
      }
    } else {
      if (value.empty()) problems.Add("intrinsics id is empty");
      if (value.size() > kMaxIntrinsicsIdBytes) {
        problems.Add("intrinsics id \"" + std::string(value) + "\" is longer than 255 bytes");
      }
      options.intrinsics_id = std::string(value);
    }
  }
  problems.ThrowIfAny();
  return options;
}

NetCamera::NetCamera(std::string name, NetCameraOptions options)
    : name_(std::move(name)), options_(std::move(options)) {
  common::Problems problems("camera source \"" + name_ + "\"");
  if (options_.host.empty()) problems.Add("host is empty");
  if (options_.port < 1 || options_.port > 65535) {
    problems.Add("port " + std::to_string(options_.port) + " is not in 1..65535");
  }
  if (options_.timeout_ms < 1 || options_.timeout_ms > 600'000) {
    problems.Add("timeout_ms " + std::to_string(options_.timeout_ms) +
                 " is not in 1..600000 milliseconds");
  }
  if (options_.intrinsics_id.size() > kMaxIntrinsicsIdBytes) {
    problems.Add("intrinsics id \"" + options_.intrinsics_id + "\" is longer than 255 bytes");
  }
  problems.ThrowIfAny();
}

NetCamera::~NetCamera() { CloseSocket(); }

void NetCamera::CloseSocket() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  in_flight_ = false;
  discard_in_flight_ = false;
  received_ = 0;
}

void NetCamera::Connect(SteadyTime::time_point deadline) {
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_NUMERICSERV;
  addrinfo* list = nullptr;
  const std::string service = std::to_string(options_.port);
  const int rc = ::getaddrinfo(options_.host.c_str(), service.c_str(), &hints, &list);
  if (rc != 0) {
    throw HalError(name_, "open",
                   "cannot resolve \"" + options_.host + "\": " +
                       (rc == EAI_SYSTEM ? ErrnoText(errno) : std::string(::gai_strerror(rc))));
  }
  std::string why = "no address";
  for (addrinfo* a = list; a != nullptr && fd_ < 0; a = a->ai_next) {
    const int fd =
        ::socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC | SOCK_NONBLOCK, a->ai_protocol);
    if (fd < 0) {
      why = ErrnoText(errno);
      continue;
    }
    int err = 0;
    if (::connect(fd, a->ai_addr, a->ai_addrlen) != 0) {
      err = errno;
      if (err == EINPROGRESS) {
        pollfd p{fd, POLLOUT, 0};
        int r = 0;
        do {
          r = ::poll(&p, 1, MillisecondsLeft(deadline));
        } while (r < 0 && errno == EINTR);
        if (r == 0) {
          err = ETIMEDOUT;
        } else {
          socklen_t length = sizeof err;
          if (::getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &length) != 0) err = errno;
        }
      }
    }
    if (err != 0) {
      why = ErrnoText(err);
      ::close(fd);
      continue;
    }
    int one = 1;
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    fd_ = fd;
  }
  ::freeaddrinfo(list);
  if (fd_ < 0) throw HalError(name_, "open", "cannot connect: " + why);
}

bool NetCamera::SendRequest(uint64_t min_frame_id) {
  FrameRequest request;
  request.min_frame_id = min_frame_id;
  uint8_t bytes[kFrameRequestSize];
  EncodeFrameRequest(request, bytes);
  size_t sent = 0;
  // 16 bytes always fit an empty send buffer (a request is sent only when none is in flight);
  // the loop is for EINTR.
  while (sent < sizeof bytes) {
    const ssize_t n = ::send(fd_, bytes + sent, sizeof bytes - sent, MSG_NOSIGNAL);
    if (n > 0) {
      sent += static_cast<size_t>(n);
    } else if (n < 0 && errno == EINTR) {
      continue;
    } else if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
      pollfd p{fd_, POLLOUT, 0};
      ::poll(&p, 1, 100);
    } else {
      return false;
    }
  }
  in_flight_ = true;
  sent_at_ = SteadyTime::now();
  received_ = 0;
  return true;
}

std::error_code NetCamera::ReceiveResponse(SteadyTime::time_point deadline, std::string* cause) {
  while (true) {
    uint8_t* target = nullptr;
    size_t want = 0;
    if (received_ < kFrameHeaderSize) {
      target = header_bytes_.data() + received_;
      want = kFrameHeaderSize - received_;
    } else {
      const size_t id_end = kFrameHeaderSize + header_.intrinsics_id_bytes;
      const size_t end = id_end + static_cast<size_t>(header_.payload_bytes);
      if (received_ == end) return {};
      if (received_ < id_end) {
        target = reinterpret_cast<uint8_t*>(intrinsics_.data()) + (received_ - kFrameHeaderSize);
        want = id_end - received_;
      } else {
        target = rx_.data() + (received_ - id_end);
        want = end - received_;
      }
    }
    const ssize_t n = ::recv(fd_, target, want, 0);
    if (n > 0) {
      const bool header_complete =
          received_ < kFrameHeaderSize && received_ + static_cast<size_t>(n) >= kFrameHeaderSize;
      received_ += static_cast<size_t>(n);
      if (header_complete) {
        header_ = DecodeFrameHeader(header_bytes_.data());
        if (header_.magic != kFrameMagic) {
          *cause = "bad magic " + Hex32(header_.magic) + " in a frame header (expected " +
                   Hex32(kFrameMagic) +
                   ", \"KVFR\"): not a kinevis frame server, or a corrupted "
                   "stream";
          return Errc::kProtocol;
        }
        if (header_.version != kFrameProtocolVersion) {
          *cause = "the server speaks frame protocol version " + std::to_string(header_.version) +
                   ", this client version " + std::to_string(kFrameProtocolVersion);
          return Errc::kProtocol;
        }
        if (const char* why = CheckFrameHeader(header_)) {
          *cause = std::string("malformed frame header: ") + why + " (width " +
                   std::to_string(header_.width) + ", height " + std::to_string(header_.height) +
                   ", pixel format code " + std::to_string(header_.pixel_format) + ", stride " +
                   std::to_string(header_.stride) + ", payload " +
                   std::to_string(header_.payload_bytes) + " bytes, intrinsics id " +
                   std::to_string(header_.intrinsics_id_bytes) + " bytes)";
          return Errc::kProtocol;
        }
        // Grows only: once a frame of this size has arrived, no more allocation.
        if (rx_.size() < header_.payload_bytes) rx_.resize(header_.payload_bytes);
      }
      continue;
    }
    if (n == 0) {
      *cause = received_ == 0 ? "the server closed the connection"
                              : "the server closed the connection in the middle of a frame";
      return Errc::kClosed;
    }
    if (errno == EINTR) continue;
    if (errno != EAGAIN && errno != EWOULDBLOCK) {
      const int err = errno;
      *cause = "receive failed: " + ErrnoText(err);
      return err == ECONNRESET || err == EPIPE ? Errc::kClosed : Errc::kIo;
    }
    const int wait_ms = MillisecondsLeft(deadline);
    if (wait_ms == 0) return Errc::kTimeout;
    pollfd p{fd_, POLLIN, 0};
    const int r = ::poll(&p, 1, wait_ms);
    if (r < 0 && errno != EINTR) {
      *cause = "poll failed: " + ErrnoText(errno);
      return Errc::kIo;
    }
    // r == 0: the loop tries recv() once more and then finds no time left.
  }
}

void NetCamera::Fault(const std::string& cause) {
  const std::string message = name_ + ": grab failed: " + cause + "; camera in fault";
  {
    std::lock_guard<std::mutex> lock(mutex_);
    last_error_ = message;
  }
  spdlog::error("{}", message);
  CloseSocket();
  lifecycle_ = common::DeviceLifecycle::kFault;
}

void NetCamera::Open() {
  const common::DeviceLifecycle state = lifecycle_.load();
  if (state == common::DeviceLifecycle::kConfigured || state == common::DeviceLifecycle::kActive)
    return;
  CloseSocket();
  const auto deadline = SteadyTime::now() + std::chrono::milliseconds(options_.timeout_ms);
  auto fail = [&](const std::string& cause) {
    CloseSocket();
    HalError error(name_, "open", cause);
    {
      std::lock_guard<std::mutex> lock(mutex_);
      last_error_ = error.what();
    }
    throw error;
  };
  try {
    Connect(deadline);
  } catch (const HalError& e) {
    fail(e.cause());
  }
  while (true) {
    if (!SendRequest(0)) fail("cannot send a request: " + ErrnoText(errno));
    std::string cause;
    const std::error_code ec = ReceiveResponse(deadline, &cause);
    if (ec == Errc::kTimeout) {
      fail("no frame within timeout_ms = " + std::to_string(options_.timeout_ms) +
           " ms (the server does not answer)");
    }
    if (ec) fail(cause);
    in_flight_ = false;
    if (header_.status == 0) break;
    const std::error_code source_error = static_cast<Errc>(header_.status);
    if (SteadyTime::now() >= deadline) {
      fail("the server's frame source failed for timeout_ms = " +
           std::to_string(options_.timeout_ms) + " ms: " + source_error.message());
    }
    // A camera behind the server may not have a frame yet: ask again shortly.
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  CameraFormat format;
  format.width = static_cast<int>(header_.width);
  format.height = static_cast<int>(header_.height);
  format.pixel_format = *FramePixelFormatFromCode(header_.pixel_format);
  format.fps = header_.fps;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    format_ = format;
  }
  intrinsics_id_ = !options_.intrinsics_id.empty()
                       ? options_.intrinsics_id
                       : std::string(intrinsics_.data(), header_.intrinsics_id_bytes);
  next_min_frame_id_ = header_.frame_id + 1;
  delivered_any_ = false;
  lifecycle_ = common::DeviceLifecycle::kConfigured;
  spdlog::debug("{}: open, {}x{} {} at {} fps, intrinsics \"{}\"", name_, format.width,
                format.height, ToString(format.pixel_format), format.fps, intrinsics_id_);
}

std::error_code NetCamera::Start() {
  const common::DeviceLifecycle state = lifecycle_.load();
  if (state == common::DeviceLifecycle::kActive) return {};
  if (state != common::DeviceLifecycle::kConfigured) return Errc::kNotActive;
  // A frame asked for before Stop() is stale by now.
  if (in_flight_) discard_in_flight_ = true;
  delivered_any_ = false;
  lifecycle_ = common::DeviceLifecycle::kActive;
  return {};
}

void NetCamera::Stop() {
  if (lifecycle_.load() == common::DeviceLifecycle::kActive)
    lifecycle_ = common::DeviceLifecycle::kConfigured;
}

std::error_code NetCamera::Grab(Image* out, std::chrono::milliseconds timeout) {
  const common::DeviceLifecycle state = lifecycle_.load();
  if (state == common::DeviceLifecycle::kFault) return Errc::kClosed;
  if (state != common::DeviceLifecycle::kActive) return Errc::kNotActive;
  const auto deadline = SteadyTime::now() + std::max(timeout, std::chrono::milliseconds(0));
  const auto link_timeout = std::chrono::milliseconds(options_.timeout_ms);
  while (true) {
    if (!in_flight_ && !SendRequest(next_min_frame_id_)) {
      const int err = errno;
      Fault("cannot send a request: " + ErrnoText(err));
      return Errc::kClosed;
    }
    std::string cause;
    const std::error_code ec = ReceiveResponse(deadline, &cause);
    if (ec == Errc::kTimeout) {
      ++counters_.timeouts;
      if (SteadyTime::now() - sent_at_ >= link_timeout) {
        Fault(
            "no answer to a frame request for timeout_ms = " + std::to_string(options_.timeout_ms) +
            " ms (the server stopped answering or the link is down)");
      }
      return Errc::kTimeout;
    }
    if (ec) {
      if (ec == Errc::kProtocol) ++counters_.decode_errors;
      Fault(cause);
      return ec;
    }
    in_flight_ = false;
    received_ = 0;
    if (discard_in_flight_) {
      discard_in_flight_ = false;
      continue;
    }
    if (header_.status != 0) {
      const std::error_code source_error =
          header_.status <= static_cast<uint16_t>(Errc::kModbusException)
              ? std::error_code(static_cast<Errc>(header_.status))
              : std::error_code(Errc::kIo);
      if (source_error == Errc::kTimeout) {
        ++counters_.timeouts;
      } else {
        ++counters_.decode_errors;
      }
      spdlog::warn("{}: the server's frame source failed: {}", name_, source_error.message());
      return source_error;
    }
    if (delivered_any_ && header_.frame_id <= last_frame_id_) {
      // The server's source went back in its numbering; frame ids must increase.
      ++counters_.duplicates;
      if (SteadyTime::now() >= deadline) {
        ++counters_.timeouts;
        return Errc::kTimeout;
      }
      continue;
    }
    break;
  }

  const PixelFormat format = *FramePixelFormatFromCode(header_.pixel_format);
  const int width = static_cast<int>(header_.width);
  const int height = static_cast<int>(header_.height);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (format_.width != width || format_.height != height || format_.pixel_format != format) {
      spdlog::info("{}: the server's frames changed to {}x{} {}", name_, width, height,
                   ToString(format));
      format_.width = width;
      format_.height = height;
      format_.pixel_format = format;
    }
  }
  const size_t payload = static_cast<size_t>(header_.payload_bytes);
  out->Resize(width, height, format);
  out->stride = header_.stride;
  out->data.resize(payload);  // keeps the capacity: allocates only when frames grow
  std::memcpy(out->data.data(), rx_.data(), payload);
  if (format == PixelFormat::kMono16 && !HostIsLittleEndian()) {
    for (size_t i = 0; i + 1 < payload; i += 2) std::swap(out->data[i], out->data[i + 1]);
  }
  out->frame_id = header_.frame_id;
  out->timestamp = common::Duration(header_.timestamp_ns);
  if (!options_.intrinsics_id.empty()) {
    out->intrinsics_id = intrinsics_id_;
  } else {
    out->intrinsics_id.assign(intrinsics_.data(), header_.intrinsics_id_bytes);
  }
  if (delivered_any_) counters_.dropped += header_.frame_id - last_frame_id_ - 1;
  delivered_any_ = true;
  last_frame_id_ = header_.frame_id;
  next_min_frame_id_ = header_.frame_id + 1;
  ++counters_.frames;
  return {};
}

CameraFormat NetCamera::format() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return format_;
}

std::string NetCamera::last_error() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return last_error_;
}

}  // namespace kinevis::hal
