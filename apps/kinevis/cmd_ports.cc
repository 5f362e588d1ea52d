// kinevis ports: the serial ports of this machine, with USB identity, so an engineer can tell
// which /dev/ttyUSBn is the RS485 adapter and which the Dynamixel bus.

#include <cstdio>
#include <iostream>
#include <nlohmann/json.hpp>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "hal/serial/port_discovery.h"

namespace kinevis::cli {
namespace {

std::string VidPid(const hal::SerialPortInfo& p) {
  if (p.usb_vid < 0) return "-";
  char buf[16];
  std::snprintf(buf, sizeof buf, "%04x:%04x", p.usb_vid & 0xFFFF, p.usb_pid & 0xFFFF);
  return buf;
}

std::string OrDash(const std::string& s) { return s.empty() ? "-" : s; }

int RunPorts(bool json) {
  const std::vector<hal::SerialPortInfo> ports = hal::ListSerialPorts();
  if (json) {
    nlohmann::json out = nlohmann::json::array();
    for (const auto& p : ports) {
      out.push_back({{"path", p.path},
                     {"transport", p.transport},
                     {"description", p.description},
                     {"usb_vid_pid", p.usb_vid < 0 ? "" : VidPid(p)},
                     {"manufacturer", p.manufacturer},
                     {"product", p.product},
                     {"serial_number", p.serial_number}});
    }
    std::cout << out.dump(2) << "\n";
    return kExitOk;
  }
  if (ports.empty()) {
    std::cout << "no serial ports found (pseudo-terminals of simulators are not listed; their "
                 "path is printed by `kinevis sim ...`)\n";
    return kExitOk;
  }
  std::printf("%-22s %-9s %-9s %-20s %-24s %s\n", "PATH", "TRANSPORT", "VID:PID", "MANUFACTURER",
              "PRODUCT", "SERIAL");
  for (const auto& p : ports) {
    std::printf("%-22s %-9s %-9s %-20s %-24s %s\n", p.path.c_str(), OrDash(p.transport).c_str(),
                VidPid(p).c_str(), OrDash(p.manufacturer).c_str(),
                OrDash(p.product.empty() ? p.description : p.product).c_str(),
                OrDash(p.serial_number).c_str());
  }
  return kExitOk;
}

}  // namespace

void AddPortsCommand(const Parents& parents, CommandList* commands) {
  CLI::App& app = *parents.app;
  auto json = std::make_shared<bool>(false);
  CLI::App* ports = app.add_subcommand(
      "ports", "List serial ports with USB VID:PID, manufacturer and serial number");
  ports->add_flag("--json", *json, "Print a JSON array instead of a table");
  commands->push_back({ports, [json] { return RunPorts(*json); }});
}

}  // namespace kinevis::cli
