#include "hal/drive/cia402_can_drive.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "hal/canopen/canopen_master.h"
#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using S = Cia402State;
using namespace std::chrono_literals;

// Profile position: controlword bit 4 ("new set-point") stays set until the drive acknowledges
// with statusword bit 12, or at most this many cycles for a drive that never acknowledges.
constexpr int kPpMaxHoldCycles = 20;

bool IsFaultState(S s) { return s == S::kFault || s == S::kFaultReactionActive; }

std::string Hex(uint32_t value, int digits) {
  char text[16];
  std::snprintf(text, sizeof text, "0x%0*X", digits, value);
  return text;
}

std::string ErrorCodeText(uint16_t code) {
  return Hex(code, 4) + " (" + canopen::EmcyErrorText(code) + ")";
}

std::string Milliseconds(common::Duration d) {
  return std::to_string(std::chrono::duration_cast<std::chrono::milliseconds>(d).count()) + " ms";
}

// The command that keeps a drive in `goal` once it is there.
Cia402Command HoldCommand(S goal) {
  switch (goal) {
    case S::kOperationEnabled:
      return Cia402Command::kEnableOperation;
    case S::kSwitchedOn:
      return Cia402Command::kSwitchOn;
    case S::kReadyToSwitchOn:
      return Cia402Command::kShutdown;
    case S::kQuickStopActive:
      return Cia402Command::kQuickStop;
    default:
      return Cia402Command::kDisableVoltage;
  }
}

bool Finite(double v) { return std::isfinite(v); }

}  // namespace

std::string ValidateCia402DriveOptions(const Cia402DriveOptions& o) {
  std::string problems;
  auto problem = [&](const std::string& p) { problems += (problems.empty() ? "" : "; ") + p; };
  auto factor = [&](const char* field, double v) {
    if (!Finite(v) || v == 0.0)
      problem(std::string(field) + " " + std::to_string(v) + " must be finite and non-zero");
  };
  factor("scaling.position_counts_per_unit", o.scaling.position_counts_per_unit);
  factor("scaling.velocity_counts_per_unit", o.scaling.velocity_counts_per_unit);
  factor("scaling.torque_per_mille_per_unit", o.scaling.torque_per_mille_per_unit);
  const DriveLimits& l = o.limits;
  if (std::isnan(l.min_position) || std::isnan(l.max_position) || l.min_position > l.max_position) {
    problem("limits.min_position " + std::to_string(l.min_position) +
            " must not exceed limits.max_position " + std::to_string(l.max_position));
  }
  if (!(l.max_velocity > 0)) {
    problem("limits.max_velocity " + std::to_string(l.max_velocity) + " must be > 0");
  }
  if (!(l.max_torque > 0)) {
    problem("limits.max_torque " + std::to_string(l.max_torque) + " must be > 0");
  }
  auto non_negative = [&](const char* field, double v) {
    if (!Finite(v) || v < 0)
      problem(std::string(field) + " " + std::to_string(v) + " must be finite and >= 0");
  };
  non_negative("profile_velocity", o.profile_velocity);
  non_negative("profile_acceleration", o.profile_acceleration);
  non_negative("following_error_window", o.following_error_window);
  if (o.command_timeout.count() <= 0) {
    problem("command_timeout " + std::to_string(o.command_timeout.count()) + " ms must be > 0");
  }
  if (!DriveModeFromValue(static_cast<int>(o.mode))) {
    problem("mode " + std::to_string(static_cast<int>(o.mode)) +
            " is not one of 1, 3, 4, 8, 9, 10");
  }
  return problems;
}

std::string SupportedModesText(uint32_t modes) {
  std::string text;
  for (int bit = 0; bit < 32; ++bit) {
    if ((modes & (1u << bit)) == 0) continue;
    if (!text.empty()) text += ", ";
    auto mode = DriveModeFromValue(bit + 1);
    text += mode ? ToString(*mode) : "mode " + std::to_string(bit + 1);
  }
  return text.empty() ? "none" : text;
}

// =============================================================================================
// Cia402HostDrive

Cia402HostDrive::Cia402HostDrive(Cia402DriveOptions options, std::string name)
    : name_(std::move(name)), options_(std::move(options)), mode_(options_.mode) {}

void Cia402HostDrive::SetError(const std::string& cause, int level) {
  last_error_text_ = name_ + ": " + cause;
  spdlog::log(static_cast<spdlog::level::level_enum>(level), "{}", last_error_text_);
}

void Cia402HostDrive::SetConfigured(DriveIdentity identity) {
  identity_ = std::move(identity);
  lifecycle_ = common::DeviceLifecycle::kConfigured;
  goal_ = S::kSwitchOnDisabled;
  allow_fault_reset_ = false;
  fault_word_ = 0x00;
  state_known_ = false;
  fresh_ = false;
  link_lost_ = false;
  new_fault_ = false;
  pp_request_ = false;
  status_ = DriveStatus{};
  mode_ = options_.mode;
}

void Cia402HostDrive::SetUnconfigured() {
  lifecycle_ = common::DeviceLifecycle::kUnconfigured;
  goal_ = S::kSwitchOnDisabled;
  allow_fault_reset_ = false;
  state_known_ = false;
  fresh_ = false;
}

bool Cia402HostDrive::Supported(DriveMode mode) const {
  const int bit = static_cast<int>(mode) - 1;
  return bit >= 0 && bit < 32 && (identity_.supported_modes & (1u << bit)) != 0;
}

void Cia402HostDrive::HoldTargets() {
  target_position_ = actual_position_counts_;
  target_velocity_ = 0;
  target_torque_ = 0;
  pp_request_ = false;
}

