// libFuzzer target for the Dynamixel decoders (hal/dynamixel/protocol1.h, protocol2.h).
// Build: clang++ -std=c++17 -g -O1 -fsanitize=fuzzer,address,undefined -I. \
//          fuzz/dynamixel_fuzz.cc hal/dynamixel/protocol1.cc hal/dynamixel/protocol2.cc
// The input is fed to a status and an instruction decoder of each protocol, whole and in pieces
// whose sizes come from the input itself. Every packet handed out must re-encode to a packet that
// decodes to the same fields; a violation traps.

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "hal/dynamixel/protocol1.h"
#include "hal/dynamixel/protocol2.h"

namespace {

using kinevis::hal::Dxl1Decoder;
using kinevis::hal::Dxl2Decoder;
using kinevis::hal::DxlInstruction;
using kinevis::hal::DxlPacket;
using kinevis::hal::DxlPacketKind;

void Check(bool condition) {
  if (!condition) __builtin_trap();
}

struct Fields {
  uint8_t id;
  uint8_t instruction;
  uint8_t error;
  std::vector<uint8_t> params;
};

Fields Copy(const DxlPacket& p) { return {p.id, p.instruction, p.error, p.ParamVector()}; }

// Re-encodes a decoded packet and decodes it again with a fresh decoder.
template <typename Decoder>
void RoundTrip(int protocol, DxlPacketKind kind, const Fields& f) {
  std::vector<uint8_t> bytes;
  const bool status = kind == DxlPacketKind::kStatus;
  if (protocol == 1) {
    bytes = status ? kinevis::hal::Dxl1StatusPacket(f.id, f.error, f.params)
                   : kinevis::hal::Dxl1InstructionPacket(
                         f.id, static_cast<DxlInstruction>(f.instruction), f.params);
  } else {
    bytes = status ? kinevis::hal::Dxl2StatusPacket(f.id, f.error, f.params)
                   : kinevis::hal::Dxl2InstructionPacket(
                         f.id, static_cast<DxlInstruction>(f.instruction), f.params);
  }
  Check(!bytes.empty());
  Decoder again(kind);
  int count = 0;
  again.FeedAll(bytes.data(), bytes.size(), [&](const DxlPacket& p) {
    ++count;
    Check(p.id == f.id && p.instruction == f.instruction && p.error == f.error);
    Check(p.ParamVector() == f.params);
  });
  Check(count == 1);
  Check(again.stats().checksum_errors == 0);
}

template <typename Decoder>
void Run(int protocol, DxlPacketKind kind, const uint8_t* data, size_t size) {
  // Whole.
  Decoder whole(kind);
  std::vector<Fields> a;
  whole.FeedAll(data, size, [&](const DxlPacket& p) { a.push_back(Copy(p)); });
  // In pieces of 1..16 bytes, chosen by the data.
  Decoder pieces(kind);
  std::vector<Fields> b;
  size_t at = 0;
  while (at < size) {
    const size_t n = std::min<size_t>(size - at, 1 + (data[at] & 0x0F));
    pieces.FeedAll(data + at, n, [&](const DxlPacket& p) { b.push_back(Copy(p)); });
    at += n;
  }
  // The split must not change what comes out.
  Check(a.size() == b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    Check(a[i].id == b[i].id && a[i].error == b[i].error && a[i].params == b[i].params);
    RoundTrip<Decoder>(protocol, kind, a[i]);
  }
  Check(whole.stats().packets == a.size());
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  Run<Dxl1Decoder>(1, DxlPacketKind::kStatus, data, size);
  Run<Dxl1Decoder>(1, DxlPacketKind::kInstruction, data, size);
  Run<Dxl2Decoder>(2, DxlPacketKind::kStatus, data, size);
  Run<Dxl2Decoder>(2, DxlPacketKind::kInstruction, data, size);
  return 0;
}
