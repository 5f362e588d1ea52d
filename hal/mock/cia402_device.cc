#include "hal/mock/cia402_device.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <sstream>
#include <utility>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using S = Cia402State;

// The modes this simulator implements, as 0x6502 bits.
constexpr uint32_t kImplementedModes = 0x38D;  // 1, 3, 4, 8, 9, 10
// Target-reached windows (0x6067 position window, 0x606D velocity window), fixed here.
constexpr double kPositionWindow = 10;  // counts
constexpr double kVelocityWindow = 10;  // counts/s
constexpr int16_t kTorqueWindow = 1;    // per mille
// A CSP set-point more than this after the previous one is a step, not a ramp to interpolate.
constexpr double kMaxInterpolationInterval = 0.1;  // s
// The feed-forward of the last set-point holds for this many of its intervals (the next
// set-point is expected within one; a lost one does not stop the axis abruptly).
constexpr double kFeedForwardHold = 1.5;
constexpr uint32_t kFollowingErrorDisabled = 0xFFFFFFFFu;

int32_t ToInt32(double x) {
  if (!std::isfinite(x)) return 0;
  const double r = std::round(x);
  return static_cast<int32_t>(std::clamp(r,
                                         static_cast<double>(std::numeric_limits<int32_t>::min()),
                                         static_cast<double>(std::numeric_limits<int32_t>::max())));
}

int16_t ToInt16(double x) {
  if (!std::isfinite(x)) return 0;
  const double r = std::round(x);
  return static_cast<int16_t>(std::clamp(r, -32768.0, 32767.0));
}

uint32_t ToUint32(double x) {
  if (!std::isfinite(x) || x <= 0) return 0;
  return static_cast<uint32_t>(std::min(std::round(x), 4294967295.0));
}

bool ModeSupported(uint32_t supported, int mode) {
  return DriveModeFromValue(mode).has_value() && ((supported >> (mode - 1)) & 1u) != 0;
}

bool PowerOff(S s) {
  return s != S::kOperationEnabled && s != S::kQuickStopActive && s != S::kFaultReactionActive;
}

}  // namespace

std::string Cia402Device::ValidateOptions(const Options& o) {
  std::ostringstream problems;
  auto problem = [&problems](const std::string& text) {
    if (problems.tellp() > 0) problems << "; ";
    problems << text;
  };
  const MotionLimits& l = o.limits;
  if (!(l.max_velocity > 0) || !std::isfinite(l.max_velocity)) {
    problem("limits.max_velocity " + std::to_string(l.max_velocity) + " must be > 0");
  }
  if (!(l.max_acceleration > 0) || !std::isfinite(l.max_acceleration)) {
    problem("limits.max_acceleration " + std::to_string(l.max_acceleration) + " must be > 0");
  }
  if (!(l.min_position <= l.max_position)) {
    problem("limits.min_position " + std::to_string(l.min_position) +
            " must be <= limits.max_position " + std::to_string(l.max_position));
  }
  if (!(l.inertia >= 0) || !std::isfinite(l.inertia)) {
    problem("limits.inertia " + std::to_string(l.inertia) + " must be >= 0");
  }
  if (!(l.rated_torque_per_mille > 0)) {
    problem("limits.rated_torque_per_mille " + std::to_string(l.rated_torque_per_mille) +
            " must be > 0");
  }
  if ((o.supported_modes & kImplementedModes) == 0) {
    problem("supported_modes 0x" + [&] {
      std::ostringstream h;
      h << std::hex << o.supported_modes;
      return h.str();
    }() + " names none of the modes 1, 3, 4, 8, 9, 10");
  }
  if (o.quick_stop_option_code < 0 || o.quick_stop_option_code > 8) {
    problem("quick_stop_option_code " + std::to_string(o.quick_stop_option_code) +
            " is outside 0..8");
  }
  if (!(o.fault_reaction_time_s >= 0) || !std::isfinite(o.fault_reaction_time_s)) {
    problem("fault_reaction_time_s " + std::to_string(o.fault_reaction_time_s) + " must be >= 0");
  }
  return problems.str();
}

Cia402Device::Cia402Device(Options options) : options_(options), model_(options.limits) {
  const std::string problems = ValidateOptions(options_);
  if (!problems.empty()) throw common::ConfigError("Cia402Device options: " + problems);
  options_.supported_modes &= kImplementedModes;
  std::lock_guard<std::mutex> lock(mutex_);
  ResetLocked();
}

