#include "control/diamond/diamond_loop.h"

#include <spdlog/spdlog.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include "common/clock.h"
#include "common/config_error.h"
#include "hal/common/error.h"

namespace kinevis::control {
namespace {

using robots::kDiamondJoints;

// Largest |w_i · u − cos β| of a forward kinematics result: zero when both limbs close on the
// tool axis, i.e. the tool point is on the sphere of the RCM through a real assembly.
double ClosureResidual(const robots::DiamondModel& model, const robots::DiamondData& data) {
  double r = 0.0;
  for (int i = 0; i < kDiamondJoints; ++i) {
    r = std::max(r, std::abs(data.w_O[i].dot(data.u_O) - std::cos(model.beta)));
  }
  return r;
}

constexpr double kClosureTolerance = 1e-9;

}  // namespace

std::string DiamondLoopOptions::Validate() const {
  common::Problems problems;
  const auto bad = [&problems](const char* field, double value, const char* rule) {
    problems.Add(field, value, rule);
  };
  if (!(cycle_period_s > 0 && cycle_period_s <= 0.1)) {
    bad("cycle_period_s", cycle_period_s, "must be in (0, 0.1] s");
  }
  if (!(max_joint_velocity > 0)) bad("max_joint_velocity", max_joint_velocity, "must be > 0");
  if (!(max_joint_acceleration > 0)) {
    bad("max_joint_acceleration", max_joint_acceleration, "must be > 0");
  }
  if (!(max_command_lead > 0)) bad("max_command_lead", max_command_lead, "must be > 0");
  if (!(stop_deceleration > 0)) bad("stop_deceleration", stop_deceleration, "must be > 0");
  if (!(theta_margin >= 0)) bad("theta_margin", theta_margin, "must be >= 0");
  if (!(separation_margin >= 0)) bad("separation_margin", separation_margin, "must be >= 0");
  if (max_consecutive_cycle_timeouts < 0) {
    bad("max_consecutive_cycle_timeouts", max_consecutive_cycle_timeouts, "must be >= 0");
  }
  if (!(timeout_s > 0)) bad("timeout_s", timeout_s, "must be > 0");
  return problems.Message();
}

double Straightness(const std::vector<Eigen::Vector2d>& points) {
  if (points.size() < 3) return 0.0;
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& p : points) mean += p;
  mean /= static_cast<double>(points.size());
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  for (const auto& p : points) cov += (p - mean) * (p - mean).transpose();
  cov /= static_cast<double>(points.size());
  // The total least-squares line runs along the largest eigenvector; the mean squared distance
  // from it is the smallest eigenvalue.
  const double lambda_min = Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(cov).eigenvalues()[0];
  return std::sqrt(std::max(0.0, lambda_min));
}

DiamondControlLoop::DiamondControlLoop(hal::DriveBus* bus, common::Clock* clock,
                                       const robots::DiamondModel& model,
                                       DiamondLoopOptions options)
    : bus_(bus), clock_(clock), model_(model), options_(options) {
  std::string message = options.Validate();
  const auto add = [&](const std::string& text) {
    message += (message.empty() ? "" : "; ") + text;
  };
  if (!bus || !clock) add("bus and clock must not be null");
  if (bus) {
    drives_ = bus->drives();
    if (drives_.size() != static_cast<size_t>(kDiamondJoints)) {
      add("bus " + bus->name() + ": has " + std::to_string(drives_.size()) + " drives, expected 2");
    }
  }
  if (const std::string m = model.Validate(); !m.empty()) add("model: " + m);
  if (!message.empty()) throw std::invalid_argument("DiamondControlLoop: " + message);
  DriveSupervisorOptions supervision;
  supervision.cycle_period_s = options_.cycle_period_s;
  supervision.max_consecutive_cycle_timeouts = options_.max_consecutive_cycle_timeouts;
  supervision.stop_action = options_.stop_action;
  supervision.axis_name = "joint";
  supervision.first_axis_number = 1;
  supervisor_ = std::make_unique<DriveSupervisor>(bus_, clock_, kDiamondJoints, supervision);
}

bool DiamondControlLoop::SetCommand(const Eigen::Vector2d& q_command) {
  bool ok = true;
  for (int i = 0; i < kDiamondJoints; ++i) {
    // A refusal (not active) shows as a fault at the next Cycle().
    ok = !drives_[i]->SetTargetPosition(q_command[i]) && ok;
  }
  return ok;
}

