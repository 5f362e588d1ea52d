#include "hal/canopen/canopen_master.h"

#include <spdlog/spdlog.h>

#include <algorithm>

#include "hal/common/error.h"

namespace kinevis::hal::canopen {
namespace {

// Frames handled per drain before a cycle goes on regardless (a flooded bus must not stall it).
constexpr int kMaxDrainFrames = 4096;
// Bus error events are logged at most once per this interval (they are all counted).
constexpr auto kErrorEventLogInterval = std::chrono::seconds(1);

}  // namespace

CanopenMaster::CanopenMaster(std::unique_ptr<CanBus> bus, CanopenMasterOptions options)
    : Cia402DriveBus(options.clock, options.cycle_period, options.quick_stop_all_on_fault),
      bus_(std::move(bus)),
      options_(options) {
  std::string problems;
  auto problem = [&](const std::string& p) { problems += (problems.empty() ? "" : "; ") + p; };
  if (bus_ == nullptr) throw common::ConfigError("CANopen master: no CAN bus");
  if (options_.cycle_period.count() <= 0) {
    problem("cycle_period " + std::to_string(options_.cycle_period.count()) + " us must be > 0");
  }
  if (options_.cycle_timeout.count() <= 0) {
    problem("cycle_timeout " + std::to_string(options_.cycle_timeout.count()) + " us must be > 0");
  }
  if (options_.sdo.timeout.count() <= 0) {
    problem("sdo.timeout " + std::to_string(options_.sdo.timeout.count()) + " ms must be > 0");
  }
  if (options_.sdo.max_upload_size == 0) problem("sdo.max_upload_size must be > 0");
  if (options_.sdo.poll_period <= common::Duration::zero()) problem("sdo.poll_period must be > 0");
  if (!problems.empty())
    throw common::ConfigError("CANopen master on " + bus_->name() + ": " + problems);
  drives_.reserve(kMaxNodeId);
}

CanopenMaster::~CanopenMaster() = default;

Cia402CanDrive* CanopenMaster::AddDrive(const Cia402CanDriveConfig& config) {
  std::string problems;
  auto problem = [&](const std::string& p) { problems += (problems.empty() ? "" : "; ") + p; };
  if (config.node < 1 || config.node > kMaxNodeId) {
    problem("node " + std::to_string(config.node) + " is not in 1..127");
  } else if (by_node_[config.node] != nullptr) {
    problem("node " + std::to_string(config.node) + " was already added");
  }
  const std::string options_problems = ValidateCia402DriveOptions(config.drive);
  if (!options_problems.empty()) problem(options_problems);
  const auto producer = config.heartbeat_producer.count();
  if (producer < 0 || producer > 65535) {
    problem("heartbeat_producer " + std::to_string(producer) + " ms is not in 0..65535");
  }
  if (config.heartbeat_consumer.count() < 0) {
    problem("heartbeat_consumer " + std::to_string(config.heartbeat_consumer.count()) +
            " ms must be >= 0");
  } else if (config.heartbeat_consumer.count() > 0 && producer > 0 &&
             config.heartbeat_consumer <= config.heartbeat_producer) {
    problem("heartbeat_consumer " + std::to_string(config.heartbeat_consumer.count()) +
            " ms must exceed heartbeat_producer " + std::to_string(producer) + " ms");
  }
  if (!problems.empty()) {
    throw common::ConfigError("CANopen master on " + bus_->name() + ", drive \"" +
                              config.drive.name + "\" (node " + std::to_string(config.node) +
                              "): " + problems);
  }
  const std::string name = (config.drive.name.empty() ? std::string("drive") : config.drive.name) +
                           " (" + bus_->name() + " node " + std::to_string(config.node) + ")";
  drives_.emplace_back(new Cia402CanDrive(this, config, name));
  by_node_[config.node] = drives_.back().get();
  AddToGroup(drives_.back().get());
  return drives_.back().get();
}

Cia402CanDrive* CanopenMaster::AddDrive(uint8_t node, const DriveScaling& scaling,
                                        const DriveLimits& limits) {
  Cia402CanDriveConfig config;
  config.node = node;
  config.drive.scaling = scaling;
  config.drive.limits = limits;
  return AddDrive(config);
}

std::vector<MotorDrive*> CanopenMaster::drives() {
  std::vector<MotorDrive*> out;
  out.reserve(drives_.size());
  for (const auto& d : drives_) out.push_back(d.get());
  return out;
}

Cia402CanDrive* CanopenMaster::drive(uint8_t node) const {
  return node <= kMaxNodeId ? by_node_[node] : nullptr;
}

std::error_code CanopenMaster::SendNmt(NmtCommand command, uint8_t node) {
  std::error_code ec = bus_->Send(EncodeNmt(command, node));
  if (ec) {
    ++counters_.send_errors;
    spdlog::warn("{}: NMT {} to node {} not sent: {}", bus_->name(), ToString(command), node,
                 ec.message());
  } else {
    spdlog::debug("{}: NMT {} to node {}", bus_->name(), ToString(command), node);
  }
  return ec;
}

void CanopenMaster::Dispatch(const CanFrame& frame, bool in_cycle) {
  if (frame.extended || frame.rtr) {
    ++counters_.unknown_frames;
    return;
  }
  const uint32_t function = frame.id & ~uint32_t{0x7F};
  const uint8_t node = static_cast<uint8_t>(frame.id & 0x7F);
  Cia402CanDrive* d = node != 0 ? by_node_[node] : nullptr;
  switch (function) {
    case kEmcyBase: {  // 0x080: SYNC (node 0) or EMCY
      if (node == 0 || d == nullptr) break;
      std::optional<EmcyMessage> emcy = DecodeEmcy(frame);
      if (!emcy) {
        ++d->counters_.protocol_errors;
        return;
      }
      ++counters_.emergencies;
      d->OnEmergency(*emcy);
      return;
    }
    case kTpdoBase[0]:
    case kTpdoBase[1]: {
      if (d == nullptr) break;
      const int pdo = function == kTpdoBase[0] ? 0 : 1;
      const bool complete_before = d->tpdo_mask_ == 3;
      if (!d->OnTpdo(pdo, frame)) {
        ++d->counters_.protocol_errors;
        return;
      }
      if (in_cycle && collecting_) {
        ++counters_.tpdos;
        if (!complete_before && d->tpdo_mask_ == 3 && d->pdo_active_ && !d->link_lost()) {
          --outstanding_tpdos_;
        }
      } else {
        ++counters_.late_tpdos;
      }
      return;
    }
    case kSdoResponseBase: {
      if (d == nullptr) break;
      d->sdo_.HandleFrame(frame);
      return;
    }
    case kHeartbeatBase: {
      if (d == nullptr) break;
      std::optional<HeartbeatMessage> hb = DecodeHeartbeat(frame);
      if (!hb) {
        ++d->counters_.protocol_errors;
        return;
      }
      ++counters_.heartbeats;
      d->OnHeartbeat(hb->state, clock_->Now());
      return;
    }
    default:
      break;
  }
  ++counters_.unknown_frames;
}

void CanopenMaster::DrainReceived() {
  CanFrame frame;
  for (int i = 0; i < kMaxDrainFrames; ++i) {
    if (bus_->Receive(&frame, std::chrono::microseconds::zero())) return;
    Dispatch(frame, false);
  }
}

void CanopenMaster::DrainErrorEvents() {
  CanErrorEvent event;
  while (bus_->TakeErrorEvent(&event)) {
    ++counters_.bus_error_events;
    const common::Duration now = clock_->Now();
    if (counters_.bus_error_events == 1 || now - last_error_event_log_ >= kErrorEventLogInterval) {
      last_error_event_log_ = now;
      spdlog::warn("{}: {}: {} ({} bus error events so far)", bus_->name(), ToString(event.kind),
                   event.detail, counters_.bus_error_events);
    }
  }
}

void CanopenMaster::SuperviseHeartbeats(common::Duration now) {
  for (const auto& d : drives_) {
    if (d->SuperviseHeartbeat(now)) ++counters_.heartbeat_losses;
  }
}

void CanopenMaster::PumpUntil(common::Duration deadline, const std::function<bool()>& done) {
  while (!done()) {
    CanFrame frame;
    const std::error_code ec =
        ReceiveFrameUntil(*bus_, *clock_, deadline, &frame, options_.sdo.poll_period);
    if (!ec) Dispatch(frame, false);
    const common::Duration now = clock_->Now();
    SuperviseHeartbeats(now);
    if (ec == Errc::kTimeout || (!ec && now >= deadline)) return;  // even when flooded
    if (ec) {
      // The link is gone: nothing will come before the deadline.
      spdlog::debug("{}: receive failed: {}", bus_->name(), ec.message());
      if (clock_->Now() < deadline) clock_->SleepUntil(deadline);
      return;
    }
  }
}

std::error_code CanopenMaster::Cycle() {
  ++counters_.cycles;
  const common::Duration start = MarkCycleStart();
  DrainReceived();
  DrainErrorEvents();
  SuperviseHeartbeats(start);

  std::error_code result;
  outstanding_tpdos_ = 0;
  for (const auto& d : drives_) {
    if (!d->pdo_active_) continue;
    CanFrame rpdo1, rpdo2;
    d->EncodeRpdos(&rpdo1, &rpdo2);
    for (const CanFrame* f : {&rpdo1, &rpdo2}) {
      if (std::error_code ec = bus_->Send(*f)) {
        ++counters_.send_errors;
        if (!result) result = ec;
      } else {
        ++counters_.rpdos;
      }
    }
    if (!d->link_lost()) ++outstanding_tpdos_;  // a node known dead is not waited for
  }
  if (std::error_code ec = bus_->Send(EncodeSync())) {
    ++counters_.send_errors;
    if (!result) result = ec;
    outstanding_tpdos_ = 0;  // no SYNC, no TPDOs
  } else {
    ++counters_.syncs;
  }
  const common::Duration sync_time = clock_->Now();
  const common::Duration deadline = sync_time + options_.cycle_timeout;
  collecting_ = true;
  while (outstanding_tpdos_ > 0) {
    CanFrame frame;
    const std::error_code ec =
        ReceiveFrameUntil(*bus_, *clock_, deadline, &frame, options_.sdo.poll_period);
    if (ec) {
      if (ec != Errc::kTimeout && !result) result = ec;
      break;
    }
    Dispatch(frame, true);
    // A flooded bus must not hold the cycle past its deadline.
    if (outstanding_tpdos_ > 0 && clock_->Now() >= deadline) break;
  }
  collecting_ = false;
  SuperviseHeartbeats(clock_->Now());

  for (const auto& d : drives_) {
    if (!d->pdo_active_) continue;
    if ((d->tpdo_mask_ & 1) != 0) d->ApplyInputs(d->inputs_, sync_time, counters_.cycles);
    if (d->tpdo_mask_ != 3 && !d->link_lost()) {
      counters_.missing_tpdos += (d->tpdo_mask_ & 1) == 0 ? 1 : 0;
      counters_.missing_tpdos += (d->tpdo_mask_ & 2) == 0 ? 1 : 0;
      ++d->counters_.timeouts;
      if (!result) result = Errc::kTimeout;
    }
  }
  return FinishCycle(result);
}

}  // namespace kinevis::hal::canopen