std::error_code Cia402HostDrive::FaultError() const {
  return status_.fault_source == DriveFaultSource::kLink ? make_error_code(Errc::kTimeout)
                                                         : make_error_code(Errc::kDeviceFault);
}

void Cia402HostDrive::EnterFault(DriveFaultSource source, uint16_t error_code,
                                 const std::string& cause) {
  if (error_code != 0) status_.error_code = error_code;
  const bool already = lifecycle_ == common::DeviceLifecycle::kFault;
  lifecycle_ = common::DeviceLifecycle::kFault;
  if (!already) {
    status_.fault_source = source;
    // Link fault: the drive may still listen, so ask for a quick stop; device fault: the drive
    // has switched its power off, keep it off (and bit 7 low, ready for a reset edge).
    fault_word_ = source == DriveFaultSource::kLink
                      ? Cia402Controlword(Cia402Command::kQuickStop)
                      : Cia402Controlword(Cia402Command::kDisableVoltage);
    new_fault_ = true;
  }
  goal_ = S::kSwitchOnDisabled;
  allow_fault_reset_ = false;
  pp_request_ = false;
  SetError(cause, spdlog::level::err);
}

bool Cia402HostDrive::TakeNewFault() {
  const bool fault = new_fault_;
  new_fault_ = false;
  return fault;
}

void Cia402HostDrive::OnLinkLost(const std::string& cause) {
  link_lost_ = true;
  ++counters_.link_losses;
  if (lifecycle_ == common::DeviceLifecycle::kUnconfigured) {
    SetError("link lost: " + cause, spdlog::level::warn);
    return;
  }
  EnterFault(DriveFaultSource::kLink, 0, "link lost: " + cause);
}

void Cia402HostDrive::OnLinkRestored() {
  if (!link_lost_) return;
  link_lost_ = false;
  spdlog::info(
      "{}: link back{}", name_,
      lifecycle_ == common::DeviceLifecycle::kFault ? "; FaultReset() clears the fault" : "");
}

void Cia402HostDrive::OnDeviceFault(uint16_t error_code, const std::string& cause) {
  if (lifecycle_ == common::DeviceLifecycle::kUnconfigured) {
    SetError(cause, spdlog::level::warn);
    return;
  }
  EnterFault(DriveFaultSource::kDevice, error_code, cause);
}

void Cia402HostDrive::SafeStop(const std::string& reason) {
  if (lifecycle_ != common::DeviceLifecycle::kActive) return;
  lifecycle_ = common::DeviceLifecycle::kConfigured;
  goal_ = S::kQuickStopActive;
  pp_request_ = false;
  SetError("quick stop: " + reason, spdlog::level::warn);
}

uint16_t Cia402HostDrive::NextControlword() {
  using namespace cia402;
  if (forcing_) {
    if (forced_command_ != Cia402Command::kFaultReset) return Cia402Controlword(forced_command_);
    return (last_controlword_ & kCwFaultReset) != 0
               ? Cia402Controlword(Cia402Command::kDisableVoltage)
               : Cia402Controlword(Cia402Command::kFaultReset);
  }
  if (lifecycle_ == common::DeviceLifecycle::kFault && !allow_fault_reset_) return fault_word_;
  if (!state_known_) return Cia402Controlword(Cia402Command::kDisableVoltage);
  const S state = status_.state;
  if (state == S::kFault) {
    if (!allow_fault_reset_) return Cia402Controlword(Cia402Command::kDisableVoltage);
    // Fault reset acts on the rising edge of bit 7: a word with bit 7 clear, then one with it
    // set; repeated while the drive stays in Fault.
    return (last_controlword_ & kCwFaultReset) != 0
               ? Cia402Controlword(Cia402Command::kDisableVoltage)
               : Cia402Controlword(Cia402Command::kFaultReset);
  }
  if (state == S::kFaultReactionActive || state == S::kNotReadyToSwitchOn) {
    return Cia402Controlword(Cia402Command::kDisableVoltage);  // the drive moves on by itself
  }
  Cia402Command command = Cia402NextCommand(state, goal_);
  if (command == Cia402Command::kNone) command = HoldCommand(goal_);
  uint16_t cw = Cia402Controlword(command);
  if (state == S::kOperationEnabled && goal_ == S::kOperationEnabled &&
      mode_ == DriveMode::kProfilePosition) {
    // Profile position set-point handshake (CiA 402-2, 6.2.2): bit 4 rising edge hands over
    // the target; bit 5 makes it replace the running one at once.
    cw |= kCwChangeSetImmediately;
    bool bit4 = false;
    if ((last_controlword_ & kCwNewSetPoint) != 0) {
      const bool acknowledged = (status_.statusword & kSwOpModeSpecific12) != 0;
      bit4 = !(acknowledged || ++pp_hold_cycles_ >= kPpMaxHoldCycles || pp_request_);
    } else if (pp_request_) {
      bit4 = true;
      pp_request_ = false;
      pp_hold_cycles_ = 0;
    }
    if (bit4) cw |= kCwNewSetPoint;
  }
  return cw;
}

void Cia402HostDrive::ComposeOutputs(ProcessOutputs* out) {
  fresh_ = false;
  const bool enabled = state_known_ && status_.state == S::kOperationEnabled &&
                       goal_ == S::kOperationEnabled &&
                       lifecycle_ != common::DeviceLifecycle::kFault;
  // While not enabled the targets follow the drive, so that enabling a cyclic mode does not jump.
  if (!enabled) HoldTargets();
  last_controlword_ = NextControlword();
  out->controlword = last_controlword_;
  out->mode = static_cast<int8_t>(mode_);
  out->target_position = target_position_;
  out->target_velocity = target_velocity_;
  out->target_torque = target_torque_;
}

