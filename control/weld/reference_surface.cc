#include "control/weld/reference_surface.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace kinevis::control {
namespace {

constexpr double kRadToDeg = 180.0 / M_PI;

// φ_k(x, y) for k = 0..K−1, t-major (see the header).
template <typename Vec>
void Monomials(int degree, double x, double y, Vec* phi) {
  double xp[5], yp[5];
  xp[0] = yp[0] = 1.0;
  for (int i = 1; i <= degree; ++i) {
    xp[i] = xp[i - 1] * x;
    yp[i] = yp[i - 1] * y;
  }
  int k = 0;
  for (int t = 0; t <= degree; ++t) {
    for (int j = 0; j <= t; ++j) (*phi)(k++) = xp[t - j] * yp[j];
  }
}

// ∂φ_k/∂x and ∂φ_k/∂y.
void MonomialDerivatives(int degree, double x, double y, Eigen::VectorXd* dx, Eigen::VectorXd* dy) {
  double xp[5], yp[5];
  xp[0] = yp[0] = 1.0;
  for (int i = 1; i <= degree; ++i) {
    xp[i] = xp[i - 1] * x;
    yp[i] = yp[i - 1] * y;
  }
  int k = 0;
  for (int t = 0; t <= degree; ++t) {
    for (int j = 0; j <= t; ++j, ++k) {
      const int i = t - j;
      (*dx)(k) = i > 0 ? i * xp[i - 1] * yp[j] : 0.0;
      (*dy)(k) = j > 0 ? j * xp[i] * yp[j - 1] : 0.0;
    }
  }
}

double Median(std::vector<double>* v) {
  if (v->empty()) return 0.0;
  const size_t mid = v->size() / 2;
  std::nth_element(v->begin(), v->begin() + static_cast<std::ptrdiff_t>(mid), v->end());
  return (*v)[mid];
}

}  // namespace

double ReferenceSurface::Height(double u, double v) const {
  const int K = CoefficientCount(degree);
  Eigen::Matrix<double, 15, 1> phi;
  Monomials(degree, u / length_scale, v / length_scale, &phi);
  return phi.head(K).dot(coefficients);
}

Eigen::Vector2d ReferenceSurface::Gradient(double u, double v) const {
  const int K = CoefficientCount(degree);
  Eigen::VectorXd dx(K), dy(K);
  MonomialDerivatives(degree, u / length_scale, v / length_scale, &dx, &dy);
  return Eigen::Vector2d(dx.dot(coefficients), dy.dot(coefficients)) / length_scale;
}

Eigen::Vector3d ReferenceSurface::NormalR(double u, double v) const {
  const Eigen::Vector2d g = Gradient(u, v);
  return Eigen::Vector3d(-g.x(), -g.y(), 1.0).normalized();
}

Eigen::Vector3d ReferenceSurface::Normal0(double u, double v) const {
  return X_0R.linear() * NormalR(u, v);
}

Eigen::Vector3d ReferenceSurface::Point0(double u, double v) const {
  return X_0R * Eigen::Vector3d(u, v, Height(u, v));
}

double ReferenceSurface::Depth(const Eigen::Vector3d& p_0) const {
  const Eigen::Vector3d p = ToR(p_0);
  return Height(p.x(), p.y()) - p.z();
}

bool ReferenceSurface::IntersectLine(const Eigen::Vector3d& p_0, const Eigen::Vector3d& u_0,
                                     double* t) const {
  const Eigen::Vector3d a = ToR(p_0);
  const Eigen::Vector3d b = X_0R.linear().transpose() * u_0.normalized();
  if (std::abs(b.z()) < 1e-3) return false;
  // f(t) = a_z + t b_z − h(a_xy + t b_xy); start from the vertical projection's height.
  double tt = (Height(a.x(), a.y()) - a.z()) / b.z();
  for (int it = 0; it < 50; ++it) {
    const double x = a.x() + tt * b.x(), y = a.y() + tt * b.y();
    const double f = a.z() + tt * b.z() - Height(x, y);
    const Eigen::Vector2d g = Gradient(x, y);
    const double df = b.z() - g.x() * b.x() - g.y() * b.y();
    if (std::abs(df) < 1e-12) return false;
    const double step = f / df;
    tt -= step;
    if (std::abs(step) < 1e-12) {
      *t = tt;
      return true;
    }
  }
  return false;
}

