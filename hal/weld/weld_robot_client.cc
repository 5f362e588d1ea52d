#include "hal/weld/weld_robot_client.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

namespace wr = weld_robot;

class WeldRobotAlarmCategoryImpl : public std::error_category {
 public:
  const char* name() const noexcept override { return "kinevis.weld_robot_alarm"; }
  std::string message(int value) const override {
    return std::string(wr::AlarmName(static_cast<uint16_t>(value))) + " (weld robot alarm " +
           std::to_string(value) + ")";
  }
};

bool IsLinkFailure(std::error_code ec) { return ec == Errc::kTimeout || ec == Errc::kClosed; }

// SI -> register units, rounded; false when not finite or outside int32.
bool ToI32(double si, double units_per_si, int32_t* out) {
  if (!std::isfinite(si)) return false;
  const double units = std::round(si * units_per_si);
  if (units < std::numeric_limits<int32_t>::min() || units > std::numeric_limits<int32_t>::max()) {
    return false;
  }
  *out = static_cast<int32_t>(units);
  return true;
}

// SI -> unsigned 16-bit register units, rounded; false when not finite or out of 0..65535.
bool ToU16(double si, double units_per_si, uint16_t* out) {
  if (!std::isfinite(si)) return false;
  const double units = std::round(si * units_per_si);
  if (units < 0 || units > 65535) return false;
  *out = static_cast<uint16_t>(units);
  return true;
}

std::string Format(const char* format, double value) {
  char text[64];
  std::snprintf(text, sizeof text, format, value);
  return text;
}

// "12.5°" or "250.0 mm": a joint value for a human, in the units they think in.
std::string JointText(int joint, double si) {
  return wr::IsPrismatic(joint) ? Format("%.3f mm", si * 1e3) : Format("%.3f°", si * 180 / M_PI);
}

// One segment in register units.
struct Segment {
  std::array<int32_t, wr::kJointCount> joints{};
  uint16_t duration_ms = 0;
  uint16_t flags = 0;
};

}  // namespace

const std::error_category& WeldRobotAlarmCategory() {
  static const WeldRobotAlarmCategoryImpl category;
  return category;
}

std::error_code WeldRobotAlarmError(uint16_t code) { return {code, WeldRobotAlarmCategory()}; }

namespace weld_robot {
std::error_code make_error_code(Alarm alarm) {
  return WeldRobotAlarmError(static_cast<uint16_t>(alarm));
}
}  // namespace weld_robot

std::unique_ptr<WeldRobotClient> WeldRobotClient::Open(std::string_view backend, Options options) {
  return std::make_unique<WeldRobotClient>(ModbusClient::Open(backend), std::move(options));
}

WeldRobotClient::WeldRobotClient(std::unique_ptr<ModbusClient> modbus, Options options)
    : modbus_(std::move(modbus)),
      options_(std::move(options)),
      clock_(options_.clock != nullptr ? options_.clock : &common::SteadyClock::Instance()) {
  name_ = options_.name + " (" + modbus_->name() + ")";
  if (options_.poll_period.count() <= 0) {
    throw common::ConfigError(name_ + ": poll_period " +
                              std::to_string(options_.poll_period.count()) + " ms is not positive");
  }
}

WeldRobotClient::~WeldRobotClient() = default;

uint64_t WeldRobotClient::LinkInterruptions() const {
  const ModbusClientCounters c = modbus_->counters();
  return c.retries + c.reconnects;
}

std::error_code WeldRobotClient::Fail(std::error_code ec, const std::string& operation,
                                      const std::string& cause) {
  last_error_text_ = name_ + ": " + operation + ": " + cause;
  if (IsLinkFailure(ec)) {
    ++counters_.link_faults;
    if (lifecycle_ != common::DeviceLifecycle::kUnconfigured)
      lifecycle_ = common::DeviceLifecycle::kFault;
  }
  if (ec.category() == WeldRobotAlarmCategory() &&
      lifecycle_ != common::DeviceLifecycle::kUnconfigured) {
    lifecycle_ = common::DeviceLifecycle::kFault;
  }
  spdlog::error("{}", last_error_text_);
  return ec;
}

std::error_code WeldRobotClient::RequireActive(const char* operation) {
  if (lifecycle_ == common::DeviceLifecycle::kActive) return {};
  return Fail(Errc::kNotActive, operation,
              std::string("refused: the driver is ") + ToString(lifecycle_) + ", not active" +
                  (lifecycle_ == common::DeviceLifecycle::kFault ? " (AlarmReset() first)" : ""));
}

