// kinevis sim world hexapod|diamond: a simulated world (sim/) as its own process, reachable by a
// second process through the transports real hardware uses (docs/simulation.md):
//  - hexapod: six CiA 402 drives on a virtual CAN bus behind a simulated slcan USB-CAN adapter on
//    a pseudo-terminal; first line "slcan:/dev/pts/N@115200,bitrate=1000000".
//  - diamond: two RS485 drives (Modbus RTU, units 1 and 2) on a pseudo-terminal; first line
//    "modbus-rtu:/dev/pts/N@3000000,8E1".
// Then one line per camera: "net:127.0.0.1:PORT NAME", a frame server (hal/camera/frame_server.h)
// rendering the world's camera NAME, so a second process grabs it as camera source
// "net:127.0.0.1:PORT". The world runs in real time (SteadyClock) until SIGINT/SIGTERM.

#include <spdlog/spdlog.h>

#include <cstdio>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "hal/camera/camera_factory.h"
#include "hal/camera/frame_server.h"
#include "hal/common/error.h"
#include "sim/diamond_world.h"
#include "sim/hexapod_world.h"
#include "vision/render/scenes/diamond_marker_scene.h"
#include "vision/render/scenes/hexapod_scene.h"

namespace kinevis::cli {
namespace {

struct WorldOptions {
  std::string config;
  std::string link;
};

// The world's render sources ("sim:NAME", in this process) served to other processes: one
// frame server per camera. Keeps the cameras and servers alive for the life of the command.
struct CameraServers {
  std::vector<std::unique_ptr<hal::Camera>> cameras;
  std::vector<std::unique_ptr<hal::FrameServer>> servers;
  std::vector<std::string> lines;  // "net:127.0.0.1:PORT NAME"

  void Serve(const std::vector<std::string>& names) {
    for (const std::string& name : names) {
      auto camera = hal::OpenCamera("sim:" + name);
      camera->Open();
      if (const std::error_code ec = camera->Start()) {
        throw hal::HalError("sim:" + name, "start", ec.message());
      }
      servers.push_back(hal::FrameServer::Listen(
          hal::CameraFrameSource(*camera, std::chrono::milliseconds(2000))));
      lines.push_back(servers.back()->backend() + " " + name);
      cameras.push_back(std::move(camera));
    }
  }
};

// Prints the camera lines (after the backend line) once; the world runs on its own threads.
std::function<bool()> PrintOnce(std::vector<std::string> lines) {
  auto printed = std::make_shared<bool>(false);
  return [lines = std::move(lines), printed] {
    if (!*printed) {
      for (const std::string& l : lines) std::printf("%s\n", l.c_str());
      std::fflush(stdout);
      *printed = true;
    }
    return true;
  };
}

int RunHexapod(const WorldOptions& o) {
  sim::HexapodWorldConfig config;
  if (!o.config.empty()) {
    config = sim::LoadHexapodWorldConfig(o.config);
  } else {
    config.cameras = sim::DefaultHexapodCameras();  // those of config/hexapod-sim.yaml
  }
  sim::HexapodWorld world(config, sim::HexapodWorld::Timing::kRealTime);
  const std::string backend = world.ExposeSlcan(o.link);
  const std::vector<std::string> names = world.RegisterCameras(
      [](const robots::HexapodModel& model, const sim::HexapodPlantState& state,
         const Eigen::Isometry3d& X_BC) -> std::unique_ptr<vision::render::Scene> {
        return std::make_unique<vision::render::HexapodScene>(model, state.X_BP, X_BC.inverse());
      });
  world.Start();
  CameraServers servers;
  servers.Serve(names);
  const sim::HexapodPlantState s = world.plant();
  spdlog::info(
      "hexapod world: 6 CiA 402 drives (nodes {},{},{},{},{},{}) at {}; true platform at "
      "[{:.4f}, {:.4f}, {:.4f}] m; truth from seed {}",
      config.nodes[0], config.nodes[1], config.nodes[2], config.nodes[3], config.nodes[4],
      config.nodes[5], backend, s.X_BP.translation().x(), s.X_BP.translation().y(),
      s.X_BP.translation().z(), config.seed);
  return ServeUntilStopped(backend, PrintOnce(servers.lines));
}

int RunDiamond(const WorldOptions& o) {
  sim::DiamondWorldConfig config;
  if (!o.config.empty()) config = sim::LoadDiamondWorldConfig(o.config);
  sim::DiamondWorld world(config, sim::DiamondWorld::Timing::kRealTime, o.link);
  const std::vector<std::string> names = world.RegisterCameras(
      [](const robots::DiamondModel&, const sim::DiamondPlantState& state,
         const Eigen::Isometry3d& X_OC) -> std::unique_ptr<vision::render::Scene> {
        vision::render::DiamondMarkerSceneParameters p;
        p.X_CO = X_OC.inverse();
        p.p_O_T = state.p_O_T;
        return std::make_unique<vision::render::DiamondMarkerScene>(p);
      });
  world.Start();
  CameraServers servers;
  servers.Serve(names);
  const sim::DiamondPlantState s = world.plant();
  spdlog::info(
      "diamond world: 2 RS485 drives (units {},{}) at {}; true tool point [{:.4f}, {:.4f}, "
      "{:.4f}] m",
      config.units[0], config.units[1], world.backend(), s.p_O_T.x(), s.p_O_T.y(), s.p_O_T.z());
  return ServeUntilStopped(world.backend(), PrintOnce(servers.lines));
}

}  // namespace

void AddSimWorldCommands(const Parents& parents, CommandList* commands) {
  CLI::App& sim = *parents.sim;
  CLI::App* world = sim.add_subcommand(
      "world", "A simulated world (robot, drives, cameras) reachable as real hardware");
  world->require_subcommand(1);

  auto hex = std::make_shared<WorldOptions>();
  CLI::App* h = world->add_subcommand(
      "hexapod", "Gough-Stewart platform: six CiA 402 drives behind a simulated slcan adapter");
  h->add_option("--config", hex->config,
                "World config (config/hexapod-sim.yaml); default: built-in defaults with "
                "that file's two cameras")
      ->check(CLI::ExistingFile);
  h->add_option("--link", hex->link, "Also reach the adapter's pty through this symbolic link");
  h->footer(
      "Prints the slcan backend string first, then one "
      "\"net:HOST:PORT NAME\" line per camera; runs "
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
      "\"net:HOST:PORT NAME\" line per camera; runs until SIGINT/SIGTERM. See docs/simulation.md.");
  commands->push_back({d, [dia] { return RunDiamond(*dia); }});

  AddCellWorldCommands(*world, commands);
}

}  // namespace kinevis::cli
