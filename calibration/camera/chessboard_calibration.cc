#include "calibration/camera/chessboard_calibration.h"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <stdexcept>

#include "common/units.h"

namespace kinevis::calibration {
namespace {

constexpr int kCoverageCols = 16;
constexpr int kCoverageRows = 12;
constexpr double kFrontoParallelTiltRad = 15.0 * common::kPi / 180.0;
constexpr double kPoorCoverage = 0.5;
constexpr int kRecommendedMinImages = 3;
constexpr double kMaxRelativeFocalStd = 0.01;   // of the focal length
constexpr double kMaxRelativeCentreStd = 0.02;  // of the image size
constexpr double kLargeRmsPx = 1.0;

std::string Format(const char* format, double a, double b = 0.0, double c = 0.0) {
  char buffer[256];
  std::snprintf(buffer, sizeof buffer, format, a, b, c);
  return buffer;
}

// Which images are usable and where their corners are; the size of the first readable image.
struct Detector {
  explicit Detector(const ChessboardCalibrationOptions& o) : options(o) {}
  const ChessboardCalibrationOptions& options;
  int width = 0, height = 0;
  std::string first_name;

  ImageReport Detect(const cv::Mat& grey, const std::string& name) {
    ImageReport report;
    report.name = name;
    report.width = grey.cols;
    report.height = grey.rows;
    if (width == 0) {
      width = grey.cols;
      height = grey.rows;
      first_name = name;
    } else if (grey.cols != width || grey.rows != height) {
      report.status = ImageStatus::kSizeMismatch;
      report.reason = "image size " + std::to_string(grey.cols) + "x" + std::to_string(grey.rows) +
                      " differs from the first image's " + std::to_string(width) + "x" +
                      std::to_string(height) + " (" + first_name + ")";
      return report;
    }
    const cv::Size pattern(options.board_cols, options.board_rows);
    std::vector<cv::Point2f> corners;
    // Adaptive threshold + normalisation: robust to uneven lighting. No FAST_CHECK: this is an
    // offline batch, robustness matters more than the time spent on images without a board.
    const bool found = cv::findChessboardCorners(
        grey, pattern, corners, cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE);
    if (!found) {
      report.status = ImageStatus::kBoardNotFound;
      report.reason = "board not found (" + std::to_string(options.board_cols) + "x" +
                      std::to_string(options.board_rows) + " inner corners)";
      return report;
    }
    int half = options.subpix_half_window_px;
    if (half == 0) {
      // The search window must stay inside the squares around a corner, or cornerSubPix is
      // pulled towards a neighbouring corner: 40 % of the smallest corner spacing.
      double spacing = 1e9;
      for (int j = 0; j < options.board_rows; ++j) {
        for (int i = 0; i < options.board_cols; ++i) {
          const cv::Point2f& p = corners[j * options.board_cols + i];
          if (i + 1 < options.board_cols) {
            spacing = std::min(spacing, cv::norm(corners[j * options.board_cols + i + 1] - p));
          }
          if (j + 1 < options.board_rows) {
            spacing = std::min(spacing, cv::norm(corners[(j + 1) * options.board_cols + i] - p));
          }
        }
      }
      half = std::clamp(static_cast<int>(0.4 * spacing), 2, 11);
    }
    cv::cornerSubPix(grey, corners, cv::Size(half, half), cv::Size(-1, -1),
                     cv::TermCriteria(cv::TermCriteria::EPS | cv::TermCriteria::COUNT, 100, 1e-4));
    report.status = ImageStatus::kUsed;
    for (const cv::Point2f& p : corners) report.corners_px.emplace_back(p.x, p.y);
    return report;
  }
};

double CoverageOf(const std::vector<ImageReport>& images, int width, int height) {
  std::vector<std::vector<cv::Point2f>> hulls;
  for (const ImageReport& r : images) {
    if (r.status != ImageStatus::kUsed) continue;
    std::vector<cv::Point2f> points, hull;
    for (const Eigen::Vector2d& p : r.corners_px) points.emplace_back(p.x(), p.y());
    cv::convexHull(points, hull);
    hulls.push_back(hull);
  }
  int covered = 0;
  for (int j = 0; j < kCoverageRows; ++j) {
    for (int i = 0; i < kCoverageCols; ++i) {
      const cv::Point2f centre((i + 0.5f) * width / kCoverageCols - 0.5f,
                               (j + 0.5f) * height / kCoverageRows - 0.5f);
      for (const auto& hull : hulls) {
        if (cv::pointPolygonTest(hull, centre, false) >= 0) {
          ++covered;
          break;
        }
      }
    }
  }
  return static_cast<double>(covered) / (kCoverageCols * kCoverageRows);
}

// The estimator contract's report: the intrinsics (held ones per the options' flags) with σ and
// covariance from one AnalyzeIdentifiability of the reprojection Jacobian J (intrinsics, then
// each view's rvec/tvec), the board poses analysed with them but not listed. total_sq: Σ |r|².
EstimationReport ChessboardEstimation(const ChessboardCalibrationResult& result,
                                      const ChessboardCalibrationOptions& options,
                                      const Eigen::MatrixXd& J, double total_sq) {
  EstimationReport e;
  e.estimator = "pinhole + Brown intrinsics (chessboards)";
  e.message = result.calibrated ? "cv::calibrateCamera" : result.message;
  if (!result.calibrated) {
    e.status = result.message.rfind("cv::calibrateCamera failed", 0) == 0
                   ? EstimationStatus::kFailed
                   : EstimationStatus::kInsufficientData;
    return e;
  }
  const char* distortion_names[] = {"k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"};
  const vision::PinholeBrownParameters& p = result.parameters;
  const int n_intrinsics = 4 + (options.rational_model ? 8 : 5);
  std::vector<std::string> names = {"fx", "fy", "cx", "cy"};
  std::vector<double> values = {p.fx, p.fy, p.cx, p.cy};
  for (int i = 0; i < n_intrinsics - 4; ++i) {
    names.push_back(distortion_names[i]);
    values.push_back(p.distortion[static_cast<size_t>(i)]);
  }
  std::vector<bool> held(static_cast<size_t>(n_intrinsics), false);
  if (options.fix_aspect_ratio) held[1] = true;  // fy = (fy/fx) fx
  if (options.fix_principal_point) held[2] = held[3] = true;
  if (options.zero_tangential) held[6] = held[7] = true;
  if (options.fix_k3) held[8] = true;
  // The free columns: intrinsics not held (fx carries fy's column when the ratio is fixed), then
  // every pose column.
  std::vector<int> free;
  std::vector<std::string> free_names;
  Eigen::MatrixXd Jf(J.rows(), J.cols());
  for (int c = 0; c < J.cols(); ++c) {
    if (c < n_intrinsics && held[static_cast<size_t>(c)]) continue;
    Eigen::VectorXd column = J.col(c);
    if (c == 0 && options.fix_aspect_ratio) column += (p.fy / p.fx) * J.col(1);
    Jf.col(static_cast<Eigen::Index>(free.size())) = column;
    free.push_back(c);
    free_names.push_back(c < n_intrinsics ? names[static_cast<size_t>(c)]
                                          : "view" + std::to_string((c - n_intrinsics) / 6) +
                                                ".pose" + std::to_string((c - n_intrinsics) % 6));
  }
  Jf.conservativeResize(Eigen::NoChange, static_cast<Eigen::Index>(free.size()));
  const Identifiability all = AnalyzeIdentifiability(Jf, free_names);
  const double dof = static_cast<double>(J.rows()) - all.rank;
  const double sigma2 = dof > 0 ? total_sq / dof : 0.0;
  e.covariance = Eigen::MatrixXd::Zero(n_intrinsics, n_intrinsics);
  bool every = true;
  for (int i = 0; i < n_intrinsics; ++i) {
    ParameterEstimate q;
    q.name = names[static_cast<size_t>(i)];
    q.unit = i < 4 ? "px" : "1";
    q.value = values[static_cast<size_t>(i)];
    q.initial = std::numeric_limits<double>::quiet_NaN();  // OpenCV's own closed-form start
    q.estimated = !held[static_cast<size_t>(i)];
    const auto at = std::find(free.begin(), free.end(), i);
    const Eigen::Index a = at - free.begin();
    if (q.estimated) {
      q.identified = all.identified[static_cast<size_t>(a)];
      q.sigma = q.identified ? std::sqrt(std::max(0.0, sigma2 * all.normal_inverse(a, a)))
                             : std::numeric_limits<double>::infinity();
      every = every && q.identified;
      for (int j = 0; j < n_intrinsics; ++j) {
        const auto bt = std::find(free.begin(), free.end(), j);
        if (bt != free.end())
          e.covariance(i, j) = sigma2 * all.normal_inverse(a, bt - free.begin());
      }
      if (!q.identified) e.covariance(i, i) = std::numeric_limits<double>::infinity();
    }
    e.parameters.push_back(q);
  }
  e.identifiability = all;
  e.status = every ? EstimationStatus::kConverged : EstimationStatus::kUnidentified;
  e.variance_factor = sigma2;  // px²: the corner noise the residuals show (σ assumed 1 px)
  std::vector<double> residuals;
  for (const ImageReport& r : result.images) {
    if (r.status != ImageStatus::kUsed) continue;
    for (size_t i = 0; i < r.corners_px.size() && i < r.reprojected_px.size(); ++i) {
      const Eigen::Vector2d d = r.reprojected_px[i] - r.corners_px[i];
      residuals.push_back(d.x());
      residuals.push_back(d.y());
    }
  }
  e.residuals.push_back(SummarizeResiduals("corner reprojection (u, v)", "px", residuals));
  e.warnings = result.warnings;
  return e;
}

ChessboardCalibrationResult Calibrate(std::vector<ImageReport> reports, int width, int height,
                                      const ChessboardCalibrationOptions& options) {
  ChessboardCalibrationResult result;
  result.images = std::move(reports);
  std::vector<ImageReport*> used;
  for (ImageReport& r : result.images) {
    if (r.status == ImageStatus::kUsed) used.push_back(&r);
  }
  result.used_images = static_cast<int>(used.size());
  if (result.used_images < options.min_images) {
    result.message = "only " + std::to_string(result.used_images) + " of " +
                     std::to_string(result.images.size()) + " images usable (minimum " +
                     std::to_string(options.min_images) + ")";
    const std::string refused = result.RefusedSummary();
    if (!refused.empty()) result.message += "; refused: " + refused;
    result.estimation = ChessboardEstimation(result, options, {}, 0.0);
    return result;
  }

  std::vector<cv::Point3f> board;
  for (int j = 0; j < options.board_rows; ++j) {
    for (int i = 0; i < options.board_cols; ++i) {
      board.emplace_back(static_cast<float>(i * options.square_m),
                         static_cast<float>(j * options.square_m), 0.0f);
    }
  }
  std::vector<std::vector<cv::Point3f>> object_points(used.size(), board);
  std::vector<std::vector<cv::Point2f>> image_points;
  for (const ImageReport* r : used) {
    std::vector<cv::Point2f> points;
    for (const Eigen::Vector2d& p : r->corners_px) points.emplace_back(p.x(), p.y());
    image_points.push_back(points);
  }

  int flags = 0;
  if (options.fix_k3) flags |= cv::CALIB_FIX_K3;
  if (options.rational_model) flags |= cv::CALIB_RATIONAL_MODEL;
  if (options.zero_tangential) flags |= cv::CALIB_ZERO_TANGENT_DIST;
  if (options.fix_principal_point) flags |= cv::CALIB_FIX_PRINCIPAL_POINT;
  if (options.fix_aspect_ratio) flags |= cv::CALIB_FIX_ASPECT_RATIO;
  // Without CALIB_USE_INTRINSIC_GUESS OpenCV initialises K itself (Zhang's closed form from the
  // homographies, principal point at the image centre); with FIX_ASPECT_RATIO it keeps the
  // input's fx/fy, hence the identity here (fx = fy).
  cv::Mat K = cv::Mat::eye(3, 3, CV_64F);
  cv::Mat D = cv::Mat::zeros(1, options.rational_model ? 8 : 5, CV_64F);
  std::vector<cv::Mat> rvecs, tvecs;
  cv::Mat std_intrinsics, std_extrinsics, per_view;
  try {
    result.rms_px = cv::calibrateCamera(
        object_points, image_points, cv::Size(width, height), K, D, rvecs, tvecs, std_intrinsics,
        std_extrinsics, per_view, flags,
        cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 100, DBL_EPSILON));
  } catch (const cv::Exception& e) {
    result.message = std::string("cv::calibrateCamera failed: ") + e.err;
    result.estimation = ChessboardEstimation(result, options, {}, 0.0);
    return result;
  }
  result.calibrated = true;

