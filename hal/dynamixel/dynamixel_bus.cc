#include "hal/dynamixel/dynamixel_bus.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <thread>

#include "hal/common/backend_spec.h"
#include "hal/common/error.h"
#include "hal/serial/termios_serial_port.h"

namespace kinevis::hal {
namespace {

using std::chrono::microseconds;
using std::chrono::milliseconds;
using std::chrono::steady_clock;

// Reads and writes above this are refused: no control table is that large, and a 2.0 decoder
// holds kDxl2DefaultMaxPacketSize bytes.
constexpr size_t kMaxTransfer = 1024;

std::string StatusErrorText(int protocol, uint8_t error) {
  return protocol == 1 ? Dxl1ErrorText(error) : Dxl2ErrorText(error);
}

std::string IdList(const std::vector<uint8_t>& ids) {
  std::string text;
  for (uint8_t id : ids) text += (text.empty() ? "" : ",") + std::to_string(id);
  return text;
}

void PutLe16(std::vector<uint8_t>* out, uint16_t v) {
  out->push_back(static_cast<uint8_t>(v & 0xFF));
  out->push_back(static_cast<uint8_t>(v >> 8));
}

bool HasDuplicates(std::vector<uint8_t> ids) {
  std::sort(ids.begin(), ids.end());
  return std::adjacent_find(ids.begin(), ids.end()) != ids.end();
}

}  // namespace

void DynamixelBus::CheckOptions(const std::string& name, const DynamixelBusOptions& options) {
  std::string bad;
  if (options.protocol != 1 && options.protocol != 2) {
    bad += " protocol " + std::to_string(options.protocol) + " (1 or 2);";
  }
  if (options.timeout <= microseconds::zero() || options.timeout > std::chrono::seconds(10)) {
    bad += " timeout " + std::to_string(options.timeout.count()) + " us (0 < t <= 10 s);";
  }
  if (options.retries < 0 || options.retries > 10) {
    bad += " retries " + std::to_string(options.retries) + " (0..10);";
  }
  if (!bad.empty()) {
    bad.pop_back();
    throw common::ConfigError("Dynamixel bus " + name + ": bad options:" + bad);
  }
}

std::unique_ptr<DynamixelBus> DynamixelBus::Open(const std::string& backend,
                                                 DynamixelBusOptions options) {
  if (BackendScheme(backend) != "tty") {
    throw common::ConfigError("Dynamixel bus \"" + backend +
                              "\": the backend must be a serial port, tty:DEVICE[@BAUD]");
  }
  const SerialSettings settings = ParseTtyBackend(backend);
  CheckOptions(backend, options);
  return std::make_unique<DynamixelBus>(OpenSerialPort(settings, backend), options);
}

DynamixelBus::DynamixelBus(std::unique_ptr<SerialPort> port, DynamixelBusOptions options)
    : port_(std::move(port)), options_(options), name_(port_->name()) {
  CheckOptions(name_, options_);
  rx_.resize(256);
  tx_.reserve(256);
  params_.reserve(256);
}

DynamixelBusCounters DynamixelBus::counters() const {
  std::lock_guard<std::mutex> lock(counters_mutex_);
  return counters_;
}

void DynamixelBus::Count(uint64_t DynamixelBusCounters::*field, uint64_t n) {
  std::lock_guard<std::mutex> lock(counters_mutex_);
  counters_.*field += n;
}

std::error_code DynamixelBus::CheckId(uint8_t id, bool broadcast_ok) const {
  if (id == kDxlBroadcastId) return broadcast_ok ? std::error_code{} : Errc::kInvalidArgument;
  const uint8_t max_id = options_.protocol == 1 ? 253 : 252;
  return id <= max_id ? std::error_code{} : Errc::kInvalidArgument;
}

bool DynamixelBus::EncodeLocked(uint8_t id, DxlInstruction instruction) {
  size_t n = 0;
  if (options_.protocol == 1) {
    tx_.resize(params_.size() + 6);
    n = EncodeDxl1Packet(id, static_cast<uint8_t>(instruction), params_.data(), params_.size(),
                         tx_.data(), tx_.size());
  } else {
    tx_.resize(Dxl2MaxEncodedSize(params_.size()));
    n = EncodeDxl2Instruction(id, static_cast<uint8_t>(instruction), params_.data(), params_.size(),
                              tx_.data(), tx_.size());
  }
  tx_.resize(n);
  return n > 0;
}

std::error_code DynamixelBus::CollectLocked(std::vector<uint8_t>* pending,
                                            std::vector<DxlReply>* replies,
                                            const std::vector<uint8_t>& expected,
                                            uint64_t* crc_errors) {
  auto checksum_errors = [this] {
    return options_.protocol == 1 ? decoder1_.stats().checksum_errors
                                  : decoder2_.stats().checksum_errors;
  };
  const uint64_t crc_before = checksum_errors();
  auto deadline = steady_clock::now() + options_.timeout;
  std::error_code link_error;
  while (!pending->empty()) {
    const auto left = std::chrono::duration_cast<microseconds>(deadline - steady_clock::now());
    if (left <= microseconds::zero()) break;
    size_t n = 0;
    const std::error_code ec = port_->Read(rx_.data(), rx_.size(), left, &n);
    if (ec == Errc::kTimeout) break;
    if (ec) {
      link_error = ec;
      break;
    }
    bool got = false;
    auto on_packet = [&](const DxlPacket& p) {
      const auto it = std::find(pending->begin(), pending->end(), p.id);
      if (it == pending->end()) {
        Count(&DynamixelBusCounters::protocol_errors);
        spdlog::debug("{}: unexpected status packet from servo {}", name_, p.id);
        return;
      }
      pending->erase(it);
      const size_t index =
          static_cast<size_t>(std::find(expected.begin(), expected.end(), p.id) - expected.begin());
      DxlReply& r = (*replies)[index];
      r.error = p.error;
      r.data.assign(p.params, p.params + p.param_count);
      r.ec = {};
      if (p.error != 0) {
        Count(&DynamixelBusCounters::status_errors);
        spdlog::debug("{}: servo {}: status error: {}", name_, p.id,
                      StatusErrorText(options_.protocol, p.error));
      }
      got = true;
    };
    if (options_.protocol == 1) {
      decoder1_.FeedAll(rx_.data(), n, on_packet);
    } else {
      decoder2_.FeedAll(rx_.data(), n, on_packet);
    }
    if (got) deadline = steady_clock::now() + options_.timeout;
    *crc_errors = checksum_errors() - crc_before;
    // The answers still missing came corrupted: no use waiting for them.
    if (!pending->empty() && *crc_errors >= pending->size()) break;
  }
  *crc_errors = checksum_errors() - crc_before;
  if (*crc_errors > 0) Count(&DynamixelBusCounters::crc_errors, *crc_errors);
  return link_error;
}

std::error_code DynamixelBus::TransactLocked(const char* what, const std::vector<uint8_t>& expected,
                                             const Encoder& encode,
                                             std::vector<DxlReply>* replies) {
  replies->clear();
  for (uint8_t id : expected) {
    DxlReply r;
    r.id = id;
    r.ec = Errc::kTimeout;
    replies->push_back(std::move(r));
  }
  auto set_pending = [&](const std::vector<uint8_t>& ids, std::error_code ec) {
    for (uint8_t id : ids) {
      const size_t i =
          static_cast<size_t>(std::find(expected.begin(), expected.end(), id) - expected.begin());
      (*replies)[i].ec = ec;
    }
  };
  std::vector<uint8_t> pending = expected;
  const int attempts = 1 + options_.retries;
  int attempt = 0;
  for (; attempt < attempts; ++attempt) {
    if (attempt > 0) {
      Count(&DynamixelBusCounters::retries);
      spdlog::debug("{}: servo {}: {}: retry {} of {}", name_, IdList(pending), what, attempt,
                    options_.retries);
    }
    if (!encode(pending)) {
      set_pending(pending, Errc::kInvalidArgument);
      return Errc::kInvalidArgument;
    }
    if (options_.protocol == 1) {
      decoder1_.Reset();
    } else {
      decoder2_.Reset();
    }
    // A late answer to an earlier request must not be taken for this one.
    port_->FlushInput();
    // Generous: ten bits per byte at the line's rate, plus scheduling slack.
    const int baud = std::max(port_->settings().baud, 1200);
    const microseconds write_timeout(100000 +
                                     10 * 1000000LL * static_cast<int64_t>(tx_.size()) / baud);
    Count(&DynamixelBusCounters::requests);
    std::error_code ec = port_->WriteAll(tx_.data(), tx_.size(), write_timeout);
    if (ec) {
      spdlog::warn("{}: servo {}: {}: write failed: {}", name_, IdList(expected), what,
                   ec.message());
      set_pending(pending, ec);
      return ec;
    }
    if (pending.empty()) return {};  // a broadcast nobody answers
    uint64_t crc_errors = 0;
    ec = CollectLocked(&pending, replies, expected, &crc_errors);
    if (ec) {
      spdlog::warn("{}: servo {}: {}: read failed: {}", name_, IdList(pending), what, ec.message());
      set_pending(pending, ec);
      return ec;
    }
    if (pending.empty()) break;
    if (crc_errors < pending.size()) Count(&DynamixelBusCounters::timeouts);
    set_pending(pending, crc_errors > 0 ? Errc::kCrc : Errc::kTimeout);
  }
  if (!pending.empty()) {
    const size_t i = static_cast<size_t>(
        std::find(expected.begin(), expected.end(), pending.front()) - expected.begin());
    spdlog::warn("{}: servo {}: {}: {} after {} attempts", name_, IdList(pending), what,
                 (*replies)[i].ec == Errc::kCrc ? "only corrupted answers" : "no answer", attempts);
  }
  std::error_code first;
  for (DxlReply& r : *replies) {
    if (!r.ec && r.error != 0) r.ec = Errc::kDeviceFault;
    if (r.ec && !first) first = r.ec;
  }
  return first;
}

std::error_code DynamixelBus::SimpleRequest(const char* what, uint8_t id,
                                            DxlInstruction instruction, std::vector<uint8_t> params,
                                            DxlReply* reply) {
  std::lock_guard<std::mutex> lock(mutex_);
  params_ = std::move(params);
  std::vector<uint8_t> expected;
  if (id != kDxlBroadcastId) expected.push_back(id);
  std::vector<DxlReply> replies;
  const std::error_code ec = TransactLocked(
      what, expected, [&](const std::vector<uint8_t>&) { return EncodeLocked(id, instruction); },
      &replies);
  if (reply != nullptr) {
    if (!replies.empty()) {
      *reply = std::move(replies.front());
    } else {
      *reply = DxlReply{};
      reply->id = id;
      reply->ec = ec;
    }
  }
  return ec;
}

std::error_code DynamixelBus::CheckLength(DxlReply* reply, size_t length) {
  if (reply->ec && reply->ec != Errc::kDeviceFault) return reply->ec;
  if (reply->data.size() == length) return reply->ec;
  // A servo that refuses a read answers with its error field and no data.
  if (reply->error != 0 && reply->data.empty()) return reply->ec;
  Count(&DynamixelBusCounters::protocol_errors);
  spdlog::warn("{}: servo {}: answer of {} bytes where {} were expected", name_, reply->id,
               reply->data.size(), length);
  reply->ec = Errc::kProtocol;
  return reply->ec;
}

std::error_code DynamixelBus::Ping(uint8_t id, DxlReply* reply) {
  if (std::error_code ec = CheckId(id, false)) return ec;
  DxlReply local;
  DxlReply* r = reply != nullptr ? reply : &local;
  SimpleRequest("ping", id, DxlInstruction::kPing, {}, r);
  return CheckLength(r, options_.protocol == 1 ? 0 : 3);
}

std::error_code DynamixelBus::PingModel(uint8_t id, uint16_t* model_number, uint8_t* firmware) {
  DxlReply r;
  std::error_code ec = Ping(id, &r);
  if (ec && ec != Errc::kDeviceFault) return ec;
  if (options_.protocol == 1) {
    // The 1.0 ping answer is empty; every 1.0 model keeps its number at 0 and firmware at 2.
    ec = Read(id, 0, 3, &r);
    if (ec && ec != Errc::kDeviceFault) return ec;
  }
  if (r.data.size() != 3) return ec ? ec : make_error_code(Errc::kProtocol);
  *model_number = static_cast<uint16_t>(r.data[0] | r.data[1] << 8);
  if (firmware != nullptr) *firmware = r.data[2];
  return ec;
}

std::error_code DynamixelBus::Read(uint8_t id, uint16_t address, uint16_t length, DxlReply* reply) {
  if (std::error_code ec = CheckId(id, false)) return ec;
  if (length == 0 || length > kMaxTransfer) return Errc::kInvalidArgument;
  std::vector<uint8_t> params;
  if (options_.protocol == 1) {
    if (address + length > 256 || length > kDxl1MaxParams) return Errc::kInvalidArgument;
    params = {static_cast<uint8_t>(address), static_cast<uint8_t>(length)};
  } else {
    PutLe16(&params, address);
    PutLe16(&params, length);
  }
  DxlReply local;
  DxlReply* r = reply != nullptr ? reply : &local;
  SimpleRequest("read", id, DxlInstruction::kRead, std::move(params), r);
  return CheckLength(r, length);
}

namespace {

// Parameters of write and reg write: the address, then the data.
std::error_code WriteParams(int protocol, uint16_t address, const std::vector<uint8_t>& data,
                            std::vector<uint8_t>* params) {
  if (data.empty() || data.size() > kMaxTransfer) return Errc::kInvalidArgument;
  if (protocol == 1) {
    if (address + data.size() > 256 || data.size() + 1 > kDxl1MaxParams) {
      return Errc::kInvalidArgument;
    }
    params->push_back(static_cast<uint8_t>(address));
  } else {
    PutLe16(params, address);
  }
  params->insert(params->end(), data.begin(), data.end());
  return {};
}

}  // namespace

std::error_code DynamixelBus::Write(uint8_t id, uint16_t address, const std::vector<uint8_t>& data,
                                    DxlReply* reply) {
  if (std::error_code ec = CheckId(id, true)) return ec;
  std::vector<uint8_t> params;
  if (std::error_code ec = WriteParams(options_.protocol, address, data, &params)) return ec;
  return SimpleRequest("write", id, DxlInstruction::kWrite, std::move(params), reply);
}

std::error_code DynamixelBus::RegWrite(uint8_t id, uint16_t address,
                                       const std::vector<uint8_t>& data, DxlReply* reply) {
  if (std::error_code ec = CheckId(id, true)) return ec;
  std::vector<uint8_t> params;
  if (std::error_code ec = WriteParams(options_.protocol, address, data, &params)) return ec;
  return SimpleRequest("reg write", id, DxlInstruction::kRegWrite, std::move(params), reply);
}

std::error_code DynamixelBus::Action(uint8_t id) {
  if (std::error_code ec = CheckId(id, true)) return ec;
  return SimpleRequest("action", id, DxlInstruction::kAction, {}, nullptr);
}

std::error_code DynamixelBus::SyncWrite(uint16_t address, uint16_t length,
                                        const std::vector<DxlWriteItem>& items) {
  if (items.empty() || length == 0 || length > kMaxTransfer) return Errc::kInvalidArgument;
  std::vector<uint8_t> params;
  if (options_.protocol == 1) {
    if (address + length > 256) return Errc::kInvalidArgument;
    params = {static_cast<uint8_t>(address), static_cast<uint8_t>(length)};
  } else {
    PutLe16(&params, address);
    PutLe16(&params, length);
  }
  for (const DxlWriteItem& item : items) {
    if (CheckId(item.id, false) || item.data.size() != length) return Errc::kInvalidArgument;
    params.push_back(item.id);
    params.insert(params.end(), item.data.begin(), item.data.end());
  }
  if (options_.protocol == 1 && params.size() > kDxl1MaxParams) return Errc::kInvalidArgument;
  return SimpleRequest("sync write", kDxlBroadcastId, DxlInstruction::kSyncWrite, std::move(params),
                       nullptr);
}

std::error_code DynamixelBus::SyncRead(uint16_t address, uint16_t length,
                                       const std::vector<uint8_t>& ids,
                                       std::vector<DxlReply>* replies) {
  if (options_.protocol != 2) return Errc::kUnsupported;
  if (ids.empty() || length == 0 || length > kMaxTransfer || HasDuplicates(ids)) {
    return Errc::kInvalidArgument;
  }
  for (uint8_t id : ids) {
    if (CheckId(id, false)) return Errc::kInvalidArgument;
  }
  std::error_code ec;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ec = TransactLocked(
        "sync read", ids,
        [&](const std::vector<uint8_t>& pending) {
          params_.clear();
          PutLe16(&params_, address);
          PutLe16(&params_, length);
          params_.insert(params_.end(), pending.begin(), pending.end());
          return EncodeLocked(kDxlBroadcastId, DxlInstruction::kSyncRead);
        },
        replies);
  }
  std::error_code first;
  for (DxlReply& r : *replies) {
    CheckLength(&r, length);
    if (r.ec && !first) first = r.ec;
  }
  return first ? first : ec;
}

