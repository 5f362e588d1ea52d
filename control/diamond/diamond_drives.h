#pragma once

// The DIAMOND's two RS485 motor-arm drives as the control loop uses them (issue 8): one
// hal::Rs485DriveBus on a "modbus-rtu:" line (the real USB-RS485 adapter, or DiamondWorld's pty),
// joint i at Modbus unit units[i], in cyclic synchronous position with SI scaling to the joint
// readings q_i (rad). What `kinevis servo diamond` binds from a deployment file.

#include <array>
#include <chrono>
#include <memory>
#include <string>

#include "common/clock.h"
#include "hal/drive/rs485_drive.h"
#include "robots/diamond/diamond_model.h"

namespace kinevis::control {

struct DiamondDriveBusConfig {
  // "modbus-rtu:/dev/ttyUSB0@3000000,8E1" (timeout_ms and retries may be appended; see
  // hal/common/backend_spec.h). The unit option is ignored: units below.
  std::string backend;
  std::array<int, robots::kDiamondJoints> units{1, 2};  // distinct, 1..247
  double counts_per_rad = 131072.0 / (2 * M_PI);        // encoder counts per rad, > 0
  // Bus cycles the drive API runs itself (Configure, Enable, stops), > 0.
  std::chrono::microseconds cycle_period{1000};
  std::chrono::milliseconds watchdog{200};          // the drives' communication watchdog
  std::chrono::milliseconds command_timeout{1000};  // Configure / Enable / stop confirmations
  int max_missed_cycles = 3;                        // failed exchanges before a link fault
  std::string Validate() const;  // empty when usable, else every bad field and its value
};

// Builds the bus and its two drives ("arm1", "arm2") on `clock` (nullptr: SteadyClock). Throws
// std::invalid_argument for a bad config, common::ConfigError / hal::HalError from the HAL (bad
// backend string, the serial device cannot be opened).
std::unique_ptr<hal::Rs485DriveBus> MakeDiamondDriveBus(const DiamondDriveBusConfig& config,
                                                        common::Clock* clock);

// Configures and enables both drives (CSP). Throws hal::HalError naming the drive and the step,
// or std::runtime_error when enabling fails (naming the drive and its last error).
void BringUpDiamondDrives(hal::Rs485DriveBus* bus, std::chrono::milliseconds enable_timeout);

}  // namespace kinevis::control
