#include "hal/common/backend_spec.h"

#include <cctype>
#include <charconv>
#include <vector>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

// Collects every problem with one backend string, then throws them together.
class Problems : public common::Problems {
 public:
  explicit Problems(std::string_view text)
      : common::Problems("backend \"" + std::string(text) + "\"") {}
};

bool ParseInt(std::string_view s, long long min, long long max, int* out) {
  if (s.empty()) return false;
  long long value = 0;
  auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), value);
  if (ec != std::errc() || ptr != s.data() + s.size() || value < min || value > max) return false;
  *out = static_cast<int>(value);
  return true;
}

std::vector<std::string_view> Split(std::string_view s, char sep) {
  std::vector<std::string_view> parts;
  size_t start = 0;
  while (true) {
    size_t pos = s.find(sep, start);
    parts.push_back(s.substr(start, pos == std::string_view::npos ? pos : pos - start));
    if (pos == std::string_view::npos) break;
    start = pos + 1;
  }
  return parts;
}

// A parsed "scheme:target[,item]..." string. Items are "key=value" or bare flags.
struct Parts {
  std::string scheme;
  std::string_view target;
  std::vector<std::string_view> items;
};

Parts SplitBackend(std::string_view text) {
  Parts parts;
  size_t colon = text.find(':');
  if (colon == std::string_view::npos || colon == 0) {
    throw common::ConfigError(
        "backend \"" + std::string(text) +
        "\": no scheme; expected SCHEME:TARGET with SCHEME one of socketcan, slcan, "
        "virtual, tty, modbus-tcp, modbus-rtu (see docs/backends.md)");
  }
  parts.scheme = std::string(text.substr(0, colon));
  std::vector<std::string_view> fields = Split(text.substr(colon + 1), ',');
  parts.target = fields.front();
  parts.items.assign(fields.begin() + 1, fields.end());
  return parts;
}

// "DEVICE[@BAUD]" into settings.
void ParseDeviceAndBaud(std::string_view target, SerialSettings* s, Problems* problems) {
  size_t at = target.rfind('@');
  std::string_view device = target.substr(0, at);
  if (device.empty()) problems->Add("serial device path is empty");
  s->device = std::string(device);
  if (at != std::string_view::npos) {
    std::string_view baud = target.substr(at + 1);
    if (!ParseInt(baud, 50, 12'000'000, &s->baud)) {
      problems->Add("baud rate \"" + std::string(baud) +
                    "\" is not an integer in 50..12000000 bit/s");
    }
  }
}

// "8N1", "8E1", "7O2": data bits, parity, stop bits.
bool IsFrameFormat(std::string_view item) {
  return item.size() == 3 && std::isdigit(static_cast<unsigned char>(item[0])) &&
         std::isalpha(static_cast<unsigned char>(item[1])) &&
         std::isdigit(static_cast<unsigned char>(item[2]));
}

void ParseFrameFormat(std::string_view item, SerialSettings* s, Problems* problems) {
  int data_bits = item[0] - '0';
  char parity = static_cast<char>(std::toupper(static_cast<unsigned char>(item[1])));
  int stop_bits = item[2] - '0';
  bool ok = true;
  if (data_bits < 5 || data_bits > 8) ok = false;
  if (parity != 'N' && parity != 'E' && parity != 'O') ok = false;
  if (stop_bits != 1 && stop_bits != 2) ok = false;
  if (!ok) {
    problems->Add("frame format \"" + std::string(item) +
                  "\" is not DATA PARITY STOP with data bits 5..8, parity N/E/O, stop bits 1/2");
    return;
  }
  s->data_bits = data_bits;
  s->parity = parity;
  s->stop_bits = stop_bits;
}

std::pair<std::string_view, std::string_view> KeyValue(std::string_view item) {
  size_t eq = item.find('=');
  if (eq == std::string_view::npos) return {item, {}};
  return {item.substr(0, eq), item.substr(eq + 1)};
}

void UnknownOption(std::string_view item, const char* allowed, Problems* problems) {
  problems->Add("unknown option \"" + std::string(item) + "\" (allowed: " + allowed + ")");
}

bool ValidInterfaceName(std::string_view name) {
  if (name.empty() || name.size() > 15) return false;
  for (char c : name) {
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '_' && c != '-' && c != '.') {
      return false;
    }
  }
  return true;
}

}  // namespace

int SlcanBitrateCode(int bitrate) {
  static constexpr int kRates[] = {10000,  20000,  50000,  100000, 125000,
                                   250000, 500000, 800000, 1000000};
  for (int i = 0; i < 9; ++i) {
    if (kRates[i] == bitrate) return i;
  }
  return -1;
}

std::string BackendScheme(std::string_view text) { return SplitBackend(text).scheme; }

