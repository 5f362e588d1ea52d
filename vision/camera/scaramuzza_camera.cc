#include "vision/camera/scaramuzza_camera.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "common/units.h"

namespace kinevis::vision {
namespace {

constexpr int kMaxFitDegree = 30;
constexpr int kFitSweepIntervals = 8192;
constexpr int kMonotonicSweepIntervals = 4096;
constexpr int kMaxRootIterations = 100;

double Polynomial(const std::array<double, 5>& a, double rho, double* df) {
  double f = a[4];
  double d = 0.0;
  for (int i = 3; i >= 0; --i) {
    d = d * rho + f;
    f = f * rho + a[i];
  }
  if (df != nullptr) *df = d;
  return f;
}

// Ideal sensor point (OCamCalib's (x, y) = (a, b)) of a pixel: [v - v0; u - u0] = A [a; b].
Eigen::Vector2d IdealPoint(const ScaramuzzaParameters& p, double u, double v) {
  const double det = p.c - p.d * p.e;
  const double du = u - p.u0, dv = v - p.v0;
  return Eigen::Vector2d((dv - p.d * du) / det, (p.c * du - p.e * dv) / det);
}

// ρ_max actually used: the parameter, or the farthest image corner (pixel edges) in ideal
// coordinates.
double MaxRadius(const ScaramuzzaParameters& p) {
  if (p.max_radius_px > 0.0) return p.max_radius_px;
  double rho = 0.0;
  for (double u : {-0.5, p.width - 0.5}) {
    for (double v : {-0.5, p.height - 0.5}) rho = std::max(rho, IdealPoint(p, u, v).norm());
  }
  return rho;
}

// Clenshaw evaluation of Σ c_j T_j(t).
double Chebyshev(const std::vector<double>& c, double t) {
  double b1 = 0.0, b2 = 0.0;
  for (int j = static_cast<int>(c.size()) - 1; j >= 1; --j) {
    const double b0 = c[j] + 2.0 * t * b1 - b2;
    b2 = b1;
    b1 = b0;
  }
  return c.empty() ? 0.0 : c[0] + t * b1 - b2;
}

}  // namespace

ScaramuzzaParameters ScaramuzzaParameters::Default() {
  ScaramuzzaParameters p;
  p.width = 752;
  p.height = 480;
  p.poly = {-2.065170e+02, 0.0, 2.207161e-03, -4.879622e-06, 1.865656e-08};
  p.u0 = 394.552874;  // calib_results.txt: column (second number), 0-based
  p.v0 = 241.800066;  // row (first number), 0-based
  p.c = 1.000330;
  p.d = 0.000219;
  p.e = 0.000257;
  p.max_radius_px = 0.0;  // the image corners
  p.inverse_fit_tolerance_px = 0.01;
  return p;
}

ScaramuzzaCamera::ScaramuzzaCamera(const ScaramuzzaParameters& parameters,
                                   ScaramuzzaProjection projection)
    : parameters_(parameters), projection_(projection) {
  const std::string problems = Validate();
  if (!problems.empty()) throw std::invalid_argument("scaramuzza camera: " + problems);
  rho_max_ = MaxRadius(parameters_);
  phi_max_ = std::atan2(rho_max_, -F(rho_max_));
  FitInverse();
}

double ScaramuzzaCamera::F(double rho, double* df) const {
  return Polynomial(parameters_.poly, rho, df);
}

std::string ScaramuzzaCamera::Validate() const {
  const ScaramuzzaParameters& p = parameters_;
  std::ostringstream errors;
  if (p.width <= 0) errors << "width = " << p.width << " must be > 0; ";
  if (p.height <= 0) errors << "height = " << p.height << " must be > 0; ";
  bool poly_ok = true;
  for (int i = 0; i < 5; ++i) {
    if (!std::isfinite(p.poly[i])) {
      errors << "poly[" << i << "] (a" << i << ") = " << p.poly[i] << " is not finite; ";
      poly_ok = false;
    }
  }
  if (poly_ok && !(p.poly[0] < 0.0)) {
    errors << "poly[0] (a0) = " << p.poly[0]
           << " must be < 0 (OCamCalib's z points away from the centre's line of sight); ";
    poly_ok = false;
  }
  bool geometry_ok = true;
  for (const auto& [value, name] :
       {std::pair{p.u0, "u0"}, std::pair{p.v0, "v0"}, std::pair{p.c, "c"}, std::pair{p.d, "d"},
        std::pair{p.e, "e"}}) {
    if (!std::isfinite(value)) {
      errors << name << " = " << value << " is not finite; ";
      geometry_ok = false;
    }
  }
  if (geometry_ok && !(p.c - p.d * p.e > 1e-9)) {
    errors << "affine c - d*e = " << p.c - p.d * p.e << " (c = " << p.c << ", d = " << p.d
           << ", e = " << p.e << ") must be > 0; ";
    geometry_ok = false;
  }
  if (!(std::isfinite(p.max_radius_px) && p.max_radius_px >= 0.0)) {
    errors << "max_radius_px = " << p.max_radius_px << " must be >= 0 (0: image corners); ";
    geometry_ok = false;
  }
  if (!(std::isfinite(p.inverse_fit_tolerance_px) && p.inverse_fit_tolerance_px > 0.0)) {
    errors << "inverse_fit_tolerance_px = " << p.inverse_fit_tolerance_px << " must be > 0; ";
  }
  if (poly_ok && geometry_ok && p.width > 0 && p.height > 0) {
    // φ(ρ) = atan2(ρ, -f(ρ)) increases iff dφ/dρ ∝ ρ f'(ρ) - f(ρ) > 0.
    const double rho_max = MaxRadius(p);
    for (int i = 0; i <= kMonotonicSweepIntervals; ++i) {
      const double rho = rho_max * i / kMonotonicSweepIntervals;
      double df = 0.0;
      const double f = Polynomial(p.poly, rho, &df);
      if (!(rho * df - f > 0.0)) {
        errors << "poly = [" << p.poly[0] << ", " << p.poly[1] << ", " << p.poly[2] << ", "
               << p.poly[3] << ", " << p.poly[4]
               << "]: the viewing angle is not increasing at rho = " << rho
               << " px within max radius " << rho_max << " px (reduce max_radius_px); ";
        break;
      }
    }
  }
  std::string message = errors.str();
  if (message.size() >= 2) message.resize(message.size() - 2);
  return message;
}

ProjectionStatus ScaramuzzaCamera::SolveRadius(double r, double z, double rho_guess,
                                               double* rho) const {
  if (r == 0.0) {  // on the axis (z > 0 here): the centre
    *rho = 0.0;
    return ProjectionStatus::kOk;
  }
  // h(ρ) = ρ z + f(ρ) r ∝ sin(φ(ρ) - φ): negative below the root, positive above (φ(ρ) increases).
  double lo = 0.0, hi = rho_max_;
  double x = std::clamp(rho_guess, lo, hi);
  for (int iteration = 0; iteration < kMaxRootIterations; ++iteration) {
    double df = 0.0;
    const double h = x * z + F(x, &df) * r;
    if (h == 0.0) {
      *rho = x;
      return ProjectionStatus::kOk;
    }
    if (h < 0.0) {
      lo = x;
    } else {
      hi = x;
    }
    const double dh = z + df * r;
    double next = dh > 0.0 ? x - h / dh : 0.5 * (lo + hi);
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);  // safeguard: bisect
    const double step = std::abs(next - x);
    x = next;
    if (step <= 1e-14 * (x + 1e-6 * rho_max_)) {
      *rho = x;
      return ProjectionStatus::kOk;
    }
  }
  *rho = x;
  return ProjectionStatus::kNoConvergence;
}

