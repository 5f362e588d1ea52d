#include "hal/mock/rs485_drive_sim.h"

#include <poll.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <mutex>
#include <set>
#include <thread>

#include "hal/common/error.h"
#include "hal/drive/rs485_drive_registers.h"
#include "hal/modbus/modbus_server.h"

namespace kinevis::hal {
namespace {

using namespace rs485_drive;
using namespace std::chrono_literals;

constexpr uint32_t kProductCode = 0x0485;
constexpr uint16_t kWatchdogErrorCode = 0x8130;  // life guard / heartbeat error
// RTU frames are delimited by 3.5 character times of silence; on a pty bytes come in bursts
// as written, so a frame of unknown length is taken as complete after this much silence.
constexpr auto kSilence = 2ms;
constexpr int kIdlePollMs = 20;
constexpr auto kWriteTimeout = 100ms;
constexpr size_t kMaxFrame = 256;  // Modbus RTU ADU limit

constexpr uint8_t kIllegalFunction = 1;
constexpr uint8_t kIllegalDataAddress = 2;
constexpr uint8_t kIllegalDataValue = 3;

uint16_t Be16(const uint8_t* p) { return static_cast<uint16_t>(p[0] << 8 | p[1]); }
void PutBe16(uint8_t* p, uint16_t v) {
  p[0] = static_cast<uint8_t>(v >> 8);
  p[1] = static_cast<uint8_t>(v);
}

bool CrcOk(const uint8_t* frame, size_t n) {
  if (n < 4) return false;
  const uint16_t crc = ModbusRtuCrc(frame, n - 2);
  return frame[n - 2] == static_cast<uint8_t>(crc) &&
         frame[n - 1] == static_cast<uint8_t>(crc >> 8);
}

// [first, first + count) overlaps [reg, reg + n).
bool Touches(int first, int count, int reg, int n = 1) {
  return first < reg + n && reg < first + count;
}

bool InOutputBlock(int address, int count) { return address + count <= kOutputBlockSize; }
bool InInputBlock(int address, int count) {
  return address >= kInputBlockStart && address + count <= kInputBlockStart + kInputBlockSize;
}

constexpr size_t kUnknownLength = static_cast<size_t>(-1);

// The length of the request at the start of rx[0..n) (n >= 2) as its function code implies
// it; 0 when more bytes are needed to know; kUnknownLength for a function code this slave does
// not parse.
size_t ExpectedLength(const uint8_t* rx, size_t n) {
  switch (rx[1]) {
    case 0x03:
    case 0x06:
      return 8;
    case 0x10:
      return n < 7 ? 0 : 9 + size_t{rx[6]};
    case 0x17:
      return n < 11 ? 0 : 13 + size_t{rx[10]};
    default:
      return kUnknownLength;
  }
}

}  // namespace

struct Rs485DriveSim::Impl {
  struct Drive {
    DriveOptions options;
    std::unique_ptr<Cia402Device> device;
    std::array<uint16_t, kOutputBlockSize> outputs{};
    common::Duration last_request{0};
    common::Duration last_step{0};
    bool watchdog_tripped = false;
    bool silent = false;
    int corrupt = 0;
  };

  int fd;
  std::string device_path;
  common::Clock* clock;
  Options options;
  std::string backend;
  std::string name;

  mutable std::mutex mutex;
  std::vector<Drive> drives;
  Statistics stats;

  std::atomic<bool> serving{false};
  std::atomic<bool> stepping{false};
  std::thread server;
  std::thread stepper;

  Drive* Find(int unit) {
    for (Drive& d : drives) {
      if (d.options.unit == unit) return &d;
    }
    return nullptr;
  }

  Drive& Get(int unit) {
    Drive* d = Find(unit);
    if (d == nullptr) {
      throw common::ConfigError(name + ": no drive with unit " + std::to_string(unit) +
                                " on this line");
    }
    return *d;
  }

