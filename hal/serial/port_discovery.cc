#include "hal/serial/port_discovery.h"

#include <libserialport.h>

#include <algorithm>
#include <memory>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

std::string Text(const char* s) { return s != nullptr ? std::string(s) : std::string(); }

[[noreturn]] void ThrowLibraryError(const char* operation, sp_return code) {
  std::string cause;
  switch (code) {
    case SP_ERR_FAIL: {
      // Only after SP_ERR_FAIL does libserialport have an operating-system message.
      char* message = sp_last_error_message();
      cause = Text(message) + " (error " + std::to_string(sp_last_error_code()) + ")";
      sp_free_error_message(message);
      break;
    }
    case SP_ERR_MEM:
      cause = "libserialport ran out of memory";
      break;
    case SP_ERR_SUPP:
      cause = "libserialport does not support port listing on this system";
      break;
    case SP_ERR_ARG:
      cause = "libserialport rejected an argument (a kinevis bug)";
      break;
    default:
      cause = "libserialport error " + std::to_string(static_cast<int>(code));
      break;
  }
  throw HalError("serial ports", operation, cause, make_error_code(Errc::kIo));
}

const char* TransportName(sp_transport transport) {
  switch (transport) {
    case SP_TRANSPORT_USB:
      return "usb";
    case SP_TRANSPORT_BLUETOOTH:
      return "bluetooth";
    case SP_TRANSPORT_NATIVE:
      return "native";
  }
  return "native";
}

struct PortListDeleter {
  void operator()(sp_port** list) const { sp_free_port_list(list); }
};

}  // namespace

std::vector<SerialPortInfo> ListSerialPorts() {
  sp_port** raw = nullptr;
  const sp_return result = sp_list_ports(&raw);
  if (result != SP_OK) ThrowLibraryError("list serial ports (sp_list_ports)", result);
  std::unique_ptr<sp_port*, PortListDeleter> list(raw);

  std::vector<SerialPortInfo> ports;
  for (sp_port** p = list.get(); p != nullptr && *p != nullptr; ++p) {
    const sp_port* port = *p;
    SerialPortInfo info;
    info.path = Text(sp_get_port_name(port));
    info.description = Text(sp_get_port_description(port));
    const sp_transport transport = sp_get_port_transport(port);
    info.transport = TransportName(transport);
    if (transport == SP_TRANSPORT_USB) {
      int vid = -1, pid = -1;
      if (sp_get_port_usb_vid_pid(port, &vid, &pid) == SP_OK) {
        info.usb_vid = vid;
        info.usb_pid = pid;
      }
      info.manufacturer = Text(sp_get_port_usb_manufacturer(port));
      info.product = Text(sp_get_port_usb_product(port));
      info.serial_number = Text(sp_get_port_usb_serial(port));
    }
    if (!info.path.empty()) ports.push_back(std::move(info));
  }
  std::sort(ports.begin(), ports.end(),
            [](const SerialPortInfo& a, const SerialPortInfo& b) { return a.path < b.path; });
  return ports;
}

}  // namespace kinevis::hal
