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

  CommandList commands;
  AddDemoCommand(app, &commands);
  AddPortsCommand(app, &commands);
  AddCheckCommands(app, &commands);
  AddCanCommands(app, &commands);
  CLI::App* sim = app.add_subcommand(
      "sim",
      "Run a device simulator as its own process; it prints the backend string that "
      "reaches it as its first line and runs until SIGINT/SIGTERM");
  sim->require_subcommand(1);
  AddDriveCommands(app, *sim, &commands);
  AddServoCommands(app, *sim, &commands);
  AddWeldRobotCommands(app, *sim, &commands);
  AddSimWorldCommands(*sim, &commands);
  AddCameraCommands(app, &commands);
  AddCalibrateCommands(app, &commands);
  AddModelCommands(app, &commands);
  AddHexapodCommands(app, *app.get_subcommand("calibrate"), *app.get_subcommand("servo"),
                     &commands);
  AddWeldCommands(app, *app.get_subcommand("calibrate"), &commands);
  AddWeldMountCommands(app, *app.get_subcommand("calibrate"), &commands);
  AddWeldScanCommands(app, &commands);
  AddDiamondCommands(app, *app.get_subcommand("calibrate"), *app.get_subcommand("servo"),
                     &commands);

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