void Cia402Device::ResetLocked() {
  MotionLimits limits = options_.limits;
  model_.SetLimits(limits);
  state_ = S::kNotReadyToSwitchOn;
  controlword_ = 0;
  mode_ = ModeSupported(options_.supported_modes, 8) ? 8 : 0;
  if (mode_ == 0) {
    for (int m : {1, 3, 9, 10, 4}) {
      if (ModeSupported(options_.supported_modes, m)) {
        mode_ = static_cast<int8_t>(m);
        break;
      }
    }
  }
  profile_velocity_ = ToUint32(limits.max_velocity);
  profile_acceleration_ = ToUint32(limits.max_acceleration);
  limit_min_ = ToInt32(limits.min_position);
  limit_max_ = ToInt32(limits.max_position);
  quick_stop_option_code_ = options_.quick_stop_option_code;
  following_error_window_ = options_.following_error_window;
  error_code_ = 0;
  fault_reaction_elapsed_s_ = 0;
  const AxisState& s = model_.state();
  target_position_ = ToInt32(s.position);
  target_velocity_ = 0;
  target_torque_ = 0;
  last_setpoint_time_s_ = -1;
  csp_from_ = csp_to_ = target_position_;
  csp_start_s_ = time_s_;
  csp_interval_s_ = 0;
  position_demand_ = s.position;
  pp_target_ = target_position_;
  setpoint_acknowledge_ = false;
  following_error_ = 0;
  following_error_flag_ = false;
  limit_active_ = false;
  if (!plant_) {
    position_actual_ = ToInt32(s.position);
    velocity_actual_ = ToInt32(s.velocity);
    torque_actual_ = ToInt16(s.torque);
  }
}

void Cia402Device::Reset() {
  std::lock_guard<std::mutex> lock(mutex_);
  ResetLocked();
}

std::optional<DriveMode> Cia402Device::ModeLocked() const { return DriveModeFromValue(mode_); }

void Cia402Device::TakeCallbacksLocked(std::vector<uint16_t>* out) {
  if (pending_callbacks_.empty() || !fault_callback_) {
    pending_callbacks_.clear();
    return;
  }
  out->swap(pending_callbacks_);
}

void Cia402Device::FireCallbacks(const std::vector<uint16_t>& codes) {
  if (codes.empty()) return;
  std::function<void(uint16_t)> callback;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    callback = fault_callback_;
  }
  if (!callback) return;
  for (uint16_t code : codes) callback(code);
}

void Cia402Device::ResetModeStateLocked() {
  const AxisState& s = model_.state();
  csp_from_ = csp_to_ = target_position_;
  csp_start_s_ = time_s_;
  csp_interval_s_ = 0;
  const auto mode = ModeLocked();
  position_demand_ = mode == DriveMode::kCyclicSynchronousPosition
                         ? std::clamp<double>(target_position_, limit_min_, limit_max_)
                         : s.position;
  pp_target_ = ToInt32(s.position);
  setpoint_acknowledge_ = false;
}

void Cia402Device::EnterLocked(Cia402State next) {
  if (next == state_) return;
  state_ = next;
  if (next == S::kOperationEnabled) ResetModeStateLocked();
  if (next == S::kFaultReactionActive) fault_reaction_elapsed_s_ = 0;
  if (next != S::kOperationEnabled) setpoint_acknowledge_ = false;
  // Bit 13 stays on through the fault reaction and the fault it caused, until a reset.
  if (next == S::kOperationEnabled || next == S::kSwitchOnDisabled) following_error_flag_ = false;
}

void Cia402Device::FaultLocked(uint16_t error_code) {
  if (state_ == S::kFaultReactionActive || state_ == S::kFault) return;
  error_code_ = error_code;
  EnterLocked(S::kFaultReactionActive);
}

void Cia402Device::ApplyCommandLocked(Cia402Command command) {
  if (command == Cia402Command::kFaultReset) {
    if (state_ == S::kFault) {
      EnterLocked(S::kSwitchOnDisabled);
      error_code_ = 0;
      pending_callbacks_.push_back(0);
    }
    return;
  }
  const bool quick_stop_to_disabled = quick_stop_option_code_ <= 4;
  EnterLocked(Cia402ApplyCommand(state_, command, quick_stop_to_disabled));
}

