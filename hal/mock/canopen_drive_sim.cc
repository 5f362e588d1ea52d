#include "hal/mock/canopen_drive_sim.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cstring>
#include <deque>
#include <initializer_list>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using namespace canopen;
using namespace std::chrono_literals;
using Snapshot = Cia402Device::Snapshot;

constexpr uint32_t kDeviceTypeValue = 0x00020192;  // CiA 402, servo drive
constexpr char kDeviceName[] = "kinevis simulated drive";
constexpr uint16_t kManufacturerName = 0x1008;
constexpr uint16_t kApplicationTag = 0x2000;
constexpr size_t kMaxStringSize = 64;
// CiA 301 leaves the server's SDO timeout to the device; 1 s is what most drives use.
constexpr common::Duration kSdoTimeout = 1s;
// Without SYNC for this long, a drive in a cyclic mode is stepped on the clock again.
constexpr common::Duration kSyncLossTimeout = 50ms;
constexpr std::chrono::microseconds kThreadPoll = 1ms;
constexpr uint32_t kCobIdMask = 0x7FF;
constexpr uint32_t kCobIdExtendedBit = 0x20000000u;

enum class Access : uint8_t { kRo, kRw, kConst };
struct SubDef {
  uint8_t bytes = 0;  // 1, 2, 4; 0 = VISIBLE_STRING
  Access access = Access::kRo;
  bool is_signed = false;
};

struct PdoComm {
  uint32_t cob_id = kPdoCobIdInvalid;
  uint8_t type = kTransmissionSynchronous;
  uint16_t inhibit_100us = 0;   // TPDO only
  uint16_t event_timer_ms = 0;  // TPDO only
  bool valid() const { return (cob_id & kPdoCobIdInvalid) == 0; }
  uint32_t id() const { return cob_id & kCobIdMask; }
};

struct PdoMap {
  uint8_t count = 0;
  std::array<uint32_t, 8> entries{};
};

bool IsSynchronousType(uint8_t type) { return type <= 240; }

// CiA 301, 7.3.5: identifiers a PDO may not use (NMT, SYNC/EMCY range below 0x80 reserved,
// TIME, SDO, NMT error control, LSS).
bool RestrictedCobId(uint32_t id) {
  return id <= 0x7F || (id >= 0x101 && id <= 0x180) || (id >= 0x581 && id <= 0x5FF) ||
         (id >= 0x601 && id <= 0x67F) || (id >= 0x6E0 && id <= 0x6FF) || id >= 0x701;
}

// Bits of the error register 0x1001 for an error code (CiA 301, 7.5.2.2).
uint8_t ErrorRegisterFor(uint16_t code) {
  if (code == 0) return 0;
  uint8_t reg = 0x01;  // generic
  switch (code >> 12) {
    case 0x2:
      reg |= 0x02;  // current
      break;
    case 0x3:
      reg |= 0x04;  // voltage
      break;
    case 0x4:
      reg |= 0x08;  // temperature
      break;
    case 0x8:
      reg |= (code >> 8) == 0x81 ? 0x10 : 0x20;  // communication / device profile
      break;
    case 0x7:
      reg |= 0x20;
      break;
    case 0xF:
      reg |= 0x80;  // manufacturer specific
      break;
    default:
      break;
  }
  return reg;
}

// The sub-index `sub` of a record with the given sub-indices. Returns 0 or the abort code.
uint32_t FromRecord(uint8_t sub, std::initializer_list<std::pair<uint8_t, SubDef>> subs,
                    SubDef* def) {
  for (const auto& [s, d] : subs) {
    if (s == sub) {
      *def = d;
      return 0;
    }
  }
  return sdo_abort::kSubindexDoesNotExist;
}

// The object dictionary's structure: whether (index, sub) exists and its type. Returns 0 or the
// abort code.
uint32_t Lookup(uint16_t index, uint8_t sub, SubDef* def) {
  auto var = [&](uint8_t bytes, Access access, bool is_signed = false) -> uint32_t {
    if (sub != 0) return sdo_abort::kSubindexDoesNotExist;
    *def = SubDef{bytes, access, is_signed};
    return 0;
  };
  const SubDef u8_const{1, Access::kConst}, u8_rw{1, Access::kRw}, u16_rw{2, Access::kRw},
      u32_rw{4, Access::kRw}, u32_const{4, Access::kConst}, i32_rw{4, Access::kRw, true};
  if (index >= kRpdoCommunication && index < kRpdoCommunication + 4) {
    return FromRecord(sub, {{0, u8_const}, {1, u32_rw}, {2, u8_rw}}, def);
  }
  if (index >= kTpdoCommunication && index < kTpdoCommunication + 4) {
    return FromRecord(sub, {{0, u8_const}, {1, u32_rw}, {2, u8_rw}, {3, u16_rw}, {5, u16_rw}}, def);
  }
  if ((index >= kRpdoMapping && index < kRpdoMapping + 4) ||
      (index >= kTpdoMapping && index < kTpdoMapping + 4)) {
    if (sub > 8) return sdo_abort::kSubindexDoesNotExist;
    *def = sub == 0 ? u8_rw : u32_rw;
    return 0;
  }
  if (index == kIdentity) {
    return FromRecord(
        sub, {{0, u8_const}, {1, u32_const}, {2, u32_const}, {3, u32_const}, {4, u32_const}}, def);
  }
  if (index == cia402::kSoftwarePositionLimit) {
    return FromRecord(sub, {{0, u8_const}, {1, i32_rw}, {2, i32_rw}}, def);
  }
  switch (index) {
    case kDeviceType:
      return var(4, Access::kConst);
    case kErrorRegister:
      return var(1, Access::kRo);
    case kManufacturerName:
      return var(0, Access::kConst);
    case kProducerHeartbeatTime:
      return var(2, Access::kRw);
    case kApplicationTag:
      return var(0, Access::kRw);
    case cia402::kErrorCode:
      return var(2, Access::kRo);
    case cia402::kControlword:
      return var(2, Access::kRw);
    case cia402::kStatusword:
      return var(2, Access::kRo);
    case cia402::kQuickStopOptionCode:
      return var(2, Access::kRw, true);
    case cia402::kModesOfOperation:
      return var(1, Access::kRw, true);
    case cia402::kModesOfOperationDisplay:
      return var(1, Access::kRo, true);
    case cia402::kPositionActualValue:
      return var(4, Access::kRo, true);
    case cia402::kFollowingErrorWindow:
      return var(4, Access::kRw);
    case cia402::kVelocityActualValue:
      return var(4, Access::kRo, true);
    case cia402::kTargetTorque:
      return var(2, Access::kRw, true);
    case cia402::kTorqueActualValue:
      return var(2, Access::kRo, true);
    case cia402::kTargetPosition:
      return var(4, Access::kRw, true);
    case cia402::kMaxProfileVelocity:
    case cia402::kProfileVelocity:
    case cia402::kProfileAcceleration:
      return var(4, Access::kRw);
    case 0x60F4:  // following error actual value
      return var(4, Access::kRo, true);
    case cia402::kTargetVelocity:
      return var(4, Access::kRw, true);
    case cia402::kSupportedDriveModes:
      return var(4, Access::kConst);
    default:
      return sdo_abort::kObjectDoesNotExist;
  }
}

