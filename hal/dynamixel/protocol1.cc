#include "hal/dynamixel/protocol1.h"

#include <cstdio>
#include <cstring>

namespace kinevis::hal {

std::string ToString(DxlInstruction instruction) {
  switch (instruction) {
    case DxlInstruction::kPing:
      return "ping";
    case DxlInstruction::kRead:
      return "read";
    case DxlInstruction::kWrite:
      return "write";
    case DxlInstruction::kRegWrite:
      return "reg write";
    case DxlInstruction::kAction:
      return "action";
    case DxlInstruction::kFactoryReset:
      return "factory reset";
    case DxlInstruction::kReboot:
      return "reboot";
    case DxlInstruction::kClear:
      return "clear";
    case DxlInstruction::kStatus:
      return "status";
    case DxlInstruction::kSyncRead:
      return "sync read";
    case DxlInstruction::kSyncWrite:
      return "sync write";
    case DxlInstruction::kBulkRead:
      return "bulk read";
    case DxlInstruction::kBulkWrite:
      return "bulk write";
  }
  char text[8];
  std::snprintf(text, sizeof text, "0x%02X", static_cast<unsigned>(instruction));
  return text;
}

const char* Dxl1ErrorBitName(uint8_t bit) {
  switch (bit) {
    case kDxl1InputVoltageError:
      return "input voltage";
    case kDxl1AngleLimitError:
      return "angle limit";
    case kDxl1OverheatingError:
      return "overheating";
    case kDxl1RangeError:
      return "range";
    case kDxl1ChecksumError:
      return "checksum";
    case kDxl1OverloadError:
      return "overload";
    case kDxl1InstructionError:
      return "instruction";
    default:
      return nullptr;
  }
}

std::string Dxl1ErrorText(uint8_t error) {
  if (error == 0) return "none";
  std::string text;
  for (int i = 0; i < 8; ++i) {
    const uint8_t bit = static_cast<uint8_t>(1u << i);
    if ((error & bit) == 0) continue;
    if (!text.empty()) text += ", ";
    const char* name = Dxl1ErrorBitName(bit);
    text += name != nullptr ? name : "bit " + std::to_string(i);
  }
  return text;
}

uint8_t Dxl1Checksum(const uint8_t* data, size_t size) {
  unsigned sum = 0;
  for (size_t i = 0; i < size; ++i) sum += data[i];
  return static_cast<uint8_t>(~sum & 0xFFu);
}

size_t EncodeDxl1Packet(uint8_t id, uint8_t code, const uint8_t* params, size_t param_count,
                        uint8_t* out, size_t capacity) {
  const size_t total = param_count + 6;
  if (param_count > kDxl1MaxParams || id == 0xFF || capacity < total) return 0;
  out[0] = 0xFF;
  out[1] = 0xFF;
  out[2] = id;
  out[3] = static_cast<uint8_t>(param_count + 2);
  out[4] = code;
  if (param_count > 0) std::memcpy(out + 5, params, param_count);
  out[total - 1] = Dxl1Checksum(out + 2, total - 3);
  return total;
}

namespace {

std::vector<uint8_t> EncodeToVector(uint8_t id, uint8_t code, const std::vector<uint8_t>& params) {
  std::vector<uint8_t> out(params.size() + 6);
  const size_t n = EncodeDxl1Packet(id, code, params.data(), params.size(), out.data(), out.size());
  out.resize(n);
  return out;
}

}  // namespace

std::vector<uint8_t> Dxl1InstructionPacket(uint8_t id, DxlInstruction instruction,
                                           const std::vector<uint8_t>& params) {
  return EncodeToVector(id, static_cast<uint8_t>(instruction), params);
}

std::vector<uint8_t> Dxl1StatusPacket(uint8_t id, uint8_t error,
                                      const std::vector<uint8_t>& params) {
  return EncodeToVector(id, error, params);
}

Dxl1Decoder::Dxl1Decoder(DxlPacketKind kind) : kind_(kind) {}

void Dxl1Decoder::Reset() {
  begin_ = end_ = 0;
  has_packet_ = false;
}

void Dxl1Decoder::Drop() {
  ++begin_;
  ++stats_.discarded_bytes;
}

bool Dxl1Decoder::Parse() {
  while (end_ > begin_) {
    const uint8_t* p = buffer_.data() + begin_;
    const size_t avail = end_ - begin_;
    if (p[0] != 0xFF) {
      Drop();
      continue;
    }
    if (avail < 2) return false;
    if (p[1] != 0xFF) {
      Drop();
      continue;
    }
    if (avail < 3) return false;
    // FF FF FF: no id is 0xFF, so the header can only start at the second FF.
    if (p[2] == 0xFF) {
      Drop();
      continue;
    }
    if (avail < 4) return false;
    const size_t len = p[3];
    if (len < 2) {
      ++stats_.malformed;
      Drop();
      continue;
    }
    const size_t total = 4 + len;
    if (avail < total) return false;
    if (Dxl1Checksum(p + 2, total - 3) != p[total - 1]) {
      // Rescan from the next byte: the "header" may have been noise inside other bytes, and a
      // real packet may start within what was taken for this one.
      ++stats_.checksum_errors;
      Drop();
      continue;
    }
    packet_.id = p[2];
    if (kind_ == DxlPacketKind::kStatus) {
      packet_.instruction = static_cast<uint8_t>(DxlInstruction::kStatus);
      packet_.error = p[4];
    } else {
      packet_.instruction = p[4];
      packet_.error = 0;
    }
    packet_.params = p + 5;
    packet_.param_count = len - 2;
    begin_ += total;
    ++stats_.packets;
    return true;
  }
  return false;
}

size_t Dxl1Decoder::Feed(const uint8_t* data, size_t size) {
  has_packet_ = false;
  if (begin_ == end_) begin_ = end_ = 0;
  // A rescan may have left a whole packet behind the one handed out last.
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
    // One byte at a time: Parse() is O(1) until a candidate packet is complete.
    buffer_[end_++] = data[used++];
    if (Parse()) {
      has_packet_ = true;
      return used;
    }
  }
  return used;
}

}  // namespace kinevis::hal
