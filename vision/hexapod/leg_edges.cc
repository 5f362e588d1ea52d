#include "vision/hexapod/leg_edges.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <memory>
#include <stdexcept>

#include "vision/render/scenes/hexapod_scene.h"

namespace kinevis::vision::hexapod {
namespace {

constexpr double kMaxSearchHalfWidthPx = 256.0;
// Longest profile: a row or column within 60° of the curve's normal, over ±half/cos.
constexpr int kMaxProfile = 4 * static_cast<int>(kMaxSearchHalfWidthPx) + 4;
constexpr double kTukeyC = 4.685;  // 95 % efficiency at Gaussian noise
constexpr double kHuberK = 1.345;
constexpr double kMadToSigma = 1.4826;

// Appends "name = value (requirement)" to *message (allocates only when something is bad).
void AddBad(std::string* message, const char* name, double value, const char* requirement) {
  char buffer[160];
  std::snprintf(buffer, sizeof(buffer), "%s%s = %g (%s)", message->empty() ? "" : "; ", name, value,
                requirement);
  message->append(buffer);
}

void ThrowIfBad(const vision::ImageView8& image, const CameraModel& camera,
                const LegEdgeOptions& options) {
  std::string message = options.Validate();
  if (image.data == nullptr || image.width != camera.width() || image.height != camera.height() ||
      image.stride < static_cast<size_t>(image.width)) {
    char buffer[200];
    std::snprintf(buffer, sizeof(buffer),
                  "%simage %dx%d (stride %zu, data %s) does not match the %dx%d camera",
                  message.empty() ? "" : "; ", image.width, image.height, image.stride,
                  image.data == nullptr ? "null" : "set", camera.width(), camera.height());
    message.append(buffer);
  }
  if (!camera.IsCentral()) {
    message.append(message.empty() ? "" : "; ");
    message.append("camera model '")
        .append(camera.Name())
        .append("' is not central: leg edges need one viewpoint (the origin of C)");
  }
  if (!message.empty()) throw std::invalid_argument("leg edges: " + message);
}

bool PredictionUsable(const LegPrediction& p) {
  return p.p_C_A.allFinite() && p.p_C_B.allFinite() && std::isfinite(p.radius) && p.radius > 0.0 &&
         (p.p_C_B - p.p_C_A).norm() > 0.0;
}

// Sub-pixel edge location in a profile read outward across a limb (samples at whole pixels
// k = 0 .. count − 1, the leg on the low side), around the central-difference gradient peak
// `best` (gm, g0, gp: the gradients at best − 1, best, best + 1). Returns the offset from best, in
// samples.
//
// kParabola: the vertex of the parabola through gm, g0, gp — exact for an anti-aliased (box-
// filtered) step, whose central differences form a tent with its apex on the step, but pulled
// towards the leg by its shading (below).
//
// kStepRamp: least squares fit of the pixel-integrated (and, with edge_blur_px = σ > 0,
// Gaussian-blurred) model of a limb
//     I(s) = L + c·√(x0 − s)   for s < x0 (the leg),    I(s) = B   for s > x0 (beside it)
// over best − 3 .. best + 3 (L, c, B linear; x0 searched over ±0.5 px around the parabola's
// estimate: a coarse scan, then successive parabolic interpolation between pixel boundaries,
// where the cost is smooth). Why the root: at a limb the cylinder's surface normal turns away
// from the ray as √(distance from the limb in the image) — image distance δ = r (1 − cos α) for a
// normal turned by α, r the apparent radius — so any smooth shading ramps as √δ just inside a
// limb. The ramp adds to the gradient on the leg's side and moves the parabola's vertex into the
// leg by ~0.1 px (the simulator's Lambertian legs, r ≈ 17 px); the fit removes it.
double LocateParabola(double gm, double g0, double gp) {
  const double curvature = gm - 2.0 * g0 + gp;
  const double delta = curvature < 0.0 ? 0.5 * (gm - gp) / curvature : 0.0;
  return std::clamp(delta, -0.5, 0.5);
}

// The model's two shape functions for a pixel whose centre lies d = x0 − k inside the edge (px),
// unblurred: the fraction of the pixel inside the leg, and ∫ √(x0 − s) ds over that part.
inline void SharpBasis(double d, double* inside, double* ramp) {
  *inside = std::clamp(d + 0.5, 0.0, 1.0);
  if (d <= -0.5) {
    *ramp = 0.0;
    return;
  }
  const double a = d + 0.5, b = std::max(0.0, d - 0.5);
  *ramp = (2.0 / 3.0) * (a * std::sqrt(a) - b * std::sqrt(b));
}

// The same blurred by a Gaussian (blur and pixel integration commute: the sharp shape functions
// convolved with the Gaussian). Along a row or column that crosses the edge at θ from its normal
// the profile is the normal one stretched by 1/cos θ, and so is the blur: σ_line = σ / cos θ. So
// the functions are tabulated for σ_line = σ·f, f = 1, 1.1, …, 2 (the search lines are within 60°
// of the normal), every 1/32 px over |d| <= 4.5, and interpolated bilinearly in (d, f) (error
// below 1e-4 of the step). Beyond the table the blur no longer matters: the sharp functions.
class BlurredBasis {
 public:
  void Build(double sigma) {
    sigma_ = sigma;
    constexpr int kNodes = 97;  // trapezoid over ±6σ: the sharp functions have kinks only
    for (int j = 0; j < kFactors; ++j) {
      const double sigma_line = sigma * (1.0 + 0.1 * j);
      std::array<double, kNodes> v, w;
      double total = 0.0;
      for (int i = 0; i < kNodes; ++i) {
        v[i] = sigma_line * (-6.0 + 12.0 * i / (kNodes - 1));
        const double z = v[i] / sigma_line;
        w[i] = std::exp(-0.5 * z * z) * (i == 0 || i == kNodes - 1 ? 0.5 : 1.0);
        total += w[i];
      }
      for (int t = 0; t < kSize; ++t) {
        const double d = -kRange + static_cast<double>(t) / kPerPx;
        double inside = 0.0, ramp = 0.0;
        for (int i = 0; i < kNodes; ++i) {
          double fi, fr;
          SharpBasis(d - v[i], &fi, &fr);
          inside += w[i] * fi;
          ramp += w[i] * fr;
        }
        inside_[j][t] = inside / total;
        ramp_[j][t] = ramp / total;
      }
    }
  }
  double sigma() const { return sigma_; }
  // stretch = σ_line / σ, clamped to [1, 2].
  void Evaluate(double d, double stretch, double* inside, double* ramp) const {
    const double x = (d + kRange) * kPerPx;
    if (!(x >= 0.0 && x < kSize - 1)) {
      SharpBasis(d, inside, ramp);
      return;
    }
    const int i = static_cast<int>(x);
    const double fx = x - i;
    const double y = std::clamp((stretch - 1.0) * 10.0, 0.0, kFactors - 1.0);
    const int j = std::min(static_cast<int>(y), kFactors - 2);
    const double fy = y - j;
    const auto lerp2 = [&](const std::array<std::array<double, kSize>, kFactors>& table) {
      const double lo = table[j][i] + fx * (table[j][i + 1] - table[j][i]);
      const double hi = table[j + 1][i] + fx * (table[j + 1][i + 1] - table[j + 1][i]);
      return lo + fy * (hi - lo);
    };
    *inside = lerp2(inside_);
    *ramp = lerp2(ramp_);
  }

