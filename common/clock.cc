#include "common/clock.h"

#include <time.h>

#include <cerrno>
#include <stdexcept>

namespace kinevis::common {

SteadyClock& SteadyClock::Instance() {
  static SteadyClock clock;
  return clock;
}

Duration SteadyClock::Now() const {
  return std::chrono::duration_cast<Duration>(std::chrono::steady_clock::now().time_since_epoch());
}

void SteadyClock::SleepUntil(Duration deadline) {
  // An absolute sleep on CLOCK_MONOTONIC (std::chrono::steady_clock's clock on Linux): no window
  // between reading the time and sleeping in which a preemption would shift the deadline, as a
  // relative sleep has. Resumed after a signal.
  static_assert(std::chrono::steady_clock::is_steady);
  if (deadline <= Duration::zero()) return;
  timespec t{};
  t.tv_sec = static_cast<time_t>(deadline.count() / 1000000000);
  t.tv_nsec = static_cast<decltype(t.tv_nsec)>(deadline.count() % 1000000000);
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &t, nullptr) == EINTR) {
  }
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

}  // namespace kinevis::common
