#include "hal/camera/frame_server.h"

#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <pthread.h>
#include <spdlog/spdlog.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <limits>
#include <list>
#include <mutex>
#include <thread>
#include <vector>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using SteadyTime = std::chrono::steady_clock;

int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(SteadyTime::now().time_since_epoch())
      .count();
}

// Little-endian stores and loads, independent of the host's byte order.
void Put16(uint8_t* p, uint16_t v) {
  p[0] = static_cast<uint8_t>(v);
  p[1] = static_cast<uint8_t>(v >> 8);
}
void Put32(uint8_t* p, uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<uint8_t>(v >> (8 * i));
}
void Put64(uint8_t* p, uint64_t v) {
  for (int i = 0; i < 8; ++i) p[i] = static_cast<uint8_t>(v >> (8 * i));
}
uint16_t Get16(const uint8_t* p) { return static_cast<uint16_t>(p[0] | (p[1] << 8)); }
uint32_t Get32(const uint8_t* p) {
  uint32_t v = 0;
  for (int i = 3; i >= 0; --i) v = (v << 8) | p[i];
  return v;
}
uint64_t Get64(const uint8_t* p) {
  uint64_t v = 0;
  for (int i = 7; i >= 0; --i) v = (v << 8) | p[i];
  return v;
}

std::string HostPort(const std::string& host, int port) {
  if (host.find(':') != std::string::npos) return "[" + host + "]:" + std::to_string(port);
  return host + ":" + std::to_string(port);
}

bool HostIsLittleEndian() {
  const uint16_t probe = 1;
  uint8_t first = 0;
  std::memcpy(&first, &probe, 1);
  return first == 1;
}

}  // namespace

uint32_t FramePixelFormatCode(PixelFormat format) {
  switch (format) {
    case PixelFormat::kMono8:
      return 0;
    case PixelFormat::kBgr8:
      return 1;
    case PixelFormat::kRgb8:
      return 2;
    case PixelFormat::kMono16:
      return 3;
  }
  return 0;
}

std::optional<PixelFormat> FramePixelFormatFromCode(uint32_t code) {
  switch (code) {
    case 0:
      return PixelFormat::kMono8;
    case 1:
      return PixelFormat::kBgr8;
    case 2:
      return PixelFormat::kRgb8;
    case 3:
      return PixelFormat::kMono16;
    default:
      return std::nullopt;
  }
}

void EncodeFrameRequest(const FrameRequest& request, uint8_t* bytes) {
  Put32(bytes + 0, request.magic);
  Put16(bytes + 4, request.version);
  Put16(bytes + 6, request.flags);
  Put64(bytes + 8, request.min_frame_id);
}

FrameRequest DecodeFrameRequest(const uint8_t* bytes) {
  FrameRequest r;
  r.magic = Get32(bytes + 0);
  r.version = Get16(bytes + 4);
  r.flags = Get16(bytes + 6);
  r.min_frame_id = Get64(bytes + 8);
  return r;
}

void EncodeFrameHeader(const FrameHeader& h, uint8_t* bytes) {
  std::memset(bytes, 0, kFrameHeaderSize);
  Put32(bytes + 0, h.magic);
  Put16(bytes + 4, h.version);
  Put16(bytes + 6, h.status);
  Put32(bytes + 8, h.width);
  Put32(bytes + 12, h.height);
  Put32(bytes + 16, h.pixel_format);
  Put32(bytes + 20, h.stride);
  Put64(bytes + 24, h.frame_id);
  Put64(bytes + 32, static_cast<uint64_t>(h.timestamp_ns));
  Put64(bytes + 40, h.payload_bytes);
  uint64_t fps_bits = 0;
  static_assert(sizeof(double) == 8, "IEEE 754 binary64 expected");
  std::memcpy(&fps_bits, &h.fps, 8);
  Put64(bytes + 48, fps_bits);
  Put16(bytes + 56, h.intrinsics_id_bytes);
  // 58..63 reserved, zero.
}

