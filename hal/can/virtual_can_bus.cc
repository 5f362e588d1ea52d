#include "hal/can/virtual_can_bus.h"

#include <algorithm>
#include <map>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

constexpr size_t kMaxQueuedErrorEvents = 256;

// Arbitration: the identifier bits as they appear on the wire, first bit most significant.
// A standard frame beats an extended frame with the same 11-bit base id (IDE dominant), and a
// data frame beats a remote frame with the same id (RTR dominant).
uint64_t ArbitrationKey(const CanFrame& f) {
  if (f.extended) {
    uint64_t base = f.id >> 18, ext = f.id & 0x3FFFF;
    // base(11) SRR(1)=1 IDE(1)=1 ext(18) RTR(1)
    return (base << 21) | (1ull << 20) | (1ull << 19) | (ext << 1) | (f.rtr ? 1 : 0);
  }
  // base(11) RTR(1) IDE(1)=0, padded to the same width as an extended key.
  return (static_cast<uint64_t>(f.id) << 21) | (static_cast<uint64_t>(f.rtr ? 1 : 0) << 20);
}

std::mutex& RegistryMutex() {
  static std::mutex m;
  return m;
}

std::map<std::string, std::weak_ptr<VirtualCanNetwork>>& Registry() {
  static std::map<std::string, std::weak_ptr<VirtualCanNetwork>> r;
  return r;
}

