#include "hal/modbus/modbus_server.h"

#include <fcntl.h>
#include <modbus.h>
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
#include <array>
#include <atomic>
#include <cerrno>
#include <condition_variable>
#include <cstring>
#include <exception>
#include <limits>
#include <thread>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using SteadyTime = std::chrono::steady_clock;

constexpr size_t kTcpMaxAdu = 260;  // MBAP header (7) + PDU (253)
constexpr size_t kRtuMaxAdu = 256;  // unit (1) + PDU (253) + CRC (2)
constexpr int kMaxValues = 2000;    // the most values one request carries (0x0F: 1968 bits)

int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(SteadyTime::now().time_since_epoch())
      .count();
}

int U16(const uint8_t* p) { return (p[0] << 8) | p[1]; }

std::string HostPort(const std::string& host, int port) {
  if (host.find(':') != std::string::npos) return "[" + host + "]:" + std::to_string(port);
  return host + ":" + std::to_string(port);
}

// The total length of the RTU request (unit .. CRC) starting at b, from the bytes seen so far:
// 0 when more bytes are needed to tell, -1 for a function code whose request length is unknown
// here (its end is the silence after it).
int RtuRequestLength(const uint8_t* b, size_t have) {
  if (have < 2) return 0;
  switch (b[1]) {
    case 0x01:
    case 0x02:
    case 0x03:
    case 0x04:
    case 0x05:
    case 0x06:
    case 0x08:
      return 8;
    case 0x07:
    case 0x0B:
    case 0x0C:
    case 0x11:
      return 4;
    case 0x0F:
    case 0x10:
      return have < 7 ? 0 : 9 + b[6];
    case 0x16:
      return 10;
    case 0x17:
      return have < 11 ? 0 : 13 + b[10];
    default:
      return -1;
  }
}

const char* FunctionName(int function) {
  switch (function) {
    case 0x01:
      return "read coils";
    case 0x02:
      return "read discrete inputs";
    case 0x03:
      return "read holding registers";
    case 0x04:
      return "read input registers";
    case 0x05:
      return "write coil";
    case 0x06:
      return "write register";
    case 0x0F:
      return "write coils";
    case 0x10:
      return "write registers";
    case 0x11:
      return "report server id";
    case 0x16:
      return "mask write register";
    case 0x17:
      return "write and read registers";
    default:
      return "unknown function";
  }
}

void ValidateOptions(const ModbusServer::Options& o, const std::string& what, bool rtu) {
  std::string problems;
  auto problem = [&](const std::string& p) { problems += (problems.empty() ? "" : "; ") + p; };
  auto size = [&](int value, const char* field) {
    if (value < 0 || value > 65536) {
      problem(std::string(field) + " " + std::to_string(value) + " is not in 0..65536");
    }
  };
  size(o.coils, "coils");
  size(o.discrete_inputs, "discrete_inputs");
  size(o.holding_registers, "holding_registers");
  size(o.input_registers, "input_registers");
  if (o.unit < 1 || o.unit > 247) problem("unit " + std::to_string(o.unit) + " is not in 1..247");
  if (rtu) {
    if (o.baud <= 0) problem("baud " + std::to_string(o.baud) + " is not positive");
    if (o.parity != 'N' && o.parity != 'E' && o.parity != 'O') {
      problem(std::string("parity '") + o.parity + "' is not N, E or O");
    }
    if (o.data_bits < 5 || o.data_bits > 8) {
      problem("data_bits " + std::to_string(o.data_bits) + " is not in 5..8");
    }
    if (o.stop_bits != 1 && o.stop_bits != 2) {
      problem("stop_bits " + std::to_string(o.stop_bits) + " is not 1 or 2");
    }
  }
  if (!problems.empty()) throw common::ConfigError("Modbus server " + what + ": " + problems);
}

}  // namespace

uint16_t ModbusRtuCrc(const uint8_t* data, size_t size) {
  uint16_t crc = 0xFFFF;
  for (size_t i = 0; i < size; ++i) {
    crc ^= data[i];
    for (int bit = 0; bit < 8; ++bit) {
      crc = (crc & 1U) != 0 ? static_cast<uint16_t>((crc >> 1) ^ 0xA001U)
                            : static_cast<uint16_t>(crc >> 1);
    }
  }
  return crc;
}