FrameHeader DecodeFrameHeader(const uint8_t* bytes) {
  FrameHeader h;
  h.magic = Get32(bytes + 0);
  h.version = Get16(bytes + 4);
  h.status = Get16(bytes + 6);
  h.width = Get32(bytes + 8);
  h.height = Get32(bytes + 12);
  h.pixel_format = Get32(bytes + 16);
  h.stride = Get32(bytes + 20);
  h.frame_id = Get64(bytes + 24);
  h.timestamp_ns = static_cast<int64_t>(Get64(bytes + 32));
  h.payload_bytes = Get64(bytes + 40);
  const uint64_t fps_bits = Get64(bytes + 48);
  std::memcpy(&h.fps, &fps_bits, 8);
  h.intrinsics_id_bytes = Get16(bytes + 56);
  return h;
}

const char* CheckFrameHeader(const FrameHeader& h) {
  if (h.magic != kFrameMagic) return "bad magic";
  if (h.version != kFrameProtocolVersion) return "unsupported protocol version";
  if (h.status != 0) {
    if (h.payload_bytes != 0 || h.intrinsics_id_bytes != 0) {
      return "an error response carries data";
    }
    return nullptr;
  }
  if (h.width < 1 || h.width > kMaxFrameSide) return "width is not in 1..16384";
  if (h.height < 1 || h.height > kMaxFrameSide) return "height is not in 1..16384";
  const std::optional<PixelFormat> format = FramePixelFormatFromCode(h.pixel_format);
  if (!format) return "unknown pixel format code";
  if (static_cast<uint64_t>(h.stride) <
      static_cast<uint64_t>(h.width) * static_cast<uint64_t>(BytesPerPixel(*format))) {
    return "stride is shorter than a row";
  }
  if (h.payload_bytes != static_cast<uint64_t>(h.stride) * h.height) {
    return "payload size is not height * stride";
  }
  if (h.payload_bytes > kMaxFramePayloadBytes) return "payload larger than 1 GiB";
  if (h.intrinsics_id_bytes > kMaxIntrinsicsIdBytes) return "intrinsics id longer than 255 bytes";
  if (!std::isfinite(h.fps) || h.fps < 0.0) return "fps is negative or not finite";
  return nullptr;
}

FrameSource CameraFrameSource(Camera& camera, std::chrono::milliseconds timeout) {
  return [&camera, timeout](Image* image) { return camera.Grab(image, timeout); };
}

FrameSource RenderFrameSource(const CameraFormat& format, RenderFn render,
                              std::string intrinsics_id, common::Clock& clock) {
  common::Problems problems("render frame source");
  if (format.width < 1 || format.width > static_cast<int>(kMaxFrameSide)) {
    problems.Add("width " + std::to_string(format.width) + " is not in 1..16384");
  }
  if (format.height < 1 || format.height > static_cast<int>(kMaxFrameSide)) {
    problems.Add("height " + std::to_string(format.height) + " is not in 1..16384");
  }
  if (!render) problems.Add("render function is empty");
  if (intrinsics_id.size() > kMaxIntrinsicsIdBytes) {
    problems.Add("intrinsics id \"" + intrinsics_id + "\" is longer than 255 bytes");
  }
  problems.ThrowIfAny();
  // The counter lives in the function object; the server calls it one call at a time.
  return [format, render = std::move(render), id = std::move(intrinsics_id), &clock,
          next = uint64_t{0}](Image* image) mutable -> std::error_code {
    image->Resize(format.width, format.height, format.pixel_format);
    const common::Duration time = clock.Now();
    const uint64_t frame_id = next++;
    const std::error_code ec = render(frame_id, time, image);
    if (ec) return ec;
    if (image->width != format.width || image->height != format.height ||
        image->format != format.pixel_format) {
      return Errc::kProtocol;  // the callback resized the image (sim_camera.h forbids it)
    }
    image->frame_id = frame_id;
    image->timestamp = time;
    image->intrinsics_id = id;
    return {};
  };
}