void WeldRobotClient::Configure() {
  uint16_t r[wr::kIdentityRegisters];
  if (std::error_code ec =
          modbus_->ReadInputRegisters(wr::kIdentityAddress, wr::kIdentityRegisters, r)) {
    throw HalError(name_, "configure: read the identity registers", modbus_->last_error_text(), ec);
  }
  std::string problems;
  auto problem = [&](const std::string& p) { problems += (problems.empty() ? "" : "; ") + p; };
  char magic[64];
  std::snprintf(magic, sizeof magic, "identity magic 0x%04x (expected 0x%04x)", r[wr::kRegMagic],
                wr::kIdentityMagic);
  if (r[wr::kRegMagic] != wr::kIdentityMagic) {
    // Anything else at address 0 means this is not a weld robot controller at all.
    throw HalError(name_, "configure", std::string(magic) + ": not a kinevis weld robot");
  }
  WeldRobotIdentity id;
  id.map_version = r[wr::kRegMapVersion];
  id.joint_count = r[wr::kRegJointCount];
  id.buffer_capacity = r[wr::kRegBufferCapacity];
  id.max_segment_duration = r[wr::kRegMaxSegmentDurationMs] / wr::kDurationUnitsPerSecond;
  id.serial_number = wr::GetU32(r + wr::kRegSerialNumber);
  id.max_current = r[wr::kRegMaxCurrent] / wr::kCurrentUnitsPerAmpere;
  id.max_voltage = r[wr::kRegMaxVoltage] / wr::kVoltageUnitsPerVolt;
  id.max_wire_feed_speed = r[wr::kRegMaxWireFeed] / wr::kWireFeedUnitsPerMetrePerSecond;
  if (id.map_version != wr::kMapVersion) {
    problem("register map version " + std::to_string(id.map_version) + " (this driver knows " +
            std::to_string(wr::kMapVersion) + ")");
  }
  if (id.joint_count != wr::kJointCount) {
    problem("joint count " + std::to_string(id.joint_count) + " (expected " +
            std::to_string(wr::kJointCount) + ")");
  }
  if (id.buffer_capacity < 1) problem("buffer capacity 0");
  if (r[wr::kRegMaxSegmentDurationMs] < wr::kMinSegmentDurationMs) {
    problem("longest segment duration 0 ms");
  }
  for (int j = 0; j < wr::kJointCount; ++j) {
    const uint16_t* p = r + wr::kRegJointLimits + wr::kJointLimitRegisters * j;
    WeldJointLimit& l = id.joints[static_cast<size_t>(j)];
    l.min = wr::GetI32(p + wr::kJointLimitMinOffset) / wr::kJointUnitsPerSi;
    l.max = wr::GetI32(p + wr::kJointLimitMaxOffset) / wr::kJointUnitsPerSi;
    l.max_speed = wr::GetU32(p + wr::kJointLimitSpeedOffset) / wr::kJointUnitsPerSi;
    if (!(l.min < l.max)) {
      problem(std::string("joint ") + wr::JointName(j) + " limits " + JointText(j, l.min) + " .. " +
              JointText(j, l.max) + " are empty");
    }
    if (!(l.max_speed > 0)) problem(std::string("joint ") + wr::JointName(j) + " speed limit 0");
  }
  if (!problems.empty()) throw HalError(name_, "configure", problems);
  identity_ = id;
  lifecycle_ = common::DeviceLifecycle::kConfigured;
  spdlog::info("{}: configured: serial number {}, map version {}, buffer of {} segments", name_,
               id.serial_number, id.map_version, id.buffer_capacity);
}