  vision::PinholeBrownParameters& p = result.parameters;
  p.width = width;
  p.height = height;
  p.fx = K.at<double>(0, 0);
  p.fy = K.at<double>(1, 1);
  p.cx = K.at<double>(0, 2);
  p.cy = K.at<double>(1, 2);
  for (int i = 0; i < static_cast<int>(D.total()) && i < 8; ++i) p.distortion[i] = D.at<double>(i);
  // stdDeviationsIntrinsics: fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6 s1..s4 τx τy.
  std_intrinsics = std_intrinsics.reshape(1, 1);
  auto sd = [&](int i) {
    return i < static_cast<int>(std_intrinsics.total()) ? std_intrinsics.at<double>(i) : 0.0;
  };
  result.stddev.fx = sd(0);
  result.stddev.fy = sd(1);
  result.stddev.cx = sd(2);
  result.stddev.cy = sd(3);
  for (int i = 0; i < 8; ++i) result.stddev.distortion[i] = sd(4 + i);

  // For the estimator contract: the Jacobian of every corner's reprojection with respect to the
  // intrinsics (fx fy cx cy, distortion) and each view's pose (OpenCV's projectPoints).
  const int n_dist = static_cast<int>(D.total());
  const int n_intrinsics = 4 + n_dist;
  const int n_columns = n_intrinsics + 6 * static_cast<int>(used.size());
  const int corners = static_cast<int>(board.size());
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(2 * corners * static_cast<int>(used.size()), n_columns);
  double total_sq = 0.0;
  for (size_t k = 0; k < used.size(); ++k) {
    ImageReport& r = *used[k];
    cv::Mat R;
    cv::Rodrigues(rvecs[k], R);
    Eigen::Matrix3d R_CT;
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) R_CT(a, b) = R.at<double>(a, b);
    }
    r.X_CT.linear() = R_CT;
    r.X_CT.translation() =
        Eigen::Vector3d(tvecs[k].at<double>(0), tvecs[k].at<double>(1), tvecs[k].at<double>(2));
    r.tilt_rad = std::acos(std::min(1.0, std::abs(R_CT(2, 2))));
    result.max_tilt_rad = std::max(result.max_tilt_rad, r.tilt_rad);
    std::vector<cv::Point2d> projected;
    std::vector<cv::Point3d> board_d(board.begin(), board.end());
    cv::Mat jacobian;  // 2N × (rvec 3, tvec 3, f 2, c 2, distortion)
    cv::projectPoints(board_d, rvecs[k], tvecs[k], K, D, projected, jacobian);
    for (int row = 0; row < 2 * corners; ++row) {
      const int global = 2 * corners * static_cast<int>(k) + row;
      for (int c = 0; c < 4 + n_dist; ++c) J(global, c) = jacobian.at<double>(row, 6 + c);
      for (int c = 0; c < 6; ++c) {
        J(global, n_intrinsics + 6 * static_cast<int>(k) + c) = jacobian.at<double>(row, c);
      }
    }
    double sum_sq = 0.0;
    r.max_px = 0.0;
    r.reprojected_px.clear();
    for (size_t i = 0; i < projected.size(); ++i) {
      r.reprojected_px.emplace_back(projected[i].x, projected[i].y);
      const double e = (r.reprojected_px.back() - r.corners_px[i]).norm();
      sum_sq += e * e;
      r.max_px = std::max(r.max_px, e);
    }
    r.rms_px = std::sqrt(sum_sq / projected.size());
    total_sq += sum_sq;
  }
  result.coverage = CoverageOf(result.images, width, height);

  std::vector<std::string>& w = result.warnings;
  if (result.used_images < kRecommendedMinImages) {
    w.push_back("only " + std::to_string(result.used_images) +
                " usable images: at least 3 (better 15-25) are needed to determine all "
                "intrinsics");
  }
  if (result.max_tilt_rad < kFrontoParallelTiltRad) {
    w.push_back(
        Format("all boards nearly fronto-parallel (largest tilt %.1f deg < 15 deg): the "
               "focal length is poorly determined; tilt the board 20-45 deg",
               result.max_tilt_rad * 180.0 / common::kPi));
  }
  if (result.coverage < kPoorCoverage) {
    w.push_back(
        Format("the boards cover only %.0f %% of the image: distortion near the edges is "
               "extrapolated; show the board near the corners and edges too",
               100.0 * result.coverage));
  }
  if (result.stddev.fx > kMaxRelativeFocalStd * p.fx ||
      result.stddev.fy > kMaxRelativeFocalStd * p.fy) {
    w.push_back(Format("focal length poorly determined: std fx %.2f px, fy %.2f px (> 1 %%)",
                       result.stddev.fx, result.stddev.fy));
  }
  if (result.stddev.cx > kMaxRelativeCentreStd * width ||
      result.stddev.cy > kMaxRelativeCentreStd * height) {
    w.push_back(Format("principal point poorly determined: std cx %.2f px, cy %.2f px",
                       result.stddev.cx, result.stddev.cy));
  }
  if (result.rms_px > kLargeRmsPx) {
    w.push_back(
        Format("RMS reprojection error %.3f px > 1 px: blurred images, a board that is "
               "not flat, wrong corners, or a lens that needs the rational model",
               result.rms_px));
  }
  result.estimation = ChessboardEstimation(result, options, J, total_sq);
  return result;
}

