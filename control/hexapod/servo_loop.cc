#include "control/hexapod/servo_loop.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "common/clock.h"
#include "common/config_error.h"
#include "hal/common/error.h"
#include "vision/plot/line_plot.h"

namespace kinevis::control {
std::string GroundTruthFeatureOptions::Validate() const {
  common::Problems p;
  p.Positive("fps", fps);
  p.NonNegative("noise_sigma", noise_sigma);
  return p.Message();
}

GroundTruthLegFeatureSource::GroundTruthLegFeatureSource(robots::HexapodModel true_model,
                                                         const Eigen::Isometry3d& X_CB,
                                                         PoseProvider pose,
                                                         GroundTruthFeatureOptions options)
    : model_(std::move(true_model)),
      X_CB_(X_CB),
      pose_(std::move(pose)),
      options_(options),
      rng_(options.seed) {
  std::string message = options.Validate();
  if (!pose_) message += std::string(message.empty() ? "" : "; ") + "pose: empty provider";
  if (!message.empty()) throw std::invalid_argument("GroundTruthLegFeatureSource: " + message);
}

bool GroundTruthLegFeatureSource::Poll(common::Duration now, LegFeatureFrame* frame) {
  if (!started_) {
    next_frame_ = now;
    started_ = true;
  }
  if (now < next_frame_) return false;
  // The camera keeps its own rate whatever the loop does; frames missed while paused are lost.
  const common::Duration period = common::FromSeconds(1.0 / options_.fps);
  while (next_frame_ <= now) next_frame_ += period;
  if (paused_) return false;
  robots::InverseKinematics(model_, pose_(), &data_);
  for (int j = 0; j < kHexapodLegs; ++j) {
    Eigen::Vector3d u = X_CB_.linear() * data_.u_B[j];
    if (options_.noise_sigma > 0) {
      for (int k = 0; k < 3; ++k) u[k] += options_.noise_sigma * noise_(rng_);
      u.normalize();
    }
    frame->u_C[j] = u;
    frame->visible[j] = !hidden_[j] && data_.q[j] > 0;
  }
  frame->timestamp = now;
  frame->sequence = ++sequence_;
  return true;
}

void GroundTruthLegFeatureSource::SetLegHidden(int leg, bool hidden) {
  if (leg >= 0 && leg < kHexapodLegs) hidden_[leg] = hidden;
}
void GroundTruthLegFeatureSource::SetPaused(bool paused) { paused_ = paused; }

std::string ServoLoopOptions::Validate() const {
  common::Problems p;
  p.Positive("cycle_period_s", cycle_period_s);
  p.Positive("max_leg_velocity", max_leg_velocity);
  p.NonNegative("stroke_margin", stroke_margin);
  p.Positive("stop_deceleration", stop_deceleration);
  p.Positive("max_command_lead", max_command_lead);
  if (min_visible_legs < 3 || min_visible_legs > kHexapodLegs) {
    p.Add("min_visible_legs", min_visible_legs, "must be in 3..6");
  }
  p.Positive("stale_camera_timeout_s", stale_camera_timeout_s);
  p.Positive("convergence_threshold", convergence_threshold);
  p.NonNegative("convergence_translation", convergence_translation);
  p.NonNegative("convergence_rotation", convergence_rotation);
  p.NonNegative("convergence_filter_s", convergence_filter_s);
  p.NonNegative("convergence_dwell_s", convergence_dwell_s);
  p.Positive("timeout_s", timeout_s);
  if (max_consecutive_cycle_timeouts < 0) {
    p.Add("max_consecutive_cycle_timeouts", max_consecutive_cycle_timeouts, "must be >= 0");
  }
  return p.Message();
}

const char* ToString(ServoLoopState state) {
  switch (state) {
    case ServoLoopState::kRunning:
      return "running";
    case ServoLoopState::kHoldLegLost:
      return "hold_leg_lost";
    case ServoLoopState::kHoldStaleCamera:
      return "hold_stale_camera";
    case ServoLoopState::kHoldLaw:
      return "hold_law";
    case ServoLoopState::kWaitFirstFrame:
      return "wait_first_frame";
    case ServoLoopState::kStopping:
      return "stopping";
  }
  return "?";
}

const char* ServoOutcomeName(LoopOutcome outcome) {
  switch (outcome) {
    case LoopOutcome::kCompleted:
      return "converged";
    case LoopOutcome::kLimit:
      return "stroke limit";
    default:
      return ToString(outcome);
  }
}

ServoLoop::ServoLoop(hal::DriveBus* bus, common::Clock* clock, LegFeatureSource* source,
                     const robots::HexapodModel& model, LegServo* law, ServoLoopOptions options)
    : bus_(bus), clock_(clock), source_(source), model_(model), law_(law), options_(options) {
  std::string message = options.Validate();
  const auto add = [&](const std::string& text) {
    message += (message.empty() ? "" : "; ") + text;
  };
  if (!bus || !clock || !source || !law) add("bus, clock, source and law must not be null");
  if (bus) {
    drives_ = bus->drives();
    if (drives_.size() != static_cast<size_t>(kHexapodLegs)) {
      add("bus " + bus->name() + ": has " + std::to_string(drives_.size()) + " drives, expected 6");
    }
  }
  const std::string model_problems = model.Validate();
  if (!model_problems.empty()) add("model: " + model_problems);
  if (!message.empty()) throw std::invalid_argument("ServoLoop: " + message);
  DriveSupervisorOptions supervision;
  supervision.cycle_period_s = options_.cycle_period_s;
  supervision.max_consecutive_cycle_timeouts = options_.max_consecutive_cycle_timeouts;
  supervision.stop_action = options_.stop_action;
  supervision.axis_name = "leg";
  supervision.first_axis_number = 0;
  supervisor_ = std::make_unique<DriveSupervisor>(bus_, clock_, kHexapodLegs, supervision);
  step_law_ = std::make_unique<LegDirectionLaw>(source_, law_, options_);
}

LegDirectionLaw::LegDirectionLaw(LegFeatureSource* source, LegServo* law,
                                 const ServoLoopOptions& options)
    : source_(source), law_(law), options_(options) {}

void LegDirectionLaw::Start(common::Duration now) {
  law_->Reset();
  out_ = LegLawOutput();
  out_.error_norm = std::numeric_limits<double>::quiet_NaN();
  q_dot_.setZero();
  have_frame_ = false;
  last_frame_time_ = now;
  converged_since_ = -1;
  filtered_displacement_.setZero();
  have_displacement_ = false;
  last_displacement_time_ = now;
  frames_ = law_steps_ = 0;
  legs_lost_ = {};
  time_to_threshold_s_ = -1;
}

const LegLawOutput& LegDirectionLaw::Step(common::Duration now, double t, const Vector6d& q) {
  out_.new_frame = source_->Poll(now, &frame_);
  if (out_.new_frame) {
    ++frames_;
    have_frame_ = true;
    last_frame_time_ = now;
    out_.u_C = frame_.u_C;
    out_.visible = frame_.visible;
    int visible = 0;
    for (int j = 0; j < kHexapodLegs; ++j) {
      visible += frame_.visible[j] ? 1 : 0;
      if (!frame_.visible[j]) legs_lost_[j] = true;
    }
    const LegServoResult r = law_->Compute(frame_.u_C, frame_.visible, q);
    ++law_steps_;
    out_.error_norm = r.error_norm;
    if (visible < options_.min_visible_legs) {
      out_.detail = ServoLoopState::kHoldLegLost;
      q_dot_.setZero();
    } else if (!r.ok()) {
      out_.detail = ServoLoopState::kHoldLaw;
      q_dot_.setZero();
    } else {
      out_.detail = ServoLoopState::kRunning;
      q_dot_ = r.q_dot;
    }
    // The remaining displacement of one frame carries the features' noise: it is judged after a
    // first-order low-pass over the frames (time constant convergence_filter_s).
    if (r.ok()) {
      const double dt = have_displacement_ ? common::ToSeconds(now - last_displacement_time_) : 0.0;
      const double a = have_displacement_ && options_.convergence_filter_s > 0
                           ? 1.0 - std::exp(-dt / options_.convergence_filter_s)
                           : 1.0;
      filtered_displacement_ += a * (r.remaining_displacement - filtered_displacement_);
      have_displacement_ = true;
      last_displacement_time_ = now;
    }
    out_.remaining_translation = filtered_displacement_.head<3>().norm();
    out_.remaining_rotation = filtered_displacement_.tail<3>().norm();
    const bool error_small = r.error_norm <= options_.convergence_threshold;
    const bool displacement_small =
        r.ok() && options_.convergence_translation > 0 && options_.convergence_rotation > 0 &&
        out_.remaining_translation <= options_.convergence_translation &&
        out_.remaining_rotation <= options_.convergence_rotation;
    if (visible == kHexapodLegs && (error_small || displacement_small)) {
      if (time_to_threshold_s_ < 0) time_to_threshold_s_ = t;
      if (converged_since_ < 0) converged_since_ = t;
      out_.converged_by_error = error_small;
    } else {
      converged_since_ = -1;
    }
  } else if (!have_frame_) {
    out_.detail = ServoLoopState::kWaitFirstFrame;
  }
  if (have_frame_ && common::ToSeconds(now - last_frame_time_) > options_.stale_camera_timeout_s) {
    out_.detail = ServoLoopState::kHoldStaleCamera;
    q_dot_.setZero();
    converged_since_ = -1;
  }
  out_.state = out_.detail == ServoLoopState::kRunning ? LawState::kRunning : LawState::kHold;
  out_.q_dot = out_.state == LawState::kRunning ? q_dot_ : Vector6d::Zero();
  // Converged: this cycle's rates are still commanded; the loop then stops.
  if (converged_since_ >= 0 && t - converged_since_ >= options_.convergence_dwell_s) {
    out_.state = LawState::kDone;
  }
  return out_;
}

bool ServoLoop::SetRates(const Vector6d& q_dot, const Vector6d& s, Vector6d* s_target) {
  bool lead_limited = false;
  for (int j = 0; j < kHexapodLegs; ++j) {
    std::error_code ec;
    if (options_.command_mode == DriveCommandMode::kVelocity) {
      ec = drives_[j]->SetTargetVelocity(q_dot[j]);
    } else {
      double target = (*s_target)[j] + q_dot[j] * options_.cycle_period_s;
      const double lead = target - s[j];
      if (std::abs(lead) > options_.max_command_lead) {
        target = s[j] + std::copysign(options_.max_command_lead, lead);
        lead_limited = true;
      }
      (*s_target)[j] = target;
      ec = drives_[j]->SetTargetPosition(target);
    }
    // Refusals (not active) show as a fault at the next Cycle(); nothing to do here.
    (void)ec;
  }
  return lead_limited;
}

void ServoLoop::StopAndSettle(Vector6d* s_target) {
  // Zero rates until every leg is at rest (at most 1 s). In CSP the set-points stay where they
  // are (within the lead of the readings): the drives come to rest on them.
  bool cycled = false;
  supervisor_->Settle([&] {
    if (cycled && supervisor_->AllAtRest()) return false;
    Vector6d s;
    supervisor_->Positions(s.data());
    SetRates(Vector6d::Zero(), s, s_target);
    cycled = true;
    return true;
  });
}

ServoLoopReport ServoLoop::Run(const std::function<void(const ServoLoopSample&)>& observer) {
  ServoLoopReport report;
  const double period_s = options_.cycle_period_s;
  const common::Duration period = common::FromSeconds(period_s);
  const size_t capacity = static_cast<size_t>(options_.timeout_s / period_s) + 16;
  report.samples.reserve(capacity);
  CycleTimingRecorder timing(capacity);

  const hal::DriveMode mode = options_.command_mode == DriveCommandMode::kVelocity
                                  ? hal::DriveMode::kCyclicSynchronousVelocity
                                  : hal::DriveMode::kCyclicSynchronousPosition;
  supervisor_->ResetCounts();
  Vector6d s_target;
  supervisor_->Positions(s_target.data());
  report.message = supervisor_->SelectMode(mode, &report.faulted_drive);
  if (!report.message.empty()) {
    report.outcome = ServoLoopOutcome::kNotStarted;
    return report;
  }

  const common::Duration start = clock_->Now();
  DeadlineGrid grid(clock_, period, start);
  step_law_->Start(start);
  ServoLoopSample sample;
  sample.error_norm = std::numeric_limits<double>::quiet_NaN();
  const double q_min = model_.leg_length_min + options_.stroke_margin;
  const double q_max = model_.leg_length_max - options_.stroke_margin;

  for (;;) {
    const DeadlineGrid::Wake wake = grid.Next();
    const common::Duration now = wake.time;
    const double t = common::ToSeconds(now - start);
    timing.Wake(wake);
    ++report.cycles;

    // 1. The bus: a fault of any drive stops all six. A cycle whose answers did not all come in
    // time (the drives keep last cycle's values; their heartbeats are supervised separately) is
    // tolerated max_consecutive_cycle_timeouts times in a row, then it is a fault too.
    const SupervisedCycle cycle = supervisor_->Cycle();
    const common::Duration io_end = clock_->Now();
    timing.Io(common::ToSeconds(io_end - now));
    report.cycle_timeouts = supervisor_->cycle_timeouts();
    if (cycle.fault) {
      // The bus has already put the faulted drive in a safe state and (quick_stop_all_on_fault)
      // asked the others to quick-stop; the supervisor makes sure of it, whatever the bus's
      // policy.
      report.outcome = ServoLoopOutcome::kDriveFault;
      report.message = supervisor_->FaultMessage(cycle, t, &report.faulted_drive);
      if (const std::string p = supervisor_->SafeStop(); !p.empty()) report.message += "; " + p;
      spdlog::error("servo loop: {}", report.message);
      break;
    }

    Vector6d s;
    supervisor_->Positions(s.data());
    const Vector6d q = robots::LegLengthsFromJointPositions(model_, s);

    // 2. The law: a camera frame's answer, or the last one held.
    const LegLawOutput& law = step_law_->Step(now, t, q);
    sample.new_frame = law.new_frame;
    sample.state = law.detail;
    sample.error_norm = law.error_norm;
    sample.remaining_translation = law.remaining_translation;
    sample.remaining_rotation = law.remaining_rotation;
    sample.u_C = law.u_C;
    sample.visible = law.visible;
    switch (law.detail) {
      case ServoLoopState::kHoldLegLost:
        ++report.hold_cycles_leg_lost;
        break;
      case ServoLoopState::kHoldStaleCamera:
        ++report.hold_cycles_stale_camera;
        break;
      case ServoLoopState::kHoldLaw:
        ++report.hold_cycles_law;
        break;
      default:
        break;
    }

    // 3. Safety: velocity limit (uniform scaling), then strokes.
    Vector6d q_dot = law.q_dot;
    const double fastest = q_dot.cwiseAbs().maxCoeff();
    if (fastest > options_.max_leg_velocity) {
      q_dot *= options_.max_leg_velocity / fastest;
      ++report.velocity_scaled_cycles;
    }
    for (int j = 0; j < kHexapodLegs && report.stroke_leg < 0; ++j) {
      // Where leg j would stop: two cycles at the commanded rate (this one and the bus latency)
      // and then braking at stop_deceleration; also the leg as it is now.
      const double v = q_dot[j];
      const double q_stop =
          q[j] + 2.0 * period_s * v + v * std::abs(v) / (2.0 * options_.stop_deceleration);
      const bool out_high = (q_stop > q_max && v > 0) || q[j] > q_max;
      const bool out_low = (q_stop < q_min && v < 0) || q[j] < q_min;
      if (out_high || out_low) {
        report.stroke_leg = j;
        std::ostringstream out;
        out << "leg " << j << " would leave its stroke: q = " << q[j] << " m, rate " << v
            << " m/s, stopping at " << q_stop << " m, limits [" << q_min << ", " << q_max
            << "] m (leg_length_min/max with stroke_margin " << options_.stroke_margin << " m)";
        report.message = out.str();
      }
    }
    if (report.stroke_leg >= 0) q_dot.setZero();

    if (SetRates(q_dot, s, &s_target)) ++report.lead_limited_cycles;
    sample.time_s = t;
    sample.q = q;
    sample.q_dot = q_dot;
    sample.q_command = options_.command_mode == DriveCommandMode::kPosition
                           ? robots::LegLengthsFromJointPositions(model_, s_target)
                           : q;
    timing.Compute(common::ToSeconds(clock_->Now() - io_end));
    report.samples.push_back(sample);
    if (observer) observer(report.samples.back());

    if (report.stroke_leg >= 0) {
      report.outcome = ServoLoopOutcome::kLimit;
      spdlog::warn("servo loop: {}", report.message);
      break;
    }
    if (law.state == LawState::kDone) {
      report.outcome = ServoLoopOutcome::kCompleted;
      std::ostringstream out;
      if (law.converged_by_error) {
        out << "converged: |e| <= " << options_.convergence_threshold;
      } else {
        out << "converged: remaining displacement <= " << 1e3 * options_.convergence_translation
            << " mm and " << options_.convergence_rotation * 180 / M_PI
            << " deg (|e| = " << sample.error_norm << ")";
      }
      out << " for " << options_.convergence_dwell_s << " s";
      report.message = out.str();
      report.converged_by_error = law.converged_by_error;
      break;
    }
    if (t >= options_.timeout_s) {
      report.outcome = ServoLoopOutcome::kTimeout;
      report.message = "timeout after " + std::to_string(options_.timeout_s) +
                       " s, |e| = " + std::to_string(sample.error_norm);
      break;
    }
  }

  if (report.outcome != ServoLoopOutcome::kDriveFault) StopAndSettle(&s_target);
  report.duration_s = common::ToSeconds(clock_->Now() - start);
  report.final_error_norm = sample.error_norm;
  report.frames = step_law_->frames();
  report.law_steps = step_law_->law_steps();
  report.legs_lost = step_law_->legs_lost();
  report.time_to_threshold_s = step_law_->time_to_threshold_s();
  Vector6d s;
  supervisor_->Positions(s.data());
  report.final_q = robots::LegLengthsFromJointPositions(model_, s);
  report.timing = timing.Statistics(period_s, grid.missed_deadlines());
  return report;
}

void WriteServoLogCsv(const std::string& path, const std::vector<ServoLoopSample>& samples) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error(path + ": cannot open for writing");
  out << "time_s,error_norm";
  for (int j = 0; j < kHexapodLegs; ++j) out << ",u" << j << "_x,u" << j << "_y,u" << j << "_z";
  for (int j = 0; j < kHexapodLegs; ++j) out << ",q" << j << "_m";
  for (int j = 0; j < kHexapodLegs; ++j) out << ",qdot" << j << "_mps";
  out << ",remaining_mm,remaining_deg,visible,state,new_frame\n";
  out.precision(10);
  for (const ServoLoopSample& s : samples) {
    out << s.time_s << ',' << s.error_norm;
    for (int j = 0; j < kHexapodLegs; ++j) {
      out << ',' << s.u_C[j].x() << ',' << s.u_C[j].y() << ',' << s.u_C[j].z();
    }
    for (int j = 0; j < kHexapodLegs; ++j) out << ',' << s.q[j];
    for (int j = 0; j < kHexapodLegs; ++j) out << ',' << s.q_dot[j];
    out << ',' << 1e3 * s.remaining_translation << ',' << s.remaining_rotation * 180 / M_PI << ',';
    for (int j = 0; j < kHexapodLegs; ++j) out << (s.visible[j] ? '1' : '0');
    out << ',' << ToString(s.state) << ',' << (s.new_frame ? 1 : 0) << '\n';
  }
  if (!out) throw std::runtime_error(path + ": write failed");
}

void WriteConvergencePlot(const std::string& path, const std::vector<ServoLoopSample>& samples,
                          double threshold, const std::string& title) {
  vision::plot::LinePlotOptions o;
  o.title = title;
  o.x_label = "time (s)";
  o.y_label = "|e|";
  o.y_scale = vision::plot::AxisScale::kLog10;
  vision::plot::LinePlot plot(o);
  vision::plot::Series error;
  error.name = "|e| (leg directions)";
  for (const ServoLoopSample& s : samples) {
    if (!s.new_frame) continue;
    error.x.push_back(s.time_s);
    error.y.push_back(s.error_norm);
  }
  vision::plot::Series line;
  line.name = "threshold";
  line.thickness_px = 1;
  if (!samples.empty()) {
    line.x = {samples.front().time_s, samples.back().time_s};
    line.y = {threshold, threshold};
  }
  plot.AddSeries(std::move(error));
  plot.AddSeries(std::move(line));
  plot.WritePng(path);
}

}  // namespace kinevis::control
