#include "hal/mock/dynamixel_sim.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstring>

#include "hal/common/error.h"
#include "hal/dynamixel/protocol1.h"
#include "hal/dynamixel/protocol2.h"

namespace kinevis::hal {
namespace {

using std::chrono::milliseconds;

// How long the thread waits for input before it looks at the stop flag again.
constexpr milliseconds kPollInterval{20};
// How long a write to the host may take before the bytes are given up (nobody reading).
constexpr milliseconds kWriteTimeout{100};
// Present load at full no-load speed, in the load register's unit (see the header).
constexpr double kLoadAtFullSpeed = 0.2;

uint16_t Le16(const uint8_t* p) { return static_cast<uint16_t>(p[0] | p[1] << 8); }

}  // namespace

struct DynamixelSim::Servo {
  Servo(uint8_t id, DxlControlTable t) : original_id(id), table(std::move(t)) {
    torque = &table.Get(DxlRole::kTorqueEnable);
    goal = &table.Get(DxlRole::kGoalPosition);
    speed = &table.Get(DxlRole::kProfileVelocity);
    present_position = &table.Get(DxlRole::kPresentPosition);
    present_velocity = &table.Get(DxlRole::kPresentVelocity);
    load = table.Find(DxlRole::kPresentLoad);
    moving = &table.Get(DxlRole::kMoving);
    min_limit = &table.Get(DxlRole::kMinPosition);
    max_limit = &table.Get(DxlRole::kMaxPosition);
    registered = &table.Get(DxlRole::kRegistered);
    hardware_error = table.Find(DxlRole::kHardwareErrorStatus);
    id_register = &table.Get(DxlRole::kId);
    model = &table.Get(DxlRole::kModelNumber);
    firmware = &table.Get(DxlRole::kFirmwareVersion);
    tick = table.Find("realtime_tick");
  }

  uint8_t id() const { return memory[id_register->address]; }

  const uint8_t original_id;
  const DxlControlTable table;
  std::vector<uint8_t> memory;
  double position_ticks = 0.0;  // exact; the register holds it rounded
  common::Duration last_update{0};
  common::Duration epoch{0};  // of the realtime tick
  bool overloaded = false;
  bool no_reply = false;
  std::chrono::steady_clock::time_point silent_until{};  // rebooting until then
  bool reg_pending = false;
  uint16_t reg_address = 0;
  std::vector<uint8_t> reg_data;

