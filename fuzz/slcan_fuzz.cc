// libFuzzer target: arbitrary bytes from a serial line into the slcan decoder (the host side) and
// arbitrary lines into the adapter-side command parser. Properties checked beyond "no crash":
// the decoder never holds more than one bounded line, and every frame it reports re-encodes to a
// line that decodes to the same frame.
#include <cstdint>
#include <cstdlib>
#include <string_view>

#include "hal/can/slcan_codec.h"

using kinevis::hal::CanFrame;
using kinevis::hal::SlcanDecoder;
using kinevis::hal::SlcanEvent;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  SlcanDecoder decoder;
  // Feed in two chunks split at a data-dependent point: chunking must not matter.
  const size_t split = size > 0 ? data[0] % (size + 1) : 0;
  auto check = [](const SlcanEvent& e) {
    if (e.kind != SlcanEvent::Kind::kFrame) return;
    if (!e.frame.Validate().empty()) std::abort();
    const std::string line = kinevis::hal::SlcanFrameLine(e.frame);
    SlcanDecoder again;
    bool same = false;
    again.Feed(line, [&](const SlcanEvent& back) {
      same = back.kind == SlcanEvent::Kind::kFrame && back.frame == e.frame;
    });
    if (!same) std::abort();
  };
  decoder.Feed(data, split, check);
  decoder.Feed(data + split, size - split, check);
  if (decoder.pending_bytes() > SlcanDecoder::kMaxLineBytes) std::abort();

  const std::string_view text(reinterpret_cast<const char*>(data), size);
  std::string error;
  (void)kinevis::hal::ParseSlcanCommand(text.substr(0, 40), &error);
  return 0;
}
