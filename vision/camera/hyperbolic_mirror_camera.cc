#include "vision/camera/hyperbolic_mirror_camera.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

// Notes on the seed's equations (seed 000 §4), which are partly garbled in the text:
//  - eq. (9)–(14): the ray–mirror intersection is written in the plane FR through the ray and the
//    y axis. Used instead: the ray t d from the pinhole in the implicit surface
//    F(X) = (y − k_off)² − (x − m_x)² − (z − m_z)² − A = 0, a quadratic in t; of its roots the
//    physical one is the first t > 0 on the upper sheet (y > k_off), which is the seed's "higher y"
//    root (the other root is the "symmetrical virtual" sheet). Same geometry, no angles, no
//    singularity for rays in the x = 0 plane (eq. (8)'s atan(p_cz/p_cx)).
//  - eq. (15)–(22): the normal from the slope angle β_tm and the reflected ray through the point
//    P_t. Used instead: n = ∇F/|∇F| and d' = d − 2 (d·n) n, the same mirror image of the incident
//    ray about the normal, without the angle bookkeeping.
//  - eq. (25) prints R_x(ρ) R_y(γ) R_z(θ), but the expansions (26) and (28) are those of
//    R_y(γ) R_x(ρ) R_z(θ) (checked symbolically and in the tests); (27) prints
//    p_cx cos ρ sin θ + p_cz sin ρ, where that product gives p_cx cos ρ sin θ − p_cz sin ρ (a sign
//    slip: with + the matrix would not be a rotation). We use R_CS = R_y(γ) R_x(ρ) R_z(θ).
//  - eq. (30) reads "cos ρ cos θ − mtf + hmf": the added lengths are a conversion artefact; g is
//    the unit vector R_x(ρ) R_z(θ) j of (29)–(31). The plane (32) passes through the point
//    (0, mtf − hmf, 0) below the pinhole; we put it through the point hmf below the apex on the
//    mirror axis, (m_x, mtf − hmf, m_z), since hmf is measured from the apex. The two agree when
//    the mirror axis passes through the pinhole or the ground is not tilted.
//  - eq. (2): C(θ) is "added to the angle of the ray exiting the lens": θ_corrected = θ + C(θ)
//    with θ the angle of the pixel's pinhole ray to the nominal sensor normal (the seed's
//    coefficients are positive, i.e. barrel distortion compressed the image; 0.4 mrad at the
//    4 mm lens's image corner).