// ---- The server ----------------------------------------------------------------------------

struct FrameServer::Impl {
  struct Connection {
    int fd = -1;  // guarded by connections_mutex; closed by its own thread
    std::thread thread;
    std::atomic<bool> done{false};
  };

  FrameSource source;
  FrameServerOptions options;
  std::string backend;
  int port = 0;
  int listen_fd = -1;
  int wake_fd = -1;
  std::thread accept_thread;
  std::mutex stop_mutex;
  std::atomic<bool> stopping{false};

  std::mutex connections_mutex;
  std::list<Connection> connections;

  // The last frame the source delivered; guarded by source_mutex.
  std::mutex source_mutex;
  Image latest;
  bool have_latest = false;

  std::atomic<int64_t> silent_until_ns{0};
  std::atomic<int> corrupt_remaining{0};

  struct Counters {
    std::atomic<uint64_t> requests{0}, frames_sent{0}, errors_sent{0}, source_frames{0},
        swallowed{0}, corrupted{0}, protocol_errors{0}, accepted{0}, refused{0}, dropped{0},
        open{0};
  } counters;

  ~Impl() {
    if (listen_fd >= 0) ::close(listen_fd);
    if (wake_fd >= 0) ::close(wake_fd);
  }

  void Wake() {
    uint64_t one = 1;
    [[maybe_unused]] ssize_t n = ::write(wake_fd, &one, sizeof one);
  }

  void AcceptLoop() {
    spdlog::info("{}: serving frames", backend);
    while (!stopping.load()) {
      pollfd fds[2] = {{wake_fd, POLLIN, 0}, {listen_fd, POLLIN, 0}};
      const int r = ::poll(fds, 2, -1);
      if (r < 0) {
        if (errno == EINTR) continue;
        spdlog::error("{}: poll failed: {}; no longer accepting", backend, ErrnoText(errno));
        return;
      }
      if (stopping.load()) return;
      if ((fds[1].revents & POLLIN) != 0) Accept();
    }
  }

  void Accept() {
    ReapFinished();
    while (true) {
      const int fd = ::accept4(listen_fd, nullptr, nullptr, SOCK_CLOEXEC);
      if (fd < 0) {
        if (errno == EINTR) continue;
        if (errno != EAGAIN && errno != EWOULDBLOCK) {
          spdlog::warn("{}: accept failed: {}", backend, ErrnoText(errno));
        }
        return;
      }
      std::lock_guard<std::mutex> lock(connections_mutex);
      if (counters.open.load() >= static_cast<uint64_t>(options.max_clients)) {
        ::close(fd);
        ++counters.refused;
        spdlog::warn("{}: connection refused: {} clients already connected", backend,
                     options.max_clients);
        continue;
      }
      int one = 1;
      ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
      connections.emplace_back();
      Connection& c = connections.back();
      c.fd = fd;
      ++counters.accepted;
      ++counters.open;
      c.thread = std::thread([this, &c] {
        pthread_setname_np(pthread_self(), "frame-server");
        Serve(&c);
      });
      spdlog::debug("{}: connection accepted ({} open)", backend, counters.open.load());
    }
  }

  void ReapFinished() {
    std::list<Connection> finished;
    {
      std::lock_guard<std::mutex> lock(connections_mutex);
      for (auto it = connections.begin(); it != connections.end();) {
        auto next = std::next(it);
        if (it->done.load()) finished.splice(finished.end(), connections, it);
        it = next;
      }
    }
    for (Connection& c : finished) c.thread.join();
  }

  // Reads exactly `size` bytes; false when the peer closed, the connection was shut down or an
  // error occurred.
  static bool ReadAll(int fd, uint8_t* p, size_t size) {
    while (size > 0) {
      const ssize_t n = ::recv(fd, p, size, 0);
      if (n > 0) {
        p += n;
        size -= static_cast<size_t>(n);
      } else if (n == 0 || errno != EINTR) {
        return false;
      }
    }
    return true;
  }

