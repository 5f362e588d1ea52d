#include "hal/drive/rs485_drive.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "hal/common/error.h"
#include "hal/drive/rs485_drive_registers.h"

namespace kinevis::hal {
namespace {

using namespace rs485_drive;

std::string Hex(uint32_t value, int digits) {
  char text[16];
  std::snprintf(text, sizeof text, "0x%0*X", digits, value);
  return text;
}

uint32_t ToU32(double v) {
  return static_cast<uint32_t>(std::min(std::round(std::fabs(v)), 4294967295.0));
}

int32_t ToI32(double v) {
  return static_cast<int32_t>(std::clamp(std::round(v), -2147483648.0, 2147483647.0));
}

}  // namespace

// =============================================================================================
// Rs485Drive

Rs485Drive::Rs485Drive(Rs485DriveBus* bus, Rs485DriveConfig config, std::string name,
                       std::shared_ptr<ModbusClient> client)
    : Cia402HostDrive(config.drive, std::move(name)),
      bus_(bus),
      config_(std::move(config)),
      client_(std::move(client)),
      client_base_(client_->counters()) {}

Rs485Drive::~Rs485Drive() = default;

common::Clock& Rs485Drive::clock() const { return bus_->clock(); }

bool Rs485Drive::RunCyclesUntil(common::Duration deadline, const std::function<bool()>& done) {
  return bus_->RunCyclesUntil(deadline, done);
}

ModbusClient& Rs485Drive::Client() {
  if (bus_->client_user_ != this) {
    if (bus_->client_user_ != nullptr) bus_->client_user_->SyncClientCounters();
    bus_->client_user_ = this;
    client_base_ = client_->counters();
  }
  client_->SetUnit(config_.unit);  // validated in AddDrive: cannot fail
  return *client_;
}

void Rs485Drive::SyncClientCounters() {
  const ModbusClientCounters c = client_->counters();
  counters_.timeouts += c.timeouts - client_base_.timeouts;
  counters_.crc_errors += c.crc_errors - client_base_.crc_errors;
  counters_.retries += c.retries - client_base_.retries;
  client_base_ = c;
}

void Rs485Drive::ThrowModbusFailure(const std::string& step, std::error_code ec) {
  exchanging_ = false;
  SetUnconfigured();
  SyncClientCounters();
  const std::string cause = Client().last_error_text();
  SetError("configure: " + step + ": " + cause, spdlog::level::err);
  throw HalError(name(), "configure: " + step, cause, ec);
}

void Rs485Drive::WriteU16(uint16_t address, uint16_t value, const char* what) {
  if (std::error_code ec = Client().WriteRegister(address, value)) ThrowModbusFailure(what, ec);
}

void Rs485Drive::WriteU32(uint16_t address, uint32_t value, const char* what) {
  uint16_t words[2];
  SplitHighFirst(value, words);
  if (std::error_code ec = Client().WriteRegisters(address, 2, words)) {
    ThrowModbusFailure(what, ec);
  }
}

void Rs485Drive::Configure() {
  exchanging_ = false;
  missed_cycles_ = 0;
  SetUnconfigured();

  uint16_t id[8];
  if (std::error_code ec = Client().ReadHoldingRegisters(kRegVendorId, 8, id)) {
    ThrowModbusFailure("read identity and supported modes", ec);
  }
  DriveIdentity identity;
  identity.vendor_id = JoinHighFirst(id[0], id[1]);
  identity.product_code = JoinHighFirst(id[2], id[3]);
  identity.serial_number = JoinHighFirst(id[4], id[5]);
  identity.supported_modes = JoinHighFirst(id[6], id[7]);
  const int mode_bit = static_cast<int>(options().mode) - 1;
  if ((identity.supported_modes & (1u << mode_bit)) == 0) {
    const std::string cause = std::string("mode ") + ToString(options().mode) +
                              " is not supported (supported modes " +
                              Hex(identity.supported_modes, 8) + ": " +
                              SupportedModesText(identity.supported_modes) + ")";
    SetError("configure: " + cause, spdlog::level::err);
    throw HalError(name(), "configure: check modes", cause);
  }

  WriteU16(kRegModeOfOperation, static_cast<uint16_t>(static_cast<int16_t>(options().mode)),
           "write mode of operation");
  const DriveScaling& sc = options().scaling;
  if (options().profile_velocity > 0) {
    WriteU32(kRegProfileVelocity, ToU32(options().profile_velocity * sc.velocity_counts_per_unit),
             "write profile velocity");
  }
  if (options().profile_acceleration > 0) {
    WriteU32(kRegProfileAcceleration,
             ToU32(options().profile_acceleration * sc.velocity_counts_per_unit),
             "write profile acceleration");
  }
  if (options().following_error_window > 0) {
    WriteU32(kRegFollowingErrorWindow,
             ToU32(options().following_error_window * sc.position_counts_per_unit),
             "write following error window");
  }
  const DriveLimits& l = options().limits;
  if (std::isfinite(l.min_position) && std::isfinite(l.max_position)) {
    const int32_t a = ToI32(l.min_position * sc.position_counts_per_unit);
    const int32_t b = ToI32(l.max_position * sc.position_counts_per_unit);
    uint16_t words[4];
    SplitHighFirst(static_cast<uint32_t>(std::min(a, b)), &words[0]);
    SplitHighFirst(static_cast<uint32_t>(std::max(a, b)), &words[2]);
    if (std::error_code ec = Client().WriteRegisters(kRegPositionLimitMin, 4, words)) {
      ThrowModbusFailure("write position limits", ec);
    }
  }
  // Last, so that the drive starts supervising when the cycles start.
  WriteU16(kRegWatchdogMs, static_cast<uint16_t>(config_.watchdog.count()), "write watchdog");

  SetConfigured(std::move(identity));
  exchanging_ = true;
  const common::Duration started = clock().Now();
  if (!RunCyclesUntil(started + options().command_timeout, [this] { return inputs_fresh(); })) {
    exchanging_ = false;
    SetUnconfigured();
    SyncClientCounters();
    const std::string cause = "no answer to the cyclic exchange within " +
                              std::to_string(options().command_timeout.count()) +
                              " ms: " + Client().last_error_text();
    SetError("configure: " + cause, spdlog::level::err);
    throw HalError(name(), "configure: first process data", cause, Client().last_error());
  }
  spdlog::info(
      "{}: configured: vendor {}, product {}, serial {}, modes: {}; watchdog {} ms; state '{}'",
      name(), Hex(identity_.vendor_id, 8), Hex(identity_.product_code, 8), identity_.serial_number,
      SupportedModesText(identity_.supported_modes), config_.watchdog.count(),
      ToString(status().state));
}

std::error_code Rs485Drive::Exchange(common::Duration now, uint64_t cycle) {
  ProcessOutputs o;
  ComposeOutputs(&o);
  uint16_t out[kCyclicOutputCount];
  out[0] = o.controlword;
  out[1] = static_cast<uint16_t>(static_cast<int16_t>(o.mode));
  SplitHighFirst(static_cast<uint32_t>(o.target_position), &out[2]);
  SplitHighFirst(static_cast<uint32_t>(o.target_velocity), &out[4]);
  out[6] = static_cast<uint16_t>(o.target_torque);
  uint16_t in[kCyclicInputCount];
  const std::error_code ec = Client().WriteAndReadRegisters(
      kRegControlword, kCyclicOutputCount, out, kRegStatusword, kCyclicInputCount, in);
  SyncClientCounters();
  if (!ec) {
    missed_cycles_ = 0;
    if (link_lost()) OnLinkRestored();
    ProcessInputs i;
    i.statusword = in[0];
    i.mode_display = static_cast<int8_t>(static_cast<int16_t>(in[1]));
    i.position = static_cast<int32_t>(JoinHighFirst(in[2], in[3]));
    i.velocity = static_cast<int32_t>(JoinHighFirst(in[4], in[5]));
    i.torque = static_cast<int16_t>(in[6]);
    i.error_code = in[7];
    following_error_actual_ = static_cast<int32_t>(JoinHighFirst(in[8], in[9])) /
                              options().scaling.position_counts_per_unit;
    ApplyInputs(i, now, cycle);
    return {};
  }
  if (IsModbusException(ec)) {
    // The drive answered but refused the outputs: a device error, not a lost link.
    ++counters_.protocol_errors;
    return ec;
  }
  if (ec.category() == ModbusCategory()) ++counters_.protocol_errors;  // bad CRC, mismatches
  ++missed_cycles_;
  if (missed_cycles_ >= bus_->options().max_missed_cycles && !link_lost()) {
    OnLinkLost(std::to_string(missed_cycles_) +
               " consecutive exchanges failed, the last: " + Client().last_error_text());
  }
  return ec;
}

std::error_code Rs485Drive::RestoreLink() {
  if (!link_lost()) return {};
  const std::error_code ec = Exchange(clock().Now(), bus_->cycle_count());
  if (!ec && !link_lost()) return {};
  SetError("cannot reset: the drive does not answer: " + Client().last_error_text(),
           spdlog::level::warn);
  return ec ? ec : make_error_code(Errc::kTimeout);
}

// =============================================================================================
// Rs485DriveBus

Rs485DriveBus::Rs485DriveBus(std::string backend, Rs485DriveBusOptions options)
    : Cia402DriveBus(options.clock, options.cycle_period, options.quick_stop_all_on_fault),
      name_(std::move(backend)),
      options_(options) {
  spec_ = ParseModbusBackend(name_);
  std::string problems;
  auto problem = [&](const std::string& p) { problems += (problems.empty() ? "" : "; ") + p; };
  if (spec_.kind != ModbusBackendSpec::Kind::kRtu) {
    problem("the RS485 drive bus needs a modbus-rtu: backend");
  }
  if (options_.cycle_period.count() <= 0) {
    problem("cycle_period " + std::to_string(options_.cycle_period.count()) + " us must be > 0");
  }
  if (options_.max_missed_cycles < 1) {
    problem("max_missed_cycles " + std::to_string(options_.max_missed_cycles) + " must be >= 1");
  }
  if (options_.faulted_poll_cycles < 1) {
    problem("faulted_poll_cycles " + std::to_string(options_.faulted_poll_cycles) +
            " must be >= 1");
  }
  if (!problems.empty())
    throw common::ConfigError("RS485 drive bus \"" + name_ + "\": " + problems);
  drives_.reserve(247);
}

Rs485DriveBus::~Rs485DriveBus() = default;

Rs485Drive* Rs485DriveBus::AddDrive(const Rs485DriveConfig& config) {
  std::string problems;
  auto problem = [&](const std::string& p) { problems += (problems.empty() ? "" : "; ") + p; };
  if (config.unit < 1 || config.unit > 247) {
    problem("unit " + std::to_string(config.unit) + " is not in 1..247");
  } else if (drive(config.unit) != nullptr) {
    problem("unit " + std::to_string(config.unit) + " was already added");
  }
  const std::string options_problems = ValidateCia402DriveOptions(config.drive);
  if (!options_problems.empty()) problem(options_problems);
  if (config.watchdog.count() < 0 || config.watchdog.count() > 65535) {
    problem("watchdog " + std::to_string(config.watchdog.count()) + " ms is not in 0..65535");
  }
  if (!problems.empty()) {
    throw common::ConfigError("RS485 drive bus \"" + name_ + "\", drive \"" + config.drive.name +
                              "\" (unit " + std::to_string(config.unit) + "): " + problems);
  }
  if (!client_) client_ = ModbusClient::Open(spec_);
  const std::string name = (config.drive.name.empty() ? std::string("drive") : config.drive.name) +
                           " (" + name_ + " unit " + std::to_string(config.unit) + ")";
  drives_.emplace_back(new Rs485Drive(this, config, name, client_));
  AddToGroup(drives_.back().get());
  return drives_.back().get();
}

Rs485Drive* Rs485DriveBus::AddDrive(int unit, const DriveScaling& scaling,
                                    const DriveLimits& limits) {
  Rs485DriveConfig config;
  config.unit = unit;
  config.drive.scaling = scaling;
  config.drive.limits = limits;
  return AddDrive(config);
}

std::vector<MotorDrive*> Rs485DriveBus::drives() {
  std::vector<MotorDrive*> out;
  out.reserve(drives_.size());
  for (const auto& d : drives_) out.push_back(d.get());
  return out;
}

Rs485Drive* Rs485DriveBus::drive(int unit) const {
  for (const auto& d : drives_) {
    if (d->unit() == unit) return d.get();
  }
  return nullptr;
}

std::error_code Rs485DriveBus::Cycle() {
  ++cycles_;
  MarkCycleStart();
  std::error_code result;
  for (const auto& d : drives_) {
    if (!d->exchanging_) continue;
    if (d->link_lost() && cycles_ % static_cast<uint64_t>(options_.faulted_poll_cycles) != 0) {
      continue;
    }
    if (std::error_code ec = d->Exchange(clock_->Now(), cycles_); ec && !result) result = ec;
  }
  return FinishCycle(result);
}

std::error_code Rs485DriveBus::Close() {
  std::error_code first = DisableAll();
  for (const auto& d : drives_) {
    if (!d->exchanging_) continue;
    if (std::error_code ec = d->Client().WriteRegister(kRegWatchdogMs, 0)) {
      spdlog::warn("{}: could not switch the watchdog off: {}", d->name(),
                   d->Client().last_error_text());
      if (!first) first = ec;
    }
    d->exchanging_ = false;
    d->SetUnconfigured();
  }
  return first;
}

}  // namespace kinevis::hal
