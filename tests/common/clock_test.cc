#include "common/clock.h"

#include <gtest/gtest.h>
#include <time.h>

#include <thread>

#include "common/lifecycle.h"

namespace kinevis::common {
namespace {

using namespace std::chrono_literals;

TEST(SteadyClockTest, IsMonotonicAndSleeps) {
  common::Clock& clock = common::SteadyClock::Instance();
  common::Duration a = clock.Now();
  clock.SleepFor(2ms);
  common::Duration b = clock.Now();
  EXPECT_GE(b - a, 2ms);
}

// SleepUntil sleeps on CLOCK_MONOTONIC with an absolute deadline: Now() must be that clock.
TEST(SteadyClockTest, IsClockMonotonicAndWakesNoEarlierThanTheDeadline) {
  common::Clock& clock = common::SteadyClock::Instance();
  timespec t{};
  clock_gettime(CLOCK_MONOTONIC, &t);
  const common::Duration monotonic =
      std::chrono::seconds(t.tv_sec) + std::chrono::nanoseconds(t.tv_nsec);
  EXPECT_LT(std::chrono::abs(clock.Now() - monotonic), 50ms);
  for (int k = 0; k < 5; ++k) {
    const common::Duration deadline = clock.Now() + 1ms;
    clock.SleepUntil(deadline);
    EXPECT_GE(clock.Now(), deadline);
  }
  clock.SleepUntil(clock.Now() - 1s);  // in the past: returns at once
}

TEST(SimulatedClockTest, FreeRunningSleepAdvancesTime) {
  common::SimulatedClock clock;
  EXPECT_EQ(clock.Now(), common::Duration::zero());
  clock.SleepFor(1h);  // returns at once
  EXPECT_EQ(clock.Now(), common::Duration(1h));
  clock.SleepUntil(common::Duration(30min));  // in the past: no change
  EXPECT_EQ(clock.Now(), common::Duration(1h));
}

TEST(SimulatedClockTest, AdvanceRejectsGoingBackwards) {
  common::SimulatedClock clock(common::SimulatedClock::Mode::kFreeRunning, common::Duration(10s));
  clock.Advance(5s);
  EXPECT_EQ(clock.Now(), common::Duration(15s));
  EXPECT_THROW(clock.Advance(-1s), std::invalid_argument);
  EXPECT_THROW(clock.AdvanceTo(common::Duration(1s)), std::invalid_argument);
}

TEST(SimulatedClockTest, DrivenSleepWaitsForAnotherThread) {
  common::SimulatedClock clock(common::SimulatedClock::Mode::kDriven);
  std::atomic<bool> woke{false};
  std::thread sleeper([&] {
    clock.SleepUntil(common::Duration(100ms));
    woke = true;
  });
  clock.Advance(50ms);
  std::this_thread::sleep_for(20ms);
  EXPECT_FALSE(woke.load());
  clock.Advance(50ms);
  sleeper.join();
  EXPECT_TRUE(woke.load());
  EXPECT_EQ(clock.Now(), common::Duration(100ms));
}

using std::chrono::milliseconds;

TEST(ClockTest, SecondsConversions) {
  EXPECT_EQ(FromSeconds(0.001), milliseconds(1));
  EXPECT_EQ(FromSeconds(2.5), Duration(2500000000));
  EXPECT_DOUBLE_EQ(ToSeconds(milliseconds(250)), 0.25);
  EXPECT_DOUBLE_EQ(ToSeconds(FromSeconds(-3.0)), -3.0);
}

TEST(LifecycleTest, EveryStateHasItsName) {
  EXPECT_STREQ(ToString(DeviceLifecycle::kUnconfigured), "unconfigured");
  EXPECT_STREQ(ToString(DeviceLifecycle::kConfigured), "configured");
  EXPECT_STREQ(ToString(DeviceLifecycle::kActive), "active");
  EXPECT_STREQ(ToString(DeviceLifecycle::kFault), "fault");
}

}  // namespace
}  // namespace kinevis::common
