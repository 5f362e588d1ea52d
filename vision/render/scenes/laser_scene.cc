#include "vision/render/scenes/laser_scene.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "vision/render/primitives.h"

namespace kinevis::vision::render {
namespace {

class Problems {
 public:
  void Add(const std::string& name, double value, const char* rule) {
    out_ << (out_.tellp() > 0 ? "; " : "") << name << " = " << value << " (" << rule << ")";
  }
  std::string str() const { return out_.str(); }

 private:
  std::ostringstream out_;
};

bool InUnit(double x) { return std::isfinite(x) && x >= 0.0 && x <= 1.0; }

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
  Problems bad;
  if (!std::isfinite(rotating_b_y)) bad.Add("scanner.rotating_b_y", rotating_b_y, "finite");
  if (!std::isfinite(rotating_d_y)) bad.Add("scanner.rotating_d_y", rotating_d_y, "finite");
  if (!std::isfinite(fixed_b_x_prime)) {
    bad.Add("scanner.fixed_b_x_prime", fixed_b_x_prime, "finite");
  }
  if (!std::isfinite(fixed_cot_theta_x)) {
    bad.Add("scanner.fixed_cot_theta_x", fixed_cot_theta_x, "finite");
  }
  return bad.str();
}

bool LaserHit::Lit(LaserId id) const {
  const int i = static_cast<int>(id);
  return hit.object != kLaserBackground && reached[i] &&
         std::abs(plane_distance[i]) <= 3.0 * stripe_sigma;
}

std::string LaserSceneParameters::Validate() const {
  Problems bad;
  const std::string scanner_problems = scanner.Validate();
  std::string message = scanner_problems;
  if (!std::isfinite(rotating_cot_theta_y)) {
    bad.Add("rotating_cot_theta_y", rotating_cot_theta_y, "finite");
  }
  if (!X_CS.matrix().allFinite()) bad.Add("X_CS", X_CS.translation().norm(), "finite");
  if (!(half_extent.allFinite() && half_extent.minCoeff() > 0.0)) {
    bad.Add("half_extent", half_extent.minCoeff(), "both > 0");
  }
  const double curvatures[3] = {curvature_xx, curvature_yy, curvature_xy};
  const char* curvature_names[3] = {"curvature_xx", "curvature_yy", "curvature_xy"};
  for (int i = 0; i < 3; ++i) {
    if (!(std::isfinite(curvatures[i]) && std::abs(curvatures[i]) <= 20.0)) {
      bad.Add(curvature_names[i], curvatures[i], "|.| <= 20 1/m");
    }
  }
  if (pits.size() > 64) bad.Add("pits.size()", static_cast<double>(pits.size()), "<= 64");
  for (size_t k = 0; k < pits.size(); ++k) {
    const std::string name = "pits[" + std::to_string(k) + "]";
    if (!pits[k].centre_S.allFinite()) bad.Add(name + ".centre_S", pits[k].centre_S.x(), "finite");
    if (!(std::isfinite(pits[k].depth) && pits[k].depth > 0.0 && pits[k].depth < 0.05)) {
      bad.Add(name + ".depth", pits[k].depth, "in (0, 0.05) m");
    }
    if (!(std::isfinite(pits[k].sigma) && pits[k].sigma >= 1e-4 && pits[k].sigma < 0.1)) {
      bad.Add(name + ".sigma", pits[k].sigma, "in [1e-4, 0.1) m");
    }
  }
  if (!gauge_centre_S.allFinite()) bad.Add("gauge_centre_S", gauge_centre_S.x(), "finite");
  if (!std::isfinite(gauge_heading)) bad.Add("gauge_heading", gauge_heading, "finite");
  if (!(gauge_size.allFinite() && gauge_size.minCoeff() > 0.0)) {
    bad.Add("gauge_size", gauge_size.minCoeff(), "all > 0");
  }
  if (!InUnit(ambient)) bad.Add("ambient", ambient, "in [0, 1]");
  if (!InUnit(background)) bad.Add("background", background, "in [0, 1]");
  if (!InUnit(laser_peak)) bad.Add("laser_peak", laser_peak, "in [0, 1]");
  if (!(std::isfinite(stripe_sigma) && stripe_sigma >= 0.05e-3 && stripe_sigma <= 2e-3)) {
    bad.Add("stripe_sigma", stripe_sigma, "in [5e-5, 2e-3] m");
  }
  const std::string own = bad.str();
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
  const double hx = parameters.half_extent.x(), hy = parameters.half_extent.y();
  if (parameters.surface == LaserSurfaceKind::kBlade) {
    height_bound_ = 0.5 * std::abs(parameters.curvature_xx) * hx * hx +
                    0.5 * std::abs(parameters.curvature_yy) * hy * hy +
                    std::abs(parameters.curvature_xy) * hx * hy;
    min_pit_sigma_ = 1.0;
    for (const CavitationPit& pit : parameters.pits) {
      pit_depth_sum_ += pit.depth;
      min_pit_sigma_ = std::min(min_pit_sigma_, pit.sigma);
    }
  }
  X_CB_ = parameters.X_CS *
          Eigen::Translation3d(parameters.gauge_centre_S.x(), parameters.gauge_centre_S.y(),
                               0.5 * parameters.gauge_size.z()) *
          Eigen::AngleAxisd(parameters.gauge_heading, Eigen::Vector3d::UnitZ());
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
    double ta = (z_hi - o.z()) / d.z(), tb = (z_lo - o.z()) / d.z();
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = tb;
  }
  if (!(t1 > t0)) return kNoHit;
  auto g = [&](double t) {
    const Eigen::Vector3d p = o + t * d;
    return p.z() - Height(p.x(), p.y());
  };
  // March so that no pit can be stepped over: horizontal travel per step ≤ σ_min / 4.
  const double horizontal = std::hypot(d.x(), d.y());
  int steps = 8;
  if (!parameters_.pits.empty() && horizontal > 0.0) {
    const double wanted = (t1 - t0) * horizontal / (0.25 * min_pit_sigma_);
    steps = std::max(steps, static_cast<int>(std::min(std::ceil(wanted), 4096.0)));
  }
  const double dt = (t1 - t0) / steps;
  double ta = t0, ga = g(ta);
  for (int i = 1; i <= steps; ++i) {
    const double tb = t0 + i * dt;
    const double gb = g(tb);
    if ((ga > 0.0) != (gb > 0.0)) {
      // Illinois regula falsi on [ta, tb].
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
      }
      const double t = 0.5 * (a + b);
      const Eigen::Vector3d p = o + t * d;
      if (std::abs(p.x()) <= hx && std::abs(p.y()) <= hy) {
        if (n_S != nullptr) {
          // ∇f by the analytic derivative of each term.
          double fx = parameters_.curvature_xx * p.x() + parameters_.curvature_xy * p.y();
          double fy = parameters_.curvature_yy * p.y() + parameters_.curvature_xy * p.x();
          for (const CavitationPit& pit : parameters_.pits) {
            const double dx = p.x() - pit.centre_S.x(), dy = p.y() - pit.centre_S.y();
            const double s2 = pit.sigma * pit.sigma;
            const double e = pit.depth * std::exp(-(dx * dx + dy * dy) / (2.0 * s2));
            fx += e * dx / s2;
            fy += e * dy / s2;
          }
          *n_S = Eigen::Vector3d(-fx, -fy, 1.0).normalized();
        }
        return t;
      }
    }
    ta = tb;
    ga = gb;
  }
  return kNoHit;
}