  void InitOutputs(Drive* d) {
    const Cia402Device::Snapshot s = d->device->snapshot();
    auto& o = d->outputs;
    o.fill(0);
    o[kRegControlword] = s.controlword;
    o[kRegModeOfOperation] = static_cast<uint16_t>(static_cast<int16_t>(s.mode));
    SplitHighFirst(static_cast<uint32_t>(s.target_position), &o[kRegTargetPosition]);
    SplitHighFirst(static_cast<uint32_t>(s.target_velocity), &o[kRegTargetVelocity]);
    o[kRegTargetTorque] = static_cast<uint16_t>(s.target_torque);
    SplitHighFirst(s.profile_velocity, &o[kRegProfileVelocity]);
    SplitHighFirst(s.profile_acceleration, &o[kRegProfileAcceleration]);
    SplitHighFirst(s.following_error_window, &o[kRegFollowingErrorWindow]);
    SplitHighFirst(static_cast<uint32_t>(s.position_limit_min), &o[kRegPositionLimitMin]);
    SplitHighFirst(static_cast<uint32_t>(s.position_limit_max), &o[kRegPositionLimitMax]);
    o[kRegQuickStopOptionCode] = static_cast<uint16_t>(s.quick_stop_option_code);
    o[kRegWatchdogMs] = 0;
  }

  // ---------------------------------------------------------------------------- registers
  void ReadInputs(const Drive& d, std::array<uint16_t, kInputBlockSize>* in) const {
    const Cia402Device::Snapshot s = d.device->snapshot();
    auto at = [in](uint16_t reg) { return &(*in)[reg - kInputBlockStart]; };
    *at(kRegStatusword) = s.statusword;
    *at(kRegModeDisplay) = static_cast<uint16_t>(static_cast<int16_t>(s.mode_display));
    SplitHighFirst(static_cast<uint32_t>(s.position), at(kRegPositionActual));
    SplitHighFirst(static_cast<uint32_t>(s.velocity), at(kRegVelocityActual));
    *at(kRegTorqueActual) = static_cast<uint16_t>(s.torque);
    *at(kRegErrorCode) = s.error_code;
    SplitHighFirst(static_cast<uint32_t>(s.following_error), at(kRegFollowingErrorActual));
    SplitHighFirst(kSimulatorVendorId, at(kRegVendorId));
    SplitHighFirst(kProductCode, at(kRegProductCode));
    SplitHighFirst(d.options.serial_number, at(kRegSerialNumber));
    SplitHighFirst(s.supported_modes, at(kRegSupportedModes));
  }

  // Reads `count` registers at `address`; returns 0 or the exception code.
  uint8_t Read(const Drive& d, int address, int count, uint16_t* out) const {
    if (InOutputBlock(address, count)) {
      std::copy_n(d.outputs.begin() + address, count, out);
      return 0;
    }
    if (InInputBlock(address, count)) {
      std::array<uint16_t, kInputBlockSize> in{};
      ReadInputs(d, &in);
      std::copy_n(in.begin() + (address - kInputBlockStart), count, out);
      return 0;
    }
    return kIllegalDataAddress;
  }