// Whether a mapping entry names an object that may be mapped into an RPDO (rx) or a TPDO: a
// numeric object of the device profile area (and the error register, TPDO only) with its exact
// length; RPDOs only take writable objects.
bool Mappable(uint32_t value, bool rx) {
  const PdoMappingEntry e = PdoMappingEntry::Decode(value);
  SubDef def;
  if (Lookup(e.index, e.subindex, &def) != 0 || def.bytes == 0) return false;
  if (e.bits != def.bytes * 8) return false;
  const bool profile_area = e.index >= 0x6000 && e.index < 0x6800;
  if (rx) return profile_area && def.access == Access::kRw;
  return profile_area || e.index == kErrorRegister;
}

int64_t SignExtend(uint32_t raw, uint8_t bytes) {
  switch (bytes) {
    case 1:
      return static_cast<int8_t>(raw);
    case 2:
      return static_cast<int16_t>(raw);
    default:
      return static_cast<int32_t>(raw);
  }
}

}  // namespace

struct CanopenDriveSim::Impl {
  CanBus* bus;
  common::Clock* clock;
  Options options;
  std::string name;
  Cia402Device device;

  mutable std::mutex mutex;
  bool booted = false;
  NmtState nmt = NmtState::kBootUp;
  std::array<PdoComm, 4> rpdo_comm, tpdo_comm;
  std::array<PdoMap, 4> rpdo_map, tpdo_map;
  uint16_t heartbeat_ms = 0;
  common::Duration next_heartbeat{0};
  std::string tag;

  struct RpdoBuffer {
    bool pending = false;
    CanFrame frame;
  };
  std::array<RpdoBuffer, 4> rpdo_buffer;
  struct TpdoState {
    int sync_count = 0;
    bool sent_once = false;
    CanFrame last;
    common::Duration last_sent{0};
    common::Duration next_event{0};
  };
  std::array<TpdoState, 4> tpdo_state;

  struct Transfer {
    enum class Kind { kNone, kDownload, kUpload };
    Kind kind = Kind::kNone;
    uint16_t index = 0;
    uint8_t subindex = 0;
    std::vector<uint8_t> data;
    size_t offset = 0;
    bool toggle = false;
    bool size_indicated = false;
    uint32_t size = 0;
    common::Duration last_activity{0};
  } sdo;

  common::Duration last_step{0};
  common::Duration last_sync{0};
  bool synced = false;

  // Fault injection.
  int drop_replies = 0;
  common::Duration reply_delay{0};
  int malformed_replies = 0;
  bool heartbeat_stopped = false;
  bool disconnected = false;
  std::deque<std::pair<common::Duration, CanFrame>> delayed;

  Statistics stats;

  // Codes reported by the device's fault callback, waiting to go out as EMCY. Own mutex: the
  // callback runs on whichever thread stepped the device, possibly holding `mutex`.
  std::mutex emcy_mutex;
  std::vector<uint16_t> emcy_pending;

  std::atomic<bool> running{false};
  std::thread thread;

  Impl(CanBus* b, common::Clock* c, Options o)
      : bus(b),
        clock(c),
        options(o),
        name("canopen-drive-sim node " + std::to_string(o.node) + " (" + b->name() + ")"),
        device(o.device) {
    device.SetFaultCallback([this](uint16_t code) {
      std::lock_guard<std::mutex> lock(emcy_mutex);
      emcy_pending.push_back(code);
    });
    DefaultCommunicationLocked();
  }

  uint8_t node() const { return options.node; }

  // ------------------------------------------------------------------------------ sending
  void SendRaw(const CanFrame& frame) {
    if (std::error_code ec = bus->Send(frame)) {
      spdlog::debug("{}: send {} failed: {}", name, FormatCanFrame(frame), ec.message());
    }
  }

