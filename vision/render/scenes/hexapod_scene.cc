#include "vision/render/scenes/hexapod_scene.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#include <sstream>
#include <stdexcept>

#include "common/check.h"
#include "vision/render/primitives.h"

namespace kinevis::vision::render {
namespace {

bool InUnitRange(double x) { return std::isfinite(x) && x >= 0.0 && x <= 1.0; }

}  // namespace

std::string HexapodSceneOptions::Validate() const {
  std::ostringstream bad;
  const char* sep = "";
  auto add = [&](const char* field, double value, const char* why) {
    bad << sep << field << " = " << value << " (" << why << ")";
    sep = "; ";
  };
  if (!std::isfinite(plate_margin) || plate_margin < 0.0)
    add("plate_margin", plate_margin, "must be finite and >= 0");
  if (!InUnitRange(background_radiance))
    add("background_radiance", background_radiance, "must be in [0, 1]");
  if (!InUnitRange(leg_ambient)) add("leg_ambient", leg_ambient, "must be in [0, 1]");
  if (!InUnitRange(leg_diffuse)) add("leg_diffuse", leg_diffuse, "must be in [0, 1]");
  if (InUnitRange(leg_ambient) && InUnitRange(leg_diffuse) && leg_ambient + leg_diffuse > 1.0)
    add("leg_ambient + leg_diffuse", leg_ambient + leg_diffuse, "must be <= 1");
  if (!InUnitRange(plate_radiance)) add("plate_radiance", plate_radiance, "must be in [0, 1]");
  if (!light_direction_B.allFinite() || light_direction_B.norm() == 0.0) {
    bad << sep << "light_direction_B = (" << light_direction_B.transpose()
        << ") (must be finite and non-zero)";
    sep = "; ";
  }
  const std::string message = bad.str();
  return message.empty() ? message : "invalid hexapod scene options: " + message;
}

Eigen::Isometry3d CameraLookingAt(const Eigen::Vector3d& eye_W, const Eigen::Vector3d& target_W,
                                  const Eigen::Vector3d& up_W) {
  const Eigen::Vector3d z = (target_W - eye_W).normalized();
  const Eigen::Vector3d x = z.cross(up_W);  // image right = forward × up (y is down)
  KINEVIS_DEMAND_MSG(x.norm() > 1e-12 && z.allFinite(),
                     "CameraLookingAt: degenerate eye/target/up");
  Eigen::Isometry3d X_WC = Eigen::Isometry3d::Identity();
  X_WC.linear().col(0) = x.normalized();
  X_WC.linear().col(2) = z;
  X_WC.linear().col(1) = z.cross(X_WC.linear().col(0));
  X_WC.translation() = eye_W;
  return X_WC;
}

// Seed 002 eq. (3), checked here rather than copied: with the axis' binormalised Plücker
// coordinates (u, n̲, n) — u the unit direction, n̲ n = h × u for h the foot of the perpendicular
// from the viewpoint to the axis, so n = |h| — one has u × n̲ = h / |h|, and the planes
//   n1 = cos θ n̲ − sin θ (u × n̲),  n2 = −cos θ n̲ − sin θ (u × n̲),  sin θ = R / n
// contain u (n_k · u = 0) and pass at distance |n_k · h| = sin θ · n = R from the axis, i.e.
// they are the two planes through the viewpoint tangent to the cylinder. The equation as printed
// is consistent; the test checks the tangency numerically.
bool PredictCylinderLimbs(const Eigen::Vector3d& p_C_A, const Eigen::Vector3d& p_C_B, double radius,
                          Eigen::Vector3d* n1_C, Eigen::Vector3d* n2_C) {
  const Eigen::Vector3d axis = p_C_B - p_C_A;
  const double length = axis.norm();
  if (!(length > 0.0) || !(radius > 0.0)) return false;
  const Eigen::Vector3d u = axis / length;
  const Eigen::Vector3d h = p_C_A - p_C_A.dot(u) * u;  // foot of the perpendicular from 0
  const double n = h.norm();
  if (!(n > radius)) return false;  // viewpoint inside the cylinder: no tangent plane
  const Eigen::Vector3d n_unit = h.cross(u) / n;
  const Eigen::Vector3d u_cross_n = u.cross(n_unit);  // = h / n
  const double sin_theta = radius / n;
  const double cos_theta = std::sqrt(n * n - radius * radius) / n;  // ᵐz / ᵐn
  *n1_C = cos_theta * n_unit - sin_theta * u_cross_n;
  *n2_C = -cos_theta * n_unit - sin_theta * u_cross_n;
  return true;
}

HexapodScene::HexapodScene(const robots::HexapodModel& model, const Eigen::Isometry3d& X_BP,
                           const Eigen::Isometry3d& X_CB, const HexapodSceneOptions& options)
    : options_(options), radius_(model.leg_radius) {
  std::ostringstream bad;
  const char* sep = "";
  const std::string options_message = options_.Validate();
  if (!options_message.empty()) {
    bad << options_message;
    sep = "; ";
  }
  if (!std::isfinite(model.leg_radius) || model.leg_radius <= 0.0) {
    bad << sep << "leg_radius = " << model.leg_radius << " (must be finite and > 0)";
    sep = "; ";
  }
  if (!X_BP.matrix().allFinite()) {
    bad << sep << "X_BP is not finite";
    sep = "; ";
  }
  if (!X_CB.matrix().allFinite()) {
    bad << sep << "X_CB is not finite";
    sep = "; ";
  }
  double base_extent = 0.0, platform_extent = 0.0;
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    const Eigen::Vector3d& p_B_A = model.p_B_A[j];
    const Eigen::Vector3d& p_P_B = model.p_P_B[j];
    if (!p_B_A.allFinite() || !p_P_B.allFinite()) {
      bad << sep << "leg " << j << ": joint centres not finite (p_B_A = (" << p_B_A.transpose()
          << "), p_P_B = (" << p_P_B.transpose() << "))";
      sep = "; ";
      continue;
    }
    Leg& leg = legs_[j];
    leg.a = X_CB * p_B_A;
    leg.b = X_CB * (X_BP * p_P_B);
    leg.length = (leg.b - leg.a).norm();
    if (!(leg.length > 0.0)) {
      bad << sep << "leg " << j << ": A_j and B_j coincide at this pose (length 0)";
      sep = "; ";
      continue;
    }
    leg.w = (leg.b - leg.a) / leg.length;
    leg.m0 = leg.w.cross(-leg.a);
    base_extent = std::max(base_extent, p_B_A.head<2>().norm());
    platform_extent = std::max(platform_extent, p_P_B.head<2>().norm());
  }
  const std::string message = bad.str();
  if (!message.empty()) throw std::invalid_argument("hexapod scene: " + message);