struct ModbusServer::Impl {
  struct Client {
    int fd = -1;
    size_t have = 0;
    std::array<uint8_t, kTcpMaxAdu> buffer{};
  };

  struct Counters {
    std::atomic<uint64_t> requests{0}, replies{0}, exceptions{0}, swallowed{0}, ignored{0},
        broadcasts{0}, framing_errors{0}, accepted{0}, dropped{0}, open{0};
  };

  ModbusServer* owner = nullptr;
  Options options;
  bool tcp = true;
  std::string backend;
  int port = 0;
  int listen_fd = -1;
  int rtu_fd = -1;  // the caller's pty master; never closed here
  int wake_fd = -1;
  modbus_t* ctx = nullptr;
  std::thread thread;
  std::mutex stop_mutex;
  std::atomic<bool> stopping{false};

  // Server thread only.
  std::vector<Client> clients;
  std::vector<pollfd> poll_fds;
  std::array<uint8_t, 2 * kRtuMaxAdu> rtu_buffer{};
  size_t rtu_have = 0;
  int rtu_gap_ms = 10;
  std::array<uint16_t, kMaxValues> values{};

  // Control requests from other threads.
  std::mutex control_mutex;
  std::condition_variable control_cv;
  uint64_t drops_requested = 0;
  uint64_t drops_done = 0;
  int last_drop_count = 0;
  bool loop_exited = false;
  std::atomic<int64_t> silent_until_ns{0};
  std::atomic<int64_t> reply_delay_ns{0};

  // Guarded by owner->registers_mutex_.
  RequestHook request_hook;
  WriteHook write_hook;

  Counters counters;

  ~Impl() {
    for (Client& c : clients) {
      if (c.fd >= 0) ::close(c.fd);
    }
    if (listen_fd >= 0) ::close(listen_fd);
    if (wake_fd >= 0) ::close(wake_fd);
    if (ctx != nullptr) {
      modbus_set_socket(ctx, -1);
      modbus_free(ctx);
    }
  }

  void Wake() {
    uint64_t one = 1;
    // A full eventfd counter still wakes the loop; nothing to do on failure.
    [[maybe_unused]] ssize_t n = ::write(wake_fd, &one, sizeof one);
  }

  void DrainWake() {
    uint64_t value = 0;
    [[maybe_unused]] ssize_t n = ::read(wake_fd, &value, sizeof value);
  }

  void Start() {
    thread = std::thread([this] {
      pthread_setname_np(pthread_self(), "modbus-server");
      Loop();
    });
  }

  // ---- The loop -------------------------------------------------------------------------------

  void Loop() {
    spdlog::info(
        "{}: serving unit {} ({} coils, {} discrete inputs, {} holding registers, {} "
        "input registers)",
        backend, options.unit, options.coils, options.discrete_inputs, options.holding_registers,
        options.input_registers);
    while (!stopping.load()) {
      HandleControl();
      poll_fds.clear();
      poll_fds.push_back({wake_fd, POLLIN, 0});
      int timeout_ms = -1;
      if (tcp) {
        poll_fds.push_back({listen_fd, POLLIN, 0});
        for (const Client& c : clients) poll_fds.push_back({c.fd, POLLIN, 0});
      } else {
        poll_fds.push_back({rtu_fd, POLLIN, 0});
        if (rtu_have > 0) timeout_ms = rtu_gap_ms;
      }
      int r = ::poll(poll_fds.data(), poll_fds.size(), timeout_ms);
      if (r < 0) {
        if (errno == EINTR) continue;
        spdlog::error("{}: poll failed: {}; server stopped", backend, ErrnoText(errno));
        break;
      }
      if ((poll_fds[0].revents & POLLIN) != 0) DrainWake();
      if (stopping.load()) break;
      if (tcp) {
        ServeTcp();
      } else if (!ServeRtu(r == 0)) {
        break;
      }
    }
    CloseAllClients();
    std::lock_guard<std::mutex> lock(control_mutex);
    loop_exited = true;
    control_cv.notify_all();
  }

