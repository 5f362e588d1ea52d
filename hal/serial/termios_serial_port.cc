#include "hal/serial/termios_serial_port.h"

// This file talks to the kernel through termios2 (TCGETS2/TCSETS2 with BOTHER), which takes any
// baud rate as a number; glibc's <termios.h> only knows the B* constants and cannot be included
// together with <asm/termbits.h>, so raw mode is set up by hand below.
#include <asm/termbits.h>
#include <fcntl.h>
#include <linux/serial.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using std::chrono::microseconds;

// A deadline of now() + microseconds::max() would overflow; a day is "forever" for a serial read.
microseconds ClampTimeout(microseconds timeout) {
  return std::min(timeout, microseconds(std::chrono::hours(24)));
}

int PollTimeoutMs(microseconds timeout) {
  if (timeout <= microseconds::zero()) return 0;
  // Round up so that a 500 us timeout still waits.
  return static_cast<int>((timeout.count() + 999) / 1000);
}

class TermiosSerialPort final : public SerialPort {
 public:
  TermiosSerialPort(int fd, SerialSettings settings, std::string name, bool own, bool exclusive)
      : fd_(fd),
        settings_(std::move(settings)),
        name_(std::move(name)),
        own_(own),
        exclusive_(exclusive) {}
  ~TermiosSerialPort() override {
    // TIOCEXCL outlives this descriptor while anyone else holds the tty open (a PtyPair always
    // does): without TIOCNXCL the next open by a non-root user fails with EBUSY.
    if (exclusive_ && fd_ >= 0) ::ioctl(fd_, TIOCNXCL);
    if (own_ && fd_ >= 0) ::close(fd_);
  }

  const std::string& name() const override { return name_; }
  const SerialSettings& settings() const override { return settings_; }

  std::error_code Read(uint8_t* buffer, size_t size, microseconds timeout,
                       size_t* n_read) override {
    *n_read = 0;
    if (size == 0) return {};
    const auto deadline = std::chrono::steady_clock::now() + ClampTimeout(timeout);
    // Set when poll() reported a hang-up or an error: read once more (bytes received before it
    // are still buffered), then report it.
    std::error_code pending;
    while (true) {
      ssize_t n = ::read(fd_, buffer, size);
      if (n > 0) {
        *n_read = static_cast<size_t>(n);
        return {};
      }
      if (n < 0) {
        if (errno == EINTR) continue;
        if (errno == EIO) return Errc::kClosed;  // pty whose other side closed, unplugged USB
        if (errno != EAGAIN) return Errc::kIo;
      }
      // n == 0 is not end of file here: a raw-mode tty (VMIN = VTIME = 0) returns 0 when it has
      // no data, before it looks at O_NONBLOCK, and a hung-up tty returns 0 for ever. poll()
      // tells the two apart.
      if (pending) return pending;
      auto left =
          std::chrono::duration_cast<microseconds>(deadline - std::chrono::steady_clock::now());
      if (left <= microseconds::zero()) return Errc::kTimeout;
      pollfd p{fd_, POLLIN, 0};
      int r = ::poll(&p, 1, PollTimeoutMs(left));
      if (r < 0 && errno != EINTR) return Errc::kIo;
      if (r > 0 && (p.revents & POLLNVAL) != 0) return Errc::kIo;
      if (r > 0 && (p.revents & POLLHUP) != 0) {
        pending = Errc::kClosed;
      } else if (r > 0 && (p.revents & POLLERR) != 0) {
        pending = Errc::kIo;
      }
    }
  }

  std::error_code WriteAll(const uint8_t* data, size_t size, microseconds timeout) override {
    const auto deadline = std::chrono::steady_clock::now() + ClampTimeout(timeout);
    size_t done = 0;
    while (done < size) {
      ssize_t n = ::write(fd_, data + done, size - done);
      if (n > 0) {
        done += static_cast<size_t>(n);
        continue;
      }
      if (n < 0 && errno == EINTR) continue;
      if (n < 0 && errno == EIO) return Errc::kClosed;
      if (n < 0 && errno != EAGAIN) return Errc::kIo;
      auto left =
          std::chrono::duration_cast<microseconds>(deadline - std::chrono::steady_clock::now());
      if (left <= microseconds::zero()) return Errc::kTimeout;
      pollfd p{fd_, POLLOUT, 0};
      int r = ::poll(&p, 1, PollTimeoutMs(left));
      if (r < 0 && errno != EINTR) return Errc::kIo;
      if (r > 0 && (p.revents & (POLLERR | POLLNVAL | POLLHUP)) != 0) return Errc::kClosed;
    }
    return {};
  }

  std::error_code FlushInput() override {
    if (::ioctl(fd_, TCFLSH, TCIFLUSH) != 0) return Errc::kIo;
    return {};
  }

  std::error_code Drain() override {
    // tcdrain() is ioctl(TCSBRK, 1): wait until the output has been transmitted.
    if (::ioctl(fd_, TCSBRK, 1) != 0) return Errc::kIo;
    return {};
  }

