#pragma once

// Each file cmd_*.cc adds its subcommands to the app and registers the body to run when that
// subcommand is the one the user chose. Bodies return an exit code (cli_common.h).

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
void AddCanCommands(CLI::App& app, CommandList* commands);

}  // namespace kinevis::cli
