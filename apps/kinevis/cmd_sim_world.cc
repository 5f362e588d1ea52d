// kinevis sim world ...: simulated worlds as their own process.

#include "apps/kinevis/commands.h"

namespace kinevis::cli {

void AddSimWorldCommands(CLI::App& sim, CommandList* commands) {
  (void)sim;
  (void)commands;
}

}  // namespace kinevis::cli
