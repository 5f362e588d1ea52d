#pragma once

// Seed 002 figs. 6 and 8: the estimated attachment points re-projected onto a camera image.
// OpenCV is used in the .cc only.

#include <string>

#include "calibration/hexapod/leg_calibration.h"
#include "robots/hexapod/hexapod_model.h"
#include "vision/camera/camera_model.h"
#include "vision/image/image_view.h"

namespace kinevis::calibration {

// Writes a colour PNG of `image` (8-bit grey, the camera's size) with, for every leg j:
//   - a yellow circle (radius 8 px) at the projection of the estimated A_j (result.p_C_A[j]),
//   - a cyan cross at the projection of the CAD point mapped by the rigid fit, X_CB · cad.p_B_A[j]
//     (only when result.rigid_fit),
//   - the label "j" next to the circle,
// and a legend line. Points that do not project (behind the camera, outside the model's domain)
// are listed in the legend as "not shown". Throws std::invalid_argument when the image is empty or
// its size differs from the camera's, std::runtime_error naming `path` when it cannot be written.
void WriteReprojectionImage(const std::string& path, const vision::ImageView8& image,
                            const vision::CameraModel& camera,
                            const HexapodCalibrationResult& result,
                            const robots::HexapodModel& cad);

}  // namespace kinevis::calibration