  void HandleControl() {
    std::lock_guard<std::mutex> lock(control_mutex);
    if (drops_requested == drops_done) return;
    last_drop_count = CloseAllClients();
    counters.dropped += static_cast<uint64_t>(last_drop_count);
    spdlog::info("{}: dropped {} connection(s)", backend, last_drop_count);
    drops_done = drops_requested;
    control_cv.notify_all();
  }

  int CloseAllClients() {
    int n = 0;
    for (Client& c : clients) {
      if (c.fd >= 0) {
        ::close(c.fd);
        c.fd = -1;
        ++n;
      }
    }
    clients.clear();
    counters.open = 0;
    return n;
  }

  bool Silent() const { return NowNs() < silent_until_ns.load(); }

  // Waits `ns` unless the server is stopping; returns false when it is.
  bool Delay(int64_t ns) {
    const int64_t deadline = NowNs() + ns;
    while (!stopping.load()) {
      int64_t left = deadline - NowNs();
      if (left <= 0) return true;
      pollfd p{wake_fd, POLLIN, 0};
      int ms = static_cast<int>(std::min<int64_t>((left + 999'999) / 1'000'000, 60'000));
      // A wake-up drained here is not lost: the loop checks every control request at the top of
      // each pass, and stopping is checked right here.
      if (::poll(&p, 1, ms) > 0) DrainWake();
    }
    return false;
  }

  // ---- TCP ------------------------------------------------------------------------------------

  void ServeTcp() {
    // poll_fds[2 + i] belongs to clients[i] as they were when poll() was called; Accept() runs
    // after so that the indices stay valid.
    const size_t polled = poll_fds.size() - 2;
    for (size_t i = 0; i < polled && i < clients.size(); ++i) {
      if (poll_fds[2 + i].revents != 0 && clients[i].fd >= 0) ReadClient(&clients[i]);
    }
    auto closed = [](const Client& c) { return c.fd < 0; };
    clients.erase(std::remove_if(clients.begin(), clients.end(), closed), clients.end());
    counters.open = clients.size();
    if ((poll_fds[1].revents & POLLIN) != 0) Accept();
  }

  void Accept() {
    while (true) {
      int fd = ::accept4(listen_fd, nullptr, nullptr, SOCK_CLOEXEC | SOCK_NONBLOCK);
      if (fd < 0) {
        if (errno == EINTR) continue;
        if (errno != EAGAIN && errno != EWOULDBLOCK) {
          spdlog::warn("{}: accept failed: {}", backend, ErrnoText(errno));
        }
        return;
      }
      int one = 1;
      ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
      Client c;
      c.fd = fd;
      clients.push_back(c);
      ++counters.accepted;
      counters.open = clients.size();
      spdlog::debug("{}: connection accepted ({} open)", backend, clients.size());
    }
  }

  void CloseClient(Client* c, const char* why) {
    spdlog::debug("{}: closing connection: {}", backend, why);
    ::close(c->fd);
    c->fd = -1;
    c->have = 0;
  }

  void ReadClient(Client* c) {
    ssize_t n = ::recv(c->fd, c->buffer.data() + c->have, c->buffer.size() - c->have, 0);
    if (n == 0) return CloseClient(c, "peer closed");
    if (n < 0) {
      if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR) return;
      return CloseClient(c, "receive failed");
    }
    c->have += static_cast<size_t>(n);
    // MBAP header: transaction id (2), protocol id (2, always 0), length (2: unit + PDU), unit.
    while (c->have >= 7) {
      const uint8_t* b = c->buffer.data();
      const int protocol = U16(b + 2);
      const int length = U16(b + 4);
      if (protocol != 0 || length < 2 || length > 254) {
        ++counters.framing_errors;
        return CloseClient(c, "malformed MBAP header");
      }
      const size_t total = 6 + static_cast<size_t>(length);
      if (c->have < total) break;
      if (!HandleFrame(c->fd, b, static_cast<int>(total))) {
        return CloseClient(c, stopping.load() ? "server stopping" : "reply failed");
      }
      std::memmove(c->buffer.data(), b + total, c->have - total);
      c->have -= total;
    }
  }

  // ---- RTU ------------------------------------------------------------------------------------

