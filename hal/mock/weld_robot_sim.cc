#include "hal/mock/weld_robot_sim.h"

#include <pthread.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>

#include "common/units.h"
#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

namespace wr = weld_robot;

constexpr size_t kCompletedLogSize = 100000;
constexpr int64_t kNsPerMs = 1'000'000;

int32_t JointUnits(double si) {
  return static_cast<int32_t>(std::llround(si * wr::kJointUnitsPerSi));
}

}  // namespace

std::array<WeldRobotSim::JointLimit, wr::kJointCount> WeldRobotSim::DefaultJointLimits() {
  return {{{-170 * common::kDeg, 170 * common::kDeg, 90 * common::kDeg},
           {-120 * common::kDeg, 120 * common::kDeg, 90 * common::kDeg},
           {0.0, 0.500, 0.050},
           {-180 * common::kDeg, 180 * common::kDeg, 90 * common::kDeg},
           {-120 * common::kDeg, 120 * common::kDeg, 90 * common::kDeg}}};
}

WeldRobotSim::WeldRobotSim(const Options& options, std::unique_ptr<PtyPair> pty)
    : options_(options),
      clock_(options.clock != nullptr ? options.clock : &common::SteadyClock::Instance()),
      pty_(std::move(pty)) {
  std::string problems;
  auto problem = [&](const std::string& p) { problems += (problems.empty() ? "" : "; ") + p; };
  auto text = [](double v) { return std::to_string(v); };
  // Joint values must fit an i32 of µrad / µm: ±2147 rad or m is far beyond any real joint.
  constexpr double kMaxJoint = 2000.0;
  for (int j = 0; j < wr::kJointCount; ++j) {
    const JointLimit& l = options.joints[static_cast<size_t>(j)];
    const std::string joint = std::string("joint ") + wr::JointName(j);
    if (!(std::isfinite(l.min) && std::isfinite(l.max) && l.min < l.max &&
          std::abs(l.min) < kMaxJoint && std::abs(l.max) < kMaxJoint)) {
      problem(joint + " limits " + text(l.min) + " .. " + text(l.max) +
              " (need finite min < max within ±2000)");
      continue;
    }
    if (!(l.max_speed > 0 && l.max_speed < kMaxJoint)) {
      problem(joint + " max_speed " + text(l.max_speed) + " (need 0 < speed < 2000)");
    }
    const double q0 = options.initial_joints[static_cast<size_t>(j)];
    if (!(q0 >= l.min && q0 <= l.max)) {
      problem(joint + " initial value " + text(q0) + " outside its limits");
    }
    min_[static_cast<size_t>(j)] = JointUnits(l.min);
    max_[static_cast<size_t>(j)] = JointUnits(l.max);
    speed_[static_cast<size_t>(j)] = std::llround(l.max_speed * wr::kJointUnitsPerSi);
    joints_[static_cast<size_t>(j)] = std::isfinite(q0) ? JointUnits(q0) : 0;
  }
  if (options.buffer_capacity < 1 || options.buffer_capacity > 1000) {
    problem("buffer_capacity " + std::to_string(options.buffer_capacity) + " (need 1..1000)");
  }
  auto u16 = [&](double si, double units_per_si, const char* field, uint16_t* out, double min) {
    const double units = std::round(si * units_per_si);
    if (!(units >= min && units <= 65535)) {
      problem(std::string(field) + " " + text(si) + " out of range");
    } else {
      *out = static_cast<uint16_t>(units);
    }
  };
  u16(options.max_segment_duration, wr::kDurationUnitsPerSecond, "max_segment_duration",
      &max_duration_ms_, wr::kMinSegmentDurationMs);
  u16(options.max_current, wr::kCurrentUnitsPerAmpere, "max_current", &max_current_, 0);
  u16(options.max_voltage, wr::kVoltageUnitsPerVolt, "max_voltage", &max_voltage_, 0);
  u16(options.max_wire_feed_speed, wr::kWireFeedUnitsPerMetrePerSecond, "max_wire_feed_speed",
      &max_wire_feed_, 0);
  if (options.tick.count() <= 0) {
    problem("tick " + std::to_string(options.tick.count()) + " ms (need > 0)");
  }
  if (!problems.empty()) throw common::ConfigError("weld robot simulator options: " + problems);
}