ProjectionStatus ScaramuzzaCamera::ExactRadius(double phi, double* rho) const {
  if (!(phi >= 0.0 && phi <= phi_max_)) return ProjectionStatus::kOutsideDomain;
  return SolveRadius(std::sin(phi), std::cos(phi), -parameters_.poly[0] * phi, rho);
}

double ScaramuzzaCamera::FittedRadius(double phi, double* drho_dphi) const {
  const double t = 2.0 * phi / phi_max_ - 1.0;
  const double g = Chebyshev(chebyshev_, t);
  if (drho_dphi != nullptr) {
    *drho_dphi = g + phi * Chebyshev(chebyshev_derivative_, t) * 2.0 / phi_max_;
  }
  return phi * g;
}

void ScaramuzzaCamera::FitInverse() {
  fit_ = InverseFit{};
  fit_.max_radius_px = rho_max_;
  fit_.max_angle = phi_max_;
  // A pixel error of Δρ along the ideal radius is at most σ_max(A) Δρ in the image.
  Eigen::Matrix2d A;
  A << parameters_.c, parameters_.d, parameters_.e, 1.0;
  const double gain = Eigen::JacobiSVD<Eigen::Matrix2d>(A).singularValues()(0);

  std::vector<double> sweep_rho(kFitSweepIntervals + 1), sweep_phi(kFitSweepIntervals + 1);
  for (int i = 0; i <= kFitSweepIntervals; ++i) {
    sweep_rho[i] = rho_max_ * i / kFitSweepIntervals;
    sweep_phi[i] = std::atan2(sweep_rho[i], -F(sweep_rho[i]));
  }
  for (int n = 0; n <= kMaxFitDegree; ++n) {
    // Interpolate G(φ) = ρ(φ)/φ at the n + 1 Chebyshev nodes of [0, φ_max] (near-minimax).
    std::vector<double> g(n + 1), t(n + 1);
    bool ok = true;
    for (int k = 0; k <= n && ok; ++k) {
      t[k] = std::cos(common::kPi * (k + 0.5) / (n + 1));
      const double phi = 0.5 * (t[k] + 1.0) * phi_max_;
      double rho = 0.0;
      ok = ExactRadius(phi, &rho) == ProjectionStatus::kOk;
      g[k] = rho / phi;
    }
    if (!ok) break;
    chebyshev_.assign(n + 1, 0.0);
    for (int j = 0; j <= n; ++j) {
      double sum = 0.0;
      for (int k = 0; k <= n; ++k) sum += g[k] * std::cos(j * common::kPi * (k + 0.5) / (n + 1));
      chebyshev_[j] = (j == 0 ? 1.0 : 2.0) * sum / (n + 1);
    }
    chebyshev_derivative_.assign(std::max(n, 1), 0.0);
    {
      // d_{j-1} = d_{j+1} + 2 j c_j, then halve d_0 (so that dG/dt = Σ d_j T_j).
      std::vector<double> d(n + 2, 0.0);
      for (int j = n; j >= 1; --j) d[j - 1] = d[j + 1] + 2.0 * j * chebyshev_[j];
      d[0] *= 0.5;
      for (int j = 0; j < n; ++j) chebyshev_derivative_[j] = d[j];
    }
    double max_error = 0.0;
    for (int i = 0; i <= kFitSweepIntervals; ++i) {
      max_error = std::max(max_error, std::abs(FittedRadius(sweep_phi[i]) - sweep_rho[i]));
    }
    max_error *= gain;
    if (max_error <= parameters_.inverse_fit_tolerance_px) {
      fit_.fitted = true;
      fit_.degree = n;
      fit_.max_error_px = max_error;
      return;
    }
    fit_.max_error_px = max_error;  // best so far, reported when no degree meets the bound
  }
  chebyshev_.clear();
  chebyshev_derivative_.clear();
}

