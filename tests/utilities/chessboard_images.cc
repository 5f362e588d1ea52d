#include "tests/utilities/chessboard_images.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <random>
#include <stdexcept>
#include <string>

#include "common/units.h"

namespace kinevis::testing {
namespace {

cv::Mat CameraMatrix(const vision::PinholeBrownParameters& c) {
  return (cv::Mat_<double>(3, 3) << c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1);
}

cv::Mat DistortionVector(const vision::PinholeBrownParameters& c) {
  cv::Mat d(1, 8, CV_64F);
  for (int i = 0; i < 8; ++i) d.at<double>(i) = c.distortion[i];
  return d;
}

// cv::projectPoints of points given in T, at pose X_CT.
std::vector<cv::Point2d> Project(const vision::PinholeBrownParameters& camera,
                                 const Eigen::Isometry3d& X_CT,
                                 const std::vector<cv::Point3d>& p_T) {
  cv::Mat R(3, 3, CV_64F);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) R.at<double>(r, c) = X_CT.linear()(r, c);
  }
  cv::Mat rvec;
  cv::Rodrigues(R, rvec);
  const cv::Mat tvec = (cv::Mat_<double>(3, 1) << X_CT.translation().x(), X_CT.translation().y(),
                        X_CT.translation().z());
  std::vector<cv::Point2d> pixels;
  cv::projectPoints(p_T, rvec, tvec, CameraMatrix(camera), DistortionVector(camera), pixels);
  return pixels;
}

enum Shade : std::uint8_t { kBlack, kWhite, kBackground };

struct BoardPoint {
  double x = 0, y = 0;  // in T (m)
  bool valid = false;   // the ray meets the board plane in front of the camera
};

// Which shade the board point (x, y) in T shows, and the index of the region it lies in (so
// that a pixel whose four corners are in one region is uniform).
Shade Classify(double x, double y, const ChessboardTarget& t, int* region) {
  const double s = t.square_m;
  if (x >= -s && x < t.cols * s && y >= -s && y < t.rows * s) {
    const int ix = static_cast<int>(std::floor(x / s)) + 1;
    const int iy = static_cast<int>(std::floor(y / s)) + 1;
    *region = 2 + iy * (t.cols + 1) + ix;
    return (ix + iy) % 2 == 0 ? kBlack : kWhite;
  }
  const double m = t.margin_m;
  if (x >= -s - m && x < t.cols * s + m && y >= -s - m && y < t.rows * s + m) {
    *region = 1;
    return kWhite;
  }
  *region = 0;
  return kBackground;
}

}  // namespace