void Cia402Device::SetControlword(uint16_t cw) {
  std::vector<uint16_t> fire;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const uint16_t previous = controlword_;
    controlword_ = cw;
    ApplyCommandLocked(DecodeCia402Controlword(cw, previous));
    if (state_ == S::kOperationEnabled && ModeLocked() == DriveMode::kProfilePosition &&
        (cw & cia402::kCwNewSetPoint) != 0 && (previous & cia402::kCwNewSetPoint) == 0) {
      pp_target_ = target_position_;
      setpoint_acknowledge_ = true;
    }
    if ((cw & cia402::kCwNewSetPoint) == 0) setpoint_acknowledge_ = false;
    TakeCallbacksLocked(&fire);
  }
  FireCallbacks(fire);
}

bool Cia402Device::SetModeOfOperation(int8_t mode) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!ModeSupported(options_.supported_modes, mode)) return false;
  if (mode != mode_) {
    mode_ = mode;
    if (state_ == S::kOperationEnabled) ResetModeStateLocked();
  }
  return true;
}

void Cia402Device::SetTargetPosition(int32_t counts) {
  std::lock_guard<std::mutex> lock(mutex_);
  target_position_ = counts;
  const double now = time_s_;
  const bool first = last_setpoint_time_s_ < 0;
  const double interval = first ? 0.0 : now - last_setpoint_time_s_;
  last_setpoint_time_s_ = now;
  if (!first && interval <= 0) {
    // A second set-point within the same step (e.g. SDO and PDO): it corrects the end point of
    // the interpolation in progress.
    csp_to_ = counts;
  } else if (!first && interval <= kMaxInterpolationInterval) {
    csp_from_ = CspDemandLocked(now);
    csp_to_ = counts;
    csp_start_s_ = now;
    csp_interval_s_ = interval;
  } else {
    csp_from_ = csp_to_ = counts;
    csp_start_s_ = now;
    csp_interval_s_ = 0;
  }
}

void Cia402Device::SetTargetVelocity(int32_t counts_per_s) {
  std::lock_guard<std::mutex> lock(mutex_);
  target_velocity_ = counts_per_s;
}

void Cia402Device::SetTargetTorque(int16_t per_mille) {
  std::lock_guard<std::mutex> lock(mutex_);
  target_torque_ = per_mille;
}

void Cia402Device::SetProfile(uint32_t velocity, uint32_t acceleration) {
  std::lock_guard<std::mutex> lock(mutex_);
  profile_velocity_ = velocity;
  profile_acceleration_ = acceleration;
}

void Cia402Device::SetPositionLimits(int32_t min, int32_t max) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (min > max) return;
  limit_min_ = min;
  limit_max_ = max;
  MotionLimits limits = model_.limits();
  limits.min_position = min;
  limits.max_position = max;
  model_.SetLimits(limits);
}

bool Cia402Device::SetQuickStopOptionCode(int16_t code) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (code < 0 || code > 8) return false;
  quick_stop_option_code_ = code;
  return true;
}

void Cia402Device::SetFollowingErrorWindow(uint32_t counts) {
  std::lock_guard<std::mutex> lock(mutex_);
  following_error_window_ = counts;
}

bool Cia402Device::SetMaxVelocity(uint32_t counts_per_s) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (counts_per_s == 0) return false;
  MotionLimits limits = model_.limits();
  limits.max_velocity = counts_per_s;
  model_.SetLimits(limits);
  return true;
}

double Cia402Device::CspDemandLocked(double t) const {
  if (csp_interval_s_ <= 0) return csp_to_;
  const double fraction = (t - csp_start_s_) / csp_interval_s_;
  if (fraction >= 1) return csp_to_;
  if (fraction <= 0) return csp_from_;
  return csp_from_ + (csp_to_ - csp_from_) * fraction;
}

double Cia402Device::CspFeedForwardLocked(double t) const {
  if (csp_interval_s_ <= 0) return 0;
  if (t - csp_start_s_ > kFeedForwardHold * csp_interval_s_) return 0;
  return (csp_to_ - csp_from_) / csp_interval_s_;
}

