#include "hal/mock/slcan_adapter_sim.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <optional>

#include "common/clock.h"
#include "hal/can/slcan_codec.h"
#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using std::chrono::milliseconds;

// How long a thread waits for input before it looks at the stop flag again.
constexpr milliseconds kPollInterval{20};
// How long a write to the host may take before the bytes are given up (nobody reading).
constexpr milliseconds kWriteTimeout{100};
// A host line longer than any command is garbage; it is answered '\a' once at its '\r'.
constexpr size_t kMaxCommandLine = 64;

void CheckField(const std::string& value, const char* what) {
  bool ok = value.size() == 4;
  for (char c : value) ok = ok && c > ' ' && c <= '~';
  if (!ok) {
    throw common::ConfigError(std::string("SlcanAdapterSim: ") + what + " \"" + value +
                              "\" is not exactly 4 printable characters");
  }
}

}  // namespace

const char* ToString(SlcanAdapterSim::State state) {
  switch (state) {
    case SlcanAdapterSim::State::kClosed:
      return "closed";
    case SlcanAdapterSim::State::kOpen:
      return "open";
    case SlcanAdapterSim::State::kListenOnly:
      return "listen-only";
  }
  return "?";
}

SlcanAdapterSim::SlcanAdapterSim(std::unique_ptr<SerialPort> port, CanBus* bus, Options options)
    : port_(std::move(port)),
      bus_(bus),
      options_(std::move(options)),
      name_("slcan-sim:" + port_->name()) {
  CheckField(options_.version, "version");
  CheckField(options_.serial_number, "serial number");
}

SlcanAdapterSim::~SlcanAdapterSim() { Stop(); }

void SlcanAdapterSim::Start() {
  if (running_.exchange(true)) return;
  serial_thread_ = std::thread([this] { SerialLoop(); });
  bus_thread_ = std::thread([this] { BusLoop(); });
  spdlog::debug("{}: started (version {}, serial number {})", name_, options_.version,
                options_.serial_number);
}

void SlcanAdapterSim::Stop() {
  if (!running_.exchange(false)) return;
  if (serial_thread_.joinable()) serial_thread_.join();
  if (bus_thread_.joinable()) bus_thread_.join();
  spdlog::debug("{}: stopped", name_);
}

SlcanAdapterSim::State SlcanAdapterSim::state() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return state_;
}

int SlcanAdapterSim::bitrate_code() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return bitrate_code_;
}

bool SlcanAdapterSim::timestamps() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return timestamps_;
}

SlcanAdapterSim::Statistics SlcanAdapterSim::statistics() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

void SlcanAdapterSim::DropBytesToHost(size_t n) {
  std::lock_guard<std::mutex> lock(write_mutex_);
  drop_remaining_ += n;
}

void SlcanAdapterSim::InjectGarbage(std::string_view bytes) {
  std::lock_guard<std::mutex> lock(write_mutex_);
  WriteToHostLocked(bytes.data(), bytes.size());
}

void SlcanAdapterSim::SetSilent(bool silent) {
  std::lock_guard<std::mutex> lock(mutex_);
  silent_ = silent;
}

void SlcanAdapterSim::RefuseCommands(std::string letters) {
  std::lock_guard<std::mutex> lock(mutex_);
  refused_letters_ = std::move(letters);
}

void SlcanAdapterSim::SetStatusFlags(uint8_t flags) {
  std::lock_guard<std::mutex> lock(mutex_);
  status_flags_ |= flags;
}

void SlcanAdapterSim::WriteToHostLocked(const char* data, size_t size) {
  const size_t dropped = std::min(size, drop_remaining_);
  drop_remaining_ -= dropped;
  if (dropped > 0) {
    std::lock_guard<std::mutex> lock(mutex_);
    stats_.bytes_dropped += dropped;
  }
  if (dropped == size) return;
  std::error_code ec = port_->WriteAll(reinterpret_cast<const uint8_t*>(data + dropped),
                                       size - dropped, kWriteTimeout);
  if (ec) spdlog::debug("{}: write to host failed: {}", name_, ec.message());
}

void SlcanAdapterSim::SerialLoop() {
  uint8_t buffer[256];
  std::string line;
  line.reserve(kMaxCommandLine);
  bool overlong = false;
  bool reported_link_error = false;
  while (running_.load()) {
    size_t n = 0;
    std::error_code ec = port_->Read(buffer, sizeof buffer, kPollInterval, &n);
    if (ec == Errc::kTimeout) continue;
    if (ec) {
      // The pty pair keeps its own slave descriptor, so this means the port itself is gone.
      if (!reported_link_error) spdlog::warn("{}: serial read failed: {}", name_, ec.message());
      reported_link_error = true;
      std::this_thread::sleep_for(kPollInterval);
      continue;
    }
    reported_link_error = false;
    for (size_t i = 0; i < n; ++i) {
      const char c = static_cast<char>(buffer[i]);
      if (c == '\n') continue;
      if (c != '\r') {
        if (line.size() < kMaxCommandLine) {
          line += c;
        } else {
          overlong = true;
        }
        continue;
      }
      if (overlong) {
        // Longer than any command: refuse it as a whole, whatever it started with.
        line = "?";
        overlong = false;
      }
      HandleLine(line);
      line.clear();
    }
  }
}