std::error_code WeldRobotClient::ReadStateRaw(WeldRobotState* state) {
  uint16_t r[wr::kStatusRegisters];
  if (std::error_code ec =
          modbus_->ReadInputRegisters(wr::kStatusAddress, wr::kStatusRegisters, r)) {
    return ec;
  }
  ++counters_.status_reads;
  auto at = [&](int address) { return r + (address - wr::kStatusAddress); };
  WeldRobotState s;
  s.motion_raw = *at(wr::kRegMotionState);
  s.motion = static_cast<wr::MotionState>(s.motion_raw);
  s.alarm_code = *at(wr::kRegAlarmCode);
  s.alarm_name = wr::AlarmName(s.alarm_code);
  s.buffer_level = *at(wr::kRegBufferLevel);
  s.buffer_capacity = s.buffer_level + *at(wr::kRegBufferFree);
  s.arc_enabled = *at(wr::kRegArcEnabled) != 0;
  s.arc_on = *at(wr::kRegArcOn) != 0;
  s.last_sequence = wr::GetU32(at(wr::kRegLastSequence));
  s.completed_sequence = wr::GetU32(at(wr::kRegCompletedSequence));
  s.alarm_sequence = wr::GetU32(at(wr::kRegAlarmSequence));
  for (int j = 0; j < wr::kJointCount; ++j) {
    s.joints[static_cast<size_t>(j)] =
        wr::GetI32(at(wr::kRegActualJoints + 2 * j)) / wr::kJointUnitsPerSi;
  }
  s.weld.current = *at(wr::kRegActualCurrent) / wr::kCurrentUnitsPerAmpere;
  s.weld.voltage = *at(wr::kRegActualVoltage) / wr::kVoltageUnitsPerVolt;
  s.weld.wire_feed_speed = *at(wr::kRegActualWireFeed) / wr::kWireFeedUnitsPerMetrePerSecond;
  // A robot reporting an alarm is in fault for the host too; each alarm is logged once.
  if (s.alarm_code != 0) {
    if (lifecycle_ != common::DeviceLifecycle::kUnconfigured)
      lifecycle_ = common::DeviceLifecycle::kFault;
    if (s.alarm_code != last_alarm_seen_) {
      ++counters_.alarms;
      spdlog::error("{}: alarm {} (code {}){}", name_, s.alarm_name, s.alarm_code,
                    s.alarm_sequence != 0
                        ? " raised by segment sequence " + std::to_string(s.alarm_sequence)
                        : std::string());
    }
  }
  last_alarm_seen_ = s.alarm_code;
  *state = s;
  return {};
}

std::error_code WeldRobotClient::ReadState(WeldRobotState* state) {
  if (lifecycle_ == common::DeviceLifecycle::kUnconfigured) {
    return Fail(Errc::kNotActive, "read state", "refused: Configure() first");
  }
  if (std::error_code ec = ReadStateRaw(state)) {
    return Fail(ec, "read state", modbus_->last_error_text());
  }
  return {};
}

std::error_code WeldRobotClient::SendCommand(wr::Command command) {
  return modbus_->WriteRegister(wr::kRegCommand, static_cast<uint16_t>(command));
}

std::error_code WeldRobotClient::ExplainRefusal(std::error_code ec, WeldRobotState* state) {
  if (!IsModbusException(ec)) return ec;
  if (!ReadStateRaw(state) && state->alarm()) return WeldRobotAlarmError(state->alarm_code);
  return ec;
}

std::error_code WeldRobotClient::Activate() {
  if (lifecycle_ == common::DeviceLifecycle::kActive) return {};
  if (lifecycle_ != common::DeviceLifecycle::kConfigured) {
    return Fail(Errc::kNotActive, "activate",
                std::string("refused: the driver is ") + ToString(lifecycle_) +
                    (lifecycle_ == common::DeviceLifecycle::kFault ? " (AlarmReset() first)"
                                                                   : " (Configure() first)"));
  }
  WeldRobotState s;
  if (std::error_code ec = ReadStateRaw(&s)) {
    return Fail(ec, "activate", modbus_->last_error_text());
  }
  if (s.alarm()) {
    return Fail(WeldRobotAlarmError(s.alarm_code), "activate",
                std::string("the robot reports alarm ") + s.alarm_name + " (code " +
                    std::to_string(s.alarm_code) + "); AlarmReset() first");
  }
  lifecycle_ = common::DeviceLifecycle::kActive;
  spdlog::info("{}: active", name_);
  return {};
}