double LaserScene::IntersectSurface(const Ray& ray_C, int* object, Eigen::Vector3d* n_C) const {
  Ray ray_S;
  ray_S.p_C_O = X_SC_ * ray_C.p_C_O;
  ray_S.d_C = X_SC_.linear() * ray_C.d_C;
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
  Eigen::Vector3d normal = parameters_.X_CS.linear() * n_S;
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
  if (n_C != nullptr) *n_C = normal.dot(ray_C.d_C) > 0.0 ? -normal : normal;
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
  out.p_C = ray_C.p_C_O + t * ray_C.d_C;
  out.n_C = n_C;
  out.hit.object = object;
  out.hit.depth = t;
  double radiance = parameters_.ambient * (0.3 + 0.7 * std::abs(n_C.dot(ray_C.d_C)));
  const bool on[2] = {parameters_.fixed_on, parameters_.rotating_on};
  const double inverse_two_sigma2 =
      1.0 / (2.0 * parameters_.stripe_sigma * parameters_.stripe_sigma);
  for (int i = 0; i < 2; ++i) {
    out.plane_distance[i] = planes_[i].SignedDistance(out.p_C);
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
  out.hit.radiance = std::min(radiance, 1.0);
  return out;
}

Hit LaserScene::Trace(const Ray& ray_C) const { return TraceDetailed(ray_C).hit; }

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
