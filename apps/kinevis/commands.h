#pragma once

// Each file cmd_*.cc adds its subcommands to the app and registers the body to run when that
// subcommand is the one the user chose. Bodies return an exit code (cli_common.h).
// Simulators register under the shared `sim` subcommand (`kinevis sim dynamixel ...`).

#include <CLI/CLI.hpp>
#include <functional>
#include <vector>

namespace kinevis::cli {

struct Command {
  CLI::App* app;
  std::function<int()> run;
};
using CommandList = std::vector<Command>;

void AddDemoCommand(CLI::App& app, CommandList* commands);
void AddPortsCommand(CLI::App& app, CommandList* commands);
// `kinevis check timing`: how steadily this host paces a fixed-rate loop.
void AddCheckCommands(CLI::App& app, CommandList* commands);
void AddCanCommands(CLI::App& app, CommandList* commands);
// `sim` is the shared `kinevis sim` subcommand; each adds its simulator under it.
void AddServoCommands(CLI::App& app, CLI::App& sim, CommandList* commands);
void AddWeldRobotCommands(CLI::App& app, CLI::App& sim, CommandList* commands);
void AddCameraCommands(CLI::App& app, CommandList* commands);
// `kinevis calibrate ...`: one subcommand per calibration routine (camera, later robots).
void AddCalibrateCommands(CLI::App& app, CommandList* commands);
// `kinevis sim world hexapod|diamond ...`: a simulated world as its own process.
void AddSimWorldCommands(CLI::App& sim, CommandList* commands);
// Called by AddSimWorldCommands: `kinevis sim world weld-cell` and `kinevis sim world soccer`.
void AddCellWorldCommands(CLI::App& world, CommandList* commands);
// `kinevis model hexapod|diamond|weld5 fk|ik ...` and `kinevis project MODEL ...`.
void AddModelCommands(CLI::App& app, CommandList* commands);
// `kinevis record hexapod`, `kinevis calibrate hexapod`, `kinevis servo hexapod`: `calibrate` and
// `servo` are the existing subcommands (AddCalibrateCommands, AddServoCommands run first).
void AddHexapodCommands(CLI::App& app, CLI::App& calibrate, CLI::App& servo, CommandList* commands);
// `kinevis record scanner`, `kinevis calibrate scanner` (issue 7): after AddHexapodCommands (which
// creates `record`).
void AddWeldCommands(CLI::App& app, CLI::App& calibrate, CommandList* commands);
// `kinevis record scanner-mount`, `kinevis calibrate scanner-mount` (issue 7): after
// AddWeldCommands (`record` is found or made).
void AddWeldMountCommands(CLI::App& app, CLI::App& calibrate, CommandList* commands);
// `kinevis scan`, `record scan`, `weld-path`, `weld-run` (issue 7): after AddWeldCommands.
void AddWeldScanCommands(CLI::App& app, CommandList* commands);
// `kinevis record diamond`, `calibrate diamond`, `servo diamond`, `plan-camera diamond` (issue 8):
// after AddWeldCommands (`record` is found or made; `plan-camera` too).
void AddDiamondCommands(CLI::App& app, CLI::App& calibrate, CLI::App& servo, CommandList* commands);
void AddDriveCommands(CLI::App& app, CLI::App& sim, CommandList* commands);
// Called by AddDriveCommands: `kinevis sim drive` and `kinevis sim rs485-drive`.
void AddDriveSimCommands(CLI::App& sim, CommandList* commands);

}  // namespace kinevis::cli