  light_C_ = X_CB.linear() * options_.light_direction_B.normalized();
  for (Leg& leg : legs_) {
    const Eigen::Vector3d oa = -leg.a;
    leg.along0 = oa.dot(leg.w);
    leg.o_perp = oa - leg.along0 * leg.w;
    leg.c0 = leg.o_perp.squaredNorm() - radius_ * radius_;
  }
  const Eigen::Isometry3d X_CP = X_CB * X_BP;
  // Where each leg ends (header): the plate planes when the plates are on. A plate nearly parallel
  // to a leg's axis (|n · w| < 1e-6: no sensible flush end) keeps the perpendicular cut.
  for (Leg& leg : legs_) {
    const Eigen::Vector3d middle = 0.5 * (leg.a + leg.b);
    leg.cut_normal[0] = -leg.w;
    leg.cut_offset[0] = -leg.w.dot(leg.a);
    leg.cut_normal[1] = leg.w;
    leg.cut_offset[1] = leg.w.dot(leg.b);
    leg.along_lo = 0.0;
    leg.along_hi = leg.length;
    const bool on[2] = {options_.base_plate, options_.platform_plate};
    const Eigen::Isometry3d* X_CF[2] = {&X_CB, &X_CP};
    for (int k = 0; k < 2; ++k) {
      const Eigen::Vector3d normal = X_CF[k]->linear().col(2);
      const Eigen::Vector3d centre = X_CF[k]->translation();
      const double n_dot_w = normal.dot(leg.w);
      if (!on[k] || std::abs(n_dot_w) < 1e-6) continue;
      // Keep the side of the plane the leg's middle is on.
      const double side = normal.dot(middle - centre) >= 0.0 ? 1.0 : -1.0;
      leg.cut_normal[k] = -side * normal;
      leg.cut_offset[k] = -side * normal.dot(centre);
      // The axis meets the plane at along = s; the elliptic end spans s ± R tan φ along the axis,
      // tan φ = sqrt(1 − (n · w)²) / |n · w|.
      const double s_axis = normal.dot(centre - leg.a) / n_dot_w;
      // A leg at a grazing angle to its plate would reach far along it (R tan φ: 0.2 m at 5.7°);
      // a real leg ends in its joint housing, so the end is also cut perpendicularly at most one
      // radius beyond the plane's crossing.
      const double spread = std::min(
          radius_, radius_ * std::sqrt(std::max(0.0, 1.0 - n_dot_w * n_dot_w)) / std::abs(n_dot_w));
      // And never more than one radius beyond the joint centre: a leg nearly parallel to its plate,
      // whose joint is a fraction of a millimetre off the plate's plane (a perturbed robot),
      // would otherwise cross the plane far beyond the joint.
      if (k == 0) {
        leg.along_lo = std::max(-radius_, s_axis - spread);
      } else {
        leg.along_hi = std::min(leg.length + radius_, s_axis + spread);
      }
    }
  }
  base_.centre = X_CB.translation();
  base_.normal = X_CB.linear().col(2);
  base_.radius = base_extent + options_.plate_margin;
  platform_.centre = X_CP.translation();
  platform_.normal = X_CP.linear().col(2);
  platform_.radius = platform_extent + options_.plate_margin;
  base_.n_dot_c = base_.normal.dot(base_.centre);
  platform_.n_dot_c = platform_.normal.dot(platform_.centre);
  // Bounding cones from the origin of C (the viewpoint of every central camera): the cone of
  // directions towards a sphere of radius ρ at distance D has half-angle asin(ρ / D). A small
  // relative margin keeps grazing rays exact.
  auto cone = [](const Eigen::Vector3d& centre, double rho, Eigen::Vector3d* axis, double* cos) {
    const double distance = centre.norm();
    rho *= 1.0 + 1e-6;
    if (distance <= rho) {
      *axis = Eigen::Vector3d::UnitZ();
      *cos = -1.0;
      return;
    }
    *axis = centre / distance;
    *cos = std::sqrt(1.0 - (rho / distance) * (rho / distance));
  };
  for (Leg& leg : legs_) {
    cone(leg.a + 0.5 * (leg.along_lo + leg.along_hi) * leg.w,
         std::hypot(0.5 * (leg.along_hi - leg.along_lo), radius_), &leg.cone_axis, &leg.cone_cos);
  }
  cone(base_.centre, base_.radius, &base_.cone_axis, &base_.cone_cos);
  cone(platform_.centre, platform_.radius, &platform_.cone_axis, &platform_.cone_cos);
  for (int k = 0; k < kCones; ++k) {
    const Eigen::Vector3d& axis = k < robots::kHexapodLegs    ? legs_[k].cone_axis
                                  : k == robots::kHexapodLegs ? base_.cone_axis
                                                              : platform_.cone_axis;
    cone_x_[k] = axis.x();
    cone_y_[k] = axis.y();
    cone_z_[k] = axis.z();
    cone_cos_[k] = k < robots::kHexapodLegs    ? legs_[k].cone_cos
                   : k == robots::kHexapodLegs ? base_.cone_cos
                                               : platform_.cone_cos;
  }
  if (!options_.base_plate) cone_cos_[robots::kHexapodLegs] = 2.0;  // never inside
  if (!options_.platform_plate) cone_cos_[robots::kHexapodLegs + 1] = 2.0;
}

