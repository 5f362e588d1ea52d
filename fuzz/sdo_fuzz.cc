// libFuzzer target for the SDO layer: CAN frames built from the input go through both SDO
// decoders and, as server responses, through the client's transfer state machine
// (hal::canopen::SdoTransfer), which must neither crash nor accept more than it may.
//
// Input layout: byte 0 picks the transfer (bit 0 upload/download, bits 1..3 the download size
// class); then frames, each a header byte (bits 0..3 dlc, clamped to 8; bit 4 rtr; bit 5
// "no answer": a timeout instead of a frame) followed by dlc data bytes.
//
// Build: clang++ -std=c++17 -fsanitize=fuzzer,address,undefined -I. fuzz/sdo_fuzz.cc
//        hal/canopen/sdo_client.cc hal/canopen/canopen_codec.cc hal/can/can_frame.cc
//        hal/common/error.cc hal/common/clock.cc -lspdlog -lfmt

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <vector>

#include "hal/can/can_frame.h"
#include "hal/canopen/canopen_codec.h"
#include "hal/canopen/sdo_client.h"

namespace {

using kinevis::hal::CanFrame;
using namespace kinevis::hal::canopen;

constexpr uint8_t kNode = 0x21;
constexpr size_t kMaxUpload = 512;

void Check(bool condition) {
  if (!condition) std::abort();
}

// Every frame the client produces must be a well-formed request of its node.
void CheckRequest(const CanFrame& request) {
  Check(request.id == kSdoRequestBase + kNode);
  Check(request.dlc == 8 && !request.rtr && !request.extended);
  Check(DecodeSdoRequest(request).has_value());
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  const uint8_t mode = data[0];
  size_t pos = 1;

  SdoTransfer transfer(kMaxUpload);
  CanFrame request;
  const bool upload = (mode & 1) != 0;
  std::vector<uint8_t> download;
  if (upload) {
    transfer.StartUpload(kNode, 0x1008, 0x00, &request);
  } else {
    static const size_t kSizes[8] = {0, 1, 2, 4, 5, 7, 8, 40};
    download.resize(kSizes[(mode >> 1) & 7]);
    for (size_t i = 0; i < download.size(); ++i) download[i] = static_cast<uint8_t>(i * 37);
    transfer.StartDownload(kNode, 0x2000, 0x01, download.data(), download.size(), &request);
  }
  CheckRequest(request);

  while (pos < size) {
    const uint8_t header = data[pos++];
    CanFrame frame;
    frame.id = kSdoResponseBase + kNode;
    frame.rtr = (header & 0x10) != 0;
    frame.dlc = static_cast<uint8_t>(header & 0x0F) > 8 ? 8 : static_cast<uint8_t>(header & 0x0F);
    for (uint8_t i = 0; i < frame.dlc && pos < size; ++i) frame.data[i] = data[pos++];

    // The decoders take any frame.
    std::string error;
    const auto as_request = DecodeSdoRequest(frame, &error);
    const auto as_response = DecodeSdoResponse(frame, &error);
    Check(as_request.has_value() == as_response.has_value() || frame.dlc == 8);
    if (as_response && as_response->type != SdoType::kAbort) {
      Check(as_response->data_length <= 7);
      if (as_response->expedited) Check(as_response->size >= 1 && as_response->size <= 4);
    }

    if (!transfer.active()) continue;
    const SdoTransfer::Action action =
        (header & 0x20) != 0 ? transfer.OnTimeout(&request) : transfer.OnResponse(frame, &request);
    switch (action) {
      case SdoTransfer::Action::kSend:
        Check(transfer.active());
        CheckRequest(request);
        break;
      case SdoTransfer::Action::kAbort:
        Check(!transfer.active() && transfer.error());
        CheckRequest(request);
        Check(request.data[0] == 0x80);
        Check(transfer.abort_code() != 0 && !transfer.abort_from_server());
        break;
      case SdoTransfer::Action::kFailed:
        Check(!transfer.active() && transfer.error());
        break;
      case SdoTransfer::Action::kComplete:
        Check(!transfer.active() && !transfer.error());
        if (upload) Check(transfer.data().size() <= kMaxUpload);
        break;
    }
  }
  return 0;
}
