#pragma once

// The one clock abstraction of kinevis. Everything that waits, time-stamps or runs at a fixed rate
// takes a Clock, so that a simulated world can run faster than real time and tests are
// deterministic.
//
// Time is a std::chrono::nanoseconds count since the clock's own epoch (for SteadyClock the
// epoch of std::chrono::steady_clock, i.e. boot; for SimulatedClock, zero at construction).

#include <chrono>
#include <condition_variable>
#include <mutex>

namespace kinevis::common {

using Duration = std::chrono::nanoseconds;

// Seconds as a double, and back (truncated to whole nanoseconds).
inline double ToSeconds(Duration d) { return std::chrono::duration<double>(d).count(); }
inline Duration FromSeconds(double s) {
  return std::chrono::duration_cast<Duration>(std::chrono::duration<double>(s));
}

class Clock {
 public:
  virtual ~Clock() = default;
  // Current time since the clock's epoch. Monotonic, thread-safe.
  virtual Duration Now() const = 0;
  // Blocks until Now() >= deadline. On a simulated clock this is where simulated time passes.
  virtual void SleepUntil(Duration deadline) = 0;
  void SleepFor(Duration d) { SleepUntil(Now() + d); }
};

// Wall time from std::chrono::steady_clock. Stateless; Instance() is shared.
class SteadyClock final : public Clock {
 public:
  static SteadyClock& Instance();
  Duration Now() const override;
  void SleepUntil(Duration deadline) override;
};

// Time that moves only when told to. SleepUntil() advances the clock to the deadline at once when
// the clock is in free-running mode (the default: a single-threaded simulation never waits), or
// waits for another thread's Advance() when constructed with kDriven.
class SimulatedClock final : public Clock {
 public:
  enum class Mode { kFreeRunning, kDriven };
  explicit SimulatedClock(Mode mode = Mode::kFreeRunning, Duration start = Duration::zero());

  Duration Now() const override;
  void SleepUntil(Duration deadline) override;
  // Moves time forward by d (d >= 0) and wakes sleepers whose deadline has passed.
  void Advance(Duration d);
  // Sets the time; t must not be earlier than Now().
  void AdvanceTo(Duration t);

 private:
  const Mode mode_;
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  Duration now_;
};

}  // namespace kinevis::common