std::error_code DynamixelBus::BulkRead(const std::vector<DxlReadRequest>& requests,
                                       std::vector<DxlReply>* replies) {
  if (options_.protocol != 1) return Errc::kUnsupported;
  if (requests.empty()) return Errc::kInvalidArgument;
  std::vector<uint8_t> ids;
  for (const DxlReadRequest& q : requests) {
    if (CheckId(q.id, false) || q.length == 0 || q.length > kDxl1MaxParams ||
        q.address + q.length > 256) {
      return Errc::kInvalidArgument;
    }
    ids.push_back(q.id);
  }
  if (HasDuplicates(ids) || 1 + 3 * requests.size() > kDxl1MaxParams) {
    return Errc::kInvalidArgument;
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    TransactLocked(
        "bulk read", ids,
        [&](const std::vector<uint8_t>& pending) {
          params_.assign(1, 0x00);
          for (const DxlReadRequest& q : requests) {
            if (std::find(pending.begin(), pending.end(), q.id) == pending.end()) continue;
            params_.push_back(static_cast<uint8_t>(q.length));
            params_.push_back(q.id);
            params_.push_back(static_cast<uint8_t>(q.address));
          }
          return EncodeLocked(kDxlBroadcastId, DxlInstruction::kBulkRead);
        },
        replies);
  }
  std::error_code first;
  for (size_t i = 0; i < replies->size(); ++i) {
    CheckLength(&(*replies)[i], requests[i].length);
    if ((*replies)[i].ec && !first) first = (*replies)[i].ec;
  }
  return first;
}

