// kinevis drive BACKEND --nodes 1,2 [options] status|enable|disable|fault-reset|move: bring-up
// of motor drives on every drive backend: CiA 402 over CANopen ("socketcan:can0",
// "slcan:/dev/ttyACM0@115200,bitrate=1000000", "virtual:NAME") and the RS485 drives
// ("modbus-rtu:/dev/ttyUSB0@3000000,8E1"). The simulators are `kinevis sim drive` and
// `kinevis sim rs485-drive` (cmd_drive_sim.cc). docs/canopen.md describes the commands.

#include <spdlog/spdlog.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "common/clock.h"
#include "hal/can/can_bus_factory.h"
#include "hal/canopen/canopen_codec.h"
#include "hal/canopen/canopen_master.h"
#include "hal/common/backend_spec.h"
#include "hal/common/error.h"
#include "hal/drive/cia402_can_drive.h"
#include "hal/drive/rs485_drive.h"

namespace kinevis::cli {
namespace {

using namespace std::chrono_literals;
using common::Duration;

struct DriveCliOptions {
  std::string backend;
  std::vector<int> nodes{1};
  std::string protocol;  // "", "cia402" or "rs485"
  double counts_per_rad = 1.0;
  double per_mille_per_nm = 1.0;
  double cycle_ms = 5.0;
  int sdo_timeout_ms = 500;
  int heartbeat_ms = 50;
  // enable
  bool reset_fault = false;
  double hold_s = 0.0;
  // move
  double position = 0.0;
  std::string mode = "csp";
  double duration_s = 2.0;
  double tolerance = 0.01;
};

// The drives of one bus, whichever protocol.
class Session {
 public:
  explicit Session(const DriveCliOptions& o) : options_(o) {
    const std::string scheme = hal::BackendScheme(o.backend);
    std::string protocol = o.protocol;
    const bool can = scheme == "socketcan" || scheme == "slcan" || scheme == "virtual";
    if (protocol.empty()) protocol = scheme == "modbus-rtu" ? "rs485" : "cia402";
    if (protocol == "cia402" && !can) {
      throw common::ConfigError("backend \"" + o.backend + "\": --protocol cia402 needs a CAN " +
                                "backend (socketcan:, slcan:, virtual:)");
    }
    if (protocol == "rs485" && scheme != "modbus-rtu") {
      throw common::ConfigError("backend \"" + o.backend + "\": --protocol rs485 needs a " +
                                "modbus-rtu: backend");
    }
    CheckNodes(protocol == "rs485" ? 247 : 127);
    const auto period = std::chrono::microseconds(std::llround(o.cycle_ms * 1000));
    if (protocol == "cia402") {
      hal::canopen::CanopenMasterOptions mo;
      mo.cycle_period = period;
      mo.cycle_timeout = period * 4 / 5;
      mo.sdo.timeout = std::chrono::milliseconds(o.sdo_timeout_ms);
      can_ = std::make_unique<hal::canopen::CanopenMaster>(hal::OpenCanBus(o.backend), mo);
      for (int node : o.nodes) {
        hal::Cia402CanDriveConfig c;
        c.node = static_cast<uint8_t>(node);
        c.drive = DriveOptions();
        c.heartbeat_producer = std::chrono::milliseconds(o.heartbeat_ms);
        drives_.push_back(can_->AddDrive(c));
      }
    } else {
      hal::Rs485DriveBusOptions ro;
      ro.cycle_period = period;
      rs485_ = std::make_unique<hal::Rs485DriveBus>(o.backend, ro);
      for (int unit : o.nodes) {
        hal::Rs485DriveConfig c;
        c.unit = unit;
        c.drive = DriveOptions();
        drives_.push_back(rs485_->AddDrive(c));
      }
    }
  }

  const std::vector<hal::Cia402HostDrive*>& drives() const { return drives_; }
  common::Clock& clock() const { return can_ ? can_->clock() : rs485_->clock(); }

