#include "hal/dynamixel/control_table.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <string>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using ::testing::Contains;
using ::testing::HasSubstr;
using ::testing::MatchesRegex;

constexpr double kTick = 2.0 * M_PI / 4096.0;  // rad per position tick
constexpr double kRpm = 2.0 * M_PI / 60.0;     // rad/s per rev/min

// A minimal valid table; tests break one thing at a time.
std::string MinimalTable(const std::string& registers_extra = "",
                         const std::string& roles_extra = "") {
  return R"(model: test-servo
protocol: 2
model_number: 7
default_baud: 57600
eeprom_end: 8
no_load_speed: 5.0
registers:
  - {name: model_number, address: 0, size: 2, access: r, initial: 7}
  - {name: firmware_version, address: 2, size: 1, access: r}
  - {name: id, address: 3, size: 1, access: rw, initial: 1, range: [0, 252]}
  - {name: torque_enable, address: 8, size: 1, access: rw, range: [0, 1]}
  - {name: goal_position, address: 10, size: 4, access: rw, encoding: signed, unit: rad, scale: 0.0015339807878856412, range: [0, 4095]}
  - {name: profile_velocity, address: 14, size: 4, access: rw, unit: rad/s, scale: 0.024}
  - {name: present_position, address: 18, size: 4, access: r, encoding: signed, unit: rad, scale: 0.0015339807878856412}
  - {name: present_velocity, address: 22, size: 4, access: r, encoding: signed}
  - {name: moving, address: 26, size: 1, access: r}
  - {name: min_limit, address: 28, size: 4, access: rw, range: [0, 4095]}
  - {name: max_limit, address: 32, size: 4, access: rw, range: [0, 4095], initial: 4095}
  - {name: registered, address: 36, size: 1, access: r}
)" + registers_extra +
         R"(roles:
  model_number: model_number
  firmware_version: firmware_version
  id: id
  torque_enable: torque_enable
  goal_position: goal_position
  profile_velocity: profile_velocity
  present_position: present_position
  present_velocity: present_velocity
  moving: moving
  min_position: min_limit
  max_position: max_limit
  registered: registered
)" + roles_extra;
}

