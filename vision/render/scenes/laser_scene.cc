#include "vision/render/scenes/laser_scene.h"

#include <emmintrin.h>  // SSE2: part of every x86-64 target

#include <algorithm>
#include <array>
#include <cmath>
#include <new>
#include <sstream>
#include <stdexcept>

#include "common/config_error.h"
#include "vision/render/primitives.h"

namespace kinevis::vision::render {
namespace {

bool InUnit(double x) { return std::isfinite(x) && x >= 0.0 && x <= 1.0; }

// Two doubles (SSE2). Every operation is the IEEE one of the scalar code, lane by lane (no fused
// multiply-add: x86-64's baseline has none), so the lanes round exactly as the scalar code does.
struct D2 {
  __m128d v;
};
inline D2 Set(double x) { return {_mm_set1_pd(x)}; }
inline D2 operator+(D2 a, D2 b) { return {_mm_add_pd(a.v, b.v)}; }
inline D2 operator-(D2 a, D2 b) { return {_mm_sub_pd(a.v, b.v)}; }
inline D2 operator*(D2 a, D2 b) { return {_mm_mul_pd(a.v, b.v)}; }
inline D2 operator/(D2 a, D2 b) { return {_mm_div_pd(a.v, b.v)}; }
inline D2 operator-(D2 a) { return {_mm_xor_pd(a.v, _mm_set1_pd(-0.0))}; }
inline D2 Sqrt(D2 a) { return {_mm_sqrt_pd(a.v)}; }
inline D2 Abs(D2 a) { return {_mm_andnot_pd(_mm_set1_pd(-0.0), a.v)}; }
// std::copysign(magnitude, sign) for a magnitude ≥ 0.
inline D2 CopySignOfPositive(D2 magnitude, D2 sign) {
  return {_mm_or_pd(magnitude.v, _mm_and_pd(sign.v, _mm_set1_pd(-0.0)))};
}
// Comparison masks (all ones where true; false for NaN operands, as in C++).
inline __m128d Less(D2 a, D2 b) { return _mm_cmplt_pd(a.v, b.v); }
inline __m128d LessEqual(D2 a, D2 b) { return _mm_cmple_pd(a.v, b.v); }
inline __m128d Greater(D2 a, D2 b) { return _mm_cmpgt_pd(a.v, b.v); }
inline __m128d NotEqual(D2 a, D2 b) { return _mm_cmpneq_pd(a.v, b.v); }
inline __m128d Equal(D2 a, D2 b) { return _mm_cmpeq_pd(a.v, b.v); }
inline D2 Select(__m128d mask, D2 a, D2 b) {
  return {_mm_or_pd(_mm_and_pd(mask, a.v), _mm_andnot_pd(mask, b.v))};
}
inline D2 Lanes(double a, double b) { return {_mm_set_pd(b, a)}; }
inline double Lane(D2 a, int k) {
  alignas(16) double x[2];
  _mm_store_pd(x, a.v);
  return x[k];
}

LaserPlane MakePlane(const Eigen::Vector3d& normal, const Eigen::Vector3d& emitter) {
  LaserPlane plane;
  plane.normal = normal.normalized();
  plane.point = emitter;
  plane.emitter = emitter;
  return plane;
}

}  // namespace

LaserPlane LaserScannerGeometry::RotatingPlane(double cot_theta_y) const {
  // Seed 004 eq. (17): V_N^Y = (0, 1, cot θ_y), P_L^Y = (0, b_y, d_y):
  // y + cot θ_y z − b_y − d_y cot θ_y = 0.
  return MakePlane(Eigen::Vector3d(0.0, 1.0, cot_theta_y),
                   Eigen::Vector3d(0.0, rotating_b_y, rotating_d_y));
}

LaserPlane LaserScannerGeometry::FixedPlane() const {
  // Seed 004 eq. (18) with b_x + d_x cot θ_x = b_x' (Table 2 gives b_x' only):
  // x + cot θ_x z − b_x' = 0.
  return MakePlane(Eigen::Vector3d(1.0, 0.0, fixed_cot_theta_x),
                   Eigen::Vector3d(fixed_b_x_prime, 0.0, 0.0));
}

std::string LaserScannerGeometry::Validate() const {
  common::Problems bad;
  if (!std::isfinite(rotating_b_y)) bad.Add("scanner.rotating_b_y", rotating_b_y, "must be finite");
  if (!std::isfinite(rotating_d_y)) bad.Add("scanner.rotating_d_y", rotating_d_y, "must be finite");
  if (!std::isfinite(fixed_b_x_prime)) {
    bad.Add("scanner.fixed_b_x_prime", fixed_b_x_prime, "must be finite");
  }
  if (!std::isfinite(fixed_cot_theta_x)) {
    bad.Add("scanner.fixed_cot_theta_x", fixed_cot_theta_x, "must be finite");
  }
  return bad.Message();
}

double DotGrid::Reflectance(double x_S, double y_S) const {
  // The nearest dot centre (the grid is regular): its column and row, clamped to the grid.
  const double u = (x_S - centre_S.x()) / pitch + 0.5 * (cols - 1);
  const double v = (y_S - centre_S.y()) / pitch + 0.5 * (rows - 1);
  const double col = std::clamp(std::round(u), 0.0, static_cast<double>(cols - 1));
  const double row = std::clamp(std::round(v), 0.0, static_cast<double>(rows - 1));
  const double dx = (u - col) * pitch, dy = (v - row) * pitch;
  return dx * dx + dy * dy <= dot_radius * dot_radius ? albedo : 1.0;
}

std::string DotGrid::Validate(const std::string& prefix) const {
  common::Problems bad;
  if (!(rows >= 2 && rows <= 100)) bad.Add(prefix + "rows", rows, "must be in [2, 100]");
  if (!(cols >= 2 && cols <= 100)) bad.Add(prefix + "cols", cols, "must be in [2, 100]");
  if (!(std::isfinite(pitch) && pitch > 0.0)) bad.Add(prefix + "pitch", pitch, "must be > 0 m");
  if (!(std::isfinite(dot_radius) && dot_radius > 0.0 && dot_radius < 0.5 * pitch)) {
    bad.Add(prefix + "dot_radius", dot_radius, "must be in (0, pitch / 2) m");
  }
  if (!(std::isfinite(albedo) && albedo >= 0.0 && albedo < 1.0)) {
    bad.Add(prefix + "albedo", albedo, "must be in [0, 1)");
  }
  if (!centre_S.allFinite()) bad.Add(prefix + "centre_S", centre_S.x(), "must be finite");
  return bad.Message();
}

bool LaserHit::Lit(LaserId id) const {
  const int i = static_cast<int>(id);
  return hit.object != kLaserBackground && reached[i] &&
         std::abs(plane_distance[i]) <= 3.0 * stripe_sigma;
}

std::string LaserSceneParameters::Validate() const {
  common::Problems bad;
  const std::string scanner_problems = scanner.Validate();
  std::string message = scanner_problems;
  if (!std::isfinite(rotating_cot_theta_y)) {
    bad.Add("rotating_cot_theta_y", rotating_cot_theta_y, "must be finite");
  }
  if (!X_CS.matrix().allFinite()) bad.Add("X_CS", X_CS.translation().norm(), "must be finite");
  if (!(half_extent.allFinite() && half_extent.minCoeff() > 0.0)) {
    bad.Add("half_extent", half_extent.minCoeff(), "must be both > 0");
  }
  const double curvatures[3] = {curvature_xx, curvature_yy, curvature_xy};
  const char* curvature_names[3] = {"curvature_xx", "curvature_yy", "curvature_xy"};
  for (int i = 0; i < 3; ++i) {
    if (!(std::isfinite(curvatures[i]) && std::abs(curvatures[i]) <= 20.0)) {
      bad.Add(curvature_names[i], curvatures[i], "must be |.| <= 20 1/m");
    }
  }
  if (pits.size() > 64) bad.Add("pits.size()", static_cast<double>(pits.size()), "must be <= 64");
  for (size_t k = 0; k < pits.size(); ++k) {
    const std::string name = "pits[" + std::to_string(k) + "]";
    if (!pits[k].centre_S.allFinite())
      bad.Add(name + ".centre_S", pits[k].centre_S.x(), "must be finite");
    if (!(std::isfinite(pits[k].depth) && pits[k].depth > 0.0 && pits[k].depth < 0.05)) {
      bad.Add(name + ".depth", pits[k].depth, "must be in (0, 0.05) m");
    }
    if (!(std::isfinite(pits[k].sigma) && pits[k].sigma >= 1e-4 && pits[k].sigma < 0.1)) {
      bad.Add(name + ".sigma", pits[k].sigma, "must be in [1e-4, 0.1) m");
    }
  }
  if (!gauge_centre_S.allFinite()) bad.Add("gauge_centre_S", gauge_centre_S.x(), "must be finite");
  if (!std::isfinite(gauge_heading)) bad.Add("gauge_heading", gauge_heading, "must be finite");
  if (!(gauge_size.allFinite() && gauge_size.minCoeff() > 0.0)) {
    bad.Add("gauge_size", gauge_size.minCoeff(), "must be all > 0");
  }
  if (dot_grid) {
    const std::string grid = dots.Validate();
    if (!grid.empty()) {
      message += (message.empty() ? "" : "; ") + grid;
    } else {
      // The outermost dots' edges, in S.
      const double x_reach =
          std::abs(dots.centre_S.x()) + 0.5 * (dots.cols - 1) * dots.pitch + dots.dot_radius;
      const double y_reach =
          std::abs(dots.centre_S.y()) + 0.5 * (dots.rows - 1) * dots.pitch + dots.dot_radius;
      if (!(x_reach <= half_extent.x())) {
        bad.Add("dots (x reach)", x_reach,
                "must be <= half_extent.x (the grid must fit the board)");
      }
      if (!(y_reach <= half_extent.y())) {
        bad.Add("dots (y reach)", y_reach,
                "must be <= half_extent.y (the grid must fit the board)");
      }
    }
    if (surface != LaserSurfaceKind::kBoard) {
      bad.Add("dot_grid: only on the board (surface kBoard)");
    }
  }
  if (!InUnit(ambient)) bad.Add("ambient", ambient, "must be in [0, 1]");
  if (!InUnit(background)) bad.Add("background", background, "must be in [0, 1]");
  if (!InUnit(laser_peak)) bad.Add("laser_peak", laser_peak, "must be in [0, 1]");
  if (!(std::isfinite(stripe_sigma) && stripe_sigma >= 0.05e-3 && stripe_sigma <= 2e-3)) {
    bad.Add("stripe_sigma", stripe_sigma, "must be in [5e-5, 2e-3] m");
  }
  const std::string own = bad.Message();
  if (!own.empty()) message += (message.empty() ? "" : "; ") + own;
  return message;
}

LaserScene::LaserScene(const LaserSceneParameters& parameters) : parameters_(parameters) {
  const std::string message = parameters.Validate();
  if (!message.empty()) throw std::invalid_argument("LaserScene: " + message);
  planes_[static_cast<int>(LaserId::kFixed)] = parameters.scanner.FixedPlane();
  planes_[static_cast<int>(LaserId::kRotating)] =
      parameters.scanner.RotatingPlane(parameters.rotating_cot_theta_y);
  X_SC_ = parameters.X_CS.inverse();
  R_SC_ = X_SC_.linear();
  p_S_C_ = X_SC_.translation();
  R_CS_ = parameters.X_CS.linear();
  const double hx = parameters.half_extent.x(), hy = parameters.half_extent.y();
  if (parameters.surface == LaserSurfaceKind::kBlade) {
    height_bound_ = 0.5 * std::abs(parameters.curvature_xx) * hx * hx +
                    0.5 * std::abs(parameters.curvature_yy) * hy * hy +
                    std::abs(parameters.curvature_xy) * hx * hy;
    min_pit_sigma_ = 1.0;
    for (const CavitationPit& pit : parameters.pits) {
      pit_depth_sum_ += pit.depth;
      min_pit_sigma_ = std::min(min_pit_sigma_, pit.sigma);
      // h exp(−r² / (2σ²)) < kNegligiblePitHeight beyond r² = 2σ² ln(h / kNegligiblePitHeight).
      pit_cutoff2_.push_back(2.0 * pit.sigma * pit.sigma *
                             std::log(std::max(pit.depth / kNegligiblePitHeight, 1.0)));
      pit_reach_.push_back(std::sqrt(pit_cutoff2_.back()) * (1.0 + 1e-9) + 1e-12);
    }
  }
  batch_fast_path_ = parameters.surface == LaserSurfaceKind::kBlade &&
                     (parameters.curvature_xx != 0.0 || parameters.curvature_yy != 0.0 ||
                      parameters.curvature_xy != 0.0);
  X_CB_ = parameters.X_CS * parameters.X_SB();
}

Eigen::Isometry3d LaserSceneParameters::X_SB() const {
  return Eigen::Isometry3d(
      Eigen::Translation3d(gauge_centre_S.x(), gauge_centre_S.y(), 0.5 * gauge_size.z()) *
      Eigen::AngleAxisd(gauge_heading, Eigen::Vector3d::UnitZ()));
}

double LaserScene::Height(double x_S, double y_S) const {
  if (parameters_.surface != LaserSurfaceKind::kBlade) return 0.0;
  double f = 0.5 * parameters_.curvature_xx * x_S * x_S +
             0.5 * parameters_.curvature_yy * y_S * y_S + parameters_.curvature_xy * x_S * y_S;
  for (const CavitationPit& pit : parameters_.pits) {
    const double dx = x_S - pit.centre_S.x(), dy = y_S - pit.centre_S.y();
    f -= pit.depth * std::exp(-(dx * dx + dy * dy) / (2.0 * pit.sigma * pit.sigma));
  }
  return f;
}

double LaserScene::IntersectHeightfield(const Ray& ray_S, Eigen::Vector3d* n_S) const {
  const Eigen::Vector3d& o = ray_S.p_C_O;
  const Eigen::Vector3d& d = ray_S.d_C;
  const double hx = parameters_.half_extent.x(), hy = parameters_.half_extent.y();
  // The surface lies in the slab z_lo ≤ z_S ≤ z_hi over the extent.
  const double z_hi = height_bound_ + 1e-9;
  const double z_lo = -height_bound_ - pit_depth_sum_ - 1e-9;
  double t0 = 1e-9, t1 = 0.0;
  if (std::abs(d.z()) < 1e-12) {
    if (o.z() < z_lo || o.z() > z_hi) return kNoHit;
    t1 = 4.0 * (hx + hy) + std::abs(o.x()) + std::abs(o.y());
  } else {
    const double inverse_dz = 1.0 / d.z();
    double ta = (z_hi - o.z()) * inverse_dz, tb = (z_lo - o.z()) * inverse_dz;
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = tb;
  }
  if (!(t1 > t0)) return kNoHit;

  // g(t) = z − f along the ray splits into the pit-free part, a quadratic in t,
  //   g_q(t) = z − q = a t² + b t + c   (q the curvature terms of f),
  // plus Σ_k h_k exp(−|p(t) − c_k|² / (2 σ_k²)) ≥ 0 from the pits. Issue 5's speed-up: a pit
  // whose closest approach to this ray's stretch through the slab keeps its term below
  // kNegligiblePitHeight everywhere there is left out (pit_cutoff2_), so most rays meet just the
  // quadric, analytically. With pits left, g_q ≤ g ≤ g_q + H, H = Σ h_k exp(−D_k² / (2 σ_k²))
  // over the pits kept, D_k the closest approach of the stretch to pit k's centre (a bound of its
  // term on the whole stretch; the depths Σ h_k before this session's second speed-up, a bracket
  // up to a millimetre long, refined by ~20 evaluations of g; with D_k most brackets are
  // nanometres long): the first root lies between the first root of g_q and that of g_q + H, and
  // only that stretch is marched and refined (regula falsi) as before.
  const double kxx = parameters_.curvature_xx, kyy = parameters_.curvature_yy;
  const double kxy = parameters_.curvature_xy;
  const double ox = o.x(), oy = o.y(), dx = d.x(), dy = d.y();
  const double qa = -(0.5 * kxx * dx * dx + 0.5 * kyy * dy * dy + kxy * dx * dy);
  const double qb = d.z() - (kxx * ox * dx + kyy * oy * dy + kxy * (ox * dy + oy * dx));
  const double qc = o.z() - (0.5 * kxx * ox * ox + 0.5 * kyy * oy * oy + kxy * ox * oy);

  std::array<int, 64> active;
  int active_count = 0;
  double active_depth = 0.0, active_min_sigma = 1.0;  // active_depth: H below
  const double h2 = dx * dx + dy * dy;
  for (int k = 0; k < static_cast<int>(parameters_.pits.size()); ++k) {
    const CavitationPit& pit = parameters_.pits[k];
    // Closest approach of the stretch [t0, t1] to the pit's centre, without a division: the
    // unconstrained one, t* = −(c·d)/|d_xy|², when t0 ≤ t* ≤ t1, else the nearer end.
    const double cx = ox - pit.centre_S.x(), cy = oy - pit.centre_S.y();
    const double cd = -(cx * dx + cy * dy), c2 = cx * cx + cy * cy;
    double distance2;
    if (cd <= t0 * h2) {
      const double ex = cx + t0 * dx, ey = cy + t0 * dy;
      distance2 = ex * ex + ey * ey;
      if (distance2 > pit_cutoff2_[k]) continue;
    } else if (cd >= t1 * h2) {
      const double ex = cx + t1 * dx, ey = cy + t1 * dy;
      distance2 = ex * ex + ey * ey;
      if (distance2 > pit_cutoff2_[k]) continue;
    } else if (c2 * h2 - cd * cd > pit_cutoff2_[k] * h2) {
      continue;
    } else {
      distance2 = std::max(0.0, c2 - cd * cd / h2);  // h2 > 0 here: t0 h2 < cd < t1 h2
    }
    active[active_count++] = k;
    // The relative margin covers the rounding of distance2 and exp (~1e-16 each).
    active_depth += pit.depth * std::exp(-distance2 / (2.0 * pit.sigma * pit.sigma)) * (1.0 + 1e-9);
    active_min_sigma = std::min(active_min_sigma, pit.sigma);
  }

  auto in_extent = [hx, hy](const Eigen::Vector3d& p) {
    return std::abs(p.x()) <= hx && std::abs(p.y()) <= hy;
  };
  auto normal = [&](const Eigen::Vector3d& p) {
    // ∇f by the analytic derivative of each term kept.
    double fx = kxx * p.x() + kxy * p.y();
    double fy = kyy * p.y() + kxy * p.x();
    for (int n = 0; n < active_count; ++n) {
      const CavitationPit& pit = parameters_.pits[active[n]];
      const double ex = p.x() - pit.centre_S.x(), ey = p.y() - pit.centre_S.y();
      const double s2 = pit.sigma * pit.sigma;
      const double e = pit.depth * std::exp(-(ex * ex + ey * ey) / (2.0 * s2));
      fx += e * ex / s2;
      fy += e * ey / s2;
    }
    return Eigen::Vector3d(-fx, -fy, 1.0).normalized();
  };
  // Roots of a t² + b t + (c + shift) in (lo, hi], ascending; returns how many (0..2). Double
  // roots (no sign change) are not roots here, as for the march.
  auto quadratic_roots = [qa, qb, qc](double shift, double lo, double hi, double roots[2]) {
    const double c = qc + shift;
    double r[2];
    int count = 0;
    if (qa == 0.0) {
      if (qb != 0.0) r[count++] = -c / qb;
    } else {
      const double disc = qb * qb - 4.0 * qa * c;
      if (disc > 0.0) {
        const double q = -0.5 * (qb + std::copysign(std::sqrt(disc), qb));
        r[0] = q / qa;
        r[1] = q != 0.0 ? c / q : r[0];
        if (r[0] > r[1]) std::swap(r[0], r[1]);
        count = 2;
      }
    }
    int kept = 0;
    for (int n = 0; n < count; ++n) {
      if (r[n] > lo && r[n] <= hi) roots[kept++] = r[n];
    }
    return kept;
  };

  double roots[2];
  if (active_count == 0) {
    // The quadric alone, written out (the common case: most rays pass no pit).
    double r0 = kNoHit, r1 = kNoHit;
    if (qa == 0.0) {
      if (qb != 0.0) r0 = -qc / qb;
    } else {
      const double disc = qb * qb - 4.0 * qa * qc;
      if (!(disc > 0.0)) return kNoHit;
      const double q = -0.5 * (qb + std::copysign(std::sqrt(disc), qb));
      r0 = q / qa;
      r1 = q != 0.0 ? qc / q : r0;
      if (r0 > r1) std::swap(r0, r1);
    }
    for (const double t : {r0, r1}) {
      if (!(t > t0 && t <= t1)) continue;
      const double x = ox + t * dx, y = oy + t * dy;
      if (!(std::abs(x) <= hx && std::abs(y) <= hy)) continue;
      if (n_S != nullptr) {
        const double fx = kxx * x + kxy * y, fy = kyy * y + kxy * x;
        const double inverse_norm = 1.0 / std::sqrt(fx * fx + fy * fy + 1.0);
        *n_S = Eigen::Vector3d(-fx * inverse_norm, -fy * inverse_norm, inverse_norm);
      }
      return t;
    }
    return kNoHit;
  }

  auto g = [&](double t) {
    const double x = ox + t * dx, y = oy + t * dy;
    double value = (qa * t + qb) * t + qc;
    for (int n = 0; n < active_count; ++n) {
      const CavitationPit& pit = parameters_.pits[active[n]];
      const double ex = x - pit.centre_S.x(), ey = y - pit.centre_S.y();
      value += pit.depth * std::exp(-(ex * ex + ey * ey) / (2.0 * pit.sigma * pit.sigma));
    }
    return value;
  };
  // March [ts, te] so that no pit can be stepped over (horizontal travel per step ≤ σ_min / 4);
  // at the first sign change, Illinois regula falsi; a root outside the extent is passed over.
  auto march = [&](double ts, double te) {
    const double horizontal = std::sqrt(h2);
    int steps = 1;
    if (horizontal > 0.0) {
      const double wanted = (te - ts) * horizontal / (0.25 * active_min_sigma);
      steps = std::max(steps, static_cast<int>(std::min(std::ceil(wanted), 4096.0)));
    }
    const double dt = (te - ts) / steps;
    double ta = ts, ga = g(ta);
    for (int i = 1; i <= steps; ++i) {
      const double tb = i == steps ? te : ts + i * dt;
      const double gb = g(tb);
      if ((ga > 0.0) != (gb > 0.0)) {
        double a = ta, fa = ga, b = tb, fb = gb;
        int side = 0;
        for (int k = 0; k < 100 && b - a > 1e-13; ++k) {
          const double c = (a * fb - b * fa) / (fb - fa);
          const double fc = g(c);
          if ((fc > 0.0) == (fa > 0.0)) {
            a = c;
            fa = fc;
            if (side == -1) fb *= 0.5;
            side = -1;
          } else {
            b = c;
            fb = fc;
            if (side == 1) fa *= 0.5;
            side = 1;
          }
          if (fc == 0.0) {
            a = b = c;
            break;
          }
          // Close the bracket from the moved end: one evaluation 0.9e-13 beyond c towards the
          // other end. Near a root g is almost linear here, so c usually lands within that of it
          // and the bracket is done after one step; regula falsi alone keeps one end in place
          // for several steps (issue 5: pit rays cost ~10 evaluations of g, each an exp per pit).
          const double probe = side == -1 ? c + 0.9e-13 : c - 0.9e-13;
          if (b - a > 1e-13 && probe > a && probe < b) {
            const double fp = g(probe);
            if ((fp > 0.0) == (fa > 0.0)) {
              a = probe;
              fa = fp;
            } else {
              b = probe;
              fb = fp;
            }
          }
        }
        const double t = 0.5 * (a + b);
        const Eigen::Vector3d p = o + t * d;
        if (in_extent(p)) {
          if (n_S != nullptr) *n_S = normal(p);
          return t;
        }
      }
      ta = tb;
      ga = gb;
    }
    return kNoHit;
  };
  // Start: the first point where g_q ≤ 0 (g > 0 before it). End of the first stretch: the first
  // root of g_q + H after it (g ≤ 0 there); the rest only if that stretch's root is off the extent.
  double t_start = t0;
  if (qc + (qa * t0 + qb) * t0 > 0.0) {  // g_q(t0) > 0
    if (quadratic_roots(0.0, t0, t1, roots) == 0) return kNoHit;
    t_start = std::max(t0, roots[0] * (1.0 - 1e-12) - 1e-12);
  }
  double t_end = t1;
  if (quadratic_roots(active_depth, t_start, t1, roots) > 0) {
    t_end = std::min(t1, roots[0] * (1.0 + 1e-12) + 1e-12);
  }
  const double t = march(t_start, t_end);
  if (t != kNoHit || t_end >= t1) return t;
  return march(t_end, t1);
}

double LaserScene::IntersectSurface(const Ray& ray_C, int* object, Eigen::Vector3d* n_C) const {
  Ray ray_S;
  // X_SC_ * p written out with a plain 3×3 matrix (Eigen's Isometry product goes through 4×4).
  const Eigen::Vector3d& o = ray_C.p_C_O;
  const Eigen::Vector3d& d = ray_C.d_C;
  for (int row = 0; row < 3; ++row) {
    ray_S.p_C_O[row] =
        R_SC_(row, 0) * o.x() + R_SC_(row, 1) * o.y() + R_SC_(row, 2) * o.z() + p_S_C_[row];
    ray_S.d_C[row] = R_SC_(row, 0) * d.x() + R_SC_(row, 1) * d.y() + R_SC_(row, 2) * d.z();
  }
  Eigen::Vector3d n_S = Eigen::Vector3d::UnitZ();
  double t = kNoHit;
  if (parameters_.surface == LaserSurfaceKind::kBlade) {
    t = IntersectHeightfield(ray_S, &n_S);
  } else {
    t = IntersectPlane(ray_S, Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ());
    if (t != kNoHit) {
      const Eigen::Vector3d p = ray_S.p_C_O + t * ray_S.d_C;
      if (std::abs(p.x()) > parameters_.half_extent.x() ||
          std::abs(p.y()) > parameters_.half_extent.y()) {
        t = kNoHit;
      }
    }
  }
  int hit_object = t == kNoHit ? kLaserBackground : kLaserSurface;
  // R_CS_ * n_S written out (TracePair repeats these operations in this order).
  Eigen::Vector3d normal;
  for (int row = 0; row < 3; ++row) {
    normal[row] = R_CS_(row, 0) * n_S.x() + R_CS_(row, 1) * n_S.y() + R_CS_(row, 2) * n_S.z();
  }
  if (parameters_.surface == LaserSurfaceKind::kBoard && parameters_.gauge_block) {
    Eigen::Vector3d n_box;
    const double t_box = IntersectBox(ray_C, X_CB_, 0.5 * parameters_.gauge_size, 1e-9, &n_box);
    if (t_box < t) {
      t = t_box;
      hit_object = kLaserGaugeBlock;
      normal = n_box;
    }
  }
  if (object != nullptr) *object = hit_object;
  if (n_C != nullptr) {
    const double facing = normal.x() * d.x() + normal.y() * d.y() + normal.z() * d.z();
    *n_C = facing > 0.0 ? Eigen::Vector3d(-normal) : normal;
  }
  return t;
}

bool LaserScene::Shadowed(const Eigen::Vector3d& p_C, const LaserPlane& laser) const {
  if (!parameters_.laser_shadows || parameters_.surface != LaserSurfaceKind::kBoard ||
      !parameters_.gauge_block) {
    return false;
  }
  const Eigen::Vector3d to_emitter = laser.emitter - p_C;
  const double length = to_emitter.norm();
  Ray ray;
  ray.p_C_O = p_C;
  ray.d_C = to_emitter / length;
  // t_min keeps a point on the block's lit face from shadowing itself.
  return IntersectBox(ray, X_CB_, 0.5 * parameters_.gauge_size, 1e-7) < length;
}

LaserHit LaserScene::TraceDetailed(const Ray& ray_C) const {
  LaserHit out;
  out.stripe_sigma = parameters_.stripe_sigma;
  out.hit.radiance = parameters_.background;
  out.hit.object = kLaserBackground;
  out.hit.depth = kNoHit;
  int object = kLaserBackground;
  Eigen::Vector3d n_C;
  const double t = IntersectSurface(ray_C, &object, &n_C);
  if (t == kNoHit) return out;
  const Eigen::Vector3d& d = ray_C.d_C;
  out.p_C = ray_C.p_C_O + t * d;
  out.n_C = n_C;
  out.hit.object = object;
  out.hit.depth = t;
  // Dot products written out (TracePair repeats these operations in this order).
  const double cosine = n_C.x() * d.x() + n_C.y() * d.y() + n_C.z() * d.z();
  double radiance = parameters_.ambient * (0.3 + 0.7 * std::abs(cosine));
  const bool on[2] = {parameters_.fixed_on, parameters_.rotating_on};
  const double inverse_two_sigma2 =
      1.0 / (2.0 * parameters_.stripe_sigma * parameters_.stripe_sigma);
  for (int i = 0; i < 2; ++i) {
    const Eigen::Vector3d& n = planes_[i].normal;
    const Eigen::Vector3d& q = planes_[i].point;
    out.plane_distance[i] = n.x() * (out.p_C.x() - q.x()) + n.y() * (out.p_C.y() - q.y()) +
                            n.z() * (out.p_C.z() - q.z());
    if (!on[i]) continue;
    const double d2 = out.plane_distance[i] * out.plane_distance[i];
    // Beyond 8 σ the stripe adds < 1e-13; skip the shadow ray there.
    if (d2 * inverse_two_sigma2 > 32.0) {
      out.reached[i] = true;
      continue;
    }
    out.reached[i] = !Shadowed(out.p_C, planes_[i]);
    if (out.reached[i]) radiance += parameters_.laser_peak * std::exp(-d2 * inverse_two_sigma2);
  }
  if (parameters_.dot_grid && object == kLaserSurface) {
    const Eigen::Vector3d p_S = X_SC_ * out.p_C;
    out.reflectance = parameters_.dots.Reflectance(p_S.x(), p_S.y());
    radiance *= out.reflectance;
  }
  out.hit.radiance = std::min(radiance, 1.0);
  return out;
}

Hit LaserScene::Trace(const Ray& ray_C) const { return TraceDetailed(ray_C).hit; }

// Issue 5's frame time: most of a blade frame's rays meet the quadric only (no pit within reach),
// which TraceChunk solves two rays at a time with the operations of IntersectSurface(),
// IntersectHeightfield()'s pit-free branch and TraceDetailed() in the same order — so the hits are
// bit for bit those of Trace() (laser_scene_test compares them). Rays it cannot settle (a pit
// within reach, a ray parallel to the slab, a zero leading coefficient) go through Trace(); so
// does the board. The work runs in stages over a chunk of rays (short loop bodies, so that the
// CPU overlaps the divisions and square roots of many rays; one ray's chain of them is ~200
// cycles long).
void LaserScene::TraceBatch(const RayBatch& rays, Hit* hits) const {
  Ray ray;
  auto trace_one = [&](int k) {
    ray.p_C_O = rays.origins[rays.shared_origin ? 0 : k];
    ray.d_C = rays.directions[k];
    new (&hits[k]) Hit(Trace(ray));  // in place, as Scene::TraceBatch (renderer.cc) says why
  };
  if (!batch_fast_path_) {
    for (int k = 0; k < rays.count; ++k) trace_one(k);
    return;
  }
  bool done[kChunkRays];
  for (int first = 0; first < rays.count; first += kChunkRays) {
    const int count = std::min(kChunkRays, rays.count - first);
    TraceChunk(rays, first, count, hits + first, done);
    for (int k = 0; k < count; ++k) {
      if (!done[k]) trace_one(first + k);
    }
  }
}

void LaserScene::TraceChunk(const RayBatch& rays, int first, int count, Hit* hits,
                            bool* done) const {
  const LaserSceneParameters& p = parameters_;
  constexpr int kPairs = kChunkRays / 2;
  const int pairs = (count + 1) / 2;
  // Per pair: the ray in C and in S, the stretch [t0, t1] through the slab, the quadric, masks.
  D2 ox[kPairs], oy[kPairs], oz[kPairs], dx[kPairs], dy[kPairs], dz[kPairs];
  D2 sox[kPairs], soy[kPairs], sdx[kPairs], sdy[kPairs], t0s[kPairs], t1s[kPairs];
  D2 qas[kPairs], qbs[kPairs], qcs[kPairs];
  __m128d hits_mask[kPairs], fallback_mask[kPairs];
  const double kxx = p.curvature_xx, kyy = p.curvature_yy, kxy = p.curvature_xy;
  const D2 hkxx = Set(0.5 * kxx), hkyy = Set(0.5 * kyy);
  const D2 Kxx = Set(kxx), Kyy = Set(kyy), Kxy = Set(kxy);

  // 1. The ray in S, the slab, the pits within reach and the quadric (IntersectSurface,
  // IntersectHeightfield).
  const D2 z_hi = Set(height_bound_ + 1e-9);
  const D2 z_lo = Set(-height_bound_ - pit_depth_sum_ - 1e-9);
  const D2 hx = Set(p.half_extent.x()), hy = Set(p.half_extent.y());
  for (int j = 0; j < pairs; ++j) {
    const int a = first + 2 * j, b = std::min(a + 1, first + count - 1);  // odd count: repeat
    const Eigen::Vector3d& oa = rays.origins[rays.shared_origin ? 0 : a];
    const Eigen::Vector3d& ob = rays.origins[rays.shared_origin ? 0 : b];
    const Eigen::Vector3d& da = rays.directions[a];
    const Eigen::Vector3d& db = rays.directions[b];
    ox[j] = Lanes(oa.x(), ob.x());
    oy[j] = Lanes(oa.y(), ob.y());
    oz[j] = Lanes(oa.z(), ob.z());
    dx[j] = Lanes(da.x(), db.x());
    dy[j] = Lanes(da.y(), db.y());
    dz[j] = Lanes(da.z(), db.z());
    D2 os[3], ds[3];
    for (int row = 0; row < 3; ++row) {
      os[row] = Set(R_SC_(row, 0)) * ox[j] + Set(R_SC_(row, 1)) * oy[j] +
                Set(R_SC_(row, 2)) * oz[j] + Set(p_S_C_[row]);
      ds[row] =
          Set(R_SC_(row, 0)) * dx[j] + Set(R_SC_(row, 1)) * dy[j] + Set(R_SC_(row, 2)) * dz[j];
    }
    __m128d fallback = Less(Abs(ds[2]), Set(1e-12));
    const D2 inverse_dz = Set(1.0) / ds[2];
    const D2 ta0 = (z_hi - os[2]) * inverse_dz, tb0 = (z_lo - os[2]) * inverse_dz;
    const __m128d swap = Greater(ta0, tb0);
    const D2 ta = Select(swap, tb0, ta0), tb = Select(swap, ta0, tb0);
    const D2 t0 = {_mm_max_pd(ta.v, _mm_set1_pd(1e-9))};  // std::max(1e-9, ta)
    const D2 t1 = tb;
    // The stretch's xy bounding box, grown by a margin for rounding: a ray whose box misses the
    // extent sees the background (whatever the pits: the scalar code's root would be off the
    // extent), and a pit whose cut-off square misses the box is out of reach.
    const D2 ex0 = os[0] + t0 * ds[0], ey0 = os[1] + t0 * ds[1];
    const D2 ex1 = os[0] + t1 * ds[0], ey1 = os[1] + t1 * ds[1];
    const D2 margin = Set(1e-9);
    const D2 box_x0 = D2{_mm_min_pd(ex0.v, ex1.v)} - margin;
    const D2 box_x1 = D2{_mm_max_pd(ex0.v, ex1.v)} + margin;
    const D2 box_y0 = D2{_mm_min_pd(ey0.v, ey1.v)} - margin;
    const D2 box_y1 = D2{_mm_max_pd(ey0.v, ey1.v)} + margin;
    const __m128d on_extent = _mm_and_pd(_mm_and_pd(LessEqual(box_x0, hx), LessEqual(-hx, box_x1)),
                                         _mm_and_pd(LessEqual(box_y0, hy), LessEqual(-hy, box_y1)));
    const __m128d hit = _mm_and_pd(Greater(t1, t0), on_extent);
    if (_mm_movemask_pd(hit) == 0) {
      hits_mask[j] = hit;
      fallback_mask[j] = fallback;
      continue;
    }
    const D2 h2 = ds[0] * ds[0] + ds[1] * ds[1];
    for (size_t n = 0; n < p.pits.size(); ++n) {
      const CavitationPit& pit = p.pits[n];
      const D2 reach = Set(pit_reach_[n]);
      const D2 pcx = Set(pit.centre_S.x()), pcy = Set(pit.centre_S.y());
      const __m128d in_square =
          _mm_and_pd(_mm_and_pd(LessEqual(box_x0, pcx + reach), LessEqual(pcx - reach, box_x1)),
                     _mm_and_pd(LessEqual(box_y0, pcy + reach), LessEqual(pcy - reach, box_y1)));
      if (_mm_movemask_pd(_mm_and_pd(hit, in_square)) == 0) continue;
      const D2 cut = Set(pit_cutoff2_[n]);
      const D2 cx = os[0] - Set(pit.centre_S.x()), cy = os[1] - Set(pit.centre_S.y());
      const D2 cd = -(cx * ds[0] + cy * ds[1]), c2 = cx * cx + cy * cy;
      const D2 fx0 = cx + t0 * ds[0], fy0 = cy + t0 * ds[1];
      const D2 fx1 = cx + t1 * ds[0], fy1 = cy + t1 * ds[1];
      const __m128d near0 = LessEqual(fx0 * fx0 + fy0 * fy0, cut);
      const __m128d near1 = LessEqual(fx1 * fx1 + fy1 * fy1, cut);
      const __m128d near = LessEqual(c2 * h2 - cd * cd, cut * h2);
      const __m128d before = LessEqual(cd, t0 * h2), after = _mm_cmpge_pd(cd.v, (t1 * h2).v);
      const __m128d active = _mm_or_pd(
          _mm_and_pd(before, near0),
          _mm_andnot_pd(before, _mm_or_pd(_mm_and_pd(after, near1), _mm_andnot_pd(after, near))));
      fallback = _mm_or_pd(fallback, _mm_and_pd(hit, active));
    }
    qas[j] = -(hkxx * ds[0] * ds[0] + hkyy * ds[1] * ds[1] + Kxy * ds[0] * ds[1]);
    qbs[j] =
        ds[2] - (Kxx * os[0] * ds[0] + Kyy * os[1] * ds[1] + Kxy * (os[0] * ds[1] + os[1] * ds[0]));
    qcs[j] = os[2] - (hkxx * os[0] * os[0] + hkyy * os[1] * os[1] + Kxy * os[0] * os[1]);
    fallback_mask[j] = _mm_or_pd(fallback, _mm_and_pd(hit, Equal(qas[j], Set(0.0))));
    hits_mask[j] = hit;
    sox[j] = os[0];
    soy[j] = os[1];
    sdx[j] = ds[0];
    sdy[j] = ds[1];
    t0s[j] = t0;
    t1s[j] = t1;
  }

  // 2. The quadric's first root on the stretch and within the extent (IntersectHeightfield's
  // pit-free branch). t, x, y overwrite t0s, sox, soy.
  for (int j = 0; j < pairs; ++j) {
    if (_mm_movemask_pd(hits_mask[j]) == 0) continue;
    const D2 qa = qas[j], qb = qbs[j], qc = qcs[j], t0 = t0s[j], t1 = t1s[j];
    const D2 disc = qb * qb - Set(4.0) * qa * qc;
    __m128d hit = _mm_and_pd(hits_mask[j], Greater(disc, Set(0.0)));
    const D2 q = Set(-0.5) * (qb + CopySignOfPositive(Sqrt(disc), qb));
    const D2 s0 = q / qa;
    const D2 s1 = Select(NotEqual(q, Set(0.0)), qc / q, s0);
    const __m128d order = Greater(s0, s1);
    const D2 r0 = Select(order, s1, s0), r1 = Select(order, s0, s1);
    const D2 x0 = sox[j] + r0 * sdx[j], y0 = soy[j] + r0 * sdy[j];
    const D2 x1 = sox[j] + r1 * sdx[j], y1 = soy[j] + r1 * sdy[j];
    const __m128d use0 = _mm_and_pd(_mm_and_pd(Greater(r0, t0), LessEqual(r0, t1)),
                                    _mm_and_pd(LessEqual(Abs(x0), hx), LessEqual(Abs(y0), hy)));
    const __m128d use1 = _mm_and_pd(_mm_and_pd(Greater(r1, t0), LessEqual(r1, t1)),
                                    _mm_and_pd(LessEqual(Abs(x1), hx), LessEqual(Abs(y1), hy)));
    hits_mask[j] = _mm_and_pd(hit, _mm_or_pd(use0, use1));
    t0s[j] = Select(use0, r0, r1);
    sox[j] = Select(use0, x0, x1);
    soy[j] = Select(use0, y0, y1);
  }

  // 3. Normal (in S, then in C facing the ray), shading and the planes' distances
  // (IntersectSurface, TraceDetailed); then per ray the stripes and the hit.
  const bool on[2] = {p.fixed_on, p.rotating_on};
  const double inverse_two_sigma2 = 1.0 / (2.0 * p.stripe_sigma * p.stripe_sigma);
  for (int j = 0; j < pairs; ++j) {
    if (_mm_movemask_pd(hits_mask[j]) == 0) {
      for (int lane = 0; lane < 2 && 2 * j + lane < count; ++lane) {
        const int k = 2 * j + lane;
        done[k] = ((_mm_movemask_pd(fallback_mask[j]) >> lane) & 1) == 0;
        hits[k].radiance = p.background;
        hits[k].object = kLaserBackground;
        hits[k].depth = kNoHit;
      }
      continue;
    }
    const D2 t = t0s[j], x = sox[j], y = soy[j];
    const D2 fx = Kxx * x + Kxy * y, fy = Kyy * y + Kxy * x;
    const D2 inverse_norm = Set(1.0) / Sqrt(fx * fx + fy * fy + Set(1.0));
    const D2 n_S[3] = {-fx * inverse_norm, -fy * inverse_norm, inverse_norm};
    D2 n_C[3];
    for (int row = 0; row < 3; ++row) {
      n_C[row] =
          Set(R_CS_(row, 0)) * n_S[0] + Set(R_CS_(row, 1)) * n_S[1] + Set(R_CS_(row, 2)) * n_S[2];
    }
    const __m128d flip = Greater(n_C[0] * dx[j] + n_C[1] * dy[j] + n_C[2] * dz[j], Set(0.0));
    for (D2& n : n_C) n = Select(flip, -n, n);
    const D2 px = ox[j] + t * dx[j], py = oy[j] + t * dy[j], pz = oz[j] + t * dz[j];
    const D2 cosine = n_C[0] * dx[j] + n_C[1] * dy[j] + n_C[2] * dz[j];
    const D2 radiance = Set(p.ambient) * (Set(0.3) + Set(0.7) * Abs(cosine));
    D2 distance[2];
    for (int i = 0; i < 2; ++i) {
      const Eigen::Vector3d& n = planes_[i].normal;
      const Eigen::Vector3d& c = planes_[i].point;
      distance[i] = Set(n.x()) * (px - Set(c.x())) + Set(n.y()) * (py - Set(c.y())) +
                    Set(n.z()) * (pz - Set(c.z()));
    }
    const int fallback_bits = _mm_movemask_pd(fallback_mask[j]);
    const int hit_bits = _mm_movemask_pd(hits_mask[j]);
    for (int lane = 0; lane < 2; ++lane) {
      const int k = 2 * j + lane;
      if (k >= count) break;
      done[k] = ((fallback_bits >> lane) & 1) == 0;
      if (!done[k]) continue;
      Hit& out = hits[k];
      if (((hit_bits >> lane) & 1) == 0) {
        out.radiance = p.background;
        out.object = kLaserBackground;
        out.depth = kNoHit;
        continue;
      }
      double value = Lane(radiance, lane);
      for (int i = 0; i < 2; ++i) {
        if (!on[i]) continue;
        const double e = Lane(distance[i], lane);
        const double d2 = e * e;
        if (d2 * inverse_two_sigma2 > 32.0) continue;  // as TraceDetailed (no shadows on a blade)
        value += p.laser_peak * std::exp(-d2 * inverse_two_sigma2);
      }
      out.radiance = std::min(value, 1.0);
      out.object = kLaserSurface;
      out.depth = Lane(t, lane);
    }
  }
}

std::vector<Eigen::Vector3d> LaserScene::StripeCurve(LaserId id, double spacing) const {
  std::vector<Eigen::Vector3d> points;
  if (!(spacing > 0.0)) return points;
  const LaserPlane& laser = plane(id);
  const Eigen::Vector3d z_S = parameters_.X_CS.linear().col(2);
  const Eigen::Vector3d p_C_S = parameters_.X_CS.translation();
  const Eigen::Vector3d l = laser.normal.cross(z_S);
  if (l.norm() < 1e-9) return points;  // the laser plane is parallel to the surface
  const Eigen::Vector3d line = l.normalized();
  // L0: the point of the trace line (laser plane ∩ {z_S = 0}) nearest to S's origin.
  const Eigen::Vector3d w = z_S.cross(line);
  const double alpha = laser.normal.dot(laser.point - p_C_S) / laser.normal.dot(w);
  const Eigen::Vector3d L0 = p_C_S + alpha * w;
  // In-plane direction across the trace, out of the material.
  Eigen::Vector3d m = laser.normal.cross(line);
  if (m.dot(z_S) < 0.0) m = -m;
  // Start above everything: the slab's top and the block's top, plus a margin.
  const double top = height_bound_ + parameters_.gauge_size.z() + 0.01;
  const double lambda0 = top / m.dot(z_S);
  // Range of s along the trace that crosses the extent.
  const Eigen::Vector3d line_S = parameters_.X_CS.linear().transpose() * line;
  const Eigen::Vector3d L0_S = X_SC_ * L0;
  double s_min = -1e9, s_max = 1e9;
  for (int axis = 0; axis < 2; ++axis) {
    const double h = parameters_.half_extent[axis];
    if (std::abs(line_S[axis]) < 1e-12) {
      if (std::abs(L0_S[axis]) > h) return points;
      continue;
    }
    double a = (-h - L0_S[axis]) / line_S[axis], b = (h - L0_S[axis]) / line_S[axis];
    if (a > b) std::swap(a, b);
    s_min = std::max(s_min, a);
    s_max = std::min(s_max, b);
  }
  for (double s = s_min; s <= s_max; s += spacing) {
    Ray ray;
    ray.p_C_O = L0 + s * line + lambda0 * m;
    ray.d_C = -m;
    const double t = IntersectSurface(ray, nullptr, nullptr);
    if (t != kNoHit) points.push_back(ray.p_C_O + t * ray.d_C);
  }
  return points;
}

}  // namespace kinevis::vision::render