std::error_code DynamixelBus::Reboot(uint8_t id) {
  if (options_.protocol != 2) return Errc::kUnsupported;
  if (std::error_code ec = CheckId(id, false)) return ec;
  return SimpleRequest("reboot", id, DxlInstruction::kReboot, {}, nullptr);
}

// ---------------------------------------------------------------------------------------------
// DynamixelServo

namespace {

std::string ServoName(const DynamixelBus& bus, uint8_t id, const DxlControlTable& table) {
  return bus.name() + " servo " + std::to_string(id) + " (" + table.model() + ")";
}

}  // namespace

DynamixelServo::DynamixelServo(DynamixelBus* bus, uint8_t id, DxlControlTable table,
                               DynamixelServoOptions options)
    : bus_(bus),
      id_(id),
      table_(std::move(table)),
      options_(options),
      name_(ServoName(*bus, id, table_)) {
  if (table_.protocol() != bus_->protocol()) {
    throw common::ConfigError(name_ + ": the control table " + table_.source() +
                              " is for protocol " + std::to_string(table_.protocol()) +
                              ".0, the bus speaks protocol " + std::to_string(bus_->protocol()) +
                              ".0");
  }
  if (id_ > (bus_->protocol() == 1 ? 253 : 252)) {
    throw common::ConfigError(name_ + ": id " + std::to_string(id_) + " is out of range");
  }
  uint32_t lo = 0xFFFF;
  uint32_t hi = 0;
  for (DxlRole role : {DxlRole::kTorqueEnable, DxlRole::kPresentPosition, DxlRole::kPresentVelocity,
                       DxlRole::kPresentLoad, DxlRole::kMoving, DxlRole::kHardwareErrorStatus}) {
    if (const DxlRegister* r = table_.Find(role)) {
      lo = std::min<uint32_t>(lo, r->address);
      hi = std::max<uint32_t>(hi, static_cast<uint32_t>(r->address) + r->size);
    }
  }
  state_address_ = static_cast<uint16_t>(lo);
  state_length_ = static_cast<uint16_t>(hi - lo);
}