  // One pass of the RTU side after poll(); `silence` when poll() timed out, i.e. the line has
  // been quiet for rtu_gap_ms. Returns false when the descriptor is unusable.
  bool ServeRtu(bool silence) {
    if (silence) {
      ProcessRtu(true);
      return true;
    }
    const int revents = poll_fds[1].revents;
    if ((revents & POLLNVAL) != 0) {
      spdlog::error("{}: the pty master descriptor was closed; server stopped", backend);
      return false;
    }
    if ((revents & POLLIN) != 0) {
      ssize_t n = ::read(rtu_fd, rtu_buffer.data() + rtu_have, rtu_buffer.size() - rtu_have);
      if (n > 0) {
        rtu_have += static_cast<size_t>(n);
        ProcessRtu(false);
        return true;
      }
      if (n < 0 && (errno == EAGAIN || errno == EINTR)) return true;
    }
    if ((revents & (POLLHUP | POLLERR | POLLIN)) != 0) {
      // No host has the slave side open (a pty master reports POLLHUP / EIO then): wait for one
      // without spinning.
      Delay(20'000'000);
    }
    return true;
  }

  // Takes every complete frame out of rtu_buffer. A frame's length follows from its function
  // code; its CRC confirms it. Bytes that do not start a valid frame (line noise, a frame cut
  // short, a frame of unknown length followed by silence but with a bad CRC) are dropped one at
  // a time until a valid frame starts, so that a good request right behind garbage is still
  // served without relying on the timing of the gap between them.
  void ProcessRtu(bool silence) {
    size_t dropped = 0;
    uint8_t* b = rtu_buffer.data();
    while (rtu_have > 0) {
      int length = RtuRequestLength(b, rtu_have);
      bool complete = length > 0 && rtu_have >= static_cast<size_t>(length);
      if (length < 0 && silence) {
        length = static_cast<int>(rtu_have);  // an unknown function's frame ends with the silence
        complete = true;
      }
      const bool impossible = length > static_cast<int>(kRtuMaxAdu) || (complete && length < 4) ||
                              (!complete && rtu_have == rtu_buffer.size());
      if (!complete && !impossible) {
        if (!silence) break;  // wait for the rest
      } else if (!impossible) {
        const uint16_t crc = static_cast<uint16_t>(b[length - 2] | (b[length - 1] << 8));
        if (ModbusRtuCrc(b, static_cast<size_t>(length - 2)) == crc) {
          const int unit = b[0];
          if (unit != options.unit && unit != MODBUS_BROADCAST_ADDRESS) {
            ++counters.ignored;
          } else {
            HandleFrame(rtu_fd, b, length);
          }
          std::memmove(b, b + length, rtu_have - static_cast<size_t>(length));
          rtu_have -= static_cast<size_t>(length);
          continue;
        }
      }
      // Counted at once, before a good frame behind the noise is answered.
      if (dropped == 0) ++counters.framing_errors;
      std::memmove(b, b + 1, rtu_have - 1);
      --rtu_have;
      ++dropped;
    }
    if (dropped > 0) {
      spdlog::debug("{}: {} byte(s) of line noise or damaged frames discarded", backend, dropped);
    }
  }

  // ---- Requests -------------------------------------------------------------------------------

