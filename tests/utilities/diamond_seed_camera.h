#pragma once

// The DIAMOND seed's calibration camera (seed 001 §V): 1280×640 pixels, f = 1000 px, principal
// point at the centre, no distortion; placed by vision::render::DiamondCameraPose(0.4462).

#include "vision/camera/pinhole_camera.h"

namespace kinevis::testing {

inline vision::PinholeBrownParameters DiamondSeedCamera() {
  vision::PinholeBrownParameters p;
  p.width = 1280;
  p.height = 640;
  p.fx = p.fy = 1000.0;
  p.cx = 639.5;
  p.cy = 319.5;
  return p;
}

}  // namespace kinevis::testing