  void ConfigureAll() {
    if (can_) {
      can_->ConfigureAll();
    } else {
      rs485_->ConfigureAll();
    }
  }
  std::error_code EnableAll(std::chrono::milliseconds timeout, bool reset) {
    return can_ ? can_->EnableAll(timeout, reset) : rs485_->EnableAll(timeout, reset);
  }
  std::error_code DisableAll() { return can_ ? can_->DisableAll() : rs485_->DisableAll(); }
  // Before the process ends: RS485 drives are disabled and their watchdogs switched off, so
  // that the next command does not find them faulted (CANopen drives keep their state).
  void Close() {
    if (rs485_) rs485_->Close();
  }
  bool RunCyclesUntil(Duration deadline, const std::function<bool()>& done) {
    return can_ ? can_->RunCyclesUntil(deadline, done) : rs485_->RunCyclesUntil(deadline, done);
  }
  // Cycles for `seconds` (or until Ctrl-C); `each` runs before every cycle with the time since
  // the start, in s.
  void RunFor(double seconds, const std::function<void(double)>& each = {}) {
    const Duration start = clock().Now();
    const Duration end =
        start + std::chrono::duration_cast<Duration>(std::chrono::duration<double>(seconds));
    RunCyclesUntil(end, [&] {
      if (each) each(std::chrono::duration<double>(clock().Now() - start).count());
      return StopRequested();
    });
  }

 private:
  hal::Cia402DriveOptions DriveOptions() const {
    hal::Cia402DriveOptions d;
    d.scaling.position_counts_per_unit = options_.counts_per_rad;
    d.scaling.velocity_counts_per_unit = options_.counts_per_rad;
    d.scaling.torque_per_mille_per_unit = options_.per_mille_per_nm;
    d.command_timeout = 1000ms;
    if (options_.mode == "pp") d.mode = hal::DriveMode::kProfilePosition;
    return d;
  }

  void CheckNodes(int max) const {
    std::string problems;
    std::set<int> seen;
    for (int n : options_.nodes) {
      if (n < 1 || n > max) {
        problems += " " + std::to_string(n) + " is outside 1.." + std::to_string(max) + ";";
      } else if (!seen.insert(n).second) {
        problems += " " + std::to_string(n) + " appears twice;";
      }
    }
    if (options_.nodes.empty()) problems += " none given;";
    if (!problems.empty()) {
      problems.pop_back();
      throw common::ConfigError("--nodes:" + problems);
    }
  }