  const DxlRegister* torque;
  const DxlRegister* goal;
  const DxlRegister* speed;
  const DxlRegister* present_position;
  const DxlRegister* present_velocity;
  const DxlRegister* load;  // may be null
  const DxlRegister* moving;
  const DxlRegister* min_limit;
  const DxlRegister* max_limit;
  const DxlRegister* registered;
  const DxlRegister* hardware_error;  // may be null
  const DxlRegister* id_register;
  const DxlRegister* model;
  const DxlRegister* firmware;
  const DxlRegister* tick;  // may be null
};

DynamixelSim::DynamixelSim(std::unique_ptr<SerialPort> port, Options options, common::Clock* clock)
    : port_(std::move(port)),
      protocol_(options.protocol),
      reboot_time_(options.reboot_time),
      clock_(clock),
      name_("dynamixel-sim:" + port_->name()) {
  if (protocol_ != 1 && protocol_ != 2) {
    throw common::ConfigError(name_ + ": protocol " + std::to_string(protocol_) + " is not 1 or 2");
  }
  if (options.servos.empty()) throw common::ConfigError(name_ + ": no servos");
  const int max_id = protocol_ == 1 ? 253 : 252;
  for (const ServoSpec& spec : options.servos) {
    const std::string who = name_ + ": servo " + std::to_string(spec.id);
    if (spec.id > max_id) {
      throw common::ConfigError(who + ": id out of range 0.." + std::to_string(max_id));
    }
    if (spec.table.protocol() != protocol_) {
      throw common::ConfigError(who + ": control table " + spec.table.model() +
                                " is for protocol " + std::to_string(spec.table.protocol()) +
                                ".0, the bus speaks " + std::to_string(protocol_) + ".0");
    }
    for (const auto& other : servos_) {
      if (other->original_id == spec.id) throw common::ConfigError(who + ": id given twice");
    }
    auto s = std::make_unique<Servo>(spec.id, spec.table);
    s->memory.assign(s->table.size(), 0);
    for (const DxlRegister& r : s->table.registers()) {
      DxlControlTable::EncodeRaw(r, r.initial, &s->memory[r.address]);
    }
    SetLocked(*s, *s->id_register, spec.id);
    s->position_ticks = static_cast<double>(GetLocked(*s, *s->present_position));
    SetLocked(*s, *s->goal, GetLocked(*s, *s->present_position));
    s->last_update = s->epoch = clock_->Now();
    servos_.push_back(std::move(s));
  }
}

DynamixelSim::~DynamixelSim() { Stop(); }

void DynamixelSim::Start() {
  if (running_.exchange(true)) return;
  thread_ = std::thread([this] { Serve(); });
  spdlog::debug("{}: started, protocol {}.0, {} servos", name_, protocol_, servos_.size());
}

void DynamixelSim::Stop() {
  if (!running_.exchange(false)) return;
  if (thread_.joinable()) thread_.join();
  spdlog::debug("{}: stopped", name_);
}

DynamixelSim::Statistics DynamixelSim::statistics() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

DynamixelSim::Servo* DynamixelSim::FindLocked(uint8_t current_id) const {
  for (const auto& s : servos_) {
    if (s->id() == current_id) return s.get();
  }
  return nullptr;
}

DynamixelSim::Servo& DynamixelSim::At(uint8_t original_id) const {
  for (const auto& s : servos_) {
    if (s->original_id == original_id) return *s;
  }
  throw common::ConfigError(name_ + ": no servo " + std::to_string(original_id));
}

int64_t DynamixelSim::GetLocked(const Servo& s, const DxlRegister& reg) const {
  return DxlControlTable::DecodeRaw(reg, &s.memory[reg.address]);
}

void DynamixelSim::SetLocked(Servo& s, const DxlRegister& reg, int64_t raw) const {
  DxlControlTable::EncodeRaw(reg, std::clamp(raw, reg.min, reg.max), &s.memory[reg.address]);
}

int64_t DynamixelSim::Register(uint8_t id, const std::string& register_name) const {
  std::lock_guard<std::mutex> lock(mutex_);
  Servo& s = At(id);
  const DxlRegister* reg = s.table.Find(register_name);
  if (reg == nullptr) {
    throw common::ConfigError(name_ + ": servo " + std::to_string(id) + " (" + s.table.model() +
                              ") has no register " + register_name);
  }
  UpdateLocked(s);
  return GetLocked(s, *reg);
}

void DynamixelSim::SetRegister(uint8_t id, const std::string& register_name, int64_t raw) {
  std::lock_guard<std::mutex> lock(mutex_);
  Servo& s = At(id);
  const DxlRegister* reg = s.table.Find(register_name);
  if (reg == nullptr) {
    throw common::ConfigError(name_ + ": servo " + std::to_string(id) + " (" + s.table.model() +
                              ") has no register " + register_name);
  }
  UpdateLocked(s);
  SetLocked(s, *reg, raw);
  if (reg == s.present_position) s.position_ticks = static_cast<double>(GetLocked(s, *reg));
}

double DynamixelSim::Position(uint8_t id) const {
  std::lock_guard<std::mutex> lock(mutex_);
  Servo& s = At(id);
  UpdateLocked(s);
  return s.position_ticks * s.present_position->scale;
}

void DynamixelSim::CorruptNextReplies(size_t n) {
  std::lock_guard<std::mutex> lock(mutex_);
  corrupt_remaining_ += n;
}

void DynamixelSim::SetNoReply(uint8_t id, bool no_reply) {
  std::lock_guard<std::mutex> lock(mutex_);
  At(id).no_reply = no_reply;
}

void DynamixelSim::InjectOverload(uint8_t id) {
  std::lock_guard<std::mutex> lock(mutex_);
  Servo& s = At(id);
  UpdateLocked(s);  // the motion up to now happened
  s.overloaded = true;
  SetLocked(s, *s.torque, 0);
  SetLocked(s, *s.moving, 0);
  SetLocked(s, *s.present_velocity, 0);
  if (s.hardware_error != nullptr) {
    SetLocked(s, *s.hardware_error, GetLocked(s, *s.hardware_error) | kDxl2HwOverload);
  }
  spdlog::debug("{}: servo {}: overload injected", name_, id);
}

bool DynamixelSim::Overloaded(uint8_t id) const {
  std::lock_guard<std::mutex> lock(mutex_);
  return At(id).overloaded;
}

void DynamixelSim::PowerCycle(uint8_t id) {
  std::lock_guard<std::mutex> lock(mutex_);
  ResetRamLocked(At(id));
}

void DynamixelSim::ResetRamLocked(Servo& s) {
  UpdateLocked(s);
  for (const DxlRegister& r : s.table.registers()) {
    if (r.address >= s.table.eeprom_end()) {
      DxlControlTable::EncodeRaw(r, r.initial, &s.memory[r.address]);
    }
  }
  s.overloaded = false;
  s.reg_pending = false;
  const int64_t here = std::llround(s.position_ticks);
  SetLocked(s, *s.present_position, here);
  SetLocked(s, *s.goal, here);
  s.epoch = s.last_update = clock_->Now();
}

bool DynamixelSim::ListeningLocked(const Servo& s) const {
  return !s.no_reply && std::chrono::steady_clock::now() >= s.silent_until;
}

void DynamixelSim::UpdateLocked(Servo& s) const {
  const common::Duration now = clock_->Now();
  const double dt = std::max(0.0, std::chrono::duration<double>(now - s.last_update).count());
  s.last_update = now;
  const double rad_per_tick = s.present_position->scale;
  const double no_load = s.table.no_load_speed();
  double velocity = 0.0;  // rad/s
  if (GetLocked(s, *s.torque) != 0 && !s.overloaded) {
    const double lo = static_cast<double>(GetLocked(s, *s.min_limit));
    const double hi = static_cast<double>(GetLocked(s, *s.max_limit));
    const double goal = std::clamp(static_cast<double>(GetLocked(s, *s.goal)), lo, hi);
    double speed = DxlControlTable::ToSi(*s.speed, GetLocked(s, *s.speed));
    if (speed <= 0.0 || speed > no_load) speed = no_load;  // 0: as fast as the motor turns
    const double step = speed * dt / rad_per_tick;
    const double diff = goal - s.position_ticks;
    if (std::abs(diff) <= step) {
      s.position_ticks = goal;
    } else {
      s.position_ticks += std::copysign(step, diff);
      velocity = std::copysign(speed, diff);
    }
  }
  SetLocked(s, *s.present_position, std::llround(s.position_ticks));
  SetLocked(s, *s.present_velocity, std::llround(velocity / s.present_velocity->scale));
  if (s.load != nullptr) {
    SetLocked(s, *s.load, std::llround(kLoadAtFullSpeed * velocity / no_load / s.load->scale));
  }
  SetLocked(s, *s.moving, velocity != 0.0 ? 1 : 0);
  if (s.tick != nullptr) {
    const auto ms = std::chrono::duration_cast<milliseconds>(now - s.epoch).count();
    SetLocked(s, *s.tick, ms % (s.tick->max + 1));
  }
}

uint8_t DynamixelSim::AlarmLocked(const Servo& s) const {
  if (protocol_ == 1) return s.overloaded ? kDxl1OverloadError : 0;
  const bool hardware_error =
      s.overloaded || (s.hardware_error != nullptr && GetLocked(s, *s.hardware_error) != 0);
  return hardware_error ? kDxl2AlertBit : 0;
}

uint8_t DynamixelSim::ErrorCode(uint8_t code_2, uint8_t bit_1) const {
  return protocol_ == 1 ? bit_1 : code_2;
}

DynamixelSim::WriteCheck DynamixelSim::CheckWriteLocked(const Servo& s, uint16_t address,
                                                        const uint8_t* data, size_t size) const {
  auto refuse = [this](Dxl2ErrorCode code, uint8_t bit_1) {
    return WriteCheck{false, ErrorCode(static_cast<uint8_t>(code), bit_1)};
  };
  const size_t end = static_cast<size_t>(address) + size;
  if (size == 0 || end > s.memory.size()) {
    return refuse(Dxl2ErrorCode::kAccessError, kDxl1RangeError);
  }
  const bool torque_on = GetLocked(s, *s.torque) != 0;
  size_t pos = address;
  while (pos < end) {
    const DxlRegister* reg = nullptr;
    for (const DxlRegister& r : s.table.registers()) {
      if (r.address <= pos && pos < static_cast<size_t>(r.address) + r.size) reg = &r;
    }
    if (reg == nullptr) return refuse(Dxl2ErrorCode::kAccessError, kDxl1RangeError);
    if (reg->address != pos || static_cast<size_t>(reg->address) + reg->size > end) {
      return refuse(Dxl2ErrorCode::kDataLengthError, kDxl1RangeError);
    }
    if (reg->access != DxlAccess::kReadWrite) {
      return refuse(Dxl2ErrorCode::kAccessError, kDxl1RangeError);
    }
    if (s.table.eeprom_locked_by_torque() && reg->address < s.table.eeprom_end() && torque_on) {
      return refuse(Dxl2ErrorCode::kAccessError, kDxl1RangeError);
    }
    const int64_t raw = DxlControlTable::DecodeRaw(*reg, data + (pos - address));
    if (raw < reg->min || raw > reg->max) {
      return refuse(Dxl2ErrorCode::kDataRangeError, kDxl1RangeError);
    }
    if (reg == s.goal && (raw < GetLocked(s, *s.min_limit) || raw > GetLocked(s, *s.max_limit))) {
      return refuse(Dxl2ErrorCode::kDataLimitError, kDxl1AngleLimitError);
    }
    if (reg == s.torque && raw != 0 && s.overloaded) {
      // 1.0 has no bit for "refused while in alarm": the overload bit the answer carries anyway
      // is all the host gets.
      return refuse(Dxl2ErrorCode::kResultFail, 0);
    }
    pos += reg->size;
  }
  return {};
}

void DynamixelSim::ApplyWriteLocked(Servo& s, uint16_t address, const uint8_t* data, size_t size) {
  const bool torque_was_on = GetLocked(s, *s.torque) != 0;
  std::memcpy(&s.memory[address], data, size);
  auto written = [&](const DxlRegister* r) {
    return r->address >= address && r->address < address + size;
  };
  if (written(s.present_position)) {
    s.position_ticks = static_cast<double>(GetLocked(s, *s.present_position));
  }
  // Torque on: the servo holds where it stands unless the same write set a goal.
  if (!torque_was_on && GetLocked(s, *s.torque) != 0 && !written(s.goal)) {
    SetLocked(s, *s.goal, std::llround(s.position_ticks));
  }
}

void DynamixelSim::ReplyLocked(const Servo& s, uint8_t error, const uint8_t* params, size_t size) {
  error |= AlarmLocked(s);
  uint8_t packet[kDxl1MaxPacketSize + 16];
  std::vector<uint8_t> big;
  uint8_t* out = packet;
  size_t capacity = sizeof packet;
  if (protocol_ == 2 && Dxl2MaxEncodedSize(size + 1) > capacity) {
    big.resize(Dxl2MaxEncodedSize(size + 1));
    out = big.data();
    capacity = big.size();
  }
  const size_t n = protocol_ == 1 ? EncodeDxl1Packet(s.id(), error, params, size, out, capacity)
                                  : EncodeDxl2Status(s.id(), error, params, size, out, capacity);
  if (n == 0) {
    spdlog::warn("{}: servo {}: answer of {} bytes does not fit a packet", name_, s.id(), size);
    return;
  }
  if (corrupt_remaining_ > 0) {
    --corrupt_remaining_;
    out[n - 1] ^= 0xA5;  // the checksum (1.0) or the CRC's high byte (2.0)
    ++stats_.corrupted_replies;
  }
  ++stats_.replies;
  out_.insert(out_.end(), out, out + n);
}

void DynamixelSim::ReplyReadLocked(Servo& s, uint16_t address, uint16_t length) {
  UpdateLocked(s);
  const size_t max_length = protocol_ == 1 ? kDxl1MaxParams : kDxl2DefaultMaxPacketSize / 2;
  if (length == 0 || length > max_length ||
      static_cast<size_t>(address) + length > s.memory.size()) {
    ++stats_.refused;
    ReplyLocked(s, ErrorCode(static_cast<uint8_t>(Dxl2ErrorCode::kAccessError), kDxl1RangeError),
                nullptr, 0);
    return;
  }
  ReplyLocked(s, 0, &s.memory[address], length);
}

void DynamixelSim::HandleLocked(uint8_t id, uint8_t instruction, const uint8_t* p, size_t n) {
  ++stats_.instructions;
  const bool broadcast = id == kDxlBroadcastId;
  const uint8_t instruction_error =
      ErrorCode(static_cast<uint8_t>(Dxl2ErrorCode::kInstructionError), kDxl1InstructionError);
  // The servos an instruction addresses: the one with this id, or every one on a broadcast.
  std::vector<Servo*> targets;
  if (broadcast) {
    for (const auto& s : servos_) {
      if (ListeningLocked(*s)) targets.push_back(s.get());
    }
    std::sort(targets.begin(), targets.end(),
              [](const Servo* a, const Servo* b) { return a->id() < b->id(); });
  } else if (Servo* s = FindLocked(id); s != nullptr && ListeningLocked(*s)) {
    targets.push_back(s);
  }
  for (Servo* s : targets) UpdateLocked(*s);
  const size_t address_size = protocol_ == 1 ? 1 : 2;
  auto address_at = [&](const uint8_t* q) -> uint16_t { return protocol_ == 1 ? q[0] : Le16(q); };

  switch (static_cast<DxlInstruction>(instruction)) {
    case DxlInstruction::kPing: {
      if (broadcast && protocol_ == 1) return;  // 1.0 servos would all answer at once
      for (Servo* s : targets) {
        if (protocol_ == 1) {
          ReplyLocked(*s, 0, nullptr, 0);
        } else {
          const int64_t model = GetLocked(*s, *s->model);
          const uint8_t info[3] = {static_cast<uint8_t>(model & 0xFF),
                                   static_cast<uint8_t>(model >> 8),
                                   static_cast<uint8_t>(GetLocked(*s, *s->firmware))};
          ReplyLocked(*s, 0, info, sizeof info);
        }
      }
      return;
    }
    case DxlInstruction::kRead: {
      if (broadcast || targets.empty()) return;
      if (n != 2 * address_size) {
        ++stats_.refused;
        ReplyLocked(*targets[0], instruction_error, nullptr, 0);
        return;
      }
      const uint16_t length = protocol_ == 1 ? p[1] : Le16(p + 2);
      ReplyReadLocked(*targets[0], address_at(p), length);
      return;
    }
    case DxlInstruction::kWrite:
    case DxlInstruction::kRegWrite: {
      const bool reg = instruction == static_cast<uint8_t>(DxlInstruction::kRegWrite);
      for (Servo* s : targets) {
        WriteCheck check;
        if (n <= address_size) {
          check = {false, instruction_error};
        } else {
          check = CheckWriteLocked(*s, address_at(p), p + address_size, n - address_size);
        }
        if (!check.allowed) ++stats_.refused;
        if (check.allowed) {
          if (reg) {
            s->reg_pending = true;
            s->reg_address = address_at(p);
            s->reg_data.assign(p + address_size, p + n);
            SetLocked(*s, *s->registered, 1);
          } else {
            ApplyWriteLocked(*s, address_at(p), p + address_size, n - address_size);
          }
        }
        if (!broadcast) ReplyLocked(*s, check.error, nullptr, 0);
      }
      return;
    }
    case DxlInstruction::kAction: {
      for (Servo* s : targets) {
        uint8_t error = 0;
        if (s->reg_pending) {
          ApplyWriteLocked(*s, s->reg_address, s->reg_data.data(), s->reg_data.size());
          s->reg_pending = false;
          SetLocked(*s, *s->registered, 0);
        } else {
          error = instruction_error;
          ++stats_.refused;
        }
        if (!broadcast) ReplyLocked(*s, error, nullptr, 0);
      }
      return;
    }
    case DxlInstruction::kReboot: {
      if (broadcast || targets.empty()) return;
      Servo& s = *targets[0];
      if (protocol_ == 1) {
        ++stats_.refused;
        ReplyLocked(s, instruction_error, nullptr, 0);
        return;
      }
      ReplyLocked(s, 0, nullptr, 0);
      ResetRamLocked(s);
      s.silent_until = std::chrono::steady_clock::now() + reboot_time_;
      spdlog::debug("{}: servo {}: reboot", name_, s.id());
      return;
    }
    case DxlInstruction::kSyncWrite: {
      const size_t header = 2 * address_size;
      if (!broadcast || n <= header) return;
      const uint16_t address = address_at(p);
      const size_t length = protocol_ == 1 ? p[1] : Le16(p + 2);
      if (length == 0 || (n - header) % (length + 1) != 0) return;
      for (size_t at = header; at < n; at += length + 1) {
        Servo* s = FindLocked(p[at]);
        if (s == nullptr || !ListeningLocked(*s)) continue;
        if (CheckWriteLocked(*s, address, p + at + 1, length).allowed) {
          ApplyWriteLocked(*s, address, p + at + 1, length);
        } else {
          ++stats_.refused;
        }
      }
      return;
    }
    case DxlInstruction::kSyncRead: {
      if (protocol_ != 2 || !broadcast || n < 5) return;
      for (size_t at = 4; at < n; ++at) {
        Servo* s = FindLocked(p[at]);
        if (s != nullptr && ListeningLocked(*s)) ReplyReadLocked(*s, Le16(p), Le16(p + 2));
      }
      return;
    }
    case DxlInstruction::kBulkRead: {
      if (protocol_ != 1 || !broadcast || n < 4 || p[0] != 0x00 || (n - 1) % 3 != 0) return;
      for (size_t at = 1; at < n; at += 3) {
        Servo* s = FindLocked(p[at + 1]);
        if (s != nullptr && ListeningLocked(*s)) ReplyReadLocked(*s, p[at + 2], p[at]);
      }
      return;
    }
    default:
      if (broadcast || targets.empty()) return;
      ++stats_.refused;
      ReplyLocked(*targets[0], instruction_error, nullptr, 0);
      return;
  }
}

void DynamixelSim::Serve() {
  Dxl1Decoder decoder1(DxlPacketKind::kInstruction);
  Dxl2Decoder decoder2(DxlPacketKind::kInstruction);
  uint8_t buffer[512];
  std::vector<uint8_t> to_send;
  bool reported_link_error = false;
  while (running_.load()) {
    size_t n = 0;
    const std::error_code ec = port_->Read(buffer, sizeof buffer, kPollInterval, &n);
    if (ec == Errc::kTimeout) continue;
    if (ec) {
      // The pty pair keeps its own slave descriptor, so this means the port itself is gone.
      if (!reported_link_error) spdlog::warn("{}: serial read failed: {}", name_, ec.message());
      reported_link_error = true;
      std::this_thread::sleep_for(kPollInterval);
      continue;
    }
    reported_link_error = false;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      auto on_packet = [this](const DxlPacket& packet) {
        HandleLocked(packet.id, packet.instruction, packet.params, packet.param_count);
      };
      if (protocol_ == 1) {
        decoder1.FeedAll(buffer, n, on_packet);
        stats_.checksum_errors = decoder1.stats().checksum_errors;
      } else {
        decoder2.FeedAll(buffer, n, on_packet);
        stats_.checksum_errors = decoder2.stats().checksum_errors;
      }
      to_send.swap(out_);
      out_.clear();
    }
    if (to_send.empty()) continue;
    const std::error_code wec = port_->WriteAll(to_send.data(), to_send.size(), kWriteTimeout);
    if (wec) spdlog::debug("{}: write to host failed: {}", name_, wec.message());
    to_send.clear();
  }
}

}  // namespace kinevis::hal
