// kinevis sim world weld-cell|soccer: the weld cell and the soccer robot (sim/weld_cell_world.h,
// sim/soccer_world.h) as their own process, reachable by a second process through the transports
// real hardware uses (docs/simulation.md):
//  - weld-cell: the weld-robot controller over Modbus (TCP on loopback by default, or RTU on a
//    pty); first line its backend ("modbus-tcp:127.0.0.1:40123"), second line the scanner
//    camera's frames and its name, as cmd_sim_world.cc prints cameras
//    ("net:127.0.0.1:40124,timeout_ms=10000 weld-scanner": kinevis' frame transport,
//    hal/camera/frame_server.h; frames are rendered on request, hence the long timeout).
//  - soccer: one line, the omnidirectional camera
//    ("net:127.0.0.1:40125,timeout_ms=10000 soccer-omni").
// Both run in real time (SteadyClock) until SIGINT/SIGTERM.

#include <spdlog/spdlog.h>

#include <cstdio>
#include <memory>
#include <string>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "hal/camera/frame_server.h"
#include "sim/soccer_world.h"
#include "sim/weld_cell_world.h"

namespace kinevis::cli {
namespace {

struct CellOptions {
  std::string config;
  std::string camera_host = "127.0.0.1";
  int camera_port = 0;
};

// A frame is rendered on request (≈ 1–2 s for the scanner's 1616 × 1216 blade image on one core),
// so the printed source asks the client for a generous timeout (net_camera.h).
constexpr const char* kCameraTimeout = ",timeout_ms=10000";

hal::FrameServerOptions FrameOptions(const CellOptions& o) {
  hal::FrameServerOptions f;
  f.host = o.camera_host;
  f.port = o.camera_port;
  return f;
}

int RunWeldCell(const CellOptions& o) {
  sim::WeldCellWorldConfig config;
  if (!o.config.empty()) config = sim::LoadWeldCellWorldConfig(o.config);
  sim::WeldCellWorld world(config, sim::WeldCellWorld::Timing::kRealTime);
  const std::string camera = world.ServeCamera(FrameOptions(o)) + kCameraTimeout;
  const Eigen::Vector3d p_0C = world.TrueScannerPose(world.joints()).translation();
  spdlog::info(
      "weld-cell world: robot controller at {}, scanner camera at {}; true scanner at [{:.4f}, "
      "{:.4f}, {:.4f}] m; truth from seed {}",
      world.backend(), camera, p_0C.x(), p_0C.y(), p_0C.z(), config.seed);
  bool printed = false;
  return ServeUntilStopped(world.backend(), [&] {
    if (!printed) {
      std::printf("%s %s\n", camera.c_str(), config.camera_name.c_str());
      std::fflush(stdout);
      printed = true;
    }
    return true;
  });
}

int RunSoccer(const CellOptions& o) {
  sim::SoccerWorldConfig config;
  if (!o.config.empty()) config = sim::LoadSoccerWorldConfig(o.config);
  sim::SoccerRobotWorld world(config, sim::SoccerRobotWorld::Timing::kRealTime);
  const std::string camera = world.ServeCamera(FrameOptions(o)) + kCameraTimeout;
  spdlog::info("soccer world: robot at ({:.3f}, {:.3f}) m, heading {:.2f} rad; camera at {}",
               config.field.robot_x, config.field.robot_y, config.field.robot_heading, camera);
  return ServeUntilStopped(camera + " " + config.camera_name);
}

void AddCameraOptions(CLI::App* app, CellOptions* o) {
  app->add_option("--camera-host", o->camera_host,
                  "Address the camera frames are served on (0.0.0.0: every interface)")
      ->capture_default_str();
  app->add_option("--camera-port", o->camera_port, "TCP port of the camera frames (0: any free)")
      ->capture_default_str()
      ->check(CLI::Range(0, 65535));
}

}  // namespace

void AddCellWorldCommands(CLI::App& world, CommandList* commands) {
  auto weld = std::make_shared<CellOptions>();
  CLI::App* w = world.add_subcommand(
      "weld-cell",
      "Weld-repair cell: the weld robot's Modbus controller and the laser scanner's camera");
  w->add_option("--config", weld->config,
                "World config (config/weld-cell-sim.yaml); default: built-in defaults")
      ->check(CLI::ExistingFile);
  AddCameraOptions(w, weld.get());
  w->footer(
      "Prints the Modbus backend first (for `kinevis weld-robot BACKEND ...`), then the "
      "scanner camera's \"net:HOST:PORT,timeout_ms=10000 NAME\" line (the source for `kinevis "
      "camera "
      "grab` is the part before the space); runs until "
      "SIGINT/SIGTERM. docs/simulation.md describes the world and its config.");
  commands->push_back({w, [weld] { return RunWeldCell(*weld); }});

  auto soccer = std::make_shared<CellOptions>();
  CLI::App* s = world.add_subcommand(
      "soccer", "RoboCup soccer robot: its catadioptric camera (true misalignments) on the field");
  s->add_option("--config", soccer->config,
                "World config (config/soccer-sim.yaml); default: built-in defaults")
      ->check(CLI::ExistingFile);
  AddCameraOptions(s, soccer.get());
  s->footer(
      "Prints the camera's \"net:HOST:PORT,timeout_ms=10000 NAME\" line; runs until "
      "SIGINT/SIGTERM. "
      "docs/simulation.md describes the world and its config.");
  commands->push_back({s, [soccer] { return RunSoccer(*soccer); }});
}

}  // namespace kinevis::cli
