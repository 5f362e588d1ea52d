#pragma once

// The renderer's benchmark scenes (issue 5), shared by render_bench (time per frame) and
// render_frames (instructions per frame under callgrind), so that both measure the same frames.

#include <memory>
#include <string>
#include <vector>

#include "robots/hexapod/hexapod_model.h"
#include "vision/camera/hyperbolic_mirror_camera.h"
#include "vision/camera/pinhole_camera.h"
#include "vision/camera/tsai_camera.h"
#include "vision/camera/unified_camera.h"
#include "vision/render/renderer.h"
#include "vision/render/scenes/diamond_marker_scene.h"
#include "vision/render/scenes/hexapod_scene.h"
#include "vision/render/scenes/laser_scene.h"
#include "vision/render/scenes/soccer_field_scene.h"
#include "vision/render/scenes/target_scene.h"

namespace kinevis::vision::render::bench {

struct BenchScene {
  std::unique_ptr<CameraModel> camera;
  std::unique_ptr<Scene> scene;
};

inline const std::vector<std::string>& BenchSceneNames() {
  static const std::vector<std::string> names = {
      "hexapod-perspective", "hexapod-unified", "chessboard", "soccer", "laser", "diamond"};
  return names;
}

inline PinholeBrownParameters Pinhole(int width, int height, double f) {
  PinholeBrownParameters p;
  p.width = width;
  p.height = height;
  p.fx = p.fy = f;
  p.cx = 0.5 * (width - 1);
  p.cy = 0.5 * (height - 1);
  return p;
}

// One of BenchSceneNames(); null members for another name.
inline BenchScene MakeBenchScene(const std::string& name) {
  BenchScene out;
  if (name == "hexapod-perspective") {
    // The perspective camera outside the legs, 1 m from the axis, looking at mid-height.
    out.camera = std::make_unique<PinholeBrownCamera>(Pinhole(640, 480, 500.0));
    out.scene = std::make_unique<HexapodScene>(
        robots::HexapodModel::Default(), robots::HexapodModel::NominalPose(),
        CameraLookingAt(Eigen::Vector3d(1.0, 0.25, 0.3), Eigen::Vector3d(0.0, 0.0, 0.2),
                        Eigen::Vector3d::UnitZ())
            .inverse());
  } else if (name == "hexapod-unified") {
    // The unified camera at the base centre, 3 cm above the base, mirror axis up.
    out.camera = std::make_unique<UnifiedCamera>(UnifiedParameters::Default());
    Eigen::Isometry3d X_CB = Eigen::Isometry3d::Identity();
    X_CB.translation() = Eigen::Vector3d(0.0, 0.0, -0.03);
    out.scene = std::make_unique<HexapodScene>(robots::HexapodModel::Default(),
                                               robots::HexapodModel::NominalPose(), X_CB);
  } else if (name == "chessboard") {
    out.camera = std::make_unique<PinholeBrownCamera>(Pinhole(640, 480, 500.0));
    Eigen::Isometry3d X_CT = Eigen::Isometry3d::Identity();
    X_CT.translation() = Eigen::Vector3d(-0.12, -0.09, 0.6);
    out.scene = std::make_unique<TargetScene>(TargetSpec{}, X_CT);
  } else if (name == "soccer") {
    // Seed 000's robot camera: the soccer field through the hyperbolic mirror (640×480).
    auto camera =
        std::make_unique<HyperbolicMirrorCamera>(HyperbolicMirrorParameters::Seed000Lens4mm());
    SoccerFieldSceneParameters p;
    p.robot_x = 1.2;
    p.robot_y = -0.7;
    p.robot_heading = 0.4;
    out.scene = std::make_unique<SoccerFieldScene>(*camera, p);
    out.camera = std::move(camera);
  } else if (name == "laser") {
    // Seed 004's scanner: both stripes on the blade with pits, full 1616×1216 Tsai frame.
    out.camera = std::make_unique<TsaiCamera>(TsaiParameters::Seed004());
    LaserSceneParameters p;
    p.curvature_xx = 2.0;
    p.pits = {CavitationPit{Eigen::Vector2d(0.01, 0.0), 1.0e-3, 3e-3},
              CavitationPit{Eigen::Vector2d(-0.02, 0.015), 0.5e-3, 2e-3}};
    out.scene = std::make_unique<LaserScene>(p);
  } else if (name == "diamond") {
    // Seed 001's marker camera (1280×640 pinhole, f = 1000 px) at 45°, 0.45 m from the RCM.
    out.camera = std::make_unique<PinholeBrownCamera>(Pinhole(1280, 640, 1000.0));
    DiamondMarkerSceneParameters p;
    p.X_CO = DiamondCameraPose(0.45);  // the pose of O in C, as its header says
    p.p_O_T = Eigen::Vector3d(0.0, 0.1414, 0.1414);
    out.scene = std::make_unique<DiamondMarkerScene>(p);
  }
  return out;
}

// With sensor effects: noise σ = 2 grey levels, vignetting 0.2, exposure 1.1.
inline RenderOptions BenchOptions(bool sensor_effects) {
  RenderOptions options;
  if (sensor_effects) {
    options.noise_sigma = 2.0;
    options.vignetting = 0.2;
    options.exposure = 1.1;
  }
  return options;
}

}  // namespace kinevis::vision::render::bench
