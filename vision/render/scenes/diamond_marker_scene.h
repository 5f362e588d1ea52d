#pragma once

// The DIAMOND eye-surgery robot's tool marker seen by its calibration camera (seed 001, issue 5).
//
// Frames (robots/diamond/diamond_model.h): O is the RCM frame, the marker centre is the tool point
// T at p_O_T = R u on the sphere of radius R; C is the camera frame of camera_model.h. The scene
// holds X_CO, the pose of O in C. It depends on no robot code: the caller passes p_O_T (and the
// tool axis) from robots::ForwardKinematics(), so vision/ stays below robots/ (ARCHITECTURE.md).
//
// The marker: a square plate of side 2 a centred at T whose four quadrants are white / black /
// white / black (an "X-corner", the pattern a checkerboard corner detector finds), on a dark
// background. Why this pattern: seed 001 (§VI) finds its marker with Harris corners; the saddle
// point of an X-corner is a projective invariant point (the crossing of two lines), so its image
// is exactly the projection of T, and Harris + cv::cornerSubPix (issue 8) locate it to a few
// hundredths of a pixel; a bright disc instead would need an ellipse fit, and its centroid is
// biased by perspective. The two white quadrants are point-symmetric about T, so the intensity
// centroid of the plate is T's image up to a second-order perspective bias (≤ 0.21 px measured for
// a = 5 mm at 0.2–0.3 m with the seed's camera, f = 1000 px), which the tests use as a
// detector-independent check.
// The plate faces the camera (its normal points from T to the camera centre), as a marker on the
// tool tip is mounted to face the camera in the seed's set-up; its edges are aligned with the
// image axes (x_P ⟂ normal, in the plane of x_C and the normal).
//
// Radiance: white 0.9, black 0.05, background 0.02 (the darkness around the marker in the seed's
// images); the sphere, links and RCM are not drawn (they are dark and out of the marker's plane).

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <string>

#include "vision/render/renderer.h"

namespace kinevis::vision::render {

// Object ids of this scene.
inline constexpr int kDiamondBackground = 0;
inline constexpr int kDiamondMarkerWhite = 1;
inline constexpr int kDiamondMarkerBlack = 2;

struct DiamondMarkerSceneParameters {
  Eigen::Isometry3d X_CO = Eigen::Isometry3d::Identity();  // pose of the RCM frame O in C
  Eigen::Vector3d p_O_T = Eigen::Vector3d(0.0, 0.0, 0.2);  // marker centre T in O (m)
  double half_side = 0.005;  // a: half the plate's side (m), > 0, < 0.05
  double white = 0.9;        // radiances in [0, 1]
  double black = 0.05;
  double background = 0.02;
  // Empty when usable, otherwise every bad field and its value.
  std::string Validate() const;
};

class DiamondMarkerScene final : public Scene {
 public:
  // Throws std::invalid_argument naming every bad field (Validate()), or when T is not in front
  // of the camera (z_C <= a).
  explicit DiamondMarkerScene(const DiamondMarkerSceneParameters& parameters);

  Hit Trace(const Ray& ray_C) const override;

  const DiamondMarkerSceneParameters& parameters() const { return parameters_; }
  // Ground truth: the marker centre T in C (m); its image is camera.Project(p_C_T()).
  const Eigen::Vector3d& p_C_T() const { return p_C_T_; }
  // Pose of the plate frame P in C: origin T, z_P towards the camera, x_P, y_P along the edges.
  const Eigen::Isometry3d& X_CP() const { return X_CP_; }

 private:
  DiamondMarkerSceneParameters parameters_;
  Eigen::Vector3d p_C_T_;
  Eigen::Isometry3d X_CP_;
};

// The seed's camera placement (seed 001 §III, §V): on the axis of the working region's centre
// (φ, γ) = (π/2, π/4), i.e. at 45° from the base axis z_O, `distance_m` from the RCM, looking at
// the RCM, x_C = x_O (so the image's v axis runs along the meridian of φ = π/2). The seed's optimum
// is 0.4462 m.
Eigen::Isometry3d DiamondCameraPose(double distance_m);

}  // namespace kinevis::vision::render