std::error_code WeldRobotClient::SetWeldParameters(const WeldParameters& p) {
  if (std::error_code ec = RequireActive("set weld parameters")) return ec;
  uint16_t values[wr::kSetPointRegisters];
  std::string problems;
  auto check = [&](double value, double max, double units, const char* what, const char* unit,
                   uint16_t* out) {
    if (!(value >= 0 && value <= max) || !ToU16(value, units, out)) {
      problems += (problems.empty() ? "" : "; ") + std::string(what) + " " + Format("%g", value) +
                  " " + unit + " is not in 0.." + Format("%g", max);
    }
  };
  check(p.current, identity_.max_current, wr::kCurrentUnitsPerAmpere, "current", "A", &values[0]);
  check(p.voltage, identity_.max_voltage, wr::kVoltageUnitsPerVolt, "voltage", "V", &values[1]);
  check(p.wire_feed_speed, identity_.max_wire_feed_speed, wr::kWireFeedUnitsPerMetrePerSecond,
        "wire feed speed", "m/s", &values[2]);
  if (!problems.empty()) return Fail(Errc::kInvalidArgument, "set weld parameters", problems);
  if (std::error_code ec =
          modbus_->WriteRegisters(wr::kRegSetCurrent, wr::kSetPointRegisters, values)) {
    const std::string cause = modbus_->last_error_text();
    WeldRobotState s;
    return Fail(ExplainRefusal(ec, &s), "set weld parameters", cause);
  }
  spdlog::info("{}: weld set-points {:.1f} A, {:.1f} V, wire feed {:.4f} m/s", name_, p.current,
               p.voltage, p.wire_feed_speed);
  return {};
}

std::error_code WeldRobotClient::ArcOn() {
  if (std::error_code ec = RequireActive("arc on")) return ec;
  WeldRobotState s;
  if (std::error_code ec = ReadStateRaw(&s)) return Fail(ec, "arc on", modbus_->last_error_text());
  if (s.alarm()) {
    return Fail(WeldRobotAlarmError(s.alarm_code), "arc on",
                std::string("refused: alarm ") + s.alarm_name + " (code " +
                    std::to_string(s.alarm_code) + ") is active");
  }
  if (s.weld.current <= 0 || s.weld.voltage <= 0 || s.weld.wire_feed_speed <= 0) {
    return Fail(Errc::kInvalidArgument, "arc on",
                "refused by the interlock: a weld set-point is zero (current " +
                    Format("%g", s.weld.current) + " A, voltage " + Format("%g", s.weld.voltage) +
                    " V, wire feed " + Format("%g", s.weld.wire_feed_speed) +
                    " m/s); SetWeldParameters() first");
  }
  if (std::error_code ec = SendCommand(wr::Command::kArcOn)) {
    const std::string cause = modbus_->last_error_text();
    return Fail(ExplainRefusal(ec, &s), "arc on", cause);
  }
  spdlog::info("{}: arc enabled", name_);
  return {};
}

std::error_code WeldRobotClient::ArcOff() {
  if (lifecycle_ == common::DeviceLifecycle::kUnconfigured) {
    return Fail(Errc::kNotActive, "arc off", "refused: Configure() first");
  }
  if (std::error_code ec = SendCommand(wr::Command::kArcOff)) {
    return Fail(ec, "arc off", modbus_->last_error_text());
  }
  spdlog::info("{}: arc disabled", name_);
  return {};
}

std::error_code WeldRobotClient::Stop() {
  if (lifecycle_ == common::DeviceLifecycle::kUnconfigured) {
    return Fail(Errc::kNotActive, "stop", "refused: Configure() first");
  }
  if (std::error_code ec = SendCommand(wr::Command::kStop)) {
    return Fail(ec, "stop", modbus_->last_error_text());
  }
  WeldRobotState s;
  if (std::error_code ec = ReadStateRaw(&s)) {
    return Fail(ec, "stop: read back the state", modbus_->last_error_text());
  }
  if (!s.safe() || s.buffer_level != 0) {
    return Fail(Errc::kDeviceFault, "stop",
                std::string("the robot acknowledged STOP but reports motion ") +
                    wr::MotionStateName(s.motion_raw) + ", arc " + (s.arc_on ? "on" : "off") +
                    ", " + std::to_string(s.buffer_level) + " segment(s) buffered");
  }
  spdlog::info("{}: stopped (motion stopped, buffer cleared, arc off)", name_);
  return {};
}