  const DriveCliOptions options_;
  std::unique_ptr<hal::canopen::CanopenMaster> can_;
  std::unique_ptr<hal::Rs485DriveBus> rs485_;
  std::vector<hal::Cia402HostDrive*> drives_;
};

void PrintStatus(const hal::Cia402HostDrive& d) {
  const hal::DriveStatus s = d.status();
  char error[16];
  std::snprintf(error, sizeof error, "0x%04X", s.error_code);
  std::string line = d.name() + ": " + common::ToString(d.lifecycle()) + ", state '" +
                     hal::ToString(s.state) + "', mode " +
                     (s.mode ? hal::ToString(*s.mode) : "unknown") + ", position " +
                     std::to_string(s.position) + " rad, velocity " + std::to_string(s.velocity) +
                     " rad/s, torque " + std::to_string(s.torque) + " N·m, error " + error + " (" +
                     (s.error_code == 0 ? "none" : hal::canopen::EmcyErrorText(s.error_code)) + ")";
  if (s.fault_source != hal::DriveFaultSource::kNone) {
    line += s.fault_source == hal::DriveFaultSource::kLink ? ", link fault" : ", device fault";
  }
  std::puts(line.c_str());
  std::fflush(stdout);
}

void PrintAll(const Session& session) {
  for (const hal::Cia402HostDrive* d : session.drives()) PrintStatus(*d);
}

// Prints every drive's status and, when `ec` is set, why each drive that failed did; then ends
// the session. Returns the exit code.
int Finish(Session& session, std::error_code ec, const char* what) {
  PrintAll(session);
  if (ec) {
    for (const hal::Cia402HostDrive* d : session.drives()) {
      if (d->last_error_text().empty()) continue;
      std::fprintf(stderr, "kinevis drive %s: %s\n", what, d->last_error_text().c_str());
    }
  }
  session.Close();
  return ec ? kExitHardware : kExitOk;
}

int RunStatus(const DriveCliOptions& o) {
  Session session(o);
  session.ConfigureAll();
  session.RunFor(0.05);
  return Finish(session, {}, "status");
}

int RunEnable(const DriveCliOptions& o) {
  Session session(o);
  session.ConfigureAll();
  if (std::error_code ec = session.EnableAll(3000ms, o.reset_fault)) {
    session.DisableAll();
    return Finish(session, ec, "enable");
  }
  if (o.hold_s > 0) {
    spdlog::info("holding position for {} s (Ctrl-C ends)", o.hold_s);
    session.RunFor(o.hold_s);
  }
  PrintAll(session);
  // A process that ends leaves nobody to supervise the drives: disable them.
  return Finish(session, session.DisableAll(), "enable");
}

int RunDisable(const DriveCliOptions& o) {
  Session session(o);
  session.ConfigureAll();
  return Finish(session, session.DisableAll(), "disable");
}

int RunFaultReset(const DriveCliOptions& o) {
  Session session(o);
  session.ConfigureAll();
  std::error_code first;
  for (hal::Cia402HostDrive* d : session.drives()) {
    if (std::error_code ec = d->FaultReset(); ec && !first) first = ec;
  }
  return Finish(session, first, "fault-reset");
}

int RunMove(const DriveCliOptions& o) {
  Session session(o);
  session.ConfigureAll();
  if (std::error_code ec = session.EnableAll(3000ms, o.reset_fault)) {
    session.DisableAll();
    return Finish(session, ec, "move");
  }
  std::vector<double> start;
  for (hal::Cia402HostDrive* d : session.drives()) start.push_back(d->status().position);
  std::error_code refused;
  if (o.mode == "pp") {
    for (hal::Cia402HostDrive* d : session.drives()) {
      if (std::error_code ec = d->SetTargetPosition(o.position); ec && !refused) refused = ec;
    }
    session.RunFor(o.duration_s + 1.0);
  } else {
    // A cosine profile: starts and ends at rest.
    session.RunFor(o.duration_s, [&](double t) {
      const double s = t >= o.duration_s ? 1.0 : 0.5 * (1 - std::cos(M_PI * t / o.duration_s));
      for (size_t i = 0; i < session.drives().size(); ++i) {
        hal::Cia402HostDrive* d = session.drives()[i];
        if (d->lifecycle() != common::DeviceLifecycle::kActive) continue;
        if (std::error_code ec = d->SetTargetPosition(start[i] + s * (o.position - start[i]));
            ec && !refused) {
          refused = ec;
        }
      }
    });
    for (hal::Cia402HostDrive* d : session.drives()) (void)d->SetTargetPosition(o.position);
    session.RunFor(0.2);
  }
  bool reached = !refused;
  bool failed = false;
  for (hal::Cia402HostDrive* d : session.drives()) {
    failed = failed || d->lifecycle() == common::DeviceLifecycle::kFault;
    reached = reached && std::fabs(d->status().position - o.position) <= o.tolerance;
  }
  PrintAll(session);
  const std::error_code off = session.DisableAll();
  if (failed || off) return Finish(session, failed ? hal::Errc::kDeviceFault : off, "move");
  session.Close();
  if (refused) {
    std::fprintf(stderr, "kinevis drive move: target %f rad refused: %s\n", o.position,
                 refused.message().c_str());
    return kExitJobFailed;
  }
  if (!reached) {
    std::fprintf(stderr, "kinevis drive move: target %f rad not reached within %f rad\n",
                 o.position, o.tolerance);
    return kExitJobFailed;
  }
  return kExitOk;
}

}  // namespace

void AddDriveCommands(const Parents& parents, CommandList* commands) {
  CLI::App& app = *parents.app;
  CLI::App& sim = *parents.sim;
  AddDriveSimCommands(sim, commands);

  auto o = std::make_shared<DriveCliOptions>();
  CLI::App* drive = app.add_subcommand(
      "drive", "Motor drive bring-up: CiA 402 over CANopen or the RS485 (Modbus RTU) drives");
  drive->require_subcommand(1);
  drive
      ->add_option("backend", o->backend,
                   "socketcan:IFACE, slcan:DEVICE[@BAUD][,bitrate=N], virtual:NAME (CiA 402) "
                   "or modbus-rtu:DEVICE[@BAUD][,8E1] (RS485); docs/backends.md")
      ->required();
  drive->add_option("--nodes", o->nodes, "CANopen node ids or Modbus unit ids, comma-separated")
      ->delimiter(',')
      ->capture_default_str();
  drive
      ->add_option("--protocol", o->protocol,
                   "cia402 or rs485 (default: from the backend: modbus-rtu is rs485)")
      ->check(CLI::IsMember({"cia402", "rs485"}));
  drive
      ->add_option("--counts-per-rad", o->counts_per_rad,
                   "Position (and velocity) scale of the drives, counts per rad")
      ->capture_default_str();
  drive
      ->add_option("--per-mille-per-nm", o->per_mille_per_nm,
                   "Torque scale, per mille of rated torque per N·m")
      ->capture_default_str();
  drive->add_option("--cycle-ms", o->cycle_ms, "Cycle (SYNC) period, ms")
      ->check(CLI::Range(0.1, 1000.0))
      ->capture_default_str();
  drive->add_option("--sdo-timeout-ms", o->sdo_timeout_ms, "SDO response timeout, ms (CANopen)")
      ->check(CLI::Range(1, 60000))
      ->capture_default_str();
  drive
      ->add_option("--heartbeat-ms", o->heartbeat_ms,
                   "Producer heartbeat time set on the drives, ms (CANopen; consumer: 3x)")
      ->check(CLI::Range(1, 20000))
      ->capture_default_str();
  drive->footer(
      "Exit codes: 0 done, 1 target not reached or refused, 2 usage, 3 a drive could "
      "not be reached, refused or faulted (the message names it).");

  CLI::App* status = drive->add_subcommand("status", "Configure and print each drive's state");
  commands->push_back({status, [o] { return RunStatus(*o); }});

  CLI::App* enable = drive->add_subcommand(
      "enable", "Enable (Operation enabled), hold position for --hold seconds, then disable");
  enable->add_flag("--reset-fault", o->reset_fault, "Reset a drive fault first");
  enable->add_option("--hold", o->hold_s, "Seconds to hold enabled (Ctrl-C ends)")
      ->check(CLI::NonNegativeNumber);
  commands->push_back({enable, [o] { return RunEnable(*o); }});

  CLI::App* disable = drive->add_subcommand("disable", "Disable voltage (Switch on disabled)");
  commands->push_back({disable, [o] { return RunDisable(*o); }});

  CLI::App* reset =
      drive->add_subcommand("fault-reset", "Reset drive faults (rising edge of bit 7)");
  commands->push_back({reset, [o] { return RunFaultReset(*o); }});

  CLI::App* move = drive->add_subcommand(
      "move", "Enable, move every drive to --position, check it, then disable");
  move->add_option("--position", o->position, "Target position, rad")->required();
  move->add_option("--mode", o->mode,
                   "csp: the host interpolates a cosine profile over --duration; pp: the drive's "
                   "profile generator")
      ->check(CLI::IsMember({"csp", "pp"}))
      ->capture_default_str();
  move->add_option("--duration", o->duration_s, "Duration of the move, s")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  move->add_option("--tolerance", o->tolerance, "Accepted position error at the end, rad")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  move->add_flag("--reset-fault", o->reset_fault, "Reset a drive fault first");
  commands->push_back({move, [o] { return RunMove(*o); }});
}

}  // namespace kinevis::cli