  // Decodes and checks one request PDU (function code first) against the map, in the order of
  // the specification's state diagrams: function code, quantity and length, address range.
  ModbusErrc Decode(const uint8_t* pdu, int length, int unit, ModbusRequest* req) {
    const ModbusRegisterMap& map = owner->registers_;
    *req = ModbusRequest();
    req->unit = unit;
    req->function = pdu[0];
    auto in_map = [](int address, int count, size_t size) {
      return static_cast<size_t>(address) + static_cast<size_t>(count) <= size;
    };
    switch (pdu[0]) {
      case MODBUS_FC_READ_COILS:
      case MODBUS_FC_READ_DISCRETE_INPUTS:
      case MODBUS_FC_READ_HOLDING_REGISTERS:
      case MODBUS_FC_READ_INPUT_REGISTERS: {
        if (length != 5) return ModbusErrc::kIllegalDataValue;
        req->address = U16(pdu + 1);
        req->count = U16(pdu + 3);
        const bool bits = pdu[0] <= MODBUS_FC_READ_DISCRETE_INPUTS;
        if (req->count < 1 ||
            req->count > (bits ? MODBUS_MAX_READ_BITS : MODBUS_MAX_READ_REGISTERS)) {
          return ModbusErrc::kIllegalDataValue;
        }
        size_t size = 0;
        switch (pdu[0]) {
          case MODBUS_FC_READ_COILS:
            size = map.coils.size();
            break;
          case MODBUS_FC_READ_DISCRETE_INPUTS:
            size = map.discrete_inputs.size();
            break;
          case MODBUS_FC_READ_HOLDING_REGISTERS:
            size = map.holding_registers.size();
            break;
          default:
            size = map.input_registers.size();
            break;
        }
        if (!in_map(req->address, req->count, size)) return ModbusErrc::kIllegalDataAddress;
        return ModbusErrc::kNone;
      }
      case MODBUS_FC_WRITE_SINGLE_COIL: {
        if (length != 5) return ModbusErrc::kIllegalDataValue;
        const int value = U16(pdu + 3);
        if (value != 0xFF00 && value != 0x0000) return ModbusErrc::kIllegalDataValue;
        req->address = U16(pdu + 1);
        req->count = 1;
        if (!in_map(req->address, 1, map.coils.size())) return ModbusErrc::kIllegalDataAddress;
        values[0] = value != 0 ? 1 : 0;
        req->values = values.data();
        return ModbusErrc::kNone;
      }
      case MODBUS_FC_WRITE_SINGLE_REGISTER: {
        if (length != 5) return ModbusErrc::kIllegalDataValue;
        req->address = U16(pdu + 1);
        req->count = 1;
        if (!in_map(req->address, 1, map.holding_registers.size())) {
          return ModbusErrc::kIllegalDataAddress;
        }
        values[0] = static_cast<uint16_t>(U16(pdu + 3));
        req->values = values.data();
        return ModbusErrc::kNone;
      }
      case MODBUS_FC_WRITE_MULTIPLE_COILS: {
        if (length < 6) return ModbusErrc::kIllegalDataValue;
        req->address = U16(pdu + 1);
        req->count = U16(pdu + 3);
        const int bytes = pdu[5];
        if (req->count < 1 || req->count > MODBUS_MAX_WRITE_BITS || bytes != (req->count + 7) / 8 ||
            length != 6 + bytes) {
          return ModbusErrc::kIllegalDataValue;
        }
        if (!in_map(req->address, req->count, map.coils.size())) {
          return ModbusErrc::kIllegalDataAddress;
        }
        for (int i = 0; i < req->count; ++i) values[i] = (pdu[6 + i / 8] >> (i % 8)) & 1;
        req->values = values.data();
        return ModbusErrc::kNone;
      }
      case MODBUS_FC_WRITE_MULTIPLE_REGISTERS: {
        if (length < 6) return ModbusErrc::kIllegalDataValue;
        req->address = U16(pdu + 1);
        req->count = U16(pdu + 3);
        const int bytes = pdu[5];
        if (req->count < 1 || req->count > MODBUS_MAX_WRITE_REGISTERS || bytes != 2 * req->count ||
            length != 6 + bytes) {
          return ModbusErrc::kIllegalDataValue;
        }
        if (!in_map(req->address, req->count, map.holding_registers.size())) {
          return ModbusErrc::kIllegalDataAddress;
        }
        for (int i = 0; i < req->count; ++i) {
          values[i] = static_cast<uint16_t>(U16(pdu + 6 + 2 * static_cast<ptrdiff_t>(i)));
        }
        req->values = values.data();
        return ModbusErrc::kNone;
      }
      case MODBUS_FC_MASK_WRITE_REGISTER: {
        if (length != 7) return ModbusErrc::kIllegalDataValue;
        req->address = U16(pdu + 1);
        req->count = 1;
        if (!in_map(req->address, 1, map.holding_registers.size())) {
          return ModbusErrc::kIllegalDataAddress;
        }
        const int current = map.holding_registers[static_cast<size_t>(req->address)];
        const int and_mask = U16(pdu + 3);
        const int or_mask = U16(pdu + 5);
        values[0] = static_cast<uint16_t>((current & and_mask) | (or_mask & ~and_mask));
        req->values = values.data();
        return ModbusErrc::kNone;
      }
      case MODBUS_FC_WRITE_AND_READ_REGISTERS: {
        if (length < 10) return ModbusErrc::kIllegalDataValue;
        req->read_address = U16(pdu + 1);
        req->read_count = U16(pdu + 3);
        req->address = U16(pdu + 5);
        req->count = U16(pdu + 7);
        const int bytes = pdu[9];
        if (req->read_count < 1 || req->read_count > MODBUS_MAX_WR_READ_REGISTERS ||
            req->count < 1 || req->count > MODBUS_MAX_WR_WRITE_REGISTERS ||
            bytes != 2 * req->count || length != 10 + bytes) {
          return ModbusErrc::kIllegalDataValue;
        }
        const size_t size = map.holding_registers.size();
        if (!in_map(req->address, req->count, size) ||
            !in_map(req->read_address, req->read_count, size)) {
          return ModbusErrc::kIllegalDataAddress;
        }
        for (int i = 0; i < req->count; ++i) {
          values[i] = static_cast<uint16_t>(U16(pdu + 10 + 2 * static_cast<ptrdiff_t>(i)));
        }
        req->values = values.data();
        return ModbusErrc::kNone;
      }
      case MODBUS_FC_REPORT_SLAVE_ID:
        return length == 1 ? ModbusErrc::kNone : ModbusErrc::kIllegalDataValue;
      default:
        return ModbusErrc::kIllegalFunction;
    }
  }

