// kinevis weld-robot BACKEND status|move|stream|stop|arc|reset: bring-up of the Modbus weld robot
// (hal/weld/weld_robot_client.h); kinevis sim weld-robot: its simulator as a process.
// The command line and the trajectory CSV use degrees and millimetres, as a technician thinks;
// they are converted to SI here, at the edge. Formats: docs/weld-robot-modbus.md.

#include <spdlog/spdlog.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "common/units.h"
#include "hal/common/error.h"
#include "hal/mock/weld_robot_sim.h"
#include "hal/weld/weld_robot_client.h"
#include "hal/weld/weld_robot_registers.h"
#include "robots/io/robot_description.h"

namespace kinevis::cli {
namespace {

namespace wr = hal::weld_robot;

struct WeldRobotOptions {
  std::string backend;
  // move
  std::vector<double> joints;  // θ1, θ2 [deg], pz3 [mm], θ4, θ5 [deg]
  double duration_s = 0;
  bool arc = false;
  // stream
  std::string file;
  double timeout_s = 0;
  bool no_check = false;
  // arc
  std::string arc_state;
  double current_a = -1;
  double voltage_v = -1;
  double wire_feed_m_min = -1;
};

std::string JointsText(const hal::WeldJoints& q) {
  char text[160];
  std::snprintf(text, sizeof text, "θ1 %.3f°, θ2 %.3f°, pz3 %.3f mm, θ4 %.3f°, θ5 %.3f°",
                q[0] / common::kDeg, q[1] / common::kDeg, q[2] * 1e3, q[3] / common::kDeg,
                q[4] / common::kDeg);
  return text;
}

// Maps a run-time fault of a command to the exit code of docs/cli.md: bad values (outside the
// robot's limits) are usage errors, everything else is the device failing.
[[noreturn]] void Throw(const hal::WeldRobotClient& client, const char* operation,
                        std::error_code ec) {
  if (ec == hal::Errc::kInvalidArgument) throw common::ConfigError(client.last_error_text());
  throw hal::HalError(client.name(), operation,
                      client.last_error_text().empty() ? ec.message() : client.last_error_text(),
                      ec);
}

std::unique_ptr<hal::WeldRobotClient> Connect(const std::string& backend, bool activate) {
  auto client = hal::WeldRobotClient::Open(backend);
  client->Configure();
  if (activate) {
    if (std::error_code ec = client->Activate()) {
      if (ec.category() == hal::WeldRobotAlarmCategory()) {
        throw hal::HalError(
            client->name(), "activate",
            std::string("alarm ") + wr::AlarmName(static_cast<uint16_t>(ec.value())) + " (code " +
                std::to_string(ec.value()) + ") is active; clear it with `kinevis weld-robot " +
                backend + " reset`",
            ec);
      }
      Throw(*client, "activate", ec);
    }
  }
  return client;
}

int RunStatus(const WeldRobotOptions& o) {
  auto client = Connect(o.backend, false);
  hal::WeldRobotState s;
  if (std::error_code ec = client->ReadState(&s)) Throw(*client, "read state", ec);
  const hal::WeldRobotIdentity& id = client->identity();
  std::printf("device: %s\n", client->name().c_str());
  std::printf("serial number: %u, register map version %d\n", id.serial_number, id.map_version);
  std::printf("motion: %s\n", wr::MotionStateName(s.motion_raw));
  std::printf("alarm: %s (%u)\n", s.alarm_name, s.alarm_code);
  std::printf("buffer: %d/%d segments\n", s.buffer_level, s.buffer_capacity);
  std::printf("arc: %s, %s\n", s.arc_enabled ? "enabled" : "disabled", s.arc_on ? "on" : "off");
  std::printf("joints: %s\n", JointsText(s.joints).c_str());
  std::printf("weld: %.1f A, %.1f V, wire feed %.2f m/min\n", s.weld.current, s.weld.voltage,
              s.weld.wire_feed_speed * 60);
  std::printf("sequence: last accepted %u, last completed %u\n", s.last_sequence,
              s.completed_sequence);
  return kExitOk;
}

// Streams and reports progress on stdout about every 10 %; SIGINT/SIGTERM stops the robot.
int Stream(hal::WeldRobotClient& client, const std::vector<hal::WeldTrajectoryPoint>& points,
           const WeldRobotOptions& o) {
  std::atomic<bool> cancel{false};
  const size_t step = std::max<size_t>(1, points.size() / 10);
  size_t reported = 0;
  auto progress = [&](const hal::WeldStreamProgress& p) {
    if (StopRequested()) cancel = true;
    if (p.executed >= reported + step || (p.executed == p.total && reported != p.total)) {
      reported = p.executed;
      std::printf("progress: %zu/%zu executed, %zu sent, buffer %d/%d\n", p.executed, p.total,
                  p.sent, p.buffer_level, p.buffer_capacity);
      std::fflush(stdout);
    }
  };
  hal::WeldStreamOptions options;
  options.check_limits = !o.no_check;
  if (o.timeout_s > 0) {
    options.timeout = std::chrono::milliseconds(std::llround(o.timeout_s * 1e3));
  }
  hal::WeldStreamReport report;
  std::error_code ec = client.StreamTrajectory(points, progress, &cancel, options, &report);
  if (ec == std::errc::operation_canceled) {
    std::fprintf(stderr, "kinevis weld-robot: %s\n", report.message.c_str());
    return kExitJobFailed;
  }
  if (ec) Throw(client, "stream", ec);
  hal::WeldRobotState s;
  if (std::error_code read = client.ReadState(&s)) Throw(client, "read state", read);
  std::printf("done: %zu segments executed, highest buffer level %d, joints: %s\n", report.executed,
              report.max_buffer_level, JointsText(s.joints).c_str());
  return kExitOk;
}

int RunMove(const WeldRobotOptions& o) {
  if (o.joints.size() != wr::kJointCount) {
    throw common::ConfigError(
        "--joints: need 5 values θ1,θ2,pz3,θ4,θ5 (deg, deg, mm, deg, deg), got " +
        std::to_string(o.joints.size()));
  }
  hal::WeldTrajectoryPoint p;
  for (int j = 0; j < wr::kJointCount; ++j) {
    const double v = o.joints[static_cast<size_t>(j)];
    p.joints[static_cast<size_t>(j)] = wr::IsPrismatic(j) ? v * 1e-3 : v * common::kDeg;
  }
  p.duration = o.duration_s;
  p.arc_on = o.arc;
  auto client = Connect(o.backend, true);
  return Stream(*client, {p}, o);
}

// The trajectory CSV of docs/weld-robot-modbus.md.
std::vector<hal::WeldTrajectoryPoint> ReadTrajectoryCsv(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw common::ConfigError("trajectory \"" + path + "\": cannot be read");
  // Column name -> (joint index or -1 duration or -2 arc, scale to SI).
  const std::map<std::string, std::pair<int, double>> known = {
      {"duration_s", {-1, 1.0}}, {"duration_ms", {-1, 1e-3}},
      {"arc", {-2, 1.0}},        {"theta1_deg", {0, common::kDeg}},
      {"theta1_rad", {0, 1.0}},  {"theta2_deg", {1, common::kDeg}},
      {"theta2_rad", {1, 1.0}},  {"pz3_mm", {2, 1e-3}},
      {"pz3_m", {2, 1.0}},       {"theta4_deg", {3, common::kDeg}},
      {"theta4_rad", {3, 1.0}},  {"theta5_deg", {4, common::kDeg}},
      {"theta5_rad", {4, 1.0}}};
  std::vector<std::pair<int, double>> columns;
  std::vector<hal::WeldTrajectoryPoint> points;
  std::string line;
  int number = 0;
  auto where = [&] { return "trajectory \"" + path + "\" line " + std::to_string(number); };
  auto split = [](const std::string& text) {
    std::vector<std::string> fields;
    std::stringstream ss(text);
    std::string field;
    while (std::getline(ss, field, ',')) {
      const size_t b = field.find_first_not_of(" \t\r");
      const size_t e = field.find_last_not_of(" \t\r");
      fields.push_back(b == std::string::npos ? "" : field.substr(b, e - b + 1));
    }
    return fields;
  };
  while (std::getline(in, line)) {
    ++number;
    const size_t first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos || line[first] == '#') continue;
    const std::vector<std::string> fields = split(line);
    if (columns.empty()) {
      int seen[wr::kJointCount + 2] = {};  // joints, then duration, arc
      for (const std::string& name : fields) {
        auto it = known.find(name);
        if (it == known.end()) {
          throw common::ConfigError(where() + ": unknown column \"" + name +
                                    "\" (see docs/weld-robot-modbus.md)");
        }
        const int slot =
            it->second.first >= 0 ? it->second.first : wr::kJointCount - it->second.first - 1;
        if (seen[slot]++ > 0)
          throw common::ConfigError(where() + ": column \"" + name + "\" twice");
        columns.push_back(it->second);
      }
      for (int slot = 0; slot < wr::kJointCount + 2; ++slot) {
        if (seen[slot] == 0) {
          throw common::ConfigError(
              where() +
              ": the header needs a duration, arc, and the five joint columns "
              "(duration_s,theta1_deg,theta2_deg,pz3_mm,theta4_deg,theta5_deg,arc)");
        }
      }
      continue;
    }
    if (fields.size() != columns.size()) {
      throw common::ConfigError(where() + ": " + std::to_string(fields.size()) +
                                " fields, the header has " + std::to_string(columns.size()));
    }
    hal::WeldTrajectoryPoint p;
    for (size_t c = 0; c < columns.size(); ++c) {
      double value = 0;
      size_t used = 0;
      try {
        value = std::stod(fields[c], &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used != fields[c].size() || fields[c].empty() || !std::isfinite(value)) {
        throw common::ConfigError(where() + ": field " + std::to_string(c + 1) + " \"" + fields[c] +
                                  "\" is not a number");
      }
      const auto [slot, scale] = columns[c];
      if (slot == -1) {
        p.duration = value * scale;
      } else if (slot == -2) {
        if (value != 0 && value != 1) {
          throw common::ConfigError(where() + ": arc \"" + fields[c] + "\" is not 0 or 1");
        }
        p.arc_on = value == 1;
      } else {
        p.joints[static_cast<size_t>(slot)] = value * scale;
      }
    }
    points.push_back(p);
  }
  if (points.empty()) throw common::ConfigError("trajectory \"" + path + "\": no points");
  return points;
}

int RunStreamFile(const WeldRobotOptions& o) {
  const auto points = ReadTrajectoryCsv(o.file);
  auto client = Connect(o.backend, true);
  return Stream(*client, points, o);
}

int RunStop(const WeldRobotOptions& o) {
  auto client = Connect(o.backend, false);
  if (std::error_code ec = client->Stop()) Throw(*client, "stop", ec);
  std::printf("stopped: motion stopped, buffer cleared, arc off\n");
  return kExitOk;
}

int RunArc(const WeldRobotOptions& o) {
  if (o.arc_state == "off") {
    auto client = Connect(o.backend, false);
    if (std::error_code ec = client->ArcOff()) Throw(*client, "arc off", ec);
    std::printf("arc disabled\n");
    return kExitOk;
  }
  auto client = Connect(o.backend, true);
  if (o.current_a >= 0 || o.voltage_v >= 0 || o.wire_feed_m_min >= 0) {
    hal::WeldRobotState s;
    if (std::error_code ec = client->ReadState(&s)) Throw(*client, "read state", ec);
    hal::WeldParameters w = s.weld;
    if (o.current_a >= 0) w.current = o.current_a;
    if (o.voltage_v >= 0) w.voltage = o.voltage_v;
    if (o.wire_feed_m_min >= 0) w.wire_feed_speed = o.wire_feed_m_min / 60.0;
    if (std::error_code ec = client->SetWeldParameters(w))
      Throw(*client, "set weld parameters", ec);
  }
  if (std::error_code ec = client->ArcOn()) Throw(*client, "arc on", ec);
  std::printf("arc enabled: it burns during segments flagged arc-on\n");
  return kExitOk;
}

int RunReset(const WeldRobotOptions& o) {
  auto client = Connect(o.backend, false);
  if (std::error_code ec = client->AlarmReset()) Throw(*client, "alarm reset", ec);
  std::printf("alarm reset\n");
  return kExitOk;
}

struct SimOptions {
  std::string listen = "127.0.0.1:0";
  bool rtu = false;
  std::string link;
  int buffer = 16;
  int unit = 1;
  std::string robot_file;  // robot description: joint and speed limits
};

int RunSim(const SimOptions& o) {
  hal::WeldRobotSim::Options options;
  options.buffer_capacity = o.buffer;
  options.unit = o.unit;
  if (!o.robot_file.empty()) {
    // The simulated controller enforces the limits of the robot description (the same file the
    // path planner and `kinevis model weld5` read).
    const robots::Weld5Description d = robots::LoadWeld5Description(o.robot_file);
    for (int j = 0; j < robots::kWeld5Joints; ++j) {
      options.joints[j] = {d.model.q_min(j), d.model.q_max(j), d.model.qd_max(j)};
      // Power-on pose: the default where it is within the limits, else the middle of the range.
      double& q0 = options.initial_joints[j];
      if (q0 < d.model.q_min(j) || q0 > d.model.q_max(j))
        q0 = 0.5 * (d.model.q_min(j) + d.model.q_max(j));
    }
  }
  std::unique_ptr<hal::WeldRobotSim> sim;
  if (o.rtu) {
    sim = hal::WeldRobotSim::ServeRtu(options, o.link);
  } else {
    if (!o.link.empty()) throw common::ConfigError("--link: only with --rtu");
    const size_t colon = o.listen.rfind(':');
    std::string host = colon == std::string::npos ? "" : o.listen.substr(0, colon);
    const std::string port_text = colon == std::string::npos ? "" : o.listen.substr(colon + 1);
    if (host.size() >= 2 && host.front() == '[' && host.back() == ']') {
      host = host.substr(1, host.size() - 2);
    }
    int port = -1;
    size_t used = 0;
    try {
      port = std::stoi(port_text, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (host.empty() || used == 0 || used != port_text.size() || port < 0 || port > 65535) {
      throw common::ConfigError("--listen \"" + o.listen +
                                "\": need HOST:PORT with PORT in 0..65535 (0: any free port)");
    }
    sim = hal::WeldRobotSim::ListenTcp(host, port, options);
  }
  return ServeUntilStopped(sim->backend());
}

}  // namespace

void AddWeldRobotCommands(const Parents& parents, CommandList* commands) {
  CLI::App& app = *parents.app;
  CLI::App& sim = *parents.sim;
  auto o = std::make_shared<WeldRobotOptions>();
  CLI::App* robot = app.add_subcommand(
      "weld-robot", "Bring-up of the Modbus weld robot: state, moves, trajectory streams, arc");
  robot
      ->add_option("backend", o->backend,
                   "Modbus backend: modbus-tcp:HOST:PORT or modbus-rtu:DEVICE[@BAUD] "
                   "(docs/backends.md)")
      ->required();
  robot->require_subcommand(1);
  robot->footer("Register map, CSV format and alarms: docs/weld-robot-modbus.md.");

  CLI::App* status = robot->add_subcommand("status", "Print the robot's identity and state");
  commands->push_back({status, [o] { return RunStatus(*o); }});

  CLI::App* move =
      robot->add_subcommand("move", "Move to joint targets in one segment and wait until there");
  move->add_option("--joints", o->joints, "θ1,θ2,pz3,θ4,θ5 in deg, deg, mm, deg, deg")
      ->delimiter(',')
      ->required();
  move->add_option("--duration", o->duration_s, "Segment duration, s")
      ->required()
      ->check(CLI::PositiveNumber);
  move->add_flag("--arc", o->arc, "Flag the segment arc-on (burns only with `arc on` first)");
  move->add_flag("--no-check", o->no_check,
                 "Send without checking the limits first (the robot raises an alarm instead)");
  commands->push_back({move, [o] { return RunMove(*o); }});

  CLI::App* stream = robot->add_subcommand(
      "stream", "Stream a joint trajectory from a CSV file with flow control; Ctrl-C stops");
  stream->add_option("file", o->file, "Trajectory CSV (docs/weld-robot-modbus.md)")->required();
  stream
      ->add_option("--timeout", o->timeout_s,
                   "Bound on the whole stream, s (default: its duration + 5 s)")
      ->check(CLI::PositiveNumber);
  stream->add_flag("--no-check", o->no_check,
                   "Send without checking the limits first (the robot raises an alarm instead)");
  commands->push_back({stream, [o] { return RunStreamFile(*o); }});

  CLI::App* stop =
      robot->add_subcommand("stop", "Safe state: stop motion, clear the buffer, arc off");
  commands->push_back({stop, [o] { return RunStop(*o); }});

  CLI::App* arc = robot->add_subcommand("arc", "Arc enable (on) or disable (off)");
  arc->add_option("state", o->arc_state, "on or off")
      ->required()
      ->check(CLI::IsMember({"on", "off"}));
  arc->add_option("--current", o->current_a, "Welding current set-point, A (on only)")
      ->check(CLI::NonNegativeNumber);
  arc->add_option("--voltage", o->voltage_v, "Arc voltage set-point, V (on only)")
      ->check(CLI::NonNegativeNumber);
  arc->add_option("--wire-feed", o->wire_feed_m_min, "Wire feed speed set-point, m/min (on only)")
      ->check(CLI::NonNegativeNumber);
  commands->push_back({arc, [o] { return RunArc(*o); }});

  CLI::App* reset = robot->add_subcommand("reset", "Clear the robot's alarm");
  commands->push_back({reset, [o] { return RunReset(*o); }});

  auto s = std::make_shared<SimOptions>();
  CLI::App* sim_robot = sim.add_subcommand(
      "weld-robot", "Simulated weld robot controller: Modbus TCP on loopback, or RTU on a pty");
  sim_robot->add_option("--listen", s->listen, "TCP HOST:PORT (port 0: any free port)")
      ->capture_default_str();
  sim_robot->add_flag("--rtu", s->rtu, "Serve Modbus RTU on a new pseudo-terminal instead");
  sim_robot->add_option("--link", s->link, "With --rtu: create this symbolic link to the pty");
  sim_robot->add_option("--buffer", s->buffer, "Trajectory buffer capacity, segments")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000));
  sim_robot->add_option("--unit", s->unit, "Modbus unit id")
      ->capture_default_str()
      ->check(CLI::Range(1, 247));
  sim_robot
      ->add_option("--robot", s->robot_file,
                   "Robot description YAML whose joint and speed limits the controller enforces "
                   "(docs/robot-description.md; default: the same values as "
                   "robots/weld5/weld5.yaml)")
      ->check(CLI::ExistingFile);
  sim_robot->footer(
      "Prints the backend string as its first line, then serves until SIGINT/SIGTERM.");
  commands->push_back({sim_robot, [s] { return RunSim(*s); }});
}

}  // namespace kinevis::cli