void SlcanAdapterSim::HandleLine(std::string_view line) {
  using Kind = SlcanCommand::Kind;
  std::lock_guard<std::mutex> write_lock(write_mutex_);
  std::unique_lock<std::mutex> lock(mutex_);
  ++stats_.commands;
  if (silent_) return;

  std::string reply = std::string(1, kSlcanBell);
  auto ok = [&reply] { reply = "\r"; };
  std::string error;
  std::optional<SlcanCommand> command;
  if (!line.empty() && refused_letters_.find(line[0]) != std::string::npos) {
    error = "refused by fault injection";
  } else {
    command = ParseSlcanCommand(line, &error);
  }
  const bool closed = state_ == State::kClosed;
  if (command) {
    switch (command->kind) {
      case Kind::kTransmit: {
        if (state_ != State::kOpen) {
          error = std::string("frame while the channel is ") + ToString(state_);
          break;
        }
        lock.unlock();  // the bus takes its own locks; the state cannot change (write_mutex_)
        std::error_code ec = bus_->Send(command->frame);
        lock.lock();
        if (ec) {
          error = "the bus refused the frame: " + ec.message();
        } else {
          ++stats_.frames_to_bus;
          reply = command->frame.extended ? "Z\r" : "z\r";
        }
        break;
      }
      case Kind::kSetBitrate:
        if (!closed) {
          error = "S while the channel is open";
        } else {
          bitrate_code_ = command->bitrate_code;
          ok();
        }
        break;
      case Kind::kTimestamps:
        if (!closed) {
          error = "Z while the channel is open";
        } else {
          timestamps_ = command->timestamps_on;
          ok();
        }
        break;
      case Kind::kOpen:
      case Kind::kListenOnly:
        if (!closed) {
          error = "channel already open";
        } else {
          state_ = command->kind == Kind::kOpen ? State::kOpen : State::kListenOnly;
          ok();
        }
        break;
      case Kind::kClose:
        if (closed) {
          error = "channel already closed";
        } else {
          state_ = State::kClosed;
          ok();
        }
        break;
      case Kind::kVersion:
        reply = "V" + options_.version + "\r";
        break;
      case Kind::kSerialNumber:
        reply = "N" + options_.serial_number + "\r";
        break;
      case Kind::kStatus:
        if (closed) {
          error = "F while the channel is closed";
        } else {
          char text[8];
          std::snprintf(text, sizeof text, "F%02X\r", status_flags_);
          status_flags_ = 0;
          reply = text;
        }
        break;
    }
  }
  if (reply[0] == kSlcanBell) {
    ++stats_.refused;
    spdlog::debug("{}: refused \"{}\": {}", name_, line, error);
  }
  lock.unlock();
  WriteToHostLocked(reply.data(), reply.size());
}

void SlcanAdapterSim::BusLoop() {
  char line[kSlcanMaxLineSize];
  CanFrame frame;
  while (running_.load()) {
    std::error_code ec =
        bus_->Receive(&frame, std::chrono::duration_cast<std::chrono::microseconds>(kPollInterval));
    if (ec == Errc::kTimeout) continue;
    if (ec) {
      spdlog::debug("{}: bus receive failed: {}", name_, ec.message());
      std::this_thread::sleep_for(kPollInterval);
      continue;
    }
    std::lock_guard<std::mutex> write_lock(write_mutex_);
    std::optional<uint16_t> timestamp_ms;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      // A closed adapter does not receive; a silent one has stopped talking.
      if (state_ == State::kClosed || silent_) continue;
      if (timestamps_) {
        // The adapter's free-running millisecond counter; the frame's bus time stands in for it
        // so that a simulated clock drives the timestamps too.
        const common::Duration t =
            frame.timestamp.count() != 0 ? frame.timestamp : common::SteadyClock::Instance().Now();
        const auto ms = std::chrono::duration_cast<milliseconds>(t).count();
        timestamp_ms = static_cast<uint16_t>(ms % (kSlcanMaxTimestampMs + 1));
      }
      ++stats_.frames_to_host;
    }
    const size_t size = EncodeSlcanFrame(frame, line, timestamp_ms);
    WriteToHostLocked(line, size);
  }
}

}  // namespace kinevis::hal
