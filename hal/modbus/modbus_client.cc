#include "hal/modbus/modbus_client.h"

#include <fcntl.h>
#include <modbus.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <spdlog/spdlog.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <vector>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

class ModbusCategoryImpl : public std::error_category {
 public:
  const char* name() const noexcept override { return "kinevis.modbus"; }
  std::string message(int value) const override {
    switch (static_cast<ModbusErrc>(value)) {
      case ModbusErrc::kNone:
        return "no exception";
      case ModbusErrc::kIllegalFunction:
        return "ILLEGAL FUNCTION (Modbus exception 1)";
      case ModbusErrc::kIllegalDataAddress:
        return "ILLEGAL DATA ADDRESS (Modbus exception 2)";
      case ModbusErrc::kIllegalDataValue:
        return "ILLEGAL DATA VALUE (Modbus exception 3)";
      case ModbusErrc::kServerDeviceFailure:
        return "SERVER DEVICE FAILURE (Modbus exception 4)";
      case ModbusErrc::kAcknowledge:
        return "ACKNOWLEDGE (Modbus exception 5)";
      case ModbusErrc::kServerDeviceBusy:
        return "SERVER DEVICE BUSY (Modbus exception 6)";
      case ModbusErrc::kNegativeAcknowledge:
        return "NEGATIVE ACKNOWLEDGE (Modbus exception 7)";
      case ModbusErrc::kMemoryParityError:
        return "MEMORY PARITY ERROR (Modbus exception 8)";
      case ModbusErrc::kGatewayPathUnavailable:
        return "GATEWAY PATH UNAVAILABLE (Modbus exception 10)";
      case ModbusErrc::kGatewayTargetFailedToRespond:
        return "GATEWAY TARGET DEVICE FAILED TO RESPOND (Modbus exception 11)";
      case ModbusErrc::kBadCrc:
        return "CRC ERROR (response checksum mismatch)";
      case ModbusErrc::kBadData:
        return "BAD DATA (response does not match the request)";
      case ModbusErrc::kBadException:
        return "BAD EXCEPTION (malformed exception response)";
      case ModbusErrc::kUnknownException:
        return "UNKNOWN EXCEPTION (exception code outside the specification)";
      case ModbusErrc::kTooManyData:
        return "TOO MANY DATA (more values than a frame carries)";
      case ModbusErrc::kBadSlave:
        return "BAD SLAVE (response from another unit)";
    }
    return "unknown kinevis.modbus error " + std::to_string(value);
  }
};

// Baud rates libmodbus 3.1.6 maps to termios constants; it silently replaces any other rate by
// 9600 bit/s (checked against the library: 2000000 is among the replaced ones).
constexpr int kRtuBaudRates[] = {110,     300,     600,     1200,    2400,    4800,
                                 9600,    19200,   38400,   57600,   115200,  230400,
                                 460800,  500000,  576000,  921600,  1000000, 1152000,
                                 1500000, 2500000, 3000000, 3500000, 4000000};

bool LibmodbusKnowsBaud(int baud) {
  for (int b : kRtuBaudRates) {
    if (b == baud) return true;
  }
  return false;
}

enum class Outcome { kOk, kTimeout, kLink, kCrc, kException, kProtocol, kOther };

// Classifies the errno libmodbus left behind a failed call.
Outcome Classify(int err, std::error_code* ec) {
  if (err == ETIMEDOUT) {
    *ec = Errc::kTimeout;
    return Outcome::kTimeout;
  }
  if (err >= MODBUS_ENOBASE && err <= EMBXGTAR) {
    // libmodbus passes exception codes 0..11 through; 0 and 9 are not in the specification.
    const int code = err - MODBUS_ENOBASE;
    *ec = code == 0 || code == 9 ? ModbusErrc::kUnknownException : static_cast<ModbusErrc>(code);
    return Outcome::kException;
  }
  switch (err) {
    case EMBBADCRC:
      *ec = ModbusErrc::kBadCrc;
      return Outcome::kCrc;
    case EMBBADDATA:
      *ec = ModbusErrc::kBadData;
      return Outcome::kProtocol;
    case EMBBADEXC:
      *ec = ModbusErrc::kBadException;
      return Outcome::kProtocol;
    case EMBUNKEXC:
      *ec = ModbusErrc::kUnknownException;
      return Outcome::kProtocol;
    case EMBMDATA:
      *ec = ModbusErrc::kTooManyData;
      return Outcome::kProtocol;
    case EMBBADSLAVE:
      *ec = ModbusErrc::kBadSlave;
      return Outcome::kProtocol;
    case ECONNRESET:
    case ECONNREFUSED:
    case ECONNABORTED:
    case EPIPE:
    case ENOTCONN:
    case EBADF:
    case ENETDOWN:
    case ENETUNREACH:
    case ENETRESET:
    case EHOSTUNREACH:
    case ESHUTDOWN:
    case EIO:
    case ENXIO:
    case ENODEV:
      *ec = Errc::kClosed;
      return Outcome::kLink;
    default:
      *ec = Errc::kIo;
      return Outcome::kOther;
  }
}

