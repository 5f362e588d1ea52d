#include "vision/render/primitives.h"

#include <algorithm>
#include <cmath>

namespace kinevis::vision::render {

double IntersectPlane(const Ray& ray, const Eigen::Vector3d& point, const Eigen::Vector3d& n,
                      double t_min, Eigen::Vector3d* normal) {
  const double denom = n.dot(ray.d_C);
  if (std::abs(denom) < 1e-15) return kNoHit;
  const double t = n.dot(point - ray.p_C_O) / denom;
  if (!(t > t_min)) return kNoHit;
  if (normal) *normal = denom < 0.0 ? n : Eigen::Vector3d(-n);
  return t;
}

double IntersectSphere(const Ray& ray, const Eigen::Vector3d& centre, double radius, double t_min,
                       Eigen::Vector3d* normal) {
  // |p + t d − c|² = r² with |d| = 1: t² + 2 b t + c = 0.
  const Eigen::Vector3d oc = ray.p_C_O - centre;
  const double b = oc.dot(ray.d_C);
  const double c = oc.squaredNorm() - radius * radius;
  const double disc = b * b - c;
  if (disc < 0.0) return kNoHit;
  const double s = std::sqrt(disc);
  // The near root without cancellation: q = −(b + sign(b) s), roots q and c/q.
  double t0 = -b - s, t1 = -b + s;
  if (b < 0.0) {
    const double q = -b + s;
    t1 = q;
    t0 = q != 0.0 ? c / q : 0.0;
  }
  const double t = t0 > t_min ? t0 : (t1 > t_min ? t1 : kNoHit);
  if (t != kNoHit && normal) *normal = (oc + t * ray.d_C) / radius;
  return t;
}

double IntersectCylinder(const Ray& ray, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                         double radius, double t_min, Eigen::Vector3d* normal) {
  const Eigen::Vector3d axis = b - a;
  const double length = axis.norm();
  if (!(length > 0.0)) return kNoHit;
  const Eigen::Vector3d w = axis / length;
  // Components perpendicular to the axis: |(oa + t d)⊥|² = r².
  const Eigen::Vector3d oa = ray.p_C_O - a;
  const Eigen::Vector3d d_perp = ray.d_C - ray.d_C.dot(w) * w;
  const Eigen::Vector3d o_perp = oa - oa.dot(w) * w;
  const double A = d_perp.squaredNorm();
  if (A < 1e-18) return kNoHit;  // ray parallel to the axis: it only meets the (absent) caps
  const double B = o_perp.dot(d_perp);
  const double C = o_perp.squaredNorm() - radius * radius;
  const double disc = B * B - A * C;
  if (disc < 0.0) return kNoHit;
  const double s = std::sqrt(disc);
  for (const double t : {(-B - s) / A, (-B + s) / A}) {
    if (!(t > t_min)) continue;
    const double along = (oa + t * ray.d_C).dot(w);
    if (along < 0.0 || along > length) continue;
    if (normal) *normal = (o_perp + t * d_perp) / radius;
    return t;
  }
  return kNoHit;
}

double IntersectBox(const Ray& ray, const Eigen::Isometry3d& X_CB, const Eigen::Vector3d& half,
                    double t_min, Eigen::Vector3d* normal) {
  const Eigen::Matrix3d R_BC = X_CB.linear().transpose();
  const Eigen::Vector3d o = R_BC * (ray.p_C_O - X_CB.translation());
  const Eigen::Vector3d d = R_BC * ray.d_C;
  double t_near = -kNoHit, t_far = kNoHit;
  int near_axis = -1, far_axis = -1;
  for (int i = 0; i < 3; ++i) {
    if (std::abs(d[i]) < 1e-15) {
      if (std::abs(o[i]) > half[i]) return kNoHit;
      continue;
    }
    double t0 = (-half[i] - o[i]) / d[i];
    double t1 = (half[i] - o[i]) / d[i];
    if (t0 > t1) std::swap(t0, t1);
    if (t0 > t_near) {
      t_near = t0;
      near_axis = i;
    }
    if (t1 < t_far) {
      t_far = t1;
      far_axis = i;
    }
    if (t_near > t_far) return kNoHit;
  }
  double t = kNoHit;
  int axis = -1;
  if (t_near > t_min) {
    t = t_near;
    axis = near_axis;
  } else if (t_far > t_min) {
    t = t_far;
    axis = far_axis;
  }
  if (t == kNoHit || axis < 0) return kNoHit;
  if (normal) {
    Eigen::Vector3d n_B = Eigen::Vector3d::Zero();
    n_B[axis] = (o[axis] + t * d[axis]) > 0.0 ? 1.0 : -1.0;
    *normal = X_CB.linear() * n_B;
  }
  return t;
}

double IntersectDisc(const Ray& ray, const Eigen::Vector3d& centre, const Eigen::Vector3d& n,
                     double radius, double t_min, Eigen::Vector3d* normal) {
  const double t = IntersectPlane(ray, centre, n, t_min, normal);
  if (t == kNoHit) return kNoHit;
  return (ray.p_C_O + t * ray.d_C - centre).squaredNorm() <= radius * radius ? t : kNoHit;
}

}  // namespace kinevis::vision::render