  // Frames other than replies (boot-up, heartbeat, EMCY): only Disconnect() holds them back.
  bool SendOtherLocked(const CanFrame& frame) {
    if (disconnected) return false;
    SendRaw(frame);
    return true;
  }

  // SDO responses and TPDOs: subject to DropNextReplies, SendMalformedSdoReplies, SetReplyDelay.
  bool SendReplyLocked(CanFrame frame, bool sdo_response, common::Duration now) {
    if (disconnected) return false;
    if (drop_replies > 0) {
      --drop_replies;
      spdlog::debug("{}: dropped reply {}", name, FormatCanFrame(frame));
      return false;
    }
    if (sdo_response && malformed_replies > 0) {
      --malformed_replies;
      frame.dlc = 5;
    }
    if (reply_delay > common::Duration::zero()) {
      delayed.emplace_back(now + reply_delay, frame);
      return true;
    }
    SendRaw(frame);
    return true;
  }

  void SendSdoLocked(const SdoMessage& m, common::Duration now) {
    if (m.type == SdoType::kAbort) {
      ++stats.sdo_aborts_sent;
      spdlog::debug("{}: SDO abort 0x{:04X}.{} code 0x{:08X} ({})", name, m.index, m.subindex,
                    m.abort_code, SdoAbortText(m.abort_code));
    }
    SendReplyLocked(EncodeSdoResponse(node(), m), true, now);
  }

  void AbortLocked(uint16_t index, uint8_t sub, uint32_t code, common::Duration now) {
    sdo = Transfer{};
    SendSdoLocked(SdoMessage::Abort(index, sub, code), now);
  }

  // ------------------------------------------------------------------------------ NMT
  void DefaultCommunicationLocked() {
    for (int n = 0; n < 4; ++n) {
      rpdo_comm[n] = PdoComm{};
      tpdo_comm[n] = PdoComm{};
      rpdo_comm[n].cob_id = kRpdoBase[n] + node() + (n == 0 ? 0 : kPdoCobIdInvalid);
      tpdo_comm[n].cob_id = kTpdoBase[n] + node() + (n == 0 ? 0 : kPdoCobIdInvalid);
      rpdo_map[n] = PdoMap{};
      tpdo_map[n] = PdoMap{};
      rpdo_buffer[n] = RpdoBuffer{};
      tpdo_state[n] = TpdoState{};
    }
    rpdo_map[0].count = 2;
    rpdo_map[0].entries[0] = PdoMappingEntry{cia402::kControlword, 0, 16}.Encode();
    rpdo_map[0].entries[1] = PdoMappingEntry{cia402::kTargetPosition, 0, 32}.Encode();
    tpdo_map[0].count = 2;
    tpdo_map[0].entries[0] = PdoMappingEntry{cia402::kStatusword, 0, 16}.Encode();
    tpdo_map[0].entries[1] = PdoMappingEntry{cia402::kPositionActualValue, 0, 32}.Encode();
    heartbeat_ms = 0;
    sdo = Transfer{};
  }

  void BootLocked(common::Duration now) {
    booted = true;
    nmt = NmtState::kPreOperational;
    last_step = now;
    device.Step(0);  // CiA 402 transition 1 once the device has booted
    if (options.boot_up_message) {
      SendOtherLocked(EncodeHeartbeat(node(), NmtState::kBootUp));
      spdlog::debug("{}: boot-up", name);
    }
    next_heartbeat = now + std::chrono::milliseconds(heartbeat_ms);
  }

  void HandleNmtLocked(const NmtMessage& m, common::Duration now) {
    if (m.node != 0 && m.node != node()) return;
    ++stats.nmt_commands;
    spdlog::debug("{}: NMT {}", name, ToString(m.command));
    switch (m.command) {
      case NmtCommand::kStart:
        nmt = NmtState::kOperational;
        break;
      case NmtCommand::kStop:
        nmt = NmtState::kStopped;
        break;
      case NmtCommand::kEnterPreOperational:
        nmt = NmtState::kPreOperational;
        break;
      case NmtCommand::kResetNode:
        device.Reset();
        tag.clear();
        DefaultCommunicationLocked();
        BootLocked(now);
        break;
      case NmtCommand::kResetCommunication:
        DefaultCommunicationLocked();
        BootLocked(now);
        break;
    }
  }

