#pragma once

// The control table of a Dynamixel model, as data: which register sits at which address, its size
// and access, how its raw value converts to SI, its power-on value and its valid range. Tables are
// YAML files (format in docs/dynamixel.md); kinevis ships config/dynamixel/mx-12w.yaml
// (protocol 1.0) and config/dynamixel/xm430-w350.yaml (protocol 2.0).
//
// A table also names the registers the driver and the simulator need by their role
// (DxlRole: goal position, present position, torque enable, ...), so that code never hard-codes
// an address or a model's register name.
//
// Units: ToSi() returns SI (rad, rad/s, A, V, s, a ratio 0..1); temperatures stay in degrees
// Celsius (unit "degC"), as every datasheet and alarm threshold gives them.

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace kinevis::hal {

enum class DxlAccess { kRead, kReadWrite };

// How a register's bytes (little-endian) hold its value.
enum class DxlEncoding {
  kUnsigned,        // 0 .. 2^(8 size) - 1
  kSigned,          // two's complement
  kDirectionBit10,  // protocol 1.0 speeds and loads: bits 0..9 the magnitude, bit 10 set for the
                    // CW (negative) direction; the value is -1023 .. 1023
};

struct DxlRegister {
  std::string name;  // snake_case of the e-manual's name: "goal_position"
  uint16_t address = 0;
  uint8_t size = 1;  // bytes: 1, 2 or 4
  DxlAccess access = DxlAccess::kReadWrite;
  DxlEncoding encoding = DxlEncoding::kUnsigned;
  std::string unit = "raw";  // the unit of ToSi(): rad, rad/s, rad/s^2, A, V, s, ratio, degC, raw
  double scale = 1.0;        // SI value = raw value * scale
  int64_t initial = 0;       // power-on value (what the simulator starts with)
  int64_t min = 0;           // valid raw values, inclusive
  int64_t max = 0;
};

// Registers the driver and the simulator look up by role. The YAML `roles` map names the
// register of each; every role is required unless marked optional.
enum class DxlRole {
  kModelNumber,
  kFirmwareVersion,
  kId,
  kTorqueEnable,
  kGoalPosition,
  kProfileVelocity,  // speed towards the goal position (1.0: moving speed); 0 = as fast as possible
  kPresentPosition,
  kPresentVelocity,
  kPresentLoad,  // optional (1.0: present load, 2.0: present current)
  kMoving,
  kMinPosition,          // 1.0: CW angle limit; 2.0: min position limit
  kMaxPosition,          // 1.0: CCW angle limit; 2.0: max position limit
  kRegistered,           // 1 while a reg write waits for action
  kHardwareErrorStatus,  // optional; protocol 2.0 only
  kPresentVoltage,       // optional
  kPresentTemperature,   // optional
};
inline constexpr int kDxlRoleCount = 16;
// The YAML key of a role: "goal_position", "hardware_error_status", ...
const char* ToString(DxlRole role);

class DxlControlTable {
 public:
  // An empty table (no registers, no roles); tables come from the loaders below.
  DxlControlTable();

  // Reads and checks a table file. Throws ConfigError naming the file, and for every bad field its
  // key ("registers[4] (goal_position).size") and value, all in one message.
  static DxlControlTable LoadFile(const std::string& path);
  // The same from YAML text; `source` names it in messages.
  static DxlControlTable Parse(const std::string& yaml_text, const std::string& source);
  // A shipped table by model name ("mx-12w", "xm430-w350"): ShippedTablePath(model). Throws
  // ConfigError listing the shipped models when there is no such file.
  static DxlControlTable LoadModel(const std::string& model);
  // <source dir>/config/dynamixel/<model>.yaml.
  static std::string ShippedTablePath(const std::string& model);
  // The models of config/dynamixel/, sorted.
  static std::vector<std::string> ShippedModels();

  const std::string& model() const { return model_; }
  const std::string& source() const { return source_; }
  int protocol() const { return protocol_; }  // 1 or 2
  // The model number the servo reports, and other numbers firmware versions are known to report.
  uint16_t model_number() const { return model_number_; }
  bool AcceptsModelNumber(uint16_t number) const;
  int default_baud() const { return default_baud_; }
  // Addresses below eeprom_end() are EEPROM (kept through power cycles).
  uint16_t eeprom_end() const { return eeprom_end_; }
  // True when EEPROM may be written only with torque off (X series).
  bool eeprom_locked_by_torque() const { return eeprom_locked_by_torque_; }
  // No-load speed at the nominal voltage, rad/s: how fast the shaft turns at profile velocity 0.
  double no_load_speed() const { return no_load_speed_; }
  // One past the highest address of any register.
  size_t size() const { return size_; }

  const std::vector<DxlRegister>& registers() const { return registers_; }
  // nullptr when there is no such register / the table does not name the role.
  const DxlRegister* Find(std::string_view name) const;
  const DxlRegister* Find(DxlRole role) const;
  // The register that starts at `address`, or nullptr.
  const DxlRegister* FindAt(uint16_t address) const;
  // For a required role (never nullptr after a successful load); for an optional role it aborts
  // when absent, so call Find() for those.
  const DxlRegister& Get(DxlRole role) const;

  // Raw value from the register's bytes (little-endian, its encoding).
  static int64_t DecodeRaw(const DxlRegister& reg, const uint8_t* bytes);
  // Register bytes from a raw value (which must fit the encoding; it is not range-checked).
  static void EncodeRaw(const DxlRegister& reg, int64_t raw, uint8_t* bytes);
  static double ToSi(const DxlRegister& reg, int64_t raw) {
    return static_cast<double>(raw) * reg.scale;
  }
  // The nearest raw value of an SI value; nullopt when `si` is not finite or the raw value is out
  // of the register's range.
  static std::optional<int64_t> FromSi(const DxlRegister& reg, double si);

 private:
  std::string model_;
  std::string source_;
  int protocol_ = 0;
  uint16_t model_number_ = 0;
  std::vector<uint16_t> model_number_aliases_;
  int default_baud_ = 0;
  uint16_t eeprom_end_ = 0;
  bool eeprom_locked_by_torque_ = false;
  double no_load_speed_ = 0.0;
  size_t size_ = 0;
  std::vector<DxlRegister> registers_;
  int roles_[kDxlRoleCount];  // index into registers_ by DxlRole, -1 when not named
};

}  // namespace kinevis::hal