void Cia402HostDrive::ApplyInputs(const ProcessInputs& in, common::Duration timestamp,
                                  uint64_t cycle) {
  fresh_ = true;
  ++counters_.cycles;
  actual_position_counts_ = in.position;
  status_.statusword = in.statusword;
  status_.mode = DriveModeFromValue(in.mode_display);
  status_.position = in.position / options_.scaling.position_counts_per_unit;
  status_.velocity = in.velocity / options_.scaling.velocity_counts_per_unit;
  status_.torque = in.torque / options_.scaling.torque_per_mille_per_unit;
  // An EMCY may have brought the code before the drive's 0x603F shows it.
  if (in.error_code != 0 || lifecycle_ != common::DeviceLifecycle::kFault) {
    status_.error_code = in.error_code;
  }
  status_.target_reached = (in.statusword & cia402::kSwTargetReached) != 0;
  status_.following_error = status_.mode && IsPositionMode(*status_.mode) &&
                            (in.statusword & cia402::kSwFollowingError) != 0;
  status_.timestamp = timestamp;
  status_.cycle = cycle;

  const std::optional<S> state = DecodeCia402Statusword(in.statusword);
  if (!state) {
    ++counters_.protocol_errors;
    return;
  }
  status_.state = *state;
  state_known_ = true;
  if (allow_fault_reset_ && !IsFaultState(*state)) allow_fault_reset_ = false;  // reset done
  if (lifecycle_ == common::DeviceLifecycle::kUnconfigured ||
      lifecycle_ == common::DeviceLifecycle::kFault) {
    return;
  }
  if (IsFaultState(*state)) {
    if (!allow_fault_reset_) {
      EnterFault(DriveFaultSource::kDevice, in.error_code,
                 "drive fault: state '" + std::string(ToString(*state)) + "', error code " +
                     ErrorCodeText(in.error_code) +
                     (status_.following_error ? ", following error" : ""));
    }
    return;
  }
  if (lifecycle_ == common::DeviceLifecycle::kActive && *state != S::kOperationEnabled) {
    EnterFault(DriveFaultSource::kDevice, in.error_code,
               "the drive left 'Operation enabled' for '" + std::string(ToString(*state)) +
                   "' without a command from the host (statusword " + Hex(in.statusword, 4) + ")");
  }
}

// ---- Enable

std::error_code Cia402HostDrive::BeginEnable(bool reset_fault) {
  if (lifecycle_ == common::DeviceLifecycle::kUnconfigured) {
    SetError("enable refused: not configured", spdlog::level::warn);
    return Errc::kNotActive;
  }
  if (lifecycle_ == common::DeviceLifecycle::kFault) {
    if (!reset_fault) {
      SetError(
          "enable refused: the drive is in fault (" +
              std::string(status_.fault_source == DriveFaultSource::kLink ? "link" : "device") +
              ", error code " + ErrorCodeText(status_.error_code) + "); reset the fault first",
          spdlog::level::warn);
      return FaultError();
    }
    if (std::error_code ec = RestoreLink()) return ec;
    lifecycle_ = common::DeviceLifecycle::kConfigured;
    status_.fault_source = DriveFaultSource::kNone;
  }
  allow_fault_reset_ = reset_fault;
  goal_ = S::kOperationEnabled;
  return {};
}

bool Cia402HostDrive::EnableSettled() const {
  if (lifecycle_ == common::DeviceLifecycle::kFault ||
      lifecycle_ == common::DeviceLifecycle::kActive) {
    return true;
  }
  return fresh_ && status_.state == S::kOperationEnabled;
}

std::error_code Cia402HostDrive::FinishEnable(common::Duration started) {
  if (lifecycle_ == common::DeviceLifecycle::kActive) return {};
  if (lifecycle_ != common::DeviceLifecycle::kFault && fresh_ &&
      status_.state == S::kOperationEnabled && goal_ == S::kOperationEnabled) {
    lifecycle_ = common::DeviceLifecycle::kActive;
    allow_fault_reset_ = false;
    spdlog::info("{}: operation enabled, {}", name_, ToString(mode_));
    return {};
  }
  allow_fault_reset_ = false;
  goal_ = S::kSwitchOnDisabled;
  if (lifecycle_ == common::DeviceLifecycle::kFault) return FaultError();
  const std::string waited = Milliseconds(clock().Now() - started);
  if (state_known_ && IsFaultState(status_.state)) {
    EnterFault(DriveFaultSource::kDevice, status_.error_code,
               "enable failed after " + waited + ": the drive stays in '" +
                   ToString(status_.state) + "', error code " + ErrorCodeText(status_.error_code));
    return Errc::kDeviceFault;
  }
  SetError("enable timed out after " + waited + " in state '" +
               (state_known_ ? std::string(ToString(status_.state)) : "unknown (no data)") +
               "', controlword " + Hex(last_controlword_, 4) + (link_lost_ ? ", link lost" : ""),
           spdlog::level::warn);
  return Errc::kTimeout;
}

