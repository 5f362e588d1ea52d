#include "control/diamond/diamond_laws.h"

#include <visp3/core/vpColVector.h>
#include <visp3/core/vpHomogeneousMatrix.h>
#include <visp3/core/vpMatrix.h>
#include <visp3/visual_features/vpFeaturePoint.h>
#include <visp3/vs/vpServo.h>

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "common/clock.h"
#include "common/config_error.h"

namespace kinevis::control {
namespace {

// Normalised image coordinates of a pixel's ray (distortion removed); false when the camera
// cannot back-project it or the ray does not point forward.
bool NormalizedFromPixel(const vision::CameraModel& camera, const Eigen::Vector2d& pixel,
                         Eigen::Vector2d* xy) {
  vision::Ray ray;
  if (!pixel.allFinite() || camera.BackProject(pixel, &ray) != vision::ProjectionStatus::kOk ||
      !(ray.d_C.z() > 1e-9)) {
    return false;
  }
  *xy = Eigen::Vector2d(ray.d_C.x() / ray.d_C.z(), ray.d_C.y() / ray.d_C.z());
  return true;
}

double Condition(const Eigen::Matrix2d& J) {
  const Eigen::Vector2d sv = Eigen::JacobiSVD<Eigen::Matrix2d>(J).singularValues();
  return sv[1] > 0 ? sv[0] / sv[1] : std::numeric_limits<double>::infinity();
}

}  // namespace

const char* ToString(DiamondLineKind kind) {
  return kind == DiamondLineKind::kTaskLine ? "task" : "top-view";
}

// ---------------------------------------------------------------------------------------------
// Lines

DiamondLine DiamondLine::SeedVertical(DiamondLineKind kind) {
  DiamondLine line;
  line.kind = kind;
  // Seed: γ from π/6 to π/2. The workspace box is γ ∈ [30°, 85°] (π/2 needs the limbs on top of
  // each other; robots/diamond/README.md) and a line must not end on the box's edge, where any
  // stopping distance leaves it: we keep 2° from both ends.
  line.from = {M_PI / 2, 32 * M_PI / 180};
  line.to = {M_PI / 2, 83 * M_PI / 180};
  return line;
}

DiamondLine DiamondLine::SeedHorizontal(DiamondLineKind kind) {
  DiamondLine line;
  line.kind = kind;
  line.from = {M_PI / 3, M_PI / 4};
  line.to = {2 * M_PI / 3, M_PI / 4};
  if (kind == DiamondLineKind::kTopViewLine) {
    // The chord y_O = R sin(π/4) through (π/2, π/4): at φ = π/3 and 2π/3, sin γ = sin(π/4) /
    // sin(π/3) (R cancels), so the chord's end points are model-independent in (φ, γ).
    const double gamma_end = std::asin(std::sin(M_PI / 4) / std::sin(M_PI / 3));
    line.from[1] = gamma_end;
    line.to[1] = gamma_end;
  }
  return line;
}

std::string DiamondLine::Validate() const {
  common::Problems p;
  if (!from.allFinite()) p.Add("line.from: must be finite");
  if (!to.allFinite()) p.Add("line.to: must be finite");
  if (!(std::isfinite(duration_s) && duration_s > 0)) {
    p.Add("line.duration_s", duration_s, "must be > 0");
  }
  return p.Message();
}

bool DiamondLineReference(const DiamondLine& line, double radius, double t, Eigen::Vector2d* task,
                          Eigen::Vector2d* task_rate) {
  const double T = line.duration_s;
  const double tau = std::clamp(t / T, 0.0, 1.0);
  const double s = tau * tau * tau * (10.0 + tau * (-15.0 + 6.0 * tau));
  const double s_dot = tau * tau * (30.0 + tau * (-60.0 + 30.0 * tau)) / T;
  if (line.kind == DiamondLineKind::kTaskLine) {
    *task = line.from + s * (line.to - line.from);
    *task_rate = s_dot * (line.to - line.from);
    return true;
  }
  const auto top = [radius](const Eigen::Vector2d& x) {
    return Eigen::Vector2d(radius * std::sin(x[1]) * std::cos(x[0]),
                           radius * std::sin(x[1]) * std::sin(x[0]));
  };
  const Eigen::Vector2d a = top(line.from), b = top(line.to);
  const Eigen::Vector2d p = a + s * (b - a);
  const Eigen::Vector2d p_dot = s_dot * (b - a);
  const double r = p.norm();
  if (!(r > 1e-9 * radius && r < radius)) return false;  // on the base axis φ is undefined
  const double gamma = std::asin(r / radius);
  const double r_dot = p.dot(p_dot) / r;
  *task = Eigen::Vector2d(std::atan2(p.y(), p.x()), gamma);
  *task_rate = Eigen::Vector2d((p.x() * p_dot.y() - p.y() * p_dot.x()) / (r * r),
                               r_dot / (radius * std::cos(gamma)));
  return true;
}

// ---------------------------------------------------------------------------------------------
// Task-space PD

std::string DiamondPdOptions::Validate() const {
  common::Problems p;
  if (!(std::isfinite(kp) && kp > 0)) p.Add("kp", kp, "must be > 0 (1/s)");
  if (!(std::isfinite(kd) && kd >= 0)) p.Add("kd", kd, "must be >= 0");
  if (!(std::isfinite(derivative_filter_s) && derivative_filter_s >= 0)) {
    p.Add("derivative_filter_s", derivative_filter_s, "must be >= 0 s");
  }
  if (!(settle_tolerance > 0)) p.Add("settle_tolerance", settle_tolerance, "must be > 0 rad");
  if (!(settle_dwell_s >= 0)) p.Add("settle_dwell_s", settle_dwell_s, "must be >= 0 s");
  if (!(settle_timeout_s > 0)) p.Add("settle_timeout_s", settle_timeout_s, "must be > 0 s");
  if (!(max_condition > 1)) p.Add("max_condition", max_condition, "must be > 1");
  return p.Message();
}

DiamondTaskPdLaw::DiamondTaskPdLaw(const robots::DiamondModel& model, const DiamondLine& line,
                                   DiamondPdOptions options)
    : model_(model), line_(line), options_(options) {
  common::Problems p;
  if (const std::string m = model.Validate(); !m.empty()) p.Add("model: " + m);
  if (const std::string l = line.Validate(); !l.empty()) p.Add(l);
  if (const std::string o = options.Validate(); !o.empty()) p.Add(o);
  if (!p.Message().empty()) throw std::invalid_argument("DiamondTaskPdLaw: " + p.Message());
}

void DiamondTaskPdLaw::Start(const Eigen::Vector2d& /*q*/, common::Duration /*now*/) {
  have_prev_ = false;
  e_rate_.setZero();
  settled_since_ = -1.0;
}

DiamondLawOutput DiamondTaskPdLaw::Step(const DiamondCycleInput& in) {
  DiamondLawOutput out;
  robots::ForwardKinematics(model_, in.q, &data_);
  if (!data_.valid) {
    out.state = DiamondLawState::kStop;
    out.reason = "the readings have no assembly in the model";
    return out;
  }
  out.task = data_.task;
  Eigen::Vector2d x_ref, x_ref_rate;
  if (!DiamondLineReference(line_, model_.radius, in.t, &x_ref, &x_ref_rate)) {
    out.state = DiamondLawState::kStop;
    out.reason = "the line leaves the sphere's top view";
    return out;
  }
  out.task_reference = x_ref;
  const Eigen::Vector2d e = x_ref - data_.task;
  if (have_prev_ && in.dt > 0) {
    const Eigen::Vector2d raw = (e - e_prev_) / in.dt;
    const double a = in.dt / (options_.derivative_filter_s + in.dt);
    e_rate_ += a * (raw - e_rate_);
  }
  e_prev_ = e;
  have_prev_ = true;
  const robots::DiamondSingularityReport sing =
      robots::AnalyzeSingularity(model_, data_, options_.max_condition);
  if (!(sing.task_condition <= options_.max_condition)) {
    out.state = DiamondLawState::kStop;
    out.reason = "near a singularity of the task Jacobian";
    return out;
  }
  const Eigen::Vector2d u = x_ref_rate + options_.kp * e + options_.kd * e_rate_;
  out.q_dot = robots::TaskJacobian(data_).partialPivLu().solve(u);
  out.state = DiamondLawState::kRunning;
  if (in.t >= line_.duration_s) {
    if (e.cwiseAbs().maxCoeff() <= options_.settle_tolerance) {
      if (settled_since_ < 0) settled_since_ = in.t;
      if (in.t - settled_since_ >= options_.settle_dwell_s) out.state = DiamondLawState::kDone;
    } else {
      settled_since_ = -1.0;
    }
    if (out.state != DiamondLawState::kDone &&
        in.t > line_.duration_s + options_.settle_timeout_s) {
      out.state = DiamondLawState::kStop;
      out.q_dot.setZero();
      out.reason = "did not settle on the line's end";
    }
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// Image Jacobians

bool MarkerNormalizedJacobian(const Eigen::Isometry3d& X_CO, const robots::DiamondModel& model,
                              const robots::DiamondData& data, Eigen::Vector2d* xy,
                              Eigen::Matrix2d* J) {
  if (!data.valid) return false;
  const Eigen::Vector3d p_C = X_CO * data.p_O_T;
  const double Z = p_C.z();
  if (!(Z > 0)) return false;
  const double x = p_C.x() / Z, y = p_C.y() / Z;
  Eigen::Matrix<double, 2, 3> Jn;
  Jn << 1.0 / Z, 0.0, -x / Z, 0.0, 1.0 / Z, -y / Z;
  *xy = Eigen::Vector2d(x, y);
  *J = Jn * X_CO.linear() * robots::ToolPointJacobian(model, data);
  return true;
}

bool MarkerPixelJacobian(const vision::CameraModel& camera, const Eigen::Isometry3d& X_CO,
                         const robots::DiamondModel& model, const robots::DiamondData& data,
                         Eigen::Vector2d* pixel, Eigen::Matrix2d* J) {
  if (!data.valid) return false;
  const Eigen::Vector3d p_C = X_CO * data.p_O_T;
  Eigen::Vector2d px;
  vision::Matrix23d Jp;
  if (camera.Project(p_C, &px, &Jp) != vision::ProjectionStatus::kOk) return false;
  *pixel = px;
  *J = Jp * X_CO.linear() * robots::ToolPointJacobian(model, data);
  return true;
}

// ---------------------------------------------------------------------------------------------
// Marker source

DetectedMarkerSource::DetectedMarkerSource(Grabber grabber, vision::MarkerDetectorOptions options)
    : grabber_(std::move(grabber)), detector_(options) {
  if (!grabber_) throw std::invalid_argument("DetectedMarkerSource: the grabber is empty");
}

bool DetectedMarkerSource::Poll(common::Duration now, MarkerFrame* frame) {
  vision::ImageView8 image;
  common::Duration timestamp = now;
  if (!grabber_(now, &image, &timestamp)) return false;
  vision::MarkerDetection d = detector_.Detect(image, have_last_ ? &last_ : nullptr);
  // Lost from the window (a fast move, or a wrong prediction): search the whole image once.
  if (!d.found() && have_last_) d = detector_.Detect(image);
  have_last_ = d.found();
  if (d.found()) last_ = d.pixel;
  frame->timestamp = timestamp;
  frame->found = d.found();
  frame->pixel = d.pixel;
  frame->confidence = d.confidence;
  frame->status = d.status;
  frame->sequence = ++sequence_;
  return true;
}

// ---------------------------------------------------------------------------------------------
// Visual servo

std::string DiamondIbvsOptions::Validate() const {
  common::Problems p;
  if (!(std::isfinite(gain) && gain > 0)) p.Add("gain", gain, "must be > 0 (1/s)");
  if (!(convergence_px > 0)) p.Add("convergence_px", convergence_px, "must be > 0 px");
  if (!(convergence_dwell_s >= 0)) {
    p.Add("convergence_dwell_s", convergence_dwell_s, "must be >= 0 s");
  }
  if (max_lost_frames < 1) p.Add("max_lost_frames", max_lost_frames, "must be >= 1");
  if (!(stale_camera_timeout_s > 0)) {
    p.Add("stale_camera_timeout_s", stale_camera_timeout_s, "must be > 0 s");
  }
  if (!(first_frame_timeout_s > 0)) {
    p.Add("first_frame_timeout_s", first_frame_timeout_s, "must be > 0 s");
  }
  if (!(max_condition > 1)) p.Add("max_condition", max_condition, "must be > 1");
  return p.Message();
}

struct DiamondMarkerServo::Impl {
  vpFeaturePoint s, s_star;
  vpServo task;  // after the features: destroyed before them
  vpMatrix fJe = vpMatrix(6, 2);

  explicit Impl(const Eigen::Isometry3d& X_CO, double gain) {
    task.setServo(vpServo::EYETOHAND_L_cVf_fJe);
    task.setInteractionMatrixType(vpServo::CURRENT, vpServo::PSEUDO_INVERSE);
    task.setLambda(gain);
    vpHomogeneousMatrix cMo;
    for (int r = 0; r < 4; ++r) {
      for (int c = 0; c < 4; ++c) cMo[r][c] = X_CO.matrix()(r, c);
    }
    task.set_cVf(cMo);
    s.buildFrom(0.0, 0.0, 1.0);
    s_star.buildFrom(0.0, 0.0, 1.0);
    task.addFeature(s, s_star);
  }
};

DiamondMarkerServo::DiamondMarkerServo(const robots::DiamondModel& model,
                                       const vision::CameraModel& camera,
                                       const Eigen::Isometry3d& X_CO, MarkerFeatureSource* source,
                                       DiamondIbvsOptions options)
    : model_(model), camera_(camera), X_CO_(X_CO), source_(source), options_(options) {
  common::Problems p;
  if (const std::string m = model.Validate(); !m.empty()) p.Add("model: " + m);
  if (const std::string o = options.Validate(); !o.empty()) p.Add(o);
  if (!X_CO.matrix().allFinite()) p.Add("X_CO: must be finite");
  if (source == nullptr) p.Add("source: must not be null");
  if (!p.Message().empty()) throw std::invalid_argument("DiamondMarkerServo: " + p.Message());
  impl_ = std::make_unique<Impl>(X_CO_, options_.gain);
}

DiamondMarkerServo::~DiamondMarkerServo() = default;

void DiamondMarkerServo::SetTarget(const Eigen::Vector2d& pixel) {
  Eigen::Vector2d xy;
  if (!pixel.allFinite() || !camera_.InImage(pixel) || !NormalizedFromPixel(camera_, pixel, &xy)) {
    std::ostringstream out;
    out << "DiamondMarkerServo::SetTarget: pixel (" << pixel.x() << ", " << pixel.y()
        << ") is not a point of the " << camera_.width() << "x" << camera_.height()
        << " image the camera model can back-project";
    throw std::invalid_argument(out.str());
  }
  target_px_ = pixel;
  target_xy_ = xy;
  has_target_ = true;
}

bool DiamondMarkerServo::Compute(const Eigen::Vector2d& q, const Eigen::Vector2d& pixel,
                                 Eigen::Vector2d* q_dot, Eigen::Matrix2d* task_jacobian) {
  if (!has_target_) return false;
  robots::ForwardKinematics(model_, q, &data_);
  Eigen::Vector2d xy_model, xy;
  Eigen::Matrix2d J;
  if (!MarkerNormalizedJacobian(X_CO_, model_, data_, &xy_model, &J)) return false;
  if (!(Condition(J) <= options_.max_condition)) return false;
  if (!NormalizedFromPixel(camera_, pixel, &xy)) return false;
  const double Z = (X_CO_ * data_.p_O_T).z();
  impl_->s.buildFrom(xy.x(), xy.y(), Z);
  impl_->s_star.buildFrom(target_xy_.x(), target_xy_.y(), Z);
  const robots::Matrix32d dp_dq = robots::ToolPointJacobian(model_, data_);
  for (int r = 0; r < 6; ++r) {
    for (int c = 0; c < 2; ++c) impl_->fJe[r][c] = r < 3 ? dp_dq(r, c) : 0.0;
  }
  impl_->task.set_fJe(impl_->fJe);
  vpColVector v;
  try {
    v = impl_->task.computeControlLaw();
  } catch (const std::exception&) {
    return false;
  }
  if (v.getRows() != 2) return false;
  *q_dot = Eigen::Vector2d(v[0], v[1]);
  if (!q_dot->allFinite()) return false;
  if (task_jacobian != nullptr) {
    const vpMatrix Jt = impl_->task.getTaskJacobian();
    for (int r = 0; r < 2; ++r) {
      for (int c = 0; c < 2; ++c) (*task_jacobian)(r, c) = Jt[r][c];
    }
  }
  return true;
}

void DiamondMarkerServo::Start(const Eigen::Vector2d& /*q*/, common::Duration now) {
  start_ = now;
  last_frame_ = now;
  have_frame_ = false;
  lost_frames_ = 0;
  q_dot_.setZero();
  last_pixel_.setConstant(NAN);
  converged_since_ = -1.0;
}

DiamondLawOutput DiamondMarkerServo::Step(const DiamondCycleInput& in) {
  DiamondLawOutput out;
  out.pixel_reference = target_px_;
  if (!has_target_) {
    out.state = DiamondLawState::kStop;
    out.reason = "no target set";
    return out;
  }
  robots::ForwardKinematics(model_, in.q, &data_);
  if (data_.valid) out.task = data_.task;
  MarkerFrame frame;
  out.new_frame = source_->Poll(in.now, &frame);
  if (out.new_frame) {
    have_frame_ = true;
    last_frame_ = in.now;
    if (frame.found) {
      lost_frames_ = 0;
      last_pixel_ = frame.pixel;
      if (!Compute(in.q, frame.pixel, &q_dot_)) {
        q_dot_.setZero();
        out.state = DiamondLawState::kStop;
        out.reason = "image Jacobian singular or the marker not in front of the camera";
        out.pixel = last_pixel_;
        return out;
      }
      if ((frame.pixel - target_px_).norm() <= options_.convergence_px) {
        if (converged_since_ < 0) converged_since_ = in.t;
      } else {
        converged_since_ = -1.0;
      }
    } else {
      ++lost_frames_;
      q_dot_.setZero();
      converged_since_ = -1.0;
    }
  }
  out.pixel = last_pixel_;
  out.marker_found = have_frame_ && lost_frames_ == 0;
  if (lost_frames_ >= options_.max_lost_frames) {
    out.state = DiamondLawState::kStop;
    out.reason = "marker lost";
    return out;
  }
  if (!have_frame_) {
    out.state = DiamondLawState::kHold;
    out.reason = "waiting for the first camera frame";
    if (common::ToSeconds(in.now - start_) > options_.first_frame_timeout_s) {
      out.state = DiamondLawState::kStop;
      out.reason = "no camera frame";
    }
    return out;
  }
  if (common::ToSeconds(in.now - last_frame_) > options_.stale_camera_timeout_s) {
    out.state = DiamondLawState::kStop;
    out.reason = "camera stale";
    return out;
  }
  if (lost_frames_ > 0) {
    out.state = DiamondLawState::kHold;
    out.reason = "marker not found in the last frame";
    return out;
  }
  out.q_dot = q_dot_;
  out.state = DiamondLawState::kRunning;
  if (converged_since_ >= 0 && in.t - converged_since_ >= options_.convergence_dwell_s) {
    out.state = DiamondLawState::kDone;
    out.q_dot.setZero();
  }
  return out;
}

}  // namespace kinevis::control