std::unique_ptr<WeldRobotSim> WeldRobotSim::ListenTcp(const std::string& host, int port,
                                                      const Options& options) {
  std::unique_ptr<WeldRobotSim> sim(new WeldRobotSim(options, nullptr));
  ModbusServer::Options o;
  o.coils = 0;
  o.discrete_inputs = 0;
  o.holding_registers = wr::kHoldingRegisterCount;
  o.input_registers = wr::kInputRegisterCount;
  o.unit = options.unit;
  sim->Start(ModbusServer::ListenTcp(host, port, o));
  return sim;
}

std::unique_ptr<WeldRobotSim> WeldRobotSim::ServeRtu(const Options& options,
                                                     const std::string& link_path) {
  auto pty = std::make_unique<PtyPair>();
  if (!link_path.empty()) pty->CreateLink(link_path);
  const int fd = pty->master_fd();
  const std::string path = link_path.empty() ? pty->slave_path() : link_path;
  std::unique_ptr<WeldRobotSim> sim(new WeldRobotSim(options, std::move(pty)));
  ModbusServer::Options o;
  o.coils = 0;
  o.discrete_inputs = 0;
  o.holding_registers = wr::kHoldingRegisterCount;
  o.input_registers = wr::kInputRegisterCount;
  o.unit = options.unit;
  o.baud = 115200;
  o.parity = 'E';
  sim->Start(ModbusServer::ServeRtu(fd, path, o));
  return sim;
}

void WeldRobotSim::Start(std::unique_ptr<ModbusServer> server) {
  server_ = std::move(server);
  server_->WithRegisters([&](ModbusRegisterMap& map) {
    WriteIdentity(map);
    PublishLocked(map);
    last_update_ = clock_->Now();
  });
  server_->SetRequestHook(
      [this](const ModbusRequest& r, const ModbusRegisterMap&) { return OnRequest(r); });
  // A command register reads back 0 once the command is executed (in the request hook).
  server_->SetWriteHook([](const ModbusRequest& r, ModbusRegisterMap& map) {
    if (r.address == wr::kRegCommand) map.holding_registers[wr::kRegCommand] = 0;
  });
  spdlog::info("{}: weld robot controller on {} (buffer of {} segments)", options_.name,
               server_->backend(), options_.buffer_capacity);
  if (options_.run_executor) {
    executor_ = std::thread([this] {
      pthread_setname_np(pthread_self(), "weld-robot-sim");
      ExecutorLoop();
    });
  }
}

WeldRobotSim::~WeldRobotSim() {
  stop_ = true;
  if (executor_.joinable()) executor_.join();
  if (server_) server_->Stop();
}

void WeldRobotSim::ExecutorLoop() {
  while (!stop_.load()) {
    clock_->SleepFor(options_.tick);
    Update();
  }
}

void WeldRobotSim::WriteIdentity(ModbusRegisterMap& map) const {
  uint16_t* r = map.input_registers.data();
  r[wr::kRegMagic] = wr::kIdentityMagic;
  r[wr::kRegMapVersion] = wr::kMapVersion;
  r[wr::kRegJointCount] = wr::kJointCount;
  r[wr::kRegBufferCapacity] = static_cast<uint16_t>(options_.buffer_capacity);
  r[wr::kRegMaxSegmentDurationMs] = max_duration_ms_;
  r[wr::kRegMaxCurrent] = max_current_;
  r[wr::kRegMaxVoltage] = max_voltage_;
  r[wr::kRegMaxWireFeed] = max_wire_feed_;
  wr::PutU32(r + wr::kRegSerialNumber, options_.serial_number);
  for (int j = 0; j < wr::kJointCount; ++j) {
    uint16_t* p = r + wr::kRegJointLimits + wr::kJointLimitRegisters * j;
    const auto jj = static_cast<size_t>(j);
    wr::PutI32(p + wr::kJointLimitMinOffset, min_[jj]);
    wr::PutI32(p + wr::kJointLimitMaxOffset, max_[jj]);
    wr::PutU32(p + wr::kJointLimitSpeedOffset, static_cast<uint32_t>(speed_[jj]));
  }
}

