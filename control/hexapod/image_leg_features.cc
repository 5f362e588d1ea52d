#include "control/hexapod/image_leg_features.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <sstream>
#include <stdexcept>
#include <thread>

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
  if (!(max_prediction_deviation >= 0) || !std::isfinite(max_prediction_deviation)) {
    message += std::string(message.empty() ? "" : "; ") +
               "max_prediction_deviation: must be >= 0, got " +
               std::to_string(max_prediction_deviation);
  }
  if (grab_timeout_ms <= 0) {
    message += std::string(message.empty() ? "" : "; ") + "grab_timeout_ms: must be > 0, got " +
               std::to_string(grab_timeout_ms);
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
      workspace_(std::make_unique<vision::hexapod::LegEdgeWorkspace>()),
      X_BP_(robots::HexapodModel::NominalPose()) {
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
  if (options_.asynchronous) {
    worker_ = std::make_unique<LatestFrameWorker<LegFeatureFrame>>(
        [this](LegFeatureFrame* frame, const std::atomic<bool>& stopping) {
          return Produce(frame, stopping);
        });
  }
}

ImageLegFeatureSource::~ImageLegFeatureSource() {
  if (worker_) {
    {
      // Under the mutex: the worker may be about to wait for the first q.
      std::lock_guard<std::mutex> lock(mutex_);
      worker_->RequestStop();
    }
    q_ready_.notify_all();
    worker_->Stop();
  }
}

std::array<LegObservation, kHexapodLegs> ImageLegFeatureSource::last_observations() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return observations_;
}
Eigen::Isometry3d ImageLegFeatureSource::last_predicted_pose() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return X_BP_;
}
std::string ImageLegFeatureSource::last_error() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return last_error_;
}
ImageLegFeatureCounters ImageLegFeatureSource::counters() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return counters_;
}

void ImageLegFeatureSource::RecordError(const std::string& text,
                                        uint64_t ImageLegFeatureCounters::*counter) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ++(counters_.*counter);
    last_error_ = text;
  }
  spdlog::warn("leg features: {}", text);
}

bool ImageLegFeatureSource::Produce(LegFeatureFrame* frame, const std::atomic<bool>& stopping) {
  Vector6d q;
  {
    // The first frame waits for the first q (the predictions need it).
    std::unique_lock<std::mutex> lock(mutex_);
    q_ready_.wait(lock, [&] { return have_q_ || stopping; });
    if (stopping) return false;
    q = q_latest_;
  }
  if (GrabAndProcess(std::chrono::milliseconds(options_.grab_timeout_ms), q, frame)) return true;
  // A camera in fault answers at once: do not spin on it.
  if (camera_->lifecycle() != common::DeviceLifecycle::kActive) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return false;
}

bool ImageLegFeatureSource::Poll(common::Duration now, LegFeatureFrame* frame) {
  const Vector6d q = leg_lengths_();
  if (worker_) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      q_latest_ = q;
      if (!have_q_) {
        have_q_ = true;
        q_ready_.notify_all();
      }
    }
    return worker_->Take(frame);
  }
  if (period_ == common::Duration(0)) {
    const double fps = camera_->format().fps;
    period_ = std::chrono::duration_cast<common::Duration>(
        std::chrono::duration<double>(fps > 0 ? 1.0 / fps : 0.01));
  }
  // Not due yet: the next capture is a period after the last one (a little early is fine: the
  // grab then simply finds nothing).
  if (have_frame_ && now < last_capture_ + period_ - period_ / 20) return false;
  return GrabAndProcess(std::chrono::milliseconds(0), q, frame);
}

bool ImageLegFeatureSource::GrabAndProcess(std::chrono::milliseconds timeout, const Vector6d& q,
                                           LegFeatureFrame* frame) {
  const std::error_code ec = camera_->Grab(&image_, timeout);
  if (ec == hal::Errc::kTimeout) {
    if (options_.asynchronous) {
      RecordError(
          "camera " + camera_->name() + ": no frame for " + std::to_string(timeout.count()) + " ms",
          &ImageLegFeatureCounters::camera_errors);
    }
    return false;
  }
  if (ec) {
    RecordError("camera " + camera_->name() + ": " + ec.message(),
                &ImageLegFeatureCounters::camera_errors);
    return false;
  }
  have_frame_ = true;
  last_capture_ = image_.timestamp;

  // The grey view of the frame.
  if (image_.width != camera_model_->width() || image_.height != camera_model_->height()) {
    RecordError("camera " + camera_->name() + ": frame " + std::to_string(image_.width) + "x" +
                    std::to_string(image_.height) + " but the camera model is " +
                    std::to_string(camera_model_->width()) + "x" +
                    std::to_string(camera_model_->height()),
                &ImageLegFeatureCounters::format_errors);
    return false;
  }
  vision::ImageView8 view;
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
  Eigen::Isometry3d X_BP;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    X_BP = X_BP_;
  }
  const robots::ForwardKinematicsSummary fk =
      robots::ForwardKinematics(model_, q, X_BP, robots::ForwardKinematicsOptions{}, &fk_data_);
  if (fk.converged()) X_BP = fk.X_BP;
  std::array<LegPrediction, kHexapodLegs> predictions =
      vision::hexapod::PredictLegs(model_, X_BP, X_CB_);
  if (options_.p_C_A) {
    for (int j = 0; j < kHexapodLegs; ++j) predictions[j].p_C_A = (*options_.p_C_A)[j];
  }

  const auto& observations = vision::hexapod::ObserveLegs(view, *camera_model_, predictions,
                                                          options_.edges, workspace_.get());
  int not_visible = 0, rejected = 0;
  std::array<LegObservation, kHexapodLegs> reported = observations;
  for (int j = 0; j < kHexapodLegs; ++j) {
    frame->visible[j] = observations[j].visible;
    if (observations[j].visible && options_.max_prediction_deviation > 0) {
      const Eigen::Vector3d u_pred = (predictions[j].p_C_B - predictions[j].p_C_A).normalized();
      const double deviation = std::acos(std::clamp(u_pred.dot(observations[j].u_C), -1.0, 1.0));
      if (deviation > options_.max_prediction_deviation) {
        frame->visible[j] = false;
        ++rejected;
        reported[j].visible = false;
        reported[j].reason = "leg " + std::to_string(j) + ": measured direction " +
                             std::to_string(deviation) + " rad from the predicted one (gate " +
                             std::to_string(options_.max_prediction_deviation) + " rad)";
      }
    }
    if (frame->visible[j]) {
      frame->u_C[j] = observations[j].u_C;
    } else {
      ++not_visible;
    }
  }
  frame->timestamp = image_.timestamp;
  frame->sequence = ++sequence_;
  std::lock_guard<std::mutex> lock(mutex_);
  X_BP_ = X_BP;
  observations_ = reported;
  ++counters_.frames;
  if (!fk.converged()) ++counters_.fk_failures;
  counters_.legs_not_visible += not_visible;
  counters_.legs_rejected += rejected;
  return true;
}

}  // namespace kinevis::control
