#pragma once

// The lifecycle of every device (STYLE.md; ros2_control's hardware components are the model):
//
//   unconfigured -> configured (state readable) -> active (commands accepted) -> fault
//
// Commands are refused unless the device is active. Motor drives, servos, cameras and the weld
// robot report their state with this one enum; each device's header names the calls that move it
// (e.g. a drive's Configure() and Enable(), a camera's Start()) and how it leaves a fault.

namespace kinevis::common {

enum class DeviceLifecycle { kUnconfigured, kConfigured, kActive, kFault };

// "unconfigured", "configured", "active", "fault".
const char* ToString(DeviceLifecycle lifecycle);

}  // namespace kinevis::common