uint8_t DynamixelServo::AlarmBits(uint8_t status_error) const {
  if (bus_->protocol() == 1) {
    return status_error & (kDxl1InputVoltageError | kDxl1OverheatingError | kDxl1OverloadError);
  }
  return status_error & kDxl2AlertBit;
}

void DynamixelServo::EnterFault(const std::string& why) {
  if (lifecycle_ == common::DeviceLifecycle::kFault) return;
  lifecycle_ = common::DeviceLifecycle::kFault;
  spdlog::error("{}: fault: {}; torque off", name_, why);
  // The servo has already cut the torque on an overload; this makes the safe state explicit for
  // every other alarm too.
  WriteRegister(DxlRole::kTorqueEnable, 0);
}

void DynamixelServo::CheckAlarm(uint8_t status_error, uint8_t hardware_error) {
  const uint8_t alarm = AlarmBits(status_error);
  if (alarm == 0 && hardware_error == 0) return;
  if (lifecycle_ == common::DeviceLifecycle::kFault) return;
  std::string why;
  if (bus_->protocol() == 1) {
    why = Dxl1ErrorText(alarm != 0 ? alarm : hardware_error);
  } else {
    if (hardware_error == 0) {
      // The alert bit says only that there is a hardware error; its register says which.
      if (const DxlRegister* reg = table_.Find(DxlRole::kHardwareErrorStatus)) {
        DxlReply r;
        const std::error_code ec = bus_->Read(id_, reg->address, reg->size, &r);
        if ((!ec || ec == Errc::kDeviceFault) && r.data.size() == reg->size) {
          hardware_error = static_cast<uint8_t>(DxlControlTable::DecodeRaw(*reg, r.data.data()));
          state_.hardware_error = hardware_error;
        }
      }
    }
    why = "hardware error: " + Dxl2HardwareErrorText(hardware_error);
  }
  EnterFault(why);
}