std::error_code Cia402HostDrive::Enable(std::chrono::milliseconds timeout, bool reset_fault) {
  if (lifecycle_ == common::DeviceLifecycle::kActive) return {};
  const common::Duration started = clock().Now();
  if (std::error_code ec = BeginEnable(reset_fault)) return ec;
  RunCyclesUntil(started + timeout, [this] { return EnableSettled(); });
  std::error_code ec = FinishEnable(started);
  // A failed enable leaves the drive with "disable voltage" (or the fault word) on the bus.
  if (ec) RunCyclesUntil(clock().Now(), [] { return true; });
  return ec;
}

// ---- Disable

std::error_code Cia402HostDrive::BeginDisable() {
  if (lifecycle_ == common::DeviceLifecycle::kUnconfigured) {
    SetError("disable refused: not configured", spdlog::level::warn);
    return Errc::kNotActive;
  }
  goal_ = S::kSwitchOnDisabled;
  allow_fault_reset_ = false;
  fault_word_ = Cia402Controlword(Cia402Command::kDisableVoltage);
  pp_request_ = false;
  if (lifecycle_ == common::DeviceLifecycle::kActive)
    lifecycle_ = common::DeviceLifecycle::kConfigured;
  return {};
}

bool Cia402HostDrive::DisableSettled() const {
  if (!fresh_) return false;
  const S s = status_.state;
  return s == S::kSwitchOnDisabled || s == S::kNotReadyToSwitchOn || IsFaultState(s);
}

std::error_code Cia402HostDrive::FinishDisable() {
  if (DisableSettled()) {
    spdlog::info("{}: disabled ('{}')", name_, ToString(status_.state));
    return {};
  }
  SetError("disable not confirmed within " + Milliseconds(options_.command_timeout) +
               " (last state '" +
               (state_known_ ? std::string(ToString(status_.state)) : "unknown") + "'" +
               (link_lost_ ? ", link lost" : "") + ")",
           spdlog::level::warn);
  return Errc::kTimeout;
}

std::error_code Cia402HostDrive::Disable() {
  if (std::error_code ec = BeginDisable()) return ec;
  RunCyclesUntil(clock().Now() + options_.command_timeout, [this] { return DisableSettled(); });
  return FinishDisable();
}

// ---- Quick stop

std::error_code Cia402HostDrive::BeginQuickStop() {
  if (lifecycle_ == common::DeviceLifecycle::kUnconfigured) {
    SetError("quick stop refused: not configured", spdlog::level::warn);
    return Errc::kNotActive;
  }
  goal_ = S::kQuickStopActive;
  allow_fault_reset_ = false;
  pp_request_ = false;
  if (lifecycle_ == common::DeviceLifecycle::kFault) {
    fault_word_ = Cia402Controlword(Cia402Command::kQuickStop);
  }
  if (lifecycle_ == common::DeviceLifecycle::kActive)
    lifecycle_ = common::DeviceLifecycle::kConfigured;
  return {};
}

bool Cia402HostDrive::QuickStopSettled() const {
  return fresh_ && status_.state != S::kOperationEnabled;
}

std::error_code Cia402HostDrive::FinishQuickStop() {
  if (QuickStopSettled()) {
    spdlog::info("{}: quick stop ('{}')", name_, ToString(status_.state));
    return {};
  }
  SetError("quick stop not confirmed within " + Milliseconds(options_.command_timeout) +
               (link_lost_ ? " (link lost)" : ""),
           spdlog::level::warn);
  return Errc::kTimeout;
}

std::error_code Cia402HostDrive::QuickStop() {
  if (std::error_code ec = BeginQuickStop()) return ec;
  RunCyclesUntil(clock().Now() + options_.command_timeout, [this] { return QuickStopSettled(); });
  return FinishQuickStop();
}

// ---- Fault reset

std::error_code Cia402HostDrive::BeginFaultReset(bool* nothing_to_do) {
  *nothing_to_do = false;
  if (lifecycle_ == common::DeviceLifecycle::kUnconfigured) {
    SetError("fault reset refused: not configured", spdlog::level::warn);
    return Errc::kNotActive;
  }
  if (lifecycle_ != common::DeviceLifecycle::kFault &&
      !(state_known_ && IsFaultState(status_.state))) {
    *nothing_to_do = true;
    return {};
  }
  if (std::error_code ec = RestoreLink()) return ec;
  allow_fault_reset_ = true;
  goal_ = S::kSwitchOnDisabled;
  if (lifecycle_ == common::DeviceLifecycle::kFault)
    lifecycle_ = common::DeviceLifecycle::kConfigured;
  status_.fault_source = DriveFaultSource::kNone;
  return {};
}

bool Cia402HostDrive::FaultResetSettled() const {
  return lifecycle_ == common::DeviceLifecycle::kFault || (fresh_ && !IsFaultState(status_.state));
}

std::error_code Cia402HostDrive::FinishFaultReset() {
  if (lifecycle_ == common::DeviceLifecycle::kFault) return FaultError();  // a new fault meanwhile
  if (fresh_ && !IsFaultState(status_.state)) {
    allow_fault_reset_ = false;
    spdlog::info("{}: fault reset, now '{}'", name_, ToString(status_.state));
    return {};
  }
  EnterFault(DriveFaultSource::kDevice, status_.error_code,
             "fault reset not accepted within " + Milliseconds(options_.command_timeout) +
                 ": still '" + (state_known_ ? std::string(ToString(status_.state)) : "unknown") +
                 "', error code " + ErrorCodeText(status_.error_code));
  return Errc::kDeviceFault;
}

std::error_code Cia402HostDrive::FaultReset() {
  bool nothing_to_do = false;
  if (std::error_code ec = BeginFaultReset(&nothing_to_do)) return ec;
  if (nothing_to_do) return {};
  RunCyclesUntil(clock().Now() + options_.command_timeout, [this] { return FaultResetSettled(); });
  return FinishFaultReset();
}

