#include "hal/mock/motion_model.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace kinevis::hal {
namespace {

constexpr double kDt = 0.001;  // 1 ms cycle

MotionLimits TestLimits() {
  MotionLimits l;
  l.max_velocity = 100000;
  l.max_acceleration = 1000000;
  l.min_position = -1e7;
  l.max_position = 1e7;
  l.inertia = 500;  // 1000 per mille -> 500000 counts/s^2
  l.rated_torque_per_mille = 1000;
  return l;
}

// Relative slack for floating-point comparisons of the limits.
bool WithinLimit(double value, double limit) {
  return std::abs(value) <= limit * (1 + 1e-9) + 1e-9;
}

// Steps the model and checks the velocity and acceleration limits at every step.
struct Runner {
  AxisMotionModel model;
  double v_limit;
  double a_limit;
  int violations = 0;

  Runner(MotionLimits limits, double v_lim, double a_lim)
      : model(limits), v_limit(v_lim), a_limit(a_lim) {}

  void Run(int steps, DriveMode mode, double p_sp, double v_sp, double t_sp, double pv = 0,
           double pa = 0) {
    for (int i = 0; i < steps; ++i) StepOnce(mode, p_sp, v_sp, t_sp, pv, pa);
  }
  const AxisState& StepOnce(DriveMode mode, double p_sp, double v_sp, double t_sp, double pv = 0,
                            double pa = 0) {
    const double v0 = model.state().velocity;
    const AxisState& s = model.Step(kDt, mode, p_sp, v_sp, t_sp, pv, pa);
    if (!WithinLimit(s.velocity, v_limit)) ++violations;
    if (!WithinLimit((s.velocity - v0) / kDt, a_limit)) ++violations;
    if (!WithinLimit(s.acceleration, a_limit)) ++violations;
    return s;
  }
};

TEST(StoppingSpeedTest, BrakingFromItStopsOnThePoint) {
  std::mt19937 rng(42);
  std::uniform_real_distribution<double> distance(0.0, 50000.0);
  const double a = 1e6, dt = 1e-3;
  for (int trial = 0; trial < 200; ++trial) {
    const double d = distance(rng);
    double v = StoppingSpeed(d, a, dt);
    double travelled = v * dt;
    while (v > 0) {
      v = std::max(0.0, v - a * dt);
      travelled += v * dt;
    }
    EXPECT_LE(travelled, d * (1 + 1e-12) + 1e-9) << "d = " << d;
    // And it is the largest such speed: a little faster overshoots.
    double v2 = StoppingSpeed(d, a, dt) * 1.001 + 1e-6;
    double travelled2 = v2 * dt;
    while (v2 > 0) {
      v2 = std::max(0.0, v2 - a * dt);
      travelled2 += v2 * dt;
    }
    EXPECT_GT(travelled2, d) << "d = " << d;
  }
}

TEST(StoppingSpeedTest, LimitsOfTheFormula) {
  const double a = 1e6, dt = 1e-3;
  EXPECT_DOUBLE_EQ(StoppingSpeed(0.0, a, dt), 0.0);
  EXPECT_DOUBLE_EQ(StoppingSpeed(-5.0, a, dt), 0.0);
  // One step suffices for a short distance: d / dt.
  EXPECT_NEAR(StoppingSpeed(0.5, a, dt), 500.0, 1e-9);
  // Far away it tends to the continuous sqrt(2 a d).
  const double d = 1e6;
  EXPECT_NEAR(StoppingSpeed(d, a, dt) / std::sqrt(2 * a * d), 1.0, 1e-3);
}

TEST(MotionModelTest, CspStepReachesTheSetPointWithinTheLimitsAndWithoutOvershoot) {
  Runner r(TestLimits(), 100000, 1000000);
  double max_position = 0;
  for (int i = 0; i < 2000; ++i) {
    max_position = std::max(
        max_position, r.StepOnce(DriveMode::kCyclicSynchronousPosition, 50000, 0, 0).position);
  }
  EXPECT_EQ(r.violations, 0);
  EXPECT_NEAR(r.model.state().position, 50000, 1e-6);
  EXPECT_NEAR(r.model.state().velocity, 0, 1e-6);
  EXPECT_LE(max_position, 50000 + 1e-6);
  // The move is limited: 50000 counts at <= 100000 counts/s takes at least 0.5 s.
  AxisMotionModel fresh(TestLimits());
  for (int i = 0; i < 400; ++i) {
    fresh.Step(kDt, DriveMode::kCyclicSynchronousPosition, 50000, 0, 0, 0, 0);
  }
  EXPECT_LT(fresh.state().position, 50000 - 1000);
}

TEST(MotionModelTest, CspTracksARampWithFeedForwardExactly) {
  Runner r(TestLimits(), 100000, 1000000);
  const double slope = 40000;  // counts/s
  double setpoint = 0;
  double worst_late = 0;
  for (int i = 1; i <= 3000; ++i) {
    setpoint = slope * kDt * i;
    r.StepOnce(DriveMode::kCyclicSynchronousPosition, setpoint, slope, 0);
    if (i > 1000) worst_late = std::max(worst_late, std::abs(setpoint - r.model.state().position));
  }
  EXPECT_EQ(r.violations, 0);
  EXPECT_LT(worst_late, 1e-6);
  EXPECT_NEAR(r.model.state().velocity, slope, 1e-6);
}

TEST(MotionModelTest, CsvReachesTheVelocityWithTheAccelerationLimit) {
  Runner r(TestLimits(), 100000, 1000000);
  r.Run(40, DriveMode::kCyclicSynchronousVelocity, 0, 80000, 0);
  // 80000 counts/s at 1e6 counts/s^2 needs 80 ms: after 40 ms it is half way.
  EXPECT_NEAR(r.model.state().velocity, 40000, 1e-6);
  r.Run(100, DriveMode::kCyclicSynchronousVelocity, 0, 80000, 0);
  EXPECT_NEAR(r.model.state().velocity, 80000, 1e-6);
  // A set-point above the limit is capped.
  r.Run(100, DriveMode::kCyclicSynchronousVelocity, 0, 5e5, 0);
  EXPECT_NEAR(r.model.state().velocity, 100000, 1e-6);
  r.Run(300, DriveMode::kCyclicSynchronousVelocity, 0, -30000, 0);
  EXPECT_NEAR(r.model.state().velocity, -30000, 1e-6);
  EXPECT_EQ(r.violations, 0);
}

TEST(MotionModelTest, CstTurnsTorqueIntoAccelerationThroughTheInertia) {
  Runner r(TestLimits(), 100000, 1000000);
  r.Run(10, DriveMode::kCyclicSynchronousTorque, 0, 0, 100);  // 100 per mille * 500
  EXPECT_NEAR(r.model.state().acceleration, 50000, 1e-6);
  EXPECT_NEAR(r.model.state().velocity, 500, 1e-6);
  EXPECT_DOUBLE_EQ(r.model.state().torque, 100);
  // Torque beyond rated is limited, and the velocity limit holds.
  r.Run(2000, DriveMode::kCyclicSynchronousTorque, 0, 0, 5000);
  EXPECT_DOUBLE_EQ(r.model.state().torque, 1000);
  EXPECT_NEAR(r.model.state().velocity, 100000, 1e-6);
  EXPECT_EQ(r.violations, 0);
}

TEST(MotionModelTest, PpFollowsATrapezoidalProfileToTheTarget) {
  const double pv = 20000, pa = 100000;
  Runner r(TestLimits(), pv, pa);
  double peak = 0;
  bool cruised = false;
  for (int i = 0; i < 3000; ++i) {
    const AxisState& s = r.StepOnce(DriveMode::kProfilePosition, 30000, 0, 0, pv, pa);
    peak = std::max(peak, s.velocity);
    if (std::abs(s.velocity - pv) < 1e-6 && s.acceleration == 0) cruised = true;
  }
  EXPECT_EQ(r.violations, 0);
  EXPECT_TRUE(cruised);  // long move: a trapezoid with a cruise phase
  EXPECT_NEAR(peak, pv, 1e-6);
  EXPECT_NEAR(r.model.state().position, 30000, 1e-6);
  EXPECT_EQ(r.model.state().velocity, 0);
}

TEST(MotionModelTest, PpShortMoveIsTriangularAndProfileIsCappedByTheLimits) {
  // 1000 counts at 100000 counts/s^2: peak sqrt(a d) = 10000 counts/s < profile velocity.
  Runner r(TestLimits(), 50000, 100000);
  double peak = 0;
  for (int i = 0; i < 1000; ++i) {
    peak =
        std::max(peak, r.StepOnce(DriveMode::kProfilePosition, 1000, 0, 0, 50000, 100000).velocity);
  }
  EXPECT_LT(peak, 10500);
  EXPECT_NEAR(r.model.state().position, 1000, 1e-6);
  EXPECT_EQ(r.violations, 0);

  // Profile values above the limits are capped by them.
  Runner capped(TestLimits(), 100000, 1000000);
  capped.Run(3000, DriveMode::kProfilePosition, -150000, 0, 0, 1e9, 1e9);
  EXPECT_EQ(capped.violations, 0);
  EXPECT_NEAR(capped.model.state().position, -150000, 1e-6);
}

TEST(MotionModelTest, PpWithoutProfileVelocityDoesNotMove) {
  AxisMotionModel m(TestLimits());
  for (int i = 0; i < 100; ++i) m.Step(kDt, DriveMode::kProfilePosition, 5000, 0, 0, 0, 1e5);
  EXPECT_EQ(m.state().position, 0);
}

TEST(MotionModelTest, PvReachesTheVelocityWithTheProfileAcceleration) {
  Runner r(TestLimits(), 100000, 200000);
  r.Run(100, DriveMode::kProfileVelocity, 0, 30000, 0, 0, 200000);
  EXPECT_NEAR(r.model.state().velocity, 20000, 1e-6);  // 0.1 s at 200000 counts/s^2
  r.Run(100, DriveMode::kProfileVelocity, 0, 30000, 0, 0, 200000);
  EXPECT_NEAR(r.model.state().velocity, 30000, 1e-6);
  EXPECT_EQ(r.violations, 0);
}

TEST(MotionModelTest, VelocityModeStopsExactlyAtThePositionLimit) {
  MotionLimits l = TestLimits();
  l.max_position = 20000;
  Runner r(l, l.max_velocity, l.max_acceleration);
  bool hit = false;
  for (int i = 0; i < 2000; ++i) {
    r.StepOnce(DriveMode::kCyclicSynchronousVelocity, 0, 100000, 0);
    hit = hit || r.model.limit_hit();
    ASSERT_LE(r.model.state().position, 20000 + 1e-6) << "step " << i;
  }
  EXPECT_TRUE(hit);
  EXPECT_TRUE(r.model.limit_hit());
  EXPECT_NEAR(r.model.state().position, 20000, 1e-6);
  EXPECT_EQ(r.model.state().velocity, 0);
  EXPECT_EQ(r.violations, 0);  // braked in front of the limit, not a crash stop
  // Motion away from the limit is free again.
  r.Run(10, DriveMode::kCyclicSynchronousVelocity, 0, -1000, 0);
  EXPECT_FALSE(r.model.limit_hit());
  EXPECT_LT(r.model.state().position, 20000);
}

TEST(MotionModelTest, PositionTargetBeyondTheLimitIsClamped) {
  MotionLimits l = TestLimits();
  l.min_position = -5000;
  Runner r(l, l.max_velocity, l.max_acceleration);
  r.Run(1000, DriveMode::kCyclicSynchronousPosition, -90000, 0, 0);
  EXPECT_NEAR(r.model.state().position, -5000, 1e-6);
  EXPECT_TRUE(r.model.limit_hit());
  EXPECT_EQ(r.violations, 0);
}

TEST(MotionModelTest, TooFastForTheLimitStillStopsOnIt) {
  MotionLimits l = TestLimits();
  AxisMotionModel m(l);
  AxisState s;
  s.position = 9990;
  s.velocity = 100000;
  m.Reset(s);
  l.max_position = 10000;  // limits moved under a moving axis
  m.SetLimits(l);
  // From 100000 counts/s to the steepest stop that still ends on the limit (4000, 3000, 2000,
  // 1000 counts/s: 10 counts), then at rest on it.
  const double expected_velocity[] = {4000, 3000, 2000, 1000, 0, 0};
  for (double v : expected_velocity) {
    m.Step(kDt, DriveMode::kCyclicSynchronousVelocity, 0, 100000, 0, 0, 0);
    EXPECT_TRUE(m.limit_hit());
    EXPECT_NEAR(m.state().velocity, v, 1e-6);
    EXPECT_LE(m.state().position, 10000);
  }
  EXPECT_EQ(m.state().position, 10000);
  EXPECT_EQ(m.state().velocity, 0);
}

TEST(MotionModelTest, BrakeDeceleratesToStandstillAndStays) {
  AxisMotionModel m(TestLimits());
  AxisState s;
  s.velocity = -60000;
  m.Reset(s);
  int steps = 0;
  double previous = s.velocity;
  while (m.state().velocity != 0 && steps < 1000) {
    m.Brake(kDt, 300000);
    EXPECT_LE(std::abs(m.state().velocity - previous), 300000 * kDt * (1 + 1e-9));
    previous = m.state().velocity;
    ++steps;
  }
  EXPECT_EQ(steps, 200);  // 60000 / 300000 s
  const double stop = m.state().position;
  // Semi-implicit Euler: sum of v_k dt with v_k = -60000 + 300 k, k = 1..200.
  EXPECT_NEAR(stop, -5970, 1e-6);
  m.Brake(kDt, 300000);
  EXPECT_EQ(m.state().position, stop);
  EXPECT_EQ(m.state().velocity, 0);
}

TEST(MotionModelTest, NonPositiveStepChangesNothing) {
  AxisMotionModel m(TestLimits());
  m.Step(0.0, DriveMode::kCyclicSynchronousVelocity, 0, 1000, 0, 0, 0);
  m.Step(-1.0, DriveMode::kCyclicSynchronousVelocity, 0, 1000, 0, 0, 0);
  m.Step(std::nan(""), DriveMode::kCyclicSynchronousVelocity, 0, 1000, 0, 0, 0);
  EXPECT_EQ(m.state().velocity, 0);
  EXPECT_EQ(m.state().position, 0);
}

TEST(MotionModelTest, RandomSetPointsNeverBreakTheLimits) {
  std::mt19937 rng(7);
  MotionLimits l = TestLimits();
  l.min_position = -200000;
  l.max_position = 200000;
  Runner r(l, l.max_velocity, l.max_acceleration);
  std::uniform_int_distribution<int> pick(0, 3);
  std::uniform_real_distribution<double> pos(-300000, 300000), vel(-2e5, 2e5), torque(-2000, 2000);
  for (int segment = 0; segment < 60; ++segment) {
    const DriveMode modes[] = {DriveMode::kCyclicSynchronousPosition,
                               DriveMode::kCyclicSynchronousVelocity,
                               DriveMode::kCyclicSynchronousTorque, DriveMode::kProfilePosition};
    const DriveMode mode = modes[pick(rng)];
    const double p = pos(rng), v = vel(rng), t = torque(rng);
    for (int i = 0; i < 100; ++i) {
      r.StepOnce(mode, p, mode == DriveMode::kCyclicSynchronousPosition ? 0 : v, t, 1e5, 1e6);
      ASSERT_GE(r.model.state().position, l.min_position - 1e-6);
      ASSERT_LE(r.model.state().position, l.max_position + 1e-6);
    }
  }
  EXPECT_EQ(r.violations, 0);
}

}  // namespace
}  // namespace kinevis::hal
