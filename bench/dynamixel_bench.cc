// Dynamixel packet codecs (hal/dynamixel/protocol1.h, protocol2.h): encode + decode of the packets
// a cyclic read of present positions exchanges. Target: at least 1 M packets/s per protocol, far
// above what any serial line carries (a 14-byte 2.0 status at 4.5 Mbit/s is ~32 k packets/s).
// Reported as items/s (packets) and bytes/s.

#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstdint>
#include <type_traits>
#include <vector>

#include "hal/dynamixel/protocol1.h"
#include "hal/dynamixel/protocol2.h"

namespace kinevis::hal {
namespace {

// A status packet with a 4-byte present position: encoded, then decoded.
void BM_Dxl1StatusEncodeDecode(benchmark::State& state) {
  Dxl1Decoder decoder(DxlPacketKind::kStatus);
  uint8_t packet[kDxl1MaxPacketSize];
  uint8_t params[4] = {0x00, 0x08, 0x00, 0x00};
  uint64_t bytes = 0;
  uint32_t sum = 0;
  for (auto _ : state) {
    params[0] = static_cast<uint8_t>(bytes);
    const size_t n = EncodeDxl1Packet(1, 0, params, sizeof params, packet, sizeof packet);
    decoder.FeedAll(packet, n, [&](const DxlPacket& p) { sum += p.params[0]; });
    bytes += n;
  }
  benchmark::DoNotOptimize(sum);
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations()));
  state.SetBytesProcessed(static_cast<int64_t>(bytes));
}
BENCHMARK(BM_Dxl1StatusEncodeDecode);

void BM_Dxl2StatusEncodeDecode(benchmark::State& state) {
  Dxl2Decoder decoder(DxlPacketKind::kStatus);
  uint8_t packet[64];
  uint8_t params[4] = {0x00, 0x08, 0x00, 0x00};
  uint64_t bytes = 0;
  uint32_t sum = 0;
  for (auto _ : state) {
    params[0] = static_cast<uint8_t>(bytes);
    const size_t n = EncodeDxl2Status(1, 0, params, sizeof params, packet, sizeof packet);
    decoder.FeedAll(packet, n, [&](const DxlPacket& p) { sum += p.params[0]; });
    bytes += n;
  }
  benchmark::DoNotOptimize(sum);
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations()));
  state.SetBytesProcessed(static_cast<int64_t>(bytes));
}
BENCHMARK(BM_Dxl2StatusEncodeDecode);

// The host's side of one cycle: a read instruction encoded, its status decoded (2.0).
void BM_Dxl2ReadRequestAndStatus(benchmark::State& state) {
  Dxl2Decoder decoder(DxlPacketKind::kStatus);
  uint8_t request[32];
  const uint8_t read_params[4] = {0x84, 0x00, 0x04, 0x00};
  const std::vector<uint8_t> status = Dxl2StatusPacket(1, 0, {0xA6, 0x00, 0x00, 0x00});
  uint64_t bytes = 0;
  uint32_t sum = 0;
  for (auto _ : state) {
    const size_t n =
        EncodeDxl2Instruction(1, static_cast<uint8_t>(DxlInstruction::kRead), read_params,
                              sizeof read_params, request, sizeof request);
    benchmark::DoNotOptimize(request[n - 1]);
    decoder.FeedAll(status.data(), status.size(), [&](const DxlPacket& p) { sum += p.id; });
    bytes += n + status.size();
  }
  benchmark::DoNotOptimize(sum);
  state.SetItemsProcessed(static_cast<int64_t>(2 * state.iterations()));
  state.SetBytesProcessed(static_cast<int64_t>(bytes));
}
BENCHMARK(BM_Dxl2ReadRequestAndStatus);

// Worst case for stuffing: parameters full of FF FF FD.
void BM_Dxl2StuffedEncodeDecode(benchmark::State& state) {
  Dxl2Decoder decoder(DxlPacketKind::kStatus);
  std::vector<uint8_t> params;
  for (int i = 0; i < 10; ++i) params.insert(params.end(), {0xFF, 0xFF, 0xFD});
  std::vector<uint8_t> packet(Dxl2MaxEncodedSize(params.size() + 1));
  uint64_t bytes = 0;
  size_t got = 0;
  for (auto _ : state) {
    const size_t n =
        EncodeDxl2Status(1, 0, params.data(), params.size(), packet.data(), packet.size());
    decoder.FeedAll(packet.data(), n, [&](const DxlPacket& p) { got += p.param_count; });
    bytes += n;
  }
  benchmark::DoNotOptimize(got);
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations()));
  state.SetBytesProcessed(static_cast<int64_t>(bytes));
}
BENCHMARK(BM_Dxl2StuffedEncodeDecode);

// Decoding only, from a stream of 1000 status packets fed in 64-byte reads (as from a UART).
template <int kProtocol>
void BM_DecodeStream(benchmark::State& state) {
  std::vector<uint8_t> stream;
  for (int i = 0; i < 1000; ++i) {
    const std::vector<uint8_t> params = {static_cast<uint8_t>(i), 0x08, 0x00, 0x00};
    const std::vector<uint8_t> p = kProtocol == 1
                                       ? Dxl1StatusPacket(static_cast<uint8_t>(i % 200), 0, params)
                                       : Dxl2StatusPacket(static_cast<uint8_t>(i % 200), 0, params);
    stream.insert(stream.end(), p.begin(), p.end());
  }
  size_t packets = 0;
  for (auto _ : state) {
    typename std::conditional<kProtocol == 1, Dxl1Decoder, Dxl2Decoder>::type decoder(
        DxlPacketKind::kStatus);
    for (size_t at = 0; at < stream.size(); at += 64) {
      const size_t n = std::min<size_t>(64, stream.size() - at);
      decoder.FeedAll(stream.data() + at, n, [&](const DxlPacket&) { ++packets; });
    }
  }
  benchmark::DoNotOptimize(packets);
  state.SetItemsProcessed(static_cast<int64_t>(packets));
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * stream.size()));
}
BENCHMARK_TEMPLATE(BM_DecodeStream, 1);
BENCHMARK_TEMPLATE(BM_DecodeStream, 2);

void BM_Dxl2Crc16(benchmark::State& state) {
  std::vector<uint8_t> data(static_cast<size_t>(state.range(0)));
  for (size_t i = 0; i < data.size(); ++i) data[i] = static_cast<uint8_t>(i * 31);
  uint16_t crc = 0;
  for (auto _ : state) crc ^= Dxl2Crc16(data.data(), data.size());
  benchmark::DoNotOptimize(crc);
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * data.size()));
}
BENCHMARK(BM_Dxl2Crc16)->Arg(16)->Arg(256);

}  // namespace
}  // namespace kinevis::hal