// ---- Bring-up: one command as it is

std::error_code Cia402HostDrive::SendCommand(Cia402Command command,
                                             std::chrono::milliseconds timeout,
                                             Cia402State* reached) {
  if (lifecycle_ == common::DeviceLifecycle::kUnconfigured) {
    SetError(std::string("command '") + ToString(command) + "' refused: not configured",
             spdlog::level::warn);
    return Errc::kNotActive;
  }
  const common::Duration started = clock().Now();
  if (!state_known_ || !fresh_) {
    RunCyclesUntil(started + timeout, [this] { return state_known_ && fresh_; });
  }
  if (!state_known_) {
    SetError(std::string("command '") + ToString(command) + "': the drive sends no state",
             spdlog::level::warn);
    return Errc::kTimeout;
  }
  const S from = status_.state;
  if (lifecycle_ == common::DeviceLifecycle::kActive)
    lifecycle_ = common::DeviceLifecycle::kConfigured;
  if (command == Cia402Command::kFaultReset) {
    allow_fault_reset_ = true;
    if (lifecycle_ == common::DeviceLifecycle::kFault) {
      lifecycle_ = common::DeviceLifecycle::kConfigured;
      status_.fault_source = DriveFaultSource::kNone;
    }
  }
  pp_request_ = false;
  forced_command_ = command;
  forcing_ = true;
  const bool changed = RunCyclesUntil(started + timeout, [this, from] {
    return lifecycle_ == common::DeviceLifecycle::kFault || (fresh_ && status_.state != from);
  });
  forcing_ = false;
  allow_fault_reset_ = false;
  const S now = status_.state;
  goal_ = IsFaultState(now) ? S::kSwitchOnDisabled : now;
  if (reached != nullptr) *reached = now;
  if (lifecycle_ == common::DeviceLifecycle::kFault) return FaultError();
  if (now == S::kOperationEnabled) lifecycle_ = common::DeviceLifecycle::kActive;
  if (!changed) {
    SetError(std::string("command '") + ToString(command) + "' left the drive in '" +
                 ToString(now) + "' for " + Milliseconds(clock().Now() - started),
             spdlog::level::info);
    return Errc::kTimeout;
  }
  spdlog::info("{}: '{}': '{}' -> '{}'", name_, ToString(command), ToString(from), ToString(now));
  return {};
}

// ---- Mode and targets (cyclic path: no I/O, no allocation)

std::error_code Cia402HostDrive::SetMode(DriveMode mode) {
  if (lifecycle_ != common::DeviceLifecycle::kConfigured &&
      lifecycle_ != common::DeviceLifecycle::kActive) {
    return Errc::kNotActive;
  }
  if (!DriveModeFromValue(static_cast<int>(mode))) return Errc::kInvalidArgument;
  if (!Supported(mode)) return Errc::kUnsupported;
  if (mode != mode_) {
    mode_ = mode;
    HoldTargets();
  }
  return {};
}

std::error_code Cia402HostDrive::CheckedCounts(double value, double scale, double lo, double hi,
                                               int64_t type_min, int64_t type_max,
                                               int64_t* counts) const {
  if (lifecycle_ != common::DeviceLifecycle::kActive) return Errc::kNotActive;
  if (!Finite(value) || value < lo || value > hi) return Errc::kInvalidArgument;
  const double c = std::round(value * scale);
  if (!(c >= static_cast<double>(type_min) && c <= static_cast<double>(type_max))) {
    return Errc::kInvalidArgument;
  }
  *counts = static_cast<int64_t>(c);
  return {};
}

std::error_code Cia402HostDrive::SetTargetPosition(double position) {
  int64_t counts = 0;
  const DriveLimits& l = options_.limits;
  if (std::error_code ec =
          CheckedCounts(position, options_.scaling.position_counts_per_unit, l.min_position,
                        l.max_position, INT32_MIN, INT32_MAX, &counts)) {
    return ec;
  }
  target_position_ = static_cast<int32_t>(counts);
  if (mode_ == DriveMode::kProfilePosition) pp_request_ = true;
  return {};
}

std::error_code Cia402HostDrive::SetTargetVelocity(double velocity) {
  int64_t counts = 0;
  const double v = options_.limits.max_velocity;
  if (std::error_code ec = CheckedCounts(velocity, options_.scaling.velocity_counts_per_unit, -v, v,
                                         INT32_MIN, INT32_MAX, &counts)) {
    return ec;
  }
  target_velocity_ = static_cast<int32_t>(counts);
  return {};
}

std::error_code Cia402HostDrive::SetTargetTorque(double torque) {
  int64_t counts = 0;
  const double t = options_.limits.max_torque;
  if (std::error_code ec = CheckedCounts(torque, options_.scaling.torque_per_mille_per_unit, -t, t,
                                         INT16_MIN, INT16_MAX, &counts)) {
    return ec;
  }
  target_torque_ = static_cast<int16_t>(counts);
  return {};
}

// =============================================================================================
// Cia402CanDrive

Cia402CanDrive::Cia402CanDrive(canopen::CanopenMaster* master, Cia402CanDriveConfig config,
                               std::string name)
    : Cia402HostDrive(config.drive, name),
      master_(master),
      config_(std::move(config)),
      consumer_time_(config_.heartbeat_consumer.count() > 0 ? config_.heartbeat_consumer
                                                            : 3 * config_.heartbeat_producer),
      sdo_(&master->bus(), config_.node, &master->clock(), std::move(name), master->options().sdo) {
  sdo_.set_frame_source(master_);
}