std::error_code DynamixelServo::WriteRegister(DxlRole role, int64_t raw) {
  const DxlRegister& reg = table_.Get(role);
  std::vector<uint8_t> bytes(reg.size);
  DxlControlTable::EncodeRaw(reg, raw, bytes.data());
  DxlReply reply;
  const std::error_code ec = bus_->Write(id_, reg.address, bytes, &reply);
  if (ec == Errc::kDeviceFault) {
    state_.status_error = reply.error;
    if (role != DxlRole::kTorqueEnable || raw != 0) CheckAlarm(reply.error, 0);
  }
  return ec;
}

void DynamixelServo::Configure() {
  uint16_t model = 0;
  uint8_t firmware = 0;
  std::error_code ec = bus_->PingModel(id_, &model, &firmware);
  if (ec && ec != Errc::kDeviceFault) {
    const auto timeout_ms =
        std::chrono::duration_cast<milliseconds>(bus_->options().timeout).count();
    const std::string cause =
        ec == Errc::kTimeout
            ? "no answer within " + std::to_string(timeout_ms) + " ms in " +
                  std::to_string(1 + bus_->options().retries) +
                  " attempts (check the id, the baud rate, the protocol version and the power)"
            : ec.message();
    throw HalError(name_, "ping", cause, ec);
  }
  if (!table_.AcceptsModelNumber(model)) {
    throw HalError(name_, "check the model",
                   "the servo reports model number " + std::to_string(model) +
                       ", the control table " + table_.source() + " is for model number " +
                       std::to_string(table_.model_number()));
  }
  const DxlRegister& min_reg = table_.Get(DxlRole::kMinPosition);
  const DxlRegister& max_reg = table_.Get(DxlRole::kMaxPosition);
  const uint16_t lo = std::min(min_reg.address, max_reg.address);
  const uint16_t hi = static_cast<uint16_t>(
      std::max(min_reg.address + min_reg.size, max_reg.address + max_reg.size));
  DxlReply limits;
  ec = bus_->Read(id_, lo, static_cast<uint16_t>(hi - lo), &limits);
  if (limits.data.size() != static_cast<size_t>(hi - lo)) {
    throw HalError(name_, "read the angle limits", ec.message(), ec);
  }
  const int64_t min_raw = DxlControlTable::DecodeRaw(min_reg, &limits.data[min_reg.address - lo]);
  const int64_t max_raw = DxlControlTable::DecodeRaw(max_reg, &limits.data[max_reg.address - lo]);
  if (min_raw >= max_raw) {
    throw HalError(name_, "check the angle limits",
                   "limits [" + std::to_string(min_raw) + ", " + std::to_string(max_raw) +
                       "] put the servo in wheel or multi-turn mode; kinevis drives joint mode "
                       "only (the lower limit must be below the upper)");
  }
  min_position_ = DxlControlTable::ToSi(min_reg, min_raw);
  max_position_ = DxlControlTable::ToSi(max_reg, max_raw);
  lifecycle_ = common::DeviceLifecycle::kConfigured;
  ec = ReadState(nullptr);
  if (ec && ec != Errc::kDeviceFault) {
    lifecycle_ = common::DeviceLifecycle::kUnconfigured;
    throw HalError(name_, "read the state", ec.message(), ec);
  }
  spdlog::info(
      "{}: configured: model number {}, firmware {}, limits [{:.4f}, {:.4f}] rad, "
      "position {:.4f} rad{}",
      name_, model, firmware, min_position_, max_position_, state_.position,
      lifecycle_ == common::DeviceLifecycle::kFault ? ", in fault" : "");
}