void WeldRobotSim::PublishLocked(ModbusRegisterMap& map) const {
  uint16_t* r = map.input_registers.data();
  const wr::MotionState motion = alarm_ != 0       ? wr::MotionState::kAlarm
                                 : buffer_.empty() ? wr::MotionState::kIdle
                                                   : wr::MotionState::kMoving;
  const int level = static_cast<int>(buffer_.size());
  r[wr::kRegMotionState] = static_cast<uint16_t>(motion);
  r[wr::kRegAlarmCode] = alarm_;
  r[wr::kRegBufferLevel] = static_cast<uint16_t>(level);
  r[wr::kRegBufferFree] = static_cast<uint16_t>(options_.buffer_capacity - level);
  r[wr::kRegArcEnabled] = arc_enabled_ ? 1 : 0;
  r[wr::kRegArcOn] = arc_on_ ? 1 : 0;
  wr::PutU32(r + wr::kRegLastSequence, last_sequence_);
  wr::PutU32(r + wr::kRegCompletedSequence, completed_sequence_);
  wr::PutU32(r + wr::kRegAlarmSequence, alarm_sequence_);
  for (int j = 0; j < wr::kJointCount; ++j) {
    wr::PutI32(r + wr::kRegActualJoints + 2 * j, joints_[static_cast<size_t>(j)]);
  }
  r[wr::kRegActualCurrent] = current_;
  r[wr::kRegActualVoltage] = voltage_;
  r[wr::kRegActualWireFeed] = wire_feed_;
}

void WeldRobotSim::Publish() {
  server_->WithRegisters([&](ModbusRegisterMap& map) { PublishLocked(map); });
}

// ---- Requests ---------------------------------------------------------------------------------

ModbusErrc WeldRobotSim::OnRequest(const ModbusRequest& r) {
  if (!r.is_write()) return ModbusErrc::kNone;
  ModbusErrc result = ModbusErrc::kIllegalDataAddress;
  const int end = r.address + r.count;  // one past the last register written
  const bool plain_write = r.function == 0x06 || r.function == 0x10;
  auto overlaps = [&](int first, int count) { return r.address < first + count && end > first; };
  if (overlaps(wr::kSegmentAddress, wr::kSegmentRegisters)) {
    if (r.function != 0x10) {
      result = ModbusErrc::kIllegalFunction;
    } else if (r.address == wr::kSegmentAddress && r.count == wr::kSegmentRegisters) {
      result = OnSegment(r.values);
    }
  } else if (!plain_write) {
    result = ModbusErrc::kIllegalFunction;
  } else if (r.address == wr::kRegCommand && r.count == 1) {
    result = OnCommand(r.values[0]);
  } else if (r.address >= wr::kRegSetCurrent &&
             end <= wr::kRegSetCurrent + wr::kSetPointRegisters) {
    result = OnSetPoints(r.address, r.count, r.values);
  }
  if (result != ModbusErrc::kNone) {
    ++stats_.writes_refused;
    spdlog::debug("{}: write of {} register(s) at {} refused: {}", options_.name, r.count,
                  r.address, make_error_code(result).message());
  }
  Publish();
  return result;
}

ModbusErrc WeldRobotSim::OnSegment(const uint16_t* values) {
  Segment s;
  for (int i = 0; i < wr::kSegmentRegisters; ++i) s.raw[static_cast<size_t>(i)] = values[i];
  s.sequence = wr::GetU32(values + wr::kSegmentSequenceOffset);
  for (int j = 0; j < wr::kJointCount; ++j) {
    s.target[static_cast<size_t>(j)] = wr::GetI32(values + wr::kSegmentJointsOffset + 2 * j);
  }
  s.duration_ms = values[wr::kSegmentDurationOffset];
  s.flags = values[wr::kSegmentFlagsOffset];

  if (alarm_ != 0) return ModbusErrc::kServerDeviceFailure;
  if (stream_open_ && s.sequence == last_sequence_ && s.raw == last_raw_) {
    ++stats_.duplicates_ignored;  // a retried request whose first answer was lost
    return ModbusErrc::kNone;
  }
  auto alarm = [&](wr::Alarm a) {
    RaiseAlarmLocked(static_cast<uint16_t>(a), s.sequence);
    return ModbusErrc::kIllegalDataValue;
  };
  if (static_cast<int>(buffer_.size()) >= options_.buffer_capacity) {
    return alarm(wr::Alarm::kBufferOverflow);
  }
  if (stream_open_ && s.sequence != last_sequence_ + 1) return alarm(wr::Alarm::kSequenceGap);
  if (s.duration_ms < wr::kMinSegmentDurationMs || s.duration_ms > max_duration_ms_ ||
      (s.flags & ~wr::kSegmentKnownFlags) != 0) {
    return alarm(wr::Alarm::kBadSegment);
  }
  for (size_t j = 0; j < wr::kJointCount; ++j) {
    if (s.target[j] < min_[j] || s.target[j] > max_[j]) {
      return alarm(wr::Alarm::kTargetOutOfRange);
    }
  }
  const auto& from = buffer_.empty() ? joints_ : buffer_.back().target;
  for (size_t j = 0; j < wr::kJointCount; ++j) {
    const int64_t delta = std::abs(int64_t{s.target[j]} - from[j]);
    if (delta * 1000 > speed_[j] * s.duration_ms) return alarm(wr::Alarm::kSpeedLimit);
  }
  if (buffer_.empty()) s.start = joints_;
  buffer_.push_back(s);
  last_sequence_ = s.sequence;
  last_raw_ = s.raw;
  stream_open_ = true;
  ++stats_.segments_accepted;
  stats_.max_buffer_level = std::max(stats_.max_buffer_level, static_cast<int>(buffer_.size()));
  UpdateArcLocked();
  return ModbusErrc::kNone;
}