bool HexapodScene::PredictLegLimbs(int leg, Eigen::Vector3d* n1_C, Eigen::Vector3d* n2_C) const {
  return PredictCylinderLimbs(legs_[leg].a, legs_[leg].b, radius_, n1_C, n2_C);
}

bool HexapodScene::InsideCuts(const Leg& leg, const Eigen::Vector3d& p_C) {
  return leg.cut_normal[0].dot(p_C) <= leg.cut_offset[0] &&
         leg.cut_normal[1].dot(p_C) <= leg.cut_offset[1];
}

inline __attribute__((always_inline)) int HexapodScene::TracePlate(const Plate& plate, int id,
                                                                   const Eigen::Vector3d& o,
                                                                   const Eigen::Vector3d& d,
                                                                   bool central_at_origin,
                                                                   double* t_best) const {
  // Two-sided disc (IntersectDisc, inlined: this runs for every pixel).
  // (The bounding cone was tested by the caller.)
  const double denom = plate.normal.dot(d);
  if (std::abs(denom) < 1e-15) return 0;
  // For a ray from the origin normal · o is 0 exactly.
  const double num = central_at_origin ? plate.n_dot_c : plate.n_dot_c - plate.normal.dot(o);
  // t = num / denom must lie in (1e-9, t_best): tested without dividing first. A ray moving away
  // from the plane (num and denom of opposite signs, or num = 0) fails the first test: rejected
  // before it (half the rays for each plate).
  if (!(num * denom > 0.0)) return 0;
  const double sign = denom > 0.0 ? 1.0 : -1.0;
  if (!(sign * num > 1e-9 * sign * denom) || !(sign * num < *t_best * sign * denom)) return 0;
  const double t = num / denom;
  if ((o + t * d - plate.centre).squaredNorm() > plate.radius * plate.radius) return 0;
  *t_best = t;
  return id;
}