  // ------------------------------------------------------------------------------ objects
  // The value of a numeric object (raw bits, little-endian order when put with PutLe).
  uint32_t NumericLocked(uint16_t index, uint8_t sub, const Snapshot& s) const {
    if (index >= kRpdoCommunication && index < kRpdoCommunication + 4) {
      const PdoComm& c = rpdo_comm[index - kRpdoCommunication];
      return sub == 0 ? 2 : sub == 1 ? c.cob_id : c.type;
    }
    if (index >= kTpdoCommunication && index < kTpdoCommunication + 4) {
      const PdoComm& c = tpdo_comm[index - kTpdoCommunication];
      switch (sub) {
        case 0:
          return 5;
        case 1:
          return c.cob_id;
        case 2:
          return c.type;
        case 3:
          return c.inhibit_100us;
        default:
          return c.event_timer_ms;
      }
    }
    if (index >= kRpdoMapping && index < kRpdoMapping + 4) {
      const PdoMap& m = rpdo_map[index - kRpdoMapping];
      return sub == 0 ? m.count : m.entries[sub - 1];
    }
    if (index >= kTpdoMapping && index < kTpdoMapping + 4) {
      const PdoMap& m = tpdo_map[index - kTpdoMapping];
      return sub == 0 ? m.count : m.entries[sub - 1];
    }
    switch (index) {
      case kDeviceType:
        return kDeviceTypeValue;
      case kErrorRegister:
        return ErrorRegisterFor(s.error_code);
      case kProducerHeartbeatTime:
        return heartbeat_ms;
      case kIdentity:
        switch (sub) {
          case 0:
            return 4;
          case 1:
            return options.vendor_id;
          case 2:
            return options.product_code;
          case 3:
            return options.revision;
          default:
            return options.serial_number;
        }
      case cia402::kErrorCode:
        return s.error_code;
      case cia402::kControlword:
        return s.controlword;
      case cia402::kStatusword:
        return s.statusword;
      case cia402::kQuickStopOptionCode:
        return static_cast<uint16_t>(s.quick_stop_option_code);
      case cia402::kModesOfOperation:
        return static_cast<uint8_t>(s.mode);
      case cia402::kModesOfOperationDisplay:
        return static_cast<uint8_t>(s.mode_display);
      case cia402::kPositionActualValue:
        return static_cast<uint32_t>(s.position);
      case cia402::kFollowingErrorWindow:
        return s.following_error_window;
      case cia402::kVelocityActualValue:
        return static_cast<uint32_t>(s.velocity);
      case cia402::kTargetTorque:
        return static_cast<uint16_t>(s.target_torque);
      case cia402::kTorqueActualValue:
        return static_cast<uint16_t>(s.torque);
      case cia402::kTargetPosition:
        return static_cast<uint32_t>(s.target_position);
      case cia402::kSoftwarePositionLimit:
        return sub == 0   ? 2
               : sub == 1 ? static_cast<uint32_t>(s.position_limit_min)
                          : static_cast<uint32_t>(s.position_limit_max);
      case cia402::kMaxProfileVelocity:
        return s.max_velocity;
      case cia402::kProfileVelocity:
        return s.profile_velocity;
      case cia402::kProfileAcceleration:
        return s.profile_acceleration;
      case 0x60F4:
        return static_cast<uint32_t>(s.following_error);
      case cia402::kTargetVelocity:
        return static_cast<uint32_t>(s.target_velocity);
      case cia402::kSupportedDriveModes:
        return s.supported_modes;
      default:
        return 0;
    }
  }

  // Reads an object for an SDO upload. Returns 0 or the abort code.
  uint32_t ReadLocked(uint16_t index, uint8_t sub, std::vector<uint8_t>* out) const {
    SubDef def;
    if (uint32_t code = Lookup(index, sub, &def)) return code;
    out->clear();
    if (def.bytes == 0) {
      const std::string& text = index == kManufacturerName ? std::string(kDeviceName) : tag;
      out->assign(text.begin(), text.end());
      return 0;
    }
    out->resize(def.bytes);
    PutLe(out->data(), NumericLocked(index, sub, device.snapshot()), def.bytes);
    return 0;
  }

  uint32_t WritePdoCobIdLocked(PdoComm* c, uint32_t value) {
    if ((value & kCobIdExtendedBit) != 0) return sdo_abort::kInvalidValue;  // 11-bit only
    const bool now_valid = (value & kPdoCobIdInvalid) == 0;
    if (now_valid) {
      const uint32_t id = value & kCobIdMask;
      // CiA 301: the identifier of a valid PDO cannot be changed (invalidate it first).
      if (c->valid() && id != c->id()) return sdo_abort::kInvalidValue;
      if (RestrictedCobId(id)) return sdo_abort::kInvalidValue;
    }
    c->cob_id = value;
    return 0;
  }

  uint32_t WriteMappingLocked(const PdoComm& c, PdoMap* m, uint8_t sub, uint32_t value, bool rx) {
    // CiA 301, 7.5.2.36: a valid PDO's mapping cannot be changed; entries only while sub 0 = 0.
    if (c.valid()) return sdo_abort::kUnsupportedAccess;
    if (sub == 0) {
      if (value > 8) return sdo_abort::kPdoLengthExceeded;
      int bits = 0;
      for (uint32_t i = 0; i < value; ++i) {
        if (!Mappable(m->entries[i], rx)) return sdo_abort::kCannotBeMapped;
        bits += PdoMappingEntry::Decode(m->entries[i]).bits;
      }
      if (bits > 64) return sdo_abort::kPdoLengthExceeded;
      m->count = static_cast<uint8_t>(value);
      return 0;
    }
    if (m->count != 0) return sdo_abort::kUnsupportedAccess;
    if (value != 0 && !Mappable(value, rx)) return sdo_abort::kCannotBeMapped;
    m->entries[sub - 1] = value;
    return 0;
  }