void Cia402Device::StepMotionLocked(double dt, double t_end) {
  const auto mode = ModeLocked();
  const double amax = model_.limits().max_acceleration;
  if (!mode) {
    model_.Brake(dt, amax);
    position_demand_ = model_.state().position;
    return;
  }
  const bool profile_mode = *mode == DriveMode::kProfilePosition ||
                            *mode == DriveMode::kProfileVelocity ||
                            *mode == DriveMode::kProfileTorque;
  if (profile_mode && (controlword_ & cia402::kCwHalt) != 0) {
    model_.Brake(dt,
                 profile_acceleration_ > 0 ? std::min<double>(profile_acceleration_, amax) : amax);
    position_demand_ = model_.state().position;
    return;
  }
  switch (*mode) {
    case DriveMode::kCyclicSynchronousPosition: {
      const double demand = CspDemandLocked(t_end);
      model_.Step(dt, *mode, demand, CspFeedForwardLocked(t_end), 0, 0, 0);
      position_demand_ = std::clamp<double>(demand, limit_min_, limit_max_);
      return;
    }
    case DriveMode::kProfilePosition:
      model_.Step(dt, *mode, pp_target_, 0, 0, profile_velocity_, profile_acceleration_);
      break;
    case DriveMode::kProfileVelocity:
    case DriveMode::kCyclicSynchronousVelocity:
      model_.Step(dt, *mode, 0, target_velocity_, 0, profile_velocity_, profile_acceleration_);
      break;
    case DriveMode::kProfileTorque:
    case DriveMode::kCyclicSynchronousTorque:
      model_.Step(dt, *mode, 0, 0, target_torque_, profile_velocity_, profile_acceleration_);
      break;
  }
  position_demand_ = model_.state().position;
}

void Cia402Device::UpdateOutputsLocked(double dt) {
  const AxisState& s = model_.state();
  if (plant_) {
    if (dt > 0) {
      const PlantFeedback fb = plant_(s, dt);
      position_actual_ = fb.position;
      velocity_actual_ = fb.velocity;
      torque_actual_ = fb.torque;
    }
    if (PowerOff(state_)) {
      // Nothing drives the axis: the plant's motion is the truth, and enabling starts from it.
      AxisState actual;
      actual.position = position_actual_;
      actual.velocity = velocity_actual_;
      actual.torque = torque_actual_;
      model_.Reset(actual);
    }
  } else {
    position_actual_ = ToInt32(s.position);
    velocity_actual_ = ToInt32(s.velocity);
    torque_actual_ = ToInt16(s.torque);
  }
  const auto mode = ModeLocked();
  if (state_ == S::kOperationEnabled && mode && IsPositionMode(*mode)) {
    following_error_ = ToInt32(position_demand_ - position_actual_);
  } else {
    following_error_ = 0;
  }
  limit_active_ = model_.limit_hit();
}

void Cia402Device::Step(double dt) {
  std::vector<uint16_t> fire;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!(dt >= 0) || !std::isfinite(dt)) dt = 0;
    const double t_end = time_s_ + dt;
    const double amax = model_.limits().max_acceleration;
    if (state_ == S::kNotReadyToSwitchOn) EnterLocked(S::kSwitchOnDisabled);  // transition 1
    switch (state_) {
      case S::kOperationEnabled:
        StepMotionLocked(dt, t_end);
        break;
      case S::kQuickStopActive: {
        if (quick_stop_option_code_ == 0) {
          // "Disable drive function": no ramp, straight to Switch on disabled.
          EnterLocked(S::kSwitchOnDisabled);
          model_.Brake(dt, amax);
          break;
        }
        const bool slow_down = quick_stop_option_code_ == 1 || quick_stop_option_code_ == 5;
        const double ramp = slow_down && profile_acceleration_ > 0
                                ? std::min<double>(profile_acceleration_, amax)
                                : amax;
        model_.Brake(dt, ramp);
        break;
      }
      case S::kFaultReactionActive:
        model_.Brake(dt, amax);
        fault_reaction_elapsed_s_ += dt;
        break;
      default:
        model_.Brake(dt, amax);
        break;
    }
    time_s_ = t_end;
    UpdateOutputsLocked(dt);

    if (state_ == S::kQuickStopActive && quick_stop_option_code_ <= 4 &&
        model_.state().velocity == 0) {
      EnterLocked(S::kSwitchOnDisabled);  // transition 12, quick stop completed
    }
    if (state_ == S::kOperationEnabled) {
      const auto mode = ModeLocked();
      following_error_flag_ = false;
      if (mode && IsPositionMode(*mode) && following_error_window_ != kFollowingErrorDisabled &&
          static_cast<uint32_t>(std::abs(static_cast<int64_t>(following_error_))) >
              following_error_window_) {
        following_error_flag_ = true;
        FaultLocked(0x8611);
      } else if (mode && !IsPositionMode(*mode) && model_.limit_hit()) {
        FaultLocked(0x8612);
      }
    }
    if (state_ == S::kFaultReactionActive &&
        fault_reaction_elapsed_s_ >= options_.fault_reaction_time_s) {
      EnterLocked(S::kFault);  // transition 14
      pending_callbacks_.push_back(error_code_);
    }
    TakeCallbacksLocked(&fire);
  }
  FireCallbacks(fire);
}

