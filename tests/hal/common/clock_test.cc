#include "hal/common/clock.h"

#include <gtest/gtest.h>
#include <time.h>

#include <thread>

namespace kinevis::hal {
namespace {

using namespace std::chrono_literals;

TEST(SteadyClockTest, IsMonotonicAndSleeps) {
  Clock& clock = SteadyClock::Instance();
  Duration a = clock.Now();
  clock.SleepFor(2ms);
  Duration b = clock.Now();
  EXPECT_GE(b - a, 2ms);
}

// SleepUntil sleeps on CLOCK_MONOTONIC with an absolute deadline: Now() must be that clock.
TEST(SteadyClockTest, IsClockMonotonicAndWakesNoEarlierThanTheDeadline) {
  Clock& clock = SteadyClock::Instance();
  timespec t{};
  clock_gettime(CLOCK_MONOTONIC, &t);
  const Duration monotonic = std::chrono::seconds(t.tv_sec) + std::chrono::nanoseconds(t.tv_nsec);
  EXPECT_LT(std::chrono::abs(clock.Now() - monotonic), 50ms);
  for (int k = 0; k < 5; ++k) {
    const Duration deadline = clock.Now() + 1ms;
    clock.SleepUntil(deadline);
    EXPECT_GE(clock.Now(), deadline);
  }
  clock.SleepUntil(clock.Now() - 1s);  // in the past: returns at once
}

TEST(SimulatedClockTest, FreeRunningSleepAdvancesTime) {
  SimulatedClock clock;
  EXPECT_EQ(clock.Now(), Duration::zero());
  clock.SleepFor(1h);  // returns at once
  EXPECT_EQ(clock.Now(), Duration(1h));
  clock.SleepUntil(Duration(30min));  // in the past: no change
  EXPECT_EQ(clock.Now(), Duration(1h));
}

TEST(SimulatedClockTest, AdvanceRejectsGoingBackwards) {
  SimulatedClock clock(SimulatedClock::Mode::kFreeRunning, Duration(10s));
  clock.Advance(5s);
  EXPECT_EQ(clock.Now(), Duration(15s));
  EXPECT_THROW(clock.Advance(-1s), std::invalid_argument);
  EXPECT_THROW(clock.AdvanceTo(Duration(1s)), std::invalid_argument);
}

TEST(SimulatedClockTest, DrivenSleepWaitsForAnotherThread) {
  SimulatedClock clock(SimulatedClock::Mode::kDriven);
  std::atomic<bool> woke{false};
  std::thread sleeper([&] {
    clock.SleepUntil(Duration(100ms));
    woke = true;
  });
  clock.Advance(50ms);
  std::this_thread::sleep_for(20ms);
  EXPECT_FALSE(woke.load());
  clock.Advance(50ms);
  sleeper.join();
  EXPECT_TRUE(woke.load());
  EXPECT_EQ(clock.Now(), Duration(100ms));
}

}  // namespace
}  // namespace kinevis::hal