Cia402CanDrive::~Cia402CanDrive() = default;

common::Clock& Cia402CanDrive::clock() const { return master_->clock(); }

bool Cia402CanDrive::RunCyclesUntil(common::Duration deadline, const std::function<bool()>& done) {
  return master_->RunCyclesUntil(deadline, done);
}

void Cia402CanDrive::ThrowSdoFailure(const std::string& step, std::error_code ec) {
  pdo_active_ = false;
  heartbeat_supervised_ = false;
  SetUnconfigured();
  SetError("configure: " + step + ": " + sdo_.last_error_cause(), spdlog::level::err);
  throw HalError(name(), "configure: " + step, sdo_.last_error_cause(), ec);
}

template <typename T>
void Cia402CanDrive::Write(uint16_t index, uint8_t subindex, T value, const char* what) {
  if (std::error_code ec = sdo_.DownloadValue<T>(index, subindex, value)) {
    char where[16];
    std::snprintf(where, sizeof where, " 0x%04X:%02X", index, subindex);
    ThrowSdoFailure(std::string(what) + where, ec);
  }
}

template <typename T>
bool Cia402CanDrive::Read(uint16_t index, uint8_t subindex, T* value, const char* what,
                          bool optional) {
  std::error_code ec = sdo_.UploadValue<T>(index, subindex, value);
  if (!ec) return true;
  if (optional && canopen::SdoAbortCode(ec) != 0) {
    spdlog::debug("{}: {} not available: {}", name(), what, sdo_.last_error_cause());
    return false;
  }
  char where[16];
  std::snprintf(where, sizeof where, " 0x%04X:%02X", index, subindex);
  ThrowSdoFailure(std::string(what) + where, ec);
}

void Cia402CanDrive::MapPdo(uint16_t communication, uint16_t mapping, uint32_t cob_id,
                            const canopen::PdoMappingEntry* entries, int count, const char* what) {
  // CiA 301, 7.5.2.35: invalidate the PDO, clear the mapping, write the entries, set the
  // number of entries, then the transmission type, and validate the PDO again.
  const std::string pdo(what);
  Write<uint32_t>(communication, 1, cob_id | canopen::kPdoCobIdInvalid,
                  (pdo + ": invalidate").c_str());
  Write<uint8_t>(mapping, 0, 0, (pdo + ": clear mapping").c_str());
  for (int i = 0; i < count; ++i) {
    Write<uint32_t>(mapping, static_cast<uint8_t>(i + 1), entries[i].Encode(),
                    (pdo + ": map entry").c_str());
  }
  Write<uint8_t>(mapping, 0, static_cast<uint8_t>(count), (pdo + ": set entry count").c_str());
  Write<uint8_t>(communication, 2, canopen::kTransmissionSynchronous,
                 (pdo + ": set transmission type").c_str());
  Write<uint32_t>(communication, 1, cob_id, (pdo + ": validate").c_str());
}

void Cia402CanDrive::DisablePdo(uint16_t communication, uint32_t cob_id, const char* what) {
  std::error_code ec =
      sdo_.DownloadValue<uint32_t>(communication, 1, cob_id | canopen::kPdoCobIdInvalid);
  if (!ec) return;
  const uint32_t abort = canopen::SdoAbortCode(ec);
  if (abort == canopen::sdo_abort::kObjectDoesNotExist ||
      abort == canopen::sdo_abort::kSubindexDoesNotExist) {
    return;  // the drive does not have that PDO at all
  }
  char where[16];
  std::snprintf(where, sizeof where, " 0x%04X:01", communication);
  ThrowSdoFailure(std::string(what) + ": invalidate" + where, ec);
}

