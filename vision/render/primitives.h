#pragma once

// Ray–surface intersections for the renderer's scenes. All quantities in one frame (the caller's;
// usually the camera frame C), metres. Each returns the smallest ray parameter t > t_min at which
// the ray p + t d (d unit) meets the surface, or +infinity when it does not, and the outward unit
// normal there when `normal` is not null. Pure functions, no allocation.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <limits>

#include "vision/camera/camera_model.h"

namespace kinevis::vision::render {

inline constexpr double kNoHit = std::numeric_limits<double>::infinity();

// The plane through `point` with unit normal `n` (two-sided; the returned normal faces the ray).
double IntersectPlane(const Ray& ray, const Eigen::Vector3d& point, const Eigen::Vector3d& n,
                      double t_min = 1e-9, Eigen::Vector3d* normal = nullptr);

// A sphere (outside only: a ray starting inside gets the exit point).
double IntersectSphere(const Ray& ray, const Eigen::Vector3d& centre, double radius,
                       double t_min = 1e-9, Eigen::Vector3d* normal = nullptr);

// A finite cylinder of `radius` around the segment a→b, without end caps (the hexapod's legs:
// their caps are hidden in the joints). Normal is radial.
double IntersectCylinder(const Ray& ray, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                         double radius, double t_min = 1e-9, Eigen::Vector3d* normal = nullptr);

// A solid box: pose X_CB of the box frame (origin at the box centre, axes along its edges) and
// its half extents (m). Slab method; the normal is that of the face hit.
double IntersectBox(const Ray& ray, const Eigen::Isometry3d& X_CB, const Eigen::Vector3d& half,
                    double t_min = 1e-9, Eigen::Vector3d* normal = nullptr);

// A disc: centre, unit normal, radius (a marker, the mirror's rim seen from below).
double IntersectDisc(const Ray& ray, const Eigen::Vector3d& centre, const Eigen::Vector3d& n,
                     double radius, double t_min = 1e-9, Eigen::Vector3d* normal = nullptr);

}  // namespace kinevis::vision::render