GreyImage RenderChessboard(const vision::PinholeBrownParameters& camera,
                           const Eigen::Isometry3d& X_CT, const ChessboardTarget& target,
                           const RenderOptions& options) {
  const int W = camera.width, H = camera.height;
  if (W <= 0 || H <= 0 || options.samples_per_axis < 1 || target.square_m <= 0) {
    throw std::invalid_argument("RenderChessboard: bad image size, samples or square size");
  }
  // Pixel corners: (u - 0.5, v - 0.5) for u = 0..W, v = 0..H (pixel centres are integers).
  cv::Mat corners(1, (W + 1) * (H + 1), CV_64FC2);
  for (int v = 0; v <= H; ++v) {
    for (int u = 0; u <= W; ++u) {
      corners.at<cv::Vec2d>(v * (W + 1) + u) = cv::Vec2d(u - 0.5, v - 0.5);
    }
  }
  const cv::Mat K = CameraMatrix(camera), D = DistortionVector(camera);
  cv::Mat normalised;
  cv::undistortPoints(
      corners, normalised, K, D, cv::noArray(), cv::noArray(),
      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 200, 1e-12));
  // Check the inverse with the forward model it inverts.
  std::vector<cv::Point3d> rays(corners.cols);
  for (int i = 0; i < corners.cols; ++i) {
    const cv::Vec2d n = normalised.at<cv::Vec2d>(i);
    rays[i] = cv::Point3d(n[0], n[1], 1.0);
  }
  std::vector<cv::Point2d> reprojected;
  cv::projectPoints(rays, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K, D, reprojected);
  for (int i = 0; i < corners.cols; ++i) {
    const cv::Vec2d c = corners.at<cv::Vec2d>(i);
    if (std::hypot(reprojected[i].x - c[0], reprojected[i].y - c[1]) > 1e-6) {
      throw std::runtime_error("RenderChessboard: undistortion of pixel corner (" +
                               std::to_string(c[0]) + ", " + std::to_string(c[1]) +
                               ") does not re-project; the lens folds over in the image");
    }
  }

  // Ray (x', y', 1) meets the board plane n·p = n·t_CT at λ = n·t / n·d; p_T = R_CTᵀ (λ d − t).
  const Eigen::Matrix3d R_TC = X_CT.linear().transpose();
  const Eigen::Vector3d t = X_CT.translation();
  const Eigen::Vector3d n = X_CT.linear().col(2);
  std::vector<BoardPoint> board(corners.cols);
  for (int i = 0; i < corners.cols; ++i) {
    const Eigen::Vector3d d(rays[i].x, rays[i].y, 1.0);
    const double denominator = n.dot(d);
    if (std::abs(denominator) < 1e-12) continue;
    const double lambda = n.dot(t) / denominator;
    if (lambda <= 0) continue;
    const Eigen::Vector3d p_T = R_TC * (lambda * d - t);
    board[i] = {p_T.x(), p_T.y(), true};
  }

  const double shade_value[3] = {options.black, options.white, options.background};
  const int ns = options.samples_per_axis;
  GreyImage image;
  image.width = W;
  image.height = H;
  image.pixels.resize(static_cast<size_t>(W) * H);
  std::mt19937 rng(options.noise_seed);
  std::normal_distribution<double> noise(0.0, options.noise_sigma > 0 ? options.noise_sigma : 1.0);
  cv::Mat ideal(H, W, CV_64F);
  for (int v = 0; v < H; ++v) {
    for (int u = 0; u < W; ++u) {
      const BoardPoint& p00 = board[v * (W + 1) + u];
      const BoardPoint& p10 = board[v * (W + 1) + u + 1];
      const BoardPoint& p01 = board[(v + 1) * (W + 1) + u];
      const BoardPoint& p11 = board[(v + 1) * (W + 1) + u + 1];
      double value;
      if (!(p00.valid && p10.valid && p01.valid && p11.valid)) {
        value = options.background;
      } else {
        int r00, r10, r01, r11;
        const Shade s00 = Classify(p00.x, p00.y, target, &r00);
        Classify(p10.x, p10.y, target, &r10);
        Classify(p01.x, p01.y, target, &r01);
        Classify(p11.x, p11.y, target, &r11);
        if (r00 == r10 && r00 == r01 && r00 == r11) {
          value = shade_value[s00];  // the pixel lies inside one square (or margin, background)
        } else {
          double sum = 0;
          for (int a = 0; a < ns; ++a) {
            const double fy = (a + 0.5) / ns;
            for (int b = 0; b < ns; ++b) {
              const double fx = (b + 0.5) / ns;
              const double x =
                  (1 - fy) * ((1 - fx) * p00.x + fx * p10.x) + fy * ((1 - fx) * p01.x + fx * p11.x);
              const double y =
                  (1 - fy) * ((1 - fx) * p00.y + fx * p10.y) + fy * ((1 - fx) * p01.y + fx * p11.y);
              int region;
              sum += shade_value[Classify(x, y, target, &region)];
            }
          }
          value = sum / (ns * ns);
        }
      }
      ideal.at<double>(v, u) = value;
    }
  }
  if (options.blur_sigma_px > 0) {
    const int half = static_cast<int>(std::ceil(4 * options.blur_sigma_px));
    cv::GaussianBlur(ideal, ideal, cv::Size(2 * half + 1, 2 * half + 1), options.blur_sigma_px,
                     options.blur_sigma_px, cv::BORDER_REPLICATE);
  }
  for (int v = 0; v < H; ++v) {
    for (int u = 0; u < W; ++u) {
      double value = ideal.at<double>(v, u);
      if (options.noise_sigma > 0) value += noise(rng);
      image.pixels[static_cast<size_t>(v) * W + u] =
          static_cast<std::uint8_t>(std::clamp(std::lround(value), 0L, 255L));
    }
  }
  return image;
}

