#pragma once

// Opens a CAN bus from a backend string (docs/backends.md):
//   socketcan:IFACE | slcan:DEVICE[@BAUD][,bitrate=N][,listen][,timestamps] |
//   virtual:NAME[,bitrate=N]
// Throws ConfigError for a malformed string (exit code 2 in the CLI) and HalError when the
// device cannot be opened (exit code 3).

#include <memory>
#include <string_view>

#include "hal/can/can_bus.h"

namespace kinevis::hal {

std::unique_ptr<CanBus> OpenCanBus(std::string_view backend);

}  // namespace kinevis::hal