 private:
  int fd_;
  SerialSettings settings_;
  std::string name_;
  bool own_;
  bool exclusive_;  // this port set TIOCEXCL and must clear it
};

void Configure(int fd, const SerialSettings& s, const std::string& name) {
  struct termios2 tio {};
  if (::ioctl(fd, TCGETS2, &tio) != 0) {
    int err = errno;
    throw HalError(name, "read line settings (TCGETS2)",
                   ErrnoText(err) + "; is " + s.device + " a serial port?",
                   std::error_code(err, std::generic_category()));
  }
  // Raw mode, as cfmakeraw() sets it.
  tio.c_iflag &= ~static_cast<tcflag_t>(IGNBRK | BRKINT | PARMRK | ISTRIP | INLCR | IGNCR | ICRNL |
                                        IXON | IXOFF | IXANY | INPCK);
  tio.c_oflag &= ~static_cast<tcflag_t>(OPOST);
  tio.c_lflag &= ~static_cast<tcflag_t>(ECHO | ECHONL | ICANON | ISIG | IEXTEN);
  tio.c_cflag &= ~static_cast<tcflag_t>(CSIZE | PARENB | PARODD | CSTOPB | CRTSCTS | CBAUD |
                                        (CBAUD << IBSHIFT));
  switch (s.data_bits) {
    case 5:
      tio.c_cflag |= CS5;
      break;
    case 6:
      tio.c_cflag |= CS6;
      break;
    case 7:
      tio.c_cflag |= CS7;
      break;
    default:
      tio.c_cflag |= CS8;
      break;
  }
  if (s.parity == 'E') tio.c_cflag |= PARENB;
  if (s.parity == 'O') tio.c_cflag |= PARENB | PARODD;
  if (s.parity != 'N') tio.c_iflag |= INPCK;
  if (s.stop_bits == 2) tio.c_cflag |= CSTOPB;
  tio.c_cflag |= CREAD | CLOCAL | BOTHER | (BOTHER << IBSHIFT);
  tio.c_ispeed = static_cast<speed_t>(s.baud);
  tio.c_ospeed = static_cast<speed_t>(s.baud);
  tio.c_cc[VMIN] = 0;
  tio.c_cc[VTIME] = 0;
  if (::ioctl(fd, TCSETS2, &tio) != 0) {
    int err = errno;
    throw HalError(name, "set line settings (" + std::to_string(s.baud) + " bit/s)", ErrnoText(err),
                   std::error_code(err, std::generic_category()));
  }
  if (s.rs485) {
    struct serial_rs485 rs485 {};
    rs485.flags = SER_RS485_ENABLED | SER_RS485_RTS_ON_SEND;
    if (::ioctl(fd, TIOCSRS485, &rs485) != 0) {
      int err = errno;
      throw HalError(name, "enable RS485 direction control (TIOCSRS485)",
                     ErrnoText(err) +
                         ": the driver of this port has no kernel RS485 support; adapters that "
                         "switch direction by themselves work without the rs485 option",
                     make_error_code(Errc::kUnsupported));
    }
  }
  ::ioctl(fd, TCFLSH, TCIOFLUSH);
}

}  // namespace

std::unique_ptr<SerialPort> OpenSerialPort(const SerialSettings& settings,
                                           const std::string& name_in) {
  const std::string name = name_in.empty() ? "tty:" + settings.device : name_in;
  int fd = ::open(settings.device.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    int err = errno;
    std::string hint;
    if (err == ENOENT) hint = "; is the adapter plugged in? `kinevis ports` lists serial ports";
    if (err == EACCES) hint = "; add the user to the dialout group";
    throw HalError(name, "open " + settings.device, ErrnoText(err) + hint,
                   std::error_code(err, std::generic_category()));
  }
  bool exclusive = true;
  if (::ioctl(fd, TIOCEXCL) != 0) {
    int err = errno;
    if (err != ENOTTY) {
      ::close(fd);
      throw HalError(name, "claim exclusive access (TIOCEXCL)", ErrnoText(err),
                     std::error_code(err, std::generic_category()));
    }
    exclusive = false;
  }
  try {
    Configure(fd, settings, name);
  } catch (...) {
    if (exclusive) ::ioctl(fd, TIOCNXCL);
    ::close(fd);
    throw;
  }
  return std::make_unique<TermiosSerialPort>(fd, settings, name, /*own=*/true, exclusive);
}

std::unique_ptr<SerialPort> AdoptSerialDescriptor(int fd, const SerialSettings& settings,
                                                  const std::string& name, bool own) {
  int flags = ::fcntl(fd, F_GETFL);
  if (flags < 0 || ::fcntl(fd, F_SETFL, flags | O_NONBLOCK) != 0) {
    throw HalError(name, "set O_NONBLOCK on descriptor " + std::to_string(fd), ErrnoText(errno));
  }
  return std::make_unique<TermiosSerialPort>(fd, settings, name, own, /*exclusive=*/false);
}

}  // namespace kinevis::hal
