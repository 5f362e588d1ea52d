#include "common/check.h"

#include <stdexcept>
#include <string>

#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace kinevis::common {
namespace {

using ::testing::AllOf;
using ::testing::HasSubstr;

int Checked(int x) {
  KINEVIS_DEMAND(x > 0);
  return x;
}

TEST(CheckDeathTest, DemandAbortsWithTheConditionAndFileLineInEveryBuildType) {
  // NDEBUG is defined in the default RelWithDebInfo build: an assert would pass here.
  EXPECT_DEATH(Checked(-1), "internal error.*check_test\\.cc:[0-9]+: x > 0 failed");
  EXPECT_EQ(Checked(3), 3);
}

TEST(CheckDeathTest, DemandMsgAndUnreachableSayWhatBroke) {
  EXPECT_DEATH(KINEVIS_DEMAND_MSG(1 + 1 == 3, std::string("drive ") + "7"),
               "1 \\+ 1 == 3 failed: drive 7");
  EXPECT_DEATH(KINEVIS_UNREACHABLE(), "check_test\\.cc:[0-9]+: unreachable failed");
}

TEST(CheckTest, ThrowUnlessThrowsInvalidArgumentWithTheMessageAndTheCondition) {
  const double speed = -2.0;
  try {
    KINEVIS_THROW_UNLESS(speed > 0, "speed = " + std::to_string(speed) + " must be > 0");
    FAIL() << "no throw";
  } catch (const std::invalid_argument& e) {
    EXPECT_THAT(e.what(), AllOf(HasSubstr("speed = -2.000000 must be > 0"),
                                HasSubstr("speed > 0 failed at"), HasSubstr("check_test.cc:")));
  }
  EXPECT_NO_THROW(KINEVIS_THROW_UNLESS(speed < 0, "never built"));
}

TEST(CheckTest, TheMessageIsBuiltOnlyWhenTheCheckFails) {
  int built = 0;
  auto message = [&] {
    ++built;
    return std::string("m");
  };
  KINEVIS_THROW_UNLESS(true, message());
  EXPECT_EQ(built, 0);
  EXPECT_THROW(KINEVIS_THROW_UNLESS(false, message()), std::invalid_argument);
  EXPECT_EQ(built, 1);
}

}  // namespace
}  // namespace kinevis::common
