// kinevis calibrate ...: calibration routines.

#include "apps/kinevis/commands.h"

namespace kinevis::cli {

void AddCalibrateCommands(CLI::App& app, CommandList* commands) {
  (void)app;
  (void)commands;
}

}  // namespace kinevis::cli