  // Serves one complete frame (TCP: MBAP header + PDU; RTU: unit + PDU + CRC) that arrived on
  // `fd`. Returns false when the answer could not be sent (or the server is stopping).
  bool HandleFrame(int fd, const uint8_t* frame, int length) {
    const int header = tcp ? 7 : 1;
    const int unit = frame[header - 1];
    const uint8_t* pdu = frame + header;
    const int pdu_length = length - header - (tcp ? 0 : 2);
    ++counters.requests;
    if (Silent()) {
      ++counters.swallowed;
      return true;
    }
    const bool broadcast = !tcp && unit == MODBUS_BROADCAST_ADDRESS;
    modbus_set_socket(ctx, fd);
    if (tcp && unit != options.unit && unit != MODBUS_BROADCAST_ADDRESS &&
        unit != MODBUS_TCP_SLAVE) {
      ++counters.exceptions;
      return modbus_reply_exception(ctx, frame, MODBUS_EXCEPTION_GATEWAY_TARGET) >= 0;
    }
    const int64_t delay = reply_delay_ns.load();
    if (delay > 0 && !Delay(delay)) return false;

    std::lock_guard<std::recursive_mutex> lock(owner->registers_mutex_);
    ModbusRequest req;
    ModbusErrc refusal = Decode(pdu, pdu_length, unit, &req);
    if (broadcast && !req.is_write()) {
      ++counters.ignored;  // only writes may be broadcast
      return true;
    }
    if (refusal == ModbusErrc::kNone && request_hook) {
      try {
        refusal = request_hook(req, owner->registers_);
      } catch (const std::exception& e) {
        spdlog::error("{}: request hook threw on {}: {}", backend, FunctionName(req.function),
                      e.what());
        refusal = ModbusErrc::kServerDeviceFailure;
      }
      const int code = static_cast<int>(refusal);
      if (code < 0 || code > 11 || code == 9) {
        spdlog::error(
            "{}: request hook returned {}, which is no exception code; answering "
            "SERVER DEVICE FAILURE",
            backend, code);
        refusal = ModbusErrc::kServerDeviceFailure;
      }
    }
    if (refusal != ModbusErrc::kNone) {
      spdlog::debug("{}: {} at {} count {}: answering {}", backend, FunctionName(req.function),
                    req.address, req.count, make_error_code(refusal).message());
      if (broadcast) return true;
      ++counters.exceptions;
      return modbus_reply_exception(ctx, frame, static_cast<unsigned>(refusal)) >= 0;
    }

    ModbusRegisterMap& map = owner->registers_;
    modbus_mapping_t mapping{};
    mapping.nb_bits = static_cast<int>(map.coils.size());
    mapping.nb_input_bits = static_cast<int>(map.discrete_inputs.size());
    mapping.nb_registers = static_cast<int>(map.holding_registers.size());
    mapping.nb_input_registers = static_cast<int>(map.input_registers.size());
    mapping.tab_bits = map.coils.data();
    mapping.tab_input_bits = map.discrete_inputs.data();
    mapping.tab_registers = map.holding_registers.data();
    mapping.tab_input_registers = map.input_registers.data();
    // Counted before the answer leaves, so that a peer holding the answer sees it counted.
    if (broadcast) {
      ++counters.broadcasts;
    } else {
      ++counters.replies;
    }
    const int rc = modbus_reply(ctx, frame, length, &mapping);
    if (req.is_write() && write_hook) {
      try {
        write_hook(req, map);
      } catch (const std::exception& e) {
        spdlog::error("{}: write hook threw on {}: {}", backend, FunctionName(req.function),
                      e.what());
      }
    }
    return rc >= 0;
  }
};