void ThrowIfInvalid(const ChessboardCalibrationOptions& options) {
  const std::string problems = options.Validate();
  if (!problems.empty()) throw std::invalid_argument(problems);
}

}  // namespace

std::string ChessboardCalibrationOptions::Validate() const {
  std::ostringstream e;
  if (board_cols < 2) e << "board_cols = " << board_cols << " must be >= 2; ";
  if (board_rows < 2) e << "board_rows = " << board_rows << " must be >= 2; ";
  if (!std::isfinite(square_m) || square_m <= 0) {
    e << "square_m = " << square_m << " must be finite and > 0; ";
  }
  if (min_images < 1) e << "min_images = " << min_images << " must be >= 1; ";
  if (subpix_half_window_px < 0) {
    e << "subpix_half_window_px = " << subpix_half_window_px << " must be >= 0 (0: automatic); ";
  }
  std::string message = e.str();
  if (!message.empty())
    message = "chessboard calibration options: " + message.substr(0, message.size() - 2);
  return message;
}

const char* ToString(ImageStatus status) {
  switch (status) {
    case ImageStatus::kUsed:
      return "used";
    case ImageStatus::kBoardNotFound:
      return "board not found";
    case ImageStatus::kSizeMismatch:
      return "size differs";
    case ImageStatus::kUnreadable:
      return "unreadable";
  }
  return "unknown";
}