inline __attribute__((always_inline)) Hit HexapodScene::TraceRay(const Eigen::Vector3d& o,
                                                                 const Eigen::Vector3d& d,
                                                                 bool central_at_origin) const {
  const double r2 = radius_ * radius_;
  double t_best = kNoHit;
  int best = 0;
  // Which bounding cones contain the ray (all, for a ray from elsewhere than the origin).
  unsigned inside = (1u << kCones) - 1;
  if (central_at_origin) {
    inside = 0;
#if defined(__SSE2__)
    // Two cones per instruction (the same products and sums as the scalar loop below, so the
    // same bits); kCones is even and the arrays 16-byte aligned. Issue 5: a third of the time.
    static_assert(kCones % 2 == 0, "cones are tested in pairs");
    const __m128d dx = _mm_set1_pd(d.x()), dy = _mm_set1_pd(d.y()), dz = _mm_set1_pd(d.z());
    for (int k = 0; k < kCones; k += 2) {
      const __m128d c = _mm_add_pd(_mm_add_pd(_mm_mul_pd(dx, _mm_load_pd(&cone_x_[k])),
                                              _mm_mul_pd(dy, _mm_load_pd(&cone_y_[k]))),
                                   _mm_mul_pd(dz, _mm_load_pd(&cone_z_[k])));
      inside |= static_cast<unsigned>(_mm_movemask_pd(_mm_cmpge_pd(c, _mm_load_pd(&cone_cos_[k]))))
                << k;
    }
#else
    for (int k = 0; k < kCones; ++k) {
      const double c = d.x() * cone_x_[k] + d.y() * cone_y_[k] + d.z() * cone_z_[k];
      inside |= static_cast<unsigned>(c >= cone_cos_[k]) << k;
    }
#endif
    if (inside == 0) return Hit{options_.background_radiance, 0, kNoHit};
  }
  // The legs whose cones hold the ray, in ascending order (ties keep the first).
  for (unsigned legs = inside & ((1u << robots::kHexapodLegs) - 1); legs != 0; legs &= legs - 1) {
    const int j = __builtin_ctz(legs);
    const Leg& leg = legs_[j];
    // Early out: the ray's line must pass within R of the axis' line,
    // |(o − a) · (d × w)| <= R |d × w|, i.e. (d · (w × (o − a)))² <= R² (1 − (d · w)²).
    // For rays from the origin of C, w × (o − a) is the precomputed moment m0.
    const double dw = d.dot(leg.w);
    const double a_coef = 1.0 - dw * dw;  // |d⊥|²
    if (central_at_origin) {
      const double dm = d.dot(leg.m0);
      if (dm * dm > r2 * a_coef) continue;
      // IntersectCylinder with the origin-dependent terms precomputed: |o⊥ + t d⊥|² = R², and
      // o⊥ · d⊥ = o⊥ · d since o⊥ is normal to the axis.
      if (a_coef < 1e-18) continue;
      const double b = leg.o_perp.dot(d);
      const double disc = b * b - a_coef * leg.c0;
      if (disc < 0.0) continue;
      const double s = std::sqrt(disc);
      // The near root first; the far one (a second division) only when the near one fails.
      for (int root = 0; root < 2; ++root) {
        const double t = (root == 0 ? -b - s : -b + s) / a_coef;
        if (!(t > 1e-9) || !(t < t_best)) continue;
        const double along = leg.along0 + t * dw;
        if (along < leg.along_lo || along > leg.along_hi) continue;
        if (!InsideCuts(leg, t * d)) continue;
        t_best = t;
        best = j + 1;
        break;
      }
    } else {
      const Eigen::Vector3d oa = o - leg.a;
      const double dm = d.dot(leg.w.cross(oa));
      if (dm * dm > r2 * a_coef) continue;
      // The infinite cylinder |o⊥ + t d⊥|² = R² (as IntersectCylinder), then the leg's ends.
      const double along0 = oa.dot(leg.w);
      const Eigen::Vector3d o_perp = oa - along0 * leg.w;
      const Eigen::Vector3d d_perp = d - dw * leg.w;
      const double a2 = d_perp.squaredNorm();
      if (a2 < 1e-18) continue;
      const double b = o_perp.dot(d_perp);
      const double disc = b * b - a2 * (o_perp.squaredNorm() - r2);
      if (disc < 0.0) continue;
      const double s = std::sqrt(disc);
      for (int root = 0; root < 2; ++root) {
        const double t = (root == 0 ? -b - s : -b + s) / a2;
        if (!(t > 1e-9) || !(t < t_best)) continue;
        const double along = along0 + t * dw;
        if (along < leg.along_lo || along > leg.along_hi) continue;
        if (!InsideCuts(leg, o + t * d)) continue;
        t_best = t;
        best = j + 1;
        break;
      }
    }
  }
  int plate = 0;
  if (options_.base_plate && (inside & (1u << robots::kHexapodLegs))) {
    const int id = TracePlate(base_, kBasePlateId, o, d, central_at_origin, &t_best);
    if (id) plate = id;
  }
  if (options_.platform_plate && (inside & (1u << (robots::kHexapodLegs + 1)))) {
    const int id = TracePlate(platform_, kPlatformPlateId, o, d, central_at_origin, &t_best);
    if (id) plate = id;
  }
  if (plate != 0) return Hit{options_.plate_radiance, plate, t_best};
  if (best == 0) return Hit{options_.background_radiance, 0, kNoHit};
  // Lambertian shading with the outward radial normal at the hit.
  const Leg& leg = legs_[best - 1];
  const Eigen::Vector3d p = o + t_best * d - leg.a;
  const Eigen::Vector3d normal = (p - p.dot(leg.w) * leg.w) / radius_;
  const double radiance =
      options_.leg_ambient + options_.leg_diffuse * std::max(0.0, normal.dot(light_C_));
  return Hit{radiance, best, t_best};
}

