#include "hal/common/clock.h"

#include <stdexcept>
#include <thread>

namespace kinevis::hal {

SteadyClock& SteadyClock::Instance() {
  static SteadyClock clock;
  return clock;
}

Duration SteadyClock::Now() const {
  return std::chrono::duration_cast<Duration>(std::chrono::steady_clock::now().time_since_epoch());
}

void SteadyClock::SleepUntil(Duration deadline) {
  std::this_thread::sleep_until(std::chrono::steady_clock::time_point(
      std::chrono::duration_cast<std::chrono::steady_clock::duration>(deadline)));
}

SimulatedClock::SimulatedClock(Mode mode, Duration start) : mode_(mode), now_(start) {}

Duration SimulatedClock::Now() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return now_;
}

void SimulatedClock::SleepUntil(Duration deadline) {
  std::unique_lock<std::mutex> lock(mutex_);
  if (mode_ == Mode::kFreeRunning) {
    if (deadline > now_) now_ = deadline;
    cv_.notify_all();
    return;
  }
  cv_.wait(lock, [&] { return now_ >= deadline; });
}

void SimulatedClock::Advance(Duration d) {
  if (d < Duration::zero()) throw std::invalid_argument("SimulatedClock::Advance: negative step");
  {
    std::lock_guard<std::mutex> lock(mutex_);
    now_ += d;
  }
  cv_.notify_all();
}

void SimulatedClock::AdvanceTo(Duration t) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (t < now_) throw std::invalid_argument("SimulatedClock::AdvanceTo: time would go backwards");
    now_ = t;
  }
  cv_.notify_all();
}

}  // namespace kinevis::hal