  static bool SendAll(int fd, const uint8_t* p, size_t size) {
    while (size > 0) {
      const ssize_t n = ::send(fd, p, size, MSG_NOSIGNAL);
      if (n > 0) {
        p += n;
        size -= static_cast<size_t>(n);
      } else if (n < 0 && errno != EINTR) {
        return false;
      }
    }
    return true;
  }

  // Builds the response to `request` in *tx (header, intrinsics id, pixels). tx keeps its
  // capacity, so a connection allocates only when frames grow.
  void Respond(const FrameRequest& request, std::vector<uint8_t>* tx) {
    FrameHeader h;
    std::lock_guard<std::mutex> lock(source_mutex);
    if (!have_latest || latest.frame_id < request.min_frame_id) {
      have_latest = false;
      std::error_code ec;
      try {
        ec = source(&latest);
      } catch (const std::exception& e) {
        spdlog::error("{}: the frame source threw: {}", backend, e.what());
        ec = Errc::kIo;
      }
      const size_t row = static_cast<size_t>(std::max(latest.width, 0)) *
                         static_cast<size_t>(BytesPerPixel(latest.format));
      if (!ec && (latest.width < 1 || latest.height < 1 ||
                  latest.width > static_cast<int>(kMaxFrameSide) ||
                  latest.height > static_cast<int>(kMaxFrameSide) || latest.stride < row ||
                  latest.stride > std::numeric_limits<uint32_t>::max() ||
                  latest.data.size() < latest.stride * static_cast<size_t>(latest.height) ||
                  latest.intrinsics_id.size() > kMaxIntrinsicsIdBytes)) {
        spdlog::error(
            "{}: the frame source delivered an inconsistent image ({}x{} {}, stride {}, "
            "{} bytes, intrinsics id of {} bytes)",
            backend, latest.width, latest.height, ToString(latest.format), latest.stride,
            latest.data.size(), latest.intrinsics_id.size());
        ec = Errc::kProtocol;
      }
      if (ec) {
        h.status = ec.category() == HalCategory() ? static_cast<uint16_t>(ec.value())
                                                  : static_cast<uint16_t>(Errc::kIo);
        spdlog::debug("{}: the frame source failed: {}", backend, ec.message());
      } else {
        have_latest = true;
        ++counters.source_frames;
      }
    }
    if (h.status != 0) {
      tx->resize(kFrameHeaderSize);
      ++counters.errors_sent;
    } else {
      h.fps = options.fps;
      h.width = static_cast<uint32_t>(latest.width);
      h.height = static_cast<uint32_t>(latest.height);
      h.pixel_format = FramePixelFormatCode(latest.format);
      h.stride = static_cast<uint32_t>(latest.stride);
      h.frame_id = latest.frame_id;
      h.timestamp_ns = latest.timestamp.count();
      h.payload_bytes = static_cast<uint64_t>(latest.stride) * static_cast<uint64_t>(latest.height);
      h.intrinsics_id_bytes = static_cast<uint16_t>(latest.intrinsics_id.size());
      const size_t payload = static_cast<size_t>(h.payload_bytes);
      tx->resize(kFrameHeaderSize + h.intrinsics_id_bytes + payload);
      uint8_t* p = tx->data() + kFrameHeaderSize;
      std::memcpy(p, latest.intrinsics_id.data(), h.intrinsics_id_bytes);
      p += h.intrinsics_id_bytes;
      std::memcpy(p, latest.data.data(), payload);
      // The wire carries mono16 samples little-endian; Image holds them in host order.
      if (latest.format == PixelFormat::kMono16 && !HostIsLittleEndian()) {
        for (size_t i = 0; i + 1 < payload; i += 2) std::swap(p[i], p[i + 1]);
      }
      ++counters.frames_sent;
    }
    int corrupt = corrupt_remaining.load();
    while (corrupt > 0 && !corrupt_remaining.compare_exchange_weak(corrupt, corrupt - 1)) {
    }
    if (corrupt > 0) {
      h.magic = 0;
      ++counters.corrupted;
    }
    EncodeFrameHeader(h, tx->data());
  }