namespace kinevis::vision {
namespace {

Eigen::Matrix3d RotX(double a) {
  return Eigen::AngleAxisd(a, Eigen::Vector3d::UnitX()).toRotationMatrix();
}
Eigen::Matrix3d RotY(double a) {
  return Eigen::AngleAxisd(a, Eigen::Vector3d::UnitY()).toRotationMatrix();
}
Eigen::Matrix3d RotZ(double a) {
  return Eigen::AngleAxisd(a, Eigen::Vector3d::UnitZ()).toRotationMatrix();
}

Eigen::Matrix3d SensorRotation(const HyperbolicMirrorParameters& p) {
  return RotY(p.sensor_gamma) * RotX(p.sensor_rho) * RotZ(p.sensor_theta);
}

// Largest angle of a pinhole ray to the nominal sensor normal over the image (rad).
double ImageCornerAngle(const HyperbolicMirrorParameters& p) {
  double r2_max = 0.0;
  for (double u : {-0.5, p.width - 0.5}) {
    for (double v : {-0.5, p.height - 0.5}) {
      r2_max = std::max(r2_max, (u - p.cx) * (u - p.cx) + (v - p.cy) * (v - p.cy));
    }
  }
  return std::atan(std::sqrt(r2_max) * p.pixel_pitch / p.focal_length);
}

constexpr double kLensDomainFactor = 1.25;
constexpr double kMaxMisalignmentAngle = 0.5;  // rad
constexpr double kMaxSensorOffset = 0.01;      // m
constexpr int kMaxNewtonIterations = 50;
constexpr int kLensTableNodes = 2048;
constexpr double kNewtonStepTolerance = 1e-12;  // m on the mirror: ~1e-8 px

double LensC(const std::array<double, 4>& k, double theta) {
  return k[0] + theta * (k[1] + theta * (k[2] + theta * k[3]));
}
double LensDc(const std::array<double, 4>& k, double theta) {
  return k[1] + theta * (2.0 * k[2] + 3.0 * theta * k[3]);
}

// (x − h_x, y − h_y, z − h_z) weighted by diag(−1, 1, −1): half the gradient of F.
Eigen::Vector3d HalfGradient(const Eigen::Vector3d& p_C_M, const Eigen::Vector3d& p_C_H) {
  return Eigen::Vector3d(-(p_C_M.x() - p_C_H.x()), p_C_M.y() - p_C_H.y(), -(p_C_M.z() - p_C_H.z()));
}

Eigen::Vector3d DiagD(const Eigen::Vector3d& v) { return Eigen::Vector3d(-v.x(), v.y(), -v.z()); }

// Jacobian of the radial map s ↦ s · (ρ(|s|)/|s|) given gain = ρ/r and slope = dρ/dr.
Eigen::Matrix2d RadialJacobian(const Eigen::Vector2d& s, double gain, double slope) {
  Eigen::Matrix2d J = gain * Eigen::Matrix2d::Identity();
  const double r = s.norm();
  if (r > 0.0) {
    const Eigen::Vector2d s_hat = s / r;
    J += (slope - gain) * s_hat * s_hat.transpose();
  }
  return J;
}

}  // namespace

double HyperbolicMirrorParameters::mirror_offset() const {
  return apex_distance - std::sqrt(mirror_constant);
}

std::string HyperbolicMirrorParameters::Validate() const {
  std::ostringstream errors;
  auto positive = [&errors](const char* name, double value) {
    if (!std::isfinite(value) || value <= 0.0) {
      errors << name << " = " << value << " must be finite and > 0; ";
      return false;
    }
    return true;
  };
  auto finite = [&errors](const char* name, double value) {
    if (!std::isfinite(value)) {
      errors << name << " = " << value << " must be finite; ";
      return false;
    }
    return true;
  };
  auto bounded = [&errors](const char* name, double value, double bound, const char* unit) {
    if (!std::isfinite(value) || std::abs(value) > bound) {
      errors << name << " = " << value << " must be finite with |" << name << "| <= " << bound
             << " " << unit << "; ";
      return false;
    }
    return true;
  };
  bool sensor_ok = true;
  if (width <= 0) {
    errors << "width = " << width << " must be > 0; ";
    sensor_ok = false;
  }
  if (height <= 0) {
    errors << "height = " << height << " must be > 0; ";
    sensor_ok = false;
  }
  sensor_ok &= positive("pixel_pitch", pixel_pitch);
  sensor_ok &= finite("cx", cx);
  sensor_ok &= finite("cy", cy);
  sensor_ok &= positive("focal_length", focal_length);
  bool lens_ok = true;
  for (int i = 0; i < 4; ++i) {
    if (!std::isfinite(lens_correction[i])) {
      errors << "lens_correction[" << i << "] = " << lens_correction[i] << " must be finite; ";
      lens_ok = false;
    }
  }
  if (lens_ok && lens_correction[0] != 0.0) {
    errors << "lens_correction[0] = " << lens_correction[0]
           << " must be 0 (an angle offset on the lens axis has no direction); ";
    lens_ok = false;
  }
  if (sensor_ok && lens_ok) {
    const double theta_max = kLensDomainFactor * ImageCornerAngle(*this);
    constexpr int kSamples = 256;
    for (int i = 0; i <= kSamples; ++i) {
      const double theta = theta_max * i / kSamples;
      if (1.0 + LensDc(lens_correction, theta) <= 0.05 ||
          theta + LensC(lens_correction, theta) >= 1.5) {
        errors << "lens_correction = [" << lens_correction[0] << ", " << lens_correction[1] << ", "
               << lens_correction[2] << ", " << lens_correction[3]
               << "] is not monotonic (1 + C'(θ) > 0.05, θ + C(θ) < 1.5 rad) up to θ = " << theta
               << " rad within the domain [0, " << theta_max << "] rad; ";
        break;
      }
    }
  }
  positive("mirror_constant", mirror_constant);
  const bool radius_ok = positive("mirror_radius", mirror_radius);
  const bool apex_ok = positive("apex_distance", apex_distance);
  const bool axis_x_ok = finite("mirror_axis_x", mirror_axis_x);
  const bool axis_z_ok = finite("mirror_axis_z", mirror_axis_z);
  if (radius_ok && axis_x_ok && axis_z_ok &&
      std::hypot(mirror_axis_x, mirror_axis_z) >= mirror_radius) {
    errors << "mirror axis offset (mirror_axis_x, mirror_axis_z) = (" << mirror_axis_x << ", "
           << mirror_axis_z << ") must lie within mirror_radius = " << mirror_radius
           << " of the pinhole; ";
  }
  if (!std::isfinite(apex_to_ground) || (apex_ok && apex_to_ground <= apex_distance)) {
    errors << "apex_to_ground = " << apex_to_ground
           << " must be finite and > apex_distance = " << apex_distance << "; ";
  }
  bool misalignment_ok = true;
  misalignment_ok &= bounded("sensor_offset_x", sensor_offset_x, kMaxSensorOffset, "m");
  misalignment_ok &= bounded("sensor_offset_z", sensor_offset_z, kMaxSensorOffset, "m");
  misalignment_ok &= bounded("sensor_gamma", sensor_gamma, kMaxMisalignmentAngle, "rad");
  misalignment_ok &= bounded("sensor_rho", sensor_rho, kMaxMisalignmentAngle, "rad");
  misalignment_ok &= bounded("sensor_theta", sensor_theta, kMaxMisalignmentAngle, "rad");
  bounded("ground_rho", ground_rho, kMaxMisalignmentAngle, "rad");
  bounded("ground_theta", ground_theta, kMaxMisalignmentAngle, "rad");
  if (misalignment_ok && sensor_ok) {
    const Eigen::Vector3d n_C_S = SensorRotation(*this).col(1);
    const Eigen::Vector3d p_C_S(sensor_offset_x, -focal_length, sensor_offset_z);
    const double distance = -n_C_S.dot(p_C_S);
    if (distance < 0.5 * focal_length) {
      errors << "sensor pose (sensor_offset_x, sensor_offset_z, sensor_gamma, sensor_rho, "
                "sensor_theta) puts the pinhole "
             << distance << " m from the sensor plane, less than focal_length / 2; ";
    }
  }
  std::string message = errors.str();
  if (message.size() >= 2) message.resize(message.size() - 2);
  return message;
}

HyperbolicMirrorParameters HyperbolicMirrorParameters::Seed000Lens4mm() {
  return HyperbolicMirrorParameters{};
}

HyperbolicMirrorParameters HyperbolicMirrorParameters::Seed000Lens6mm() {
  HyperbolicMirrorParameters p;
  p.focal_length = 6.77e-3;
  p.lens_correction = {0.0, 0.0, 0.0002, 0.00075};
  p.apex_distance = 0.170;
  return p;
}

HyperbolicMirrorCamera::HyperbolicMirrorCamera(const HyperbolicMirrorParameters& parameters)
    : parameters_(parameters) {
  const std::string problems = parameters_.Validate();
  if (!problems.empty()) {
    throw std::invalid_argument("hyperbolic-mirror camera parameters: " + problems);
  }
  const HyperbolicMirrorParameters& p = parameters_;
  R_CS_ = SensorRotation(p);
  n_C_S_ = R_CS_.col(1);
  p_C_S_ = Eigen::Vector3d(p.sensor_offset_x, -p.focal_length, p.sensor_offset_z);
  p_C_H_ = Eigen::Vector3d(p.mirror_axis_x, p.mirror_offset(), p.mirror_axis_z);
  // F at the pinhole: the ray–mirror quadratic's constant term.
  quadratic_c_ = p_C_H_.dot(DiagD(p_C_H_)) - p.mirror_constant;
  Eigen::Matrix3d R_CG0;
  R_CG0.col(0) = Eigen::Vector3d::UnitZ();  // x_G forward
  R_CG0.col(1) = Eigen::Vector3d::UnitX();  // y_G left
  R_CG0.col(2) = Eigen::Vector3d::UnitY();  // z_G up
  X_CG_.setIdentity();
  X_CG_.linear() = RotX(p.ground_rho) * RotZ(p.ground_theta) * R_CG0;
  X_CG_.translation() =
      Eigen::Vector3d(p.mirror_axis_x, p.apex_distance - p.apex_to_ground, p.mirror_axis_z);
  theta_max_ = kLensDomainFactor * ImageCornerAngle(p);
  theta_c_max_ = theta_max_ + LensC(p.lens_correction, theta_max_);
  r_max_ = p.focal_length * std::tan(theta_max_);
  // Hermite table of gain(r) = r_c / r; at r = 0, gain = 1 + k1 and d gain/dr = k2 / f (series
  // of f tan(θ + C(θ)) / r with θ = atan(r / f), k0 = 0).
  const double step = r_max_ / (kLensTableNodes - 1);
  lens_table_inverse_step_ = 1.0 / step;
  lens_table_.resize(2 * static_cast<std::size_t>(kLensTableNodes));
  for (int i = 0; i < kLensTableNodes; ++i) {
    double gain = 1.0 + p.lens_correction[1];
    double slope = p.lens_correction[2] / p.focal_length;
    const double r = i == kLensTableNodes - 1 ? r_max_ : i * step;
    if (i > 0) {
      double r_c = 0.0;
      double dr_c_dr = 0.0;
      // Inside the domain by construction; at the last node rounding may put θ a hair above
      // θ_max, so evaluate there without the domain check.
      const double theta = std::min(std::atan(r / p.focal_length), theta_max_);
      r_c = p.focal_length * std::tan(theta + LensC(p.lens_correction, theta));
      const double t = r / p.focal_length;
      const double t_c = r_c / p.focal_length;
      dr_c_dr = (1.0 + t_c * t_c) * (1.0 + LensDc(p.lens_correction, theta)) / (1.0 + t * t);
      gain = r_c / r;
      slope = (dr_c_dr - gain) / r;
    }
    const std::size_t node = 2 * static_cast<std::size_t>(i);
    lens_table_[node] = gain;
    lens_table_[node + 1] = step * slope;
  }
}

Eigen::Vector3d HyperbolicMirrorCamera::MirrorApex() const {
  return Eigen::Vector3d(parameters_.mirror_axis_x, parameters_.apex_distance,
                         parameters_.mirror_axis_z);
}

bool HyperbolicMirrorCamera::LensForward(double r, double* r_c, double* dr_c_dr) const {
  const double f = parameters_.focal_length;
  const auto& k = parameters_.lens_correction;
  const double tan_theta = r / f;
  const double theta = std::atan(tan_theta);
  if (!(theta <= theta_max_)) return false;
  const double tan_theta_c = std::tan(theta + LensC(k, theta));
  *r_c = f * tan_theta_c;
  if (dr_c_dr != nullptr) {
    // dθ/dr = 1 / (f (1 + tan²θ)), d(f tan θ_c)/dθ_c = f (1 + tan²θ_c).
    *dr_c_dr = (1.0 + tan_theta_c * tan_theta_c) * (1.0 + LensDc(k, theta)) /
               (1.0 + tan_theta * tan_theta);
  }
  return true;
}

bool HyperbolicMirrorCamera::LensInverse(double r_c, double* r, double* dr_dr_c) const {
  const double f = parameters_.focal_length;
  const auto& k = parameters_.lens_correction;
  const double theta_c = std::atan(r_c / f);
  if (!(theta_c <= theta_c_max_)) return false;
  // θ + C(θ) = θ_c is monotonic on the domain (Validate()); Newton from θ_c converges in a few
  // steps since C is small.
  double theta = theta_c;
  for (int i = 0; i < 30; ++i) {
    const double step = (theta + LensC(k, theta) - theta_c) / (1.0 + LensDc(k, theta));
    theta -= step;
    if (std::abs(step) <= 1e-16) break;
  }
  const double tan_theta = std::tan(theta);
  *r = f * tan_theta;
  if (dr_dr_c != nullptr) {
    const double tan_theta_c = r_c / f;
    *dr_dr_c = (1.0 + tan_theta * tan_theta) /
               ((1.0 + tan_theta_c * tan_theta_c) * (1.0 + LensDc(k, theta)));
  }
  return true;
}

bool HyperbolicMirrorCamera::LensGain(double r, double* gain) const {
  if (r > 0.0) {
    double r_c = 0.0;
    if (!LensForward(r, &r_c, nullptr)) return false;
    *gain = r_c / r;
  } else {
    *gain = 1.0 + parameters_.lens_correction[1];  // limit of r_c / r at r = 0 (k0 = 0)
  }
  return true;
}

inline bool HyperbolicMirrorCamera::LensGainFromTable(double r, double* gain) const {
  if (!(r <= r_max_)) return false;
  const double x = r * lens_table_inverse_step_;
  int i = static_cast<int>(x);
  if (i > kLensTableNodes - 2) i = kLensTableNodes - 2;
  const double t = x - i;
  const double* node = &lens_table_[2 * static_cast<std::size_t>(i)];
  const double t2 = t * t;
  const double t3 = t2 * t;
  *gain = (2.0 * t3 - 3.0 * t2 + 1.0) * node[0] + (t3 - 2.0 * t2 + t) * node[1] +
          (-2.0 * t3 + 3.0 * t2) * node[2] + (t3 - t2) * node[3];
  return true;
}

Eigen::Vector2d HyperbolicMirrorCamera::SensorPoint(const Eigen::Vector2d& pixel) const {
  // seed eq. (5), signs as documented in the header.
  return Eigen::Vector2d(-(pixel.x() - parameters_.cx) * parameters_.pixel_pitch,
                         (pixel.y() - parameters_.cy) * parameters_.pixel_pitch);
}

bool HyperbolicMirrorCamera::CorrectedSensorPoint(double s_x, double s_z, Eigen::Vector3d* p_C_P,
                                                  Matrix32d* J_p_s) const {
  const double r = std::sqrt(s_x * s_x + s_z * s_z);
  double gain = 1.0 + parameters_.lens_correction[1];  // limit of r_c / r at r = 0 (k0 = 0)
  double slope = gain;
  if (r > 0.0) {
    double r_c = 0.0;
    if (!LensForward(r, &r_c, J_p_s != nullptr ? &slope : nullptr)) return false;
    gain = r_c / r;
  }
  // seed eq. (26)–(28): P_p' = R_CS (s_c,x, 0, s_c,z) + (d_x, −htf, d_z).
  *p_C_P = R_CS_.col(0) * (gain * s_x) + R_CS_.col(2) * (gain * s_z) + p_C_S_;
  if (J_p_s != nullptr) {
    const Eigen::Matrix2d J_lens = RadialJacobian(Eigen::Vector2d(s_x, s_z), gain, slope);
    Matrix32d R02;
    R02.col(0) = R_CS_.col(0);
    R02.col(1) = R_CS_.col(2);
    *J_p_s = R02 * J_lens;
  }
  return true;
}

Eigen::Vector3d HyperbolicMirrorCamera::PixelOnSensor(const Eigen::Vector2d& pixel) const {
  const Eigen::Vector2d s = SensorPoint(pixel);
  Eigen::Vector3d p_C_P;
  if (!CorrectedSensorPoint(s.x(), s.y(), &p_C_P)) {
    return Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
  }
  return p_C_P;
}

bool HyperbolicMirrorCamera::HitMirror(const Eigen::Vector3d& d_C, double* t,
                                       Eigen::Vector3d* p_C_M) const {
  // F(t d) = (o + t d)ᵀ D (o + t d) − A with o = −p_C_H (the pinhole relative to the hyperbola's
  // centre) and D = diag(−1, 1, −1): a t² + b t + c = 0 (replaces seed eq. (9)–(14)).
  const Eigen::Vector3d Dd = DiagD(d_C);
  const double a = d_C.dot(Dd);
  const double b = -2.0 * p_C_H_.dot(Dd);
  const double c = quadratic_c_;
  const double discriminant = b * b - 4.0 * a * c;
  if (!(discriminant >= 0.0)) return false;
  // The mirror is entered where F changes from − to + (F > 0 above the upper sheet), i.e. at the
  // root where F'(t) = 2 a t + b = +sqrt(disc): t = (−b + sqrt(disc)) / (2a), in the form
  // without cancellation. It must lie ahead (t > 0) and on the upper sheet (y > k_off): the
  // lower sheet is the seed's "symmetrical virtual" mirror.
  const double root_disc = std::sqrt(discriminant);
  const double best = b < 0.0 ? (root_disc - b) / (2.0 * a) : (2.0 * c) / (-b - root_disc);
  if (!(best > 0.0) || !(best * d_C.y() > p_C_H_.y())) return false;
  const Eigen::Vector3d p = best * d_C;
  const double dx = p.x() - p_C_H_.x();
  const double dz = p.z() - p_C_H_.z();
  const double rim = parameters_.mirror_radius;
  if (dx * dx + dz * dz > rim * rim) return false;  // beyond the rim: misses the mirror
  *t = best;
  *p_C_M = p;
  return true;
}

// The hot path of ComputeGroundMap(): the same geometry as HitMirror() and BackProject(),
// written out in scalars, with the reflected direction scaled by |m|² > 0 to save a division.
inline bool HyperbolicMirrorCamera::TraceToGround(double s_x, double s_z, double gain, double* x_G,
                                                  double* y_G) const {
  const double c_x = gain * s_x;
  const double c_z = gain * s_z;
  const Eigen::Matrix3d& R = R_CS_;
  // d = −P_p', seed eq. (26)–(28).
  const double dx = -(R(0, 0) * c_x + R(0, 2) * c_z + p_C_S_.x());
  const double dy = -(R(1, 0) * c_x + R(1, 2) * c_z + p_C_S_.y());
  const double dz = -(R(2, 0) * c_x + R(2, 2) * c_z + p_C_S_.z());
  const double hx = p_C_H_.x();
  const double hy = p_C_H_.y();
  const double hz = p_C_H_.z();
  const double a = dy * dy - dx * dx - dz * dz;
  const double b = -2.0 * (hy * dy - hx * dx - hz * dz);
  const double c = quadratic_c_;
  const double discriminant = b * b - 4.0 * a * c;
  if (!(discriminant >= 0.0)) return false;
  const double root_disc = std::sqrt(discriminant);
  const double t = b < 0.0 ? (root_disc - b) / (2.0 * a) : (2.0 * c) / (-b - root_disc);
  const double mx = t * dx;
  const double my = t * dy;
  const double mz = t * dz;
  if (!(t > 0.0) || !(my > hy)) return false;
  const double wx = mx - hx;
  const double wz = mz - hz;
  const double rim = parameters_.mirror_radius;
  if (wx * wx + wz * wz > rim * rim) return false;  // beyond the rim: misses the mirror
  // Normal direction m = ∇F / 2 = (−w_x, y − k_off, −w_z); reflection |m|² d − 2 (d·m) m.
  const double nx = -wx;
  const double ny = my - hy;
  const double nz = -wz;
  const double mm = nx * nx + ny * ny + nz * nz;
  const double dm2 = 2.0 * (dx * nx + dy * ny + dz * nz);
  const double ox = mm * dx - dm2 * nx;
  const double oy = mm * dy - dm2 * ny;
  const double oz = mm * dz - dm2 * nz;
  // seed eq. (23)–(24), (32): the reflected line meets the ground when it goes down towards it.
  const Eigen::Matrix3d& R_CG = X_CG_.linear();
  const double denominator = R_CG(0, 2) * ox + R_CG(1, 2) * oy + R_CG(2, 2) * oz;
  if (!(denominator < 0.0)) return false;  // parallel to or above the horizon
  const Eigen::Vector3d& p_C_G = X_CG_.translation();
  const double gx = p_C_G.x() - mx;
  const double gy = p_C_G.y() - my;
  const double gz = p_C_G.z() - mz;
  const double u = (R_CG(0, 2) * gx + R_CG(1, 2) * gy + R_CG(2, 2) * gz) / denominator;
  if (!(u > 0.0)) return false;
  const double rx = u * ox - gx;  // ground point relative to G's origin, in C
  const double ry = u * oy - gy;
  const double rz = u * oz - gz;
  *x_G = R_CG(0, 0) * rx + R_CG(1, 0) * ry + R_CG(2, 0) * rz;
  *y_G = R_CG(0, 1) * rx + R_CG(1, 1) * ry + R_CG(2, 1) * rz;
  return true;
}

ProjectionStatus HyperbolicMirrorCamera::BackProject(const Eigen::Vector2d& pixel, Ray* ray,
                                                     RayJacobian* J) const {
  const Eigen::Vector2d s = SensorPoint(pixel);
  Eigen::Vector3d p_C_P;
  Matrix32d J_p_s;
  if (!CorrectedSensorPoint(s.x(), s.y(), &p_C_P, J != nullptr ? &J_p_s : nullptr)) {
    return ProjectionStatus::kOutsideDomain;
  }
  const Eigen::Vector3d d = -p_C_P;
  double t = 0.0;
  Eigen::Vector3d p_C_M;
  if (!HitMirror(d, &t, &p_C_M)) return ProjectionStatus::kOutsideDomain;
  const Eigen::Vector3d m = HalfGradient(p_C_M, p_C_H_);
  const double m_norm = m.norm();
  const Eigen::Vector3d n = m / m_norm;
  const double d_norm = d.norm();
  const Eigen::Vector3d e = d / d_norm;
  const double e_dot_n = e.dot(n);
  ray->p_C_O = p_C_M;
  ray->d_C = (e - 2.0 * e_dot_n * n).normalized();
  if (J != nullptr) {
    // pixel → s_S: diag(−pitch, pitch); s_S → P_p': J_p_s; d = −P_p'.
    const double pitch = parameters_.pixel_pitch;
    Matrix32d dd = -J_p_s;
    dd.col(0) *= -pitch;
    dd.col(1) *= pitch;
    // F(t d) = 0 ⇒ ∇F·(dt d + t dd) = 0.
    const Eigen::RowVector2d dt = -t * (m.transpose() * dd) / m.dot(d);
    const Matrix32d dM = d * dt + t * dd;
    const Matrix32d dm = (Eigen::Matrix3d() << -1, 0, 0, 0, 1, 0, 0, 0, -1).finished() * dM;
    const Eigen::Matrix3d P_n = Eigen::Matrix3d::Identity() - n * n.transpose();
    const Eigen::Matrix3d P_e = Eigen::Matrix3d::Identity() - e * e.transpose();
    const Matrix32d dn = P_n * dm / m_norm;
    const Matrix32d de = P_e * dd / d_norm;
    const Eigen::RowVector2d d_e_dot_n = n.transpose() * de + e.transpose() * dn;
    J->d_origin_d_pixel = dM;
    J->d_direction_d_pixel = de - 2.0 * (n * d_e_dot_n + e_dot_n * dn);
  }
  return ProjectionStatus::kOk;
}

ProjectionStatus HyperbolicMirrorCamera::BackProjectToGround(
    const Eigen::Vector2d& pixel, Eigen::Vector2d* p_G_xy, Eigen::Matrix2d* J_ground_pixel) const {
  const Eigen::Vector2d s = SensorPoint(pixel);
  double gain = 0.0;
  double x = 0.0;
  double y = 0.0;
  if (!LensGain(s.norm(), &gain) || !TraceToGround(s.x(), s.y(), gain, &x, &y)) {
    return ProjectionStatus::kOutsideDomain;
  }
  *p_G_xy = Eigen::Vector2d(x, y);
  if (J_ground_pixel != nullptr) {
    Ray ray;
    RayJacobian J;
    if (BackProject(pixel, &ray, &J) != ProjectionStatus::kOk) {
      return ProjectionStatus::kOutsideDomain;  // not reached: the trace above succeeded
    }
    // P_G = O + u d with u = g·(p_G − O) / (g·d).
    const Eigen::Vector3d g = X_CG_.linear().col(2);
    const double g_d = g.dot(ray.d_C);
    const double g_r = g.dot(X_CG_.translation() - ray.p_C_O);
    const double u = g_r / g_d;
    const Eigen::RowVector2d du = (-(g.transpose() * J.d_origin_d_pixel) * g_d -
                                   g_r * (g.transpose() * J.d_direction_d_pixel)) /
                                  (g_d * g_d);
    const Matrix32d dP = J.d_origin_d_pixel + ray.d_C * du + u * J.d_direction_d_pixel;
    J_ground_pixel->row(0) = X_CG_.linear().col(0).transpose() * dP;
    J_ground_pixel->row(1) = X_CG_.linear().col(1).transpose() * dP;
  }
  return ProjectionStatus::kOk;
}

ProjectionStatus HyperbolicMirrorCamera::ProjectDirect(const Eigen::Vector3d& p_C,
                                                       Eigen::Vector2d* pixel,
                                                       Matrix23d* J_pixel_point) const {
  // Central projection onto the misaligned sensor plane n·(P − p_C_S) = 0 through the pinhole:
  // P' = κ p_C / (n·p_C), κ = n·p_C_S < 0 (Validate()).
  const double n_p = n_C_S_.dot(p_C);
  if (!(n_p > 0.0)) return ProjectionStatus::kBehindCamera;
  const double kappa = n_C_S_.dot(p_C_S_);
  const Eigen::Vector3d p_C_P = (kappa / n_p) * p_C;
  const Eigen::Vector3d q3 = R_CS_.transpose() * (p_C_P - p_C_S_);
  const Eigen::Vector2d q(q3.x(), q3.z());
  const double r_c = q.norm();
  double gain = 1.0 / (1.0 + parameters_.lens_correction[1]);
  double slope = gain;
  if (r_c > 0.0) {
    double r = 0.0;
    if (!LensInverse(r_c, &r, &slope)) return ProjectionStatus::kOutsideDomain;
    gain = r / r_c;
  }
  const Eigen::Vector2d s = gain * q;
  const double pitch = parameters_.pixel_pitch;
  *pixel = Eigen::Vector2d(parameters_.cx - s.x() / pitch, parameters_.cy + s.y() / pitch);
  if (J_pixel_point != nullptr) {
    const Eigen::Matrix3d dP =
        (kappa / n_p) * (Eigen::Matrix3d::Identity() - p_C * n_C_S_.transpose() / n_p);
    const Eigen::Matrix3d dq3 = R_CS_.transpose() * dP;
    Matrix23d dq;
    dq.row(0) = dq3.row(0);
    dq.row(1) = dq3.row(2);
    Matrix23d ds = RadialJacobian(q, gain, slope) * dq;
    ds.row(0) *= -1.0 / pitch;
    ds.row(1) *= 1.0 / pitch;
    *J_pixel_point = ds;
  }
  return ProjectionStatus::kOk;
}

namespace {

// The path pinhole → M(w) → P, M(w) = (m_x + w_0, k_off + sqrt(A + |w|²), m_z + w_1), and its
// derivatives in w.
struct PathLength {
  Eigen::Vector3d p_C_M;
  Matrix32d J_M;  // ∂M/∂w
  double length = 0.0;
  Eigen::Vector2d gradient;
  Eigen::Matrix2d hessian;
  Eigen::Matrix3d H2;  // ∂u2/∂P = (I − u2 u2ᵀ)/ℓ2
  bool degenerate = false;
};

void EvaluatePath(const Eigen::Vector3d& p_C_H, double A, const Eigen::Vector3d& p_C,
                  const Eigen::Vector2d& w, bool derivatives, PathLength* out) {
  const double s = std::sqrt(A + w.squaredNorm());
  out->p_C_M = Eigen::Vector3d(p_C_H.x() + w.x(), p_C_H.y() + s, p_C_H.z() + w.y());
  const Eigen::Vector3d to_point = p_C - out->p_C_M;
  const double l1 = out->p_C_M.norm();
  const double l2 = to_point.norm();
  out->length = l1 + l2;
  out->degenerate = !(l1 > 0.0 && l2 > 0.0);
  if (!derivatives || out->degenerate) return;
  out->J_M << 1.0, 0.0, w.x() / s, w.y() / s, 0.0, 1.0;
  const Eigen::Vector3d u1 = out->p_C_M / l1;
  const Eigen::Vector3d u2 = to_point / l2;
  const Eigen::Vector3d du = u1 - u2;
  out->gradient = out->J_M.transpose() * du;
  const Eigen::Matrix3d H1 = (Eigen::Matrix3d::Identity() - u1 * u1.transpose()) / l1;
  out->H2 = (Eigen::Matrix3d::Identity() - u2 * u2.transpose()) / l2;
  const Eigen::Matrix2d d2y =
      (s * s * Eigen::Matrix2d::Identity() - w * w.transpose()) / (s * s * s);
  out->hessian = out->J_M.transpose() * (H1 + out->H2) * out->J_M + du.y() * d2y;
}

}  // namespace

ProjectionStatus HyperbolicMirrorCamera::Project(const Eigen::Vector3d& p_C, Eigen::Vector2d* pixel,
                                                 Matrix23d* J_pixel_point) const {
  if (!p_C.allFinite()) return ProjectionStatus::kOutsideDomain;
  const double A = parameters_.mirror_constant;
  const double R = parameters_.mirror_radius;
  // Start halfway to the rim on the side of the point (exact azimuth when the pinhole is on the
  // axis); the path length is convex near the solution, damped Newton does the rest.
  Eigen::Vector2d w(p_C.x() - p_C_H_.x(), p_C.z() - p_C_H_.z());
  const double w_norm = w.norm();
  w = w_norm > 0.0 ? Eigen::Vector2d(w * (0.5 * R / w_norm)) : Eigen::Vector2d::Zero();
  PathLength path;
  PathLength trial;
  bool converged = false;
  for (int iteration = 0; iteration < kMaxNewtonIterations && !converged; ++iteration) {
    EvaluatePath(p_C_H_, A, p_C, w, true, &path);
    if (path.degenerate) return ProjectionStatus::kBehindCamera;
    // Newton step on ∇L = 0; where the Hessian is not positive definite, shift it.
    Eigen::Matrix2d H = path.hessian;
    const double half_trace = 0.5 * H.trace();
    const double det = H.determinant();
    const double lambda_min = half_trace - std::sqrt(std::max(0.0, half_trace * half_trace - det));
    const bool newton = lambda_min > 0.0;
    if (!newton) {
      H += (-lambda_min + 0.1 * std::abs(half_trace) + 1e-6) * Eigen::Matrix2d::Identity();
    }
    Eigen::Vector2d step = -H.inverse() * path.gradient;
    if (newton && step.norm() <= kNewtonStepTolerance) {
      w += step;
      converged = true;
      break;
    }
    const double step_norm = step.norm();
    if (step_norm > 0.5 * R) step *= 0.5 * R / step_norm;  // trust region
    // Backtracking: accept when the path does not get longer (to rounding).
    double alpha = 1.0;
    bool accepted = false;
    for (int k = 0; k < 40; ++k) {
      EvaluatePath(p_C_H_, A, p_C, w + alpha * step, false, &trial);
      if (trial.length <= path.length * (1.0 + 4.0 * std::numeric_limits<double>::epsilon())) {
        accepted = true;
        break;
      }
      alpha *= 0.5;
    }
    if (!accepted) break;
    w += alpha * step;
    // The surface is extended beyond the rim only as a device for the solve; a path that keeps
    // shortening far out there (points high above the horizon, whose path-length minimum is at
    // infinity along the asymptotic cone) has no reflection on the mirror.
    if (w.squaredNorm() > 100.0 * R * R) return ProjectionStatus::kOutsideDomain;
  }
  if (!converged) {
    return w.squaredNorm() > R * R ? ProjectionStatus::kOutsideDomain
                                   : ProjectionStatus::kNoConvergence;
  }
  EvaluatePath(p_C_H_, A, p_C, w, true, &path);
  if (path.degenerate) return ProjectionStatus::kBehindCamera;
  // The point must be on the reflecting (outer, lower) side of the mirror: ∇F points inside.
  const Eigen::Vector3d m = HalfGradient(path.p_C_M, p_C_H_);
  if (!(m.dot(p_C - path.p_C_M) < 0.0)) return ProjectionStatus::kBehindCamera;
  if (w.squaredNorm() > R * R) return ProjectionStatus::kOutsideDomain;
  Matrix23d J_direct;
  const ProjectionStatus status =
      ProjectDirect(path.p_C_M, pixel, J_pixel_point != nullptr ? &J_direct : nullptr);
  if (status != ProjectionStatus::kOk) return status;
  if (J_pixel_point != nullptr) {
    // Implicit-function theorem on ∇_w L(w, P) = 0: H dw + ∂(∇_w L)/∂P dP = 0 with
    // ∂(∇_w L)/∂P = −J_Mᵀ H2, so dw/dP = H⁻¹ J_Mᵀ H2.
    const Eigen::Matrix<double, 2, 3> dw = path.hessian.inverse() * path.J_M.transpose() * path.H2;
    *J_pixel_point = J_direct * path.J_M * dw;
  }
  return ProjectionStatus::kOk;
}

ProjectionStatus HyperbolicMirrorCamera::ProjectGroundPoint(const Eigen::Vector2d& p_G_xy,
                                                            Eigen::Vector2d* pixel) const {
  return Project(X_CG_ * Eigen::Vector3d(p_G_xy.x(), p_G_xy.y(), 0.0), pixel);
}

void ComputeGroundMap(const HyperbolicMirrorCamera& camera, GroundMap* map) {
  const int width = camera.width();
  const int height = camera.height();
  const std::size_t size = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
  if (map->width != width || map->height != height || map->x_m.size() != size ||
      map->y_m.size() != size || map->valid.size() != size) {
    map->width = width;
    map->height = height;
    map->x_m.assign(size, 0.0);
    map->y_m.assign(size, 0.0);
    map->valid.assign(size, 0);
  }
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const HyperbolicMirrorParameters& p = camera.parameters_;
  int valid_count = 0;
  for (int v = 0; v < height; ++v) {
    const double s_z = (v - p.cy) * p.pixel_pitch;  // seed eq. (5), as SensorPoint()
    const std::size_t row = static_cast<std::size_t>(v) * static_cast<std::size_t>(width);
    for (int u = 0; u < width; ++u) {
      const double s_x = -(u - p.cx) * p.pixel_pitch;
      double gain = 0.0;
      double x = nan;
      double y = nan;
      const bool ok = camera.LensGainFromTable(std::sqrt(s_x * s_x + s_z * s_z), &gain) &&
                      camera.TraceToGround(s_x, s_z, gain, &x, &y);
      map->x_m[row + u] = ok ? x : nan;
      map->y_m[row + u] = ok ? y : nan;
      map->valid[row + u] = ok ? 1 : 0;
      valid_count += ok ? 1 : 0;
    }
  }
  map->valid_count = valid_count;
}

}  // namespace kinevis::vision
