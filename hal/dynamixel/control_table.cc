#include "hal/dynamixel/control_table.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include "common/check.h"
#include "hal/common/error.h"

#ifndef KINEVIS_SOURCE_DIR
#error "KINEVIS_SOURCE_DIR must be defined (hal/CMakeLists.txt)"
#endif

namespace kinevis::hal {
namespace {

constexpr const char* kRoleNames[kDxlRoleCount] = {
    "model_number",
    "firmware_version",
    "id",
    "torque_enable",
    "goal_position",
    "profile_velocity",
    "present_position",
    "present_velocity",
    "present_load",
    "moving",
    "min_position",
    "max_position",
    "registered",
    "hardware_error_status",
    "present_voltage",
    "present_temperature",
};

bool IsOptional(DxlRole role) {
  return role == DxlRole::kPresentLoad || role == DxlRole::kHardwareErrorStatus ||
         role == DxlRole::kPresentVoltage || role == DxlRole::kPresentTemperature;
}

// Every problem found in one file, thrown together as one ConfigError.

std::string Show(const YAML::Node& node) {
  if (node.IsScalar()) return "\"" + node.Scalar() + "\"";
  if (node.IsSequence()) return "a list";
  if (node.IsMap()) return "a map";
  return "nothing";
}

template <typename T>
std::optional<T> Convert(const YAML::Node& node, const std::string& key, const char* what,
                         common::Problems* problems) {
  if (!node.IsScalar()) {
    problems->Add(std::string(key) + ": " + Show(node) + " is not " + what);
    return std::nullopt;
  }
  try {
    return node.as<T>();
  } catch (const YAML::Exception&) {
    problems->Add(std::string(key) + ": " + Show(node) + " is not " + what);
    return std::nullopt;
  }
}

template <typename T>
std::optional<T> Field(const YAML::Node& map, const std::string& field, const std::string& prefix,
                       const char* what, bool required, common::Problems* problems) {
  const std::string key = prefix.empty() ? field : prefix + "." + field;
  const YAML::Node node = map[field];
  if (!node) {
    if (required) problems->Add(std::string(key) + ": missing");
    return std::nullopt;
  }
  return Convert<T>(node, key, what, problems);
}

void CheckKeys(const YAML::Node& map, const std::set<std::string>& allowed,
               const std::string& prefix, common::Problems* problems) {
  for (const auto& item : map) {
    const std::string key = item.first.Scalar();
    if (allowed.count(key) == 0) {
      problems->Add(std::string(prefix.empty() ? key : prefix + "." + key) + ": " + "unknown key");
    }
  }
}

// The raw values an encoding of `size` bytes can hold.
std::pair<int64_t, int64_t> Representable(DxlEncoding encoding, int size) {
  switch (encoding) {
    case DxlEncoding::kUnsigned:
      return {0, (int64_t{1} << (8 * size)) - 1};
    case DxlEncoding::kSigned:
      return {-(int64_t{1} << (8 * size - 1)), (int64_t{1} << (8 * size - 1)) - 1};
    case DxlEncoding::kDirectionBit10:
      return {-1023, 1023};
  }
  return {0, 0};
}

bool ValidName(const std::string& name) {
  if (name.empty()) return false;
  for (char c : name) {
    if (!((c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_')) return false;
  }
  return true;
}

[[noreturn]] void AbortMissingRole(const std::string& model, DxlRole role) {
  KINEVIS_DEMAND_MSG(
      false, "DxlControlTable::Get: table " + model + " does not name role " + ToString(role));
  KINEVIS_UNREACHABLE();
}

}  // namespace

DxlControlTable::DxlControlTable() { std::fill(std::begin(roles_), std::end(roles_), -1); }

const char* ToString(DxlRole role) {
  const int i = static_cast<int>(role);
  return i >= 0 && i < kDxlRoleCount ? kRoleNames[i] : "?";
}

DxlControlTable DxlControlTable::LoadFile(const std::string& path) {
  std::ifstream in(path);
  if (!in)
    throw common::ConfigError(path +
                              ": cannot read the Dynamixel control table: " + ErrnoText(errno));
  std::stringstream text;
  text << in.rdbuf();
  return Parse(text.str(), path);
}

std::string DxlControlTable::ShippedTablePath(const std::string& model) {
  return std::string(KINEVIS_SOURCE_DIR) + "/config/dynamixel/" + model + ".yaml";
}

std::vector<std::string> DxlControlTable::ShippedModels() {
  std::vector<std::string> models;
  std::error_code ec;
  const std::filesystem::path dir = std::string(KINEVIS_SOURCE_DIR) + "/config/dynamixel";
  for (const auto& entry : std::filesystem::directory_iterator(dir, ec)) {
    if (entry.path().extension() == ".yaml") models.push_back(entry.path().stem().string());
  }
  std::sort(models.begin(), models.end());
  return models;
}

DxlControlTable DxlControlTable::LoadModel(const std::string& model) {
  const std::string path = ShippedTablePath(model);
  if (!std::filesystem::exists(path)) {
    std::string known;
    for (const std::string& m : ShippedModels()) known += (known.empty() ? "" : ", ") + m;
    throw common::ConfigError("Dynamixel model \"" + model + "\": no control table " + path +
                              " (shipped: " + (known.empty() ? "none" : known) + ")");
  }
  return LoadFile(path);
}

DxlControlTable DxlControlTable::Parse(const std::string& yaml_text, const std::string& source) {
  YAML::Node root;
  try {
    root = YAML::Load(yaml_text);
  } catch (const YAML::Exception& e) {
    throw common::ConfigError(source + ": YAML syntax error at line " +
                              std::to_string(e.mark.line + 1) + ", column " +
                              std::to_string(e.mark.column + 1) + ": " + e.msg);
  }
  if (!root.IsMap())
    throw common::ConfigError(source + ": a Dynamixel control table must be a YAML map");

  common::Problems problems(source + ": invalid Dynamixel control table");
  DxlControlTable t;
  t.source_ = source;
  CheckKeys(root,
            {"model", "protocol", "model_number", "model_number_aliases", "default_baud",
             "eeprom_end", "eeprom_locked_by_torque", "no_load_speed", "registers", "roles"},
            "", &problems);

  if (auto v = Field<std::string>(root, "model", "", "a string", true, &problems)) {
    if (v->empty()) problems.Add("model: empty");
    t.model_ = *v;
  }
  if (auto v = Field<int>(root, "protocol", "", "an integer", true, &problems)) {
    if (*v != 1 && *v != 2)
      problems.Add(std::string("protocol: ") + std::to_string(*v) + " is not 1 or 2");
    t.protocol_ = *v;
  }
  if (auto v = Field<int64_t>(root, "model_number", "", "an integer", true, &problems)) {
    if (*v < 0 || *v > 0xFFFF) {
      problems.Add(std::string("model_number: ") + std::to_string(*v) + " is not in 0..65535");
    }
    t.model_number_ = static_cast<uint16_t>(*v);
  }
  if (const YAML::Node aliases = root["model_number_aliases"]) {
    if (!aliases.IsSequence()) {
      problems.Add(std::string("model_number_aliases: ") + Show(aliases) + " is not a list");
    } else {
      for (size_t i = 0; i < aliases.size(); ++i) {
        const std::string key = "model_number_aliases[" + std::to_string(i) + "]";
        if (auto v = Convert<int64_t>(aliases[i], key, "an integer", &problems)) {
          if (*v < 0 || *v > 0xFFFF) {
            problems.Add(std::string(key) + ": " + std::to_string(*v) + " is not in 0..65535");
          } else {
            t.model_number_aliases_.push_back(static_cast<uint16_t>(*v));
          }
        }
      }
    }
  }
  if (auto v = Field<int64_t>(root, "default_baud", "", "an integer", true, &problems)) {
    if (*v <= 0 || *v > 100000000) {
      problems.Add(std::string("default_baud: ") + std::to_string(*v) + " is not a baud rate");
    }
    t.default_baud_ = static_cast<int>(*v);
  }
  if (auto v = Field<int64_t>(root, "eeprom_end", "", "an integer", true, &problems)) {
    if (*v < 0 || *v > 0xFFFF) {
      problems.Add(std::string("eeprom_end: ") + std::to_string(*v) + " is not in 0..65535");
    }
    t.eeprom_end_ = static_cast<uint16_t>(*v);
  }
  if (auto v =
          Field<bool>(root, "eeprom_locked_by_torque", "", "true or false", false, &problems)) {
    t.eeprom_locked_by_torque_ = *v;
  }
  if (auto v = Field<double>(root, "no_load_speed", "", "a number", true, &problems)) {
    if (!std::isfinite(*v) || *v <= 0) {
      problems.Add(std::string("no_load_speed: ") + std::to_string(*v) +
                   " is not a positive speed in rad/s");
    }
    t.no_load_speed_ = *v;
  }

  const YAML::Node regs = root["registers"];
  if (!regs) {
    problems.Add("registers: missing");
  } else if (!regs.IsSequence() || regs.size() == 0) {
    problems.Add(std::string("registers: ") + Show(regs) + " is not a non-empty list");
  } else {
    for (size_t i = 0; i < regs.size(); ++i) {
      const YAML::Node node = regs[i];
      std::string key = "registers[" + std::to_string(i) + "]";
      if (!node.IsMap()) {
        problems.Add(std::string(key) + ": " + Show(node) + " is not a map");
        continue;
      }
      DxlRegister r;
      bool ok = true;
      if (auto v = Field<std::string>(node, "name", key, "a string", true, &problems)) {
        r.name = *v;
        if (!ValidName(r.name)) {
          problems.Add(std::string(key + ".name") + ": \"" + r.name + "\" is not snake_case");
          ok = false;
        }
        key += " (" + r.name + ")";
      } else {
        ok = false;
      }
      CheckKeys(
          node,
          {"name", "address", "size", "access", "encoding", "unit", "scale", "initial", "range"},
          key, &problems);
      if (auto v = Field<int64_t>(node, "address", key, "an integer", true, &problems)) {
        if (*v < 0 || *v > 0xFFFF) {
          problems.Add(std::string(key + ".address") + ": " + std::to_string(*v) +
                       " is not in 0..65535");
          ok = false;
        }
        r.address = static_cast<uint16_t>(*v);
      } else {
        ok = false;
      }
      if (auto v = Field<int>(node, "size", key, "an integer", true, &problems)) {
        if (*v != 1 && *v != 2 && *v != 4) {
          problems.Add(std::string(key + ".size") + ": " + std::to_string(*v) +
                       " is not 1, 2 or 4");
          ok = false;
        }
        r.size = static_cast<uint8_t>(*v);
      } else {
        ok = false;
      }
      if (auto v = Field<std::string>(node, "access", key, "a string", true, &problems)) {
        if (*v == "r") {
          r.access = DxlAccess::kRead;
        } else if (*v == "rw") {
          r.access = DxlAccess::kReadWrite;
        } else {
          problems.Add(std::string(key + ".access") + ": \"" + *v + "\" is not r or rw");
        }
      }
      if (auto v = Field<std::string>(node, "encoding", key, "a string", false, &problems)) {
        if (*v == "unsigned") {
          r.encoding = DxlEncoding::kUnsigned;
        } else if (*v == "signed") {
          r.encoding = DxlEncoding::kSigned;
        } else if (*v == "direction_bit10") {
          r.encoding = DxlEncoding::kDirectionBit10;
          if (r.size != 2) {
            problems.Add(std::string(key + ".encoding") + ": direction_bit10 needs size 2");
            ok = false;
          }
        } else {
          problems.Add(std::string(key + ".encoding") + ": " + "\"" + *v +
                       "\" is not unsigned, signed or direction_bit10");
        }
      }
      if (auto v = Field<std::string>(node, "unit", key, "a string", false, &problems)) {
        r.unit = *v;
      }
      if (auto v = Field<double>(node, "scale", key, "a number", false, &problems)) {
        if (!std::isfinite(*v) || *v == 0.0) {
          problems.Add(std::string(key + ".scale") + ": " + node["scale"].Scalar() +
                       " is not a finite non-zero number");
        }
        r.scale = *v;
      }
      if (!ok) continue;  // the checks below need a valid size
      if (t.protocol_ == 1 && r.address + r.size > 256) {
        problems.Add(std::string(key + ".address") + ": " + std::to_string(r.address) +
                     " + size is beyond protocol 1.0's 256 bytes");
      }
      const auto [lo, hi] = Representable(r.encoding, r.size);
      r.min = lo;
      r.max = hi;
      if (const YAML::Node range = node["range"]) {
        if (!range.IsSequence() || range.size() != 2) {
          problems.Add(std::string(key + ".range") + ": " + Show(range) + " is not [min, max]");
        } else {
          auto a = Convert<int64_t>(range[0], key + ".range[0]", "an integer", &problems);
          auto b = Convert<int64_t>(range[1], key + ".range[1]", "an integer", &problems);
          if (a && b) {
            if (*a > *b || *a < lo || *b > hi) {
              problems.Add(std::string(key + ".range") + ": [" + std::to_string(*a) + ", " +
                           std::to_string(*b) + "] is empty or outside what " +
                           std::to_string(r.size) + " bytes hold [" + std::to_string(lo) + ", " +
                           std::to_string(hi) + "]");
            } else {
              r.min = *a;
              r.max = *b;
            }
          }
        }
      }
      r.initial = std::clamp<int64_t>(0, r.min, r.max);
      if (auto v = Field<int64_t>(node, "initial", key, "an integer", false, &problems)) {
        if (*v < r.min || *v > r.max) {
          problems.Add(std::string(key + ".initial") + ": " + std::to_string(*v) +
                       " is outside the range [" + std::to_string(r.min) + ", " +
                       std::to_string(r.max) + "]");
        }
        r.initial = *v;
      }
      for (const DxlRegister& other : t.registers_) {
        if (other.name == r.name) {
          problems.Add(std::string(key + ".name") + ": \"" + r.name + "\" is defined twice");
        } else if (r.address < other.address + other.size && other.address < r.address + r.size) {
          problems.Add(std::string(key + ".address") + ": " + std::to_string(r.address) +
                       " overlaps " + other.name + " at " + std::to_string(other.address));
        }
      }
      t.registers_.push_back(std::move(r));
    }
  }

  const YAML::Node roles = root["roles"];
  if (!roles) {
    problems.Add("roles: missing");
  } else if (!roles.IsMap()) {
    problems.Add(std::string("roles: ") + Show(roles) + " is not a map");
  } else {
    for (const auto& item : roles) {
      const std::string role_name = item.first.Scalar();
      const std::string key = "roles." + role_name;
      const auto* it = std::find_if(std::begin(kRoleNames), std::end(kRoleNames),
                                    [&](const char* n) { return role_name == n; });
      if (it == std::end(kRoleNames)) {
        problems.Add(std::string(key) + ": unknown role");
        continue;
      }
      auto reg_name = Convert<std::string>(item.second, key, "a register name", &problems);
      if (!reg_name) continue;
      const auto reg = std::find_if(t.registers_.begin(), t.registers_.end(),
                                    [&](const DxlRegister& r) { return r.name == *reg_name; });
      if (reg == t.registers_.end()) {
        problems.Add(std::string(key) + ": \"" + *reg_name + "\" is not a register of this table");
        continue;
      }
      t.roles_[it - std::begin(kRoleNames)] = static_cast<int>(reg - t.registers_.begin());
    }
    for (int i = 0; i < kDxlRoleCount; ++i) {
      if (t.roles_[i] < 0 && !IsOptional(static_cast<DxlRole>(i))) {
        problems.Add(std::string(std::string("roles.") + kRoleNames[i]) + ": " + "missing");
      }
    }
  }
  // What the driver writes must be writable; the model number register must report model_number.
  if (problems.empty()) {
    for (DxlRole role : {DxlRole::kTorqueEnable, DxlRole::kGoalPosition, DxlRole::kProfileVelocity,
                         DxlRole::kMinPosition, DxlRole::kMaxPosition}) {
      if (t.Get(role).access != DxlAccess::kReadWrite) {
        problems.Add(std::string(std::string("roles.") + ToString(role)) + ": " + "register " +
                     t.Get(role).name + " is read-only");
      }
    }
    const DxlRegister& model_reg = t.Get(DxlRole::kModelNumber);
    if (model_reg.initial != t.model_number_) {
      problems.Add(std::string("registers (" + model_reg.name + ").initial") + ": " +
                   std::to_string(model_reg.initial) + " differs from model_number " +
                   std::to_string(t.model_number_));
    }
  }
  problems.ThrowIfAny();
  for (const DxlRegister& r : t.registers_) {
    t.size_ = std::max<size_t>(t.size_, static_cast<size_t>(r.address) + r.size);
  }
  return t;
}

bool DxlControlTable::AcceptsModelNumber(uint16_t number) const {
  return number == model_number_ ||
         std::find(model_number_aliases_.begin(), model_number_aliases_.end(), number) !=
             model_number_aliases_.end();
}

const DxlRegister* DxlControlTable::Find(std::string_view name) const {
  for (const DxlRegister& r : registers_) {
    if (r.name == name) return &r;
  }
  return nullptr;
}

const DxlRegister* DxlControlTable::Find(DxlRole role) const {
  const int i = static_cast<int>(role);
  if (i < 0 || i >= kDxlRoleCount || roles_[i] < 0) return nullptr;
  return &registers_[static_cast<size_t>(roles_[i])];
}

const DxlRegister* DxlControlTable::FindAt(uint16_t address) const {
  for (const DxlRegister& r : registers_) {
    if (r.address == address) return &r;
  }
  return nullptr;
}

const DxlRegister& DxlControlTable::Get(DxlRole role) const {
  const DxlRegister* r = Find(role);
  if (r == nullptr) AbortMissingRole(model_, role);
  return *r;
}

int64_t DxlControlTable::DecodeRaw(const DxlRegister& reg, const uint8_t* bytes) {
  uint64_t u = 0;
  for (int i = reg.size - 1; i >= 0; --i) u = (u << 8) | bytes[i];
  switch (reg.encoding) {
    case DxlEncoding::kUnsigned:
      return static_cast<int64_t>(u);
    case DxlEncoding::kSigned: {
      const uint64_t sign = uint64_t{1} << (8 * reg.size - 1);
      return static_cast<int64_t>(u ^ sign) - static_cast<int64_t>(sign);
    }
    case DxlEncoding::kDirectionBit10: {
      const int64_t magnitude = static_cast<int64_t>(u & 0x3FF);
      return (u & 0x400) != 0 ? -magnitude : magnitude;
    }
  }
  return 0;
}

void DxlControlTable::EncodeRaw(const DxlRegister& reg, int64_t raw, uint8_t* bytes) {
  uint64_t u = static_cast<uint64_t>(raw);
  if (reg.encoding == DxlEncoding::kDirectionBit10) {
    u = raw < 0 ? (0x400u | static_cast<uint64_t>(-raw)) : static_cast<uint64_t>(raw);
  }
  for (int i = 0; i < reg.size; ++i) {
    bytes[i] = static_cast<uint8_t>(u & 0xFF);
    u >>= 8;
  }
}

std::optional<int64_t> DxlControlTable::FromSi(const DxlRegister& reg, double si) {
  if (!std::isfinite(si)) return std::nullopt;
  const double raw = std::round(si / reg.scale);
  if (!(raw >= static_cast<double>(reg.min) && raw <= static_cast<double>(reg.max))) {
    return std::nullopt;
  }
  return static_cast<int64_t>(raw);
}

}  // namespace kinevis::hal
