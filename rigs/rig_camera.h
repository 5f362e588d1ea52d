#pragma once

// The camera of a rig: opened from its source string (docs/cameras.md), started, and checked to
// deliver frames of the size its camera model was made for.

#include <memory>
#include <string>

#include "hal/camera/camera.h"

namespace kinevis::common {
class Clock;
}  // namespace kinevis::common

namespace kinevis::rigs {

// Opens `source` on `clock` and starts it. Throws hal::HalError when it cannot be started, and
// std::invalid_argument "<what>: frames are WxH but the model <model_spec> is for wxh".
std::unique_ptr<hal::Camera> OpenRigCamera(const std::string& source, common::Clock& clock,
                                           int model_width, int model_height,
                                           const std::string& what, const std::string& model_spec);

}  // namespace kinevis::rigs
