#include "control/hexapod/image_leg_features.h"

#include <spdlog/spdlog.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <sstream>
#include <stdexcept>

#include "hal/common/error.h"

namespace kinevis::control {
namespace {

using vision::hexapod::LegObservation;
using vision::hexapod::LegPrediction;

bool AllFinite(const LegPoints& p) {
  for (const Eigen::Vector3d& v : p) {
    if (!v.allFinite()) return false;
  }
  return true;
}

}  // namespace

std::string ImageLegFeatureOptions::Validate() const {
  std::string message = edges.Validate();
  if (p_C_A && !AllFinite(*p_C_A)) {
    message += std::string(message.empty() ? "" : "; ") + "p_C_A: not finite";
  }
  return message;
}

ImageLegFeatureSource::ImageLegFeatureSource(
    hal::Camera* camera, const vision::CameraModel* camera_model, robots::HexapodModel model,
    const Eigen::Isometry3d& X_CB, LegLengthProvider leg_lengths, ImageLegFeatureOptions options)
    : camera_(camera),
      camera_model_(camera_model),
      model_(std::move(model)),
      X_CB_(X_CB),
      leg_lengths_(std::move(leg_lengths)),
      options_(std::move(options)),
      X_BP_(robots::HexapodModel::NominalPose()),
      workspace_(std::make_unique<vision::hexapod::LegEdgeWorkspace>()) {
  std::string message;
  const auto add = [&](const std::string& text) {
    message += (message.empty() ? "" : "; ") + text;
  };
  if (camera_ == nullptr) add("camera: null");
  if (camera_model_ == nullptr) {
    add("camera model: null");
  } else if (!camera_model_->IsCentral()) {
    add(std::string("camera model ") + std::string(camera_model_->Name()) +
        ": not central (the limb planes need one viewpoint)");
  }
  if (!leg_lengths_) add("leg lengths: empty provider");
  if (const std::string m = model_.Validate(); !m.empty()) add("model: " + m);
  if (!X_CB_.matrix().allFinite()) add("X_CB: not finite");
  if (const std::string m = options_.Validate(); !m.empty()) add("options: " + m);
  if (!message.empty()) throw std::invalid_argument("ImageLegFeatureSource: " + message);
}

ImageLegFeatureSource::~ImageLegFeatureSource() = default;

const std::array<LegObservation, kHexapodLegs>& ImageLegFeatureSource::last_observations() const {
  return workspace_->observations;
}

bool ImageLegFeatureSource::Poll(hal::Duration now, LegFeatureFrame* frame) {
  if (period_ == hal::Duration(0)) {
    const double fps = camera_->format().fps;
    period_ = std::chrono::duration_cast<hal::Duration>(
        std::chrono::duration<double>(fps > 0 ? 1.0 / fps : 0.01));
  }
  // Not due yet: the next capture is a period after the last one (a little early is fine: the
  // grab below then simply finds nothing).
  if (have_frame_ && now < last_capture_ + period_ - period_ / 20) return false;
  const std::error_code ec = camera_->Grab(&image_, std::chrono::milliseconds(0));
  if (ec == hal::Errc::kTimeout) return false;
  if (ec) {
    ++counters_.camera_errors;
    last_error_ = "camera " + camera_->name() + ": " + ec.message();
    spdlog::warn("leg features: {}", last_error_);
    return false;
  }
  have_frame_ = true;
  last_capture_ = image_.timestamp;

  // The grey view of the frame.
  if (image_.width != camera_model_->width() || image_.height != camera_model_->height()) {
    ++counters_.format_errors;
    last_error_ = "camera " + camera_->name() + ": frame " + std::to_string(image_.width) + "x" +
                  std::to_string(image_.height) + " but the camera model is " +
                  std::to_string(camera_model_->width()) + "x" +
                  std::to_string(camera_model_->height());
    spdlog::warn("leg features: {}", last_error_);
    return false;
  }
  vision::render::ImageView8 view;
  view.width = image_.width;
  view.height = image_.height;
  if (image_.format == hal::PixelFormat::kMono8) {
    view.data = image_.data.data();
    view.stride = image_.stride;
  } else {
    grey_.resize(static_cast<size_t>(image_.width) * image_.height);
    for (int y = 0; y < image_.height; ++y) {
      const uint8_t* in = image_.row(y);
      uint8_t* out = grey_.data() + static_cast<size_t>(y) * image_.width;
      for (int x = 0; x < image_.width; ++x) {
        switch (image_.format) {
          case hal::PixelFormat::kBgr8:  // ITU-R BT.601 luma, in fixed point
            out[x] = static_cast<uint8_t>(
                (29 * in[3 * x] + 150 * in[3 * x + 1] + 77 * in[3 * x + 2] + 128) >> 8);
            break;
          case hal::PixelFormat::kRgb8:
            out[x] = static_cast<uint8_t>(
                (77 * in[3 * x] + 150 * in[3 * x + 1] + 29 * in[3 * x + 2] + 128) >> 8);
            break;
          case hal::PixelFormat::kMono16: {
            uint16_t v;
            std::memcpy(&v, in + 2 * x, 2);
            out[x] = static_cast<uint8_t>(v >> 8);
            break;
          }
          case hal::PixelFormat::kMono8:
            out[x] = in[x];
            break;
        }
      }
    }
    view.data = grey_.data();
    view.stride = static_cast<size_t>(image_.width);
  }

  // Predictions: nominal FK of the measured leg lengths, warm-started from the last pose.
  const Vector6d q = leg_lengths_();
  const robots::ForwardKinematicsSummary fk =
      robots::ForwardKinematics(model_, q, X_BP_, robots::ForwardKinematicsOptions{}, &fk_data_);
  if (fk.converged()) {
    X_BP_ = fk.X_BP;
  } else {
    ++counters_.fk_failures;
  }
  std::array<LegPrediction, kHexapodLegs> predictions =
      vision::hexapod::PredictLegs(model_, X_BP_, X_CB_);
  if (options_.p_C_A) {
    for (int j = 0; j < kHexapodLegs; ++j) predictions[j].p_C_A = (*options_.p_C_A)[j];
  }

  const auto& observations = vision::hexapod::ObserveLegs(view, *camera_model_, predictions,
                                                          options_.edges, workspace_.get());
  ++counters_.frames;
  for (int j = 0; j < kHexapodLegs; ++j) {
    frame->visible[j] = observations[j].visible;
    if (observations[j].visible) {
      frame->u_C[j] = observations[j].u_C;
    } else {
      ++counters_.legs_not_visible;
    }
  }
  frame->timestamp = image_.timestamp;
  frame->sequence = ++sequence_;
  (void)now;
  return true;
}

}  // namespace kinevis::control