ProjectionStatus ScaramuzzaCamera::Project(const Eigen::Vector3d& p_C, Eigen::Vector2d* pixel,
                                           Matrix23d* J_pixel_point) const {
  if (!p_C.allFinite()) return ProjectionStatus::kOutsideDomain;
  const double x = p_C.x(), y = p_C.y(), z = p_C.z();
  const double r = std::hypot(x, y);
  const double norm2 = r * r + z * z;
  if (!(norm2 > 0.0)) return ProjectionStatus::kOutsideDomain;
  const double phi = std::atan2(r, z);
  if (!(phi <= phi_max_)) return ProjectionStatus::kOutsideDomain;

  double rho = 0.0, drho_dr = 0.0, drho_dz = 0.0;
  if (fit_.fitted && projection_ == ScaramuzzaProjection::kInversePolynomial) {
    double drho_dphi = 0.0;
    rho = FittedRadius(phi, &drho_dphi);
    drho_dr = drho_dphi * z / norm2;  // φ = atan2(r, z)
    drho_dz = -drho_dphi * r / norm2;
  } else {
    const double guess = fit_.fitted ? FittedRadius(phi) : -parameters_.poly[0] * phi;
    const ProjectionStatus status = SolveRadius(r, z, guess, &rho);
    if (status != ProjectionStatus::kOk) return status;
    // Implicit-function theorem on h(ρ, r, z) = ρ z + f(ρ) r = 0.
    double df = 0.0;
    const double f = F(rho, &df);
    const double dh_drho = z + df * r;
    drho_dr = -f / dh_drho;
    drho_dz = -rho / dh_drho;
  }
  // Ideal point in kinevis order (b, a) = ρ (x, y)/r; ρ/r → ∂ρ/∂r on the axis.
  const double s = r > 0.0 ? rho / r : drho_dr;
  const double b = s * x, a = s * y;
  const ScaramuzzaParameters& p = parameters_;
  (*pixel) << p.u0 + p.e * a + b, p.v0 + p.c * a + p.d * b;
  if (J_pixel_point != nullptr) {
    Matrix23d J_m;  // ∂(b, a)/∂(x, y, z)
    if (r > 0.0) {
      const Eigen::Vector2d q(x / r, y / r);
      J_m.leftCols<2>() =
          drho_dr * q * q.transpose() + s * (Eigen::Matrix2d::Identity() - q * q.transpose());
      J_m.col(2) = drho_dz * q;
    } else {
      J_m.leftCols<2>() = drho_dr * Eigen::Matrix2d::Identity();
      J_m.col(2).setZero();
    }
    Eigen::Matrix2d J_pixel_m;  // ∂(u, v)/∂(b, a)
    J_pixel_m << 1.0, p.e, p.d, p.c;
    *J_pixel_point = J_pixel_m * J_m;
  }
  return ProjectionStatus::kOk;
}

