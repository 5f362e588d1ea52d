#include "common/config_error.h"

#include <cmath>
#include <cstdlib>
#include <limits>
#include <random>

#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace kinevis::common {
namespace {

using ::testing::HasSubstr;

TEST(ProblemsTest, EveryBadFieldIsNamedWithItsValueInOneMessage) {
  Problems p("config/hexapod-sim.yaml");
  p.Positive("drives.counts_per_metre", -1);
  p.NonNegative("perturbation.joint_offset_sigma_mm", std::nan(""));
  p.InRange("modbus.unit", 0, 1, 247);
  p.Finite("scanner.cot_theta_y", std::numeric_limits<double>::infinity());
  p.Add("camera.lens", "5mm", "expected 4mm or 6mm");
  p.Add("drives: missing");
  ASSERT_EQ(p.problems().size(), 6u);
  EXPECT_EQ(p.Message(),
            "drives.counts_per_metre: must be > 0, got -1; "
            "perturbation.joint_offset_sigma_mm: must be >= 0, got nan; "
            "modbus.unit: must be in 1..247, got 0; scanner.cot_theta_y: must be finite, got inf; "
            "camera.lens: expected 4mm or 6mm, got '5mm'; drives: missing");
  try {
    p.ThrowIfAny();
    FAIL() << "no throw";
  } catch (const ConfigError& e) {
    EXPECT_THAT(e.what(), HasSubstr("config/hexapod-sim.yaml: drives.counts_per_metre"));
  }
}

TEST(ProblemsTest, GoodValuesAddNothingAndNothingIsThrown) {
  Problems p("x");
  p.Positive("a", 1e-300);
  p.NonNegative("b", 0.0);
  p.InRange("c", 247, 1, 247);
  p.Finite("d", -1e308);
  EXPECT_TRUE(p.empty());
  EXPECT_EQ(p.Message(), "");
  EXPECT_NO_THROW(p.ThrowIfAny());
}

TEST(ProblemsTest, NanBreaksEveryRule) {
  Problems p;
  const double nan = std::nan("");
  p.Positive("a", nan);
  p.NonNegative("b", nan);
  p.InRange("c", nan, -1e9, 1e9);
  p.Finite("d", nan);
  EXPECT_EQ(p.problems().size(), 4u);
  // No subject: the message is the problems alone.
  EXPECT_THROW(
      {
        try {
          p.ThrowIfAny();
        } catch (const ConfigError& e) {
          EXPECT_EQ(std::string(e.what()).rfind("a: ", 0), 0u);
          throw;
        }
      },
      ConfigError);
}

TEST(NumTest, ReadsBackAsTheSameDoubleAndIsShort) {
  EXPECT_EQ(Num(0.1), "0.1");
  EXPECT_EQ(Num(-1), "-1");
  EXPECT_EQ(Num(1e6), "1e+06");
  EXPECT_EQ(Num(std::nan("")), "nan");
  EXPECT_EQ(Num(-std::numeric_limits<double>::infinity()), "-inf");
  std::mt19937_64 rng(17);
  std::uniform_real_distribution<double> exponent(-300, 300);
  for (int i = 0; i < 2000; ++i) {
    const double v = (i % 2 ? -1 : 1) * std::pow(10.0, exponent(rng));
    EXPECT_EQ(std::strtod(Num(v).c_str(), nullptr), v) << Num(v);
  }
}

}  // namespace
}  // namespace kinevis::common