std::error_code DynamixelServo::ReadState(DxlServoState* state) {
  if (lifecycle_ == common::DeviceLifecycle::kUnconfigured) return Errc::kNotActive;
  DxlReply r;
  const std::error_code ec = bus_->Read(id_, state_address_, state_length_, &r);
  if (ec && ec != Errc::kDeviceFault) return ec;
  state_.status_error = r.error;
  if (r.data.size() != state_length_) {
    CheckAlarm(r.error, 0);
    return ec;
  }
  auto value = [&](DxlRole role) {
    const DxlRegister& reg = table_.Get(role);
    return DxlControlTable::DecodeRaw(reg, &r.data[reg.address - state_address_]);
  };
  auto si = [&](DxlRole role) { return DxlControlTable::ToSi(table_.Get(role), value(role)); };
  state_.position = si(DxlRole::kPresentPosition);
  state_.velocity = si(DxlRole::kPresentVelocity);
  state_.load.reset();
  if (table_.Find(DxlRole::kPresentLoad) != nullptr) state_.load = si(DxlRole::kPresentLoad);
  state_.moving = value(DxlRole::kMoving) != 0;
  state_.torque_enabled = value(DxlRole::kTorqueEnable) != 0;
  if (table_.Find(DxlRole::kHardwareErrorStatus) != nullptr) {
    state_.hardware_error = static_cast<uint8_t>(value(DxlRole::kHardwareErrorStatus));
  } else {
    state_.hardware_error = AlarmBits(r.error);
  }
  CheckAlarm(r.error, state_.hardware_error);
  if (state != nullptr) *state = state_;
  return ec;
}

