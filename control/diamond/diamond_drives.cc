#include "control/diamond/diamond_drives.h"

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace kinevis::control {

std::string DiamondDriveBusConfig::Validate() const {
  std::ostringstream out;
  const auto bad = [&](const std::string& text) { out << (out.tellp() > 0 ? "; " : "") << text; };
  if (backend.rfind("modbus-rtu:", 0) != 0) {
    bad("backend \"" + backend + "\": must be a modbus-rtu: backend string");
  }
  for (int i = 0; i < robots::kDiamondJoints; ++i) {
    if (units[i] < 1 || units[i] > 247) {
      bad("units[" + std::to_string(i) + "] = " + std::to_string(units[i]) + " (must be 1..247)");
    }
  }
  if (units[0] == units[1]) bad("units: " + std::to_string(units[0]) + " appears twice");
  if (!(std::isfinite(counts_per_rad) && counts_per_rad > 0)) {
    bad("counts_per_rad = " + std::to_string(counts_per_rad) + " (must be > 0)");
  }
  if (cycle_period.count() <= 0) bad("cycle_period must be > 0");
  if (watchdog.count() < 0 || watchdog.count() > 65535) bad("watchdog must be 0..65535 ms");
  if (command_timeout.count() <= 0) bad("command_timeout must be > 0");
  if (max_missed_cycles < 1) bad("max_missed_cycles must be >= 1");
  return out.str();
}

std::unique_ptr<hal::Rs485DriveBus> MakeDiamondDriveBus(const DiamondDriveBusConfig& config,
                                                        common::Clock* clock) {
  if (const std::string p = config.Validate(); !p.empty()) {
    throw std::invalid_argument("diamond drives: " + p);
  }
  hal::Rs485DriveBusOptions o;
  o.clock = clock;
  o.cycle_period = config.cycle_period;
  o.max_missed_cycles = config.max_missed_cycles;
  auto bus = std::make_unique<hal::Rs485DriveBus>(config.backend, o);
  for (int i = 0; i < robots::kDiamondJoints; ++i) {
    hal::Rs485DriveConfig c;
    c.unit = config.units[i];
    c.watchdog = config.watchdog;
    c.drive.name = "arm" + std::to_string(i + 1);
    c.drive.scaling.position_counts_per_unit = config.counts_per_rad;
    c.drive.scaling.velocity_counts_per_unit = config.counts_per_rad;
    c.drive.mode = hal::DriveMode::kCyclicSynchronousPosition;
    c.drive.command_timeout = config.command_timeout;
    bus->AddDrive(c);
  }
  return bus;
}

void BringUpDiamondDrives(hal::Rs485DriveBus* bus, std::chrono::milliseconds enable_timeout) {
  bus->ConfigureAll();
  if (const std::error_code ec = bus->EnableAll(enable_timeout)) {
    std::string text = "diamond drives: enabling failed (" + ec.message() + ")";
    for (const hal::MotorDrive* d : bus->drives()) {
      if (const std::string cause = d->last_error_text(); !cause.empty()) text += "; " + cause;
    }
    throw std::runtime_error(text);
  }
}

}  // namespace kinevis::control