std::string ChessboardCalibrationResult::RefusedSummary() const {
  std::string out;
  for (const ImageReport& r : images) {
    if (r.status == ImageStatus::kUsed) continue;
    out += (out.empty() ? "" : ", ") + r.name + " (" + r.reason + ")";
  }
  return out;
}

CalibrationImage LoadCalibrationImage(const std::string& path) {
  cv::Mat grey;
  try {
    grey = cv::imread(path, cv::IMREAD_GRAYSCALE);
  } catch (const cv::Exception& e) {
    throw std::runtime_error("image \"" + path + "\": cannot read: " + e.err);
  }
  if (grey.empty()) {
    throw std::runtime_error("image \"" + path + "\": cannot read (missing or not an image)");
  }
  CalibrationImage image;
  image.name = path;
  image.width = grey.cols;
  image.height = grey.rows;
  image.grey.resize(grey.total());
  for (int v = 0; v < grey.rows; ++v) {
    std::copy(grey.ptr<std::uint8_t>(v), grey.ptr<std::uint8_t>(v) + grey.cols,
              image.grey.begin() + static_cast<size_t>(v) * grey.cols);
  }
  return image;
}

ChessboardCalibrationResult CalibrateChessboard(const std::vector<CalibrationImage>& images,
                                                const ChessboardCalibrationOptions& options) {
  ThrowIfInvalid(options);
  Detector detector(options);
  std::vector<ImageReport> reports;
  for (const CalibrationImage& image : images) {
    if (image.width <= 0 || image.height <= 0 ||
        image.grey.size() != static_cast<size_t>(image.width) * image.height) {
      ImageReport r;
      r.name = image.name;
      r.status = ImageStatus::kUnreadable;
      r.reason = "pixel buffer does not match its size";
      reports.push_back(r);
      continue;
    }
    const cv::Mat grey(image.height, image.width, CV_8U,
                       const_cast<std::uint8_t*>(image.grey.data()));
    reports.push_back(detector.Detect(grey, image.name));
  }
  return Calibrate(std::move(reports), detector.width, detector.height, options);
}