common::Duration WireTime(int bits, int bitrate) {
  return common::Duration(static_cast<int64_t>(bits) * 1'000'000'000LL / bitrate);
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// VirtualCanNetwork

VirtualCanNetwork::VirtualCanNetwork(std::string name, Options options)
    : name_(std::move(name)),
      options_(options),
      clock_(options.clock != nullptr ? options.clock : &common::SteadyClock::Instance()),
      rng_(1) {
  std::string problems;
  if (options_.bitrate != 0 && (options_.bitrate < 10'000 || options_.bitrate > 1'000'000)) {
    problems += " bitrate " + std::to_string(options_.bitrate) +
                " is outside 10000..1000000 bit/s (0 = no bit-rate model);";
  }
  if (options_.rx_queue_capacity == 0) problems += " rx_queue_capacity must be > 0;";
  if (options_.tx_queue_capacity == 0) problems += " tx_queue_capacity must be > 0;";
  if (!problems.empty()) {
    problems.pop_back();
    throw common::ConfigError("virtual CAN network \"" + name_ + "\":" + problems);
  }
  stats_start_ = clock_->Now();
  bus_free_at_ = stats_start_;
}

VirtualCanNetwork::~VirtualCanNetwork() = default;

std::shared_ptr<VirtualCanNetwork> VirtualCanNetwork::Get(const std::string& name,
                                                          const Options& options) {
  std::lock_guard<std::mutex> lock(RegistryMutex());
  auto& registry = Registry();
  auto it = registry.find(name);
  if (it != registry.end()) {
    if (auto existing = it->second.lock()) {
      if (existing->bitrate() != options.bitrate) {
        throw common::ConfigError(
            "virtual CAN network \"" + name + "\" already exists with bitrate " +
            std::to_string(existing->bitrate()) + ", asked for " + std::to_string(options.bitrate));
      }
      return existing;
    }
  }
  auto network = std::make_shared<VirtualCanNetwork>(name, options);
  registry[name] = network;
  return network;
}

std::unique_ptr<VirtualCanBus> VirtualCanNetwork::Connect(std::string node_name) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (node_name.empty()) node_name = "virtual:" + name_ + "#" + std::to_string(node_count_);
  ++node_count_;
  std::unique_ptr<VirtualCanBus> node(new VirtualCanBus(shared_from_this(), std::move(node_name)));
  nodes_.push_back(node.get());
  return node;
}

void VirtualCanNetwork::SetFaults(const Faults& faults) {
  std::lock_guard<std::mutex> lock(mutex_);
  faults_ = faults;
  faults_.drop_probability = std::clamp(faults.drop_probability, 0.0, 1.0);
  faults_.corrupt_probability = std::clamp(faults.corrupt_probability, 0.0, 1.0);
  if (faults_.delay < common::Duration::zero()) faults_.delay = common::Duration::zero();
  faults_active_ = faults_.drop_probability > 0 || faults_.corrupt_probability > 0 ||
                   faults_.delay > common::Duration::zero();
  rng_.seed(faults.seed);
}

VirtualCanNetwork::Statistics VirtualCanNetwork::statistics() const {
  std::lock_guard<std::mutex> lock(mutex_);
  const_cast<VirtualCanNetwork*>(this)->PumpLocked(clock_->Now());
  Statistics s = stats_;
  s.elapsed = clock_->Now() - stats_start_;
  return s;
}

void VirtualCanNetwork::ResetStatistics() {
  std::lock_guard<std::mutex> lock(mutex_);
  PumpLocked(clock_->Now());
  stats_ = Statistics{};
  stats_start_ = clock_->Now();
}

void VirtualCanNetwork::Detach(VirtualCanBus* node) {
  nodes_.erase(std::remove(nodes_.begin(), nodes_.end(), node), nodes_.end());
  pending_.erase(std::remove_if(pending_.begin(), pending_.end(),
                                [node](const Pending& p) { return p.sender == node; }),
                 pending_.end());
  for (InFlight& f : in_flight_) {
    if (f.sender == node) f.sender = nullptr;
  }
}

void VirtualCanNetwork::AbandonPendingLocked(VirtualCanBus* node) {
  for (const Pending& q : pending_) {
    if (q.sender == node) ++node->counters_.tx_errors;
  }
  pending_.erase(std::remove_if(pending_.begin(), pending_.end(),
                                [node](const Pending& q) { return q.sender == node; }),
                 pending_.end());
  node->tx_pending_ = 0;
}

void VirtualCanNetwork::DeliverLocked(const CanFrame& frame, VirtualCanBus* sender,
                                      common::Duration at) {
  ++stats_.frames;
  for (VirtualCanBus* node : nodes_) {
    if (node == sender || node->state_ == CanBusState::kBusOff) continue;
    if (!node->PassesFiltersLocked(frame)) {
      ++node->counters_.rx_filtered;
      continue;
    }
    if (node->ring_size_ == node->ring_.size()) {
      ++node->counters_.rx_overflows;
      // One event per overflow episode, not per lost frame.
      if (node->counters_.rx_overflows == 1 || node->errors_.empty() ||
          node->errors_.back().kind != CanErrorKind::kRxOverflow) {
        node->RaiseLocked(CanErrorKind::kRxOverflow, at,
                          "receive queue of " + std::to_string(node->ring_.size()) +
                              " frames full; frames are being lost");
      }
      continue;
    }
    size_t tail = (node->ring_head_ + node->ring_size_) % node->ring_.size();
    node->ring_[tail] = frame;
    node->ring_[tail].timestamp = at;
    ++node->ring_size_;
    if (node->rec_ > 0) node->AdjustCountersLocked(0, -1, at);
    if (node->waiting_receivers_ > 0) node->rx_cv_.notify_one();
  }
}

void VirtualCanNetwork::PumpLocked(common::Duration now) {
  while (!pending_.empty()) {
    common::Duration earliest = pending_.front().submitted;
    for (const Pending& p : pending_) earliest = std::min(earliest, p.submitted);
    const common::Duration start = std::max(bus_free_at_, earliest);
    if (start > now) break;
    // Arbitration among the frames waiting when the wire became free.
    size_t winner = pending_.size();
    for (size_t i = 0; i < pending_.size(); ++i) {
      const Pending& p = pending_[i];
      if (p.submitted > start) continue;
      if (winner == pending_.size()) {
        winner = i;
        continue;
      }
      const Pending& w = pending_[winner];
      uint64_t kp = ArbitrationKey(p.frame), kw = ArbitrationKey(w.frame);
      if (kp < kw || (kp == kw && p.sequence < w.sequence)) winner = i;
    }
    const Pending p = pending_[winner];
    common::Duration end = start;
    int bits = 0;
    if (options_.bitrate > 0) {
      bits = CanFrameWireBits(p.frame);
      end = start + WireTime(bits, options_.bitrate);
      if (end > now) break;  // still on the wire
      stats_.busy += end - start;
      stats_.bits += static_cast<uint64_t>(bits);
    }
    bus_free_at_ = end;
    VirtualCanBus* sender = p.sender;
    std::uniform_real_distribution<double> uniform(0.0, 1.0);
    if (faults_active_ && faults_.corrupt_probability > 0 &&
        uniform(rng_) < faults_.corrupt_probability) {
      // A CRC error: the receivers signal an error frame, the frame stays queued for
      // retransmission (automatic in CAN), the counters move (ISO 11898-1, fault confinement).
      ++stats_.error_frames;
      for (VirtualCanBus* node : nodes_) {
        if (node->state_ == CanBusState::kBusOff) continue;
        node->RaiseLocked(CanErrorKind::kProtocol, end,
                          "CRC error on frame " + FormatCanFrame(p.frame) +
                              (node == sender ? " (own transmission; retransmitting)" : ""));
        if (node == sender) {
          node->AdjustCountersLocked(+8, 0, end);
        } else {
          node->AdjustCountersLocked(0, +1, end);
        }
      }
      continue;
    }
    pending_.erase(pending_.begin() + static_cast<std::ptrdiff_t>(winner));
    --sender->tx_pending_;
    if (sender->tec_ > 0) sender->AdjustCountersLocked(-1, 0, end);
    if (faults_active_ && faults_.drop_probability > 0 &&
        uniform(rng_) < faults_.drop_probability) {
      ++stats_.dropped;
      continue;
    }
    const common::Duration deliver_at =
        end + (faults_active_ ? faults_.delay : common::Duration::zero());
    // Keep in_flight_ sorted by delivery time (the delay may change between frames).
    auto pos = in_flight_.end();
    while (pos != in_flight_.begin() && std::prev(pos)->deliver_at > deliver_at) --pos;
    in_flight_.insert(pos, InFlight{p.frame, sender, deliver_at});
  }
  while (!in_flight_.empty() && in_flight_.front().deliver_at <= now) {
    InFlight f = in_flight_.front();
    in_flight_.pop_front();
    DeliverLocked(f.frame, f.sender, f.deliver_at);
  }
}

// ---------------------------------------------------------------------------------------------
// VirtualCanBus

VirtualCanBus::VirtualCanBus(std::shared_ptr<VirtualCanNetwork> network, std::string name)
    : network_(std::move(network)),
      name_(std::move(name)),
      ring_(network_->options_.rx_queue_capacity) {}

VirtualCanBus::~VirtualCanBus() {
  std::lock_guard<std::mutex> lock(network_->mutex_);
  network_->Detach(this);
}

std::error_code VirtualCanBus::Send(const CanFrame& frame) {
  if (frame.dlc > 8 || (frame.extended ? frame.id > CanFrame::kMaxExtendedId
                                       : frame.id > CanFrame::kMaxStandardId)) {
    std::lock_guard<std::mutex> lock(network_->mutex_);
    ++counters_.tx_errors;
    return Errc::kInvalidArgument;
  }
  VirtualCanNetwork& net = *network_;
  std::lock_guard<std::mutex> lock(net.mutex_);
  if (state_ == CanBusState::kBusOff) {
    ++counters_.tx_errors;
    return Errc::kBusOff;
  }
  const common::Duration now = net.clock_->Now();
  if (net.options_.bitrate == 0 && !net.faults_active_ && net.pending_.empty() &&
      net.in_flight_.empty()) {
    // Infinitely fast wire, nothing queued: the frame is on every node at once.
    ++counters_.tx_frames;
    net.DeliverLocked(frame, this, now);
    if (tec_ > 0) AdjustCountersLocked(-1, 0, now);
    return {};
  }
  if (tx_pending_ >= net.options_.tx_queue_capacity) {
    ++counters_.tx_errors;
    return Errc::kOverflow;
  }
  net.pending_.push_back(VirtualCanNetwork::Pending{frame, this, now, net.sequence_++});
  ++tx_pending_;
  ++counters_.tx_frames;
  net.PumpLocked(now);
  // Receivers compute their wake-up time from the queue; a new frame changes it.
  for (VirtualCanBus* node : net.nodes_) {
    if (node->waiting_receivers_ > 0) node->rx_cv_.notify_all();
  }
  return {};
}

std::error_code VirtualCanBus::Receive(CanFrame* frame, std::chrono::microseconds timeout) {
  VirtualCanNetwork& net = *network_;
  const bool wall_clock = net.clock_ == &common::SteadyClock::Instance();
  // Clamped: now() + microseconds::max() would overflow.
  const auto wall_deadline = std::chrono::steady_clock::now() +
                             std::min(timeout, std::chrono::microseconds(std::chrono::hours(24)));
  std::unique_lock<std::mutex> lock(net.mutex_);
  while (true) {
    const common::Duration now = net.clock_->Now();
    net.PumpLocked(now);
    if (ring_size_ > 0) {
      *frame = ring_[ring_head_];
      ring_head_ = (ring_head_ + 1) % ring_.size();
      --ring_size_;
      ++counters_.rx_frames;
      return {};
    }
    if (timeout <= std::chrono::microseconds::zero() ||
        std::chrono::steady_clock::now() >= wall_deadline) {
      return Errc::kTimeout;
    }
    auto wake = wall_deadline;
    if (!wall_clock) {
      wake = std::min(wake, std::chrono::steady_clock::now() + std::chrono::milliseconds(1));
    } else {
      // Next moment the wire can change: a delivery falling due or a transmission ending.
      common::Duration next = common::Duration::max();
      if (!net.in_flight_.empty()) next = net.in_flight_.front().deliver_at;
      if (!net.pending_.empty()) {
        common::Duration earliest = common::Duration::max();
        for (const auto& p : net.pending_) earliest = std::min(earliest, p.submitted);
        common::Duration start = std::max(net.bus_free_at_, earliest);
        // Upper bound of one frame time (160 bits) keeps this cheap; the loop re-checks.
        common::Duration end =
            net.options_.bitrate > 0 ? start + WireTime(160, net.options_.bitrate) : start;
        next = std::min(next, std::max(end, now));
      }
      if (next != common::Duration::max()) {
        auto t = std::chrono::steady_clock::time_point(
            std::chrono::duration_cast<std::chrono::steady_clock::duration>(next));
        wake = std::min(wake, t);
      }
    }
    ++waiting_receivers_;
    rx_cv_.wait_until(lock, wake);
    --waiting_receivers_;
  }
}

std::error_code VirtualCanBus::SetFilters(const std::vector<CanFilter>& filters) {
  for (const CanFilter& f : filters) {
    if (f.mask > CanFrame::kMaxExtendedId) return Errc::kInvalidArgument;
  }
  std::lock_guard<std::mutex> lock(network_->mutex_);
  filters_ = filters;
  return {};
}

bool VirtualCanBus::TakeErrorEvent(CanErrorEvent* event) {
  std::lock_guard<std::mutex> lock(network_->mutex_);
  network_->PumpLocked(network_->clock_->Now());
  if (errors_.empty()) return false;
  *event = std::move(errors_.front());
  errors_.pop_front();
  return true;
}

CanBusState VirtualCanBus::state() const {
  std::lock_guard<std::mutex> lock(network_->mutex_);
  return state_;
}

CanCounters VirtualCanBus::counters() const {
  std::lock_guard<std::mutex> lock(network_->mutex_);
  return counters_;
}

int VirtualCanBus::tx_error_counter() const {
  std::lock_guard<std::mutex> lock(network_->mutex_);
  return tec_;
}

int VirtualCanBus::rx_error_counter() const {
  std::lock_guard<std::mutex> lock(network_->mutex_);
  return rec_;
}

void VirtualCanBus::InjectBusOff() {
  std::lock_guard<std::mutex> lock(network_->mutex_);
  AdjustCountersLocked(256 - tec_, 0, network_->clock_->Now());
}

void VirtualCanBus::Recover() {
  std::lock_guard<std::mutex> lock(network_->mutex_);
  const bool was_off = state_ == CanBusState::kBusOff;
  tec_ = 0;
  rec_ = 0;
  state_ = CanBusState::kErrorActive;
  if (was_off) RaiseLocked(CanErrorKind::kRestarted, network_->clock_->Now(), "bus-off recovery");
}

bool VirtualCanBus::PassesFiltersLocked(const CanFrame& frame) const {
  if (filters_.empty()) return true;
  for (const CanFilter& f : filters_) {
    if (f.Matches(frame)) return true;
  }
  return false;
}

void VirtualCanBus::RaiseLocked(CanErrorKind kind, common::Duration at, std::string detail) {
  ++counters_.error_events;
  if (kind == CanErrorKind::kBusOff) ++counters_.bus_off_events;
  if (errors_.size() >= kMaxQueuedErrorEvents) errors_.pop_front();
  errors_.push_back(CanErrorEvent{kind, at, std::move(detail)});
}

void VirtualCanBus::AdjustCountersLocked(int tec_delta, int rec_delta, common::Duration at) {
  if (state_ == CanBusState::kBusOff) return;
  tec_ = std::max(0, tec_ + tec_delta);
  // The receive error counter saturates at 128+ in error-passive (ISO 11898-1 keeps it there).
  rec_ = std::clamp(rec_ + rec_delta, 0, 135);
  const int worst = std::max(tec_, rec_);
  CanBusState next = CanBusState::kErrorActive;
  if (tec_ >= 256) {
    next = CanBusState::kBusOff;
  } else if (worst >= 128) {
    next = CanBusState::kErrorPassive;
  } else if (worst >= 96) {
    next = CanBusState::kErrorWarning;
  }
  if (next == state_) return;
  const std::string counters = "tec " + std::to_string(tec_) + ", rec " + std::to_string(rec_);
  if (static_cast<int>(next) > static_cast<int>(state_)) {
    CanErrorKind kind = next == CanBusState::kBusOff         ? CanErrorKind::kBusOff
                        : next == CanBusState::kErrorPassive ? CanErrorKind::kErrorPassive
                                                             : CanErrorKind::kErrorWarning;
    RaiseLocked(kind, at, name_ + ": " + counters);
  }
  state_ = next;
  if (state_ == CanBusState::kBusOff) {
    // The controller leaves the bus and abandons its transmit queue; frames already received
    // stay readable.
    network_->AbandonPendingLocked(this);
  }
}

}  // namespace kinevis::hal
