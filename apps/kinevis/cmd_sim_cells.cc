// kinevis sim world weld-cell|soccer ...: the weld cell and the soccer robot as their own process.

#include "apps/kinevis/commands.h"

namespace kinevis::cli {

// Called by AddSimWorldCommands with the `kinevis sim world` subcommand.
void AddCellWorldCommands(CLI::App& world, CommandList* commands) {
  (void)world;
  (void)commands;
}

}  // namespace kinevis::cli
