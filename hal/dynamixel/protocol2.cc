#include "hal/dynamixel/protocol2.h"

#include <array>
#include <cstring>

namespace kinevis::hal {
namespace {

constexpr std::array<uint16_t, 256> MakeCrcTable() {
  std::array<uint16_t, 256> table{};
  for (unsigned i = 0; i < 256; ++i) {
    unsigned crc = i << 8;
    for (int bit = 0; bit < 8; ++bit) {
      crc = (crc & 0x8000u) != 0 ? (crc << 1) ^ 0x8005u : crc << 1;
    }
    table[i] = static_cast<uint16_t>(crc & 0xFFFFu);
  }
  return table;
}

constexpr std::array<uint16_t, 256> kCrcTable = MakeCrcTable();

// Writes the body (the instruction byte, then `prefix` when there is one, then the parameters)
// with stuffing, the header and the CRC. Returns 0 when it does not fit.
size_t Encode(uint8_t id, uint8_t instruction, const uint8_t* prefix, const uint8_t* params,
              size_t param_count, uint8_t* out, size_t capacity) {
  if (id == 0xFD || id == 0xFF) return 0;
  const size_t body_in = 1 + (prefix != nullptr ? 1 : 0) + param_count;
  if (capacity < kDxl2HeaderSize + body_in + 2) return 0;
  out[0] = 0xFF;
  out[1] = 0xFF;
  out[2] = 0xFD;
  out[3] = 0x00;
  out[4] = id;
  size_t pos = kDxl2HeaderSize;
  // The last three body bytes as sent (a stuffed FD is not counted: FF FF FD FD ends the match).
  uint32_t window = 0;
  auto put = [&](uint8_t b) -> bool {
    if (pos + 2 >= capacity) return false;  // keep room for the CRC
    out[pos++] = b;
    window = ((window << 8) | b) & 0xFFFFFFu;
    if (window == 0xFFFFFDu) {
      if (pos + 2 >= capacity) return false;
      out[pos++] = 0xFD;
      window = 0;
    }
    return true;
  };
  bool ok = put(instruction);
  if (ok && prefix != nullptr) ok = put(*prefix);
  for (size_t i = 0; ok && i < param_count; ++i) ok = put(params[i]);
  if (!ok) return 0;
  const size_t len = pos - kDxl2HeaderSize + 2;
  if (len > 0xFFFF) return 0;
  out[5] = static_cast<uint8_t>(len & 0xFF);
  out[6] = static_cast<uint8_t>(len >> 8);
  const uint16_t crc = Dxl2Crc16(out, pos);
  out[pos++] = static_cast<uint8_t>(crc & 0xFF);
  out[pos++] = static_cast<uint8_t>(crc >> 8);
  return pos;
}

std::string JoinBits(uint8_t bits, const char* (*name_of)(uint8_t)) {
  if (bits == 0) return "none";
  std::string text;
  for (int i = 0; i < 8; ++i) {
    const uint8_t bit = static_cast<uint8_t>(1u << i);
    if ((bits & bit) == 0) continue;
    if (!text.empty()) text += ", ";
    const char* name = name_of(bit);
    text += name != nullptr ? name : "bit " + std::to_string(i);
  }
  return text;
}

const char* HardwareErrorBitName(uint8_t bit) {
  switch (bit) {
    case kDxl2HwInputVoltage:
      return "input voltage";
    case kDxl2HwOverheating:
      return "overheating";
    case kDxl2HwMotorEncoder:
      return "motor encoder";
    case kDxl2HwElectricalShock:
      return "electrical shock";
    case kDxl2HwOverload:
      return "overload";
    default:
      return nullptr;
  }
}

}  // namespace

std::string Dxl2ErrorCodeName(uint8_t code) {
  switch (static_cast<Dxl2ErrorCode>(code)) {
    case Dxl2ErrorCode::kNone:
      return "none";
    case Dxl2ErrorCode::kResultFail:
      return "result fail";
    case Dxl2ErrorCode::kInstructionError:
      return "instruction error";
    case Dxl2ErrorCode::kCrcError:
      return "CRC error";
    case Dxl2ErrorCode::kDataRangeError:
      return "data range error";
    case Dxl2ErrorCode::kDataLengthError:
      return "data length error";
    case Dxl2ErrorCode::kDataLimitError:
      return "data limit error";
    case Dxl2ErrorCode::kAccessError:
      return "access error";
  }
  return "error code " + std::to_string(code);
}

std::string Dxl2ErrorText(uint8_t error) {
  const uint8_t code = error & 0x7F;
  const bool alert = (error & kDxl2AlertBit) != 0;
  if (!alert) return Dxl2ErrorCodeName(code);
  return code == 0 ? "alert" : "alert, " + Dxl2ErrorCodeName(code);
}

std::string Dxl2HardwareErrorText(uint8_t bits) { return JoinBits(bits, HardwareErrorBitName); }

uint16_t Dxl2Crc16(const uint8_t* data, size_t size, uint16_t crc) {
  for (size_t i = 0; i < size; ++i) {
    const uint8_t index = static_cast<uint8_t>((crc >> 8) ^ data[i]);
    crc = static_cast<uint16_t>((crc << 8) ^ kCrcTable[index]);
  }
  return crc;
}

size_t EncodeDxl2Instruction(uint8_t id, uint8_t instruction, const uint8_t* params,
                             size_t param_count, uint8_t* out, size_t capacity) {
  return Encode(id, instruction, nullptr, params, param_count, out, capacity);
}

size_t EncodeDxl2Status(uint8_t id, uint8_t error, const uint8_t* params, size_t param_count,
                        uint8_t* out, size_t capacity) {
  return Encode(id, static_cast<uint8_t>(DxlInstruction::kStatus), &error, params, param_count, out,
                capacity);
}

std::vector<uint8_t> Dxl2InstructionPacket(uint8_t id, DxlInstruction instruction,
                                           const std::vector<uint8_t>& params) {
  std::vector<uint8_t> out(Dxl2MaxEncodedSize(params.size()));
  out.resize(EncodeDxl2Instruction(id, static_cast<uint8_t>(instruction), params.data(),
                                   params.size(), out.data(), out.size()));
  return out;
}

std::vector<uint8_t> Dxl2StatusPacket(uint8_t id, uint8_t error,
                                      const std::vector<uint8_t>& params) {
  std::vector<uint8_t> out(Dxl2MaxEncodedSize(params.size() + 1));
  out.resize(EncodeDxl2Status(id, error, params.data(), params.size(), out.data(), out.size()));
  return out;
}

Dxl2Decoder::Dxl2Decoder(DxlPacketKind kind, size_t max_packet_size)
    : kind_(kind),
      max_packet_size_(max_packet_size < 11 ? 11 : max_packet_size),
      buffer_(2 * max_packet_size_),
      payload_(max_packet_size_) {}

void Dxl2Decoder::Reset() {
  begin_ = end_ = 0;
  has_packet_ = false;
}

void Dxl2Decoder::Drop() {
  ++begin_;
  ++stats_.discarded_bytes;
}

bool Dxl2Decoder::Parse() {
  static constexpr uint8_t kHeader[4] = {0xFF, 0xFF, 0xFD, 0x00};
  const size_t min_len = kind_ == DxlPacketKind::kStatus ? 4 : 3;
  while (end_ > begin_) {
    const uint8_t* p = buffer_.data() + begin_;
    const size_t avail = end_ - begin_;
    // Compare the header bytes that have arrived so far.
    bool header_ok = true;
    for (size_t i = 0; i < 4 && i < avail; ++i) header_ok = header_ok && p[i] == kHeader[i];
    if (!header_ok) {
      Drop();
      continue;
    }
    if (avail < 5) return false;
    if (p[4] == 0xFD || p[4] == 0xFF) {
      Drop();
      continue;
    }
    if (avail < kDxl2HeaderSize) return false;
    const size_t len = static_cast<size_t>(p[5]) | static_cast<size_t>(p[6]) << 8;
    const size_t total = kDxl2HeaderSize + len;
    if (len < min_len || total > max_packet_size_) {
      ++stats_.malformed;
      Drop();
      continue;
    }
    if (avail < total) return false;
    const uint16_t crc = static_cast<uint16_t>(p[total - 2] | p[total - 1] << 8);
    if (Dxl2Crc16(p, total - 2) != crc) {
      ++stats_.checksum_errors;
      Drop();
      continue;
    }
    // Remove the stuffing: an FD that follows FF FF FD in the body is dropped.
    size_t n = 0;
    uint32_t window = 0;
    bool stuffing_ok = true;
    bool skip_next = false;
    for (size_t i = kDxl2HeaderSize; i < total - 2; ++i) {
      const uint8_t b = p[i];
      if (skip_next) {
        skip_next = false;
        if (b != 0xFD) {
          stuffing_ok = false;
          break;
        }
        continue;
      }
      payload_[n++] = b;
      window = ((window << 8) | b) & 0xFFFFFFu;
      if (window == 0xFFFFFDu) {
        skip_next = true;
        window = 0;
      }
    }
    // A body may not end in an unstuffed FF FF FD either.
    if (!stuffing_ok || skip_next) {
      ++stats_.malformed;
      Drop();
      continue;
    }
    const bool is_status = payload_[0] == static_cast<uint8_t>(DxlInstruction::kStatus);
    if (is_status != (kind_ == DxlPacketKind::kStatus) || (is_status && n < 2)) {
      // A valid packet of the other direction (or a status packet without its error field):
      // skip it whole.
      if (is_status == (kind_ == DxlPacketKind::kStatus)) {
        ++stats_.malformed;
      } else {
        ++stats_.ignored;
      }
      begin_ += total;
      continue;
    }
    packet_.id = p[4];
    packet_.instruction = payload_[0];
    if (is_status) {
      packet_.error = payload_[1];
      packet_.params = payload_.data() + 2;
      packet_.param_count = n - 2;
    } else {
      packet_.error = 0;
      packet_.params = payload_.data() + 1;
      packet_.param_count = n - 1;
    }
    begin_ += total;
    ++stats_.packets;
    return true;
  }
  return false;
}

size_t Dxl2Decoder::Feed(const uint8_t* data, size_t size) {
  has_packet_ = false;
  if (begin_ == end_) begin_ = end_ = 0;
  if (Parse()) {
    has_packet_ = true;
    return 0;
  }
  size_t used = 0;
  while (used < size) {
    if (end_ == buffer_.size()) {
      // What is held is always less than one packet, so this frees at least half the buffer.
      std::memmove(buffer_.data(), buffer_.data() + begin_, end_ - begin_);
      end_ -= begin_;
      begin_ = 0;
    }
    buffer_[end_++] = data[used++];
    if (Parse()) {
      has_packet_ = true;
      return used;
    }
  }
  return used;
}

}  // namespace kinevis::hal
