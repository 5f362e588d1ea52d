#include "hal/common/clock.h"

#include <gtest/gtest.h>

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
