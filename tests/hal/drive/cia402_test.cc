#include "hal/drive/cia402.h"

#include <gtest/gtest.h>

#include <set>

#include "tests/hal/drive/cia402_spec_table.h"

namespace kinevis::hal {
namespace {

using S = Cia402State;
using C = Cia402Command;

constexpr S kAllStates[] = {
    S::kNotReadyToSwitchOn, S::kSwitchOnDisabled, S::kReadyToSwitchOn,     S::kSwitchedOn,
    S::kOperationEnabled,   S::kQuickStopActive,  S::kFaultReactionActive, S::kFault};

TEST(Cia402Test, ControlwordsAreTheSpecificationValues) {
  EXPECT_EQ(Cia402Controlword(C::kShutdown), 0x06);
  EXPECT_EQ(Cia402Controlword(C::kSwitchOn), 0x07);
  EXPECT_EQ(Cia402Controlword(C::kEnableOperation), 0x0F);
  EXPECT_EQ(Cia402Controlword(C::kDisableVoltage), 0x00);
  EXPECT_EQ(Cia402Controlword(C::kQuickStop), 0x02);
  EXPECT_EQ(Cia402Controlword(C::kFaultReset), 0x80);
}

TEST(Cia402Test, EveryCommandDecodesBackFromItsControlword) {
  for (C c : {C::kShutdown, C::kSwitchOn, C::kEnableOperation, C::kDisableVoltage, C::kQuickStop}) {
    EXPECT_EQ(DecodeCia402Controlword(Cia402Controlword(c), 0), c) << ToString(c);
  }
  // Fault reset only on the rising edge of bit 7.
  EXPECT_EQ(DecodeCia402Controlword(0x80, 0x00), C::kFaultReset);
  EXPECT_NE(DecodeCia402Controlword(0x80, 0x80), C::kFaultReset);
  // Don't-care bits: halt (8) and the mode-specific bits (4..6) do not change the command.
  EXPECT_EQ(DecodeCia402Controlword(0x010F, 0), C::kEnableOperation);
  EXPECT_EQ(DecodeCia402Controlword(0x001F, 0), C::kEnableOperation);
  // Quick stop is xxxx.x01x whatever bits 0 and 3 say; disable voltage is xxxx.xx0x.
  EXPECT_EQ(DecodeCia402Controlword(0x0B, 0), C::kQuickStop);
  EXPECT_EQ(DecodeCia402Controlword(0x0D, 0), C::kDisableVoltage);
}

TEST(Cia402Test, StatuswordOfEveryStateDecodesToThatState) {
  for (S s : kAllStates) {
    const uint16_t sw = Cia402StatuswordBits(s);
    ASSERT_TRUE(DecodeCia402Statusword(sw).has_value()) << ToString(s);
    EXPECT_EQ(*DecodeCia402Statusword(sw), s) << ToString(s);
    // With every non-state bit set too (warning, remote, target reached, manufacturer bits).
    const uint16_t noise = 0xFF80 & ~0x0040;
    EXPECT_EQ(*DecodeCia402Statusword(sw | noise), s) << ToString(s);
  }
}

TEST(Cia402Test, StatuswordMaskValuePairsFromTheSpecification) {
  EXPECT_EQ(*DecodeCia402Statusword(0x0000), S::kNotReadyToSwitchOn);
  EXPECT_EQ(*DecodeCia402Statusword(0x0040), S::kSwitchOnDisabled);
  EXPECT_EQ(*DecodeCia402Statusword(0x0021), S::kReadyToSwitchOn);
  EXPECT_EQ(*DecodeCia402Statusword(0x0023), S::kSwitchedOn);
  EXPECT_EQ(*DecodeCia402Statusword(0x0027), S::kOperationEnabled);
  EXPECT_EQ(*DecodeCia402Statusword(0x0237), S::kOperationEnabled);  // remote + voltage
  EXPECT_EQ(*DecodeCia402Statusword(0x0007), S::kQuickStopActive);
  EXPECT_EQ(*DecodeCia402Statusword(0x000F), S::kFaultReactionActive);
  EXPECT_EQ(*DecodeCia402Statusword(0x0008), S::kFault);
  EXPECT_FALSE(DecodeCia402Statusword(0x0001).has_value());  // matches no state
}

TEST(Cia402Test, EveryCommandedRowOfTheTransitionTableIsApplied) {
  std::set<int> numbers;
  for (const Cia402Transition& t : kCia402Transitions) {
    numbers.insert(t.number);
    if (t.automatic) continue;
    const bool qs_to_disabled = t.number != 16;
    EXPECT_EQ(Cia402ApplyCommand(t.from, t.command, qs_to_disabled), t.to)
        << "transition " << t.number << " from " << ToString(t.from) << " on "
        << ToString(t.command);
  }
  for (int n = 1; n <= 16; ++n) EXPECT_TRUE(numbers.count(n)) << "transition " << n << " missing";
}

// Every controlword with bit 7 clear (bits 0..3 all 16 ways, with and without the don't-care
// bits 4..6 and halt), in every state, under both quick stop option regimes: the decoder and
// Cia402ApplyCommand give the state of the specification's tables as transcribed in
// cia402_spec_table.h (not the library's kCia402Transitions).
TEST(Cia402Test, DeviceSideFollowsTheSpecificationsTablesForEveryControlword) {
  for (S from : kAllStates) {
    for (bool resume : {false, true}) {
      for (uint16_t low = 0; low < 16; ++low) {
        for (uint16_t extra : {0x0000, 0x0170}) {
          const uint16_t cw = low | extra;
          const S expected = spec::After(from, spec::Classify(low), resume).value_or(from);
          EXPECT_EQ(Cia402ApplyCommand(from, DecodeCia402Controlword(cw, cw), !resume), expected)
              << spec::Describe(from, cw, resume);
        }
      }
    }
  }
  // Transition 15 on the rising edge of bit 7 only.
  EXPECT_EQ(Cia402ApplyCommand(S::kFault, DecodeCia402Controlword(0x80, 0x00)),
            S::kSwitchOnDisabled);
  EXPECT_EQ(Cia402ApplyCommand(S::kFault, DecodeCia402Controlword(0x80, 0x80)), S::kFault);
}

// The library's table says the same as the specification, row by row.
TEST(Cia402Test, EveryRowOfTheLibrarysTableIsInTheSpecification) {
  for (const Cia402Transition& t : kCia402Transitions) {
    SCOPED_TRACE(::testing::Message() << "row: transition " << t.number << " " << ToString(t.from)
                                      << " -> " << ToString(t.to));
    if (t.automatic) {
      switch (t.number) {
        case 1:
          EXPECT_EQ(t.from, S::kNotReadyToSwitchOn);
          EXPECT_EQ(t.to, S::kSwitchOnDisabled);
          break;
        case 12:
          EXPECT_EQ(t.from, S::kQuickStopActive);
          EXPECT_EQ(t.to, S::kSwitchOnDisabled);
          break;
        case 13:
          EXPECT_NE(t.from, S::kFault);
          EXPECT_NE(t.from, S::kFaultReactionActive);
          EXPECT_EQ(t.to, S::kFaultReactionActive);
          break;
        case 14:
          EXPECT_EQ(t.from, S::kFaultReactionActive);
          EXPECT_EQ(t.to, S::kFault);
          break;
        default:
          ADD_FAILURE() << "transition " << t.number << " is not automatic in the specification";
      }
      continue;
    }
    if (t.command == C::kFaultReset) {
      EXPECT_EQ(t.number, 15);
      EXPECT_EQ(t.from, S::kFault);
      EXPECT_EQ(t.to, S::kSwitchOnDisabled);
      continue;
    }
    const spec::Word word = spec::Classify(Cia402Controlword(t.command));
    EXPECT_EQ(spec::After(t.from, word, t.number == 16).value_or(t.from), t.to) << spec::Name(word);
  }
}

// The host never sends a word that the specification makes do nothing in the drive's state.
TEST(Cia402Test, HostCommandsAreTransitionsOfTheSpecification) {
  for (S target : {S::kOperationEnabled, S::kSwitchOnDisabled, S::kSwitchedOn, S::kReadyToSwitchOn,
                   S::kQuickStopActive}) {
    for (S from : kAllStates) {
      const C c = Cia402NextCommand(from, target);
      if (c == C::kNone) continue;
      if (c == C::kFaultReset) {
        EXPECT_EQ(from, S::kFault) << "fault reset towards " << ToString(target);
        continue;
      }
      const spec::Word word = spec::Classify(Cia402Controlword(c));
      EXPECT_TRUE(spec::After(from, word, false).has_value())
          << ToString(from) << " towards " << ToString(target) << ": host sends "
          << spec::Name(word);
    }
  }
}

TEST(Cia402Test, CommandsThatDoNotApplyLeaveTheStateAlone) {
  EXPECT_EQ(Cia402ApplyCommand(S::kSwitchOnDisabled, C::kEnableOperation), S::kSwitchOnDisabled);
  EXPECT_EQ(Cia402ApplyCommand(S::kFault, C::kShutdown), S::kFault);
  EXPECT_EQ(Cia402ApplyCommand(S::kFaultReactionActive, C::kFaultReset), S::kFaultReactionActive);
  // Quick stop option code 0..4: Enable operation does not resume (no transition 16).
  EXPECT_EQ(Cia402ApplyCommand(S::kQuickStopActive, C::kEnableOperation, true),
            S::kQuickStopActive);
}

// Following Cia402NextCommand from every state reaches every reachable target in a few steps.
TEST(Cia402Test, HostSequencingReachesEveryTarget) {
  for (S target :
       {S::kOperationEnabled, S::kSwitchOnDisabled, S::kSwitchedOn, S::kReadyToSwitchOn}) {
    for (S start : kAllStates) {
      S s = start;
      int steps = 0;
      while (s != target && steps < 8) {
        if (s == S::kNotReadyToSwitchOn) {
          s = S::kSwitchOnDisabled;  // automatic transition 1
        } else if (s == S::kFaultReactionActive) {
          s = S::kFault;  // automatic transition 14
        } else {
          C c = Cia402NextCommand(s, target);
          ASSERT_NE(c, C::kNone) << ToString(s) << " -> " << ToString(target);
          s = Cia402ApplyCommand(s, c);
        }
        ++steps;
      }
      EXPECT_EQ(s, target) << "from " << ToString(start);
      EXPECT_LE(steps, 5);
    }
  }
  EXPECT_EQ(Cia402NextCommand(S::kOperationEnabled, S::kQuickStopActive), C::kQuickStop);
  EXPECT_EQ(Cia402NextCommand(S::kFaultReactionActive, S::kOperationEnabled), C::kNone);
}

TEST(Cia402Test, Modes) {
  for (int v : {1, 3, 4, 8, 9, 10}) {
    auto m = DriveModeFromValue(v);
    ASSERT_TRUE(m.has_value()) << v;
    EXPECT_EQ(static_cast<int>(*m), v);
  }
  for (int v : {0, 2, 5, 6, 7, 11, -1}) EXPECT_FALSE(DriveModeFromValue(v).has_value()) << v;
  EXPECT_TRUE(IsCyclicMode(DriveMode::kCyclicSynchronousTorque));
  EXPECT_FALSE(IsCyclicMode(DriveMode::kProfilePosition));
  EXPECT_TRUE(IsPositionMode(DriveMode::kCyclicSynchronousPosition));
  EXPECT_TRUE(IsVelocityMode(DriveMode::kProfileVelocity));
  EXPECT_TRUE(IsTorqueMode(DriveMode::kProfileTorque));
}

}  // namespace
}  // namespace kinevis::hal