ModbusErrc WeldRobotSim::OnCommand(uint16_t command) {
  switch (static_cast<wr::Command>(command)) {
    case wr::Command::kNone:
      return ModbusErrc::kNone;
    case wr::Command::kStop:
      StopMotionLocked();
      spdlog::info("{}: STOP", options_.name);
      return ModbusErrc::kNone;
    case wr::Command::kAlarmReset:
      if (alarm_ != 0) {
        spdlog::info("{}: alarm {} (code {}) reset", options_.name, wr::AlarmName(alarm_), alarm_);
      }
      alarm_ = 0;
      alarm_sequence_ = 0;
      StopMotionLocked();
      return ModbusErrc::kNone;
    case wr::Command::kArcOn:
      if (alarm_ != 0) return ModbusErrc::kServerDeviceFailure;
      if (current_ == 0 || voltage_ == 0 || wire_feed_ == 0) return ModbusErrc::kIllegalDataValue;
      arc_enabled_ = true;
      UpdateArcLocked();
      return ModbusErrc::kNone;
    case wr::Command::kArcOff:
      arc_enabled_ = false;
      UpdateArcLocked();
      return ModbusErrc::kNone;
  }
  return ModbusErrc::kIllegalDataValue;
}

ModbusErrc WeldRobotSim::OnSetPoints(int address, int count, const uint16_t* values) {
  const uint16_t limits[wr::kSetPointRegisters] = {max_current_, max_voltage_, max_wire_feed_};
  for (int i = 0; i < count; ++i) {
    if (values[i] > limits[address - wr::kRegSetCurrent + i]) return ModbusErrc::kIllegalDataValue;
  }
  uint16_t* targets[wr::kSetPointRegisters] = {&current_, &voltage_, &wire_feed_};
  for (int i = 0; i < count; ++i) *targets[address - wr::kRegSetCurrent + i] = values[i];
  UpdateArcLocked();
  return ModbusErrc::kNone;
}

// ---- Motion -----------------------------------------------------------------------------------

void WeldRobotSim::StopMotionLocked() {
  buffer_.clear();
  stream_open_ = false;
  arc_enabled_ = false;
  UpdateArcLocked();
}

void WeldRobotSim::RaiseAlarmLocked(uint16_t code, uint32_t sequence) {
  alarm_ = code;
  alarm_sequence_ = sequence;
  ++stats_.alarms_raised;
  StopMotionLocked();
  spdlog::warn("{}: alarm {} (code {}){}; motion stopped, arc off, buffer cleared", options_.name,
               wr::AlarmName(code), code,
               sequence != 0 ? " on segment sequence " + std::to_string(sequence) : std::string());
}

// The interlock of weld_robot_registers.h.
void WeldRobotSim::UpdateArcLocked() {
  arc_on_ = alarm_ == 0 && arc_enabled_ && current_ != 0 && voltage_ != 0 && wire_feed_ != 0 &&
            !buffer_.empty() && (buffer_.front().flags & wr::kSegmentFlagArcOn) != 0;
}

