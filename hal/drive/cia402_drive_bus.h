#pragma once

// What every bus of CiA 402 drives does the same way, whatever carries the process data
// (CanopenMaster: PDOs and SYNC on CAN; Rs485DriveBus: Modbus RTU transactions): pacing cycles at
// the cycle period, configuring, enabling and disabling the whole group with one deadline, the
// quick-stop policy when one drive faults, and the error a cycle returns when a drive is in fault.
// A derived bus implements Cycle() (calling MarkCycleStart() first and FinishCycle() last) and
// registers its drives with AddToGroup().

#include <chrono>
#include <functional>
#include <system_error>
#include <vector>

#include "common/clock.h"
#include "hal/drive/cia402_can_drive.h"
#include "hal/drive/motor_drive.h"

namespace kinevis::hal {

class Cia402DriveBus : public DriveBus {
 public:
  common::Clock& clock() const { return *clock_; }

  // Configure() on every drive, in the order they were added. Throws as Configure() does.
  void ConfigureAll();
  // Enables every drive with one shared deadline, all at once (the state machines advance
  // together). Returns {} or the first drive's error (each drive's last_error_text() says why).
  std::error_code EnableAll(std::chrono::milliseconds timeout, bool reset_fault = false);
  // Disable voltage on every configured drive at once; waits for them as Disable() does.
  std::error_code DisableAll();
  // Runs cycles every cycle period until done() returns true or the clock passes `deadline`;
  // at least one cycle. Returns done().
  bool RunCyclesUntil(common::Duration deadline, const std::function<bool()>& done);

 protected:
  // clock: nullptr = SteadyClock::Instance(). cycle_period > 0 (validated by the derived bus).
  Cia402DriveBus(common::Clock* clock, std::chrono::microseconds cycle_period,
                 bool quick_stop_all_on_fault);

  void AddToGroup(Cia402HostDrive* drive) { group_.push_back(drive); }
  // Start of a cycle: returns its time, from which RunCyclesUntil paces the next one.
  common::Duration MarkCycleStart();
  // End of a cycle: applies the quick-stop policy (a drive that faulted in this cycle
  // quick-stops the other active drives), then returns `result`, or, when that is {}, the error
  // of a drive in fault (Errc::kTimeout for a link fault, Errc::kDeviceFault otherwise).
  std::error_code FinishCycle(std::error_code result);

  common::Clock* const clock_;

 private:
  const std::chrono::microseconds cycle_period_;
  const bool quick_stop_all_on_fault_;
  std::vector<Cia402HostDrive*> group_;
  common::Duration last_cycle_start_{0};
  bool cycled_ = false;
};

}  // namespace kinevis::hal