  // Writes `count` registers at `address` and applies them to the device; returns 0 or the
  // exception code (nothing applied then).
  uint8_t Write(Drive* d, int address, int count, const uint16_t* values) {
    if (!InOutputBlock(address, count)) return kIllegalDataAddress;
    std::array<uint16_t, kOutputBlockSize> staged = d->outputs;
    std::copy_n(values, count, staged.begin() + address);
    auto touched = [&](uint16_t reg, int n = 1) { return Touches(address, count, reg, n); };
    auto i32 = [&staged](uint16_t reg) {
      return static_cast<int32_t>(JoinHighFirst(staged[reg], staged[reg + 1]));
    };
    auto u32 = [&staged](uint16_t reg) { return JoinHighFirst(staged[reg], staged[reg + 1]); };

    const int16_t mode = static_cast<int16_t>(staged[kRegModeOfOperation]);
    if (touched(kRegModeOfOperation)) {
      const uint32_t supported = d->device->snapshot().supported_modes;
      if (!DriveModeFromValue(mode) || ((supported >> (mode - 1)) & 1u) == 0) {
        return kIllegalDataValue;
      }
    }
    const bool limits = touched(kRegPositionLimitMin, 2) || touched(kRegPositionLimitMax, 2);
    if (limits && i32(kRegPositionLimitMin) > i32(kRegPositionLimitMax)) return kIllegalDataValue;
    const int16_t qs = static_cast<int16_t>(staged[kRegQuickStopOptionCode]);
    if (touched(kRegQuickStopOptionCode) && (qs < 0 || qs > 8)) return kIllegalDataValue;

    d->outputs = staged;
    Cia402Device& dev = *d->device;
    if (touched(kRegModeOfOperation)) dev.SetModeOfOperation(static_cast<int8_t>(mode));
    if (touched(kRegProfileVelocity, 4)) {
      dev.SetProfile(u32(kRegProfileVelocity), u32(kRegProfileAcceleration));
    }
    if (touched(kRegFollowingErrorWindow, 2)) {
      dev.SetFollowingErrorWindow(u32(kRegFollowingErrorWindow));
    }
    if (limits) dev.SetPositionLimits(i32(kRegPositionLimitMin), i32(kRegPositionLimitMax));
    if (touched(kRegQuickStopOptionCode)) dev.SetQuickStopOptionCode(qs);
    if (touched(kRegTargetPosition, 2)) dev.SetTargetPosition(i32(kRegTargetPosition));
    if (touched(kRegTargetVelocity, 2)) dev.SetTargetVelocity(i32(kRegTargetVelocity));
    if (touched(kRegTargetTorque)) {
      dev.SetTargetTorque(static_cast<int16_t>(staged[kRegTargetTorque]));
    }
    if (touched(kRegControlword)) dev.SetControlword(staged[kRegControlword]);
    return 0;
  }

  // ---------------------------------------------------------------------------- the line
  void Send(uint8_t* reply, size_t n, Drive* d) {
    const uint16_t crc = ModbusRtuCrc(reply, n);
    reply[n] = static_cast<uint8_t>(crc);
    reply[n + 1] = static_cast<uint8_t>(crc >> 8);
    if (d->corrupt > 0) {
      --d->corrupt;
      reply[n] ^= 0xFF;
      reply[n + 1] ^= 0xFF;
    }
    n += 2;
    size_t written = 0;
    const auto deadline = std::chrono::steady_clock::now() + kWriteTimeout;
    while (written < n) {
      const ssize_t r = ::write(fd, reply + written, n - written);
      if (r > 0) {
        written += static_cast<size_t>(r);
        continue;
      }
      if (r < 0 && errno == EINTR) continue;
      if (r < 0 && errno != EAGAIN) {
        spdlog::debug("{}: write failed: {}", name, ErrnoText(errno));
        return;
      }
      if (std::chrono::steady_clock::now() > deadline) {
        spdlog::debug("{}: reply dropped, nobody reads the line", name);
        return;
      }
      pollfd p{fd, POLLOUT, 0};
      ::poll(&p, 1, 5);
    }
  }