std::string DiamondControlLoop::CheckLimits(const Eigen::Vector2d& q,
                                            robots::DiamondData* data) const {
  const robots::DiamondReachability reach = robots::ForwardKinematics(model_, q, data);
  std::ostringstream out;
  if (!reach.ok()) out << reach.Describe();
  const auto add = [&](const std::string& text) { out << (out.tellp() > 0 ? "; " : "") << text; };
  char text[160];
  for (int i = 0; i < kDiamondJoints; ++i) {
    const double theta = q[i] + model_.joint_offsets[i];
    const double lo = model_.theta_min[i] + options_.theta_margin;
    const double hi = model_.theta_max[i] - options_.theta_margin;
    if (theta < lo || theta > hi) {
      std::snprintf(text, sizeof text, "theta_%d = %.6g rad outside [%.6g, %.6g] (limits less %g)",
                    i + 1, theta, lo, hi, options_.theta_margin);
      add(text);
    }
  }
  const double separation = (q[0] + model_.joint_offsets[0]) - (q[1] + model_.joint_offsets[1]);
  const double lo = model_.separation_min + options_.separation_margin;
  const double hi = model_.separation_max - options_.separation_margin;
  if (separation < lo || separation > hi) {
    std::snprintf(text, sizeof text,
                  "limb separation theta_1 - theta_2 = %.6g rad outside [%.6g, %.6g]", separation,
                  lo, hi);
    add(text);
  }
  return out.str();
}

void DiamondControlLoop::HoldAndSettle(Eigen::Vector2d* q_command) {
  // Brakes the commanded motion at stop_deceleration (the stopping distance the limit check
  // allowed for), then holds the set-point for a few cycles so that the drives arrive.
  const double dt = options_.cycle_period_s;
  Eigen::Vector2d v = Eigen::Vector2d::Zero();
  for (int i = 0; i < kDiamondJoints; ++i) v[i] = drives_[i]->status().velocity;
  int still = 0;
  supervisor_->Settle([&] {
    if (still >= 10) return false;
    const double speed = v.cwiseAbs().maxCoeff();
    if (speed > 0) v *= std::max(0.0, speed - options_.stop_deceleration * dt) / speed;
    *q_command += v * dt;
    SetCommand(*q_command);
    still = v.isZero() ? still + 1 : 0;
    return true;
  });
}

void DiamondControlLoop::SafeState(DiamondLoopReport* report) {
  if (const std::string problems = supervisor_->SafeStop(); !problems.empty()) {
    report->message += "; " + problems;
  }
}