std::string HostPort(const std::string& host, int port) {
  if (host.find(':') != std::string::npos) return "[" + host + "]:" + std::to_string(port);
  return host + ":" + std::to_string(port);
}

// Connects a TCP socket to `address`, waiting at most timeout_ms. Returns the descriptor (blocking
// mode, as libmodbus' TCP backend expects) or -1 with *err set to the cause.
int ConnectTcp(const sockaddr_storage& address, socklen_t length, int timeout_ms, int* err) {
  int fd = ::socket(address.ss_family, SOCK_STREAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
  if (fd < 0) {
    *err = errno;
    return -1;
  }
  auto fail = [&](int e) {
    *err = e;
    ::close(fd);
    return -1;
  };
  int one = 1;
  // Requests are small and each waits for its answer: Nagle's algorithm would only add latency.
  ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  if (::connect(fd, reinterpret_cast<const sockaddr*>(&address), length) != 0) {
    if (errno != EINPROGRESS) return fail(errno);
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeout_ms);
    while (true) {
      auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
          deadline - std::chrono::steady_clock::now());
      if (left.count() <= 0) return fail(ETIMEDOUT);
      pollfd p{fd, POLLOUT, 0};
      int r = ::poll(&p, 1, static_cast<int>(left.count()));
      if (r < 0 && errno == EINTR) continue;
      if (r < 0) return fail(errno);
      if (r == 0) return fail(ETIMEDOUT);
      break;
    }
    int so_error = 0;
    socklen_t so_length = sizeof so_error;
    if (::getsockopt(fd, SOL_SOCKET, SO_ERROR, &so_error, &so_length) != 0) return fail(errno);
    if (so_error != 0) return fail(so_error);
  }
  int flags = ::fcntl(fd, F_GETFL);
  if (flags < 0 || ::fcntl(fd, F_SETFL, flags & ~O_NONBLOCK) != 0) return fail(errno);
  return fd;
}

bool ValidRange(int address, int count, int max_count) {
  return address >= 0 && address <= 0xFFFF && count >= 1 && count <= max_count &&
         address + count <= 0x10000;
}

void PutU16(uint8_t* p, int value) {
  p[0] = static_cast<uint8_t>((value >> 8) & 0xFF);
  p[1] = static_cast<uint8_t>(value & 0xFF);
}

}  // namespace

const std::error_category& ModbusCategory() {
  static const ModbusCategoryImpl category;
  return category;
}

std::error_code make_error_code(ModbusErrc e) { return {static_cast<int>(e), ModbusCategory()}; }

bool IsModbusException(std::error_code ec) {
  return ec.category() == ModbusCategory() && ec.value() >= 1 && ec.value() <= 11;
}

struct ModbusClient::Impl {
  ModbusBackendSpec spec;
  std::string name;
  bool tcp = true;
  bool broadcast = false;  // RTU with unit 0: writes only, no answers
  modbus_t* ctx = nullptr;
  bool connected = false;
  bool flush_before_next = false;
  std::vector<std::pair<sockaddr_storage, socklen_t>> addresses;  // TCP, resolved at Open

  ModbusClientCounters counters;