 private:
  static constexpr double kRange = 4.5;
  static constexpr int kPerPx = 32;
  static constexpr int kSize = static_cast<int>(2 * kRange * kPerPx) + 1;
  static constexpr int kFactors = 11;
  double sigma_ = -1.0;
  std::array<std::array<double, kSize>, kFactors> inside_{}, ramp_{};
};

// The tables for σ, built on first use in each thread (a few ms) and kept while σ stays the same
// (rebuilt, without allocating, when it changes).
const BlurredBasis& BlurredBasisFor(double sigma) {
  thread_local std::unique_ptr<BlurredBasis> basis;
  if (basis == nullptr) basis = std::make_unique<BlurredBasis>();
  if (basis->sigma() != sigma) basis->Build(sigma);
  return *basis;
}

// Sum of squared residuals of the best (L, c, B) for an edge at x0, over samples [k0, k1];
// `blurred` is null for a sharp image.
double StepRampCost(const float* profile, int k0, int k1, double x0, const BlurredBasis* blurred,
                    double stretch) {
  double m00 = 0, m01 = 0, m02 = 0, m11 = 0, m12 = 0, m22 = 0, v0 = 0, v1 = 0, v2 = 0, yy = 0;
  for (int k = k0; k <= k1; ++k) {
    double inside, ramp;
    if (blurred == nullptr) {
      SharpBasis(x0 - k, &inside, &ramp);
    } else {
      blurred->Evaluate(x0 - k, stretch, &inside, &ramp);
    }
    const double beside = 1.0 - inside;
    const double y = profile[k];
    m00 += inside * inside;
    m01 += inside * ramp;
    m02 += inside * beside;
    m11 += ramp * ramp;
    m12 += ramp * beside;
    m22 += beside * beside;
    v0 += inside * y;
    v1 += ramp * y;
    v2 += beside * y;
    yy += y * y;
  }
  // Cholesky of the 3×3 normal matrix; cost = yy − vᵀ M⁻¹ v.
  if (!(m00 > 0.0)) return std::numeric_limits<double>::infinity();
  const double l00 = std::sqrt(m00), l10 = m01 / l00, l20 = m02 / l00;
  const double d1 = m11 - l10 * l10;
  if (!(d1 > 1e-12 * m11)) return std::numeric_limits<double>::infinity();
  const double l11 = std::sqrt(d1), l21 = (m12 - l20 * l10) / l11;
  const double d2 = m22 - l20 * l20 - l21 * l21;
  if (!(d2 > 1e-12 * m22)) return std::numeric_limits<double>::infinity();
  const double l22 = std::sqrt(d2);
  const double z0 = v0 / l00, z1 = (v1 - l10 * z0) / l11, z2 = (v2 - l20 * z0 - l21 * z1) / l22;
  return yy - (z0 * z0 + z1 * z1 + z2 * z2);
}

double LocateStepRamp(const float* profile, int count, int best, double parabola, double blur_px,
                      double stretch) {
  const int k0 = std::max(0, best - 3), k1 = std::min(count - 1, best + 3);
  if (k1 - k0 < 5) return parabola;
  const BlurredBasis* blurred = blur_px > 0.0 ? &BlurredBasisFor(blur_px) : nullptr;
  const auto cost = [&](double x) { return StepRampCost(profile, k0, k1, x, blurred, stretch); };
  // Coarse: every 0.25 px over ±0.5 px around the parabola's estimate (the shading pulls it by
  // ~0.1 px).
  const double x_par = best + parabola;
  double x_best = x_par, f_best = std::numeric_limits<double>::infinity();
  for (int i = -2; i <= 2; ++i) {
    const double x = x_par + 0.25 * i;
    const double f = cost(x);
    if (f < f_best) {
      f_best = f;
      x_best = x;
    }
  }
  if (!std::isfinite(f_best)) return parabola;
  // Fine: the sharp model's cost is smooth between pixel boundaries (k ± 0.5), so the minimum is
  // refined by successive parabolic interpolation in the piece around the coarse minimum, from a
  // bracket a < m < b with f(m) <= f(a), f(b).
  const double piece_lo = std::max(x_par - 0.5, std::round(x_best) - 0.5);
  const double piece_hi = std::min(x_par + 0.5, std::round(x_best) + 0.5);
  double a = std::max(piece_lo, x_best - 0.25), b = std::min(piece_hi, x_best + 0.25);
  double m = x_best, fm = f_best, fa = cost(a), fb = cost(b);
  for (int it = 0; it < 6 && b - a > 1e-4; ++it) {
    const double da = m - a, db = m - b;
    const double num = da * da * (fm - fb) - db * db * (fm - fa);
    const double den = 2.0 * (da * (fm - fb) - db * (fm - fa));
    double v = std::abs(den) > 0.0 ? m - num / den : 0.5 * (a + b);
    // Keep the new point strictly inside the bracket, away from m.
    if (!(v > a && v < b) || std::abs(v - m) < 1e-5) {
      v = (m - a > b - m) ? 0.5 * (a + m) : 0.5 * (m + b);
    }
    const double fv = cost(v);
    if (fv <= fm) {
      if (v < m) {
        b = m;
        fb = fm;
      } else {
        a = m;
        fa = fm;
      }
      m = v;
      fm = fv;
    } else if (v < m) {
      a = v;
      fa = fv;
    } else {
      b = v;
      fb = fv;
    }
  }
  return m - best;
}

// stretch = 1 / cos of the angle between the search line and the edge's normal.
double LocateEdge(const float* profile, int count, int best, double gm, double g0, double gp,
                  EdgeLocator locator, double blur_px, double stretch) {
  const double parabola = LocateParabola(gm, g0, gp);
  if (locator == EdgeLocator::kParabola) return parabola;
  return LocateStepRamp(profile, count, best, parabola, blur_px, stretch);
}

// Range [s_lo, s_hi] of s for which p + s e stays in [0, w − 1] × [0, h − 1], intersected with
// [−half, half]. Returns false when empty.
bool ClipToImage(const Eigen::Vector2d& p, const Eigen::Vector2d& e, double half, int width,
                 int height, double* s_lo, double* s_hi) {
  double lo = -half, hi = half;
  const double limits[2] = {static_cast<double>(width - 1), static_cast<double>(height - 1)};
  for (int k = 0; k < 2; ++k) {
    if (std::abs(e[k]) < 1e-12) {
      if (p[k] < 0.0 || p[k] > limits[k]) return false;
      continue;
    }
    double a = (0.0 - p[k]) / e[k], b = (limits[k] - p[k]) / e[k];
    if (a > b) std::swap(a, b);
    lo = std::max(lo, a);
    hi = std::min(hi, b);
  }
  *s_lo = lo;
  *s_hi = hi;
  return hi > lo;
}

// Another leg's silhouette as seen from the origin of C, a region of ray directions bounded by
// four planes through the origin: the two limb planes (normals outward, inside where n · d < 0)
// and the planes through the origin and the end points A, B spanned with the axis' normal
// (inside where e · d > 0). Ignores the end circles' roundness (R ≪ leg length; the margin
// covers it).
struct Silhouette {
  Eigen::Vector3d n1, n2, e_a, e_b;
  Eigen::Vector3d a, w;  // axis start and A → B vector, for the depth test
  double radius = 0.0;
};

bool MakeSilhouette(const OtherLeg& other, Silhouette* s) {
  const LegPrediction& p = other.prediction;
  if (!PredictionUsable(p)) return false;
  if (other.measured) {
    if (!other.n1_C.allFinite() || !other.n2_C.allFinite()) return false;
    s->n1 = other.n1_C.normalized();
    s->n2 = other.n2_C.normalized();
  } else if (!render::PredictCylinderLimbs(p.p_C_A, p.p_C_B, p.radius, &s->n1, &s->n2)) {
    return false;
  }
  const Eigen::Vector3d u = (p.p_C_B - p.p_C_A).normalized();
  const Eigen::Vector3d a_hat = p.p_C_A.normalized(), b_hat = p.p_C_B.normalized();
  s->e_a = u - u.dot(a_hat) * a_hat;
  s->e_b = -(u - u.dot(b_hat) * b_hat);
  s->a = p.p_C_A;
  s->w = p.p_C_B - p.p_C_A;
  s->radius = p.radius;
  return s->e_a.allFinite() && s->e_b.allFinite();
}

// The interval [*lo, *hi] of s where the line X + s δX (seen from the origin, |X + s δX| ≈ depth)
// is inside the silhouette widened by margin_rad. False when it never is.
bool SilhouetteInterval(const Silhouette& sil, const Eigen::Vector3d& X, const Eigen::Vector3d& dX,
                        double depth, double margin_rad, double* lo, double* hi) {
  double l = -std::numeric_limits<double>::infinity();
  double h = std::numeric_limits<double>::infinity();
  // Each condition c · (X + s dX) < k depth, k the margin (signs folded into c).
  auto constrain = [&](const Eigen::Vector3d& c, double k) {
    const double c0 = c.dot(X) - k * depth, c1 = c.dot(dX);
    if (std::abs(c1) < 1e-300) {
      if (c0 >= 0.0) h = -std::numeric_limits<double>::infinity();
      return;
    }
    const double root = -c0 / c1;
    if (c1 > 0.0) {
      h = std::min(h, root);
    } else {
      l = std::max(l, root);
    }
  };
  constrain(sil.n1, margin_rad);
  constrain(sil.n2, margin_rad);
  constrain(-sil.e_a, margin_rad);
  constrain(-sil.e_b, margin_rad);
  *lo = l;
  *hi = h;
  return h > l;
}

// True when the other leg is nearer than `depth` along the ray d (its axis' closest approach).
bool Nearer(const Silhouette& sil, const Eigen::Vector3d& d, double depth) {
  const double ww = sil.w.squaredNorm(), dw = d.dot(sil.w), da = d.dot(sil.a),
               wa = sil.w.dot(sil.a);
  const double denom = ww - dw * dw;  // d is unit
  double mu = denom > 1e-15 * ww ? (dw * da - wa) / denom : 0.0;
  mu = std::clamp(mu, 0.0, 1.0);
  return d.dot(sil.a + mu * sil.w) < depth;
}

// Pixel distance of a point to the curve of plane n, to first order: (n · r) / |Jᵀ n|.
inline double ResidualPx(const EdgePoint& p, const Eigen::Vector3d& n) {
  const double g = (p.d_ray_d_pixel.transpose() * n).norm();
  return g > 0.0 ? n.dot(p.ray_C) / g : std::numeric_limits<double>::infinity();
}

// Median of |points[i].weight| (the field holds residuals at this point) without heap storage:
// selection in a stack buffer, or (more than kMedianBuffer points) bisection on the value.
constexpr int kMedianBuffer = 1024;
double MedianAbsField(const std::vector<EdgePoint>& points) {
  const int n = static_cast<int>(points.size());
  if (n <= kMedianBuffer) {
    std::array<double, kMedianBuffer> buffer;
    for (int i = 0; i < n; ++i) {
      const double r = std::abs(points[i].weight);
      buffer[i] = std::isfinite(r) ? r : std::numeric_limits<double>::max();
    }
    std::nth_element(buffer.begin(), buffer.begin() + n / 2, buffer.begin() + n);
    return buffer[n / 2];
  }
  double hi = 0.0;
  for (const EdgePoint& p : points) {
    if (std::isfinite(p.weight)) hi = std::max(hi, std::abs(p.weight));
  }
  double lo = 0.0;
  for (int pass = 0; pass < 60 && hi - lo > 1e-9 * (1.0 + hi); ++pass) {
    const double mid = 0.5 * (lo + hi);
    int below = 0;
    for (const EdgePoint& p : points) below += std::abs(p.weight) <= mid;
    if (below > n / 2) {
      hi = mid;
    } else {
      lo = mid;
    }
  }
  return hi;
}

// The plane minimising Σ w_i d_i², d_i the pixel distance (n · r_i)/|J_iᵀ n| with the
// denominator frozen at n_lin: smallest eigenvector of Σ w_i r_i r_iᵀ / |J_iᵀ n_lin|². Weights
// from points[i].weight, or 1 when !weighted. False when the points do not define a plane.
bool WeightedPlane(const std::vector<EdgePoint>& points, bool weighted,
                   const Eigen::Vector3d& n_lin, Eigen::Vector3d* n) {
  Eigen::Matrix3d M = Eigen::Matrix3d::Zero();
  for (const EdgePoint& p : points) {
    const double w = weighted ? p.weight : 1.0;
    if (!(w > 0.0)) continue;
    const double g2 = (p.d_ray_d_pixel.transpose() * n_lin).squaredNorm();
    if (!(g2 > 0.0)) continue;
    M.noalias() += (w / g2) * p.ray_C * p.ray_C.transpose();
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver;
  solver.computeDirect(M);
  const Eigen::Vector3d& lambda = solver.eigenvalues();  // ascending
  if (!(lambda(2) > 0.0) || !(lambda(1) > 1e-14 * lambda(2))) return false;
  *n = solver.eigenvectors().col(0).normalized();
  return n->allFinite();
}

}  // namespace

std::string LegEdgeOptions::Validate() const {
  std::string m;
  if (!(search_half_width_px > 0.0 && search_half_width_px <= kMaxSearchHalfWidthPx)) {
    AddBad(&m, "search_half_width_px", search_half_width_px, "must be in (0, 256]");
  }
  if (!(refine_half_width_px >= 0.0 && refine_half_width_px <= search_half_width_px)) {
    AddBad(&m, "refine_half_width_px", refine_half_width_px,
           "must be in [0, search_half_width_px]");
  }
  if (!(sample_step_px > 0.0 && std::isfinite(sample_step_px))) {
    AddBad(&m, "sample_step_px", sample_step_px, "must be finite and > 0");
  }
  if (!(end_margin >= 0.0 && std::isfinite(end_margin))) {
    AddBad(&m, "end_margin", end_margin, "m, must be finite and >= 0");
  }
  if (!(min_gradient > 0.0 && std::isfinite(min_gradient))) {
    AddBad(&m, "min_gradient", min_gradient, "grey levels/px, must be finite and > 0");
  }
  if (polarity != EdgePolarity::kBrightLeg && polarity != EdgePolarity::kDarkLeg &&
      polarity != EdgePolarity::kEither) {
    AddBad(&m, "polarity", static_cast<double>(polarity), "not an EdgePolarity");
  }
  if (!(occlusion_margin_px >= 0.0 && std::isfinite(occlusion_margin_px))) {
    AddBad(&m, "occlusion_margin_px", occlusion_margin_px, "must be finite and >= 0");
  }
  if (min_points < 3) AddBad(&m, "min_points", min_points, "must be >= 3");
  if (!(edge_blur_px >= 0.0 && edge_blur_px <= 3.0)) {
    AddBad(&m, "edge_blur_px", edge_blur_px, "px, must be in [0, 3]");
  }
  if (locator != EdgeLocator::kStepRamp && locator != EdgeLocator::kParabola) {
    AddBad(&m, "locator", static_cast<double>(locator), "not an EdgeLocator");
  }
  if (loss != RobustLoss::kTukey && loss != RobustLoss::kHuber) {
    AddBad(&m, "loss", static_cast<double>(loss), "not a RobustLoss");
  }
  if (ransac_hypotheses < 0) AddBad(&m, "ransac_hypotheses", ransac_hypotheses, "must be >= 0");
  if (!(ransac_threshold_px > 0.0 && std::isfinite(ransac_threshold_px))) {
    AddBad(&m, "ransac_threshold_px", ransac_threshold_px, "must be finite and > 0");
  }
  if (!(min_scale_px > 0.0 && std::isfinite(min_scale_px))) {
    AddBad(&m, "min_scale_px", min_scale_px, "must be finite and > 0");
  }
  if (max_iterations < 1) AddBad(&m, "max_iterations", max_iterations, "must be >= 1");
  if (!(max_outlier_fraction >= 0.0 && max_outlier_fraction < 1.0)) {
    AddBad(&m, "max_outlier_fraction", max_outlier_fraction, "must be in [0, 1)");
  }
  if (!(max_rms_px > 0.0 && std::isfinite(max_rms_px))) {
    AddBad(&m, "max_rms_px", max_rms_px, "must be finite and > 0");
  }
  if (!(max_occluded_fraction > 0.0 && max_occluded_fraction <= 1.0)) {
    AddBad(&m, "max_occluded_fraction", max_occluded_fraction, "must be in (0, 1]");
  }
  if (!(max_width_error > 0.0 && std::isfinite(max_width_error))) {
    AddBad(&m, "max_width_error", max_width_error, "must be finite and > 0");
  }
  if (!(min_limb_separation > 0.0 && min_limb_separation < 1.0)) {
    AddBad(&m, "min_limb_separation", min_limb_separation, "must be in (0, 1)");
  }
  return m;
}

bool MakeEdgePoint(const CameraModel& camera, const Eigen::Vector2d& pixel, EdgePoint* point) {
  Ray ray;
  RayJacobian J;
  if (camera.BackProject(pixel, &ray, &J) != ProjectionStatus::kOk) return false;
  // The limb planes pass through the origin of C: a ray starting elsewhere cannot be used.
  if (!(ray.p_C_O.squaredNorm() <= 1e-18)) return false;
  point->pixel = pixel;
  point->ray_C = ray.d_C;
  point->d_ray_d_pixel = J.d_direction_d_pixel;
  return true;
}

LimbSearchStats FindLimbEdgePoints(const vision::ImageView8& image, const CameraModel& camera,
                                   const LegPrediction& prediction, int limb,
                                   const OtherLeg* others, size_t other_count,
                                   const LegEdgeOptions& options, std::vector<EdgePoint>* points,
                                   const Eigen::Vector3d* refine_n_C) {
  ThrowIfBad(image, camera, options);
  if (limb != 0 && limb != 1) {
    throw std::invalid_argument("leg edges: limb = " + std::to_string(limb) + " (must be 0 or 1)");
  }
  if (points == nullptr) throw std::invalid_argument("leg edges: points is null");
  if (other_count > kMaxOtherLegs || (other_count > 0 && others == nullptr)) {
    throw std::invalid_argument("leg edges: other_count = " + std::to_string(other_count) +
                                " (must be <= 15, with others not null)");
  }
  LimbSearchStats stats;
  if (!PredictionUsable(prediction)) return stats;
  Eigen::Vector3d n1, n2;
  if (!render::PredictCylinderLimbs(prediction.p_C_A, prediction.p_C_B, prediction.radius, &n1,
                                    &n2)) {
    return stats;
  }
  std::array<Silhouette, kMaxOtherLegs> silhouettes;
  size_t silhouette_count = 0;
  for (size_t k = 0; k < other_count; ++k) {
    if (MakeSilhouette(others[k], &silhouettes[silhouette_count])) ++silhouette_count;
  }
  const Eigen::Vector3d n_pred = limb == 0 ? n1 : n2;
  const bool refine = refine_n_C != nullptr && refine_n_C->allFinite() &&
                      refine_n_C->norm() > 0.5 && options.refine_half_width_px > 0.0;
  // The plane whose curve is searched around; its positive side is outside the leg.
  Eigen::Vector3d n_guide = n_pred;
  if (refine) {
    n_guide = refine_n_C->normalized();
    if (n_guide.dot(n_pred) < 0.0) n_guide = -n_guide;
  }
  const double half = refine ? options.refine_half_width_px : options.search_half_width_px;

  const Eigen::Vector3d axis = prediction.p_C_B - prediction.p_C_A;
  const double length = axis.norm();
  // The generator of tangency of limb i: A + R n_i + t (B − A) (n_i ⟂ axis, n_i · A = −R).
  const Eigen::Vector3d start = prediction.p_C_A + prediction.radius * n_pred;
  const double t_begin = options.end_margin / length;
  const double t_end = 1.0 - options.end_margin / length;
  // Polarity: g = −dI/ds along the outward normal is positive on a bright leg's limb.
  const double polarity_sign = options.polarity == EdgePolarity::kDarkLeg ? -1.0 : 1.0;
  const bool either = options.polarity == EdgePolarity::kEither;
  // The search lines are image rows (where the curve is closer to vertical) or columns, every
  // `grid` pixels, and the profile is read at whole pixels: which pixels are read, and so the
  // sub-pixel edge found, does not move with the prediction (a servo's prediction moves by a
  // fraction of a pixel every frame). A row or column crosses the curve at up to 45° from its
  // normal, so it is searched over ±half/cos to cover ±half across the curve.
  const int grid = std::max(1, static_cast<int>(std::lround(options.sample_step_px)));
  float profile[kMaxProfile];
  constexpr double kFallbackDt = 0.005;  // step when a position cannot be projected

  auto point_at = [&](double t) {
    Eigen::Vector3d X = start + t * axis;
    if (refine) X -= n_guide.dot(X) * n_guide;
    return X;
  };

  // Searches grid line `line` (row v = line when along_x, else column u = line) where the curve
  // crosses it, near the curve parameter t_line.
  auto search_line = [&](double t_line, bool along_x, int line) {
    ++stats.samples;
    const Eigen::Vector3d X = point_at(t_line);
    Eigen::Vector2d p;
    Matrix23d J;
    if (camera.Project(X, &p, &J) != ProjectionStatus::kOk) {
      ++stats.out_of_view;
      return;
    }
    const Eigen::Vector2d tangent = J * axis;
    const double speed = tangent.norm();
    if (!(speed > 1e-9)) {
      ++stats.out_of_view;
      return;
    }
    const Eigen::Vector2d t_hat = tangent / speed;
    const double depth = X.norm();
    const Eigen::Vector3d d = X / depth;
    // The image normal of the curve, oriented outward, and the 3-D displacements (⟂ d, at X) that
    // move the pixel: [b1 b2] (J [b1 b2])⁻¹ with b1 = n_guide, b2 = d × n_guide (both ⟂ d: X
    // lies in the guide plane).
    const Eigen::Vector3d b2 = d.cross(n_guide);
    Eigen::Matrix2d M;
    M.col(0) = J * n_guide;
    M.col(1) = J * b2;
    Eigen::Vector2d normal(-t_hat.y(), t_hat.x());
    if (normal.dot(M.col(0)) < 0.0) normal = -normal;
    const double det = M.determinant();
    if (!camera.InImage(p) || !(std::abs(det) > 0.0)) {
      ++stats.out_of_view;
      return;
    }
    // The search direction: along the line, outward.
    const int ax = along_x ? 0 : 1;  // the coordinate that varies along the line
    const int lx = 1 - ax;           // the coordinate that names the line
    Eigen::Vector2d e = Eigen::Vector2d::Zero();
    e[ax] = normal[ax] >= 0.0 ? 1.0 : -1.0;
    const double cos_e = std::abs(normal[ax]);
    if (!(cos_e > 0.5) || !(std::abs(t_hat[lx]) > 0.5)) {  // the caller picks the axis: >= 0.7
      ++stats.out_of_view;
      return;
    }
    // The curve's crossing with the line (along its tangent) and its 3-D point, to first order.
    const Eigen::Vector2d pc = p + ((line - p[lx]) / t_hat[lx]) * t_hat;
    Eigen::Matrix<double, 3, 2> B;
    B.col(0) = n_guide;
    B.col(1) = b2;
    const Eigen::Matrix<double, 3, 2> BMinv = B * M.inverse();
    const Eigen::Vector3d Xc = X + BMinv * (pc - p);
    const Eigen::Vector3d dX = BMinv * e;  // m per px along the line, at depth
    const double rad_per_px = dX.norm() / depth;
    const double half_line = half / cos_e;
    // Other legs: on one's silhouette → skip; else cut the segment where one begins.
    double s_lo = -half_line, s_hi = half_line;
    const double margin_rad = options.occlusion_margin_px * rad_per_px;
    bool on_other = false, other_nearer = false;
    for (size_t k = 0; k < silhouette_count; ++k) {
      double lo, hi;
      if (!SilhouetteInterval(silhouettes[k], Xc, dX, depth, margin_rad, &lo, &hi)) continue;
      if (lo <= 0.0 && hi >= 0.0) {
        on_other = true;
        other_nearer = other_nearer || Nearer(silhouettes[k], d, depth);
      } else if (lo > 0.0) {
        s_hi = std::min(s_hi, lo);
      } else {
        s_lo = std::max(s_lo, hi);
      }
    }
    if (on_other) {
      ++(other_nearer ? stats.occluded : stats.against_leg);
      return;
    }
    if (s_lo > -2.5 || s_hi < 2.5) {
      ++stats.against_leg;  // boxed in between other legs
      return;
    }
    // The segment clipped to the image, both ends inside the model's domain (the image of the
    // unified model's sphere is a disc; outside it the image is black).
    double c_lo, c_hi;
    if (!ClipToImage(pc, e, half_line, image.width, image.height, &c_lo, &c_hi) || c_lo > -2.5 ||
        c_hi < 2.5) {
      ++stats.out_of_view;
      return;
    }
    s_lo = std::max(s_lo, c_lo);
    s_hi = std::min(s_hi, c_hi);
    // Domain check through Project (closed form for every model here, where BackProject may
    // iterate): the 3-D points that map to the segment's ends, to first order.
    Eigen::Vector2d end_pixel;
    if (camera.Project(Xc + s_lo * dX, &end_pixel) != ProjectionStatus::kOk ||
        camera.Project(Xc + s_hi * dX, &end_pixel) != ProjectionStatus::kOk) {
      ++stats.out_of_view;
      return;
    }
    // Whole pixels q = first + sign · k along the line, s = sign · (q − pc[ax]) in [s_lo, s_hi].
    const int sign = e[ax] > 0.0 ? 1 : -1;
    const int first = sign > 0 ? static_cast<int>(std::ceil(pc[ax] + s_lo))
                               : static_cast<int>(std::floor(pc[ax] - s_lo));
    const int last = sign > 0 ? static_cast<int>(std::floor(pc[ax] + s_hi))
                              : static_cast<int>(std::ceil(pc[ax] - s_hi));
    const int count = std::min(kMaxProfile, sign * (last - first) + 1);
    if (along_x) {
      const uint8_t* row = image.data + static_cast<size_t>(line) * image.stride;
      for (int k = 0; k < count; ++k) profile[k] = row[first + sign * k];
    } else {
      const uint8_t* column = image.data + line;
      for (int k = 0; k < count; ++k) {
        profile[k] = column[static_cast<size_t>(first + sign * k) * image.stride];
      }
    }
    // Central-difference gradient along e, signed by the polarity; the peak must be interior so
    // that the sub-pixel locator has neighbours on both sides.
    auto gradient = [&](int k) {
      const double g = -0.5 * (profile[k + 1] - profile[k - 1]) * polarity_sign;
      return either ? std::abs(g) : g;
    };
    int best = -1;
    double best_g = options.min_gradient;
    for (int k = 2; k + 2 < count; ++k) {
      const double g = gradient(k);
      if (g >= best_g) {
        best_g = g;
        best = k;
      }
    }
    if (best < 0) {
      ++stats.no_edge;
      return;
    }
    const double gm = gradient(best - 1), g0 = best_g, gp = gradient(best + 1);
    const double delta = LocateEdge(profile, count, best, gm, g0, gp, options.locator,
                                    options.edge_blur_px, 1.0 / cos_e);
    Eigen::Vector2d pixel;
    pixel[ax] = first + sign * (best + delta);
    pixel[lx] = line;
    EdgePoint point;
    if (!MakeEdgePoint(camera, pixel, &point)) {
      ++stats.out_of_view;
      return;
    }
    point.gradient = g0;
    points->push_back(point);
    ++stats.found;
  };

  // March along the curve about one grid step at a time; every grid line crossed between two
  // consecutive positions is searched (rows while the curve is closer to vertical, else columns).
  double t = t_begin;
  bool have_previous = false;
  double t_previous = 0.0;
  Eigen::Vector2d p_previous = Eigen::Vector2d::Zero();
  while (t <= t_end) {
    Eigen::Vector2d p;
    Matrix23d J;
    if (camera.Project(point_at(t), &p, &J) != ProjectionStatus::kOk) {
      ++stats.samples;
      ++stats.out_of_view;
      have_previous = false;
      t += kFallbackDt;
      continue;
    }
    const Eigen::Vector2d tangent = J * axis;  // px per unit t
    const double speed = tangent.norm();
    if (!(speed > 1e-9)) break;  // the leg is seen end-on
    const bool along_x = std::abs(tangent.y()) >= std::abs(tangent.x());
    const int lx = along_x ? 1 : 0;
    if (have_previous) {
      const double a = p_previous[lx], b = p[lx];
      // Lines m · grid in (a, b] (or [b, a)), each searched once; only those in the image.
      const double last_line = along_x ? image.height - 1 : image.width - 1;
      const double lo = std::max(std::min(a, b), -1.0);
      const double hi = std::min(std::max(a, b), last_line + 1.0);
      const long m_lo = static_cast<long>(std::floor(lo / grid));
      const long m_hi = static_cast<long>(std::ceil(hi / grid));
      const long step = b > a ? 1 : -1;
      for (long m = b > a ? m_lo : m_hi; b != a && m >= m_lo && m <= m_hi; m += step) {
        const double line = static_cast<double>(m * grid);
        const bool crossed = b > a ? (line > a && line <= b) : (line >= b && line < a);
        if (!crossed || line < 0.0 || line > last_line) continue;
        search_line(t_previous + (line - a) / (b - a) * (t - t_previous), along_x,
                    static_cast<int>(m * grid));
      }
    }
    have_previous = true;
    t_previous = t;
    p_previous = p;
    t += grid / speed;
  }
  return stats;
}

LimbFit FitLimbPlane(std::vector<EdgePoint>* points_in, const LegPrediction& prediction,
                     const LegEdgeOptions& options, const Eigen::Vector3d* n_start) {
  const std::string message = options.Validate();
  if (!message.empty()) throw std::invalid_argument("leg edges: " + message);
  if (points_in == nullptr) throw std::invalid_argument("leg edges: points is null");
  std::vector<EdgePoint>& points = *points_in;
  const int n = static_cast<int>(points.size());
  LimbFit fit;
  fit.points = n;
  for (EdgePoint& p : points) {
    p.weight = 0.0;
    p.inlier = false;
  }
  if (n < options.min_points) {
    fit.reason = "too few edge points";
    return fit;
  }
  // Start: MSAC over point pairs (deterministic generator), else plain least squares.
  Eigen::Vector3d n_C = Eigen::Vector3d::Zero();
  bool have_start = false;
  if (n_start != nullptr && n_start->allFinite() && n_start->norm() > 0.5) {
    n_C = n_start->normalized();
    have_start = true;
  } else if (options.ransac_hypotheses > 0) {
    uint64_t state = 0x9E3779B97F4A7C15ull;
    auto next = [&state](int bound) {
      state = state * 6364136223846793005ull + 1442695040888963407ull;
      return static_cast<int>((state >> 33) % static_cast<uint64_t>(bound));
    };
    const double th2 = options.ransac_threshold_px * options.ransac_threshold_px;
    double best_cost = std::numeric_limits<double>::infinity();
    for (int h = 0; h < options.ransac_hypotheses; ++h) {
      const int i = next(n), j = next(n);
      const Eigen::Vector3d c = points[i].ray_C.cross(points[j].ray_C);
      if (!(c.norm() > 1e-6)) continue;  // too close together to define the plane
      const Eigen::Vector3d candidate = c.normalized();
      double cost = 0.0;
      for (int k = 0; k < n && cost < best_cost; ++k) {
        const double r = ResidualPx(points[k], candidate);
        cost += std::min(r * r, th2);
      }
      if (cost < best_cost) {
        best_cost = cost;
        n_C = candidate;
        have_start = true;
      }
    }
  }
  if (!have_start) {
    // Linearise the pixel scale first at a plane through the mean ray, then at that result.
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const EdgePoint& p : points) mean += p.ray_C;
    Eigen::Vector3d lin = mean.unitOrthogonal();
    for (int pass = 0; pass < 2; ++pass) {
      if (!WeightedPlane(points, false, lin, &lin)) {
        fit.reason = "edge points do not span a curve";
        return fit;
      }
    }
    n_C = lin;
  }

