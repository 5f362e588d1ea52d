#include "hal/common/error.h"

#include <cerrno>
#include <cstring>

namespace kinevis::hal {
namespace {

class HalCategoryImpl : public std::error_category {
 public:
  const char* name() const noexcept override { return "kinevis.hal"; }
  std::string message(int value) const override {
    switch (static_cast<Errc>(value)) {
      case Errc::kTimeout:
        return "timed out";
      case Errc::kBusOff:
        return "CAN bus-off";
      case Errc::kClosed:
        return "channel closed";
      case Errc::kIo:
        return "I/O error";
      case Errc::kCrc:
        return "checksum error";
      case Errc::kProtocol:
        return "protocol violation";
      case Errc::kOverflow:
        return "overflow, data lost";
      case Errc::kNotActive:
        return "device not active";
      case Errc::kUnsupported:
        return "not supported by this backend";
      case Errc::kDeviceFault:
        return "device fault";
      case Errc::kInvalidArgument:
        return "invalid argument";
      case Errc::kModbusException:
        return "Modbus exception response";
    }
    return "unknown kinevis.hal error " + std::to_string(value);
  }
};

}  // namespace

const std::error_category& HalCategory() {
  static const HalCategoryImpl category;
  return category;
}

std::error_code make_error_code(Errc e) { return {static_cast<int>(e), HalCategory()}; }

HalError::HalError(std::string device, std::string operation, std::string cause,
                   std::error_code code)
    : std::runtime_error(device + ": " + operation + " failed: " + cause),
      device_(std::move(device)),
      operation_(std::move(operation)),
      cause_(std::move(cause)),
      code_(code) {}

std::string ErrnoText(int err) {
  const char* name = strerrorname_np(err);
  std::string text = std::strerror(err);
  if (name != nullptr) text += std::string(" (") + name + ")";
  return text;
}

}  // namespace kinevis::hal