ModbusServer::ModbusServer() : impl_(std::make_unique<Impl>()) { impl_->owner = this; }

ModbusServer::~ModbusServer() { Stop(); }

void ModbusServer::Stop() {
  std::lock_guard<std::mutex> lock(impl_->stop_mutex);
  if (!impl_->thread.joinable()) return;
  impl_->stopping = true;
  impl_->Wake();
  impl_->thread.join();
  spdlog::info("{}: stopped", impl_->backend);
}

std::unique_ptr<ModbusServer> ModbusServer::ListenTcp(const std::string& host, int port,
                                                      const Options& options) {
  const std::string where = HostPort(host, port);
  ValidateOptions(options, "on " + where, /*rtu=*/false);
  if (port < 0 || port > 65535) {
    throw common::ConfigError("Modbus server on " + where + ": port " + std::to_string(port) +
                              " is not in 0..65535");
  }
  std::unique_ptr<ModbusServer> server(new ModbusServer());
  Impl& impl = *server->impl_;
  impl.options = options;
  impl.tcp = true;
  const std::string device = "modbus-tcp server " + where;

  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_PASSIVE | AI_NUMERICSERV;
  addrinfo* list = nullptr;
  const std::string service = std::to_string(port);
  int rc = ::getaddrinfo(host.empty() ? nullptr : host.c_str(), service.c_str(), &hints, &list);
  if (rc != 0) {
    throw HalError(device, "resolve " + host,
                   rc == EAI_SYSTEM ? ErrnoText(errno) : std::string(::gai_strerror(rc)));
  }
  int err = EADDRNOTAVAIL;
  int family = AF_INET;
  for (addrinfo* a = list; a != nullptr && impl.listen_fd < 0; a = a->ai_next) {
    int fd = ::socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC | SOCK_NONBLOCK, a->ai_protocol);
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
  std::string connect_host = host;
  if (host.empty() || host == "0.0.0.0") connect_host = "127.0.0.1";
  if (host == "::") connect_host = "::1";
  impl.backend = "modbus-tcp:" + HostPort(connect_host, impl.port);
  if (options.unit != 1) impl.backend += ",unit=" + std::to_string(options.unit);

  // The context only builds and sends answers (modbus_reply); framing, connections and unit
  // filtering are done here, so it never connects or listens by itself.
  impl.ctx = modbus_new_tcp("127.0.0.1", impl.port);
  if (impl.ctx == nullptr) throw HalError(device, "create libmodbus TCP context", ErrnoText(errno));

  impl.wake_fd = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
  if (impl.wake_fd < 0) throw HalError(device, "create eventfd", ErrnoText(errno));
  server->registers_.coils.assign(static_cast<size_t>(options.coils), 0);
  server->registers_.discrete_inputs.assign(static_cast<size_t>(options.discrete_inputs), 0);
  server->registers_.holding_registers.assign(static_cast<size_t>(options.holding_registers), 0);
  server->registers_.input_registers.assign(static_cast<size_t>(options.input_registers), 0);
  impl.Start();
  return server;
}