  // IRLS on the pixel distances; the points' weight fields hold the residuals, then the weights
  // (scratch without allocation).
  double sigma = options.min_scale_px;
  double cutoff = kTukeyC * sigma;
  auto weight_of = [&](double r) {
    if (!std::isfinite(r)) return 0.0;
    if (options.loss == RobustLoss::kTukey) {
      const double x = r / cutoff;
      return x < 1.0 ? (1.0 - x * x) * (1.0 - x * x) : 0.0;
    }
    const double k = kHuberK * sigma;
    return r <= k ? 1.0 : k / r;
  };
  for (int it = 0; it < options.max_iterations; ++it) {
    fit.iterations = it + 1;
    for (EdgePoint& p : points) p.weight = ResidualPx(p, n_C);
    sigma = std::max(kMadToSigma * MedianAbsField(points), options.min_scale_px);
    cutoff = kTukeyC * sigma;
    for (EdgePoint& p : points) p.weight = weight_of(std::abs(p.weight));
    Eigen::Vector3d next;
    if (!WeightedPlane(points, true, n_C, &next)) {
      fit.reason = "edge points do not span a curve";
      for (EdgePoint& p : points) p.weight = 0.0;
      return fit;
    }
    if (next.dot(n_C) < 0.0) next = -next;
    const double change = (next - n_C).norm();
    n_C = next;
    if (change < 1e-11) break;  // rad: far below any pixel
  }