uint16_t Cia402Device::StatuswordLocked() const {
  using namespace cia402;
  uint16_t sw = Cia402StatuswordBits(state_) | kSwRemote;
  const auto mode = ModeLocked();
  const double v = velocity_actual_;
  if (state_ == S::kOperationEnabled && mode) {
    const bool halted = (controlword_ & kCwHalt) != 0 &&
                        *mode != DriveMode::kCyclicSynchronousPosition &&
                        *mode != DriveMode::kCyclicSynchronousVelocity &&
                        *mode != DriveMode::kCyclicSynchronousTorque;
    bool reached = false;
    switch (*mode) {
      case DriveMode::kProfilePosition:
        if (setpoint_acknowledge_) sw |= kSwOpModeSpecific12;
        reached = std::abs(static_cast<double>(pp_target_) - position_actual_) <= kPositionWindow &&
                  std::abs(v) <= kVelocityWindow;
        break;
      case DriveMode::kCyclicSynchronousPosition:
        sw |= kSwOpModeSpecific12;
        reached =
            std::abs(static_cast<double>(target_position_) - position_actual_) <= kPositionWindow;
        break;
      case DriveMode::kProfileVelocity:
        if (std::abs(v) <= kVelocityWindow) sw |= kSwOpModeSpecific12;
        reached = std::abs(v - target_velocity_) <= kVelocityWindow;
        break;
      case DriveMode::kCyclicSynchronousVelocity:
        sw |= kSwOpModeSpecific12;
        reached = std::abs(v - target_velocity_) <= kVelocityWindow;
        break;
      case DriveMode::kCyclicSynchronousTorque:
        sw |= kSwOpModeSpecific12;
        reached = std::abs(torque_actual_ - target_torque_) <= kTorqueWindow;
        break;
      case DriveMode::kProfileTorque:
        reached = std::abs(torque_actual_ - target_torque_) <= kTorqueWindow;
        break;
    }
    if (halted) reached = std::abs(v) <= kVelocityWindow;
    if (reached) sw |= kSwTargetReached;
  }
  if (state_ == S::kQuickStopActive && std::abs(v) <= kVelocityWindow) sw |= kSwTargetReached;
  if (limit_active_) sw |= kSwInternalLimit;
  if (following_error_flag_) sw |= kSwFollowingError;
  return sw;
}

uint16_t Cia402Device::statusword() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return StatuswordLocked();
}

Cia402State Cia402Device::state() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return state_;
}

int8_t Cia402Device::mode_display() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return mode_;
}

int32_t Cia402Device::position() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return position_actual_;
}

int32_t Cia402Device::velocity() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return velocity_actual_;
}

int16_t Cia402Device::torque() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return torque_actual_;
}

int32_t Cia402Device::following_error() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return following_error_;
}

uint16_t Cia402Device::error_code() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return error_code_;
}

AxisState Cia402Device::commanded() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return model_.state();
}

Cia402Device::Snapshot Cia402Device::snapshot() const {
  std::lock_guard<std::mutex> lock(mutex_);
  Snapshot s;
  s.state = state_;
  s.statusword = StatuswordLocked();
  s.controlword = controlword_;
  s.mode = mode_;
  s.mode_display = mode_;
  s.position = position_actual_;
  s.velocity = velocity_actual_;
  s.torque = torque_actual_;
  s.following_error = following_error_;
  s.error_code = error_code_;
  s.target_position = target_position_;
  s.target_velocity = target_velocity_;
  s.target_torque = target_torque_;
  s.profile_velocity = profile_velocity_;
  s.profile_acceleration = profile_acceleration_;
  s.max_velocity = ToUint32(model_.limits().max_velocity);
  s.position_limit_min = limit_min_;
  s.position_limit_max = limit_max_;
  s.quick_stop_option_code = quick_stop_option_code_;
  s.following_error_window = following_error_window_;
  s.supported_modes = options_.supported_modes;
  return s;
}

void Cia402Device::RaiseFault(uint16_t error_code) {
  std::lock_guard<std::mutex> lock(mutex_);
  FaultLocked(error_code);
}

void Cia402Device::SetPlantHook(PlantHook hook) {
  std::lock_guard<std::mutex> lock(mutex_);
  plant_ = std::move(hook);
}

void Cia402Device::SetFaultCallback(std::function<void(uint16_t)> callback) {
  std::lock_guard<std::mutex> lock(mutex_);
  fault_callback_ = std::move(callback);
}

}  // namespace kinevis::hal
