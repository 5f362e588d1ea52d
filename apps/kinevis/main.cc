// kinevis: the command-line program. Thin by design: it parses, binds backends and calls the
// libraries. Subcommands live in cmd_*.cc; exit codes are documented in docs/cli.md.

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <iostream>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"

int main(int argc, char** argv) {
  using namespace kinevis::cli;
  // Logs go to stderr: stdout carries the data a command produces (frames, backend strings).
  spdlog::set_default_logger(spdlog::stderr_color_mt("kinevis"));
  spdlog::set_pattern("[%H:%M:%S.%e] [%^%l%$] %v");

  CLI::App app{
      "kinevis: host stack for vision-guided robots. Every command runs unchanged against real "
      "hardware or the simulators, chosen by backend strings (docs/backends.md)."};
  app.set_version_flag("--version", "kinevis 0.1.0");
  app.require_subcommand(1);
  std::string log_level = "info";
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error, critical or off")
      ->capture_default_str()
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error", "critical", "off"}));
  app.footer(
      "Exit codes: 0 success, 1 the job failed, 2 usage or configuration error, "
      "3 hardware or communication failure (docs/cli.md).");

  // The shared parents first, then every file's commands: the table's order is only the order
  // of `--help`'s listing.
  Parents parents;
  parents.app = &app;
  parents.sim = app.add_subcommand(
      "sim",
      "Run a device simulator as its own process; it prints the backend string that "
      "reaches it as its first line and runs until SIGINT/SIGTERM");
  parents.calibrate =
      app.add_subcommand("calibrate",
                         "Calibration routines: camera, hexapod, scanner, scanner-mount, diamond "
                         "(docs/camera-calibration.md and the robots' pages)");
  parents.servo = app.add_subcommand(
      "servo",
      "Dynamixel servos on a serial bus (ping, read, move, torque, reboot), and the robots' "
      "visual servoing (hexapod, diamond)");
  parents.record = app.add_subcommand("record", "Record calibration datasets on the robot");
  parents.plan_camera =
      app.add_subcommand("plan-camera", "Plan a camera's placement for a robot's calibration");
  for (CLI::App* parent :
       {parents.sim, parents.calibrate, parents.servo, parents.record, parents.plan_camera}) {
    parent->require_subcommand(1);
  }
  constexpr AddCommands kCommandFiles[] = {
      AddDemoCommand,    AddPortsCommand,      AddCheckCommands,     AddCanCommands,
      AddDriveCommands,  AddServoCommands,     AddWeldRobotCommands, AddSimWorldCommands,
      AddCameraCommands, AddCalibrateCommands, AddModelCommands,     AddHexapodCommands,
      AddWeldCommands,   AddWeldMountCommands, AddWeldScanCommands,  AddDiamondCommands,
  };
  CommandList commands;
  for (const AddCommands add : kCommandFiles) add(parents, &commands);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    int code = app.exit(e);
    return code == 0 ? kExitOk : kExitUsage;
  }
  SetLogLevel(log_level);
  InstallStopHandlers();
  // The deepest parsed subcommand is the one to run.
  const Command* chosen = nullptr;
  for (const Command& c : commands) {
    if (c.app->parsed()) {
      bool deeper = false;
      for (const CLI::App* sub : c.app->get_subcommands()) deeper = deeper || sub->parsed();
      if (!deeper) chosen = &c;
    }
  }
  if (chosen == nullptr) {
    std::cerr << app.help();
    return kExitUsage;
  }
  // "can dump", for messages.
  std::string name = chosen->app->get_name();
  for (const CLI::App* p = chosen->app->get_parent(); p != nullptr && p->get_parent() != nullptr;
       p = p->get_parent()) {
    name = p->get_name() + " " + name;
  }
  return RunGuarded(name, chosen->run);
}
