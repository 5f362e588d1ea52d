#pragma once

// Ground-truth stripe pixels of a simulated laser scene, for tests, experiments and simulated
// datasets when no stripe extractor is run: the scene's exact stripe (LaserScene::StripeCurve)
// projected through the camera and sampled the way a column/row-wise extractor reports it — the
// rotating laser's stripe (running across the image) at every integer column u, the fixed
// laser's (running down it) at every integer row v, the other coordinate interpolated on the
// projected curve. Samples where the projected curve jumps by more than 1 px between curve
// points (a step of the surface) or leaves the image are left out. Noise is the caller's.

#include <Eigen/Core>
#include <vector>

#include "vision/camera/camera_model.h"
#include "vision/render/scenes/laser_scene.h"

namespace kinevis::calibration {

// `spacing` (m, > 0): the curve's sampling along the stripe (0.1 mm resolves < 0.05 px here).
std::vector<Eigen::Vector2d> ExactStripePixels(const vision::render::LaserScene& scene,
                                               const vision::CameraModel& camera,
                                               vision::render::LaserId id, double spacing = 1e-4);

}  // namespace kinevis::calibration