std::error_code DynamixelServo::Enable() {
  switch (lifecycle_) {
    case common::DeviceLifecycle::kUnconfigured:
      return Errc::kNotActive;
    case common::DeviceLifecycle::kFault:
      return Errc::kDeviceFault;
    case common::DeviceLifecycle::kActive:
      return {};
    case common::DeviceLifecycle::kConfigured:
      break;
  }
  // Hold where it stands: the goal becomes the present position before the torque comes on.
  const DxlRegister& present = table_.Get(DxlRole::kPresentPosition);
  DxlReply r;
  std::error_code ec = bus_->Read(id_, present.address, present.size, &r);
  if (ec) {
    CheckAlarm(r.error, 0);
    return ec;
  }
  const DxlRegister& goal = table_.Get(DxlRole::kGoalPosition);
  const int64_t hold =
      std::clamp(DxlControlTable::DecodeRaw(present, r.data.data()), goal.min, goal.max);
  if ((ec = WriteRegister(DxlRole::kGoalPosition, hold))) return ec;
  if ((ec = WriteRegister(DxlRole::kTorqueEnable, 1))) return ec;
  lifecycle_ = common::DeviceLifecycle::kActive;
  spdlog::info("{}: torque on, holding {:.4f} rad", name_, DxlControlTable::ToSi(goal, hold));
  return {};
}

