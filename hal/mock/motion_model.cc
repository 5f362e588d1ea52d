#include "hal/mock/motion_model.h"

#include <algorithm>
#include <cmath>

namespace kinevis::hal {
namespace {

double Sign(double x) { return x < 0 ? -1.0 : 1.0; }

// A profile value caps the limit; <= 0 (or not finite) means "no motion" in the profile modes.
double Cap(double profile, double limit) {
  if (!(profile > 0)) return 0.0;
  return std::min(profile, limit);
}

}  // namespace

double StoppingSpeed(double distance, double a, double dt) {
  if (!(distance > 0) || !(a > 0) || !(dt > 0)) return 0.0;
  // Moving at k a dt this step, then braking by a dt per step, the axis covers
  // a dt^2 (k + (k - 1) + ... + (k - n)) with n = floor(k), i.e. a dt^2 (n + 1)(k - n / 2).
  // The largest k for which that is at most E = distance / (a dt^2): n is the largest integer
  // with n (n + 1) / 2 <= E, then k = E / (n + 1) + n / 2 (which is < n + 1).
  const double e = distance / (a * dt * dt);
  double n = std::floor((-1.0 + std::sqrt(1.0 + 8.0 * e)) / 2.0);
  // Rounding of the square root may put n one off; fix it so that n (n + 1) / 2 <= E holds.
  while (n > 0 && n * (n + 1) / 2 > e) n -= 1;
  while ((n + 1) * (n + 2) / 2 <= e) n += 1;
  const double k = std::min(e / (n + 1) + n / 2, n + 1);
  return k * a * dt;
}

AxisMotionModel::AxisMotionModel(MotionLimits limits) : limits_(limits) {}

const AxisState& AxisMotionModel::state() const { return state_; }
bool AxisMotionModel::limit_hit() const { return limit_hit_; }

void AxisMotionModel::Reset(const AxisState& state) {
  state_ = state;
  limit_hit_ = false;
}

const AxisState& AxisMotionModel::Step(double dt, DriveMode mode, double position_setpoint,
                                       double velocity_setpoint, double torque_setpoint,
                                       double profile_velocity, double profile_acceleration) {
  if (!(dt > 0) || !std::isfinite(dt)) return state_;
  limit_hit_ = false;
  const double vmax = limits_.max_velocity;
  const double amax = limits_.max_acceleration;
  const double p = state_.position;
  auto clamp_target = [this](double target) {
    const double t = std::clamp(target, limits_.min_position, limits_.max_position);
    if (t != target) limit_hit_ = true;
    return t;
  };
  double torque = 0;
  bool torque_commanded = false;
  switch (mode) {
    case DriveMode::kCyclicSynchronousPosition: {
      const double target = clamp_target(position_setpoint);
      // A set-point that was clamped does not continue beyond the limit.
      double ff = limit_hit_ ? 0.0 : std::clamp(velocity_setpoint, -vmax, vmax);
      if (!std::isfinite(ff)) ff = 0;
      // In the frame moving with the set-point, the axis has to stop on it: the static law
      // applied to the error left after this step if it moved at the feed-forward velocity.
      const double e = target - p - ff * dt;
      const double v_des = ff + Sign(e) * StoppingSpeed(std::abs(e), amax, dt);
      Integrate(dt, v_des, vmax, amax);
      break;
    }
    case DriveMode::kProfilePosition: {
      const double v_limit = Cap(profile_velocity, vmax);
      const double a_limit = Cap(profile_acceleration, amax);
      if (v_limit <= 0 || a_limit <= 0) {
        Integrate(dt, 0.0, vmax, amax);
        break;
      }
      const double e = clamp_target(position_setpoint) - p;
      Integrate(dt, Sign(e) * StoppingSpeed(std::abs(e), a_limit, dt), v_limit, a_limit);
      break;
    }
    case DriveMode::kCyclicSynchronousVelocity:
      Integrate(dt, std::isfinite(velocity_setpoint) ? velocity_setpoint : 0.0, vmax, amax);
      break;
    case DriveMode::kProfileVelocity: {
      const double a_limit = Cap(profile_acceleration, amax);
      if (a_limit <= 0) {
        Integrate(dt, 0.0, vmax, amax);
        break;
      }
      Integrate(dt, std::isfinite(velocity_setpoint) ? velocity_setpoint : 0.0, vmax, a_limit);
      break;
    }
    case DriveMode::kCyclicSynchronousTorque:
    case DriveMode::kProfileTorque: {
      const double tmax = limits_.rated_torque_per_mille;
      torque = std::isfinite(torque_setpoint) ? std::clamp(torque_setpoint, -tmax, tmax) : 0.0;
      torque_commanded = true;
      const double a = std::clamp(torque * limits_.inertia, -amax, amax);
      Integrate(dt, state_.velocity + a * dt, vmax, amax);
      break;
    }
  }
  if (torque_commanded) {
    state_.torque = torque;
  } else {
    const double tmax = limits_.rated_torque_per_mille;
    state_.torque =
        limits_.inertia > 0 ? std::clamp(state_.acceleration / limits_.inertia, -tmax, tmax) : 0.0;
  }
  return state_;
}

const AxisState& AxisMotionModel::Brake(double dt, double deceleration) {
  if (!(dt > 0) || !std::isfinite(dt)) return state_;
  limit_hit_ = false;
  const double d = deceleration > 0 ? deceleration : limits_.max_acceleration;
  const double v = state_.velocity;
  const double v_new = v > 0 ? std::max(0.0, v - d * dt) : std::min(0.0, v + d * dt);
  // Braking never goes faster, so only the hard stop at the limits applies.
  Integrate(dt, v_new, std::max(std::abs(v), std::abs(v_new)), d);
  const double tmax = limits_.rated_torque_per_mille;
  state_.torque =
      limits_.inertia > 0 ? std::clamp(state_.acceleration / limits_.inertia, -tmax, tmax) : 0.0;
  return state_;
}

void AxisMotionModel::Integrate(double dt, double v_des, double v_limit, double a_limit) {
  const double p = state_.position;
  const double v = state_.velocity;
  v_des = std::clamp(v_des, -v_limit, v_limit);
  // Brake in front of the limits so that the axis stops on them (a position already beyond a
  // limit allows motion back into the range only).
  const double up = StoppingSpeed(limits_.max_position - p, a_limit, dt);
  const double down = -StoppingSpeed(p - limits_.min_position, a_limit, dt);
  if (v_des > up) {
    v_des = up;
    limit_hit_ = true;
  }
  if (v_des < down) {
    v_des = down;
    limit_hit_ = true;
  }
  double v_new = std::clamp(v_des, v - a_limit * dt, v + a_limit * dt);
  // The limits win over the acceleration limit. With a constant step this never happens (the
  // braking above keeps the axis able to stop); it does when the axis is too fast for the
  // limit, e.g. after the limits were moved or the step grew while braking.
  if (v_new > up) {
    v_new = up;
    limit_hit_ = true;
  } else if (v_new < down) {
    v_new = down;
    limit_hit_ = true;
  }
  double p_new = p + v_new * dt;
  // Arriving on a limit, rounding may put the axis a hair beyond it: that is the limit.
  const double hair = 1e-9 * std::max(1.0, std::abs(v_new * dt));
  if (p_new > limits_.max_position && p_new - limits_.max_position <= hair) {
    p_new = limits_.max_position;
  } else if (p_new < limits_.min_position && limits_.min_position - p_new <= hair) {
    p_new = limits_.min_position;
  }
  // Too fast to stop in front of a limit: a hard stop on it (never a jump into the range).
  if (p_new > limits_.max_position && v_new > 0) {
    p_new = std::max(limits_.max_position, p);
    v_new = 0;
    limit_hit_ = true;
  } else if (p_new < limits_.min_position && v_new < 0) {
    p_new = std::min(limits_.min_position, p);
    v_new = 0;
    limit_hit_ = true;
  }
  state_.acceleration = (v_new - v) / dt;
  state_.velocity = v_new;
  state_.position = p_new;
}

}  // namespace kinevis::hal
