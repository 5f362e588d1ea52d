// kinevis model hexapod|weld5 fk|ik ...: forward and inverse kinematics of the robot models, for
// sanity-checking a robot description or a configuration by hand. Units on the command line are
// the engineer's: metres or millimetres and degrees as each option says; SI inside.

#include <cmath>
#include <cstdio>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "apps/kinevis/cli_common.h"
#include "apps/kinevis/commands.h"
#include "common/units.h"
#include "hal/common/error.h"
#include "robots/io/robot_description.h"
#include "vision/camera/camera_file.h"
#include "vision/camera/hyperbolic_mirror_camera.h"

namespace kinevis::cli {
namespace {

struct ModelOptions {
  std::string robot_file;              // empty: the built-in default description
  std::vector<double> pose;            // x, y, z (m), roll, pitch, yaw (deg)
  std::vector<double> legs;            // q_j (m)
  std::vector<double> actuators;       // s_j (m)
  std::vector<double> guess_pose;      // as pose
  std::vector<double> joints;          // θ1, θ2 (deg), pz3 (mm), θ4, θ5 (deg)
  std::vector<double> tip_mm;          // torch tip in frame 0 (mm)
  std::vector<double> axis;            // torch axis in frame 0
  double axis_tolerance_deg = -1;      // < 0: the library's default
  std::vector<double> diamond_joints;  // q1, q2 (deg)
  std::vector<double> task;            // φ, γ (deg)
  std::vector<double> direction;       // tool axis in O
  bool json = false;
};

void RequireCount(const std::vector<double>& v, size_t n, const std::string& option,
                  const std::string& what) {
  common::Problems problems(option);
  if (v.size() != n) {
    problems.Add("need " + std::to_string(n) + " comma-separated values " + what + ", got " +
                 std::to_string(v.size()));
  }
  for (size_t i = 0; i < v.size(); ++i) {
    if (!std::isfinite(v[i])) problems.Add("value " + std::to_string(i + 1) + " is not finite");
  }
  problems.ThrowIfAny();
}

// R = Rz(yaw) Ry(pitch) Rx(roll), the convention of the robot description files.
Eigen::Isometry3d PoseFromXyzRpyDeg(const std::vector<double>& v) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
  X.linear() = (Eigen::AngleAxisd(v[5] * common::kDeg, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(v[4] * common::kDeg, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(v[3] * common::kDeg, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  return X;
}

// Roll, pitch, yaw (deg) of R = Rz(yaw) Ry(pitch) Rx(roll).
Eigen::Vector3d RpyDeg(const Eigen::Matrix3d& R) {
  const double pitch = std::asin(std::clamp(-R(2, 0), -1.0, 1.0));
  const double roll = std::atan2(R(2, 1), R(2, 2));
  const double yaw = std::atan2(R(1, 0), R(0, 0));
  return Eigen::Vector3d(roll, pitch, yaw) / common::kDeg;
}

robots::HexapodDescription Hexapod(const ModelOptions& o) {
  if (!o.robot_file.empty()) return robots::LoadHexapodDescription(o.robot_file);
  robots::HexapodDescription d;
  d.name = "kinevis-default-hexapod (built in; robots/hexapod/hexapod.yaml)";
  d.model = robots::HexapodModel::Default();
  d.X_BP_home = robots::HexapodModel::NominalPose();
  return d;
}

robots::Weld5Description Weld5(const ModelOptions& o) {
  if (!o.robot_file.empty()) return robots::LoadWeld5Description(o.robot_file);
  robots::Weld5Description d;
  d.name = "seed004-weld-repair-robot (built in; robots/weld5/weld5.yaml)";
  d.model = robots::Weld5Model::Seed(robots::Weld5TorchTransform(0.025, 0.250, 0.0));
  return d;
}

nlohmann::json PoseJson(const Eigen::Isometry3d& X) {
  const Eigen::Vector3d p = X.translation();
  const Eigen::Vector3d rpy = RpyDeg(X.linear());
  return {{"position_m", {p.x(), p.y(), p.z()}}, {"rpy_deg", {rpy.x(), rpy.y(), rpy.z()}}};
}

void PrintPose(const char* label, const Eigen::Isometry3d& X) {
  const Eigen::Vector3d p = X.translation();
  const Eigen::Vector3d rpy = RpyDeg(X.linear());
  std::printf("%s position %.6f %.6f %.6f m, roll %.4f° pitch %.4f° yaw %.4f°\n", label, p.x(),
              p.y(), p.z(), rpy.x(), rpy.y(), rpy.z());
}

int RunHexapodIk(const ModelOptions& o) {
  RequireCount(o.pose, 6, "--pose", "x,y,z (m), roll,pitch,yaw (deg)");
  const robots::HexapodDescription d = Hexapod(o);
  const Eigen::Isometry3d X_BP = PoseFromXyzRpyDeg(o.pose);
  robots::HexapodData data;
  const robots::Reachability reach = robots::InverseKinematics(d.model, X_BP, &data);
  const robots::Vector6d s = robots::JointPositionsFromLegLengths(d.model, data.q);
  const double cond = robots::ConditionNumber(robots::InverseDifferential(data));
  if (o.json) {
    nlohmann::json legs = nlohmann::json::array();
    for (int j = 0; j < robots::kHexapodLegs; ++j) {
      legs.push_back({{"leg", j},
                      {"length_m", data.q(j)},
                      {"actuator_m", s(j)},
                      {"u", {data.u_B[j].x(), data.u_B[j].y(), data.u_B[j].z()}}});
    }
    std::cout << nlohmann::json{{"robot", d.name},
                                {"pose", PoseJson(X_BP)},
                                {"legs", legs},
                                {"reachable", reach.ok()},
                                {"problem", reach.Describe(d.model, data.q)},
                                {"condition_number", cond}}
                     .dump(2)
              << "\n";
  } else {
    std::printf("robot: %s\n", d.name.c_str());
    PrintPose("pose X_BP:", X_BP);
    std::printf("%-4s %12s %14s   %s\n", "leg", "length (m)", "actuator (m)", "direction u_j (B)");
    for (int j = 0; j < robots::kHexapodLegs; ++j) {
      std::printf("%-4d %12.6f %14.6f   %+.5f %+.5f %+.5f\n", j, data.q(j), s(j), data.u_B[j].x(),
                  data.u_B[j].y(), data.u_B[j].z());
    }
    std::printf("condition number of D_inv: %.3g\n", cond);
    std::printf("%s\n", reach.ok() ? "reachable: all legs within their stroke"
                                   : ("NOT reachable: " + reach.Describe(d.model, data.q)).c_str());
  }
  return reach.ok() ? kExitOk : kExitJobFailed;
}

int RunHexapodFk(const ModelOptions& o) {
  if (o.legs.empty() == o.actuators.empty()) {
    throw common::ConfigError("model hexapod fk: give exactly one of --legs or --actuators");
  }
  const robots::HexapodDescription d = Hexapod(o);
  robots::Vector6d q;
  if (!o.legs.empty()) {
    RequireCount(o.legs, 6, "--legs", "(leg lengths, m)");
    q = Eigen::Map<const robots::Vector6d>(o.legs.data());
  } else {
    RequireCount(o.actuators, 6, "--actuators", "(actuator readings, m)");
    q = robots::LegLengthsFromJointPositions(
        d.model, Eigen::Map<const robots::Vector6d>(o.actuators.data()));
  }
  Eigen::Isometry3d guess = d.X_BP_home;
  if (!o.guess_pose.empty()) {
    RequireCount(o.guess_pose, 6, "--guess", "x,y,z (m), roll,pitch,yaw (deg)");
    guess = PoseFromXyzRpyDeg(o.guess_pose);
  }
  robots::HexapodData data;
  const robots::ForwardKinematicsSummary fk =
      robots::ForwardKinematics(d.model, q, guess, robots::ForwardKinematicsOptions{}, &data);
  const bool in_stroke = fk.converged() && data.reach.ok();
  if (o.json) {
    nlohmann::json out{{"robot", d.name},
                       {"status", robots::ToString(fk.status)},
                       {"iterations", fk.iterations},
                       {"residual_m", fk.residual},
                       {"condition_number", fk.condition_number},
                       {"within_stroke", in_stroke}};
    if (fk.converged()) out["pose"] = PoseJson(fk.X_BP);
    std::cout << out.dump(2) << "\n";
  } else {
    std::printf("robot: %s\n", d.name.c_str());
    std::printf("forward kinematics: %s after %d iterations, residual %.3g m, cond(D_inv) %.3g\n",
                robots::ToString(fk.status), fk.iterations, fk.residual, fk.condition_number);
    if (fk.converged()) {
      PrintPose("pose X_BP:", fk.X_BP);
      if (!data.reach.ok()) {
        std::printf("warning: %s\n", data.reach.Describe(d.model, q).c_str());
      }
    } else {
      std::printf("no pose: the legs given have no solution near the guess (try --guess)\n");
    }
  }
  return fk.converged() ? kExitOk : kExitJobFailed;
}

robots::Vector5d JointsFromCli(const std::vector<double>& v) {
  robots::Vector5d q;
  q << v[0] * common::kDeg, v[1] * common::kDeg, v[2] * 1e-3, v[3] * common::kDeg,
      v[4] * common::kDeg;
  return q;
}

std::string JointsText(const robots::Vector5d& q) {
  char text[160];
  std::snprintf(text, sizeof text, "θ1 %.4f°, θ2 %.4f°, pz3 %.4f mm, θ4 %.4f°, θ5 %.4f°",
                q(0) / common::kDeg, q(1) / common::kDeg, q(2) * 1e3, q(3) / common::kDeg,
                q(4) / common::kDeg);
  return text;
}

nlohmann::json JointsJson(const robots::Vector5d& q) {
  return {{"theta1_deg", q(0) / common::kDeg},
          {"theta2_deg", q(1) / common::kDeg},
          {"pz3_mm", q(2) * 1e3},
          {"theta4_deg", q(3) / common::kDeg},
          {"theta5_deg", q(4) / common::kDeg}};
}

// First joint outside its limits, or -1.
int OutsideLimits(const robots::Weld5Model& m, const robots::Vector5d& q) {
  for (int i = 0; i < robots::kWeld5Joints; ++i) {
    if (q(i) < m.q_min(i) || q(i) > m.q_max(i)) return i;
  }
  return -1;
}

int RunWeld5Fk(const ModelOptions& o) {
  RequireCount(o.joints, 5, "--joints", "θ1,θ2,pz3,θ4,θ5 (deg, deg, mm, deg, deg)");
  const robots::Weld5Description d = Weld5(o);
  const robots::Vector5d q = JointsFromCli(o.joints);
  robots::Weld5Data data;
  robots::Weld5ForwardKinematics(d.model, q, &data);
  const int bad = OutsideLimits(d.model, q);
  const Eigen::Vector3d p = data.p_0T * 1e3;
  const Eigen::Vector3d& u = data.u_0T;
  if (o.json) {
    std::cout << nlohmann::json{{"robot", d.name},
                                {"joints", JointsJson(q)},
                                {"tip_mm", {p.x(), p.y(), p.z()}},
                                {"axis", {u.x(), u.y(), u.z()}},
                                {"outside_limits", bad < 0 ? "" : robots::Weld5JointName(bad)}}
                     .dump(2)
              << "\n";
  } else {
    std::printf("robot: %s\njoints: %s\n", d.name.c_str(), JointsText(q).c_str());
    std::printf("torch tip (frame 0): %.4f %.4f %.4f mm\ntorch axis (frame 0): %+.6f %+.6f %+.6f\n",
                p.x(), p.y(), p.z(), u.x(), u.y(), u.z());
    if (bad >= 0) std::printf("warning: %s outside its limits\n", robots::Weld5JointName(bad));
  }
  return kExitOk;
}

int RunWeld5Ik(const ModelOptions& o) {
  RequireCount(o.tip_mm, 3, "--tip", "x,y,z (mm, frame 0)");
  RequireCount(o.axis, 3, "--axis", "ux,uy,uz (frame 0)");
  const Eigen::Vector3d axis(o.axis[0], o.axis[1], o.axis[2]);
  if (!(axis.norm() > 1e-9)) throw common::ConfigError("--axis: must not be the zero vector");
  const robots::Weld5Description d = Weld5(o);
  robots::Vector5d guess = 0.5 * (d.model.q_min + d.model.q_max);
  if (!o.joints.empty()) {
    RequireCount(o.joints, 5, "--guess", "θ1,θ2,pz3,θ4,θ5 (deg, deg, mm, deg, deg)");
    guess = JointsFromCli(o.joints);
  }
  const Eigen::Vector3d p(o.tip_mm[0] * 1e-3, o.tip_mm[1] * 1e-3, o.tip_mm[2] * 1e-3);
  robots::Weld5IkOptions options;
  if (o.axis_tolerance_deg >= 0) options.axis_tolerance = o.axis_tolerance_deg * common::kDeg;
  const robots::Weld5IkResult r = robots::Weld5InverseKinematics(d.model, p, axis, guess, options);
  if (o.json) {
    nlohmann::json out{{"robot", d.name},
                       {"status", robots::ToString(r.status)},
                       {"iterations", r.iterations},
                       {"position_error_mm", r.position_error * 1e3},
                       {"axis_error_deg", r.axis_error / common::kDeg},
                       {"limiting_joint", r.limiting_joint_name}};
    if (r.converged()) out["joints"] = JointsJson(r.q);
    std::cout << out.dump(2) << "\n";
  } else {
    std::printf("robot: %s\ninverse kinematics: %s after %d iterations\n", d.name.c_str(),
                robots::ToString(r.status), r.iterations);
    if (r.converged()) {
      std::printf("joints: %s\nerrors: tip %.3g mm, axis %.3g°\n", JointsText(r.q).c_str(),
                  r.position_error * 1e3, r.axis_error / common::kDeg);
    } else if (r.status == robots::Weld5IkStatus::kJointLimit) {
      std::printf("the target needs %s outside its limits\n", r.limiting_joint_name);
    } else {
      std::printf("the target is not reachable (closest: tip %.3g mm, axis %.3g° off)\n",
                  r.position_error * 1e3, r.axis_error / common::kDeg);
    }
  }
  return r.converged() ? kExitOk : kExitJobFailed;
}

robots::DiamondDescription Diamond(const ModelOptions& o) {
  if (!o.robot_file.empty()) return robots::LoadDiamondDescription(o.robot_file);
  robots::DiamondDescription d;
  d.name = "diamond-apriori (built in; robots/diamond/diamond_apriori.yaml)";
  d.model = robots::DiamondModel::APriori();
  return d;
}

void PrintDiamondPose(const robots::DiamondModel& m, const robots::DiamondData& data, bool json,
                      const std::string& name, const robots::DiamondReachability& reach) {
  const robots::DiamondSingularityReport sing =
      data.valid ? robots::AnalyzeSingularity(m, data) : robots::DiamondSingularityReport{};
  if (json) {
    nlohmann::json out{{"robot", name}, {"ok", reach.ok()}, {"problem", reach.Describe()}};
    if (data.valid) {
      out["joints_deg"] = {data.q(0) / common::kDeg, data.q(1) / common::kDeg};
      out["task_deg"] = {{"phi", data.task(0) / common::kDeg},
                         {"gamma", data.task(1) / common::kDeg}};
      out["tool_point_mm"] = {data.p_O_T.x() * 1e3, data.p_O_T.y() * 1e3, data.p_O_T.z() * 1e3};
      out["singularity"] = robots::ToString(sing.kind);
      out["task_condition"] = sing.task_condition;
    }
    std::cout << out.dump(2) << "\n";
    return;
  }
  std::printf("robot: %s\n", name.c_str());
  if (data.valid) {
    std::printf("joints: q1 %.4f°, q2 %.4f°\n", data.q(0) / common::kDeg, data.q(1) / common::kDeg);
    std::printf("task: φ %.4f°, γ %.4f°\n", data.task(0) / common::kDeg,
                data.task(1) / common::kDeg);
    std::printf("tool point (RCM frame): %.4f %.4f %.4f mm\n", data.p_O_T.x() * 1e3,
                data.p_O_T.y() * 1e3, data.p_O_T.z() * 1e3);
    std::printf("condition of d(φ,γ)/dq: %.3g (%s)\n", sing.task_condition,
                robots::ToString(sing.kind));
  }
  std::printf("%s\n", reach.ok() ? "within the joint limits and the workspace"
                                 : ("NOT ok: " + reach.Describe()).c_str());
}

int RunDiamondFk(const ModelOptions& o) {
  RequireCount(o.diamond_joints, 2, "--joints", "q1,q2 (deg)");
  const robots::DiamondDescription d = Diamond(o);
  robots::DiamondData data;
  const Eigen::Vector2d q(o.diamond_joints[0] * common::kDeg, o.diamond_joints[1] * common::kDeg);
  const robots::DiamondReachability reach = robots::ForwardKinematics(d.model, q, &data);
  PrintDiamondPose(d.model, data, o.json, d.name, reach);
  return reach.ok() ? kExitOk : kExitJobFailed;
}

int RunDiamondIk(const ModelOptions& o) {
  if (o.task.empty() == o.direction.empty()) {
    throw common::ConfigError("model diamond ik: give exactly one of --task or --direction");
  }
  const robots::DiamondDescription d = Diamond(o);
  Eigen::Vector2d q;
  robots::DiamondReachability reach;
  if (!o.task.empty()) {
    RequireCount(o.task, 2, "--task", "phi,gamma (deg)");
    reach = robots::InverseKinematics(d.model, Eigen::Vector2d(o.task[0], o.task[1]) * common::kDeg,
                                      &q);
  } else {
    RequireCount(o.direction, 3, "--direction", "ux,uy,uz (RCM frame)");
    const Eigen::Vector3d u(o.direction[0], o.direction[1], o.direction[2]);
    if (!(u.norm() > 1e-12)) throw common::ConfigError("--direction: must not be the zero vector");
    reach = robots::InverseKinematicsFromDirection(d.model, u, &q);
  }
  robots::DiamondData data;
  const bool solved = q.allFinite() && !reach.Has(robots::DiamondReach::kInvalidInput) &&
                      !reach.Has(robots::DiamondReach::kNoAssembly) &&
                      !reach.Has(robots::DiamondReach::kUnreachable);
  if (solved) robots::ForwardKinematics(d.model, q, &data);
  PrintDiamondPose(d.model, data, o.json, d.name, reach);
  return reach.ok() ? kExitOk : kExitJobFailed;
}

struct ProjectOptions {
  std::string camera;
  std::vector<double> point;  // x, y, z in C (m)
  std::vector<double> pixel;  // u, v (px)
  bool json = false;
};

int RunProject(const ProjectOptions& o) {
  if (o.point.empty() == o.pixel.empty()) {
    throw common::ConfigError("project: give exactly one of --point or --pixel");
  }
  const std::unique_ptr<vision::CameraModel> camera = vision::OpenCameraModel(o.camera);
  nlohmann::json out{{"camera", o.camera},
                     {"model", std::string(camera->Name())},
                     {"width", camera->width()},
                     {"height", camera->height()}};
  vision::ProjectionStatus status;
  if (!o.point.empty()) {
    RequireCount(o.point, 3, "--point", "x,y,z (m, camera frame)");
    const Eigen::Vector3d p(o.point[0], o.point[1], o.point[2]);
    Eigen::Vector2d pixel;
    vision::Matrix23d J;
    status = camera->Project(p, &pixel, &J);
    out["status"] = std::string(vision::ToString(status));
    if (status == vision::ProjectionStatus::kOk) {
      out["pixel"] = {pixel.x(), pixel.y()};
      out["in_image"] = camera->InImage(pixel);
      out["jacobian_px_per_m"] = {{J(0, 0), J(0, 1), J(0, 2)}, {J(1, 0), J(1, 1), J(1, 2)}};
    }
    if (!o.json) {
      std::printf("camera: %s (%.*s, %d×%d)\n", o.camera.c_str(),
                  static_cast<int>(camera->Name().size()), camera->Name().data(), camera->width(),
                  camera->height());
      if (status == vision::ProjectionStatus::kOk) {
        std::printf("pixel: %.6f %.6f (%s the image)\n", pixel.x(), pixel.y(),
                    camera->InImage(pixel) ? "inside" : "OUTSIDE");
        std::printf("d pixel / d point (px/m):\n  %12.4f %12.4f %12.4f\n  %12.4f %12.4f %12.4f\n",
                    J(0, 0), J(0, 1), J(0, 2), J(1, 0), J(1, 1), J(1, 2));
      } else {
        std::printf("no image of the point: %.*s\n", static_cast<int>(ToString(status).size()),
                    ToString(status).data());
      }
    }
  } else {
    RequireCount(o.pixel, 2, "--pixel", "u,v (px)");
    vision::Ray ray;
    status = camera->BackProject(Eigen::Vector2d(o.pixel[0], o.pixel[1]), &ray);
    out["status"] = std::string(vision::ToString(status));
    if (status == vision::ProjectionStatus::kOk) {
      out["ray_origin_m"] = {ray.p_C_O.x(), ray.p_C_O.y(), ray.p_C_O.z()};
      out["ray_direction"] = {ray.d_C.x(), ray.d_C.y(), ray.d_C.z()};
    }
    // The robot-camera's question: where on the floor is this pixel (seed 000's distance map)?
    const auto* mirror = dynamic_cast<const vision::HyperbolicMirrorCamera*>(camera.get());
    Eigen::Vector2d ground;
    const bool on_ground =
        mirror && mirror->BackProjectToGround(Eigen::Vector2d(o.pixel[0], o.pixel[1]), &ground) ==
                      vision::ProjectionStatus::kOk;
    if (on_ground) {
      out["ground_m"] = {ground.x(), ground.y()};
      out["ground_distance_m"] = ground.norm();
    }
    if (!o.json) {
      std::printf("camera: %s (%.*s, %d×%d)\n", o.camera.c_str(),
                  static_cast<int>(camera->Name().size()), camera->Name().data(), camera->width(),
                  camera->height());
      if (status == vision::ProjectionStatus::kOk) {
        std::printf("ray origin (m): %.6f %.6f %.6f\nray direction: %+.8f %+.8f %+.8f\n",
                    ray.p_C_O.x(), ray.p_C_O.y(), ray.p_C_O.z(), ray.d_C.x(), ray.d_C.y(),
                    ray.d_C.z());
        if (camera->IsCentral()) {
          const double angle = std::acos(std::clamp(ray.d_C.z(), -1.0, 1.0)) / common::kDeg;
          std::printf("angle from the camera's z axis: %.4f°\n", angle);
        }
        if (on_ground) {
          std::printf("ground point (x forward, y left): %.4f %.4f m, distance %.4f m\n",
                      ground.x(), ground.y(), ground.norm());
        } else if (mirror) {
          std::printf("the ray does not reach the ground\n");
        }
      } else {
        std::printf("no ray: %.*s\n", static_cast<int>(ToString(status).size()),
                    ToString(status).data());
      }
    }
  }
  if (o.json) std::cout << out.dump(2) << "\n";
  return status == vision::ProjectionStatus::kOk ? kExitOk : kExitJobFailed;
}

}  // namespace

void AddModelCommands(const Parents& parents, CommandList* commands) {
  CLI::App& app = *parents.app;
  auto o = std::make_shared<ModelOptions>();
  CLI::App* model = app.add_subcommand(
      "model", "Forward and inverse kinematics of the robot models, to sanity-check a description");
  model->require_subcommand(1);
  model->footer(
      "Description file format: docs/robot-description.md. Exit 1 when a pose is "
      "unreachable or forward kinematics does not converge.");
  const auto robot_option = [o](CLI::App* sub, const char* default_file) {
    sub->add_option("--robot", o->robot_file,
                    std::string("Robot description YAML (default: the built-in model, equal to ") +
                        default_file + ")")
        ->check(CLI::ExistingFile);
    sub->add_flag("--json", o->json, "Print JSON instead of text");
  };

  CLI::App* hexapod = model->add_subcommand("hexapod", "Gough–Stewart hexapod (seed 002)");
  hexapod->require_subcommand(1);
  CLI::App* hik = hexapod->add_subcommand("ik",
                                          "Leg lengths, actuator readings and directions "
                                          "for a platform pose");
  hik->add_option("--pose", o->pose, "X_BP as x,y,z (m),roll,pitch,yaw (deg; R = Rz Ry Rx)")
      ->delimiter(',')
      ->required();
  robot_option(hik, "robots/hexapod/hexapod.yaml");
  commands->push_back({hik, [o] { return RunHexapodIk(*o); }});
  CLI::App* hfk = hexapod->add_subcommand("fk", "Platform pose for given leg lengths (Newton)");
  hfk->add_option("--legs", o->legs, "Leg lengths q1..q6 (m)")->delimiter(',');
  hfk->add_option("--actuators", o->actuators, "Actuator readings s1..s6 (m), q = q0 + s")
      ->delimiter(',');
  hfk->add_option("--guess", o->guess_pose,
                  "Initial pose x,y,z (m),roll,pitch,yaw (deg); "
                  "default: the description's home pose")
      ->delimiter(',');
  robot_option(hfk, "robots/hexapod/hexapod.yaml");
  commands->push_back({hfk, [o] { return RunHexapodFk(*o); }});

  CLI::App* weld5 = model->add_subcommand("weld5", "5-DOF weld-repair robot (seed 004)");
  weld5->require_subcommand(1);
  CLI::App* wfk = weld5->add_subcommand("fk", "Torch tip and axis for joint values");
  wfk->add_option("--joints", o->joints, "θ1,θ2,pz3,θ4,θ5 in deg, deg, mm, deg, deg")
      ->delimiter(',')
      ->required();
  robot_option(wfk, "robots/weld5/weld5.yaml");
  commands->push_back({wfk, [o] { return RunWeld5Fk(*o); }});
  CLI::App* wik = weld5->add_subcommand(
      "ik", "Joints for a torch tip and axis (roll about the axis is free); limits enforced");
  wik->add_option("--tip", o->tip_mm, "Torch tip x,y,z in frame 0 (mm)")
      ->delimiter(',')
      ->required();
  wik->add_option("--axis", o->axis, "Torch axis ux,uy,uz in frame 0 (normalised here)")
      ->delimiter(',')
      ->required();
  wik->add_option("--guess", o->joints,
                  "Initial joints θ1,θ2,pz3,θ4,θ5 (deg, deg, mm, deg, deg); "
                  "default: mid-range")
      ->delimiter(',');
  wik->add_option("--axis-tolerance", o->axis_tolerance_deg,
                  "Accept the axis within this angle (deg; default ~1e-7°). The seed robot's "
                  "α1 = −89.827° keeps its torch axis 0.173° off vertical at best")
      ->check(CLI::NonNegativeNumber);
  robot_option(wik, "robots/weld5/weld5.yaml");
  commands->push_back({wik, [o] { return RunWeld5Ik(*o); }});

  CLI::App* diamond =
      model->add_subcommand("diamond", "DIAMOND spherical parallelogram robot (seed 001)");
  diamond->require_subcommand(1);
  CLI::App* dfk =
      diamond->add_subcommand("fk", "Tool direction (φ, γ) and point for joint readings");
  dfk->add_option("--joints", o->diamond_joints, "q1,q2 (deg)")->delimiter(',')->required();
  robot_option(dfk, "robots/diamond/diamond_apriori.yaml");
  commands->push_back({dfk, [o] { return RunDiamondFk(*o); }});
  CLI::App* dik = diamond->add_subcommand(
      "ik", "Joint readings for a tool direction, on the collision-free branch");
  dik->add_option("--task", o->task, "φ,γ (deg): azimuth and polar angle of the tool axis")
      ->delimiter(',');
  dik->add_option("--direction", o->direction, "Tool axis ux,uy,uz in the RCM frame")
      ->delimiter(',');
  robot_option(dik, "robots/diamond/diamond_apriori.yaml");
  commands->push_back({dik, [o] { return RunDiamondIk(*o); }});

  auto p = std::make_shared<ProjectOptions>();
  std::string builtins;
  for (const auto& n : vision::BuiltinCameraModelNames()) builtins += " builtin:" + n;
  CLI::App* project = app.add_subcommand(
      "project", "Project a 3-D point through a camera model, or back-project a pixel to a ray");
  project
      ->add_option("camera", p->camera,
                   "Camera model file (docs/camera-models.md; a ROS/OpenCV intrinsics YAML is a "
                   "pinhole-brown model) or one of:" +
                       builtins)
      ->required();
  project->add_option("--point", p->point, "x,y,z in the camera frame (m)")->delimiter(',');
  project->add_option("--pixel", p->pixel, "u,v (px; (0,0) = centre of the top-left pixel)")
      ->delimiter(',');
  project->add_flag("--json", p->json, "Print JSON instead of text");
  project->footer(
      "Exit 1 when the point has no image or the pixel no ray (the reason is printed).");
  commands->push_back({project, [p] { return RunProject(*p); }});
}

}  // namespace kinevis::cli
