#include "control/common/fixed_rate.h"

#include <gtest/gtest.h>

#include <chrono>
#include <stdexcept>

namespace kinevis::control {
namespace {

using std::chrono::microseconds;
using std::chrono::milliseconds;

// A simulated clock whose sleep number `stall_at` oversleeps by `stall` (a scheduler stall).
class StallingClock final : public common::Clock {
 public:
  StallingClock(int stall_at, common::Duration stall) : stall_at_(stall_at), stall_(stall) {}
  common::Duration Now() const override { return clock_.Now(); }
  void SleepUntil(common::Duration deadline) override {
    clock_.SleepUntil(deadline);
    if (++sleeps_ == stall_at_) clock_.Advance(stall_);
  }

 private:
  common::SimulatedClock clock_;
  int stall_at_;
  common::Duration stall_;
  int sleeps_ = 0;
};

TEST(DeadlineGridTest, WakesOnTheGridWithExactPeriodsOnASimulatedClock) {
  common::SimulatedClock clock;
  DeadlineGrid grid(&clock, milliseconds(1), clock.Now());
  const DeadlineGrid::Wake first = grid.Next();
  EXPECT_TRUE(first.first);
  EXPECT_EQ(first.period_s, 0.0);
  EXPECT_EQ(first.time, milliseconds(1));
  for (int k = 2; k <= 10; ++k) {
    const DeadlineGrid::Wake wake = grid.Next();
    EXPECT_FALSE(wake.first);
    EXPECT_EQ(wake.time, milliseconds(k));
    EXPECT_DOUBLE_EQ(wake.period_s, 0.001);
    EXPECT_EQ(wake.lateness_s, 0.0);
  }
  EXPECT_EQ(grid.missed_deadlines(), 0u);
}

TEST(DeadlineGridTest, ALateWakeUpWithinAPeriodKeepsTheGrid) {
  StallingClock clock(3, microseconds(400));
  DeadlineGrid grid(&clock, milliseconds(1), common::Duration::zero());
  grid.Next();
  grid.Next();
  const DeadlineGrid::Wake late = grid.Next();  // deadline 3 ms, woke at 3.4 ms
  EXPECT_EQ(late.time, microseconds(3400));
  EXPECT_NEAR(late.lateness_s, 400e-6, 1e-12);
  const DeadlineGrid::Wake next = grid.Next();  // back on the grid: 4 ms
  EXPECT_EQ(next.time, milliseconds(4));
  EXPECT_NEAR(next.period_s, 600e-6, 1e-12);
  EXPECT_EQ(grid.missed_deadlines(), 0u);
}

TEST(DeadlineGridTest, AStallLongerThanAPeriodCountsTheMissedDeadlinesAndResynchronises) {
  StallingClock clock(2, microseconds(3500));
  DeadlineGrid grid(&clock, milliseconds(1), common::Duration::zero());
  grid.Next();
  const DeadlineGrid::Wake stalled = grid.Next();  // deadline 2 ms, woke at 5.5 ms
  EXPECT_EQ(stalled.time, microseconds(5500));
  EXPECT_NEAR(stalled.lateness_s, 3.5e-3, 1e-12);
  EXPECT_EQ(grid.missed_deadlines(), 3u);       // 3, 4 and 5 ms were never served
  const DeadlineGrid::Wake next = grid.Next();  // one period after the wake-up, no burst
  EXPECT_EQ(next.time, microseconds(6500));
  EXPECT_NEAR(next.period_s, 1e-3, 1e-12);
}

TEST(DeadlineGridTest, RefusesANullClockAndANonPositivePeriod) {
  common::SimulatedClock clock;
  EXPECT_THROW(DeadlineGrid(nullptr, milliseconds(1), common::Duration::zero()),
               std::invalid_argument);
  EXPECT_THROW(DeadlineGrid(&clock, common::Duration::zero(), common::Duration::zero()),
               std::invalid_argument);
}

TEST(MeasureLoopTimingTest, SimulatedClockIsPerfectlySteady) {
  common::SimulatedClock clock;
  const PeriodStatistics s = MeasureLoopTiming(&clock, 0.001, 0.5);
  EXPECT_EQ(s.periods, 499u);
  EXPECT_DOUBLE_EQ(s.mean_s, 0.001);
  EXPECT_DOUBLE_EQ(s.p99_s, 0.001);
  EXPECT_EQ(s.missed_deadlines, 0u);
  EXPECT_EQ(s.late_cycles, 0u);
  EXPECT_EQ(SteadyRateProblem(s), "");
}

TEST(MeasureLoopTimingTest, AStallIsReportedAsNotSteady) {
  StallingClock clock(100, milliseconds(7));
  const PeriodStatistics s = MeasureLoopTiming(&clock, 0.001, 0.5);
  EXPECT_EQ(s.missed_deadlines, 7u);
  EXPECT_NEAR(s.max_s, 0.008, 1e-12);
  const std::string problem = SteadyRateProblem(s);
  EXPECT_NE(problem.find("7 deadline(s) missed"), std::string::npos) << problem;
}

TEST(MeasureLoopTimingTest, RealClockMeasuresPeriodsNearTheTarget) {
  // Only what cannot flake on a loaded machine: the loop ran, and never woke early.
  const PeriodStatistics s = MeasureLoopTiming(&common::SteadyClock::Instance(), 0.002, 0.1);
  EXPECT_GT(s.periods, 0u);
  EXPECT_LE(s.periods, 50u);
  EXPECT_GE(s.min_s, 0.0);
  EXPECT_GE(s.mean_s, 0.002 * 0.9);
}

TEST(MeasureLoopTimingTest, RefusesBadPeriodsAndDurationsNamingThem) {
  common::SimulatedClock clock;
  try {
    MeasureLoopTiming(&clock, 0.0, 1.0);
    FAIL() << "no throw";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("period"), std::string::npos) << e.what();
  }
  try {
    MeasureLoopTiming(&clock, 0.001, 0.0001);
    FAIL() << "no throw";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("duration"), std::string::npos) << e.what();
  }
  EXPECT_THROW(MeasureLoopTiming(nullptr, 0.001, 1.0), std::invalid_argument);
}

}  // namespace
}  // namespace kinevis::control