void Cia402CanDrive::Configure() {
  using namespace canopen;
  pdo_active_ = false;
  heartbeat_supervised_ = false;
  needs_configure_ = false;
  SetUnconfigured();
  const uint8_t node = config_.node;
  if (std::error_code ec = master_->SendNmt(NmtCommand::kEnterPreOperational, node)) {
    SetError("configure: NMT enter pre-operational: " + ec.message(), spdlog::level::err);
    throw HalError(name(), "configure: NMT enter pre-operational", ec.message(), ec);
  }

  DriveIdentity id;
  Read<uint32_t>(kDeviceType, 0, &id.device_type, "read device type", false);
  if ((id.device_type & 0xFFFF) != 402) {
    spdlog::warn("{}: device type {} does not announce the CiA 402 profile", name(),
                 Hex(id.device_type, 8));
  }
  Read<uint32_t>(kIdentity, 1, &id.vendor_id, "read vendor id", false);
  Read<uint32_t>(kIdentity, 2, &id.product_code, "read product code", true);
  Read<uint32_t>(kIdentity, 3, &id.revision, "read revision number", true);
  Read<uint32_t>(kIdentity, 4, &id.serial_number, "read serial number", true);
  std::string device_name;
  if (std::error_code ec = sdo_.UploadString(0x1008, 0, &device_name)) {
    if (SdoAbortCode(ec) == 0) ThrowSdoFailure("read device name 0x1008:00", ec);
  } else {
    id.device_name = device_name;
  }
  Read<uint32_t>(cia402::kSupportedDriveModes, 0, &id.supported_modes, "read supported drive modes",
                 false);
  const int mode_bit = static_cast<int>(options().mode) - 1;
  if ((id.supported_modes & (1u << mode_bit)) == 0) {
    const std::string cause = std::string("mode ") + ToString(options().mode) +
                              " is not supported (0x6502 = " + Hex(id.supported_modes, 8) + ": " +
                              SupportedModesText(id.supported_modes) + ")";
    SetError("configure: " + cause, spdlog::level::err);
    throw HalError(name(), "configure: check modes", cause);
  }

  static constexpr PdoMappingEntry kRpdo1[] = {{cia402::kControlword, 0, 16},
                                               {cia402::kModesOfOperation, 0, 8},
                                               {cia402::kTargetPosition, 0, 32}};
  static constexpr PdoMappingEntry kRpdo2[] = {{cia402::kTargetVelocity, 0, 32},
                                               {cia402::kTargetTorque, 0, 16}};
  static constexpr PdoMappingEntry kTpdo1[] = {{cia402::kStatusword, 0, 16},
                                               {cia402::kModesOfOperationDisplay, 0, 8},
                                               {cia402::kPositionActualValue, 0, 32}};
  static constexpr PdoMappingEntry kTpdo2[] = {{cia402::kVelocityActualValue, 0, 32},
                                               {cia402::kTorqueActualValue, 0, 16},
                                               {cia402::kErrorCode, 0, 16}};
  MapPdo(kRpdoCommunication + 0, kRpdoMapping + 0, kRpdoBase[0] + node, kRpdo1, 3, "RPDO1");
  MapPdo(kRpdoCommunication + 1, kRpdoMapping + 1, kRpdoBase[1] + node, kRpdo2, 2, "RPDO2");
  DisablePdo(kRpdoCommunication + 2, kRpdoBase[2] + node, "RPDO3");
  DisablePdo(kRpdoCommunication + 3, kRpdoBase[3] + node, "RPDO4");
  MapPdo(kTpdoCommunication + 0, kTpdoMapping + 0, kTpdoBase[0] + node, kTpdo1, 3, "TPDO1");
  MapPdo(kTpdoCommunication + 1, kTpdoMapping + 1, kTpdoBase[1] + node, kTpdo2, 3, "TPDO2");
  DisablePdo(kTpdoCommunication + 2, kTpdoBase[2] + node, "TPDO3");
  DisablePdo(kTpdoCommunication + 3, kTpdoBase[3] + node, "TPDO4");

  Write<int8_t>(cia402::kModesOfOperation, 0, static_cast<int8_t>(options().mode),
                "write modes of operation");
  const DriveScaling& sc = options().scaling;
  auto u32 = [](double v) {
    return static_cast<uint32_t>(std::min(std::round(std::fabs(v)), 4294967295.0));
  };
  auto i32 = [](double v) {
    return static_cast<int32_t>(std::clamp(std::round(v), -2147483648.0, 2147483647.0));
  };
  if (options().profile_velocity > 0) {
    Write<uint32_t>(cia402::kProfileVelocity, 0,
                    u32(options().profile_velocity * sc.velocity_counts_per_unit),
                    "write profile velocity");
  }
  if (options().profile_acceleration > 0) {
    Write<uint32_t>(cia402::kProfileAcceleration, 0,
                    u32(options().profile_acceleration * sc.velocity_counts_per_unit),
                    "write profile acceleration");
  }
  if (options().following_error_window > 0) {
    Write<uint32_t>(cia402::kFollowingErrorWindow, 0,
                    u32(options().following_error_window * sc.position_counts_per_unit),
                    "write following error window");
  }
  const DriveLimits& l = options().limits;
  if (std::isfinite(l.min_position) && std::isfinite(l.max_position)) {
    // Counts may be in reverse order when the scale is negative.
    const int32_t a = i32(l.min_position * sc.position_counts_per_unit);
    const int32_t b = i32(l.max_position * sc.position_counts_per_unit);
    Write<int32_t>(cia402::kSoftwarePositionLimit, 1, std::min(a, b),
                   "write software position limit (min)");
    Write<int32_t>(cia402::kSoftwarePositionLimit, 2, std::max(a, b),
                   "write software position limit (max)");
  }
  Write<uint16_t>(kProducerHeartbeatTime, 0,
                  static_cast<uint16_t>(config_.heartbeat_producer.count()),
                  "write producer heartbeat time");

  if (std::error_code ec = master_->SendNmt(NmtCommand::kStart, node)) {
    SetError("configure: NMT start: " + ec.message(), spdlog::level::err);
    throw HalError(name(), "configure: NMT start", ec.message(), ec);
  }
  SetConfigured(std::move(id));
  pdo_active_ = true;
  tpdo_mask_ = 0;
  heartbeat_supervised_ = config_.heartbeat_producer.count() > 0;
  heartbeat_lost_ = false;
  seen_operational_ = false;
  last_heartbeat_ = clock().Now();
  const common::Duration started = clock().Now();
  if (!RunCyclesUntil(started + options().command_timeout, [this] { return inputs_fresh(); })) {
    pdo_active_ = false;
    heartbeat_supervised_ = false;
    SetUnconfigured();
    const std::string cause =
        "no TPDO within " + Milliseconds(options().command_timeout) + " after NMT start";
    SetError("configure: " + cause, spdlog::level::err);
    throw HalError(name(), "configure: first process data", cause, Errc::kTimeout);
  }
  spdlog::info(
      "{}: configured: vendor {}, product {}, revision {}, serial {}{}, modes: {}; heartbeat {} "
      "ms (consumer {} ms); state '{}'",
      name(), Hex(identity_.vendor_id, 8), Hex(identity_.product_code, 8),
      Hex(identity_.revision, 8), identity_.serial_number,
      identity_.device_name.empty() ? "" : ", \"" + identity_.device_name + "\"",
      SupportedModesText(identity_.supported_modes), config_.heartbeat_producer.count(),
      consumer_time_.count(), ToString(status().state));
}

