// slcan (Lawicel ASCII) codec throughput: frames encoded and decoded per second. For scale: a
// 1 Mbit/s CAN bus at 100 % load carries about 8,000 frames/s of 8 bytes, 17,000 of 0 bytes.

#include <benchmark/benchmark.h>

#include <algorithm>
#include <random>
#include <string>
#include <vector>

#include "hal/can/slcan_codec.h"

namespace kinevis::hal {
namespace {

// A fixed, seeded mix of standard and extended frames with 0..8 data bytes.
std::vector<CanFrame> FrameMix(size_t n) {
  std::mt19937 rng(42);
  std::uniform_int_distribution<int> byte(0, 255), dlc(0, 8), coin(0, 1);
  std::vector<CanFrame> frames(n);
  for (CanFrame& f : frames) {
    f.extended = coin(rng) == 1;
    f.id = std::uniform_int_distribution<uint32_t>(
        0, f.extended ? CanFrame::kMaxExtendedId : CanFrame::kMaxStandardId)(rng);
    f.dlc = static_cast<uint8_t>(dlc(rng));
    for (int i = 0; i < f.dlc; ++i) f.data[i] = static_cast<uint8_t>(byte(rng));
  }
  return frames;
}

void BM_SlcanEncodeFrame(benchmark::State& state) {
  const bool timestamps = state.range(0) != 0;
  const std::vector<CanFrame> frames = FrameMix(1024);
  char line[kSlcanMaxLineSize];
  size_t i = 0, bytes = 0;
  for (auto _ : state) {
    const CanFrame& f = frames[i++ & 1023];
    const size_t n = EncodeSlcanFrame(
        f, line,
        timestamps ? std::optional<uint16_t>(static_cast<uint16_t>(i % 60000)) : std::nullopt);
    benchmark::DoNotOptimize(line);
    bytes += n;
  }
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations()));
  state.SetBytesProcessed(static_cast<int64_t>(bytes));
  state.SetLabel(timestamps ? "with timestamps" : "no timestamps");
}
BENCHMARK(BM_SlcanEncodeFrame)->Arg(0)->Arg(1);

// Decodes an adapter stream in 256-byte reads, as SlcanBus's reader thread does. Arg: percent of
// the lines that are garbage.
void BM_SlcanDecodeStream(benchmark::State& state) {
  const int garbage_percent = static_cast<int>(state.range(0));
  const std::vector<CanFrame> frames = FrameMix(4096);
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> percent(0, 99);
  std::string stream;
  int64_t valid = 0;
  for (size_t i = 0; i < frames.size(); ++i) {
    if (percent(rng) < garbage_percent) {
      stream += "x#garbage!\r";
    } else {
      stream += SlcanFrameLine(frames[i], static_cast<uint16_t>(i * 13 % 60000));
      ++valid;
    }
  }
  SlcanDecoder decoder;
  int64_t decoded = 0;
  const SlcanDecoder::EventCallback on_event = [&decoded](const SlcanEvent& e) {
    decoded += e.kind == SlcanEvent::Kind::kFrame;
  };
  for (auto _ : state) {
    for (size_t pos = 0; pos < stream.size(); pos += 256) {
      const size_t n = std::min<size_t>(256, stream.size() - pos);
      decoder.Feed(reinterpret_cast<const uint8_t*>(stream.data() + pos), n, on_event);
    }
  }
  if (decoded != valid * static_cast<int64_t>(state.iterations())) {
    state.SkipWithError("decoder lost valid frames");
  }
  state.SetItemsProcessed(valid * static_cast<int64_t>(state.iterations()));
  state.SetBytesProcessed(static_cast<int64_t>(stream.size()) *
                          static_cast<int64_t>(state.iterations()));
  state.counters["decode_errors"] = static_cast<double>(decoder.decode_errors());
}
BENCHMARK(BM_SlcanDecodeStream)->Arg(0)->Arg(10);

}  // namespace
}  // namespace kinevis::hal
