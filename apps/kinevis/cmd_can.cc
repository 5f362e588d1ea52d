// kinevis can dump|send|replay: candump, cansend and canplayer on every CAN backend.

#include <spdlog/spdlog.h>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <thread>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "hal/can/can_bus_factory.h"
#include "hal/can/candump.h"
#include "hal/common/backend_spec.h"
#include "hal/common/error.h"

namespace kinevis::cli {
namespace {

using namespace std::chrono_literals;

// The interface column of a candump line: the SocketCAN interface, the virtual bus name, or the
// serial device's base name for slcan.
std::string InterfaceLabel(const hal::CanBackendSpec& spec) {
  if (spec.kind != hal::CanBackendSpec::Kind::kSlcan) return spec.interface;
  const std::string& d = spec.serial.device;
  size_t slash = d.rfind('/');
  return slash == std::string::npos ? d : d.substr(slash + 1);
}

// Every backend stamps frames on the steady clock (SocketCAN converts the kernel's wall-clock
// stamps); candump logs carry wall time, so stamps are shifted by the offset between the clocks.
std::chrono::nanoseconds WallTimeOffset() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
      std::chrono::system_clock::now().time_since_epoch() -
      std::chrono::steady_clock::now().time_since_epoch());
}

struct DumpOptions {
  std::string backend;
  int count = 0;          // 0 = no limit
  double duration_s = 0;  // 0 = no limit
  std::vector<std::string> filters;
  std::string log_path;
};

int RunDump(const DumpOptions& o) {
  const hal::CanBackendSpec spec = hal::ParseCanBackend(o.backend);
  std::vector<hal::CanFilter> filters;
  for (const std::string& text : o.filters) {
    std::string error;
    auto f = hal::ParseCanFilter(text, &error);
    if (!f) throw common::ConfigError("--filter: " + error);
    filters.push_back(*f);
  }
  std::ofstream log;
  if (!o.log_path.empty()) {
    log.open(o.log_path);
    if (!log) throw common::ConfigError("--log: cannot write \"" + o.log_path + "\"");
  }
  auto bus = hal::OpenCanBus(o.backend);
  if (!filters.empty()) {
    if (std::error_code ec = bus->SetFilters(filters)) {
      throw hal::HalError(bus->name(), "set filters", ec.message());
    }
  }
  spdlog::info("{}: listening{}{}", bus->name(),
               o.count > 0 ? ", stopping after " + std::to_string(o.count) + " frames" : "",
               o.duration_s > 0 ? ", for " + std::to_string(o.duration_s) + " s" : "");
  const std::string iface = InterfaceLabel(spec);
  const auto offset = WallTimeOffset();
  const auto start = std::chrono::steady_clock::now();
  const auto end = start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                               std::chrono::duration<double>(o.duration_s));
  int received = 0;
  while (!StopRequested() && (o.count == 0 || received < o.count)) {
    if (o.duration_s > 0 && std::chrono::steady_clock::now() >= end) break;
    hal::CanFrame frame;
    std::error_code ec = bus->Receive(&frame, 100ms);
    hal::CanErrorEvent event;
    while (bus->TakeErrorEvent(&event)) {
      spdlog::warn("{}: {} {}", bus->name(), hal::ToString(event.kind), event.detail);
    }
    if (ec == hal::Errc::kTimeout) continue;
    if (ec) throw hal::HalError(bus->name(), "receive", ec.message(), ec);
    ++received;
    hal::CandumpRecord record;
    record.timestamp = frame.timestamp + offset;
    record.interface = iface;
    record.frame = frame;
    const std::string line = hal::FormatCandumpLine(record);
    std::fputs(line.c_str(), stdout);
    std::fputc('\n', stdout);
    std::fflush(stdout);
    if (log.is_open()) log << line << '\n';
  }
  const hal::CanCounters c = bus->counters();
  spdlog::info("{}: {} frames received, {} filtered, {} overflows, {} error events", bus->name(),
               received, c.rx_filtered, c.rx_overflows, c.error_events);
  return kExitOk;
}

struct SendOptions {
  std::string backend;
  std::vector<std::string> frames;
  int repeat = 1;
  double interval_ms = 0;
};