  // Writes a numeric object (from SDO or a PDO). Returns 0 or the abort code.
  uint32_t WriteNumericLocked(uint16_t index, uint8_t sub, uint32_t raw, const SubDef& def,
                              common::Duration now) {
    const int64_t value = def.is_signed ? SignExtend(raw, def.bytes) : static_cast<int64_t>(raw);
    if (index >= kRpdoCommunication && index < kRpdoCommunication + 4) {
      PdoComm& c = rpdo_comm[index - kRpdoCommunication];
      if (sub == 1) return WritePdoCobIdLocked(&c, raw);
      if (raw > 240 && raw != 254 && raw != 255) return sdo_abort::kInvalidValue;
      c.type = static_cast<uint8_t>(raw);
      return 0;
    }
    if (index >= kTpdoCommunication && index < kTpdoCommunication + 4) {
      const int n = index - kTpdoCommunication;
      PdoComm& c = tpdo_comm[n];
      switch (sub) {
        case 1:
          return WritePdoCobIdLocked(&c, raw);
        case 2:
          // 252, 253 (RTR only) are not supported.
          if (raw > 240 && raw != 254 && raw != 255) return sdo_abort::kInvalidValue;
          c.type = static_cast<uint8_t>(raw);
          tpdo_state[n] = TpdoState{};  // a new transmission type starts afresh
          return 0;
        case 3:
          c.inhibit_100us = static_cast<uint16_t>(raw);
          return 0;
        default:
          c.event_timer_ms = static_cast<uint16_t>(raw);
          tpdo_state[n].next_event = now + std::chrono::milliseconds(c.event_timer_ms);
          return 0;
      }
    }
    if (index >= kRpdoMapping && index < kRpdoMapping + 4) {
      const int n = index - kRpdoMapping;
      return WriteMappingLocked(rpdo_comm[n], &rpdo_map[n], sub, raw, true);
    }
    if (index >= kTpdoMapping && index < kTpdoMapping + 4) {
      const int n = index - kTpdoMapping;
      return WriteMappingLocked(tpdo_comm[n], &tpdo_map[n], sub, raw, false);
    }
    switch (index) {
      case kProducerHeartbeatTime:
        heartbeat_ms = static_cast<uint16_t>(raw);
        next_heartbeat = now + std::chrono::milliseconds(heartbeat_ms);
        return 0;
      case cia402::kControlword:
        device.SetControlword(static_cast<uint16_t>(raw));
        return 0;
      case cia402::kQuickStopOptionCode:
        if (value < 0) return sdo_abort::kValueTooLow;
        if (value > 8) return sdo_abort::kValueTooHigh;
        device.SetQuickStopOptionCode(static_cast<int16_t>(value));
        return 0;
      case cia402::kModesOfOperation:
        return device.SetModeOfOperation(static_cast<int8_t>(value)) ? 0 : sdo_abort::kInvalidValue;
      case cia402::kFollowingErrorWindow:
        device.SetFollowingErrorWindow(raw);
        return 0;
      case cia402::kTargetTorque:
        device.SetTargetTorque(static_cast<int16_t>(value));
        return 0;
      case cia402::kTargetPosition:
        device.SetTargetPosition(static_cast<int32_t>(value));
        return 0;
      case cia402::kSoftwarePositionLimit: {
        const Snapshot s = device.snapshot();
        int32_t min = s.position_limit_min, max = s.position_limit_max;
        if (sub == 1) {
          if (value > max) return sdo_abort::kValueTooHigh;
          min = static_cast<int32_t>(value);
        } else {
          if (value < min) return sdo_abort::kValueTooLow;
          max = static_cast<int32_t>(value);
        }
        device.SetPositionLimits(min, max);
        return 0;
      }
      case cia402::kMaxProfileVelocity:
        return device.SetMaxVelocity(raw) ? 0 : sdo_abort::kValueTooLow;
      case cia402::kProfileVelocity: {
        const Snapshot s = device.snapshot();
        device.SetProfile(raw, s.profile_acceleration);
        return 0;
      }
      case cia402::kProfileAcceleration: {
        const Snapshot s = device.snapshot();
        device.SetProfile(s.profile_velocity, raw);
        return 0;
      }
      case cia402::kTargetVelocity:
        device.SetTargetVelocity(static_cast<int32_t>(value));
        return 0;
      default:
        return sdo_abort::kReadOnly;
    }
  }

  // Writes an object for an SDO download of `size` bytes. Returns 0 or the abort code.
  uint32_t WriteLocked(uint16_t index, uint8_t sub, const uint8_t* data, size_t size,
                       common::Duration now) {
    SubDef def;
    if (uint32_t code = Lookup(index, sub, &def)) return code;
    if (def.access != Access::kRw) return sdo_abort::kReadOnly;
    if (def.bytes == 0) {
      if (size > kMaxStringSize) return sdo_abort::kLengthTooHigh;
      tag.assign(reinterpret_cast<const char*>(data), size);
      return 0;
    }
    if (size > def.bytes) return sdo_abort::kLengthTooHigh;
    if (size < def.bytes) return sdo_abort::kLengthTooLow;
    return WriteNumericLocked(index, sub, GetLe(data, def.bytes), def, now);
  }

  // ------------------------------------------------------------------------------ SDO server
  void HandleSdoLocked(const CanFrame& frame, common::Duration now) {
    if (nmt == NmtState::kStopped) return;
    if (frame.dlc != 8 || frame.rtr) {
      spdlog::debug("{}: ignored SDO request with dlc {}", name, frame.dlc);
      return;
    }
    ++stats.sdo_requests;
    std::string error;
    const std::optional<SdoMessage> request = DecodeSdoRequest(frame, &error);
    if (!request) {
      // Block transfers and unknown specifiers; the multiplexer is where an initiate has it.
      AbortLocked(static_cast<uint16_t>(frame.data[1] | frame.data[2] << 8), frame.data[3],
                  sdo_abort::kInvalidCommandSpecifier, now);
      return;
    }
    const SdoMessage& m = *request;
    switch (m.type) {
      case SdoType::kAbort:
        sdo = Transfer{};
        return;
      case SdoType::kInitiateDownloadRequest:
        InitiateDownloadLocked(m, now);
        return;
      case SdoType::kDownloadSegmentRequest:
        DownloadSegmentLocked(m, now);
        return;
      case SdoType::kInitiateUploadRequest:
        InitiateUploadLocked(m, now);
        return;
      case SdoType::kUploadSegmentRequest:
        UploadSegmentLocked(m, now);
        return;
      default:
        AbortLocked(m.index, m.subindex, sdo_abort::kInvalidCommandSpecifier, now);
        return;
    }
  }

