#include "control/common/drive_supervisor.h"

#include <spdlog/spdlog.h>

#include <cmath>
#include <sstream>
#include <stdexcept>

#include "common/config_error.h"
#include "hal/common/error.h"
#include "hal/drive/cia402.h"

namespace kinevis::control {

std::string DriveSupervisorOptions::Validate() const {
  common::Problems p;
  p.Positive("cycle_period_s", cycle_period_s);
  if (max_consecutive_cycle_timeouts < 0) {
    p.Add("max_consecutive_cycle_timeouts", max_consecutive_cycle_timeouts, "must be >= 0");
  }
  if (axis_name.empty()) p.Add("axis_name: must not be empty");
  p.Positive("rest_velocity", rest_velocity);
  p.Positive("settle_timeout_s", settle_timeout_s);
  return p.Message();
}

DriveSupervisor::DriveSupervisor(hal::DriveBus* bus, common::Clock* clock, size_t expected_drives,
                                 DriveSupervisorOptions options)
    : bus_(bus), clock_(clock), options_(std::move(options)) {
  std::string message = options_.Validate();
  const auto add = [&](const std::string& text) {
    message += (message.empty() ? "" : "; ") + text;
  };
  if (!bus || !clock) add("bus and clock must not be null");
  if (bus) {
    drives_ = bus->drives();
    if (drives_.size() != expected_drives) {
      add("bus " + bus->name() + ": has " + std::to_string(drives_.size()) + " drives, expected " +
          std::to_string(expected_drives));
    }
    for (size_t i = 0; i < drives_.size(); ++i) {
      if (drives_[i] == nullptr) {
        add("bus " + bus->name() + ": drive " + std::to_string(i) + " is null");
      }
    }
  }
  if (!message.empty()) throw std::invalid_argument("DriveSupervisor: " + message);
}

std::string DriveSupervisor::AxisName(size_t i) const {
  return options_.axis_name + " " +
         std::to_string(static_cast<int>(i) + options_.first_axis_number) + " drive " +
         drives_[i]->name();
}

std::string DriveSupervisor::SelectMode(hal::DriveMode mode, int* failed_drive) {
  const bool position = mode == hal::DriveMode::kCyclicSynchronousPosition ||
                        mode == hal::DriveMode::kProfilePosition;
  for (size_t i = 0; i < drives_.size(); ++i) {
    hal::MotorDrive* d = drives_[i];
    // The first target is where the drive is: selecting the mode never moves the axis.
    if (position) {
      d->SetTargetPosition(d->status().position);
    } else if (mode == hal::DriveMode::kCyclicSynchronousTorque) {
      d->SetTargetTorque(0.0);
    } else {
      d->SetTargetVelocity(0.0);
    }
    if (const std::error_code ec = d->SetMode(mode)) {
      if (failed_drive) *failed_drive = static_cast<int>(i);
      return AxisName(i) + ": cannot select " + hal::ToString(mode) + ": " + ec.message();
    }
  }
  if (failed_drive) *failed_drive = -1;
  return {};
}

SupervisedCycle DriveSupervisor::Cycle() {
  SupervisedCycle c;
  c.error = bus_->Cycle();
  if (c.error == hal::Errc::kTimeout) {
    ++cycle_timeouts_;
    c.late = true;
    c.fault = ++consecutive_timeouts_ > options_.max_consecutive_cycle_timeouts;
  } else {
    consecutive_timeouts_ = 0;
    c.fault = static_cast<bool>(c.error);
  }
  for (const hal::MotorDrive* d : drives_) {
    c.fault = c.fault || d->lifecycle() == common::DeviceLifecycle::kFault;
  }
  return c;
}

std::string DriveSupervisor::FaultMessage(const SupervisedCycle& cycle, double t,
                                          int* faulted_drive) const {
  std::ostringstream m;
  m << "drive fault at t = " << t << " s (bus " << bus_->name() << ": "
    << (cycle.error ? cycle.error.message() : "no error");
  if (consecutive_timeouts_ > options_.max_consecutive_cycle_timeouts) {
    m << ", " << consecutive_timeouts_ << " cycles in a row without every drive's answer";
  }
  m << "): " << DriveFaults(faulted_drive);
  return m.str();
}

std::string DriveSupervisor::DriveFaults(int* first) const {
  std::ostringstream out;
  if (first) *first = -1;
  for (size_t i = 0; i < drives_.size(); ++i) {
    const hal::MotorDrive* d = drives_[i];
    const hal::DriveStatus st = d->status();
    if (d->lifecycle() != common::DeviceLifecycle::kFault &&
        st.fault_source == hal::DriveFaultSource::kNone) {
      continue;
    }
    if (first && *first < 0) *first = static_cast<int>(i);
    out << (out.tellp() > 0 ? "; " : "") << AxisName(i) << ": "
        << (st.fault_source == hal::DriveFaultSource::kLink ? "link lost" : "device fault")
        << ", error code 0x" << std::hex << st.error_code << std::dec;
    if (const std::string text = d->last_error_text(); !text.empty()) out << " (" << text << ")";
  }
  return out.str();
}

bool DriveSupervisor::AllAtRest() const {
  for (const hal::MotorDrive* d : drives_) {
    if (!(std::abs(d->status().velocity) < options_.rest_velocity)) return false;
  }
  return true;
}

void DriveSupervisor::Positions(double* out) const {
  for (size_t i = 0; i < drives_.size(); ++i) out[i] = drives_[i]->status().position;
}

std::string DriveSupervisor::SafeStop() {
  std::string problems;
  for (hal::MotorDrive* d : drives_) {
    const common::DeviceLifecycle state = d->lifecycle();
    std::error_code ec;
    if (options_.stop_action == StopAction::kDisable) {
      if (state != common::DeviceLifecycle::kFault &&
          state != common::DeviceLifecycle::kUnconfigured) {
        ec = d->Disable();
      }
    } else if (state == common::DeviceLifecycle::kActive) {
      ec = d->QuickStop();
    }
    if (ec) {
      spdlog::warn("bringing {} to the safe state failed: {}", d->name(), ec.message());
      problems += (problems.empty() ? "" : "; ") + d->name() + ": safe state not confirmed (" +
                  ec.message() + ")";
    }
  }
  const common::Duration period = common::FromSeconds(options_.cycle_period_s);
  const common::Duration end = clock_->Now() + common::FromSeconds(options_.settle_timeout_s);
  for (common::Duration next = clock_->Now() + period; clock_->Now() < end; next += period) {
    clock_->SleepUntil(next);
    (void)bus_->Cycle();  // keeps reporting a fault; the stop is what matters now
    if (AllAtRest()) break;
  }
  return problems;
}

bool DriveSupervisor::Settle(const std::function<bool()>& step) {
  const common::Duration period = common::FromSeconds(options_.cycle_period_s);
  const common::Duration start = clock_->Now();
  const common::Duration end = start + common::FromSeconds(options_.settle_timeout_s);
  for (common::Duration next = start + period; clock_->Now() < end; next += period) {
    if (!step()) return true;
    clock_->SleepUntil(next);
    if (bus_->Cycle()) return false;
  }
  return true;
}

}  // namespace kinevis::control
