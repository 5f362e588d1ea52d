#include "rigs/rig_camera.h"

#include <stdexcept>
#include <system_error>

#include "hal/camera/camera_factory.h"
#include "hal/common/error.h"

namespace kinevis::rigs {

std::unique_ptr<hal::Camera> OpenRigCamera(const std::string& source, common::Clock& clock,
                                           int model_width, int model_height,
                                           const std::string& what, const std::string& model_spec) {
  std::unique_ptr<hal::Camera> camera = hal::OpenCamera(source, clock);
  camera->Open();
  if (const std::error_code ec = camera->Start()) {
    throw hal::HalError(source, "start", ec.message(), ec);
  }
  const hal::CameraFormat f = camera->format();
  if (f.width != model_width || f.height != model_height) {
    throw std::invalid_argument(what + ": frames are " + std::to_string(f.width) + "x" +
                                std::to_string(f.height) + " but the model " + model_spec +
                                " is for " + std::to_string(model_width) + "x" +
                                std::to_string(model_height));
  }
  return camera;
}

}  // namespace kinevis::rigs