  void InitiateDownloadLocked(const SdoMessage& m, common::Duration now) {
    sdo = Transfer{};  // a new initiate ends any transfer in progress
    SubDef def;
    if (uint32_t code = Lookup(m.index, m.subindex, &def)) {
      AbortLocked(m.index, m.subindex, code, now);
      return;
    }
    if (def.access != Access::kRw) {
      AbortLocked(m.index, m.subindex, sdo_abort::kReadOnly, now);
      return;
    }
    if (m.expedited) {
      // Without size indication the four bytes carry an object of the object's own size.
      const size_t size = m.size_indicated ? m.size : (def.bytes == 0 ? 4 : def.bytes);
      if (uint32_t code = WriteLocked(m.index, m.subindex, m.data.data(), size, now)) {
        AbortLocked(m.index, m.subindex, code, now);
        return;
      }
      SendSdoLocked(SdoMessage::InitiateDownloadResponse(m.index, m.subindex), now);
      return;
    }
    if (m.size_indicated) {
      const size_t limit = def.bytes == 0 ? kMaxStringSize : def.bytes;
      if (m.size > limit) {
        AbortLocked(m.index, m.subindex, sdo_abort::kLengthTooHigh, now);
        return;
      }
      if (def.bytes != 0 && m.size < def.bytes) {
        AbortLocked(m.index, m.subindex, sdo_abort::kLengthTooLow, now);
        return;
      }
    }
    sdo.kind = Transfer::Kind::kDownload;
    sdo.index = m.index;
    sdo.subindex = m.subindex;
    sdo.size_indicated = m.size_indicated;
    sdo.size = m.size;
    sdo.toggle = false;
    sdo.last_activity = now;
    SendSdoLocked(SdoMessage::InitiateDownloadResponse(m.index, m.subindex), now);
  }

  void DownloadSegmentLocked(const SdoMessage& m, common::Duration now) {
    if (sdo.kind != Transfer::Kind::kDownload) {
      AbortLocked(sdo.index, sdo.subindex, sdo_abort::kInvalidCommandSpecifier, now);
      return;
    }
    if (m.toggle != sdo.toggle) {
      AbortLocked(sdo.index, sdo.subindex, sdo_abort::kToggleBitNotAlternated, now);
      return;
    }
    sdo.data.insert(sdo.data.end(), m.data.begin(), m.data.begin() + m.data_length);
    if (sdo.data.size() > kMaxStringSize || (sdo.size_indicated && sdo.data.size() > sdo.size)) {
      AbortLocked(sdo.index, sdo.subindex, sdo_abort::kLengthTooHigh, now);
      return;
    }
    sdo.last_activity = now;
    sdo.toggle = !sdo.toggle;
    if (m.last) {
      const uint16_t index = sdo.index;
      const uint8_t sub = sdo.subindex;
      if (sdo.size_indicated && sdo.data.size() != sdo.size) {
        AbortLocked(index, sub, sdo_abort::kLengthMismatch, now);
        return;
      }
      const std::vector<uint8_t> data = std::move(sdo.data);
      sdo = Transfer{};
      if (uint32_t code = WriteLocked(index, sub, data.data(), data.size(), now)) {
        AbortLocked(index, sub, code, now);
        return;
      }
    }
    SendSdoLocked(SdoMessage::DownloadSegmentResponse(m.toggle), now);
  }

  void InitiateUploadLocked(const SdoMessage& m, common::Duration now) {
    sdo = Transfer{};
    std::vector<uint8_t> data;
    if (uint32_t code = ReadLocked(m.index, m.subindex, &data)) {
      AbortLocked(m.index, m.subindex, code, now);
      return;
    }
    if (!data.empty() && data.size() <= 4) {
      SendSdoLocked(SdoMessage::ExpeditedUploadResponse(m.index, m.subindex, data.data(),
                                                        static_cast<uint8_t>(data.size())),
                    now);
      return;
    }
    sdo.kind = Transfer::Kind::kUpload;
    sdo.index = m.index;
    sdo.subindex = m.subindex;
    sdo.data = std::move(data);
    sdo.offset = 0;
    sdo.toggle = false;
    sdo.last_activity = now;
    SendSdoLocked(SdoMessage::SegmentedUploadResponse(m.index, m.subindex,
                                                      static_cast<uint32_t>(sdo.data.size())),
                  now);
  }

  void UploadSegmentLocked(const SdoMessage& m, common::Duration now) {
    if (sdo.kind != Transfer::Kind::kUpload) {
      AbortLocked(sdo.index, sdo.subindex, sdo_abort::kInvalidCommandSpecifier, now);
      return;
    }
    if (m.toggle != sdo.toggle) {
      AbortLocked(sdo.index, sdo.subindex, sdo_abort::kToggleBitNotAlternated, now);
      return;
    }
    const size_t n = std::min<size_t>(7, sdo.data.size() - sdo.offset);
    const bool last = sdo.offset + n == sdo.data.size();
    const SdoMessage reply = SdoMessage::UploadSegmentResponse(
        sdo.toggle, sdo.data.data() + sdo.offset, static_cast<uint8_t>(n), last);
    sdo.offset += n;
    sdo.toggle = !sdo.toggle;
    sdo.last_activity = now;
    if (last) sdo = Transfer{};
    SendSdoLocked(reply, now);
  }