std::error_code WeldRobotClient::AlarmReset() {
  if (lifecycle_ == common::DeviceLifecycle::kUnconfigured) {
    return Fail(Errc::kNotActive, "alarm reset", "refused: Configure() first");
  }
  if (std::error_code ec = SendCommand(wr::Command::kAlarmReset)) {
    return Fail(ec, "alarm reset", modbus_->last_error_text());
  }
  WeldRobotState s;
  if (std::error_code ec = ReadStateRaw(&s)) {
    return Fail(ec, "alarm reset: read back the state", modbus_->last_error_text());
  }
  if (s.alarm()) {
    return Fail(WeldRobotAlarmError(s.alarm_code), "alarm reset",
                std::string("the robot keeps alarm ") + s.alarm_name + " (code " +
                    std::to_string(s.alarm_code) + ")");
  }
  if (lifecycle_ == common::DeviceLifecycle::kFault) lifecycle_ = common::DeviceLifecycle::kActive;
  spdlog::info("{}: alarm reset; {}", name_, ToString(lifecycle_));
  return {};
}

bool WeldRobotClient::SafeStop() {
  ++counters_.safe_stops;
  if (SendCommand(wr::Command::kStop)) {
    spdlog::error("{}: STOP for the safe state failed: {}", name_, modbus_->last_error_text());
    return false;
  }
  WeldRobotState s;
  if (ReadStateRaw(&s)) {
    spdlog::error("{}: STOP sent, but the state could not be read back: {}", name_,
                  modbus_->last_error_text());
    return false;
  }
  const bool safe = s.safe() && s.buffer_level == 0;
  if (safe) {
    spdlog::warn("{}: safe state confirmed: motion {}, arc off, buffer empty", name_,
                 wr::MotionStateName(s.motion_raw));
  } else {
    spdlog::error("{}: STOP sent, but the robot reports motion {}, arc {}", name_,
                  wr::MotionStateName(s.motion_raw), s.arc_on ? "on" : "off");
  }
  return safe;
}