std::string ReferenceFitOptions::Validate() const {
  std::ostringstream bad;
  auto add = [&](const char* name, double value) {
    if (bad.tellp() > 0) bad << "; ";
    bad << name << " = " << value;
  };
  if (degree < 1 || degree > 4) add("degree (1..4)", degree);
  if (!(tukey_c > 0.0) || !std::isfinite(tukey_c)) add("tukey_c (> 0)", tukey_c);
  if (max_iterations < 1) add("max_iterations (>= 1)", max_iterations);
  if (!(min_scale > 0.0) || !std::isfinite(min_scale)) add("min_scale (> 0 m)", min_scale);
  if (!(tolerance > 0.0) || !std::isfinite(tolerance)) add("tolerance (> 0 m)", tolerance);
  if (coarse_cells < 2 || coarse_cells > 100) add("coarse_cells (2..100)", coarse_cells);
  if (max_fit_points < 100) add("max_fit_points (>= 100)", max_fit_points);
  if (!outward_hint_0.allFinite()) add("outward_hint_0 (finite)", outward_hint_0.norm());
  return bad.str();
}

const char* ToString(ReferenceFitStatus status) {
  switch (status) {
    case ReferenceFitStatus::kOk:
      return "ok";
    case ReferenceFitStatus::kTooFewPoints:
      return "too few points";
    case ReferenceFitStatus::kDegenerate:
      return "degenerate";
  }
  return "?";
}