  // ------------------------------------------------------------------------------ PDOs
  size_t MappedBytes(const PdoMap& m) const {
    size_t bits = 0;
    for (int i = 0; i < m.count; ++i) bits += PdoMappingEntry::Decode(m.entries[i]).bits;
    return bits / 8;
  }

  void ApplyRpdoLocked(int n, const CanFrame& frame, common::Duration now) {
    const PdoMap& m = rpdo_map[n];
    size_t offset = 0;
    std::optional<uint16_t> controlword;
    for (int i = 0; i < m.count; ++i) {
      const PdoMappingEntry e = PdoMappingEntry::Decode(m.entries[i]);
      const int bytes = e.bits / 8;
      const uint32_t raw = GetLe(&frame.data[offset], bytes);
      offset += bytes;
      if (e.index == cia402::kControlword) {
        controlword = static_cast<uint16_t>(raw);  // applied last, as one PDO is one command
        continue;
      }
      SubDef def;
      if (Lookup(e.index, e.subindex, &def) != 0) continue;
      WriteNumericLocked(e.index, e.subindex, raw, def, now);
    }
    if (controlword) device.SetControlword(*controlword);
  }

  void HandleRpdoLocked(int n, const CanFrame& frame, common::Duration now) {
    if (frame.dlc < MappedBytes(rpdo_map[n])) {
      // CiA 301 would raise EMCY 0x8210; the simulator only reports it in the log.
      spdlog::debug("{}: RPDO{} with {} bytes, mapping needs {}; ignored", name, n + 1, frame.dlc,
                    MappedBytes(rpdo_map[n]));
      return;
    }
    ++stats.rpdos;
    if (IsSynchronousType(rpdo_comm[n].type)) {
      rpdo_buffer[n].pending = true;
      rpdo_buffer[n].frame = frame;
    } else {
      ApplyRpdoLocked(n, frame, now);
    }
  }

  CanFrame ComposeTpdoLocked(int n, const Snapshot& s) const {
    CanFrame f;
    f.id = tpdo_comm[n].id();
    const PdoMap& m = tpdo_map[n];
    size_t offset = 0;
    for (int i = 0; i < m.count; ++i) {
      const PdoMappingEntry e = PdoMappingEntry::Decode(m.entries[i]);
      const int bytes = e.bits / 8;
      PutLe(&f.data[offset], NumericLocked(e.index, e.subindex, s), bytes);
      offset += bytes;
    }
    f.dlc = static_cast<uint8_t>(offset);
    return f;
  }

  void SendTpdoLocked(int n, const CanFrame& f, common::Duration now) {
    TpdoState& t = tpdo_state[n];
    t.sent_once = true;
    t.last = f;
    t.last_sent = now;
    t.next_event = now + std::chrono::milliseconds(tpdo_comm[n].event_timer_ms);
    if (SendReplyLocked(f, false, now)) ++stats.tpdos;
  }

  void HandleSyncLocked(common::Duration now) {
    if (nmt == NmtState::kStopped) return;
    ++stats.syncs;
    last_sync = now;
    synced = true;
    const bool operational = nmt == NmtState::kOperational;
    if (operational) {
      for (int n = 0; n < 4; ++n) {
        if (!rpdo_buffer[n].pending) continue;
        rpdo_buffer[n].pending = false;
        if (rpdo_comm[n].valid()) ApplyRpdoLocked(n, rpdo_buffer[n].frame, now);
      }
    }
    StepDeviceLocked(now);
    SendEmcysLocked();
    if (!operational) return;
    const Snapshot s = device.snapshot();
    for (int n = 0; n < 4; ++n) {
      const PdoComm& c = tpdo_comm[n];
      if (!c.valid() || !IsSynchronousType(c.type)) continue;
      TpdoState& t = tpdo_state[n];
      const CanFrame f = ComposeTpdoLocked(n, s);
      if (c.type == 0) {
        if (!t.sent_once || f != t.last) SendTpdoLocked(n, f, now);
        continue;
      }
      if (++t.sync_count >= c.type) {
        t.sync_count = 0;
        SendTpdoLocked(n, f, now);
      }
    }
  }

  void EventTpdosLocked(common::Duration now) {
    if (nmt != NmtState::kOperational) return;
    std::optional<Snapshot> s;
    for (int n = 0; n < 4; ++n) {
      const PdoComm& c = tpdo_comm[n];
      if (!c.valid() || IsSynchronousType(c.type)) continue;
      if (!s) s = device.snapshot();
      TpdoState& t = tpdo_state[n];
      const CanFrame f = ComposeTpdoLocked(n, *s);
      const bool changed = !t.sent_once || f != t.last;
      const bool inhibit_over =
          !t.sent_once || now - t.last_sent >= std::chrono::microseconds(100) * c.inhibit_100us;
      const bool timer_due = c.event_timer_ms > 0 && now >= t.next_event;
      if ((changed && inhibit_over) || timer_due) SendTpdoLocked(n, f, now);
    }
  }

  // ------------------------------------------------------------------------------ time
  void StepDeviceLocked(common::Duration now) {
    if (now <= last_step) return;
    const double dt = std::chrono::duration<double>(now - last_step).count();
    last_step = now;
    device.Step(dt);
  }

  void SendEmcysLocked() {
    std::vector<uint16_t> codes;
    {
      std::lock_guard<std::mutex> lock(emcy_mutex);
      codes.swap(emcy_pending);
    }
    for (uint16_t code : codes) {
      if (nmt != NmtState::kPreOperational && nmt != NmtState::kOperational) continue;
      EmcyMessage e;
      e.node = node();
      e.error_code = code;
      e.error_register = ErrorRegisterFor(code);
      if (SendOtherLocked(EncodeEmcy(e))) {
        ++stats.emcys;
        spdlog::debug("{}: EMCY 0x{:04X} ({})", name, code, EmcyErrorText(code));
      }
    }
  }