ChessboardCalibrationResult CalibrateChessboardFiles(const std::vector<std::string>& paths,
                                                     const ChessboardCalibrationOptions& options) {
  ThrowIfInvalid(options);
  Detector detector(options);
  std::vector<ImageReport> reports;
  for (const std::string& path : paths) {
    cv::Mat grey;
    try {
      grey = cv::imread(path, cv::IMREAD_GRAYSCALE);
    } catch (const cv::Exception&) {
      grey.release();
    }
    if (grey.empty()) {
      ImageReport r;
      r.name = path;
      r.status = ImageStatus::kUnreadable;
      r.reason = "cannot be read as an image";
      reports.push_back(r);
      continue;
    }
    reports.push_back(detector.Detect(grey, path));
  }
  return Calibrate(std::move(reports), detector.width, detector.height, options);
}

void WriteOverlayPng(const CalibrationImage& image, const ImageReport& report,
                     const std::string& png_path) {
  if (report.status != ImageStatus::kUsed || report.corners_px.empty() ||
      report.reprojected_px.size() != report.corners_px.size() || image.width != report.width ||
      image.height != report.height ||
      image.grey.size() != static_cast<size_t>(image.width) * image.height) {
    throw std::invalid_argument("overlay for \"" + report.name +
                                "\": not a calibrated image of this size");
  }
  const cv::Mat grey(image.height, image.width, CV_8U,
                     const_cast<std::uint8_t*>(image.grey.data()));
  cv::Mat canvas;
  cv::cvtColor(grey, canvas, cv::COLOR_GRAY2BGR);
  const int scale = std::max(1, std::min(image.width, image.height) / 480);
  const int radius = 4 * scale;
  const cv::Scalar green(0, 200, 0), red(0, 0, 255), blue(255, 64, 0);
  auto pt = [](const Eigen::Vector2d& p) {
    // Sub-pixel drawing: 4 fractional bits.
    return cv::Point(static_cast<int>(std::lround(p.x() * 16)),
                     static_cast<int>(std::lround(p.y() * 16)));
  };
  for (size_t i = 0; i + 1 < report.corners_px.size(); ++i) {
    cv::line(canvas, pt(report.corners_px[i]), pt(report.corners_px[i + 1]), cv::Scalar(0, 140, 0),
             1, cv::LINE_AA, 4);
  }
  for (const Eigen::Vector2d& p : report.corners_px) {
    cv::circle(canvas, pt(p), radius * 16, green, scale, cv::LINE_AA, 4);
  }
  cv::circle(canvas, pt(report.corners_px.front()), radius * 16 * 2, blue, 2 * scale, cv::LINE_AA,
             4);
  for (const Eigen::Vector2d& p : report.reprojected_px) {
    const cv::Point c(static_cast<int>(std::lround(p.x())), static_cast<int>(std::lround(p.y())));
    cv::drawMarker(canvas, c, red, cv::MARKER_CROSS, 2 * radius, scale, cv::LINE_AA);
  }
  const std::string text = Format("rms %.3f px  max %.3f px", report.rms_px, report.max_px) +
                           "  (green o detected, red + reprojected)";
  const cv::Point origin(8 * scale, 20 * scale);
  cv::putText(canvas, text, origin, cv::FONT_HERSHEY_SIMPLEX, 0.45 * scale, cv::Scalar(0, 0, 0),
              3 * scale, cv::LINE_AA);
  cv::putText(canvas, text, origin, cv::FONT_HERSHEY_SIMPLEX, 0.45 * scale,
              cv::Scalar(255, 255, 255), scale, cv::LINE_AA);
  bool ok = false;
  try {
    ok = cv::imwrite(png_path, canvas);
  } catch (const cv::Exception& e) {
    throw std::runtime_error("overlay \"" + png_path + "\": cannot write: " + e.err);
  }
  if (!ok) throw std::runtime_error("overlay \"" + png_path + "\": cannot write");
}

}  // namespace kinevis::calibration
