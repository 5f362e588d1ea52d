#pragma once

// A simulated clock that steps a bare drive simulator (no world) whenever the host waits: the
// host's waits advance simulated time and the devices follow, deterministically, while the
// bytes still travel over the real transport (a pty for Rs485DriveSim).

#include "common/clock.h"
#include "hal/mock/rs485_drive_sim.h"

namespace kinevis::testing {

class SimStepClock final : public common::Clock {
 public:
  common::SimulatedClock time;
  hal::Rs485DriveSim* sim = nullptr;
  common::Duration Now() const override { return time.Now(); }
  void SleepUntil(common::Duration deadline) override {
    if (deadline > time.Now()) time.AdvanceTo(deadline);
    if (sim) sim->Step();
  }
};

}  // namespace kinevis::testing