Hit HexapodScene::Trace(const Ray& ray_C) const {
  const Eigen::Vector3d& o = ray_C.p_C_O;
  return TraceRay(ray_C.p_C_O, ray_C.d_C, o.x() == 0.0 && o.y() == 0.0 && o.z() == 0.0);
}

// Trace() inlined into one loop (no virtual call or Ray copy per ray); a shared origin is tested
// for the origin of C once.
void HexapodScene::TraceBatch(const RayBatch& rays, Hit* hits) const {
  if (rays.shared_origin) {
    const Eigen::Vector3d& o = rays.origins[0];
    const bool central_at_origin = o.x() == 0.0 && o.y() == 0.0 && o.z() == 0.0;
    if (central_at_origin) {
      for (int k = 0; k < rays.count; ++k) hits[k] = TraceRay(o, rays.directions[k], true);
    } else {
      for (int k = 0; k < rays.count; ++k) hits[k] = TraceRay(o, rays.directions[k], false);
    }
    return;
  }
  for (int k = 0; k < rays.count; ++k) {
    const Eigen::Vector3d& o = rays.origins[k];
    hits[k] = TraceRay(o, rays.directions[k], o.x() == 0.0 && o.y() == 0.0 && o.z() == 0.0);
  }
}

}  // namespace kinevis::vision::render
