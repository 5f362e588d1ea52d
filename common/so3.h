#pragma once

// Rotations (SO(3)) as the whole stack uses them. Header-only, Eigen only.
//
//   Skew(a) * b == a.cross(b)
//   Exp(w): the rotation by |w| about w / |w| (Rodrigues); Exp(0) = I
//   Log(R): the rotation vector w with Exp(w) == R, |w| in [0, pi]

#include <Eigen/Geometry>
#include <cmath>

namespace kinevis::common {

// The cross-product matrix [a]x.
inline Eigen::Matrix3d Skew(const Eigen::Vector3d& a) {
  Eigen::Matrix3d m;
  m << 0, -a.z(), a.y(), a.z(), 0, -a.x(), -a.y(), a.x(), 0;
  return m;
}

// The rotation matrix of the rotation vector w (rad). Exact for every w, including |w| -> 0.
inline Eigen::Matrix3d Exp(const Eigen::Vector3d& w) {
  const double angle = w.norm();
  if (angle < 1e-12) return Eigen::Matrix3d::Identity() + Skew(w);
  return Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
}

// The rotation vector of the rotation matrix R (orthonormal, det +1), |w| in [0, pi].
inline Eigen::Vector3d Log(const Eigen::Matrix3d& R) {
  const Eigen::AngleAxisd aa(R);
  return aa.angle() * aa.axis();
}

}  // namespace kinevis::common