DiamondLoopReport DiamondControlLoop::Run(
    DiamondLaw* law, const std::function<void(const DiamondLoopSample&)>& observer) {
  DiamondLoopReport report;
  if (law == nullptr) {
    report.message = "no law";
    return report;
  }
  const double dt = options_.cycle_period_s;
  const common::Duration period = common::FromSeconds(dt);
  const size_t capacity = static_cast<size_t>(options_.timeout_s / dt) + 16;
  if (options_.keep_samples) report.samples.reserve(capacity);
  CycleTimingRecorder timing(capacity);

  supervisor_->ResetCounts();
  Eigen::Vector2d q_command;
  supervisor_->Positions(q_command.data());
  report.message =
      supervisor_->SelectMode(hal::DriveMode::kCyclicSynchronousPosition, &report.faulted_drive);
  if (!report.message.empty()) {
    report.outcome = DiamondLoopOutcome::kNotStarted;
    return report;
  }

  const common::Duration start = clock_->Now();
  law->Start(q_command, start);
  DeadlineGrid grid(clock_, period, start);
  Eigen::Vector2d q_dot_previous = Eigen::Vector2d::Zero();
  robots::DiamondData data;
  DiamondLoopSample sample;

  const auto finish = [&](DiamondLoopOutcome outcome, const std::string& message) {
    report.outcome = outcome;
    report.message = message;
  };

  for (;;) {
    const DeadlineGrid::Wake wake = grid.Next();
    const common::Duration now = wake.time;
    sample.time_s = common::ToSeconds(now - start);
    sample.period_s = wake.period_s;
    sample.lateness_s = wake.lateness_s;
    timing.Wake(wake);
    ++report.cycles;

    // 1. The bus.
    const SupervisedCycle cycle = supervisor_->Cycle();
    const common::Duration io_end = clock_->Now();
    sample.io_s = common::ToSeconds(io_end - now);
    timing.Io(sample.io_s);
    report.cycle_timeouts = supervisor_->cycle_timeouts();
    if (cycle.fault) {
      finish(DiamondLoopOutcome::kDriveFault,
             supervisor_->FaultMessage(cycle, sample.time_s, &report.faulted_drive));
      SafeState(&report);
      spdlog::error("diamond loop: {}", report.message);
      break;
    }

    // 2. The law.
    for (int i = 0; i < kDiamondJoints; ++i) sample.q[i] = drives_[i]->status().position;
    DiamondCycleInput input;
    input.now = now;
    input.t = sample.time_s;
    input.dt = dt;
    input.q = sample.q;
    sample.law = law->Step(input);
    if (sample.law.state == DiamondLawState::kStop) {
      finish(DiamondLoopOutcome::kLawStop,
             "stopped at t = " + std::to_string(sample.time_s) + " s: " + sample.law.reason);
      HoldAndSettle(&q_command);
      SafeState(&report);
      spdlog::error("diamond loop: {}", report.message);
      break;
    }
    if (sample.law.state == DiamondLawState::kDone) {
      finish(DiamondLoopOutcome::kCompleted,
             "completed at t = " + std::to_string(sample.time_s) + " s");
      HoldAndSettle(&q_command);
      break;
    }

    // 3. Safety: rates, limits with the stopping distance, RCM closure.
    Eigen::Vector2d q_dot = Eigen::Vector2d::Zero();
    if (sample.law.state == DiamondLawState::kRunning) {
      q_dot = sample.law.q_dot;
    } else {
      ++report.hold_cycles;
    }
    if (!q_dot.allFinite()) q_dot.setZero();
    const double fastest = q_dot.cwiseAbs().maxCoeff();
    if (fastest > options_.max_joint_velocity) {
      q_dot *= options_.max_joint_velocity / fastest;
      ++report.velocity_scaled_cycles;
    }
    const Eigen::Vector2d change = q_dot - q_dot_previous;
    const double largest_change = change.cwiseAbs().maxCoeff();
    if (largest_change > options_.max_joint_acceleration * dt) {
      q_dot = q_dot_previous + change * (options_.max_joint_acceleration * dt / largest_change);
      ++report.acceleration_limited_cycles;
    }
    Eigen::Vector2d q_next = q_command + q_dot * dt;
    const Eigen::Vector2d lead = q_next - sample.q;
    if (lead.cwiseAbs().maxCoeff() > options_.max_command_lead) {
      const double L = options_.max_command_lead;
      q_next = sample.q + lead.cwiseMax(-L).cwiseMin(L);
      ++report.lead_limited_cycles;
    }
    const Eigen::Vector2d q_stop =
        q_next + q_dot * dt +
        q_dot.cwiseProduct(q_dot.cwiseAbs()) / (2.0 * options_.stop_deceleration);
    robots::DiamondData stop_data;
    std::string problem = CheckLimits(q_next, &data);
    const double closure = data.valid ? ClosureResidual(model_, data) : INFINITY;
    if (problem.empty()) problem = CheckLimits(q_stop, &stop_data);
    if (problem.empty() && !(closure <= kClosureTolerance)) {
      problem = "the commanded joints do not close the mechanism (RCM): residual " +
                std::to_string(closure);
    }
    if (!problem.empty()) {
      finish(DiamondLoopOutcome::kLimit, "limit at t = " + std::to_string(sample.time_s) +
                                             " s: commanded q = (" + std::to_string(q_next[0]) +
                                             ", " + std::to_string(q_next[1]) +
                                             ") rad: " + problem);
      HoldAndSettle(&q_command);
      SafeState(&report);
      spdlog::error("diamond loop: {}", report.message);
      break;
    }
    report.rcm_closure_max = std::max(report.rcm_closure_max, closure);
    q_command = q_next;
    q_dot_previous = q_dot;
    SetCommand(q_command);
    sample.q_command = q_command;
    sample.q_dot = q_dot;
    timing.Compute(common::ToSeconds(clock_->Now() - io_end));
    if (options_.keep_samples && report.samples.size() < capacity) report.samples.push_back(sample);
    if (observer) observer(sample);

    if (sample.time_s >= options_.timeout_s) {
      finish(DiamondLoopOutcome::kTimeout, "timeout after " + std::to_string(sample.time_s) + " s");
      HoldAndSettle(&q_command);
      break;
    }
  }
  report.duration_s = common::ToSeconds(clock_->Now() - start);
  for (int i = 0; i < kDiamondJoints; ++i) report.final_q[i] = drives_[i]->status().position;
  report.timing = timing.Statistics(dt, grid.missed_deadlines());
  return report;
}

void WriteDiamondLogCsv(const std::string& path, const std::vector<DiamondLoopSample>& samples) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error(path + ": cannot write the diamond control log");
  out << "time_s,period_us,lateness_us,io_us,q1_rad,q2_rad,q1_cmd_rad,q2_cmd_rad,qdot1_radps,"
         "qdot2_radps,phi_rad,gamma_rad,phi_ref_rad,gamma_ref_rad,u_px,v_px,u_ref_px,v_ref_px,"
         "new_frame,marker_found,state\n";
  out.precision(10);
  for (const DiamondLoopSample& s : samples) {
    out << s.time_s << ',' << s.period_s * 1e6 << ',' << s.lateness_s * 1e6 << ',' << s.io_s * 1e6
        << ',' << s.q[0] << ',' << s.q[1] << ',' << s.q_command[0] << ',' << s.q_command[1] << ','
        << s.q_dot[0] << ',' << s.q_dot[1] << ',' << s.law.task[0] << ',' << s.law.task[1] << ','
        << s.law.task_reference[0] << ',' << s.law.task_reference[1] << ',' << s.law.pixel[0] << ','
        << s.law.pixel[1] << ',' << s.law.pixel_reference[0] << ',' << s.law.pixel_reference[1]
        << ',' << (s.law.new_frame ? 1 : 0) << ',' << (s.law.marker_found ? 1 : 0) << ','
        << ToString(s.law.state) << '\n';
  }
  if (!out) throw std::runtime_error(path + ": writing the diamond control log failed");
}

}  // namespace kinevis::control
