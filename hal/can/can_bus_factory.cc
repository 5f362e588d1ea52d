#include "hal/can/can_bus_factory.h"

#include "hal/can/slcan_bus.h"
#include "hal/can/socketcan_bus.h"
#include "hal/can/virtual_can_bus.h"
#include "hal/common/backend_spec.h"
#include "hal/common/error.h"

namespace kinevis::hal {

std::unique_ptr<CanBus> OpenCanBus(std::string_view backend) {
  const CanBackendSpec spec = ParseCanBackend(backend);
  switch (spec.kind) {
    case CanBackendSpec::Kind::kSocketCan:
      return SocketCanBus::Open(spec.interface, spec.text);
    case CanBackendSpec::Kind::kSlcan:
      return SlcanBus::Open(spec);
    case CanBackendSpec::Kind::kVirtual: {
      VirtualCanNetwork::Options options;
      options.bitrate = spec.bitrate;
      return VirtualCanNetwork::Get(spec.interface, options)->Connect(spec.text);
    }
  }
  throw common::ConfigError("backend \"" + spec.text + "\": unknown CAN backend kind");
}

}  // namespace kinevis::hal
