#pragma once

// One axis of a drive as a simulator moves it: acceleration- and velocity-limited following of a
// position, velocity or torque set-point, position limits, and the trapezoidal profile
// generator of the profile modes. Units are the drive's (counts, counts/s, counts/s^2, per mille).
//
// Integration is semi-implicit Euler with the step dt: v' = v + a dt, p' = p + v' dt. Every
// step keeps |v'| <= the velocity limit in force and |v' - v| <= the acceleration limit in force
// times dt, with one exception: a position limit wins over the acceleration limit when the axis
// is too fast to stop in front of it (the limits were moved under a moving axis, or the step
// grew while it was braking), so that it never passes a limit.
//
// Position following (CSP, PP) is time-optimal within those limits and does not overshoot a
// fixed target: the velocity commanded for a step is the largest from which the axis can still
// stop on the target in whole steps of the acceleration limit (the discrete form of
// v = sqrt(2 a d)). Without velocity feed-forward this gives the trapezoidal (or triangular)
// profile of the profile position mode.

#include <cstdint>

#include "hal/drive/cia402.h"

namespace kinevis::hal {

struct MotionLimits {
  double max_velocity = 200000;       // counts/s, > 0
  double max_acceleration = 2000000;  // counts/s^2, > 0
  double min_position = -1e9;         // counts
  double max_position = 1e9;          // counts, >= min_position
  // CST/PT gain: counts/s^2 of acceleration per per mille of torque set-point (the inverse of
  // the inertia the motor sees, in drive units). The torque reported in the other modes is the
  // acceleration divided by it.
  double inertia = 1.0;
  double rated_torque_per_mille = 1000;  // torque limit, per mille of rated torque, > 0
};

struct AxisState {
  double position = 0;      // counts
  double velocity = 0;      // counts/s
  double acceleration = 0;  // counts/s^2 (of the last step)
  double torque = 0;        // per mille
};

class AxisMotionModel {
 public:
  explicit AxisMotionModel(MotionLimits limits);
  // Moves towards the set-point of `mode` for dt seconds and returns the new state. dt <= 0
  // (or not finite) changes nothing.
  //  CSP: position set-point followed within the velocity and acceleration limits;
  //       `velocity_setpoint` is the set-point's own velocity (feed-forward, 0 if unknown): the
  //       set-point is taken as the position to be at the end of this step and to continue from
  //       at that velocity.
  //  CSV: velocity set-point reached within the acceleration limit.
  //  CST, PT: torque -> acceleration through the inertia (limited to the acceleration limit and
  //       the torque to rated_torque_per_mille), velocity limited.
  //  PP/PV: trapezoidal profile with the profile velocity/acceleration (each capped by limits;
  //       a profile value <= 0 means no motion: the axis stops with the acceleration limit).
  // Position limits: motion stops at a limit (limit_hit() true): position targets outside the
  // limits are clamped to them, and motion towards a limit is braked (within the acceleration
  // limit in force) so that the axis stops on it.
  const AxisState& Step(double dt_s, DriveMode mode, double position_setpoint,
                        double velocity_setpoint, double torque_setpoint, double profile_velocity,
                        double profile_acceleration);
  // Quick stop / fault reaction: decelerate to standstill with `deceleration` (counts/s^2, > 0;
  // not capped by the acceleration limit: a quick stop ramp may be steeper than the profile).
  const AxisState& Brake(double dt_s, double deceleration);
  const AxisState& state() const;
  // True when a position limit constrained the last step (target clamped, motion braked or
  // stopped at the limit).
  bool limit_hit() const;
  // Sets the state (e.g. to a plant's actual values); clears limit_hit().
  void Reset(const AxisState& state);

  const MotionLimits& limits() const { return limits_; }
  // Replaces the limits (e.g. new software position limits); the state is kept.
  void SetLimits(const MotionLimits& limits) { limits_ = limits; }

 private:
  // Integrates one step towards v_des with the velocity and acceleration limits in force, brakes
  // in front of the position limits and stops at them.
  void Integrate(double dt, double v_des, double v_limit, double a_limit);

  MotionLimits limits_;
  AxisState state_;
  bool limit_hit_ = false;
};

// The largest speed (>= 0) at which an axis may move in a step of dt towards a point `distance`
// ahead (>= 0) so that it can still stop on it with deceleration `a` applied in whole steps of
// dt (semi-implicit Euler). Tends to sqrt(2 a d) for small dt; equals d / dt when one step
// suffices. Exposed for the tests.
double StoppingSpeed(double distance, double a, double dt);

}  // namespace kinevis::hal
