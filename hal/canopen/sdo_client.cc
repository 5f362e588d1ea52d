#include "hal/canopen/sdo_client.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstdio>
#include <cstring>

#include "hal/common/error.h"

namespace kinevis::hal::canopen {
namespace {

class SdoAbortCategoryImpl : public std::error_category {
 public:
  const char* name() const noexcept override { return "kinevis.sdo-abort"; }
  std::string message(int value) const override {
    const auto code = static_cast<uint32_t>(value);
    char head[32];
    std::snprintf(head, sizeof head, "SDO abort 0x%08X: ", code);
    return head + std::string(SdoAbortText(code));
  }
};

std::string Hex(uint32_t value, int digits) {
  char text[16];
  std::snprintf(text, sizeof text, "0x%0*X", digits, value);
  return text;
}

std::string Multiplexer(uint16_t index, uint8_t subindex) {
  char text[16];
  std::snprintf(text, sizeof text, "0x%04X:%02X", index, subindex);
  return text;
}

const char* ResponseName(SdoType type) {
  switch (type) {
    case SdoType::kInitiateDownloadResponse:
      return "initiate download response";
    case SdoType::kDownloadSegmentResponse:
      return "download segment response";
    case SdoType::kInitiateUploadResponse:
      return "initiate upload response";
    case SdoType::kUploadSegmentResponse:
      return "upload segment response";
    case SdoType::kAbort:
      return "abort";
    default:
      return "request";
  }
}

}  // namespace

const std::error_category& SdoAbortCategory() {
  static const SdoAbortCategoryImpl category;
  return category;
}

std::error_code MakeSdoAbortError(uint32_t abort_code) {
  if (abort_code == 0) return make_error_code(Errc::kProtocol);
  return {static_cast<int>(abort_code), SdoAbortCategory()};
}

uint32_t SdoAbortCode(std::error_code ec) {
  return ec.category() == SdoAbortCategory() ? static_cast<uint32_t>(ec.value()) : 0;
}

std::error_code ReceiveFrameUntil(CanBus& bus, common::Clock& clock, common::Duration deadline,
                                  CanFrame* frame, common::Duration poll_period) {
  const bool wall_clock = dynamic_cast<common::SteadyClock*>(&clock) != nullptr;
  while (true) {
    const common::Duration now = clock.Now();
    if (wall_clock) {
      const common::Duration left = std::max(deadline - now, common::Duration::zero());
      return bus.Receive(frame, std::chrono::ceil<std::chrono::microseconds>(left));
    }
    std::error_code ec = bus.Receive(frame, std::chrono::microseconds::zero());
    if (ec != Errc::kTimeout) return ec;
    if (now >= deadline) return Errc::kTimeout;
    clock.SleepUntil(std::min(deadline, now + poll_period));
  }
}

// ---------------------------------------------------------------------------------------------
// SdoTransfer

SdoTransfer::SdoTransfer(size_t max_upload_size) : max_upload_size_(max_upload_size) {}

void SdoTransfer::StartUpload(uint8_t node, uint16_t index, uint8_t subindex, CanFrame* request) {
  phase_ = Phase::kInitiate;
  upload_ = true;
  node_ = node;
  index_ = index;
  subindex_ = subindex;
  toggle_ = false;
  expedited_ = false;
  size_indicated_ = false;
  size_ = 0;
  offset_ = 0;
  last_sent_ = false;
  segments_ = 0;
  data_.clear();
  error_.clear();
  abort_code_ = 0;
  abort_from_server_ = false;
  detail_.clear();
  *request = EncodeSdoRequest(node, SdoMessage::InitiateUpload(index, subindex));
}

void SdoTransfer::StartDownload(uint8_t node, uint16_t index, uint8_t subindex, const uint8_t* data,
                                size_t size, CanFrame* request) {
  StartUpload(node, index, subindex, request);  // resets the state
  upload_ = false;
  data_.assign(data, data + size);
  size_ = static_cast<uint32_t>(size);
  size_indicated_ = true;
  if (size >= 1 && size <= 4) {
    expedited_ = true;
    *request = EncodeSdoRequest(
        node, SdoMessage::ExpeditedDownload(index, subindex, data, static_cast<uint8_t>(size)));
  } else {
    *request = EncodeSdoRequest(node, SdoMessage::SegmentedDownload(index, subindex, size_));
  }
}

SdoTransfer::Action SdoTransfer::Fail(std::error_code error, std::string detail) {
  phase_ = Phase::kIdle;
  error_ = error;
  detail_ = std::move(detail);
  return Action::kFailed;
}

SdoTransfer::Action SdoTransfer::FailWithAbort(std::error_code error, uint32_t abort_code,
                                               std::string detail, CanFrame* request) {
  Fail(error, std::move(detail));
  abort_code_ = abort_code;
  abort_from_server_ = false;
  *request = EncodeSdoRequest(node_, SdoMessage::Abort(index_, subindex_, abort_code));
  return Action::kAbort;
}

SdoTransfer::Action SdoTransfer::OnTimeout(CanFrame* request) {
  if (!active()) return Action::kFailed;
  return FailWithAbort(Errc::kTimeout, sdo_abort::kProtocolTimedOut,
                       phase_ == Phase::kInitiate
                           ? "no response to the initiate request"
                           : "no response to segment " + std::to_string(segments_ + 1),
                       request);
}

SdoTransfer::Action SdoTransfer::OnResponse(const CanFrame& response, CanFrame* request) {
  if (!active()) return Action::kFailed;
  std::string why;
  std::optional<SdoMessage> m = DecodeSdoResponse(response, &why);
  if (!m) {
    return FailWithAbort(Errc::kProtocol, sdo_abort::kInvalidCommandSpecifier,
                         "malformed response (" + why + ")", request);
  }
  if (m->type == SdoType::kAbort) {
    Fail(MakeSdoAbortError(m->abort_code), "abort " + Hex(m->abort_code, 8) + " from the server (" +
                                               SdoAbortText(m->abort_code) + ")");
    abort_code_ = m->abort_code;
    abort_from_server_ = true;
    return Action::kFailed;
  }
  return upload_ ? OnUploadResponse(*m, request) : OnDownloadResponse(*m, request);
}

SdoTransfer::Action SdoTransfer::OnUploadResponse(const SdoMessage& m, CanFrame* request) {
  if (phase_ == Phase::kInitiate) {
    if (m.type != SdoType::kInitiateUploadResponse) {
      return FailWithAbort(
          Errc::kProtocol, sdo_abort::kInvalidCommandSpecifier,
          std::string("unexpected ") + ResponseName(m.type) + " to an initiate upload request",
          request);
    }
    if (m.index != index_ || m.subindex != subindex_) {
      return FailWithAbort(Errc::kProtocol, sdo_abort::kGeneralError,
                           "response is for " + Multiplexer(m.index, m.subindex), request);
    }
    if (m.expedited) {
      expedited_ = true;
      size_indicated_ = m.size_indicated;
      data_.assign(m.data.begin(), m.data.begin() + m.size);
      phase_ = Phase::kIdle;
      return Action::kComplete;
    }
    size_indicated_ = m.size_indicated;
    size_ = m.size;
    if (size_indicated_ && size_ > max_upload_size_) {
      return FailWithAbort(Errc::kOverflow, sdo_abort::kOutOfMemory,
                           "server announces " + std::to_string(size_) + " bytes, more than " +
                               std::to_string(max_upload_size_),
                           request);
    }
    phase_ = Phase::kSegments;
    toggle_ = false;
    *request = EncodeSdoRequest(node_, SdoMessage::UploadSegment(toggle_));
    return Action::kSend;
  }
  // Segments.
  if (m.type != SdoType::kUploadSegmentResponse) {
    return FailWithAbort(
        Errc::kProtocol, sdo_abort::kInvalidCommandSpecifier,
        std::string("unexpected ") + ResponseName(m.type) + " to an upload segment request",
        request);
  }
  ++segments_;
  if (m.toggle != toggle_) {
    return FailWithAbort(Errc::kProtocol, sdo_abort::kToggleBitNotAlternated,
                         "toggle bit not alternated in segment " + std::to_string(segments_),
                         request);
  }
  const size_t total = data_.size() + m.data_length;
  if ((size_indicated_ && total > size_) || total > max_upload_size_) {
    const bool over_limit = total > max_upload_size_ && !(size_indicated_ && total > size_);
    return FailWithAbort(
        over_limit ? make_error_code(Errc::kOverflow) : make_error_code(Errc::kProtocol),
        over_limit ? sdo_abort::kOutOfMemory : sdo_abort::kLengthTooHigh,
        "segment " + std::to_string(segments_) + " brings " + std::to_string(total) +
            " bytes, more than the " +
            (over_limit ? std::to_string(max_upload_size_) + " accepted"
                        : std::to_string(size_) + " indicated"),
        request);
  }
  data_.insert(data_.end(), m.data.begin(), m.data.begin() + m.data_length);
  if (m.last) {
    if (size_indicated_ && data_.size() != size_) {
      // The server has finished; an abort would reach nobody.
      return Fail(Errc::kProtocol, "received " + std::to_string(data_.size()) +
                                       " bytes, the server indicated " + std::to_string(size_));
    }
    phase_ = Phase::kIdle;
    return Action::kComplete;
  }
  toggle_ = !toggle_;
  *request = EncodeSdoRequest(node_, SdoMessage::UploadSegment(toggle_));
  return Action::kSend;
}

void SdoTransfer::EncodeNextDownloadSegment(CanFrame* request) {
  const size_t n = std::min<size_t>(7, data_.size() - offset_);
  last_sent_ = offset_ + n == data_.size();
  *request =
      EncodeSdoRequest(node_, SdoMessage::DownloadSegment(toggle_, data_.data() + offset_,
                                                          static_cast<uint8_t>(n), last_sent_));
  offset_ += n;
}

SdoTransfer::Action SdoTransfer::OnDownloadResponse(const SdoMessage& m, CanFrame* request) {
  if (phase_ == Phase::kInitiate) {
    if (m.type != SdoType::kInitiateDownloadResponse) {
      return FailWithAbort(
          Errc::kProtocol, sdo_abort::kInvalidCommandSpecifier,
          std::string("unexpected ") + ResponseName(m.type) + " to an initiate download request",
          request);
    }
    if (m.index != index_ || m.subindex != subindex_) {
      return FailWithAbort(Errc::kProtocol, sdo_abort::kGeneralError,
                           "response is for " + Multiplexer(m.index, m.subindex), request);
    }
    if (expedited_) {
      phase_ = Phase::kIdle;
      return Action::kComplete;
    }
    phase_ = Phase::kSegments;
    toggle_ = false;
    EncodeNextDownloadSegment(request);
    return Action::kSend;
  }
  if (m.type != SdoType::kDownloadSegmentResponse) {
    return FailWithAbort(
        Errc::kProtocol, sdo_abort::kInvalidCommandSpecifier,
        std::string("unexpected ") + ResponseName(m.type) + " to a download segment request",
        request);
  }
  ++segments_;
  if (m.toggle != toggle_) {
    return FailWithAbort(
        Errc::kProtocol, sdo_abort::kToggleBitNotAlternated,
        "toggle bit not alternated in the response to segment " + std::to_string(segments_),
        request);
  }
  if (last_sent_) {
    phase_ = Phase::kIdle;
    return Action::kComplete;
  }
  toggle_ = !toggle_;
  EncodeNextDownloadSegment(request);
  return Action::kSend;
}

// ---------------------------------------------------------------------------------------------
// SdoClient

SdoClient::SdoClient(CanBus* bus, uint8_t node, common::Clock* clock, std::string name,
                     SdoClientOptions options)
    : bus_(bus),
      node_(node),
      clock_(clock),
      name_(std::move(name)),
      options_(options),
      transfer_(options.max_upload_size) {
  std::string problems;
  if (bus_ == nullptr) problems += " no CAN bus;";
  if (clock_ == nullptr) problems += " no clock;";
  if (node_ < 1 || node_ > kMaxNodeId) {
    problems += " node " + std::to_string(node_) + " is not in 1..127;";
  }
  if (options_.timeout.count() <= 0) {
    problems += " timeout " + std::to_string(options_.timeout.count()) + " ms must be > 0;";
  }
  if (options_.max_upload_size == 0) problems += " max_upload_size must be > 0;";
  if (options_.poll_period <= common::Duration::zero()) problems += " poll_period must be > 0;";
  if (!problems.empty()) {
    problems.pop_back();
    throw common::ConfigError("SDO client " + name_ + ":" + problems);
  }
}

bool SdoClient::HandleFrame(const CanFrame& frame) {
  if (frame.extended || frame.id != kSdoResponseBase + node_) return false;
  if (waiting_ && !has_response_) {
    mailbox_ = frame;
    has_response_ = true;
  } else {
    ++counters_.unexpected_responses;
  }
  return true;
}

bool SdoClient::WaitForResponse(common::Duration deadline) {
  if (source_ != nullptr) {
    source_->PumpUntil(deadline, [this] { return has_response_; });
    return has_response_;
  }
  while (!has_response_) {
    CanFrame frame;
    std::error_code ec = ReceiveFrameUntil(*bus_, *clock_, deadline, &frame, options_.poll_period);
    if (ec) {
      if (ec != Errc::kTimeout) {
        // A dead link: nothing more will come; let the timeout path report it, but do not spin.
        ++counters_.link_errors;
        if (clock_->Now() < deadline) clock_->SleepUntil(deadline);
      }
      return false;
    }
    HandleFrame(frame);
  }
  return true;
}

std::error_code SdoClient::RecordFailure(std::error_code ec, uint32_t abort_code,
                                         const std::string& cause) {
  ++counters_.failures;
  last_error_ = ec;
  last_abort_code_ = abort_code;
  last_error_cause_ = std::string("SDO ") + (transfer_.upload() ? "upload " : "download ") +
                      Multiplexer(transfer_.index(), transfer_.subindex()) + " failed: " + cause;
  last_error_text_ = name_ + ": " + last_error_cause_;
  spdlog::debug("{}", last_error_text_);
  return ec;
}

std::error_code SdoClient::Run(CanFrame request, std::optional<std::chrono::milliseconds> timeout) {
  ++counters_.transfers;
  const common::Duration wait = timeout.value_or(options_.timeout);
  // A late answer to an earlier, timed-out transfer must not be taken for this one's.
  has_response_ = false;
  waiting_ = true;
  SdoTransfer::Action action = SdoTransfer::Action::kSend;
  while (action == SdoTransfer::Action::kSend) {
    if (std::error_code ec = bus_->Send(request)) {
      // The transfer is abandoned; the server times out on its side.
      waiting_ = false;
      ++counters_.link_errors;
      transfer_.Cancel(ec, "could not send the request: " + ec.message());
      counters_.segments += static_cast<uint64_t>(transfer_.segments());
      return RecordFailure(ec, 0, transfer_.detail());
    }
    if (WaitForResponse(clock_->Now() + wait)) {
      action = transfer_.OnResponse(mailbox_, &request);
      has_response_ = false;
    } else {
      ++counters_.timeouts;
      action = transfer_.OnTimeout(&request);
    }
  }
  waiting_ = false;
  counters_.segments += static_cast<uint64_t>(transfer_.segments());
  if (action == SdoTransfer::Action::kComplete) return {};

  const std::error_code ec = transfer_.error();
  std::string cause = transfer_.detail();
  if (transfer_.abort_from_server()) {
    ++counters_.aborts_received;
  } else if (ec == Errc::kProtocol || ec == Errc::kOverflow) {
    ++counters_.protocol_errors;
  }
  if (action == SdoTransfer::Action::kAbort) {
    char sent[64];
    if (bus_->Send(request)) {
      std::snprintf(sent, sizeof sent, " (abort 0x%08X could not be sent)", transfer_.abort_code());
      ++counters_.link_errors;
    } else {
      std::snprintf(sent, sizeof sent, " (abort 0x%08X sent)", transfer_.abort_code());
      ++counters_.aborts_sent;
    }
    cause += sent;
  }
  if (ec == Errc::kTimeout) {
    cause = "timed out after " +
            std::to_string(std::chrono::duration_cast<std::chrono::milliseconds>(wait).count()) +
            " ms: " + cause;
  }
  return RecordFailure(ec, transfer_.abort_code(), cause);
}

std::error_code SdoClient::Upload(uint16_t index, uint8_t subindex, std::vector<uint8_t>* data,
                                  std::optional<std::chrono::milliseconds> timeout) {
  CanFrame request;
  transfer_.StartUpload(node_, index, subindex, &request);
  std::error_code ec = Run(request, timeout);
  if (!ec) *data = transfer_.data();
  return ec;
}

std::error_code SdoClient::Download(uint16_t index, uint8_t subindex, const uint8_t* data,
                                    size_t size, std::optional<std::chrono::milliseconds> timeout) {
  CanFrame request;
  transfer_.StartDownload(node_, index, subindex, data, size, &request);
  return Run(request, timeout);
}

std::error_code SdoClient::UploadString(uint16_t index, uint8_t subindex, std::string* text,
                                        std::optional<std::chrono::milliseconds> timeout) {
  std::vector<uint8_t> bytes;
  std::error_code ec = Upload(index, subindex, &bytes, timeout);
  if (ec) return ec;
  while (!bytes.empty() && bytes.back() == 0) bytes.pop_back();
  text->assign(bytes.begin(), bytes.end());
  return {};
}

std::error_code SdoClient::UploadInteger(uint16_t index, uint8_t subindex, size_t size,
                                         uint32_t* raw,
                                         std::optional<std::chrono::milliseconds> timeout) {
  CanFrame request;
  transfer_.StartUpload(node_, index, subindex, &request);
  std::error_code ec = Run(request, timeout);
  if (ec) return ec;
  const std::vector<uint8_t>& bytes = transfer_.data();
  // Expedited without size indication: 4 bytes of which the meaningful ones are unknown.
  const bool unsized = transfer_.expedited() && !transfer_.size_indicated();
  if (bytes.size() != size && !unsized) {
    ++counters_.protocol_errors;
    return RecordFailure(Errc::kProtocol, 0,
                         "expected " + std::to_string(size) + " bytes, the server sent " +
                             std::to_string(bytes.size()));
  }
  *raw = GetLe(bytes.data(), static_cast<int>(size));
  return {};
}

}  // namespace kinevis::hal::canopen