  // One complete request with a good CRC (n includes the CRC).
  void HandleFrame(const uint8_t* f, size_t n) {
    const int unit = f[0];
    const uint8_t function = f[1];
    std::lock_guard<std::mutex> lock(mutex);
    if (unit != 0 && Find(unit) == nullptr) {
      ++stats.ignored;
      return;
    }
    ++stats.requests;
    const common::Duration now = clock->Now();
    uint16_t values[128];
    if (unit == 0) {
      // Broadcast: writes are executed by every drive that listens, and never answered.
      int address = 0, count = 0;
      if (function == 0x06 && n == 8) {
        address = Be16(f + 2);
        count = 1;
        values[0] = Be16(f + 4);
      } else if (function == 0x10 && n >= 9) {
        address = Be16(f + 2);
        count = Be16(f + 4);
        if (count < 1 || count > 123 || f[6] != 2 * count) return;
        for (int i = 0; i < count; ++i) values[i] = Be16(f + 7 + 2 * i);
      } else {
        return;
      }
      for (Drive& d : drives) {
        if (d.silent) continue;
        d.last_request = now;
        d.watchdog_tripped = false;
        Write(&d, address, count, values);
      }
      return;
    }
    Drive& d = *Find(unit);
    if (d.silent) return;
    d.last_request = now;
    d.watchdog_tripped = false;

    uint8_t reply[kMaxFrame];
    size_t len = 0;
    uint8_t exception = 0;
    reply[0] = static_cast<uint8_t>(unit);
    reply[1] = function;
    switch (function) {
      case 0x03: {
        const int address = Be16(f + 2), count = Be16(f + 4);
        if (count < 1 || count > 125) {
          exception = kIllegalDataValue;
          break;
        }
        exception = Read(d, address, count, values);
        if (exception) break;
        reply[2] = static_cast<uint8_t>(2 * count);
        for (int i = 0; i < count; ++i) PutBe16(reply + 3 + 2 * i, values[i]);
        len = 3 + 2 * static_cast<size_t>(count);
        break;
      }
      case 0x06: {
        values[0] = Be16(f + 4);
        exception = Write(&d, Be16(f + 2), 1, values);
        if (exception) break;
        std::copy_n(f, 6, reply);
        len = 6;
        break;
      }
      case 0x10: {
        const int address = Be16(f + 2), count = Be16(f + 4);
        if (count < 1 || count > 123 || f[6] != 2 * count) {
          exception = kIllegalDataValue;
          break;
        }
        for (int i = 0; i < count; ++i) values[i] = Be16(f + 7 + 2 * i);
        exception = Write(&d, address, count, values);
        if (exception) break;
        std::copy_n(f + 2, 4, reply + 2);
        len = 6;
        break;
      }
      case 0x17: {
        const int read_address = Be16(f + 2), read_count = Be16(f + 4);
        const int write_address = Be16(f + 6), write_count = Be16(f + 8);
        if (read_count < 1 || read_count > 125 || write_count < 1 || write_count > 121 ||
            f[10] != 2 * write_count) {
          exception = kIllegalDataValue;
          break;
        }
        if (!InOutputBlock(write_address, write_count) ||
            (!InOutputBlock(read_address, read_count) && !InInputBlock(read_address, read_count))) {
          exception = kIllegalDataAddress;
          break;
        }
        for (int i = 0; i < write_count; ++i) values[i] = Be16(f + 11 + 2 * i);
        exception = Write(&d, write_address, write_count, values);
        if (exception) break;
        exception = Read(d, read_address, read_count, values);
        if (exception) break;
        reply[2] = static_cast<uint8_t>(2 * read_count);
        for (int i = 0; i < read_count; ++i) PutBe16(reply + 3 + 2 * i, values[i]);
        len = 3 + 2 * static_cast<size_t>(read_count);
        break;
      }
      default:
        exception = kIllegalFunction;
        break;
    }
    if (exception) {
      reply[1] = static_cast<uint8_t>(function | 0x80);
      reply[2] = exception;
      len = 3;
      ++stats.exceptions;
      spdlog::debug("{}: unit {} function 0x{:02X}: exception {}", name, unit, function, exception);
    } else {
      ++stats.replies;
    }
    Send(reply, len, &d);
  }

  void FramingError(const char* what) {
    std::lock_guard<std::mutex> lock(mutex);
    ++stats.framing_errors;
    spdlog::debug("{}: discarded input: {}", name, what);
  }

