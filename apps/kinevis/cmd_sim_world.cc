// kinevis sim world hexapod|diamond: a simulated world (sim/) as its own process, reachable by a
// second process through the transports real hardware uses (docs/simulation.md):
//  - hexapod: six CiA 402 drives on a virtual CAN bus behind a simulated slcan USB-CAN adapter on
//    a pseudo-terminal; first line "slcan:/dev/pts/N@115200,bitrate=1000000".
//  - diamond: two RS485 drives (Modbus RTU, units 1 and 2) on a pseudo-terminal; first line
//    "modbus-rtu:/dev/pts/N@3000000,8E1".
// Then one line per camera render source ("sim:hexapod-perspective"), and the world runs in real
// time (SteadyClock) until SIGINT/SIGTERM.

#include <spdlog/spdlog.h>

#include <cstdio>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "sim/diamond_world.h"
#include "sim/hexapod_world.h"

namespace kinevis::cli {
namespace {

struct WorldOptions {
  std::string config;
  std::string link;
};

// Prints the camera sources (after the backend line) once, then logs plant events; the world
// runs on its own threads.
std::function<bool()> PrintOnce(std::vector<std::string> lines) {
  auto printed = std::make_shared<bool>(false);
  return [lines = std::move(lines), printed] {
    if (!*printed) {
      for (const std::string& l : lines) std::printf("sim:%s\n", l.c_str());
      std::fflush(stdout);
      *printed = true;
    }
    return true;
  };
}

int RunHexapod(const WorldOptions& o) {
  sim::HexapodWorldConfig config;
  if (!o.config.empty()) config = sim::LoadHexapodWorldConfig(o.config);
  sim::HexapodWorld world(config, sim::HexapodWorld::Timing::kRealTime);
  const std::string backend = world.ExposeSlcan(o.link);
  // Cameras need the leg scene of vision/render/scenes (sim/README.md); until it is wired in,
  // the world runs without render sources.
  std::vector<std::string> cameras = world.camera_sources();
  world.Start();
  const sim::HexapodPlantState s = world.plant();
  spdlog::info(
      "hexapod world: 6 CiA 402 drives (nodes {},{},{},{},{},{}) at {}; true platform at "
      "[{:.4f}, {:.4f}, {:.4f}] m; truth from seed {}",
      config.nodes[0], config.nodes[1], config.nodes[2], config.nodes[3], config.nodes[4],
      config.nodes[5], backend, s.X_BP.translation().x(), s.X_BP.translation().y(),
      s.X_BP.translation().z(), config.seed);
  return ServeUntilStopped(backend, PrintOnce(cameras));
}

int RunDiamond(const WorldOptions& o) {
  sim::DiamondWorldConfig config;
  if (!o.config.empty()) config = sim::LoadDiamondWorldConfig(o.config);
  sim::DiamondWorld world(config, sim::DiamondWorld::Timing::kRealTime, o.link);
  std::vector<std::string> cameras = world.camera_sources();
  world.Start();
  const sim::DiamondPlantState s = world.plant();
  spdlog::info(
      "diamond world: 2 RS485 drives (units {},{}) at {}; true tool point [{:.4f}, {:.4f}, "
      "{:.4f}] m",
      config.units[0], config.units[1], world.backend(), s.p_O_T.x(), s.p_O_T.y(), s.p_O_T.z());
  return ServeUntilStopped(world.backend(), PrintOnce(cameras));
}

}  // namespace

void AddSimWorldCommands(CLI::App& sim, CommandList* commands) {
  CLI::App* world = sim.add_subcommand(
      "world", "A simulated world (robot, drives, cameras) reachable as real hardware");
  world->require_subcommand(1);

  auto hex = std::make_shared<WorldOptions>();
  CLI::App* h = world->add_subcommand(
      "hexapod", "Gough-Stewart platform: six CiA 402 drives behind a simulated slcan adapter");
  h->add_option("--config", hex->config,
                "World config (config/hexapod-sim.yaml); default: "
                "built-in defaults")
      ->check(CLI::ExistingFile);
  h->add_option("--link", hex->link, "Also reach the adapter's pty through this symbolic link");
  h->footer(
      "Prints the slcan backend string first, then one sim:NAME line per camera; runs "
      "until SIGINT/SIGTERM. docs/simulation.md describes the world and its config.");
  commands->push_back({h, [hex] { return RunHexapod(*hex); }});

  auto dia = std::make_shared<WorldOptions>();
  CLI::App* d = world->add_subcommand(
      "diamond", "DIAMOND eye-surgery robot: two RS485 drives (Modbus RTU) on a pseudo-terminal");
  d->add_option("--config", dia->config,
                "World config (config/diamond-sim.yaml); default: "
                "built-in defaults")
      ->check(CLI::ExistingFile);
  d->add_option("--link", dia->link, "Also reach the pty through this symbolic link");
  d->footer(
      "Prints the modbus-rtu backend string first (add ,unit=1 or 2 per drive), then one "
      "sim:NAME line per camera; runs until SIGINT/SIGTERM. See docs/simulation.md.");
  commands->push_back({d, [dia] { return RunDiamond(*dia); }});

  AddCellWorldCommands(*world, commands);
}

}  // namespace kinevis::cli