  // Logging state (see Fail()).
  static constexpr std::chrono::seconds kRepeatLogInterval{10};
  std::error_code last_logged_error;
  std::chrono::steady_clock::time_point last_logged_at;
  uint64_t unlogged = 0;
  bool device_gone = false;  // the last failure was a timeout or a lost link
  std::chrono::steady_clock::time_point last_link_warning;

  // The last failure, kept as numbers so that recording it does not allocate.
  std::error_code last_error;
  const char* last_operation = "";
  int last_address = 0;
  int last_count = 0;
  int last_attempts = 0;
  int last_errno = 0;

  ~Impl() {
    Disconnect();
    if (ctx != nullptr) modbus_free(ctx);
  }

  // Connects (TCP) or opens the serial device (RTU). Returns false with *err set on failure.
  bool Connect(int* err) {
    if (tcp) {
      *err = ECONNREFUSED;
      for (const auto& [address, length] : addresses) {
        int fd = ConnectTcp(address, length, spec.timeout_ms, err);
        if (fd >= 0) {
          modbus_set_socket(ctx, fd);
          connected = true;
          flush_before_next = false;
          return true;
        }
      }
      return false;
    }
    if (modbus_connect(ctx) != 0) {
      *err = errno != 0 ? errno : EIO;
      return false;
    }
    if (spec.serial.rs485 && modbus_rtu_set_serial_mode(ctx, MODBUS_RTU_RS485) != 0) {
      *err = errno;
      modbus_close(ctx);
      return false;
    }
    connected = true;
    flush_before_next = true;  // whatever the line carried while nobody listened is stale
    return true;
  }

  // Discards received bytes nobody asked for. On a serial line only the input is flushed:
  // libmodbus' modbus_flush() flushes output too, which on a pty throws away frames other
  // writers of the line (an earlier client) queued but the device has not read yet.
  void Flush() {
    if (tcp) {
      modbus_flush(ctx);
    } else {
      ::tcflush(modbus_get_socket(ctx), TCIFLUSH);
    }
  }

  void Disconnect() {
    if (!connected) return;
    if (tcp) {
      int fd = modbus_get_socket(ctx);
      if (fd >= 0) ::close(fd);
      modbus_set_socket(ctx, -1);
    } else {
      modbus_close(ctx);
    }
    connected = false;
  }

  void Fail(const char* operation, int address, int count, int attempts, std::error_code ec,
            int err) {
    ++counters.failures;
    last_error = ec;
    last_operation = operation;
    last_address = address;
    last_count = count;
    last_attempts = attempts;
    last_errno = err;
    if (ec == Errc::kTimeout || ec == Errc::kClosed) device_gone = true;
    // A device failing every cycle must not flood the log (nor allocate for it every cycle): a
    // failure is a warning unless the same error was one less than kRepeatLogInterval ago.
    const auto now = std::chrono::steady_clock::now();
    if (ec != last_logged_error || now - last_logged_at >= kRepeatLogInterval) {
      if (unlogged > 0) {
        spdlog::warn("{} ({} similar failure(s) since the last report)", Text(), unlogged);
      } else {
        spdlog::warn("{}", Text());
      }
      last_logged_error = ec;
      last_logged_at = now;
      unlogged = 0;
    } else {
      ++unlogged;
      if (spdlog::should_log(spdlog::level::debug)) spdlog::debug("{}", Text());
    }
  }

  void Succeed() {
    if (device_gone) {
      spdlog::info("{}: answering again", name);
      device_gone = false;
    }
  }

  std::string Text() const {
    if (!last_error) return name + ": no error";
    char where[48];
    std::snprintf(where, sizeof where, " at 0x%04x, count %d", last_address, last_count);
    std::string text = name + " unit " + std::to_string(spec.unit) + ": " + last_operation + where +
                       ": " + last_error.message();
    const bool os_error = last_errno > 0 && last_errno < MODBUS_ENOBASE && last_errno != ETIMEDOUT;
    if (os_error) text += " (" + ErrnoText(last_errno) + ")";
    if (last_attempts > 0) {
      text += " after " + std::to_string(last_attempts) +
              (last_attempts == 1 ? " attempt" : " attempts");
    }
    return text;
  }