std::error_code DynamixelServo::Disable() {
  if (lifecycle_ == common::DeviceLifecycle::kUnconfigured) return Errc::kNotActive;
  const std::error_code ec = WriteRegister(DxlRole::kTorqueEnable, 0);
  // A servo in alarm still takes "torque off"; only a failed transfer leaves the state unknown.
  if (ec && ec != Errc::kDeviceFault) return ec;
  if (lifecycle_ == common::DeviceLifecycle::kActive) {
    lifecycle_ = common::DeviceLifecycle::kConfigured;
    spdlog::info("{}: torque off", name_);
  }
  return ec;
}

std::error_code DynamixelServo::SetGoalPosition(double position) {
  if (lifecycle_ != common::DeviceLifecycle::kActive) return Errc::kNotActive;
  constexpr double kSlack = 1e-9;  // limits come from ticks; accept them back exactly
  if (!std::isfinite(position) || position < min_position_ - kSlack ||
      position > max_position_ + kSlack) {
    return Errc::kInvalidArgument;
  }
  const auto raw = DxlControlTable::FromSi(table_.Get(DxlRole::kGoalPosition), position);
  if (!raw) return Errc::kInvalidArgument;
  return WriteRegister(DxlRole::kGoalPosition, *raw);
}

std::error_code DynamixelServo::SetProfileVelocity(double velocity) {
  if (lifecycle_ != common::DeviceLifecycle::kActive) return Errc::kNotActive;
  if (!(velocity >= 0.0)) return Errc::kInvalidArgument;
  const auto raw = DxlControlTable::FromSi(table_.Get(DxlRole::kProfileVelocity), velocity);
  if (!raw) return Errc::kInvalidArgument;
  return WriteRegister(DxlRole::kProfileVelocity, *raw);
}

std::error_code DynamixelServo::Reboot() {
  if (bus_->protocol() != 2) return Errc::kUnsupported;
  if (lifecycle_ == common::DeviceLifecycle::kUnconfigured) return Errc::kNotActive;
  std::error_code ec = bus_->Reboot(id_);
  if (ec && ec != Errc::kDeviceFault) return ec;
  spdlog::info("{}: rebooting", name_);
  // The servo is silent while it restarts; ping until it answers.
  const auto deadline = steady_clock::now() + options_.reboot_timeout;
  do {
    std::this_thread::sleep_for(milliseconds(10));
    ec = bus_->Ping(id_);
  } while (ec && ec != Errc::kDeviceFault && steady_clock::now() < deadline);
  if (ec && ec != Errc::kDeviceFault) {
    spdlog::warn("{}: no answer within {} ms of the reboot", name_,
                 options_.reboot_timeout.count());
    return ec;
  }
  lifecycle_ = common::DeviceLifecycle::kConfigured;
  return ReadState(nullptr);
}

std::error_code DynamixelServo::ClearFault() {
  if (lifecycle_ != common::DeviceLifecycle::kFault) return {};
  if (bus_->protocol() == 2) return Reboot();
  // Protocol 1.0 has no reboot: the alarm goes with a power cycle, after which it is not reported.
  DxlReply r;
  const std::error_code ec = bus_->Ping(id_, &r);
  if (ec && ec != Errc::kDeviceFault) return ec;
  if (AlarmBits(r.error) != 0) {
    spdlog::warn("{}: alarm still reported ({}); power-cycle the servo", name_,
                 Dxl1ErrorText(r.error));
    return Errc::kDeviceFault;
  }
  lifecycle_ = common::DeviceLifecycle::kConfigured;
  return ReadState(nullptr);
}

}  // namespace kinevis::hal