  // Final residuals, weights, inliers (at the final scale).
  double sum2 = 0.0;
  int inliers = 0;
  for (EdgePoint& p : points) {
    const double r = std::abs(ResidualPx(p, n_C));
    p.inlier = std::isfinite(r) && r < cutoff;
    p.weight = weight_of(r);
    if (p.inlier) {
      ++inliers;
      sum2 += r * r;
    }
  }
  // Orientation: the predicted axis lies on the negative side (seed eq. 12–13).
  const Eigen::Vector3d mid = 0.5 * (prediction.p_C_A + prediction.p_C_B);
  if (n_C.dot(mid) > 0.0) n_C = -n_C;
  fit.n_C = n_C;
  fit.inliers = inliers;
  fit.scale_px = sigma;
  fit.rms_px = inliers > 0 ? std::sqrt(sum2 / inliers) : 0.0;
  if (inliers < options.min_points) {
    fit.reason = "too few inliers";
  } else if (n - inliers > options.max_outlier_fraction * n) {
    fit.reason = "too many outliers";
  } else if (fit.rms_px > options.max_rms_px) {
    fit.reason = "inlier RMS distance too large";
  } else if (!mid.allFinite()) {
    fit.reason = "prediction not finite (cannot orient the normal)";
  } else {
    fit.ok = true;
  }
  return fit;
}

bool LegDirectionFromLimbs(const Eigen::Vector3d& n1_C, const Eigen::Vector3d& n2_C,
                           const Eigen::Vector3d& u_pred_C, Eigen::Vector3d* u_C,
                           double min_separation) {
  // Seed 002 eq. (11). With eq. (3)'s labels n1 × n2 = −sin 2θ u, so the sign is fixed by the
  // prediction.
  const Eigen::Vector3d c = n1_C.cross(n2_C);
  const double norm = c.norm();
  if (!(norm >= min_separation) || !std::isfinite(norm)) return false;
  Eigen::Vector3d u = c / norm;
  const double agreement = u.dot(u_pred_C);
  if (!(std::abs(agreement) > 0.0)) return false;
  if (agreement < 0.0) u = -u;
  *u_C = u;
  return true;
}

std::string_view ToString(LegStatus status) {
  switch (status) {
    case LegStatus::kVisible:
      return "visible";
    case LegStatus::kBadPrediction:
      return "bad prediction";
    case LegStatus::kOutOfView:
      return "out of view";
    case LegStatus::kOccluded:
      return "occluded";
    case LegStatus::kTooFewEdgePoints:
      return "too few edge points";
    case LegStatus::kFitRejected:
      return "fit rejected";
    case LegStatus::kInconsistent:
      return "limbs inconsistent with the leg";
    case LegStatus::kParallelLimbs:
      return "limb planes parallel";
  }
  return "unknown";
}

LegEdgeWorkspace::LegEdgeWorkspace() {
  for (auto& leg : points) {
    for (auto& limb : leg) limb.reserve(1024);
  }
  for (LegObservation& o : observations) o.reason.reserve(256);
}

namespace {

// Sets the observation to not visible with a reason (no allocation while it fits the capacity).
void Refuse(LegObservation* o, LegStatus status, const char* detail) {
  o->visible = false;
  o->status = status;
  o->u_C.setZero();
  o->reason.assign(detail);
}

// Why a limb's search cannot support a fit, or kVisible when it can.
LegStatus JudgeSearch(const LimbSearchStats& s, const LegEdgeOptions& options, int leg, int limb,
                      char* buffer, size_t size) {
  const int in_view = s.samples - s.out_of_view;
  const int on_others = s.occluded + s.against_leg;
  if (in_view < options.min_points) {
    std::snprintf(buffer, size, "leg %d: out of view (limb %d: %d of %d search positions in view)",
                  leg, limb, in_view, s.samples);
    return LegStatus::kOutOfView;
  }
  if (on_others > options.max_occluded_fraction * in_view ||
      in_view - on_others < options.min_points) {
    std::snprintf(buffer, size,
                  "leg %d: occluded (limb %d: of %d search positions in view, %d behind other "
                  "legs, %d against another leg)",
                  leg, limb, in_view, s.occluded, s.against_leg);
    return LegStatus::kOccluded;
  }
  if (s.found < options.min_points) {
    std::snprintf(buffer, size,
                  "leg %d: too few edge points (limb %d: %d found at %d positions, need %d)", leg,
                  limb, s.found, in_view - on_others, options.min_points);
    return LegStatus::kTooFewEdgePoints;
  }
  return LegStatus::kVisible;
}

// One search + fit of one limb; on failure writes the reason into buffer.
LegStatus SearchAndFit(const vision::ImageView8& image, const CameraModel& camera,
                       const LegPrediction& pred, int leg, int limb, const OtherLeg* others,
                       size_t other_count, const LegEdgeOptions& options,
                       const Eigen::Vector3d* refine, std::vector<EdgePoint>* points,
                       LegObservation* o, char* buffer, size_t size) {
  points->clear();
  o->search[limb] =
      FindLimbEdgePoints(image, camera, pred, limb, others, other_count, options, points, refine);
  const LegStatus status = JudgeSearch(o->search[limb], options, leg, limb, buffer, size);
  if (status != LegStatus::kVisible) return status;
  o->limbs[limb] = FitLimbPlane(points, pred, options, refine);
  if (!o->limbs[limb].ok) {
    std::snprintf(buffer, size,
                  "leg %d: fit rejected (limb %d, %s pass: %s; %d points, %d inliers, RMS %.3g px)",
                  leg, limb, refine != nullptr ? "refining" : "first", o->limbs[limb].reason,
                  o->limbs[limb].points, o->limbs[limb].inliers, o->limbs[limb].rms_px);
    return LegStatus::kFitRejected;
  }
  return LegStatus::kVisible;
}

// The leg-level checks after both limbs are fitted: the apparent width and eq. (11). Sets the
// observation visible with u_C, or refuses it with a reason.
LegStatus FinishLeg(const LegPrediction& pred, const Eigen::Vector3d& n1p,
                    const Eigen::Vector3d& n2p, int j, const LegEdgeOptions& options,
                    LegObservation* o) {
  char buffer[256];
  // Apparent width: the limb planes make the angle π − 2θ, sin θ = R / (distance to the axis),
  // i.e. −n1 · n2 = cos 2θ (eq. 3). Compare with the prediction's.
  const Eigen::Vector3d& n1 = o->limbs[0].n_C;
  const Eigen::Vector3d& n2 = o->limbs[1].n_C;
  const double two_theta = std::acos(std::clamp(-n1.dot(n2), -1.0, 1.0));
  const double two_theta_pred = std::acos(std::clamp(-n1p.dot(n2p), -1.0, 1.0));
  if (!(std::abs(two_theta - two_theta_pred) <= options.max_width_error * two_theta_pred) ||
      n1.dot(n1p) <= 0.0 || n2.dot(n2p) <= 0.0) {
    std::snprintf(buffer, sizeof(buffer),
                  "leg %d: limbs inconsistent with the leg (they subtend %.4g rad, a leg of "
                  "radius %g m at the predicted distance %.4g rad)",
                  j, two_theta, pred.radius, two_theta_pred);
    Refuse(o, LegStatus::kInconsistent, buffer);
    return LegStatus::kInconsistent;
  }
  Eigen::Vector3d u;
  if (!LegDirectionFromLimbs(n1, n2, pred.p_C_B - pred.p_C_A, &u, options.min_limb_separation)) {
    std::snprintf(buffer, sizeof(buffer),
                  "leg %d: limb planes parallel (|n1 x n2| = %.3g < min_limb_separation %g)", j,
                  n1.cross(n2).norm(), options.min_limb_separation);
    Refuse(o, LegStatus::kParallelLimbs, buffer);
    return LegStatus::kParallelLimbs;
  }
  o->visible = true;
  o->status = LegStatus::kVisible;
  o->reason.clear();
  o->u_C = u;
  return LegStatus::kVisible;
}

}  // namespace

const std::array<LegObservation, kLegs>& ObserveLegs(
    const vision::ImageView8& image, const CameraModel& camera,
    const std::array<LegPrediction, kLegs>& predictions, const LegEdgeOptions& options,
    LegEdgeWorkspace* workspace) {
  if (workspace == nullptr) throw std::invalid_argument("leg edges: workspace is null");
  ThrowIfBad(image, camera, options);
  char buffer[256];
  std::array<LegStatus, kLegs> status;
  std::array<Eigen::Vector3d, kLegs> n1p, n2p;
  // Round 1: wide search around the predictions; others' silhouettes from their predictions.
  std::array<OtherLeg, kLegs> all;
  for (int j = 0; j < kLegs; ++j) {
    all[j].prediction = predictions[j];
    all[j].measured = false;
  }
  auto others_of = [&](int j, std::array<OtherLeg, kLegs - 1>* others) {
    int k = 0;
    for (int i = 0; i < kLegs; ++i) {
      if (i != j) (*others)[k++] = all[i];
    }
  };
  std::array<OtherLeg, kLegs - 1> others;
  // Round 1 only guides round 2 (when there is one): the cheaper locator is enough.
  LegEdgeOptions first_options = options;
  if (options.refine_half_width_px > 0.0) first_options.locator = EdgeLocator::kParabola;
  for (int j = 0; j < kLegs; ++j) {
    LegObservation& o = workspace->observations[j];
    o.search = {};
    o.limbs = {};
    o.visible = false;
    o.u_C.setZero();
    const LegPrediction& pred = predictions[j];
    if (!PredictionUsable(pred) ||
        !render::PredictCylinderLimbs(pred.p_C_A, pred.p_C_B, pred.radius, &n1p[j], &n2p[j])) {
      std::snprintf(buffer, sizeof(buffer),
                    "leg %d: bad prediction (A = (%g %g %g) m, B = (%g %g %g) m, R = %g m: not "
                    "finite, R <= 0, A = B or the viewpoint inside the cylinder)",
                    j, pred.p_C_A.x(), pred.p_C_A.y(), pred.p_C_A.z(), pred.p_C_B.x(),
                    pred.p_C_B.y(), pred.p_C_B.z(), pred.radius);
      status[j] = LegStatus::kBadPrediction;
      Refuse(&o, status[j], buffer);
      continue;
    }
    others_of(j, &others);
    status[j] = LegStatus::kVisible;
    for (int limb = 0; limb < 2 && status[j] == LegStatus::kVisible; ++limb) {
      status[j] =
          SearchAndFit(image, camera, pred, j, limb, others.data(), others.size(), first_options,
                       nullptr, &workspace->points[j][limb], &o, buffer, sizeof(buffer));
    }
    if (status[j] != LegStatus::kVisible) Refuse(&o, status[j], buffer);
  }
  // Round 2: narrow search around each round-1 fit; others' silhouettes from their fits.
  for (int j = 0; j < kLegs; ++j) {
    if (status[j] != LegStatus::kVisible) continue;
    all[j].measured = true;
    all[j].n1_C = workspace->observations[j].limbs[0].n_C;
    all[j].n2_C = workspace->observations[j].limbs[1].n_C;
  }
  for (int j = 0; j < kLegs; ++j) {
    if (status[j] != LegStatus::kVisible) continue;
    LegObservation& o = workspace->observations[j];
    const LegPrediction& pred = predictions[j];
    if (options.refine_half_width_px > 0.0) {
      others_of(j, &others);
      for (int limb = 0; limb < 2 && status[j] == LegStatus::kVisible; ++limb) {
        const Eigen::Vector3d refine = o.limbs[limb].n_C;
        status[j] =
            SearchAndFit(image, camera, pred, j, limb, others.data(), others.size(), options,
                         &refine, &workspace->points[j][limb], &o, buffer, sizeof(buffer));
      }
      if (status[j] != LegStatus::kVisible) {
        Refuse(&o, status[j], buffer);
        continue;
      }
    }
    status[j] = FinishLeg(pred, n1p[j], n2p[j], j, options, &o);
  }
  return workspace->observations;
}

const std::array<LegObservation, kLegs>& RefitObservedLegs(
    const std::array<LegPrediction, kLegs>& predictions, const LegEdgeOptions& options,
    LegEdgeWorkspace* workspace) {
  if (workspace == nullptr) throw std::invalid_argument("leg edges: workspace is null");
  const std::string message = options.Validate();
  if (!message.empty()) throw std::invalid_argument("leg edges: " + message);
  char buffer[256];
  for (int j = 0; j < kLegs; ++j) {
    LegObservation& o = workspace->observations[j];
    if (!o.visible) continue;
    const LegPrediction& pred = predictions[j];
    Eigen::Vector3d n1p, n2p;
    if (!PredictionUsable(pred) ||
        !render::PredictCylinderLimbs(pred.p_C_A, pred.p_C_B, pred.radius, &n1p, &n2p)) {
      Refuse(&o, LegStatus::kBadPrediction, "bad prediction");
      continue;
    }
    bool ok = true;
    for (int limb = 0; limb < 2 && ok; ++limb) {
      // From scratch (MSAC start): the previous fit is of other points.
      o.limbs[limb] = FitLimbPlane(&workspace->points[j][limb], pred, options, nullptr);
      if (!o.limbs[limb].ok) {
        std::snprintf(buffer, sizeof(buffer),
                      "leg %d: fit rejected (limb %d, refit: %s; %d points, %d inliers, RMS "
                      "%.3g px)",
                      j, limb, o.limbs[limb].reason, o.limbs[limb].points, o.limbs[limb].inliers,
                      o.limbs[limb].rms_px);
        Refuse(&o, LegStatus::kFitRejected, buffer);
        ok = false;
      }
    }
    if (ok) FinishLeg(pred, n1p, n2p, j, options, &o);
  }
  return workspace->observations;
}

std::array<LegObservation, kLegs> ObserveLegs(const vision::ImageView8& image,
                                              const CameraModel& camera,
                                              const std::array<LegPrediction, kLegs>& predictions,
                                              const LegEdgeOptions& options) {
  LegEdgeWorkspace workspace;
  return ObserveLegs(image, camera, predictions, options, &workspace);
}

}  // namespace kinevis::vision::hexapod