  // Runs `call` (a libmodbus request returning -1 on failure with errno set) with the retry and
  // reconnect policy described in the header.
  template <typename Call>
  std::error_code Run(const char* operation, int address, int count, Call&& call) {
    ++counters.requests;
    std::error_code ec;
    int err = 0;
    int attempts = 0;
    while (true) {
      ++attempts;
      if (attempts > 1) ++counters.retries;
      bool retryable = false;
      if (!connected) {
        if (Connect(&err)) {
          ++counters.reconnects;
          spdlog::debug("{}: reconnected", name);
        } else {
          ec = Errc::kClosed;
          retryable = true;
        }
      }
      if (connected) {
        if (flush_before_next) {
          Flush();
          flush_before_next = false;
        }
        errno = 0;
        if (call(ctx) != -1) {
          Succeed();
          return {};
        }
        err = errno;
        switch (Classify(err, &ec)) {
          case Outcome::kTimeout:
            ++counters.timeouts;
            retryable = true;
            // A late answer must never be taken for the answer to the next request. On TCP a
            // fresh connection guarantees that (libmodbus gives up on a transaction-id mismatch
            // instead of skipping the stale answer); on a serial line the best is to discard
            // what arrived so far.
            if (tcp) {
              Disconnect();
            } else {
              flush_before_next = true;
            }
            break;
          case Outcome::kLink:
            if (std::chrono::steady_clock::now() - last_link_warning >= kRepeatLogInterval) {
              spdlog::warn("{}: link dropped ({}); reconnecting", name, ErrnoText(err));
              last_link_warning = std::chrono::steady_clock::now();
            }
            Disconnect();
            retryable = true;
            break;
          case Outcome::kCrc:
            ++counters.crc_errors;
            flush_before_next = true;
            break;
          case Outcome::kException:
            ++counters.exceptions;
            break;
          case Outcome::kProtocol:
          case Outcome::kOther:
          case Outcome::kOk:
            flush_before_next = true;
            break;
        }
      }
      if (!retryable || attempts > spec.retries) break;
    }
    Fail(operation, address, count, attempts, ec, err);
    return ec;
  }

  std::error_code Invalid(const char* operation, int address, int count) {
    ++counters.requests;
    Fail(operation, address, count, 0, Errc::kInvalidArgument, 0);
    return Errc::kInvalidArgument;
  }

  // A broadcast write on RTU: sent as a raw request, no answer awaited (libmodbus 3.1.6 would
  // wait for one, which never comes). `pdu` starts with the function code.
  std::error_code Broadcast(const char* operation, int address, int count, const uint8_t* pdu,
                            int pdu_length) {
    uint8_t raw[MODBUS_MAX_PDU_LENGTH + 1];
    raw[0] = 0;
    std::memcpy(raw + 1, pdu, static_cast<size_t>(pdu_length));
    return Run(operation, address, count,
               [&](modbus_t* c) { return modbus_send_raw_request(c, raw, pdu_length + 1); });
  }
};

