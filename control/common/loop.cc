#include "control/common/loop.h"

namespace kinevis::control {

const char* ToString(LawState state) {
  switch (state) {
    case LawState::kRunning:
      return "running";
    case LawState::kHold:
      return "hold";
    case LawState::kDone:
      return "done";
    case LawState::kStop:
      return "stop";
  }
  return "?";
}

const char* ToString(StopAction action) {
  switch (action) {
    case StopAction::kQuickStop:
      return "quick stop";
    case StopAction::kDisable:
      return "disable";
  }
  return "?";
}

const char* ToString(LoopOutcome outcome) {
  switch (outcome) {
    case LoopOutcome::kCompleted:
      return "completed";
    case LoopOutcome::kDriveFault:
      return "drive fault";
    case LoopOutcome::kLawStop:
      return "stopped by the law";
    case LoopOutcome::kLimit:
      return "limit";
    case LoopOutcome::kTimeout:
      return "timeout";
    case LoopOutcome::kNotStarted:
      return "not started";
  }
  return "?";
}

}  // namespace kinevis::control