void WeldRobotSim::StepLocked(int64_t dt_ns) {
  while (dt_ns > 0 && !buffer_.empty() && alarm_ == 0) {
    Segment& s = buffer_.front();
    const int64_t duration_ns = int64_t{s.duration_ms} * kNsPerMs;
    const int64_t step = std::min(dt_ns, duration_ns - s.elapsed_ns);
    s.elapsed_ns += step;
    dt_ns -= step;
    if (arc_on_) stats_.arc_time += static_cast<double>(step) * 1e-9;
    if (s.elapsed_ns < duration_ns) {
      const double f = static_cast<double>(s.elapsed_ns) / static_cast<double>(duration_ns);
      for (size_t j = 0; j < wr::kJointCount; ++j) {
        joints_[j] = static_cast<int32_t>(
            s.start[j] + std::llround(f * static_cast<double>(int64_t{s.target[j]} - s.start[j])));
      }
      continue;
    }
    joints_ = s.target;
    completed_sequence_ = s.sequence;
    ++stats_.segments_completed;
    if (arc_on_) ++stats_.arc_segments;
    completed_log_.push_back(s.sequence);
    if (completed_log_.size() > kCompletedLogSize) completed_log_.pop_front();
    buffer_.pop_front();
    if (!buffer_.empty()) buffer_.front().start = joints_;
    UpdateArcLocked();
  }
}

void WeldRobotSim::Step(common::Duration dt) {
  server_->WithRegisters([&](ModbusRegisterMap& map) {
    StepLocked(std::max<int64_t>(0, dt.count()));
    PublishLocked(map);
  });
}

void WeldRobotSim::Update() {
  server_->WithRegisters([&](ModbusRegisterMap& map) {
    const common::Duration now = clock_->Now();
    if (now > last_update_) {
      StepLocked((now - last_update_).count());
      last_update_ = now;
    }
    PublishLocked(map);
  });
}

// ---- Observation and fault injection ----------------------------------------------------------

WeldRobotSim::State WeldRobotSim::state() const {
  return server_->WithRegisters([&](ModbusRegisterMap&) {
    State s;
    for (size_t j = 0; j < wr::kJointCount; ++j) s.joints[j] = joints_[j] / wr::kJointUnitsPerSi;
    s.motion = alarm_ != 0       ? wr::MotionState::kAlarm
               : buffer_.empty() ? wr::MotionState::kIdle
                                 : wr::MotionState::kMoving;
    s.alarm_code = alarm_;
    s.alarm_sequence = alarm_sequence_;
    s.buffer_level = static_cast<int>(buffer_.size());
    s.arc_enabled = arc_enabled_;
    s.arc_on = arc_on_;
    s.last_sequence = last_sequence_;
    s.completed_sequence = completed_sequence_;
    s.current = current_ / wr::kCurrentUnitsPerAmpere;
    s.voltage = voltage_ / wr::kVoltageUnitsPerVolt;
    s.wire_feed_speed = wire_feed_ / wr::kWireFeedUnitsPerMetrePerSecond;
    return s;
  });
}

WeldRobotSim::Statistics WeldRobotSim::statistics() const {
  return server_->WithRegisters([&](ModbusRegisterMap&) { return stats_; });
}

std::vector<uint32_t> WeldRobotSim::completed_sequences() const {
  return server_->WithRegisters([&](ModbusRegisterMap&) {
    return std::vector<uint32_t>(completed_log_.begin(), completed_log_.end());
  });
}

int WeldRobotSim::DropLink() {
  spdlog::warn("{}: fault injection: dropping the link", options_.name);
  return server_->DropConnections();
}

void WeldRobotSim::StopAnswering(std::chrono::milliseconds duration) {
  spdlog::warn("{}: fault injection: not answering for {} ms", options_.name, duration.count());
  server_->StopAnswering(duration);
}

void WeldRobotSim::ResumeAnswering() { server_->ResumeAnswering(); }

void WeldRobotSim::RaiseAlarm(uint16_t code) {
  if (code == 0)
    throw common::ConfigError(options_.name + ": RaiseAlarm(0): alarm code 0 means no alarm");
  server_->WithRegisters([&](ModbusRegisterMap& map) {
    RaiseAlarmLocked(code, 0);
    PublishLocked(map);
  });
}

}  // namespace kinevis::hal
