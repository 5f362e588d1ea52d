// kinevis servo BACKEND ping|read|move|torque|reboot: bring-up of Dynamixel servos on a serial bus
// (hal/dynamixel/dynamixel_bus.h); kinevis sim dynamixel: a chain of simulated servos on a
// pseudo-terminal (hal/mock/dynamixel_sim.h). Positions are in rad on this command line, as
// everywhere inside kinevis; the output adds degrees for the eye. docs/dynamixel.md.

#include <spdlog/spdlog.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "common/units.h"
#include "hal/common/error.h"
#include "hal/dynamixel/control_table.h"
#include "hal/dynamixel/dynamixel_bus.h"
#include "hal/mock/dynamixel_sim.h"
#include "hal/serial/pty_pair.h"

namespace kinevis::cli {
namespace {

struct ServoOptions {
  std::string backend;
  int protocol = 0;  // 0: the model's
  std::vector<int> ids{1};
  std::string model;  // empty: mx-12w for protocol 1 (and by default), xm430-w350 for 2
  std::string table_path;
  int timeout_ms = 30;
  int retries = 2;
  // read
  std::vector<std::string> registers;
  // move
  double position = 0.0;
  double velocity = -1.0;  // rad/s; < 0: leave the servo's setting
  double tolerance = 0.01;
  double wait_s = 10.0;
  bool no_wait = false;
  // torque
  std::string torque;
};

// The control table: --table FILE, --model NAME, or the protocol's default model.
hal::DxlControlTable LoadTable(const ServoOptions& o) {
  hal::DxlControlTable table;
  if (!o.table_path.empty()) {
    table = hal::DxlControlTable::LoadFile(o.table_path);
  } else if (!o.model.empty()) {
    table = hal::DxlControlTable::LoadModel(o.model);
  } else {
    table = hal::DxlControlTable::LoadModel(o.protocol == 2 ? "xm430-w350" : "mx-12w");
  }
  if (o.protocol != 0 && o.protocol != table.protocol()) {
    throw common::ConfigError("--protocol " + std::to_string(o.protocol) + ": the control table " +
                              table.model() + " (" + table.source() + ") is for protocol " +
                              std::to_string(table.protocol()));
  }
  return table;
}

std::vector<uint8_t> Ids(const std::vector<int>& ids, int protocol) {
  std::vector<uint8_t> out;
  const int max_id = protocol == 1 ? 253 : 252;
  for (int id : ids) {
    if (id < 0 || id > max_id) {
      throw common::ConfigError("--ids: " + std::to_string(id) + " is not a servo id 0.." +
                                std::to_string(max_id));
    }
    out.push_back(static_cast<uint8_t>(id));
  }
  return out;
}

struct Session {
  hal::DxlControlTable table;
  std::unique_ptr<hal::DynamixelBus> bus;
  std::vector<std::unique_ptr<hal::DynamixelServo>> servos;
};

// Opens the bus; with `configure`, configures every servo (throws HalError for the first that
// fails: no answer, another model, wheel mode).
Session Open(const ServoOptions& o, bool configure) {
  Session s;
  s.table = LoadTable(o);
  hal::DynamixelBusOptions bus_options;
  bus_options.protocol = s.table.protocol();
  bus_options.timeout = std::chrono::milliseconds(o.timeout_ms);
  bus_options.retries = o.retries;
  const std::vector<uint8_t> ids = Ids(o.ids, s.table.protocol());
  s.bus = hal::DynamixelBus::Open(o.backend, bus_options);
  for (uint8_t id : ids) {
    s.servos.push_back(std::make_unique<hal::DynamixelServo>(s.bus.get(), id, s.table));
    if (configure) s.servos.back()->Configure();
  }
  return s;
}

[[noreturn]] void Fail(const hal::DynamixelServo& servo, const char* operation,
                       std::error_code ec) {
  std::string cause = ec.message();
  if (ec == hal::Errc::kDeviceFault) {
    const uint8_t error = servo.state().status_error;
    cause += " (" +
             std::string(servo.table().protocol() == 1 ? hal::Dxl1ErrorText(error)
                                                       : hal::Dxl2ErrorText(error)) +
             ")";
  }
  throw hal::HalError(servo.name(), operation, cause, ec);
}

std::string StateLine(const hal::DynamixelServo& servo, const hal::DxlServoState& st) {
  char text[256];
  std::snprintf(text, sizeof text,
                "id %d: position %.4f rad (%.2f deg), velocity %.4f rad/s, moving %s, torque %s",
                servo.id(), st.position, st.position / common::kDeg, st.velocity,
                st.moving ? "yes" : "no", st.torque_enabled ? "on" : "off");
  std::string line = text;
  if (st.load) {
    const hal::DxlRegister* load = servo.table().Find(hal::DxlRole::kPresentLoad);
    std::snprintf(text, sizeof text, ", %s %.3f %s", load->name.c_str(), *st.load,
                  load->unit.c_str());
    line += text;
  }
  if (st.hardware_error != 0) {
    line += ", alarm: " + (servo.table().protocol() == 1
                               ? hal::Dxl1ErrorText(st.hardware_error)
                               : hal::Dxl2HardwareErrorText(st.hardware_error));
  }
  return line;
}

int RunPing(const ServoOptions& o) {
  Session s = Open(o, false);
  int missing = 0;
  for (const auto& servo : s.servos) {
    uint16_t model = 0;
    uint8_t firmware = 0;
    const std::error_code ec = s.bus->PingModel(servo->id(), &model, &firmware);
    if (ec && ec != hal::Errc::kDeviceFault) {
      std::printf("id %d: no answer (%s)\n", servo->id(), ec.message().c_str());
      ++missing;
      continue;
    }
    const std::string known = s.table.AcceptsModelNumber(model) ? " (" + s.table.model() + ")"
                                                                : " (not " + s.table.model() + ")";
    std::printf("id %d: model number %u%s, firmware %u%s\n", servo->id(), model, known.c_str(),
                firmware, ec ? " [status error]" : "");
  }
  std::fflush(stdout);
  const hal::DynamixelBusCounters c = s.bus->counters();
  spdlog::info("{}: {} requests, {} timeouts, {} CRC errors, {} retries", s.bus->name(), c.requests,
               c.timeouts, c.crc_errors, c.retries);
  if (missing > 0) {
    throw hal::HalError(s.bus->name(), "ping",
                        std::to_string(missing) + " of " + std::to_string(s.servos.size()) +
                            " servos did not answer");
  }
  return kExitOk;
}

int RunRead(const ServoOptions& o) {
  Session s = Open(o, true);
  for (const auto& servo : s.servos) {
    hal::DxlServoState st;
    const std::error_code ec = servo->ReadState(&st);
    if (ec && ec != hal::Errc::kDeviceFault) Fail(*servo, "read the state", ec);
    std::printf("%s\n", StateLine(*servo, st).c_str());
    for (const std::string& name : o.registers) {
      const hal::DxlRegister* reg = s.table.Find(name);
      if (reg == nullptr) {
        throw common::ConfigError("--register: " + s.table.model() + " has no register \"" + name +
                                  "\"");
      }
      hal::DxlReply reply;
      const std::error_code rec = s.bus->Read(servo->id(), reg->address, reg->size, &reply);
      if (reply.data.size() != reg->size) Fail(*servo, ("read " + name).c_str(), rec);
      const int64_t raw = hal::DxlControlTable::DecodeRaw(*reg, reply.data.data());
      std::printf("id %d: %s = %lld", servo->id(), name.c_str(), static_cast<long long>(raw));
      if (reg->unit != "raw") {
        std::printf(" (%.6g %s)", hal::DxlControlTable::ToSi(*reg, raw), reg->unit.c_str());
      }
      std::printf("\n");
    }
  }
  std::fflush(stdout);
  return kExitOk;
}

int RunMove(const ServoOptions& o) {
  Session s = Open(o, true);
  for (const auto& servo : s.servos) {
    if (o.position < servo->min_position() || o.position > servo->max_position()) {
      throw common::ConfigError("--position " + std::to_string(o.position) + " rad is outside " +
                                servo->name() + "'s limits [" +
                                std::to_string(servo->min_position()) + ", " +
                                std::to_string(servo->max_position()) + "] rad");
    }
  }
  for (const auto& servo : s.servos) {
    if (std::error_code ec = servo->Enable()) Fail(*servo, "torque on", ec);
    if (o.velocity >= 0) {
      if (std::error_code ec = servo->SetProfileVelocity(o.velocity)) {
        if (ec == hal::Errc::kInvalidArgument) {
          throw common::ConfigError("--velocity " + std::to_string(o.velocity) +
                                    " rad/s is outside the range of " + servo->name());
        }
        Fail(*servo, "set the profile velocity", ec);
      }
    }
    if (std::error_code ec = servo->SetGoalPosition(o.position)) {
      Fail(*servo, "set the goal position", ec);
    }
  }
  if (o.no_wait) return kExitOk;
  const auto deadline = std::chrono::steady_clock::now() +
                        std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                            std::chrono::duration<double>(o.wait_s));
  std::vector<bool> arrived(s.servos.size(), false);
  std::vector<hal::DxlServoState> last(s.servos.size());
  bool all = false;
  while (!all && !StopRequested() && std::chrono::steady_clock::now() < deadline) {
    all = true;
    for (size_t i = 0; i < s.servos.size(); ++i) {
      const std::error_code ec = s.servos[i]->ReadState(&last[i]);
      if (ec) Fail(*s.servos[i], "read the state", ec);
      arrived[i] = !last[i].moving && std::abs(last[i].position - o.position) <= o.tolerance;
      all = all && arrived[i];
    }
    if (!all) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  for (size_t i = 0; i < s.servos.size(); ++i) {
    std::printf("%s%s\n", StateLine(*s.servos[i], last[i]).c_str(),
                arrived[i] ? "" : "  [target not reached]");
  }
  std::fflush(stdout);
  if (!all) {
    spdlog::error("{}: position {:.4f} rad not reached within {} s (tolerance {} rad)",
                  s.bus->name(), o.position, o.wait_s, o.tolerance);
    return kExitJobFailed;
  }
  return kExitOk;
}

int RunTorque(const ServoOptions& o) {
  Session s = Open(o, true);
  for (const auto& servo : s.servos) {
    const bool on = o.torque == "on";
    if (std::error_code ec = on ? servo->Enable() : servo->Disable()) {
      Fail(*servo, on ? "torque on" : "torque off", ec);
    }
    std::printf("id %d: torque %s\n", servo->id(), on ? "on" : "off");
  }
  std::fflush(stdout);
  return kExitOk;
}

int RunReboot(const ServoOptions& o) {
  const hal::DxlControlTable table = LoadTable(o);
  if (table.protocol() != 2) {
    throw common::ConfigError(
        "reboot: protocol 1.0 has no reboot instruction; power-cycle the "
        "servo to clear its alarm");
  }
  Session s = Open(o, true);
  for (const auto& servo : s.servos) {
    if (std::error_code ec = servo->Reboot()) Fail(*servo, "reboot", ec);
    std::printf("id %d: rebooted, %s\n", servo->id(), common::ToString(servo->lifecycle()));
  }
  std::fflush(stdout);
  return kExitOk;
}

struct SimOptions {
  int protocol = 0;
  std::vector<int> ids{1};
  std::string model;
  std::string table_path;
  std::string link;
  int baud = 0;  // 0: the table's default
};

int RunSim(const SimOptions& o) {
  ServoOptions as_servo;
  as_servo.protocol = o.protocol;
  as_servo.model = o.model;
  as_servo.table_path = o.table_path;
  const hal::DxlControlTable table = LoadTable(as_servo);
  const int baud = o.baud > 0 ? o.baud : table.default_baud();
  hal::DynamixelSim::Options options;
  options.protocol = table.protocol();
  for (uint8_t id : Ids(o.ids, table.protocol())) options.servos.push_back({id, table});
  hal::PtyPair pty;
  if (!o.link.empty()) pty.CreateLink(o.link);
  hal::DynamixelSim sim(pty.MasterPort(baud), options);
  sim.Start();
  const std::string path = o.link.empty() ? pty.slave_path() : o.link;
  spdlog::info("{}: {} x {} (protocol {}.0), ids {}", sim.name(), o.ids.size(), table.model(),
               table.protocol(), [&] {
                 std::string text;
                 for (int id : o.ids) text += (text.empty() ? "" : ",") + std::to_string(id);
                 return text;
               }());
  const int code = ServeUntilStopped("tty:" + path + "@" + std::to_string(baud));
  sim.Stop();
  const hal::DynamixelSim::Statistics st = sim.statistics();
  spdlog::info("{}: {} instructions, {} replies, {} refused, {} checksum errors", sim.name(),
               st.instructions, st.replies, st.refused, st.checksum_errors);
  return code;
}

void AddCommonOptions(CLI::App* cmd, int* protocol, std::vector<int>* ids, std::string* model,
                      std::string* table_path) {
  cmd->add_option("--protocol", *protocol, "Dynamixel protocol 1 or 2 (default: the model's)")
      ->check(CLI::IsMember({1, 2}));
  cmd->add_option("--ids", *ids, "Servo ids, comma-separated (default 1)")
      ->delimiter(',')
      ->check(CLI::Range(0, 253));
  cmd->add_option("--model", *model,
                  "Control table of config/dynamixel/: mx-12w (protocol 1, the default) or "
                  "xm430-w350 (protocol 2)");
  cmd->add_option("--table", *table_path, "Control table YAML file (docs/dynamixel.md)")
      ->excludes("--model");
}

// The Dynamixel commands need the serial port (a positional that `servo hexapod` does not have).
const ServoOptions& NeedBackend(const ServoOptions& o) {
  if (o.backend.empty()) {
    throw std::invalid_argument(
        "servo: give the serial port first, e.g. kinevis servo tty:/dev/ttyUSB0@1000000 ping");
  }
  return o;
}

}  // namespace

void AddServoCommands(const Parents& parents, CommandList* commands) {
  CLI::App& sim = *parents.sim;
  auto o = std::make_shared<ServoOptions>();
  CLI::App* servo = parents.servo;
  // Not ->required(): `kinevis servo hexapod ...` has no backend; the Dynamixel commands check it.
  servo->add_option("backend", o->backend, "Serial port: tty:DEVICE[@BAUD] (docs/backends.md)");
  AddCommonOptions(servo, &o->protocol, &o->ids, &o->model, &o->table_path);
  servo->add_option("--timeout-ms", o->timeout_ms, "Wait for each status packet, ms")
      ->capture_default_str()
      ->check(CLI::Range(1, 10000));
  servo->add_option("--retries", o->retries, "Repeat a request after a timeout or CRC error")
      ->capture_default_str()
      ->check(CLI::Range(0, 10));
  servo->footer("Example: kinevis servo tty:/dev/ttyUSB0@1000000 --protocol 1 --ids 1 read");

  CLI::App* ping = servo->add_subcommand("ping", "Ping each id; print model number and firmware");
  commands->push_back({ping, [o] { return RunPing(NeedBackend(*o)); }});

  CLI::App* read = servo->add_subcommand(
      "read", "Configure each servo (model check, limits) and print its state");
  read->add_option("-r,--register", o->registers,
                   "Also print these registers of the control table (raw and SI)");
  commands->push_back({read, [o] { return RunRead(NeedBackend(*o)); }});

  CLI::App* move = servo->add_subcommand(
      "move", "Torque on and go to a position; wait until it is reached (torque stays on)");
  move->add_option("--position", o->position, "Goal position, rad (0 at tick 0)")->required();
  move->add_option("--velocity", o->velocity, "Profile velocity, rad/s (0: as fast as it can)")
      ->check(CLI::NonNegativeNumber);
  move->add_option("--tolerance", o->tolerance, "Arrival tolerance, rad")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  move->add_option("--wait", o->wait_s, "Give up after this many seconds (exit 1)")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  move->add_flag("--no-wait", o->no_wait, "Return once the goal is written");
  commands->push_back({move, [o] { return RunMove(NeedBackend(*o)); }});

  CLI::App* torque = servo->add_subcommand("torque", "Torque on (hold) or off (the safe state)");
  torque->add_option("state", o->torque, "on or off")
      ->required()
      ->check(CLI::IsMember({"on", "off"}));
  commands->push_back({torque, [o] { return RunTorque(NeedBackend(*o)); }});

  CLI::App* reboot = servo->add_subcommand(
      "reboot", "Reboot (protocol 2.0): clears an overload or other hardware alarm");
  commands->push_back({reboot, [o] { return RunReboot(NeedBackend(*o)); }});

  auto so = std::make_shared<SimOptions>();
  CLI::App* dxl = sim.add_subcommand(
      "dynamixel", "Simulated Dynamixel servos on a pseudo-terminal; prints tty:PATH@BAUD");
  AddCommonOptions(dxl, &so->protocol, &so->ids, &so->model, &so->table_path);
  dxl->add_option("--link", so->link, "Also reach the pty through this symbolic link");
  dxl->add_option("--baud", so->baud, "Baud rate in the printed backend (default: the model's)")
      ->check(CLI::PositiveNumber);
  commands->push_back({dxl, [so] { return RunSim(*so); }});
}

}  // namespace kinevis::cli
