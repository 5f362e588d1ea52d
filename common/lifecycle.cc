#include "common/lifecycle.h"

namespace kinevis::common {

const char* ToString(DeviceLifecycle lifecycle) {
  switch (lifecycle) {
    case DeviceLifecycle::kUnconfigured:
      return "unconfigured";
    case DeviceLifecycle::kConfigured:
      return "configured";
    case DeviceLifecycle::kActive:
      return "active";
    case DeviceLifecycle::kFault:
      return "fault";
  }
  return "?";
}

}  // namespace kinevis::common
