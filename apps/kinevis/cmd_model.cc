// kinevis model ... and kinevis project ...: sanity checks of robot and camera models.

#include "apps/kinevis/commands.h"

namespace kinevis::cli {

void AddModelCommands(CLI::App& app, CommandList* commands) {
  (void)app;
  (void)commands;
}

}  // namespace kinevis::cli
