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

// The parent subcommands that several files add under, made once by main before any file adds
// its commands (so the order of the table in main.cc does not matter): `sim` (simulators as their
// own process), `calibrate`, `servo` (Dynamixel servos, and the robots' visual servos), `record`
// (calibration datasets) and `plan-camera`.
struct Parents {
  CLI::App* app = nullptr;
  CLI::App* sim = nullptr;
  CLI::App* calibrate = nullptr;
  CLI::App* servo = nullptr;
  CLI::App* record = nullptr;
  CLI::App* plan_camera = nullptr;
};

// One per cmd_*.cc: adds that file's subcommands (main.cc's kCommandFiles lists them all).
using AddCommands = void (*)(const Parents& parents, CommandList* commands);
void AddDemoCommand(const Parents& parents, CommandList* commands);
void AddPortsCommand(const Parents& parents, CommandList* commands);
// `kinevis check timing`: how steadily this host paces a fixed-rate loop.
void AddCheckCommands(const Parents& parents, CommandList* commands);
void AddCanCommands(const Parents& parents, CommandList* commands);
// Dynamixel servos (`servo BACKEND ...`) and `sim dynamixel`.
void AddServoCommands(const Parents& parents, CommandList* commands);
void AddWeldRobotCommands(const Parents& parents, CommandList* commands);
void AddCameraCommands(const Parents& parents, CommandList* commands);
// `kinevis calibrate camera`.
void AddCalibrateCommands(const Parents& parents, CommandList* commands);
// `kinevis sim world hexapod|diamond ...`: a simulated world as its own process.
void AddSimWorldCommands(const Parents& parents, CommandList* commands);
// Called by AddSimWorldCommands: `kinevis sim world weld-cell` and `kinevis sim world soccer`.
void AddCellWorldCommands(CLI::App& world, CommandList* commands);
// `kinevis model hexapod|diamond|weld5 fk|ik ...` and `kinevis project MODEL ...`.
void AddModelCommands(const Parents& parents, CommandList* commands);
// `kinevis record|calibrate|servo hexapod`.
void AddHexapodCommands(const Parents& parents, CommandList* commands);
// `kinevis record scanner`, `kinevis calibrate scanner` (issue 7).
void AddWeldCommands(const Parents& parents, CommandList* commands);
// `kinevis record scanner-mount`, `kinevis calibrate scanner-mount` (issue 7).
void AddWeldMountCommands(const Parents& parents, CommandList* commands);
// `kinevis scan`, `record scan`, `weld-path`, `weld-run` (issue 7).
void AddWeldScanCommands(const Parents& parents, CommandList* commands);
// `kinevis record|calibrate|servo|plan-camera diamond` (issue 8).
void AddDiamondCommands(const Parents& parents, CommandList* commands);
void AddDriveCommands(const Parents& parents, CommandList* commands);
// Called by AddDriveCommands: `kinevis sim drive` and `kinevis sim rs485-drive`.
void AddDriveSimCommands(CLI::App& sim, CommandList* commands);

}  // namespace kinevis::cli