std::error_code Cia402CanDrive::RestoreLink() {
  using canopen::NmtState;
  if (needs_configure_) {
    pdo_active_ = false;
    heartbeat_supervised_ = false;
    SetUnconfigured();
    SetError("the node rebooted and lost its configuration; Configure() it again",
             spdlog::level::err);
    return Errc::kNotActive;
  }
  if (heartbeat_lost_) {
    SetError("cannot reset: no heartbeat from the node (consumer time " +
                 std::to_string(consumer_time_.count()) + " ms)",
             spdlog::level::warn);
    return Errc::kTimeout;
  }
  if (nmt_state_ && *nmt_state_ != NmtState::kOperational) {
    seen_operational_ = false;
    if (std::error_code ec = master_->SendNmt(canopen::NmtCommand::kStart, config_.node)) {
      SetError("cannot reset: NMT start: " + ec.message(), spdlog::level::warn);
      return ec;
    }
    const bool started = RunCyclesUntil(clock().Now() + options().command_timeout, [this] {
      return nmt_state_ == NmtState::kOperational && inputs_fresh();
    });
    if (!started) {
      SetError("cannot reset: the node did not become operational after NMT start",
               spdlog::level::warn);
      return Errc::kTimeout;
    }
  }
  OnLinkRestored();
  return {};
}

void Cia402CanDrive::EncodeRpdos(CanFrame* rpdo1, CanFrame* rpdo2) {
  ProcessOutputs o;
  ComposeOutputs(&o);
  tpdo_mask_ = 0;
  rpdo1->id = canopen::kRpdoBase[0] + config_.node;
  rpdo1->extended = false;
  rpdo1->rtr = false;
  rpdo1->dlc = 7;
  canopen::PutLe(&rpdo1->data[0], o.controlword, 2);
  rpdo1->data[2] = static_cast<uint8_t>(o.mode);
  canopen::PutLe(&rpdo1->data[3], static_cast<uint32_t>(o.target_position), 4);
  rpdo2->id = canopen::kRpdoBase[1] + config_.node;
  rpdo2->extended = false;
  rpdo2->rtr = false;
  rpdo2->dlc = 6;
  canopen::PutLe(&rpdo2->data[0], static_cast<uint32_t>(o.target_velocity), 4);
  canopen::PutLe(&rpdo2->data[4], static_cast<uint16_t>(o.target_torque), 2);
}

bool Cia402CanDrive::OnTpdo(int pdo, const CanFrame& f) {
  if (pdo == 0) {
    if (f.dlc < 7) return false;
    inputs_.statusword = static_cast<uint16_t>(canopen::GetLe(&f.data[0], 2));
    inputs_.mode_display = static_cast<int8_t>(f.data[2]);
    inputs_.position = static_cast<int32_t>(canopen::GetLe(&f.data[3], 4));
  } else {
    if (f.dlc < 8) return false;
    inputs_.velocity = static_cast<int32_t>(canopen::GetLe(&f.data[0], 4));
    inputs_.torque = static_cast<int16_t>(canopen::GetLe(&f.data[4], 2));
    inputs_.error_code = static_cast<uint16_t>(canopen::GetLe(&f.data[6], 2));
  }
  tpdo_mask_ |= static_cast<uint8_t>(1u << pdo);
  return true;
}

void Cia402CanDrive::OnHeartbeat(canopen::NmtState state, common::Duration now) {
  using canopen::NmtState;
  nmt_state_ = state;
  last_heartbeat_ = now;
  heartbeat_lost_ = false;
  if (state == NmtState::kBootUp) {
    if (lifecycle() != common::DeviceLifecycle::kUnconfigured && !needs_configure_) {
      needs_configure_ = true;
      pdo_active_ = false;
      OnLinkLost("the node rebooted (boot-up message); its configuration is lost");
    }
    return;
  }
  if (needs_configure_ || lifecycle() == common::DeviceLifecycle::kUnconfigured) return;
  if (state == NmtState::kOperational) {
    seen_operational_ = true;
    if (link_lost()) OnLinkRestored();
  } else if (!link_lost() && pdo_active_ && seen_operational_) {
    OnLinkLost(std::string("the node left Operational: NMT state '") + canopen::ToString(state) +
               "'");
  }
}

void Cia402CanDrive::OnEmergency(const canopen::EmcyMessage& emcy) {
  ++counters_.emergencies;
  char registers[8];
  std::snprintf(registers, sizeof registers, "0x%02X", emcy.error_register);
  if (emcy.error_code == 0) {
    spdlog::info("{}: EMCY error reset (error register {})", name(), registers);
    return;
  }
  OnDeviceFault(emcy.error_code,
                "EMCY " + ErrorCodeText(emcy.error_code) + ", error register " + registers);
}

bool Cia402CanDrive::SuperviseHeartbeat(common::Duration now) {
  if (!heartbeat_supervised_ || heartbeat_lost_ || needs_configure_) return false;
  const common::Duration silent = now - last_heartbeat_;
  if (silent <= consumer_time_) return false;
  heartbeat_lost_ = true;
  const std::string cause = "heartbeat lost: none for " + Milliseconds(silent) +
                            " (consumer time " + std::to_string(consumer_time_.count()) + " ms)";
  if (link_lost()) {
    SetError(cause, spdlog::level::warn);
  } else {
    OnLinkLost(cause);
  }
  return true;
}

}  // namespace kinevis::hal
