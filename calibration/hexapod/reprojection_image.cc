#include "calibration/hexapod/reprojection_image.h"

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <string>

namespace kinevis::calibration {
namespace {

const cv::Scalar kEstimated(0, 255, 255);  // yellow (BGR), as the seed's fig. 6
const cv::Scalar kCad(255, 255, 0);        // cyan
constexpr int kCircleRadiusPx = 8;
constexpr int kCrossHalfPx = 7;

bool ToPixel(const vision::CameraModel& camera, const Eigen::Vector3d& p_C, cv::Point* pixel) {
  Eigen::Vector2d uv;
  if (!p_C.allFinite() || camera.Project(p_C, &uv) != vision::ProjectionStatus::kOk) return false;
  if (!uv.allFinite() || std::abs(uv.x()) > 1e6 || std::abs(uv.y()) > 1e6) return false;
  *pixel = cv::Point(static_cast<int>(std::lround(uv.x())), static_cast<int>(std::lround(uv.y())));
  return true;
}

}  // namespace

void WriteReprojectionImage(const std::string& path, const vision::ImageView8& image,
                            const vision::CameraModel& camera,
                            const HexapodCalibrationResult& result,
                            const robots::HexapodModel& cad) {
  if (image.data == nullptr || image.width <= 0 || image.height <= 0 ||
      image.stride < static_cast<size_t>(image.width)) {
    throw std::invalid_argument("WriteReprojectionImage: empty image or stride < width");
  }
  if (image.width != camera.width() || image.height != camera.height()) {
    throw std::invalid_argument("WriteReprojectionImage: image is " + std::to_string(image.width) +
                                "x" + std::to_string(image.height) + " but the camera model is " +
                                std::to_string(camera.width()) + "x" +
                                std::to_string(camera.height()));
  }
  const cv::Mat grey(image.height, image.width, CV_8UC1, image.data, image.stride);
  cv::Mat colour;
  cv::cvtColor(grey, colour, cv::COLOR_GRAY2BGR);
  std::string not_shown;
  for (int j = 0; j < robots::kHexapodLegs; ++j) {
    cv::Point p;
    if (result.legs[j].status == LegStatus::kEstimated && ToPixel(camera, result.p_C_A[j], &p)) {
      cv::circle(colour, p, kCircleRadiusPx, kEstimated, 2, cv::LINE_AA);
      cv::putText(colour, std::to_string(j), p + cv::Point(kCircleRadiusPx + 3, -kCircleRadiusPx),
                  cv::FONT_HERSHEY_SIMPLEX, 0.6, kEstimated, 2, cv::LINE_AA);
    } else {
      not_shown += " A" + std::to_string(j);
    }
    if (!result.rigid_fit) continue;
    if (ToPixel(camera, result.X_CB * cad.p_B_A[j], &p)) {
      cv::line(colour, p - cv::Point(kCrossHalfPx, kCrossHalfPx),
               p + cv::Point(kCrossHalfPx, kCrossHalfPx), kCad, 2, cv::LINE_AA);
      cv::line(colour, p + cv::Point(-kCrossHalfPx, kCrossHalfPx),
               p + cv::Point(kCrossHalfPx, -kCrossHalfPx), kCad, 2, cv::LINE_AA);
    } else {
      not_shown += " CAD" + std::to_string(j);
    }
  }
  std::string legend = "o estimated A_j (eq. 14)   x CAD A_j by X_CB (eq. 15)";
  if (!not_shown.empty()) legend += "   not shown:" + not_shown;
  cv::putText(colour, legend, cv::Point(8, 20), cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(0, 0, 0),
              3, cv::LINE_AA);
  cv::putText(colour, legend, cv::Point(8, 20), cv::FONT_HERSHEY_SIMPLEX, 0.5,
              cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
  bool written = false;
  try {
    written = cv::imwrite(path, colour);
  } catch (const cv::Exception&) {
    written = false;
  }
  if (!written) throw std::runtime_error("WriteReprojectionImage: cannot write " + path);
}

}  // namespace kinevis::calibration