int RunSend(const SendOptions& o) {
  std::vector<hal::CanFrame> frames;
  for (const std::string& text : o.frames) {
    std::string error;
    auto f = hal::ParseCanFrame(text, &error);
    if (!f) throw common::ConfigError(error);
    frames.push_back(*f);
  }
  auto bus = hal::OpenCanBus(o.backend);
  for (int r = 0; r < o.repeat && !StopRequested(); ++r) {
    for (const hal::CanFrame& f : frames) {
      if (std::error_code ec = bus->Send(f)) {
        throw hal::HalError(bus->name(), "send " + hal::FormatCanFrame(f), ec.message(), ec);
      }
      if (o.interval_ms > 0) {
        std::this_thread::sleep_for(std::chrono::duration<double, std::milli>(o.interval_ms));
      }
    }
  }
  spdlog::info("{}: sent {} frames", bus->name(), bus->counters().tx_frames);
  return kExitOk;
}

struct ReplayOptions {
  std::string backend;
  std::string file;
  bool realtime = false;
};

int RunReplay(const ReplayOptions& o) {
  const std::vector<hal::CandumpRecord> records = hal::ReadCandumpFile(o.file);
  auto bus = hal::OpenCanBus(o.backend);
  const auto start = std::chrono::steady_clock::now();
  size_t sent = 0, skipped = 0;
  for (const hal::CandumpRecord& r : records) {
    if (StopRequested()) break;
    if (r.error_frame) {
      ++skipped;  // error frames are reports of the controller, not traffic to reproduce
      continue;
    }
    if (o.realtime) {
      std::this_thread::sleep_until(start + (r.timestamp - records.front().timestamp));
    }
    if (std::error_code ec = bus->Send(r.frame)) {
      throw hal::HalError(bus->name(), "send " + hal::FormatCanFrame(r.frame), ec.message(), ec);
    }
    ++sent;
  }
  spdlog::info("{}: replayed {} frames from {} ({} error frames skipped)", bus->name(), sent,
               o.file, skipped);
  return kExitOk;
}

}  // namespace

void AddCanCommands(const Parents& parents, CommandList* commands) {
  CLI::App& app = *parents.app;
  CLI::App* can = app.add_subcommand("can", "CAN bus tools (candump, cansend, canplayer alike)");
  can->require_subcommand(1);
  const std::string backends =
      "CAN backend: socketcan:IFACE, slcan:DEVICE[@BAUD][,bitrate=N], virtual:NAME "
      "(docs/backends.md)";

  auto dump_opts = std::make_shared<DumpOptions>();
  CLI::App* dump = can->add_subcommand(
      "dump", "Print received frames in candump log format '(time) iface ID#DATA'");
  dump->add_option("backend", dump_opts->backend, backends)->required();
  dump->add_option("-n,--count", dump_opts->count, "Stop after N frames (0: no limit)")
      ->check(CLI::NonNegativeNumber);
  dump->add_option("-t,--duration", dump_opts->duration_s, "Stop after S seconds (0: no limit)")
      ->check(CLI::NonNegativeNumber);
  dump->add_option("-f,--filter", dump_opts->filters,
                   "Acceptance filter ID:MASK or ID~MASK (inverted), hex; repeatable");
  dump->add_option("-l,--log", dump_opts->log_path, "Also write the frames to this log file");
  dump->footer("Runs until Ctrl-C, --count or --duration.");
  commands->push_back({dump, [dump_opts] { return RunDump(*dump_opts); }});

  auto send_opts = std::make_shared<SendOptions>();
  CLI::App* send = can->add_subcommand("send", "Send frames given in cansend syntax");
  send->add_option("backend", send_opts->backend, backends)->required();
  send->add_option("frames", send_opts->frames,
                   "Frames: 123#DEADBEEF, 12345678#00 (extended), 123#R (remote)")
      ->required();
  send->add_option("-r,--repeat", send_opts->repeat, "Send the frames N times")
      ->check(CLI::PositiveNumber);
  send->add_option("-i,--interval-ms", send_opts->interval_ms, "Pause after each frame, ms")
      ->check(CLI::NonNegativeNumber);
  commands->push_back({send, [send_opts] { return RunSend(*send_opts); }});

  auto replay_opts = std::make_shared<ReplayOptions>();
  CLI::App* replay =
      can->add_subcommand("replay", "Send the frames of a candump log file (like canplayer)");
  replay->add_option("backend", replay_opts->backend, backends)->required();
  replay->add_option("file", replay_opts->file, "candump log file (docs/can-log-format.md)")
      ->required();
  replay->add_flag("--realtime", replay_opts->realtime, "Keep the recorded gaps between frames");
  commands->push_back({replay, [replay_opts] { return RunReplay(*replay_opts); }});
}

}  // namespace kinevis::cli
