#include "hal/drive/cia402_drive_bus.h"

#include <algorithm>

#include "hal/common/error.h"

namespace kinevis::hal {

Cia402DriveBus::Cia402DriveBus(common::Clock* clock, std::chrono::microseconds cycle_period,
                               bool quick_stop_all_on_fault)
    : clock_(clock != nullptr ? clock : &common::SteadyClock::Instance()),
      cycle_period_(cycle_period),
      quick_stop_all_on_fault_(quick_stop_all_on_fault) {}

common::Duration Cia402DriveBus::MarkCycleStart() {
  last_cycle_start_ = clock_->Now();
  cycled_ = true;
  return last_cycle_start_;
}

std::error_code Cia402DriveBus::FinishCycle(std::error_code result) {
  Cia402HostDrive* faulted = nullptr;
  for (Cia402HostDrive* d : group_) {
    if (d->TakeNewFault() && faulted == nullptr) faulted = d;
  }
  if (faulted != nullptr && quick_stop_all_on_fault_) {
    for (Cia402HostDrive* d : group_) {
      if (d != faulted && d->lifecycle() == common::DeviceLifecycle::kActive) {
        d->SafeStop(faulted->name() + " faulted");
      }
    }
  }
  if (result) return result;
  for (Cia402HostDrive* d : group_) {
    if (d->lifecycle() == common::DeviceLifecycle::kFault) {
      return d->status().fault_source == DriveFaultSource::kLink
                 ? make_error_code(Errc::kTimeout)
                 : make_error_code(Errc::kDeviceFault);
    }
  }
  return {};
}

bool Cia402DriveBus::RunCyclesUntil(common::Duration deadline, const std::function<bool()>& done) {
  while (true) {
    const common::Duration now = clock_->Now();
    const common::Duration next = cycled_ ? last_cycle_start_ + cycle_period_ : now;
    if (next > now) clock_->SleepUntil(next);
    Cycle();
    if (done()) return true;
    if (clock_->Now() >= deadline) return false;
  }
}

void Cia402DriveBus::ConfigureAll() {
  for (Cia402HostDrive* d : group_) d->Configure();
}

std::error_code Cia402DriveBus::EnableAll(std::chrono::milliseconds timeout, bool reset_fault) {
  const common::Duration started = clock_->Now();
  std::error_code first;
  std::vector<Cia402HostDrive*> enabling;
  for (Cia402HostDrive* d : group_) {
    if (d->lifecycle() == common::DeviceLifecycle::kActive) continue;
    if (std::error_code ec = d->BeginEnable(reset_fault)) {
      if (!first) first = ec;
      continue;
    }
    enabling.push_back(d);
  }
  if (enabling.empty()) return first;
  RunCyclesUntil(started + timeout, [&] {
    return std::all_of(enabling.begin(), enabling.end(),
                       [](Cia402HostDrive* d) { return d->EnableSettled(); });
  });
  bool failed = false;
  for (Cia402HostDrive* d : enabling) {
    if (std::error_code ec = d->FinishEnable(started)) {
      failed = true;
      if (!first) first = ec;
    }
  }
  if (failed) RunCyclesUntil(clock_->Now(), [] { return true; });
  return first;
}

std::error_code Cia402DriveBus::DisableAll() {
  std::error_code first;
  std::vector<Cia402HostDrive*> disabling;
  std::chrono::milliseconds timeout{0};
  for (Cia402HostDrive* d : group_) {
    if (d->lifecycle() == common::DeviceLifecycle::kUnconfigured) continue;
    if (std::error_code ec = d->BeginDisable()) {
      if (!first) first = ec;
      continue;
    }
    timeout = std::max(timeout, d->options().command_timeout);
    disabling.push_back(d);
  }
  if (disabling.empty()) return first;
  RunCyclesUntil(clock_->Now() + timeout, [&] {
    return std::all_of(disabling.begin(), disabling.end(),
                       [](Cia402HostDrive* d) { return d->DisableSettled(); });
  });
  for (Cia402HostDrive* d : disabling) {
    if (std::error_code ec = d->FinishDisable(); ec && !first) first = ec;
  }
  return first;
}

}  // namespace kinevis::hal
