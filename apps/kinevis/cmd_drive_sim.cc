// kinevis sim drive | sim rs485-drive: the motor-drive simulators as processes of their own.
//  - `sim drive`: CiA 402 drives (CanopenDriveSim) on a CAN bus that the host reaches through a
//    simulated slcan USB-CAN adapter on a pseudo-terminal (or on a SocketCAN interface).
//  - `sim rs485-drive`: RS485/Modbus RTU drives (Rs485DriveSim) on a pseudo-terminal.
// Each prints the backend string that reaches it as its first line and runs until SIGINT/SIGTERM.

#include <spdlog/spdlog.h>

#include <memory>
#include <set>
#include <string>
#include <vector>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "common/clock.h"
#include "hal/can/can_bus_factory.h"
#include "hal/can/virtual_can_bus.h"
#include "hal/canopen/canopen_codec.h"
#include "hal/common/backend_spec.h"
#include "hal/common/error.h"
#include "hal/mock/canopen_drive_sim.h"
#include "hal/mock/rs485_drive_sim.h"
#include "hal/mock/slcan_adapter_sim.h"
#include "hal/serial/pty_pair.h"

namespace kinevis::cli {
namespace {

// The serial rate of the simulated adapter's line; a pty carries any, the host must name one.
constexpr int kSlcanSerialBaud = 115200;

struct CanDriveOptions {
  std::vector<int> nodes{1};
  std::string transport = "slcan-pty";
  std::string link;
  int bitrate = 1'000'000;
};

struct Rs485DriveOptions {
  std::vector<int> ids{1};
  std::string link;
  int baud = 3'000'000;
};

// Every id in [min, max] and none twice; throws ConfigError naming each bad one.
void CheckIds(const std::vector<int>& ids, int min, int max, const std::string& option) {
  std::string problems;
  std::set<int> seen;
  for (int id : ids) {
    if (id < min || id > max) {
      problems += " " + std::to_string(id) + " is outside " + std::to_string(min) + ".." +
                  std::to_string(max) + ";";
    } else if (!seen.insert(id).second) {
      problems += " " + std::to_string(id) + " appears twice;";
    }
  }
  if (ids.empty()) problems += " no ids given;";
  if (!problems.empty()) {
    problems.pop_back();
    throw common::ConfigError(option + ":" + problems);
  }
}

int RunCanDrives(const CanDriveOptions& o) {
  CheckIds(o.nodes, 1, hal::canopen::kMaxNodeId, "--nodes");
  const bool slcan = o.transport == "slcan-pty";
  if (!slcan && o.transport.rfind("socketcan:", 0) != 0) {
    throw common::ConfigError("--transport \"" + o.transport +
                              "\": expected slcan-pty or socketcan:IFACE");
  }
  if (slcan && hal::SlcanBitrateCode(o.bitrate) < 0) {
    throw common::ConfigError(
        "--bitrate " + std::to_string(o.bitrate) +
        ": an slcan adapter knows 10000, 20000, 50000, 100000, 125000, 250000, "
        "500000, 800000 and 1000000 bit/s");
  }
  if (!slcan && !o.link.empty()) {
    throw common::ConfigError("--link applies to --transport slcan-pty only");
  }
  common::Clock& clock = common::SteadyClock::Instance();

  // Declaration order is destruction order reversed: the simulators stop before their buses go,
  // the adapter before the pty it serves.
  std::shared_ptr<hal::VirtualCanNetwork> network;
  std::unique_ptr<hal::PtyPair> pty;
  std::unique_ptr<hal::CanBus> adapter_bus;
  std::unique_ptr<hal::SlcanAdapterSim> adapter;
  std::vector<std::unique_ptr<hal::CanBus>> buses;
  std::vector<std::unique_ptr<hal::CanopenDriveSim>> drives;
  std::string backend;

  if (slcan) {
    hal::VirtualCanNetwork::Options net;
    net.bitrate = o.bitrate;
    network = std::make_shared<hal::VirtualCanNetwork>("sim-drive", net);
  }
  for (int node : o.nodes) {
    if (slcan) {
      buses.push_back(network->Connect("drive node " + std::to_string(node)));
    } else {
      buses.push_back(hal::OpenCanBus(o.transport));  // one socket per drive, as real nodes
    }
    hal::CanopenDriveSim::Options options;
    options.node = static_cast<uint8_t>(node);
    options.serial_number = static_cast<uint32_t>(node);
    drives.push_back(std::make_unique<hal::CanopenDriveSim>(buses.back().get(), &clock, options));
  }
  if (slcan) {
    pty = std::make_unique<hal::PtyPair>();
    adapter_bus = network->Connect("slcan adapter");
    adapter = std::make_unique<hal::SlcanAdapterSim>(
        pty->MasterPort(kSlcanSerialBaud), adapter_bus.get(), hal::SlcanAdapterSim::Options{});
    std::string path = pty->slave_path();
    if (!o.link.empty()) {
      pty->CreateLink(o.link);
      path = o.link;
    }
    backend = "slcan:" + path + "@" + std::to_string(kSlcanSerialBaud) +
              ",bitrate=" + std::to_string(o.bitrate);
    adapter->Start();
  } else {
    backend = o.transport;
  }
  for (auto& drive : drives) drive->Start();
  spdlog::info("{}: {} simulated CiA 402 drive(s), nodes {}", backend, drives.size(), [&] {
    std::string s;
    for (int n : o.nodes) s += (s.empty() ? "" : ",") + std::to_string(n);
    return s;
  }());
  return ServeUntilStopped(backend);
}

int RunRs485Drives(const Rs485DriveOptions& o) {
  CheckIds(o.ids, 1, 247, "--ids");
  if (o.baud <= 0) throw common::ConfigError("--baud " + std::to_string(o.baud) + " must be > 0");
  hal::PtyPair pty;
  std::string path = pty.slave_path();
  if (!o.link.empty()) {
    pty.CreateLink(o.link);
    path = o.link;
  }
  hal::Rs485DriveSim::Options options;
  options.baud = o.baud;
  options.drives.clear();
  for (int id : o.ids) {
    hal::Rs485DriveSim::DriveOptions d;
    d.unit = id;
    d.serial_number = static_cast<uint32_t>(id);
    options.drives.push_back(d);
  }
  hal::Rs485DriveSim sim(pty.master_fd(), path, &common::SteadyClock::Instance(), options);
  sim.Start();
  spdlog::info("{}: {} simulated RS485 drive(s)", sim.backend(), o.ids.size());
  return ServeUntilStopped(sim.backend());
}

}  // namespace

void AddDriveSimCommands(CLI::App& sim, CommandList* commands) {
  auto can = std::make_shared<CanDriveOptions>();
  CLI::App* drive = sim.add_subcommand(
      "drive", "Simulated CiA 402 servo drives (CANopen) behind an slcan USB-CAN adapter");
  drive->add_option("--nodes", can->nodes, "CANopen node ids, 1..127, comma-separated")
      ->delimiter(',')
      ->capture_default_str();
  drive
      ->add_option("--transport", can->transport,
                   "slcan-pty: a simulated slcan adapter on a pseudo-terminal; "
                   "socketcan:IFACE: the drives on a SocketCAN interface (e.g. vcan0)")
      ->capture_default_str();
  drive->add_option("--link", can->link,
                    "Also reach the adapter's pty through this symbolic link (slcan-pty)");
  drive->add_option("--bitrate", can->bitrate, "CAN bit rate of the simulated bus, bit/s")
      ->capture_default_str();
  drive->footer(
      "Prints the backend string (slcan:/dev/pts/N@115200,bitrate=N) first; see "
      "docs/canopen-drive-sim.md for the object dictionary and defaults.");
  commands->push_back({drive, [can] { return RunCanDrives(*can); }});

  auto rs485 = std::make_shared<Rs485DriveOptions>();
  CLI::App* rs = sim.add_subcommand(
      "rs485-drive", "Simulated RS485 motor drives (Modbus RTU, multi-drop) on a pseudo-terminal");
  rs->add_option("--ids", rs485->ids, "Modbus unit ids, 1..247, comma-separated")
      ->delimiter(',')
      ->capture_default_str();
  rs->add_option("--link", rs485->link, "Also reach the pty through this symbolic link");
  rs->add_option("--baud", rs485->baud, "Baud rate named in the backend string")
      ->capture_default_str();
  rs->footer(
      "Prints the backend string (modbus-rtu:/dev/pts/N@BAUD,8E1) first; add ,unit=N per "
      "drive. The register map is in docs/rs485-drive-registers.md.");
  commands->push_back({rs, [rs485] { return RunRs485Drives(*rs485); }});
}

}  // namespace kinevis::cli
