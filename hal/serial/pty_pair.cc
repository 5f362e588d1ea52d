#include "hal/serial/pty_pair.h"

#include <fcntl.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>

#include "hal/common/error.h"
#include "hal/serial/termios_serial_port.h"

namespace kinevis::hal {

PtyPair::PtyPair() {
  master_fd_ = ::posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC);
  if (master_fd_ < 0) throw HalError("pty", "posix_openpt", ErrnoText(errno));
  char name[128];
  if (::grantpt(master_fd_) != 0 || ::unlockpt(master_fd_) != 0 ||
      ::ptsname_r(master_fd_, name, sizeof name) != 0) {
    int err = errno;
    ::close(master_fd_);
    throw HalError("pty", "grantpt/unlockpt/ptsname", ErrnoText(err));
  }
  slave_path_ = name;
  slave_fd_ = ::open(name, O_RDWR | O_NOCTTY | O_CLOEXEC);
  if (slave_fd_ < 0) {
    int err = errno;
    ::close(master_fd_);
    throw HalError("pty", "open " + slave_path_, ErrnoText(err));
  }
  termios tio{};
  ::tcgetattr(slave_fd_, &tio);
  ::cfmakeraw(&tio);
  tio.c_cc[VMIN] = 0;
  tio.c_cc[VTIME] = 0;
  if (::tcsetattr(slave_fd_, TCSANOW, &tio) != 0) {
    int err = errno;
    ::close(slave_fd_);
    ::close(master_fd_);
    throw HalError("pty", "set raw mode on " + slave_path_, ErrnoText(err));
  }
  int flags = ::fcntl(master_fd_, F_GETFL);
  ::fcntl(master_fd_, F_SETFL, flags | O_NONBLOCK);
}

PtyPair::~PtyPair() {
  if (!link_path_.empty()) ::unlink(link_path_.c_str());
  if (slave_fd_ >= 0) ::close(slave_fd_);
  if (master_fd_ >= 0) ::close(master_fd_);
}

void PtyPair::CreateLink(const std::string& link_path) {
  ::unlink(link_path.c_str());
  if (::symlink(slave_path_.c_str(), link_path.c_str()) != 0) {
    throw HalError("pty " + slave_path_, "create link " + link_path, ErrnoText(errno));
  }
  link_path_ = link_path;
}

std::unique_ptr<SerialPort> PtyPair::MasterPort(int baud) const {
  SerialSettings s;
  s.device = slave_path_ + " (master)";
  s.baud = baud;
  return AdoptSerialDescriptor(master_fd_, s, "pty-master:" + slave_path_, /*own=*/false);
}

}  // namespace kinevis::hal