  void Serve(Connection* c) {
    const int fd = c->fd;  // only this thread closes it
    std::vector<uint8_t> tx;
    uint8_t rx[kFrameRequestSize];
    while (!stopping.load()) {
      if (!ReadAll(fd, rx, sizeof rx)) break;
      const FrameRequest request = DecodeFrameRequest(rx);
      if (request.magic != kFrameRequestMagic) {
        ++counters.protocol_errors;
        spdlog::warn("{}: request with bad magic 0x{:08x}; closing the connection", backend,
                     request.magic);
        break;
      }
      if (request.version != kFrameProtocolVersion) {
        // Answer in our version, so that the client can say which one the server speaks.
        ++counters.protocol_errors;
        spdlog::warn("{}: request of protocol version {}, this server speaks {}; closing", backend,
                     request.version, kFrameProtocolVersion);
        FrameHeader h;
        h.status = static_cast<uint16_t>(Errc::kUnsupported);
        uint8_t bytes[kFrameHeaderSize];
        EncodeFrameHeader(h, bytes);
        SendAll(fd, bytes, sizeof bytes);
        break;
      }
      ++counters.requests;
      if (NowNs() < silent_until_ns.load()) {
        ++counters.swallowed;
        continue;
      }
      Respond(request, &tx);
      if (!SendAll(fd, tx.data(), tx.size())) break;
    }
    std::lock_guard<std::mutex> lock(connections_mutex);
    ::close(c->fd);
    c->fd = -1;
    --counters.open;
    c->done = true;
  }
};

FrameServer::FrameServer() : impl_(std::make_unique<Impl>()) {}

FrameServer::~FrameServer() { Stop(); }

void FrameServer::Stop() {
  std::lock_guard<std::mutex> lock(impl_->stop_mutex);
  if (!impl_->accept_thread.joinable()) return;
  impl_->stopping = true;
  impl_->Wake();
  impl_->accept_thread.join();
  {
    std::lock_guard<std::mutex> connections_lock(impl_->connections_mutex);
    for (Impl::Connection& c : impl_->connections) {
      if (c.fd >= 0) ::shutdown(c.fd, SHUT_RDWR);
    }
  }
  // No thread adds connections any more; each one exits once its shut-down socket fails.
  for (Impl::Connection& c : impl_->connections) c.thread.join();
  impl_->connections.clear();
  spdlog::info("{}: stopped", impl_->backend);
}

