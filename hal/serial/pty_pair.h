#pragma once

// A pseudo-terminal pair for simulators and tests: the simulator does its I/O on the master side
// (master_fd(), or AdoptMaster() as a SerialPort), and the host opens slave_path() exactly as it
// would open /dev/ttyUSB0. The pair keeps its own descriptor of the slave open, so the host may
// open and close the path any number of times without the master seeing a hang-up.

#include <memory>
#include <string>

#include "hal/serial/serial_port.h"

namespace kinevis::hal {

class PtyPair {
 public:
  // Opens a new pty pair in raw mode (no echo, no line editing, 8 bits). Throws HalError.
  PtyPair();
  ~PtyPair();
  PtyPair(const PtyPair&) = delete;
  PtyPair& operator=(const PtyPair&) = delete;

  int master_fd() const { return master_fd_; }
  const std::string& slave_path() const { return slave_path_; }

  // Creates (or replaces) a symbolic link at link_path pointing to slave_path(), as socat's
  // link= option does; removed again on destruction. Throws HalError.
  void CreateLink(const std::string& link_path);

  // A SerialPort on the master side (it shares the descriptor; the PtyPair must outlive it).
  std::unique_ptr<SerialPort> MasterPort(int baud = 115200) const;

 private:
  int master_fd_ = -1;
  int slave_fd_ = -1;
  std::string slave_path_;
  std::string link_path_;
};

}  // namespace kinevis::hal
