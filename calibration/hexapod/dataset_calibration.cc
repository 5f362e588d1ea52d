#include "calibration/hexapod/dataset_calibration.h"

#include <cmath>
#include <limits>
#include <memory>
#include <stdexcept>

namespace kinevis::calibration {
namespace {

using robots::kHexapodLegs;
using vision::hexapod::LegObservation;
using vision::hexapod::LegPrediction;

}  // namespace

std::string DatasetCalibrationOptions::Validate() const {
  std::string message;
  const auto add = [&](const std::string& text) {
    if (!text.empty()) message += (message.empty() ? "" : "; ") + text;
  };
  add(edges.Validate());
  add(calibration.Validate());
  if (passes < 1) add("passes: must be >= 1, got " + std::to_string(passes));
  return message;
}

DatasetCalibrationResult CalibrateHexapodDataset(const HexapodDataset& dataset,
                                                 const vision::CameraModel& camera,
                                                 const DatasetCalibrationOptions& options) {
  if (const std::string m = options.Validate(); !m.empty()) {
    throw std::invalid_argument("hexapod dataset calibration: " + m);
  }
  if (!camera.IsCentral()) {
    throw std::invalid_argument("hexapod dataset calibration: camera model " +
                                std::string(camera.Name()) +
                                " is not central (the limb planes need one viewpoint)");
  }
  const robots::HexapodModel& nominal = dataset.nominal;
  if (const std::string m = nominal.Validate(); !m.empty()) {
    throw std::invalid_argument(dataset.directory + ": robot: " + m);
  }

  // Read every image once, and the platform pose of each by nominal FK of its readings.
  struct Frame {
    std::vector<uint8_t> pixels;
    Eigen::Isometry3d X_BP;
    bool fk_converged = false;
  };
  std::vector<Frame> frames(dataset.poses.size());
  robots::HexapodData data;
  for (size_t k = 0; k < dataset.poses.size(); ++k) {
    const HexapodDatasetPose& pose = dataset.poses[k];
    int width = 0, height = 0;
    frames[k].pixels = ReadDatasetImage(dataset, pose, &width, &height);
    if (width != camera.width() || height != camera.height()) {
      throw std::invalid_argument(
          dataset.directory + "/" + pose.image + ": image is " + std::to_string(width) + "x" +
          std::to_string(height) + " but the camera model " + dataset.camera_model + " is " +
          std::to_string(camera.width()) + "x" + std::to_string(camera.height()));
    }
    const robots::Vector6d q = robots::LegLengthsFromJointPositions(nominal, pose.s);
    const robots::ForwardKinematicsSummary fk = robots::ForwardKinematics(
        nominal, q, pose.X_BP_commanded, robots::ForwardKinematicsOptions{}, &data);
    frames[k].fk_converged = fk.converged();
    frames[k].X_BP = fk.converged() ? fk.X_BP : pose.X_BP_commanded;
  }

  vision::hexapod::LegEdgeOptions edges = options.edges;
  if (options.edge_locator_from_dataset) {
    edges.locator = dataset.edge_locator == "parabola" ? vision::hexapod::EdgeLocator::kParabola
                                                       : vision::hexapod::EdgeLocator::kStepRamp;
    edges.edge_blur_px = dataset.edge_blur_px;
  }

  DatasetCalibrationResult out;
  Eigen::Isometry3d X_CB = dataset.X_BC_hint.inverse();
  bool have_points = false;
  std::array<Eigen::Vector3d, kHexapodLegs> p_C_A{};
  auto workspace = std::make_unique<vision::hexapod::LegEdgeWorkspace>();
  out.last_pass_change = std::numeric_limits<double>::quiet_NaN();

  for (int pass = 0; pass < options.passes; ++pass) {
    HexapodCalibrationData normals;
    normals.leg_radius = nominal.leg_radius;
    normals.configurations.resize(frames.size());
    std::vector<DatasetPoseReport> reports(frames.size());
    for (size_t k = 0; k < frames.size(); ++k) {
      std::array<LegPrediction, kHexapodLegs> predictions =
          vision::hexapod::PredictLegs(nominal, frames[k].X_BP, X_CB);
      if (have_points) {
        for (int j = 0; j < kHexapodLegs; ++j) {
          if (p_C_A[j].allFinite()) predictions[j].p_C_A = p_C_A[j];
        }
      }
      vision::ImageView8 view;
      view.data = frames[k].pixels.data();
      view.width = camera.width();
      view.height = camera.height();
      view.stride = static_cast<size_t>(camera.width());
      const std::array<LegObservation, kHexapodLegs>& obs =
          vision::hexapod::ObserveLegs(view, camera, predictions, edges, workspace.get());
      DatasetPoseReport& report = reports[k];
      report.index = dataset.poses[k].index;
      report.fk_converged = frames[k].fk_converged;
      for (int j = 0; j < kHexapodLegs; ++j) {
        if (obs[j].visible) {
          normals.configurations[k][j] = LegLimbs{obs[j].limbs[0].n_C, obs[j].limbs[1].n_C};
          ++report.legs_seen;
        } else {
          report.not_seen += (report.not_seen.empty() ? "" : "; ") + obs[j].reason;
        }
      }
    }
    HexapodCalibrationResult result = CalibrateHexapod(normals, nominal, options.calibration);
    if (have_points) {
      double change = 0.0;
      for (int j = 0; j < kHexapodLegs; ++j) {
        if (result.p_C_A[j].allFinite() && p_C_A[j].allFinite()) {
          change = std::max(change, (result.p_C_A[j] - p_C_A[j]).norm());
        }
      }
      out.last_pass_change = change;
    }
    out.result = std::move(result);
    out.data = std::move(normals);
    out.poses = std::move(reports);
    out.passes_run = pass + 1;
    // The next pass searches around this one's estimate, when there is one to trust.
    if (!out.result.rigid_fit) break;
    X_CB = out.result.X_CB;
    p_C_A = out.result.p_C_A;
    have_points = true;
  }
  return out;
}

}  // namespace kinevis::calibration