  // Takes every complete request off the front of rx. Bytes that do not start a frame with a
  // good CRC are skipped one at a time (so a good frame right behind line noise is still
  // served), and counted as one framing error. A request of a function whose length this slave
  // cannot tell, or an incomplete one, waits for the silence that ends it.
  void Drain(std::vector<uint8_t>* rx, bool silence) {
    size_t start = 0;
    bool garbage = false;
    while (rx->size() - start >= 2) {
      const uint8_t* p = rx->data() + start;
      const size_t left = rx->size() - start;
      const size_t need = ExpectedLength(p, left);
      if (need == kUnknownLength) {
        if (!silence) break;
        if (left >= 4 && left <= kMaxFrame && CrcOk(p, left)) {
          HandleFrame(p, left);  // answered ILLEGAL FUNCTION when it is for a unit of this line
          start = rx->size();
          break;
        }
        garbage = true;
        ++start;
        continue;
      }
      if (need == 0 || left < need) {
        if (!silence) break;
        garbage = true;
        ++start;
        continue;
      }
      if (CrcOk(p, need)) {
        HandleFrame(p, need);
        start += need;
        continue;
      }
      garbage = true;
      ++start;
    }
    if (silence && start < rx->size()) {
      garbage = true;
      start = rx->size();
    }
    if (garbage) FramingError("bad CRC, incomplete frame or noise");
    rx->erase(rx->begin(), rx->begin() + static_cast<std::ptrdiff_t>(start));
  }

  void ServeLoop() {
    std::vector<uint8_t> rx;
    rx.reserve(2 * kMaxFrame);
    auto last_byte = std::chrono::steady_clock::now();
    bool reported = false;
    while (serving.load()) {
      pollfd p{fd, POLLIN, 0};
      const int r = ::poll(&p, 1, rx.empty() ? kIdlePollMs : 1);
      if (r > 0 && (p.revents & POLLIN) != 0) {
        uint8_t buffer[512];
        const ssize_t n = ::read(fd, buffer, sizeof buffer);
        if (n > 0) {
          rx.insert(rx.end(), buffer, buffer + n);
          last_byte = std::chrono::steady_clock::now();
          Drain(&rx, false);
          reported = false;
          continue;
        }
        if (n < 0 && errno != EAGAIN && errno != EINTR && !reported) {
          spdlog::warn("{}: read failed: {}", name, ErrnoText(errno));
          reported = true;
        }
      } else if (r > 0) {
        // Hang-up or error without data: nobody holds the slave side open. Do not spin.
        std::this_thread::sleep_for(std::chrono::milliseconds(kIdlePollMs));
      }
      if (!rx.empty() && std::chrono::steady_clock::now() - last_byte >= kSilence) {
        Drain(&rx, true);
      }
    }
  }

  // ---------------------------------------------------------------------------- time
  void StepLocked() {
    const common::Duration now = clock->Now();
    for (Drive& d : drives) {
      const uint16_t watchdog_ms = d.outputs[kRegWatchdogMs];
      if (watchdog_ms != 0 && !d.watchdog_tripped &&
          now - d.last_request > std::chrono::milliseconds(watchdog_ms)) {
        d.watchdog_tripped = true;
        ++stats.watchdog_trips;
        spdlog::debug("{}: unit {}: no request for {} ms, watchdog fault", name, d.options.unit,
                      watchdog_ms);
        d.device->RaiseFault(kWatchdogErrorCode);
      }
      if (now > d.last_step) {
        d.device->Step(std::chrono::duration<double>(now - d.last_step).count());
        d.last_step = now;
      }
    }
  }