std::unique_ptr<ModbusServer> ModbusServer::ServeRtu(int master_fd, const std::string& device_path,
                                                     const Options& options) {
  ValidateOptions(options, "on " + device_path, /*rtu=*/true);
  if (master_fd < 0 || device_path.empty()) {
    throw common::ConfigError("Modbus RTU server on \"" + device_path +
                              "\": pty master descriptor " + std::to_string(master_fd) +
                              (device_path.empty() ? " and empty path" : "") +
                              " (need an open descriptor and the slave path)");
  }
  std::unique_ptr<ModbusServer> server(new ModbusServer());
  Impl& impl = *server->impl_;
  impl.options = options;
  impl.tcp = false;
  impl.rtu_fd = master_fd;
  impl.backend = "modbus-rtu:" + device_path + "@" + std::to_string(options.baud) + "," +
                 std::to_string(options.data_bits) + options.parity +
                 std::to_string(options.stop_bits);
  if (options.unit != 1) impl.backend += ",unit=" + std::to_string(options.unit);
  // The inter-frame silence (3.5 characters of 11 bits) at the line's rate, but not under 10 ms:
  // a pty has no line timing, and a frame written in pieces must not be cut.
  impl.rtu_gap_ms = std::max(10, static_cast<int>(3.5 * 11 * 1000 / options.baud) + 1);

  // The context only builds and sends answers on the master descriptor; it is never connected
  // (that would open device_path) and never closed (that would close the caller's descriptor).
  impl.ctx = modbus_new_rtu(device_path.c_str(), options.baud, options.parity, options.data_bits,
                            options.stop_bits);
  if (impl.ctx == nullptr) {
    throw HalError(impl.backend, "create libmodbus RTU context", ErrnoText(errno));
  }
  modbus_set_socket(impl.ctx, master_fd);
  impl.wake_fd = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
  if (impl.wake_fd < 0) throw HalError(impl.backend, "create eventfd", ErrnoText(errno));
  server->registers_.coils.assign(static_cast<size_t>(options.coils), 0);
  server->registers_.discrete_inputs.assign(static_cast<size_t>(options.discrete_inputs), 0);
  server->registers_.holding_registers.assign(static_cast<size_t>(options.holding_registers), 0);
  server->registers_.input_registers.assign(static_cast<size_t>(options.input_registers), 0);
  impl.Start();
  return server;
}

const std::string& ModbusServer::backend() const { return impl_->backend; }
int ModbusServer::port() const { return impl_->tcp ? impl_->port : 0; }

void ModbusServer::SetRequestHook(RequestHook hook) {
  std::lock_guard<std::recursive_mutex> lock(registers_mutex_);
  impl_->request_hook = std::move(hook);
}

void ModbusServer::SetWriteHook(WriteHook hook) {
  std::lock_guard<std::recursive_mutex> lock(registers_mutex_);
  impl_->write_hook = std::move(hook);
}

int ModbusServer::DropConnections() {
  if (!impl_->tcp) return 0;
  std::unique_lock<std::mutex> lock(impl_->control_mutex);
  if (impl_->loop_exited || !impl_->thread.joinable()) return 0;
  const uint64_t ticket = ++impl_->drops_requested;
  impl_->Wake();
  impl_->control_cv.wait(lock, [&] { return impl_->drops_done >= ticket || impl_->loop_exited; });
  return impl_->drops_done >= ticket ? impl_->last_drop_count : 0;
}

void ModbusServer::StopAnswering(std::chrono::milliseconds duration) {
  constexpr int64_t kForeverMs = int64_t{1} << 40;  // about 35 years
  if (duration.count() >= kForeverMs) {
    impl_->silent_until_ns = std::numeric_limits<int64_t>::max();
  } else {
    impl_->silent_until_ns = NowNs() + std::max<int64_t>(0, duration.count()) * 1'000'000;
  }
}

void ModbusServer::ResumeAnswering() { impl_->silent_until_ns = 0; }

void ModbusServer::SetReplyDelay(std::chrono::milliseconds delay) {
  impl_->reply_delay_ns = std::max<int64_t>(0, delay.count()) * 1'000'000;
}

ModbusServerStats ModbusServer::stats() const {
  const Impl::Counters& c = impl_->counters;
  ModbusServerStats s;
  s.requests = c.requests;
  s.replies = c.replies;
  s.exceptions = c.exceptions;
  s.swallowed = c.swallowed;
  s.ignored = c.ignored;
  s.broadcasts = c.broadcasts;
  s.framing_errors = c.framing_errors;
  s.connections_accepted = c.accepted;
  s.connections_dropped = c.dropped;
  s.connections_open = c.open;
  return s;
}

}  // namespace kinevis::hal