GreyImage RenderEmptyScene(int width, int height, const RenderOptions& options) {
  GreyImage image;
  image.width = width;
  image.height = height;
  image.pixels.assign(static_cast<size_t>(width) * height, 0);
  std::mt19937 rng(options.noise_seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  struct Blob {
    double u, v, radius, grey;
  };
  std::vector<Blob> blobs;
  for (int i = 0; i < 6; ++i) {
    blobs.push_back({unit(rng) * width, unit(rng) * height, (0.05 + 0.15 * unit(rng)) * width,
                     options.black + unit(rng) * (options.white - options.black)});
  }
  std::normal_distribution<double> noise(0.0, options.noise_sigma > 0 ? options.noise_sigma : 1.0);
  for (int v = 0; v < height; ++v) {
    for (int u = 0; u < width; ++u) {
      double value = options.background;
      for (const Blob& b : blobs) {
        if (std::hypot(u - b.u, v - b.v) < b.radius) value = b.grey;
      }
      if (options.noise_sigma > 0) value += noise(rng);
      image.pixels[static_cast<size_t>(v) * width + u] =
          static_cast<std::uint8_t>(std::clamp(std::lround(value), 0L, 255L));
    }
  }
  return image;
}

std::vector<Eigen::Vector2d> ProjectInnerCorners(const vision::PinholeBrownParameters& camera,
                                                 const Eigen::Isometry3d& X_CT,
                                                 const ChessboardTarget& target) {
  std::vector<cv::Point3d> p_T;
  for (int j = 0; j < target.rows; ++j) {
    for (int i = 0; i < target.cols; ++i) {
      p_T.emplace_back(i * target.square_m, j * target.square_m, 0.0);
    }
  }
  std::vector<Eigen::Vector2d> out;
  for (const cv::Point2d& p : Project(camera, X_CT, p_T)) out.emplace_back(p.x, p.y);
  return out;
}

std::vector<Eigen::Isometry3d> CalibrationPoses(const vision::PinholeBrownParameters& camera,
                                                const ChessboardTarget& target, int count,
                                                unsigned seed, double border_px) {
  const double s = target.square_m, m = target.margin_m;
  const double x0 = -s - m, x1 = target.cols * s + m, y0 = -s - m, y1 = target.rows * s + m;
  const Eigen::Vector3d centre_T(0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.0);
  // The outline of the board, densely, so that barrel distortion cannot push an edge out.
  std::vector<cv::Point3d> outline;
  for (int k = 0; k <= 20; ++k) {
    const double f = k / 20.0;
    outline.emplace_back(x0 + f * (x1 - x0), y0, 0);
    outline.emplace_back(x0 + f * (x1 - x0), y1, 0);
    outline.emplace_back(x0, y0 + f * (y1 - y0), 0);
    outline.emplace_back(x1, y0 + f * (y1 - y0), 0);
  }
  // Each outer inner corner with its neighbours along the row and the column.
  std::vector<cv::Point3d> stencils;
  for (const auto& [i, j, di, dj] :
       {std::array<int, 4>{0, 0, 1, 1}, std::array<int, 4>{target.cols - 1, 0, -1, 1},
        std::array<int, 4>{0, target.rows - 1, 1, -1},
        std::array<int, 4>{target.cols - 1, target.rows - 1, -1, -1}}) {
    stencils.emplace_back(i * s, j * s, 0);
    stencils.emplace_back((i + di) * s, j * s, 0);
    stencils.emplace_back(i * s, (j + dj) * s, 0);
  }
  // The whole outline in front of the camera and inside the image, `border_px` from its edges,
  // and squares that findChessboardCorners can take apart: at least 12 px wide, and not sheared
  // beyond 55°–125° between the projected row and column directions.
  auto Fits = [&](const Eigen::Isometry3d& X_CT) {
    for (const cv::Point3d& q : outline) {
      if ((X_CT * Eigen::Vector3d(q.x, q.y, q.z)).z() < 0.05) return false;
    }
    for (const cv::Point2d& p : Project(camera, X_CT, outline)) {
      if (p.x < border_px || p.y < border_px || p.x > camera.width - 1 - border_px ||
          p.y > camera.height - 1 - border_px) {
        return false;
      }
    }
    const std::vector<cv::Point2d> q = Project(camera, X_CT, stencils);
    for (size_t k = 0; k < q.size(); k += 3) {
      const cv::Point2d a = q[k + 1] - q[k], b = q[k + 2] - q[k];
      if (cv::norm(a) < 12 || cv::norm(b) < 12) return false;
      const double cosine = a.dot(b) / (cv::norm(a) * cv::norm(b));
      if (std::abs(cosine) > std::cos(55.0 * common::kPi / 180.0)) return false;
    }
    return true;
  };
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::vector<Eigen::Isometry3d> poses;
  const double board_width = x1 - x0;
  for (int k = 0; k < count; ++k) {
    // Board centres cycle over a 3 × 3 grid of image regions, jittered, so that the corners
    // cover the whole image over the set.
    const int cell = k % 9;
    for (int attempt = 0;; ++attempt) {
      if (attempt > 20000) {
        throw std::runtime_error("CalibrationPoses: no pose fits the image; board too large");
      }
      const double fraction = 0.3 + 0.3 * unit(rng);  // of the image width the board spans
      const double Z = camera.fx * board_width / (fraction * camera.width);
      const double tilt = (10.0 + 35.0 * unit(rng)) * common::kPi / 180.0;
      const double axis_angle = 2 * common::kPi * unit(rng);
      const double roll = (-20.0 + 40.0 * unit(rng)) * common::kPi / 180.0;
      const Eigen::Matrix3d R_CT =
          (Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()) *
           Eigen::AngleAxisd(tilt, Eigen::Vector3d(std::cos(axis_angle), std::sin(axis_angle), 0)))
              .toRotationMatrix();
      const double u = camera.width * ((cell % 3) + unit(rng)) / 3.0;
      const double v = camera.height * ((cell / 3) + unit(rng)) / 3.0;
      const Eigen::Vector3d p_C_centre((u - camera.cx) / camera.fx * Z,
                                       (v - camera.cy) / camera.fy * Z, Z);
      Eigen::Isometry3d X_CT = Eigen::Isometry3d::Identity();
      X_CT.linear() = R_CT;
      X_CT.translation() = p_C_centre - R_CT * centre_T;
      if (!Fits(X_CT)) continue;
      // Push the board towards its cell's side of the image, as far as it fits: the corners of
      // the image are where the distortion is largest and hardest to cover.
      const Eigen::Vector3d push(((cell % 3) - 1) * 2.0 * Z / camera.fx,
                                 ((cell / 3) - 1) * 2.0 * Z / camera.fy, 0.0);
      if (push.norm() > 0) {
        for (int step = 0; step < 500; ++step) {
          Eigen::Isometry3d moved = X_CT;
          moved.translation() += push;
          if (!Fits(moved)) break;
          X_CT = moved;
        }
      }
      poses.push_back(X_CT);
      break;
    }
  }
  return poses;
}

}  // namespace kinevis::testing