  void StepLoop() {
    const auto period = std::chrono::duration_cast<std::chrono::microseconds>(
        std::chrono::duration<double>(options.step_period_s));
    while (stepping.load()) {
      std::this_thread::sleep_for(period);
      std::lock_guard<std::mutex> lock(mutex);
      StepLocked();
    }
  }
};

Rs485DriveSim::Rs485DriveSim(int master_fd, std::string device_path, common::Clock* clock,
                             Options options)
    : impl_(std::make_unique<Impl>()) {
  Impl& m = *impl_;
  m.fd = master_fd;
  m.device_path = std::move(device_path);
  m.clock = clock;
  m.options = options;
  m.name = "rs485-drive-sim " + m.device_path;
  std::string problems;
  auto problem = [&problems](const std::string& text) { problems += " " + text + ";"; };
  if (master_fd < 0) problem("master descriptor " + std::to_string(master_fd) + " is not open");
  if (clock == nullptr) problem("no clock given");
  if (options.drives.empty()) problem("no drives");
  if (options.baud <= 0) problem("baud " + std::to_string(options.baud) + " must be > 0");
  if (!(options.step_period_s > 0)) {
    problem("step_period_s " + std::to_string(options.step_period_s) + " must be > 0");
  }
  std::set<int> units;
  for (const DriveOptions& d : options.drives) {
    if (d.unit < 1 || d.unit > 247) {
      problem("unit " + std::to_string(d.unit) + " is outside 1..247");
    } else if (!units.insert(d.unit).second) {
      problem("unit " + std::to_string(d.unit) + " appears twice");
    }
    const std::string device_problems = Cia402Device::ValidateOptions(d.device);
    if (!device_problems.empty()) {
      problem("unit " + std::to_string(d.unit) + ": " + device_problems);
    }
  }
  if (!problems.empty()) {
    problems.pop_back();
    throw common::ConfigError(m.name + ":" + problems);
  }
  m.backend = "modbus-rtu:" + m.device_path + "@" + std::to_string(options.baud) + ",8E1";
  const common::Duration now = clock->Now();
  m.drives.reserve(options.drives.size());
  for (const DriveOptions& o : options.drives) {
    Impl::Drive d;
    d.options = o;
    d.device = std::make_unique<Cia402Device>(o.device);
    d.device->Step(0);  // power-up self test done: Switch on disabled
    d.last_request = now;
    d.last_step = now;
    m.InitOutputs(&d);
    m.drives.push_back(std::move(d));
  }
  m.serving = true;
  m.server = std::thread([this] { impl_->ServeLoop(); });
  spdlog::debug("{}: serving {} drive(s) as {}", m.name, m.drives.size(), m.backend);
}

Rs485DriveSim::~Rs485DriveSim() { Stop(); }

void Rs485DriveSim::Start() {
  if (impl_->stepping.exchange(true)) return;
  {
    std::lock_guard<std::mutex> lock(impl_->mutex);
    // Real time starts now: no catch-up step over the time spent before Start().
    const common::Duration now = impl_->clock->Now();
    for (Impl::Drive& d : impl_->drives) d.last_step = now;
  }
  impl_->stepper = std::thread([this] { impl_->StepLoop(); });
}

void Rs485DriveSim::Stop() {
  if (impl_->stepping.exchange(false) && impl_->stepper.joinable()) impl_->stepper.join();
  if (impl_->serving.exchange(false) && impl_->server.joinable()) impl_->server.join();
}

void Rs485DriveSim::Step() {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->StepLocked();
}

const std::string& Rs485DriveSim::backend() const { return impl_->backend; }

Cia402Device& Rs485DriveSim::device(int unit) {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return *impl_->Get(unit).device;
}

void Rs485DriveSim::StopAnswering(int unit, bool stopped) {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->Get(unit).silent = stopped;
}

void Rs485DriveSim::CorruptNextReplies(int unit, int n) {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->Get(unit).corrupt = std::max(0, n);
}

void Rs485DriveSim::RaiseFault(int unit, uint16_t error_code) {
  Cia402Device* device = nullptr;
  {
    std::lock_guard<std::mutex> lock(impl_->mutex);
    device = impl_->Get(unit).device.get();
  }
  device->RaiseFault(error_code);
}

Rs485DriveSim::Statistics Rs485DriveSim::statistics() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->stats;
}

}  // namespace kinevis::hal