std::unique_ptr<FrameServer> FrameServer::Listen(FrameSource source,
                                                 const FrameServerOptions& options) {
  const std::string where = HostPort(options.host, options.port);
  common::Problems problems("frame server on " + where);
  if (!source) problems.Add("frame source is empty");
  if (options.port < 0 || options.port > 65535) {
    problems.Add("port " + std::to_string(options.port) + " is not in 0..65535");
  }
  if (!std::isfinite(options.fps) || options.fps <= 0.0 || options.fps > 10000.0) {
    problems.Add("fps " + std::to_string(options.fps) + " is not in (0, 10000] frames/s");
  }
  if (options.max_clients < 1 || options.max_clients > 1024) {
    problems.Add("max_clients " + std::to_string(options.max_clients) + " is not in 1..1024");
  }
  problems.ThrowIfAny();

  std::unique_ptr<FrameServer> server(new FrameServer());
  Impl& impl = *server->impl_;
  impl.source = std::move(source);
  impl.options = options;
  const std::string device = "frame server " + where;

  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_PASSIVE | AI_NUMERICSERV;
  addrinfo* list = nullptr;
  const std::string service = std::to_string(options.port);
  const int rc = ::getaddrinfo(options.host.empty() ? nullptr : options.host.c_str(),
                               service.c_str(), &hints, &list);
  if (rc != 0) {
    throw HalError(device, "resolve " + options.host,
                   rc == EAI_SYSTEM ? ErrnoText(errno) : std::string(::gai_strerror(rc)));
  }
  int err = EADDRNOTAVAIL;
  int family = AF_INET;
  for (addrinfo* a = list; a != nullptr && impl.listen_fd < 0; a = a->ai_next) {
    const int fd =
        ::socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC | SOCK_NONBLOCK, a->ai_protocol);
    if (fd < 0) {
      err = errno;
      continue;
    }
    int one = 1;
    ::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (::bind(fd, a->ai_addr, a->ai_addrlen) != 0 || ::listen(fd, 16) != 0) {
      err = errno;
      ::close(fd);
      continue;
    }
    impl.listen_fd = fd;
    family = a->ai_family;
  }
  ::freeaddrinfo(list);
  if (impl.listen_fd < 0) {
    throw HalError(device, "listen on " + where, ErrnoText(err),
                   std::error_code(err, std::system_category()));
  }
  sockaddr_storage bound{};
  socklen_t bound_length = sizeof bound;
  if (::getsockname(impl.listen_fd, reinterpret_cast<sockaddr*>(&bound), &bound_length) != 0) {
    throw HalError(device, "read the bound port", ErrnoText(errno));
  }
  impl.port = family == AF_INET6 ? ntohs(reinterpret_cast<sockaddr_in6*>(&bound)->sin6_port)
                                 : ntohs(reinterpret_cast<sockaddr_in*>(&bound)->sin_port);
  std::string connect_host = options.host;
  if (options.host.empty() || options.host == "0.0.0.0") connect_host = "127.0.0.1";
  if (options.host == "::") connect_host = "::1";
  impl.backend = "net:" + HostPort(connect_host, impl.port);

  impl.wake_fd = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
  if (impl.wake_fd < 0) throw HalError(device, "create eventfd", ErrnoText(errno));
  impl.accept_thread = std::thread([&impl] {
    pthread_setname_np(pthread_self(), "frame-accept");
    impl.AcceptLoop();
  });
  return server;
}

const std::string& FrameServer::backend() const { return impl_->backend; }
int FrameServer::port() const { return impl_->port; }

int FrameServer::DropConnections() {
  int n = 0;
  std::lock_guard<std::mutex> lock(impl_->connections_mutex);
  for (Impl::Connection& c : impl_->connections) {
    if (c.fd >= 0 && !c.done.load()) {
      // shutdown, not close: the connection's thread owns the descriptor and closes it when its
      // blocked recv() or send() fails.
      ::shutdown(c.fd, SHUT_RDWR);
      ++n;
    }
  }
  impl_->counters.dropped += static_cast<uint64_t>(n);
  spdlog::info("{}: dropped {} connection(s)", impl_->backend, n);
  return n;
}

void FrameServer::StopAnswering(std::chrono::milliseconds duration) {
  constexpr int64_t kForeverMs = int64_t{1} << 40;  // about 35 years
  if (duration.count() >= kForeverMs) {
    impl_->silent_until_ns = std::numeric_limits<int64_t>::max();
  } else {
    impl_->silent_until_ns = NowNs() + std::max<int64_t>(0, duration.count()) * 1'000'000;
  }
}

void FrameServer::ResumeAnswering() { impl_->silent_until_ns = 0; }

void FrameServer::CorruptMagic(int responses) { impl_->corrupt_remaining = std::max(0, responses); }

FrameServerStats FrameServer::stats() const {
  const Impl::Counters& c = impl_->counters;
  FrameServerStats s;
  s.requests = c.requests;
  s.frames_sent = c.frames_sent;
  s.errors_sent = c.errors_sent;
  s.source_frames = c.source_frames;
  s.swallowed = c.swallowed;
  s.corrupted = c.corrupted;
  s.protocol_errors = c.protocol_errors;
  s.connections_accepted = c.accepted;
  s.connections_refused = c.refused;
  s.connections_dropped = c.dropped;
  s.connections_open = c.open;
  return s;
}

}  // namespace kinevis::hal