ModbusClient::ModbusClient(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
ModbusClient::~ModbusClient() = default;

std::unique_ptr<ModbusClient> ModbusClient::Open(std::string_view backend) {
  return Open(ParseModbusBackend(backend));
}

std::unique_ptr<ModbusClient> ModbusClient::Open(const ModbusBackendSpec& spec) {
  auto impl = std::make_unique<Impl>();
  impl->spec = spec;
  impl->tcp = spec.kind == ModbusBackendSpec::Kind::kTcp;
  if (spec.text.empty()) {
    impl->name = impl->tcp ? "modbus-tcp:" + HostPort(spec.host, spec.port)
                           : "modbus-rtu:" + spec.serial.device;
  } else {
    impl->name = spec.text;
  }
  const std::string& name = impl->name;

  std::string problems;
  auto problem = [&](const std::string& p) { problems += (problems.empty() ? "" : "; ") + p; };
  if (spec.unit < 0 || spec.unit > 247) {
    problem("unit " + std::to_string(spec.unit) + " is not in 0..247");
  }
  if (spec.timeout_ms < 1 || spec.timeout_ms > 60'000) {
    problem("timeout_ms " + std::to_string(spec.timeout_ms) + " is not in 1..60000");
  }
  if (spec.retries < 0 || spec.retries > 100) {
    problem("retries " + std::to_string(spec.retries) + " is not in 0..100");
  }
  if (impl->tcp) {
    if (spec.host.empty()) problem("host is empty");
    if (spec.port < 1 || spec.port > 65535) {
      problem("port " + std::to_string(spec.port) + " is not in 1..65535");
    }
  } else {
    const SerialSettings& s = spec.serial;
    if (s.device.empty()) problem("serial device path is empty");
    if (!LibmodbusKnowsBaud(s.baud)) {
      problem("baud rate " + std::to_string(s.baud) +
              " is not one libmodbus can set (standard termios rates 110..4000000 bit/s, "
              "except 2000000)");
    }
    if (s.parity != 'N' && s.parity != 'E' && s.parity != 'O') {
      problem(std::string("parity '") + s.parity + "' is not N, E or O");
    }
    if (s.data_bits < 5 || s.data_bits > 8) {
      problem("data bits " + std::to_string(s.data_bits) + " is not in 5..8");
    }
    if (s.stop_bits != 1 && s.stop_bits != 2) {
      problem("stop bits " + std::to_string(s.stop_bits) + " is not 1 or 2");
    }
  }
  if (!problems.empty()) throw common::ConfigError("backend \"" + name + "\": " + problems);

  if (impl->tcp) {
    const std::string port = std::to_string(spec.port);
    const std::string where = HostPort(spec.host, spec.port);
    addrinfo hints{};
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    addrinfo* list = nullptr;
    int rc = ::getaddrinfo(spec.host.c_str(), port.c_str(), &hints, &list);
    if (rc != 0) {
      throw HalError(name, "resolve " + where,
                     rc == EAI_SYSTEM ? ErrnoText(errno) : std::string(::gai_strerror(rc)));
    }
    for (addrinfo* a = list; a != nullptr; a = a->ai_next) {
      sockaddr_storage storage{};
      std::memcpy(&storage, a->ai_addr, a->ai_addrlen);
      impl->addresses.emplace_back(storage, a->ai_addrlen);
    }
    ::freeaddrinfo(list);
    // The context never connects by itself: Impl::Connect() hands it a connected socket, so
    // that the cause of a failed connection is known (libmodbus 3.1.6 reports EINPROGRESS for a
    // refused one) and the connect is bounded by timeout_ms.
    impl->ctx = modbus_new_tcp_pi(spec.host.c_str(), port.c_str());
    if (impl->ctx == nullptr) {
      throw HalError(name, "create libmodbus TCP context", ErrnoText(errno));
    }
    int err = 0;
    if (!impl->Connect(&err)) {
      throw HalError(name, "connect to " + where, ErrnoText(err),
                     std::error_code(err, std::system_category()));
    }
  } else {
    const SerialSettings& s = spec.serial;
    impl->ctx = modbus_new_rtu(s.device.c_str(), s.baud, s.parity, s.data_bits, s.stop_bits);
    if (impl->ctx == nullptr) {
      throw HalError(name, "create libmodbus RTU context", ErrnoText(errno));
    }
    if (modbus_connect(impl->ctx) != 0) {
      int err = errno != 0 ? errno : EIO;
      throw HalError(name, "open " + s.device, ErrnoText(err),
                     std::error_code(err, std::system_category()));
    }
    impl->connected = true;
    if (s.rs485 && modbus_rtu_set_serial_mode(impl->ctx, MODBUS_RTU_RS485) != 0) {
      int err = errno;
      throw HalError(name, "enable RS485 mode (TIOCSRS485) on " + s.device,
                     ErrnoText(err) +
                         "; the driver has no kernel RS485 direction control (ptys and most USB "
                         "adapters switch direction by themselves): leave rs485 off",
                     std::error_code(err, std::system_category()));
    }
    impl->Flush();
    impl->broadcast = spec.unit == 0;
  }
  modbus_set_error_recovery(impl->ctx, MODBUS_ERROR_RECOVERY_NONE);
  if (modbus_set_slave(impl->ctx, spec.unit) != 0) {
    throw common::ConfigError("backend \"" + name + "\": unit " + std::to_string(spec.unit) +
                              " refused by libmodbus");
  }
  const auto timeout_us = static_cast<uint32_t>(spec.timeout_ms) * 1000U;
  modbus_set_response_timeout(impl->ctx, timeout_us / 1'000'000U, timeout_us % 1'000'000U);
  // No separate byte timeout: the whole answer must arrive within the response timeout, so that
  // one attempt is bounded by timeout_ms however the bytes trickle in.
  modbus_set_byte_timeout(impl->ctx, 0, 0);
  spdlog::info("{}: connected (unit {}, timeout {} ms, {} retries)", name, spec.unit,
               spec.timeout_ms, spec.retries);
  return std::unique_ptr<ModbusClient>(new ModbusClient(std::move(impl)));
}

const std::string& ModbusClient::name() const { return impl_->name; }
const ModbusBackendSpec& ModbusClient::spec() const { return impl_->spec; }
bool ModbusClient::connected() const { return impl_->connected; }

std::error_code ModbusClient::SetUnit(int unit) {
  if (unit < 0 || unit > 247 || modbus_set_slave(impl_->ctx, unit) != 0) {
    return Errc::kInvalidArgument;
  }
  impl_->spec.unit = unit;
  impl_->broadcast = impl_->spec.kind == ModbusBackendSpec::Kind::kRtu && unit == 0;
  return {};
}
ModbusClientCounters ModbusClient::counters() const { return impl_->counters; }
std::error_code ModbusClient::last_error() const { return impl_->last_error; }
std::string ModbusClient::last_error_text() const { return impl_->Text(); }

std::error_code ModbusClient::ReadHoldingRegisters(int address, int count, uint16_t* out) {
  static constexpr char kOp[] = "read holding registers";
  if (!ValidRange(address, count, kMaxReadRegisters) || out == nullptr || impl_->broadcast) {
    return impl_->Invalid(kOp, address, count);
  }
  return impl_->Run(kOp, address, count,
                    [&](modbus_t* c) { return modbus_read_registers(c, address, count, out); });
}

std::error_code ModbusClient::ReadInputRegisters(int address, int count, uint16_t* out) {
  static constexpr char kOp[] = "read input registers";
  if (!ValidRange(address, count, kMaxReadRegisters) || out == nullptr || impl_->broadcast) {
    return impl_->Invalid(kOp, address, count);
  }
  return impl_->Run(kOp, address, count, [&](modbus_t* c) {
    return modbus_read_input_registers(c, address, count, out);
  });
}

std::error_code ModbusClient::WriteRegister(int address, uint16_t value) {
  static constexpr char kOp[] = "write register";
  if (!ValidRange(address, 1, 1)) return impl_->Invalid(kOp, address, 1);
  if (impl_->broadcast) {
    uint8_t pdu[5] = {MODBUS_FC_WRITE_SINGLE_REGISTER};
    PutU16(pdu + 1, address);
    PutU16(pdu + 3, value);
    return impl_->Broadcast(kOp, address, 1, pdu, sizeof pdu);
  }
  return impl_->Run(kOp, address, 1,
                    [&](modbus_t* c) { return modbus_write_register(c, address, value); });
}

std::error_code ModbusClient::WriteRegisters(int address, int count, const uint16_t* values) {
  static constexpr char kOp[] = "write registers";
  if (!ValidRange(address, count, kMaxWriteRegisters) || values == nullptr) {
    return impl_->Invalid(kOp, address, count);
  }
  if (impl_->broadcast) {
    uint8_t pdu[6 + 2 * kMaxWriteRegisters] = {MODBUS_FC_WRITE_MULTIPLE_REGISTERS};
    PutU16(pdu + 1, address);
    PutU16(pdu + 3, count);
    pdu[5] = static_cast<uint8_t>(2 * count);
    for (int i = 0; i < count; ++i) PutU16(pdu + 6 + 2 * static_cast<ptrdiff_t>(i), values[i]);
    return impl_->Broadcast(kOp, address, count, pdu, 6 + 2 * count);
  }
  return impl_->Run(kOp, address, count,
                    [&](modbus_t* c) { return modbus_write_registers(c, address, count, values); });
}

std::error_code ModbusClient::MaskWriteRegister(int address, uint16_t and_mask, uint16_t or_mask) {
  static constexpr char kOp[] = "mask write register";
  if (!ValidRange(address, 1, 1)) return impl_->Invalid(kOp, address, 1);
  if (impl_->broadcast) {
    uint8_t pdu[7] = {MODBUS_FC_MASK_WRITE_REGISTER};
    PutU16(pdu + 1, address);
    PutU16(pdu + 3, and_mask);
    PutU16(pdu + 5, or_mask);
    return impl_->Broadcast(kOp, address, 1, pdu, sizeof pdu);
  }
  return impl_->Run(kOp, address, 1, [&](modbus_t* c) {
    return modbus_mask_write_register(c, address, and_mask, or_mask);
  });
}

std::error_code ModbusClient::ReadCoils(int address, int count, uint8_t* out) {
  static constexpr char kOp[] = "read coils";
  if (!ValidRange(address, count, kMaxReadBits) || out == nullptr || impl_->broadcast) {
    return impl_->Invalid(kOp, address, count);
  }
  return impl_->Run(kOp, address, count,
                    [&](modbus_t* c) { return modbus_read_bits(c, address, count, out); });
}

std::error_code ModbusClient::ReadDiscreteInputs(int address, int count, uint8_t* out) {
  static constexpr char kOp[] = "read discrete inputs";
  if (!ValidRange(address, count, kMaxReadBits) || out == nullptr || impl_->broadcast) {
    return impl_->Invalid(kOp, address, count);
  }
  return impl_->Run(kOp, address, count,
                    [&](modbus_t* c) { return modbus_read_input_bits(c, address, count, out); });
}

std::error_code ModbusClient::WriteCoil(int address, bool value) {
  static constexpr char kOp[] = "write coil";
  if (!ValidRange(address, 1, 1)) return impl_->Invalid(kOp, address, 1);
  if (impl_->broadcast) {
    uint8_t pdu[5] = {MODBUS_FC_WRITE_SINGLE_COIL};
    PutU16(pdu + 1, address);
    PutU16(pdu + 3, value ? 0xFF00 : 0x0000);
    return impl_->Broadcast(kOp, address, 1, pdu, sizeof pdu);
  }
  return impl_->Run(kOp, address, 1, [&](modbus_t* c) {
    return modbus_write_bit(c, address, value ? TRUE : FALSE);
  });
}

std::error_code ModbusClient::WriteCoils(int address, int count, const uint8_t* values) {
  static constexpr char kOp[] = "write coils";
  if (!ValidRange(address, count, kMaxWriteBits) || values == nullptr) {
    return impl_->Invalid(kOp, address, count);
  }
  if (impl_->broadcast) {
    uint8_t pdu[6 + (kMaxWriteBits + 7) / 8] = {MODBUS_FC_WRITE_MULTIPLE_COILS};
    PutU16(pdu + 1, address);
    PutU16(pdu + 3, count);
    const int bytes = (count + 7) / 8;
    pdu[5] = static_cast<uint8_t>(bytes);
    for (int i = 0; i < count; ++i) {
      if (values[i] != 0) pdu[6 + i / 8] = static_cast<uint8_t>(pdu[6 + i / 8] | (1U << (i % 8)));
    }
    return impl_->Broadcast(kOp, address, count, pdu, 6 + bytes);
  }
  return impl_->Run(kOp, address, count,
                    [&](modbus_t* c) { return modbus_write_bits(c, address, count, values); });
}

std::error_code ModbusClient::WriteAndReadRegisters(int write_address, int write_count,
                                                    const uint16_t* values, int read_address,
                                                    int read_count, uint16_t* out) {
  static constexpr char kOp[] = "write and read registers";
  if (!ValidRange(write_address, write_count, kMaxWriteAndReadWriteRegisters) ||
      !ValidRange(read_address, read_count, kMaxWriteAndReadReadRegisters) || values == nullptr ||
      out == nullptr || impl_->broadcast) {
    return impl_->Invalid(kOp, write_address, write_count);
  }
  return impl_->Run(kOp, write_address, write_count, [&](modbus_t* c) {
    return modbus_write_and_read_registers(c, write_address, write_count, values, read_address,
                                           read_count, out);
  });
}

}  // namespace kinevis::hal
