#pragma once

// The CiA 402 (IEC 61800-7-201) power drive system state machine, transcribed for the tests
// straight from the specification's two tables, independently of hal/drive/cia402.cc: the host
// (Cia402NextCommand), the device decoder (DecodeCia402Controlword + Cia402ApplyCommand) and the
// simulator (hal/mock/Cia402Device) are all checked against this, so a wrong row in the library's
// kCia402Transitions cannot pass by being compared with itself.
//
// "Device control commands" (controlword bits 7, 3, 2, 1, 0; x = don't care):
//   Shutdown                 0 x 1 1 0
//   Switch on                0 0 1 1 1   (also "Disable operation" in Operation enabled)
//   Enable operation         0 1 1 1 1   (also "Switch on + enable operation")
//   Disable voltage          0 x x 0 x
//   Quick stop               0 x 0 1 x
//   Fault reset              rising edge of bit 7
//
// "State transitions" (the figure): 1 Not ready -> Switch on disabled (automatic); 2 SOD -> Ready
// (Shutdown); 3 Ready -> Switched on (Switch on); 4 Switched on -> Operation enabled (Enable
// operation); 5 Operation enabled -> Switched on (Disable operation); 6 Switched on -> Ready
// (Shutdown); 7 Ready -> SOD (Disable voltage, Quick stop); 8 Operation enabled -> Ready
// (Shutdown); 9 Operation enabled -> SOD (Disable voltage); 10 Switched on -> SOD (Disable
// voltage, Quick stop); 11 Operation enabled -> Quick stop active (Quick stop); 12 Quick stop
// active -> SOD (Disable voltage, or quick stop completed with option code 0..4); 13 any state but
// the fault ones -> Fault reaction active (fault); 14 -> Fault (automatic); 15 Fault -> SOD (Fault
// reset); 16 Quick stop active -> Operation enabled (Enable operation, option codes 5..8 only).
// A command listed for no transition out of a state leaves the state unchanged.

#include <cstdint>
#include <cstdio>
#include <optional>
#include <string>

#include "hal/drive/cia402.h"

namespace kinevis::hal::spec {

enum class Word { kShutdown, kSwitchOn, kEnableOperation, kDisableVoltage, kQuickStop };

inline const char* Name(Word w) {
  switch (w) {
    case Word::kShutdown:
      return "shutdown";
    case Word::kSwitchOn:
      return "switch on";
    case Word::kEnableOperation:
      return "enable operation";
    case Word::kDisableVoltage:
      return "disable voltage";
    case Word::kQuickStop:
      return "quick stop";
  }
  return "?";
}

// The command of a controlword with bit 7 clear, by the table's bit patterns (bits 0..3).
inline Word Classify(uint16_t controlword) {
  const bool b0 = controlword & 1u, b1 = controlword & 2u, b2 = controlword & 4u,
             b3 = controlword & 8u;
  if (!b1) return Word::kDisableVoltage;                 // 0 x x 0 x
  if (!b2) return Word::kQuickStop;                      // 0 x 0 1 x
  if (!b0) return Word::kShutdown;                       // 0 x 1 1 0
  return b3 ? Word::kEnableOperation : Word::kSwitchOn;  // 0 b3 1 1 1
}

// The state after `word` in `from`, by the transitions figure. `resume` is quick stop option code
// 5..8 (transition 16 exists, Quick stop active stays until disabled); nullopt when the word
// changes nothing.
inline std::optional<Cia402State> After(Cia402State from, Word word, bool resume) {
  using S = Cia402State;
  switch (from) {
    case S::kSwitchOnDisabled:
      if (word == Word::kShutdown) return S::kReadyToSwitchOn;  // 2
      return std::nullopt;
    case S::kReadyToSwitchOn:
      if (word == Word::kSwitchOn) return S::kSwitchedOn;               // 3
      if (word == Word::kEnableOperation) return S::kOperationEnabled;  // 3 + 4
      if (word == Word::kDisableVoltage || word == Word::kQuickStop) {
        return S::kSwitchOnDisabled;  // 7
      }
      return std::nullopt;
    case S::kSwitchedOn:
      if (word == Word::kEnableOperation) return S::kOperationEnabled;  // 4
      if (word == Word::kShutdown) return S::kReadyToSwitchOn;          // 6
      if (word == Word::kDisableVoltage || word == Word::kQuickStop) {
        return S::kSwitchOnDisabled;  // 10
      }
      return std::nullopt;
    case S::kOperationEnabled:
      if (word == Word::kSwitchOn) return S::kSwitchedOn;              // 5
      if (word == Word::kShutdown) return S::kReadyToSwitchOn;         // 8
      if (word == Word::kDisableVoltage) return S::kSwitchOnDisabled;  // 9
      if (word == Word::kQuickStop) return S::kQuickStopActive;        // 11
      return std::nullopt;
    case S::kQuickStopActive:
      if (word == Word::kDisableVoltage) return S::kSwitchOnDisabled;             // 12
      if (word == Word::kEnableOperation && resume) return S::kOperationEnabled;  // 16
      return std::nullopt;
    case S::kNotReadyToSwitchOn:
    case S::kFaultReactionActive:
    case S::kFault:
      return std::nullopt;  // 1, 14 are automatic; 15 needs the bit 7 edge
  }
  return std::nullopt;
}

inline std::string Describe(Cia402State from, uint16_t controlword, bool resume) {
  return std::string(ToString(from)) + " + controlword 0x" +
         [&] {
           char text[8];
           std::snprintf(text, sizeof text, "%02X", controlword);
           return std::string(text);
         }() +
         " (" + Name(Classify(controlword)) + ")" + (resume ? ", quick stop option 5..8" : "");
}

}  // namespace kinevis::hal::spec