std::error_code WeldRobotClient::StreamTrajectory(const std::vector<WeldTrajectoryPoint>& points,
                                                  const WeldStreamProgressCallback& progress,
                                                  const std::atomic<bool>* cancel,
                                                  const WeldStreamOptions& options,
                                                  WeldStreamReport* report) {
  WeldStreamReport local;
  WeldStreamReport& rep = report != nullptr ? *report : local;
  rep = WeldStreamReport();
  rep.total = points.size();
  const common::Duration start = clock_->Now();
  auto finish = [&](std::error_code ec) {
    rep.elapsed = clock_->Now() - start;
    if (ec) rep.message = last_error_text_;
    return ec;
  };
  if (std::error_code ec = RequireActive("stream")) return finish(ec);

  // Convert and check everything before the first byte goes out.
  const int max_duration_ms =
      static_cast<int>(std::lround(identity_.max_segment_duration * wr::kDurationUnitsPerSecond));
  std::vector<Segment> segments(points.size());
  double total_duration = 0;
  for (size_t i = 0; i < points.size(); ++i) {
    const WeldTrajectoryPoint& p = points[i];
    Segment& s = segments[i];
    const std::string where = "segment " + std::to_string(i);
    const double ms = std::round(p.duration * wr::kDurationUnitsPerSecond);
    if (!std::isfinite(p.duration) || ms < wr::kMinSegmentDurationMs || ms > max_duration_ms) {
      return finish(Fail(Errc::kInvalidArgument, "stream",
                         where + ": duration " + Format("%g", p.duration) + " s is not in 0.001.." +
                             Format("%g", identity_.max_segment_duration) + " s"));
    }
    s.duration_ms = static_cast<uint16_t>(ms);
    s.flags = p.arc_on ? wr::kSegmentFlagArcOn : 0;
    total_duration += s.duration_ms / wr::kDurationUnitsPerSecond;
    for (int j = 0; j < wr::kJointCount; ++j) {
      const double q = p.joints[static_cast<size_t>(j)];
      const WeldJointLimit& l = identity_.joints[static_cast<size_t>(j)];
      int32_t& units = s.joints[static_cast<size_t>(j)];
      const bool bad = !ToI32(q, wr::kJointUnitsPerSi, &units) ||
                       (options.check_limits && (q < l.min || q > l.max));
      if (bad) {
        return finish(Fail(Errc::kInvalidArgument, "stream",
                           where + ": joint " + wr::JointName(j) + " target " +
                               (std::isfinite(q) ? JointText(j, q) : "not finite") +
                               " is outside its limits " + JointText(j, l.min) + " .. " +
                               JointText(j, l.max)));
      }
    }
  }
  if (points.empty()) return finish({});

  WeldRobotState state;
  if (std::error_code ec = ReadStateRaw(&state)) {
    return finish(Fail(ec, "stream", modbus_->last_error_text()));
  }
  if (state.alarm()) {
    return finish(Fail(WeldRobotAlarmError(state.alarm_code), "stream",
                       std::string("refused: alarm ") + state.alarm_name + " (code " +
                           std::to_string(state.alarm_code) + ") is active"));
  }
  if (options.check_limits) {
    // The robot's own rule, in its own integer units: |Δ| * 1000 <= speed * duration_ms. The
    // first segment starts where the robot stands, when it stands still with an empty buffer.
    const bool from_actual = state.motion == wr::MotionState::kIdle && state.buffer_level == 0;
    for (size_t i = from_actual ? 0 : 1; i < segments.size(); ++i) {
      for (int j = 0; j < wr::kJointCount; ++j) {
        const auto jj = static_cast<size_t>(j);
        int32_t from = 0;
        if (i == 0) {
          ToI32(state.joints[jj], wr::kJointUnitsPerSi, &from);
        } else {
          from = segments[i - 1].joints[jj];
        }
        const int64_t delta = std::abs(int64_t{segments[i].joints[jj]} - from);
        const int64_t speed = std::llround(identity_.joints[jj].max_speed * wr::kJointUnitsPerSi);
        if (delta * 1000 > speed * segments[i].duration_ms) {
          const double needed = delta / wr::kJointUnitsPerSi / (segments[i].duration_ms / 1e3);
          return finish(Fail(Errc::kInvalidArgument, "stream",
                             "segment " + std::to_string(i) + ": joint " + wr::JointName(j) +
                                 " would move at " + JointText(j, needed) +
                                 "/s, above its speed limit " +
                                 JointText(j, identity_.joints[jj].max_speed) + "/s"));
        }
      }
    }
  }

  const common::Duration deadline =
      start + (options.timeout.count() > 0
                   ? common::Duration(options.timeout)
                   : std::chrono::duration_cast<common::Duration>(
                         std::chrono::duration<double>(total_duration) + options.margin));
  const uint32_t base = state.last_sequence;  // segment i carries base + 1 + i
  const uint64_t interruptions_at_start = LinkInterruptions();
  const int capacity = identity_.buffer_capacity;
  size_t next = 0;

  // Every failure after this point ends here: the report, the message and the safe state.
  auto abort = [&](std::error_code ec, const std::string& cause) {
    Fail(ec, "stream",
         cause + "; " + std::to_string(rep.executed) + " of " + std::to_string(rep.total) +
             " segments executed");
    rep.safe_state_confirmed = SafeStop();
    last_error_text_ += rep.safe_state_confirmed ? "; robot stopped, arc off (safe state confirmed)"
                                                 : "; the safe state could NOT be confirmed";
    return finish(ec);
  };
  // `writing`: the segment whose write was refused, if the alarm came as that refusal.
  auto alarm_abort = [&](const WeldRobotState& s, size_t writing) {
    rep.alarm_code = s.alarm_code;
    std::string cause =
        std::string("alarm ") + s.alarm_name + " (code " + std::to_string(s.alarm_code) + ")";
    if (s.alarm_sequence != 0) {
      cause += " raised by sequence " + std::to_string(s.alarm_sequence);
      if (writing < rep.total && s.alarm_sequence == base + 1 + static_cast<uint32_t>(writing)) {
        cause += " (segment " + std::to_string(writing) + ")";
      } else {
        cause += " (not written by this stream)";
      }
    }
    return abort(WeldRobotAlarmError(s.alarm_code), cause);
  };
  constexpr size_t kNotWriting = std::numeric_limits<size_t>::max();
  auto link_abort = [&](std::error_code ec) {
    const std::string cause = "link failed: " + modbus_->last_error_text();
    return abort(ec, cause);
  };
  auto interrupted = [&] {
    return options.abort_on_link_interruption && LinkInterruptions() != interruptions_at_start;
  };
  auto interruption_abort = [&] {
    const ModbusClientCounters c = modbus_->counters();
    ++counters_.link_faults;
    return abort(Errc::kClosed,
                 "link interrupted (" + std::to_string(c.retries) + " retries, " +
                     std::to_string(c.reconnects) +
                     " reconnects so far); not welding on after a gap in supervision");
  };
  auto canceled = [&] { return cancel != nullptr && cancel->load(); };

  spdlog::info("{}: streaming {} segments ({:.3f} s), sequence {}..{}", name_, rep.total,
               total_duration, base + 1, base + static_cast<uint32_t>(rep.total));
  while (true) {
    if (canceled()) {
      last_error_text_ = name_ + ": stream: canceled after " + std::to_string(rep.executed) +
                         " of " + std::to_string(rep.total) + " segments executed";
      spdlog::warn("{}", last_error_text_);
      rep.safe_state_confirmed = SafeStop();
      return finish(std::make_error_code(std::errc::operation_canceled));
    }
    if (std::error_code ec = ReadStateRaw(&state)) return link_abort(ec);
    if (interrupted()) return interruption_abort();
    if (state.alarm()) return alarm_abort(state, kNotWriting);
    const uint32_t done = state.completed_sequence - base;
    if (done <= next) rep.executed = std::max<size_t>(rep.executed, done);
    rep.max_buffer_level = std::max(rep.max_buffer_level, state.buffer_level);
    if (progress) {
      WeldStreamProgress p;
      p.total = rep.total;
      p.sent = rep.sent;
      p.executed = rep.executed;
      p.buffer_level = state.buffer_level;
      p.buffer_capacity = capacity;
      p.joints = state.joints;
      p.arc_on = state.arc_on;
      progress(p);
    }
    if (rep.executed == rep.total) break;
    // Every segment sent and not completed must still be in the buffer (level and completed
    // sequence come from one consistent read). Fewer: the robot discarded some without an
    // alarm, i.e. someone else stopped it.
    const size_t pending = rep.sent - rep.executed;
    if (static_cast<size_t>(state.buffer_level) < pending) {
      return abort(Errc::kDeviceFault,
                   "the robot discarded " + std::to_string(pending - state.buffer_level) +
                       " buffered segment(s) (stopped by another master, or at the robot)");
    }
    int free_slots = capacity - state.buffer_level;
    if (next < segments.size() && free_slots <= 0) {
      ++rep.buffer_full_waits;
      ++counters_.buffer_full_waits;
    }
    int level = state.buffer_level;
    bool wrote = false;
    for (; free_slots > 0 && next < segments.size(); --free_slots) {
      if (canceled()) break;
      const Segment& s = segments[next];
      uint16_t r[wr::kSegmentRegisters];
      const uint32_t sequence = base + 1 + static_cast<uint32_t>(next);
      wr::PutU32(r + wr::kSegmentSequenceOffset, sequence);
      for (int j = 0; j < wr::kJointCount; ++j) {
        wr::PutI32(r + wr::kSegmentJointsOffset + 2 * j, s.joints[static_cast<size_t>(j)]);
      }
      r[wr::kSegmentDurationOffset] = s.duration_ms;
      r[wr::kSegmentFlagsOffset] = s.flags;
      if (std::error_code ec =
              modbus_->WriteRegisters(wr::kSegmentAddress, wr::kSegmentRegisters, r)) {
        if (IsLinkFailure(ec)) return link_abort(ec);
        const std::string cause = modbus_->last_error_text();
        WeldRobotState s2;
        std::error_code why = ExplainRefusal(ec, &s2);
        if (why.category() == WeldRobotAlarmCategory()) return alarm_abort(s2, next);
        return abort(ec, "segment " + std::to_string(next) + " refused: " + cause);
      }
      ++next;
      wrote = true;
      ++rep.sent;
      ++counters_.segments_sent;
      rep.max_buffer_level = std::max(rep.max_buffer_level, ++level);
      // Accepted, but only after a retry or a reconnect.
      if (interrupted()) return interruption_abort();
    }
    if (clock_->Now() > deadline) {
      return abort(Errc::kTimeout,
                   "not finished within " +
                       Format("%.3f", std::chrono::duration<double>(deadline - start).count()) +
                       " s");
    }
    // Wait only when nothing could be written (the buffer is full, or everything is sent and
    // the robot is still executing); after a write, read the level again at once.
    if (!wrote) clock_->SleepFor(options_.poll_period);
  }
  spdlog::info("{}: stream done: {} segments executed, highest buffer level {} of {}, {} waits",
               name_, rep.executed, rep.max_buffer_level, capacity, rep.buffer_full_waits);
  return finish({});
}

}  // namespace kinevis::hal
