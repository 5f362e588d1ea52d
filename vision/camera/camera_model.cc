#include "vision/camera/camera_model.h"

namespace kinevis::vision {

std::string_view ToString(ProjectionStatus status) {
  switch (status) {
    case ProjectionStatus::kOk:
      return "ok";
    case ProjectionStatus::kBehindCamera:
      return "behind camera";
    case ProjectionStatus::kOutsideDomain:
      return "outside model domain";
    case ProjectionStatus::kNoConvergence:
      return "no convergence";
  }
  return "unknown projection status";
}

}  // namespace kinevis::vision