ReferenceFit FitReferenceSurface(const std::vector<Eigen::Vector3d>& p_0,
                                 const std::vector<Eigen::Vector3d>& n_0,
                                 const ReferenceFitOptions& options) {
  if (const std::string bad = options.Validate(); !bad.empty()) {
    throw std::invalid_argument("FitReferenceSurface: bad options: " + bad);
  }
  if (!n_0.empty() && n_0.size() != p_0.size()) {
    throw std::invalid_argument("FitReferenceSurface: " + std::to_string(n_0.size()) +
                                " normals for " + std::to_string(p_0.size()) +
                                " points (give none or one per point)");
  }
  ReferenceFit fit;
  const int K = ReferenceSurface::CoefficientCount(options.degree);
  fit.surface.degree = options.degree;
  fit.surface.coefficients = Eigen::VectorXd::Zero(K);

  // Finite points, subsampled by a stride to at most max_fit_points.
  size_t finite = 0;
  for (const auto& p : p_0) finite += p.allFinite() ? 1 : 0;
  if (finite < p_0.size()) {
    fit.warnings.push_back(std::to_string(p_0.size() - finite) + " non-finite points skipped");
  }
  const size_t stride =
      std::max<size_t>(1, (finite + options.max_fit_points - 1) / options.max_fit_points);
  std::vector<size_t> index;
  index.reserve(finite / stride + 1);
  size_t seen = 0;
  for (size_t i = 0; i < p_0.size(); ++i) {
    if (!p_0[i].allFinite()) continue;
    if (seen++ % stride == 0) index.push_back(i);
  }
  const int n = static_cast<int>(index.size());
  fit.points = n;
  const int needed = std::max(10, 3 * K);
  if (n < needed) {
    fit.status = ReferenceFitStatus::kTooFewPoints;
    fit.message = std::to_string(n) + " finite points, a degree-" + std::to_string(options.degree) +
                  " reference needs at least " + std::to_string(needed);
    return fit;
  }

  // PCA frame.
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (size_t i : index) centroid += p_0[i];
  centroid /= n;
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (size_t i : index) {
    const Eigen::Vector3d d = p_0[i] - centroid;
    cov += d * d.transpose();
  }
  cov /= n;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
  const Eigen::Vector3d lambda = eig.eigenvalues();  // ascending
  if (!(lambda(2) > 1e-16) || lambda(1) < 1e-8 * lambda(2)) {
    fit.status = ReferenceFitStatus::kDegenerate;
    std::ostringstream m;
    m << "the points lie on a line or a point (principal spreads " << std::sqrt(lambda(2)) * 1e3
      << ", " << std::sqrt(std::max(0.0, lambda(1))) * 1e3 << " mm): no surface to fit";
    fit.message = m.str();
    return fit;
  }
  Eigen::Vector3d x_R = eig.eigenvectors().col(2);
  Eigen::Vector3d y_R = eig.eigenvectors().col(1);
  Eigen::Vector3d z_R = x_R.cross(y_R).normalized();
  double side = 0.0;
  if (!n_0.empty()) {
    for (size_t i : index) side += n_0[i].allFinite() ? n_0[i].dot(z_R) : 0.0;
  } else {
    side = (options.outward_hint_0 - centroid).dot(z_R);
  }
  if (side < 0.0) {
    y_R = -y_R;
    z_R = -z_R;
  }
  Eigen::Isometry3d X_0R = Eigen::Isometry3d::Identity();
  X_0R.linear().col(0) = x_R;
  X_0R.linear().col(1) = y_R;
  X_0R.linear().col(2) = z_R;
  X_0R.translation() = centroid;
  fit.surface.X_0R = X_0R;

  std::vector<Eigen::Vector3d> q(n);
  const Eigen::Isometry3d X_R0 = X_0R.inverse();
  Eigen::Vector2d lo = Eigen::Vector2d::Constant(1e300), hi = -lo;
  for (int k = 0; k < n; ++k) {
    q[k] = X_R0 * p_0[index[k]];
    lo = lo.cwiseMin(q[k].head<2>());
    hi = hi.cwiseMax(q[k].head<2>());
  }
  fit.uv_min = lo;
  fit.uv_max = hi;
  const double L = std::max(0.5 * (hi - lo).maxCoeff(), 1e-6);
  fit.surface.length_scale = L;

  std::vector<Eigen::Matrix<double, 15, 1>> phi(n);
  for (int k = 0; k < n; ++k) Monomials(options.degree, q[k].x() / L, q[k].y() / L, &phi[k]);

  auto solve = [&](const std::vector<double>& weight, Eigen::VectorXd* c) {
    Eigen::MatrixXd A = Eigen::MatrixXd::Zero(K, K);
    Eigen::VectorXd b = Eigen::VectorXd::Zero(K);
    for (int k = 0; k < n; ++k) {
      if (weight[k] <= 0.0) continue;
      const auto f = phi[k].head(K);
      A.selfadjointView<Eigen::Lower>().rankUpdate(f, weight[k]);
      b += weight[k] * q[k].z() * f;
    }
    A = A.selfadjointView<Eigen::Lower>();
    Eigen::LDLT<Eigen::MatrixXd> ldlt(A);
    const Eigen::VectorXd d = ldlt.vectorD();
    if (ldlt.info() != Eigen::Success || !(d.minCoeff() > 1e-12 * d.maxCoeff())) return false;
    *c = ldlt.solve(b);
    return c->allFinite();
  };

  // Robust start: a least-squares fit to the medians of the coarse cells.
  const int G = options.coarse_cells;
  std::vector<std::vector<double>> cell_w(G * G);
  std::vector<Eigen::Vector2d> cell_uv(G * G, Eigen::Vector2d::Zero());
  const Eigen::Vector2d span = (hi - lo).cwiseMax(Eigen::Vector2d::Constant(1e-9));
  for (int k = 0; k < n; ++k) {
    const int cx = std::min(G - 1, static_cast<int>((q[k].x() - lo.x()) / span.x() * G));
    const int cy = std::min(G - 1, static_cast<int>((q[k].y() - lo.y()) / span.y() * G));
    cell_w[cy * G + cx].push_back(q[k].z());
    cell_uv[cy * G + cx] += q[k].head<2>();
  }
  Eigen::VectorXd c = Eigen::VectorXd::Zero(K);
  {
    Eigen::MatrixXd A = Eigen::MatrixXd::Zero(K, K);
    Eigen::VectorXd b = Eigen::VectorXd::Zero(K);
    int used = 0;
    for (int g = 0; g < G * G; ++g) {
      if (cell_w[g].size() < 3) continue;
      const Eigen::Vector2d uv = cell_uv[g] / static_cast<double>(cell_w[g].size());
      const double med = Median(&cell_w[g]);
      Eigen::Matrix<double, 15, 1> f;
      Monomials(options.degree, uv.x() / L, uv.y() / L, &f);
      A += f.head(K) * f.head(K).transpose();
      b += med * f.head(K);
      ++used;
    }
    Eigen::LDLT<Eigen::MatrixXd> ldlt(A);
    const Eigen::VectorXd d = ldlt.vectorD();
    const bool ok =
        used >= K && ldlt.info() == Eigen::Success && d.minCoeff() > 1e-12 * d.maxCoeff();
    if (ok) c = ldlt.solve(b);
    if (!ok || !c.allFinite()) {
      // Too few coarse cells with data: start from plain least squares.
      if (!solve(std::vector<double>(n, 1.0), &c)) {
        fit.status = ReferenceFitStatus::kDegenerate;
        fit.message = "the points do not determine a degree-" + std::to_string(options.degree) +
                      " heightfield (normal equations singular)";
        return fit;
      }
    }
  }

  std::vector<double> r(n), absr(n), weight(n, 1.0), h_prev(n);
  for (int k = 0; k < n; ++k) h_prev[k] = phi[k].head(K).dot(c);
  double s = options.min_scale;
  int it = 0;
  for (; it < options.max_iterations; ++it) {
    for (int k = 0; k < n; ++k) {
      r[k] = q[k].z() - phi[k].head(K).dot(c);
      absr[k] = std::abs(r[k]);
    }
    s = std::max(options.min_scale, 1.4826 * Median(&absr));
    const double cs = options.tukey_c * s;
    for (int k = 0; k < n; ++k) {
      const double z = r[k] / cs;
      weight[k] = std::abs(z) < 1.0 ? (1.0 - z * z) * (1.0 - z * z) : 0.0;
    }
    Eigen::VectorXd c_new;
    if (!solve(weight, &c_new)) {
      fit.status = ReferenceFitStatus::kDegenerate;
      fit.message = "the inliers do not determine a degree-" + std::to_string(options.degree) +
                    " heightfield (normal equations singular at IRLS iteration " +
                    std::to_string(it) + ")";
      return fit;
    }
    double change = 0.0;
    for (int k = 0; k < n; ++k) {
      const double h = phi[k].head(K).dot(c_new);
      change = std::max(change, std::abs(h - h_prev[k]));
      h_prev[k] = h;
    }
    c = c_new;
    if (change < options.tolerance) {
      ++it;
      break;
    }
  }
  fit.iterations = it;
  fit.surface.coefficients = c;
  fit.robust_scale = s;
  double ss = 0.0;
  int inl = 0;
  for (int k = 0; k < n; ++k) {
    const double res = q[k].z() - phi[k].head(K).dot(c);
    if (std::abs(res) < options.tukey_c * s) {
      ++inl;
      ss += res * res;
    }
  }
  fit.inliers = inl;
  fit.inlier_fraction = static_cast<double>(inl) / n;
  fit.inlier_rms = inl > 0 ? std::sqrt(ss / inl) : 0.0;
  fit.status = ReferenceFitStatus::kOk;

  double max_grad = 0.0;
  for (int i = 0; i <= 20; ++i) {
    for (int j = 0; j <= 20; ++j) {
      const double u = lo.x() + span.x() * i / 20.0, v = lo.y() + span.y() * j / 20.0;
      max_grad = std::max(max_grad, fit.surface.Gradient(u, v).norm());
    }
  }
  fit.max_slope_deg = std::atan(max_grad) * kRadToDeg;

  std::ostringstream w;
  if (fit.inlier_fraction < 0.5) {
    w << "only " << static_cast<int>(100 * fit.inlier_fraction)
      << " % of the points fit the reference surface: damage or outliers dominate the map, the "
         "reference may be wrong";
    fit.warnings.push_back(w.str());
  }
  if (fit.max_slope_deg > 30.0) {
    std::ostringstream m;
    m << "the surface tilts up to " << fit.max_slope_deg
      << " deg from its mean plane: depths (along z_R) are up to "
      << static_cast<int>(100 * (1.0 - std::cos(fit.max_slope_deg / kRadToDeg)))
      << " % off; scan smaller patches";
    fit.warnings.push_back(m.str());
  }
  if (!n_0.empty()) {
    int against = 0, counted = 0;
    for (int k = 0; k < n; ++k) {
      const Eigen::Vector3d& nn = n_0[index[k]];
      if (!nn.allFinite()) continue;
      ++counted;
      if (nn.dot(fit.surface.Normal0(q[k].x(), q[k].y())) < 0.5) ++against;
    }
    if (counted > 0 && against > counted / 10) {
      fit.warnings.push_back(std::to_string(against) + " of " + std::to_string(counted) +
                             " map normals are more than 60 deg off the reference normal");
    }
  }
  return fit;
}

}  // namespace kinevis::control