  void TimeEventsLocked(common::Duration now) {
    const Cia402State state = device.state();
    const auto mode = DriveModeFromValue(device.mode_display());
    const bool sync_driven = state == Cia402State::kOperationEnabled && mode &&
                             IsCyclicMode(*mode) && synced && now - last_sync < kSyncLossTimeout;
    if (!sync_driven) StepDeviceLocked(now);
    SendEmcysLocked();
    EventTpdosLocked(now);
    if (sdo.kind != Transfer::Kind::kNone && now - sdo.last_activity > kSdoTimeout) {
      AbortLocked(sdo.index, sdo.subindex, sdo_abort::kProtocolTimedOut, now);
    }
    if (heartbeat_ms > 0 && now >= next_heartbeat) {
      if (!heartbeat_stopped && SendOtherLocked(EncodeHeartbeat(node(), nmt))) ++stats.heartbeats;
      next_heartbeat += std::chrono::milliseconds(heartbeat_ms);
      if (next_heartbeat <= now) next_heartbeat = now + std::chrono::milliseconds(heartbeat_ms);
    }
    while (!delayed.empty() && delayed.front().first <= now) {
      if (!disconnected) SendRaw(delayed.front().second);
      delayed.pop_front();
    }
  }

  // ------------------------------------------------------------------------------ frames
  void HandleFrameLocked(const CanFrame& f, common::Duration now) {
    if (disconnected || f.extended) return;
    if (auto nmt_message = DecodeNmt(f)) {
      HandleNmtLocked(*nmt_message, now);
      return;
    }
    if (IsSync(f)) {
      HandleSyncLocked(now);
      return;
    }
    if (f.id == kSdoRequestBase + node()) {
      HandleSdoLocked(f, now);
      return;
    }
    if (nmt != NmtState::kOperational || f.rtr) return;
    for (int n = 0; n < 4; ++n) {
      if (rpdo_comm[n].valid() && f.id == rpdo_comm[n].id()) {
        HandleRpdoLocked(n, f, now);
        return;
      }
    }
  }

  // One pass: `first` (already received) and every frame waiting, then the time events.
  void ServeLocked(const CanFrame* first) {
    common::Duration now = clock->Now();
    if (!booted) BootLocked(now);
    if (first != nullptr) HandleFrameLocked(*first, now);
    CanFrame f;
    while (!bus->Receive(&f, std::chrono::microseconds::zero())) {
      now = clock->Now();
      HandleFrameLocked(f, now);
    }
    TimeEventsLocked(clock->Now());
  }

  void Loop() {
    while (running.load()) {
      CanFrame f;
      const std::error_code ec = bus->Receive(&f, kThreadPoll);
      std::lock_guard<std::mutex> lock(mutex);
      ServeLocked(ec ? nullptr : &f);
      if (ec && ec != Errc::kTimeout) {
        // A bus that is gone does not come back by polling it faster.
        std::this_thread::sleep_for(kThreadPoll);
      }
    }
  }
};

CanopenDriveSim::CanopenDriveSim(CanBus* bus, common::Clock* clock, Options options) {
  std::string problems;
  if (options.node < 1 || options.node > kMaxNodeId) {
    problems += " node " + std::to_string(options.node) + " is outside 1..127;";
  }
  if (bus == nullptr) problems += " no CAN bus given;";
  if (clock == nullptr) problems += " no clock given;";
  const std::string device_problems = Cia402Device::ValidateOptions(options.device);
  if (!device_problems.empty()) problems += " device: " + device_problems + ";";
  if (!problems.empty()) {
    problems.pop_back();
    throw common::ConfigError("CanopenDriveSim:" + problems);
  }
  impl_ = std::make_unique<Impl>(bus, clock, options);
}

CanopenDriveSim::~CanopenDriveSim() { Stop(); }

void CanopenDriveSim::Start() {
  if (impl_->running.exchange(true)) return;
  impl_->thread = std::thread([this] { impl_->Loop(); });
}

void CanopenDriveSim::Stop() {
  if (!impl_->running.exchange(false)) return;
  if (impl_->thread.joinable()) impl_->thread.join();
}

void CanopenDriveSim::Service() {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->ServeLocked(nullptr);
}

uint8_t CanopenDriveSim::node() const { return impl_->options.node; }

canopen::NmtState CanopenDriveSim::nmt_state() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->nmt;
}

Cia402Device& CanopenDriveSim::device() { return impl_->device; }

void CanopenDriveSim::DropNextReplies(int n) {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->drop_replies = std::max(0, n);
}

void CanopenDriveSim::SetReplyDelay(std::chrono::microseconds delay) {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->reply_delay = std::max(common::Duration::zero(), common::Duration(delay));
}

void CanopenDriveSim::SendMalformedSdoReplies(int n) {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->malformed_replies = std::max(0, n);
}

void CanopenDriveSim::StopHeartbeat(bool stopped) {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->heartbeat_stopped = stopped;
}

void CanopenDriveSim::Disconnect(bool disconnected) {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->disconnected = disconnected;
  if (disconnected) impl_->delayed.clear();
}

void CanopenDriveSim::RaiseFault(uint16_t error_code) { impl_->device.RaiseFault(error_code); }

CanopenDriveSim::Statistics CanopenDriveSim::statistics() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->stats;
}

}  // namespace kinevis::hal