CanBackendSpec ParseCanBackend(std::string_view text) {
  Parts parts = SplitBackend(text);
  Problems problems(text);
  CanBackendSpec spec;
  spec.text = std::string(text);
  auto parse_bitrate = [&](std::string_view value) {
    if (!ParseInt(value, 1000, 1'000'000, &spec.bitrate)) {
      problems.Add("bitrate \"" + std::string(value) +
                   "\" is not an integer CAN bit rate in 1000..1000000 bit/s");
    }
  };
  if (parts.scheme == "socketcan") {
    spec.kind = CanBackendSpec::Kind::kSocketCan;
    spec.interface = std::string(parts.target);
    if (!ValidInterfaceName(parts.target)) {
      problems.Add("interface name \"" + spec.interface +
                   "\" is not 1..15 characters of letters, digits, '_', '-', '.'");
    }
    for (std::string_view item : parts.items) UnknownOption(item, "none", &problems);
  } else if (parts.scheme == "virtual") {
    spec.kind = CanBackendSpec::Kind::kVirtual;
    spec.interface = std::string(parts.target);
    if (spec.interface.empty()) problems.Add("virtual bus name is empty");
    for (std::string_view item : parts.items) {
      auto [key, value] = KeyValue(item);
      if (key == "bitrate") {
        parse_bitrate(value);
      } else {
        UnknownOption(item, "bitrate=N", &problems);
      }
    }
  } else if (parts.scheme == "slcan") {
    spec.kind = CanBackendSpec::Kind::kSlcan;
    ParseDeviceAndBaud(parts.target, &spec.serial, &problems);
    for (std::string_view item : parts.items) {
      auto [key, value] = KeyValue(item);
      if (key == "bitrate") {
        parse_bitrate(value);
        if (spec.bitrate != 0 && SlcanBitrateCode(spec.bitrate) < 0) {
          problems.Add("bitrate " + std::to_string(spec.bitrate) +
                       " has no Lawicel code; use one of 10000, 20000, 50000, 100000, 125000, "
                       "250000, 500000, 800000, 1000000");
        }
      } else if (item == "listen") {
        spec.listen_only = true;
      } else if (item == "timestamps") {
        spec.timestamps = true;
      } else {
        UnknownOption(item, "bitrate=N, listen, timestamps", &problems);
      }
    }
  } else {
    problems.Add("scheme \"" + parts.scheme +
                 "\" is not a CAN backend (socketcan, slcan, virtual)");
  }
  problems.ThrowIfAny();
  return spec;
}

SerialSettings ParseTtyBackend(std::string_view text) {
  Parts parts = SplitBackend(text);
  Problems problems(text);
  SerialSettings s;
  if (parts.scheme != "tty") {
    problems.Add("scheme \"" + parts.scheme + "\" is not a serial backend (tty)");
    problems.ThrowIfAny();
  }
  ParseDeviceAndBaud(parts.target, &s, &problems);
  for (std::string_view item : parts.items) {
    if (IsFrameFormat(item)) {
      ParseFrameFormat(item, &s, &problems);
    } else if (item == "rs485") {
      s.rs485 = true;
    } else {
      UnknownOption(item, "a frame format like 8N1, rs485", &problems);
    }
  }
  problems.ThrowIfAny();
  return s;
}

ModbusBackendSpec ParseModbusBackend(std::string_view text) {
  Parts parts = SplitBackend(text);
  Problems problems(text);
  ModbusBackendSpec spec;
  spec.text = std::string(text);
  if (parts.scheme == "modbus-tcp") {
    spec.kind = ModbusBackendSpec::Kind::kTcp;
    // The target was cut at the first ',' only; HOST:PORT with IPv6 as [addr]:port.
    std::string_view target = parts.target;
    std::string_view host, port;
    if (!target.empty() && target.front() == '[') {
      size_t close = target.find(']');
      if (close == std::string_view::npos || close + 1 >= target.size() ||
          target[close + 1] != ':') {
        problems.Add("address \"" + std::string(target) + "\" is not [IPV6]:PORT");
      } else {
        host = target.substr(1, close - 1);
        port = target.substr(close + 2);
      }
    } else {
      size_t colon = target.rfind(':');
      if (colon == std::string_view::npos) {
        problems.Add("address \"" + std::string(target) + "\" has no port; expected HOST:PORT");
      } else {
        host = target.substr(0, colon);
        port = target.substr(colon + 1);
      }
    }
    spec.host = std::string(host);
    if (!port.empty() || !host.empty()) {
      if (host.empty()) problems.Add("host is empty");
      if (!ParseInt(port, 1, 65535, &spec.port)) {
        problems.Add("port \"" + std::string(port) + "\" is not an integer in 1..65535");
      }
    }
  } else if (parts.scheme == "modbus-rtu") {
    spec.kind = ModbusBackendSpec::Kind::kRtu;
    spec.serial.parity = 'E';  // the Modbus specification's default frame is 8E1
    ParseDeviceAndBaud(parts.target, &spec.serial, &problems);
  } else {
    problems.Add("scheme \"" + parts.scheme +
                 "\" is not a Modbus backend (modbus-tcp, modbus-rtu)");
    problems.ThrowIfAny();
  }
  const bool rtu = spec.kind == ModbusBackendSpec::Kind::kRtu;
  for (std::string_view item : parts.items) {
    auto [key, value] = KeyValue(item);
    if (key == "unit") {
      if (!ParseInt(value, 0, 247, &spec.unit)) {
        problems.Add("unit \"" + std::string(value) + "\" is not an integer in 0..247");
      }
    } else if (key == "timeout_ms") {
      if (!ParseInt(value, 1, 60'000, &spec.timeout_ms)) {
        problems.Add("timeout_ms \"" + std::string(value) + "\" is not an integer in 1..60000");
      }
    } else if (key == "retries") {
      if (!ParseInt(value, 0, 100, &spec.retries)) {
        problems.Add("retries \"" + std::string(value) + "\" is not an integer in 0..100");
      }
    } else if (rtu && IsFrameFormat(item)) {
      ParseFrameFormat(item, &spec.serial, &problems);
    } else if (rtu && item == "rs485") {
      spec.serial.rs485 = true;
    } else {
      UnknownOption(item,
                    rtu ? "unit=N, timeout_ms=N, retries=N, a frame format like 8E1, rs485"
                        : "unit=N, timeout_ms=N, retries=N",
                    &problems);
    }
  }
  problems.ThrowIfAny();
  return spec;
}

}  // namespace kinevis::hal