ProjectionStatus ScaramuzzaCamera::BackProject(const Eigen::Vector2d& pixel, Ray* ray,
                                               RayJacobian* J) const {
  if (!pixel.allFinite()) return ProjectionStatus::kOutsideDomain;
  const ScaramuzzaParameters& p = parameters_;
  const Eigen::Vector2d ab = IdealPoint(p, pixel.x(), pixel.y());
  const double a = ab.x(), b = ab.y();
  const double rho = ab.norm();
  if (!(rho <= rho_max_)) return ProjectionStatus::kOutsideDomain;
  double df = 0.0;
  const double f = F(rho, &df);
  // seed 003 eq. (2.2): OCamCalib direction (a, b, f(ρ)), in C: (b, a, -f(ρ)).
  const Eigen::Vector3d w(b, a, -f);
  const double w_norm = w.norm();
  ray->p_C_O.setZero();
  ray->d_C = w / w_norm;
  if (J != nullptr) {
    const double det = p.c - p.d * p.e;
    const Eigen::RowVector2d da(-p.d / det, 1.0 / det);  // ∂a/∂(u, v)
    const Eigen::RowVector2d db(p.c / det, -p.e / det);  // ∂b/∂(u, v)
    // ∂f/∂(a, b) = f'(ρ) (a, b)/ρ; at ρ = 0 the a1 ρ term has no derivative and is left out.
    Eigen::RowVector2d dfdu = Eigen::RowVector2d::Zero();
    if (rho > 0.0) dfdu = df / rho * (a * da + b * db);
    Matrix32d dw;
    dw.row(0) = db;
    dw.row(1) = da;
    dw.row(2) = -dfdu;
    J->d_origin_d_pixel.setZero();
    J->d_direction_d_pixel =
        (Eigen::Matrix3d::Identity() - ray->d_C * ray->d_C.transpose()) * dw / w_norm;
  }
  return ProjectionStatus::kOk;
}

}  // namespace kinevis::vision