// `text` with the first `from` replaced by `to` (which must be there).
std::string Replace(std::string text, const std::string& from, const std::string& to) {
  const size_t at = text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

std::string ErrorOf(const std::string& yaml, const std::string& source = "bad.yaml") {
  try {
    DxlControlTable::Parse(yaml, source);
  } catch (const common::ConfigError& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(DxlControlTableTest, ShippedMx12wLoadsWithTheEManualAddresses) {
  const DxlControlTable t = DxlControlTable::LoadModel("mx-12w");
  EXPECT_EQ(t.model(), "mx-12w");
  EXPECT_EQ(t.protocol(), 1);
  EXPECT_EQ(t.model_number(), 360);
  EXPECT_TRUE(t.AcceptsModelNumber(360));
  EXPECT_TRUE(t.AcceptsModelNumber(104));
  EXPECT_FALSE(t.AcceptsModelNumber(1020));
  EXPECT_EQ(t.default_baud(), 1000000);
  EXPECT_EQ(t.Get(DxlRole::kTorqueEnable).address, 24);
  EXPECT_EQ(t.Get(DxlRole::kGoalPosition).address, 30);
  EXPECT_EQ(t.Get(DxlRole::kGoalPosition).size, 2);
  EXPECT_EQ(t.Get(DxlRole::kProfileVelocity).name, "moving_speed");
  EXPECT_EQ(t.Get(DxlRole::kProfileVelocity).address, 32);
  EXPECT_EQ(t.Get(DxlRole::kPresentPosition).address, 36);
  EXPECT_EQ(t.Get(DxlRole::kMinPosition).address, 6);
  EXPECT_EQ(t.Get(DxlRole::kMaxPosition).address, 8);
  EXPECT_EQ(t.Find(DxlRole::kHardwareErrorStatus), nullptr);
  EXPECT_NEAR(t.Get(DxlRole::kPresentPosition).scale * 4096, 2 * M_PI, 1e-12);
  EXPECT_NEAR(t.Get(DxlRole::kProfileVelocity).scale, 0.916 * kRpm, 1e-12);
  EXPECT_EQ(t.Get(DxlRole::kPresentVelocity).encoding, DxlEncoding::kDirectionBit10);
  EXPECT_EQ(t.size(), 74u);  // goal acceleration at 73 is the last register
  EXPECT_NEAR(t.no_load_speed(), 470 * kRpm, 1e-9);
}

TEST(DxlControlTableTest, ShippedXm430W350LoadsWithTheEManualAddresses) {
  const DxlControlTable t = DxlControlTable::LoadModel("xm430-w350");
  EXPECT_EQ(t.protocol(), 2);
  EXPECT_EQ(t.model_number(), 1020);
  EXPECT_EQ(t.Get(DxlRole::kTorqueEnable).address, 64);
  EXPECT_EQ(t.Get(DxlRole::kGoalPosition).address, 116);
  EXPECT_EQ(t.Get(DxlRole::kGoalPosition).size, 4);
  EXPECT_EQ(t.Get(DxlRole::kPresentPosition).address, 132);
  EXPECT_EQ(t.Get(DxlRole::kPresentPosition).size, 4);
  EXPECT_EQ(t.Get(DxlRole::kProfileVelocity).address, 112);
  EXPECT_EQ(t.Get(DxlRole::kHardwareErrorStatus).address, 70);
  EXPECT_NEAR(t.Get(DxlRole::kPresentVelocity).scale, 0.229 * kRpm, 1e-12);
  EXPECT_EQ(t.eeprom_end(), 64);
  EXPECT_TRUE(t.eeprom_locked_by_torque());
  const DxlRegister* shutdown = t.Find("shutdown");
  ASSERT_NE(shutdown, nullptr);
  EXPECT_EQ(shutdown->initial, 52);
  EXPECT_EQ(t.FindAt(116), &t.Get(DxlRole::kGoalPosition));
  EXPECT_EQ(t.FindAt(117), nullptr);
}

TEST(DxlControlTableTest, ShippedModelsListsBoth) {
  const auto models = DxlControlTable::ShippedModels();
  EXPECT_THAT(models, Contains("mx-12w"));
  EXPECT_THAT(models, Contains("xm430-w350"));
}

TEST(DxlControlTableTest, UnknownModelNamesThePathAndTheShippedModels) {
  try {
    DxlControlTable::LoadModel("ax-99");
    FAIL() << "no exception";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), HasSubstr("ax-99"));
    EXPECT_THAT(e.what(), HasSubstr("config/dynamixel/ax-99.yaml"));
    EXPECT_THAT(e.what(), HasSubstr("mx-12w, xm430-w350"));
  }
}

TEST(DxlControlTableTest, MinimalTableParses) {
  const DxlControlTable t = DxlControlTable::Parse(MinimalTable(), "min.yaml");
  EXPECT_EQ(t.source(), "min.yaml");
  EXPECT_EQ(t.Get(DxlRole::kMaxPosition).initial, 4095);
  EXPECT_EQ(t.Find(DxlRole::kPresentLoad), nullptr);
  EXPECT_FALSE(t.eeprom_locked_by_torque());
}

TEST(DxlControlTableTest, BadSizeNamesFileKeyAndValue) {
  const std::string error =
      ErrorOf(MinimalTable("  - {name: led, address: 40, size: 3, access: rw}\n"));
  EXPECT_THAT(error, HasSubstr("bad.yaml"));
  EXPECT_THAT(error, HasSubstr("registers[12] (led).size: 3 is not 1, 2 or 4"));
}

TEST(DxlControlTableTest, EveryProblemIsReportedInOneMessage) {
  const std::string error =
      ErrorOf(MinimalTable("  - {name: led, address: 40, size: 1, access: x}\n"
                           "  - {name: gain, address: 41, size: 2, access: rw, initial: 70000}\n"
                           "  - {name: speed, address: 42, size: 2, access: rw, colour: red}\n"));
  EXPECT_THAT(error, HasSubstr("registers[12] (led).access: \"x\" is not r or rw"));
  EXPECT_THAT(error, HasSubstr("registers[13] (gain).initial: 70000 is outside the range"));
  EXPECT_THAT(error, HasSubstr("registers[14] (speed).colour: unknown key"));
  EXPECT_THAT(error, HasSubstr("registers[14] (speed).address: 42 overlaps gain at 41"));
}

TEST(DxlControlTableTest, MissingAndUnknownRolesAreNamed) {
  const std::string yaml =
      Replace(MinimalTable("", "  elbow: moving\n  present_load: nothing_here\n"),
              "  goal_position: goal_position\n", "");
  const std::string error = ErrorOf(yaml);
  EXPECT_THAT(error, HasSubstr("roles.goal_position: missing"));
  EXPECT_THAT(error, HasSubstr("roles.elbow: unknown role"));
  EXPECT_THAT(error, HasSubstr("roles.present_load: \"nothing_here\" is not a register"));
}

TEST(DxlControlTableTest, TopLevelFieldsAreChecked) {
  const std::string yaml = Replace(Replace(MinimalTable(), "protocol: 2", "protocol: 3"),
                                   "no_load_speed: 5.0", "no_load_speed: fast");
  const std::string error = ErrorOf(yaml);
  EXPECT_THAT(error, HasSubstr("protocol: 3 is not 1 or 2"));
  EXPECT_THAT(error, HasSubstr("no_load_speed: \"fast\" is not a number"));
}

TEST(DxlControlTableTest, ModelNumberRegisterMustAgree) {
  const std::string yaml = Replace(MinimalTable(), "model_number: 7\n", "model_number: 8\n");
  EXPECT_THAT(ErrorOf(yaml), HasSubstr("(model_number).initial: 7 differs from model_number 8"));
}

TEST(DxlControlTableTest, ReadOnlyRegisterCannotTakeAWrittenRole) {
  const std::string yaml =
      Replace(MinimalTable(), "name: torque_enable, address: 8, size: 1, access: rw",
              "name: torque_enable, address: 8, size: 1, access: r");
  EXPECT_THAT(ErrorOf(yaml), HasSubstr("roles.torque_enable: register torque_enable is read-only"));
}

TEST(DxlControlTableTest, SyntaxErrorNamesFileAndLine) {
  const std::string error = ErrorOf("model: x\nregisters: [\n  {name: a,\n", "broken.yaml");
  EXPECT_THAT(error,
              MatchesRegex("broken\\.yaml: YAML syntax error at line [0-9]+, column [0-9]+:.*"));
}

TEST(DxlControlTableTest, LoadFileNamesTheFile) {
  const std::string path =
      ::testing::TempDir() + "kinevis_bad_table_" + std::to_string(::getpid()) + ".yaml";
  {
    std::ofstream out(path);
    out << MinimalTable("  - {name: led, address: 40, size: 1, access: rw, range: [5, 2]}\n");
  }
  try {
    DxlControlTable::LoadFile(path);
    ADD_FAILURE() << "no exception";
  } catch (const common::ConfigError& e) {
    EXPECT_THAT(e.what(), HasSubstr(path + ": invalid Dynamixel control table"));
    EXPECT_THAT(e.what(), HasSubstr("registers[12] (led).range: [5, 2] is empty"));
  }
  std::remove(path.c_str());
  EXPECT_THROW(DxlControlTable::LoadFile(path), common::ConfigError);  // now absent
}

TEST(DxlControlTableTest, RawEncodingsRoundTrip) {
  DxlRegister u16{"u", 0, 2, DxlAccess::kRead, DxlEncoding::kUnsigned, "raw", 1.0, 0, 0, 65535};
  DxlRegister s32{"s",   0,   4, DxlAccess::kRead, DxlEncoding::kSigned,
                  "raw", 1.0, 0, -2147483648LL,    2147483647LL};
  DxlRegister dir{"d", 0,     2,   DxlAccess::kRead, DxlEncoding::kDirectionBit10, "raw", 1.0,
                  0,   -1023, 1023};
  uint8_t b[4];
  DxlControlTable::EncodeRaw(u16, 0xBEEF, b);
  EXPECT_EQ(b[0], 0xEF);
  EXPECT_EQ(b[1], 0xBE);
  EXPECT_EQ(DxlControlTable::DecodeRaw(u16, b), 0xBEEF);
  DxlControlTable::EncodeRaw(s32, -2, b);
  EXPECT_EQ(b[0], 0xFE);
  EXPECT_EQ(b[3], 0xFF);
  EXPECT_EQ(DxlControlTable::DecodeRaw(s32, b), -2);
  DxlControlTable::EncodeRaw(dir, -300, b);
  EXPECT_EQ(b[0] | b[1] << 8, 1024 + 300);  // CW: bit 10 set
  EXPECT_EQ(DxlControlTable::DecodeRaw(dir, b), -300);
  const uint8_t ccw[2] = {0x2C, 0x01};  // 300, CCW
  EXPECT_EQ(DxlControlTable::DecodeRaw(dir, ccw), 300);
}

TEST(DxlControlTableTest, SiConversionRoundsAndChecksTheRange) {
  const DxlControlTable t = DxlControlTable::LoadModel("mx-12w");
  const DxlRegister& goal = t.Get(DxlRole::kGoalPosition);
  EXPECT_EQ(DxlControlTable::FromSi(goal, M_PI), 2048);
  EXPECT_EQ(DxlControlTable::FromSi(goal, 100 * kTick + 0.4 * kTick), 100);
  EXPECT_NEAR(DxlControlTable::ToSi(goal, 1024), M_PI / 2, 1e-12);
  EXPECT_FALSE(DxlControlTable::FromSi(goal, -0.01).has_value());
  EXPECT_FALSE(DxlControlTable::FromSi(goal, 2 * M_PI).has_value());  // tick 4096
  EXPECT_FALSE(DxlControlTable::FromSi(goal, std::nan("")).has_value());
  const DxlRegister& speed = t.Get(DxlRole::kProfileVelocity);
  EXPECT_EQ(DxlControlTable::FromSi(speed, 300 * 0.916 * kRpm), 300);
}

}  // namespace
}  // namespace kinevis::hal
