#include "calibration/laser_scanner/board_pose.h"

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <stdexcept>

#include "common/config_error.h"
#include "common/so3.h"

namespace kinevis::calibration {
namespace {

using vision::CameraModel;
using vision::ProjectionStatus;
using vision::Ray;
using vision::render::DotGrid;

constexpr int kDiscSamples = 48;
// Margins (px) around a dot's thresholded ellipse: the darkness centroid is taken within
// kInnerMargin (covers the anti-aliased edge and some blur), the board's local level is the
// median of the ring between kInnerMargin and kOuterMargin.
constexpr double kInnerMargin = 4.0;
constexpr double kOuterMargin = 8.0;

struct Blob {
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Zero();
  double area = 0.0;
  Eigen::Vector2d centroid = Eigen::Vector2d::Zero();  // darkness centroid (px)
  Eigen::Vector2d normalized = Eigen::Vector2d::Zero();
};

double Cross(const Eigen::Vector2d& o, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  return (a.x() - o.x()) * (b.y() - o.y()) - (a.y() - o.y()) * (b.x() - o.x());
}

// Andrew's monotone chain; counter-clockwise (in the coordinates' own orientation), collinear
// points dropped. Returns indices.
std::vector<int> ConvexHull(const std::vector<Eigen::Vector2d>& p) {
  std::vector<int> order(p.size());
  for (size_t i = 0; i < p.size(); ++i) order[i] = static_cast<int>(i);
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    return p[a].x() < p[b].x() || (p[a].x() == p[b].x() && p[a].y() < p[b].y());
  });
  std::vector<int> hull(2 * p.size());
  size_t k = 0;
  for (int i : order) {
    while (k >= 2 && Cross(p[hull[k - 2]], p[hull[k - 1]], p[i]) <= 0.0) --k;
    hull[k++] = i;
  }
  for (size_t n = order.size() - 1, t = k + 1; n-- > 0;) {
    const int i = order[n];
    while (k >= t && Cross(p[hull[k - 2]], p[hull[k - 1]], p[i]) <= 0.0) --k;
    hull[k++] = i;
  }
  hull.resize(k > 1 ? k - 1 : k);
  return hull;
}

// DLT homography (Hartley-normalised) with H · (x, y, 1) ∝ (u, v, 1); from >= 4 pairs.
Eigen::Matrix3d FitHomography(const std::vector<Eigen::Vector2d>& from,
                              const std::vector<Eigen::Vector2d>& to) {
  auto normaliser = [](const std::vector<Eigen::Vector2d>& q) {
    Eigen::Vector2d mean = Eigen::Vector2d::Zero();
    for (const auto& x : q) mean += x;
    mean /= static_cast<double>(q.size());
    double spread = 0.0;
    for (const auto& x : q) spread += (x - mean).norm();
    spread = std::max(spread / static_cast<double>(q.size()), 1e-300);
    const double s = std::sqrt(2.0) / spread;
    Eigen::Matrix3d T;
    T << s, 0.0, -s * mean.x(), 0.0, s, -s * mean.y(), 0.0, 0.0, 1.0;
    return T;
  };
  const Eigen::Matrix3d Tf = normaliser(from), Tt = normaliser(to);
  Eigen::MatrixXd A(2 * from.size(), 9);
  for (size_t i = 0; i < from.size(); ++i) {
    const Eigen::Vector3d x = Tf * from[i].homogeneous();
    const Eigen::Vector3d u = Tt * to[i].homogeneous();
    A.row(2 * i) << 0.0, 0.0, 0.0, -u.z() * x.transpose(), u.y() * x.transpose();
    A.row(2 * i + 1) << u.z() * x.transpose(), 0.0, 0.0, 0.0, -u.x() * x.transpose();
  }
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(A, Eigen::ComputeFullV);
  const Eigen::VectorXd h = svd.matrixV().col(8);
  Eigen::Matrix3d Hn;
  Hn << h(0), h(1), h(2), h(3), h(4), h(5), h(6), h(7), h(8);
  return Tt.inverse() * Hn * Tf;
}

Eigen::Vector2d Apply(const Eigen::Matrix3d& H, const Eigen::Vector2d& x) {
  return (H * x.homogeneous()).hnormalized();
}

// Assigns every point to a grid node under `H_image_grid`; the largest distance from a node
// (cells), or +inf when two points share a node or a point falls outside the grid.
double AssignNodes(const Eigen::Matrix3d& H_image_grid, const std::vector<Eigen::Vector2d>& image,
                   int rows, int cols, std::vector<Eigen::Vector2i>* nodes) {
  const Eigen::Matrix3d H_grid_image = H_image_grid.inverse();
  std::vector<int> owner(rows * cols, -1);
  nodes->assign(image.size(), Eigen::Vector2i::Zero());
  double worst = 0.0;
  for (size_t i = 0; i < image.size(); ++i) {
    const Eigen::Vector2d g = Apply(H_grid_image, image[i]);  // (col, row)
    if (!g.allFinite()) return INFINITY;
    const int col = static_cast<int>(std::lround(g.x())),
              row = static_cast<int>(std::lround(g.y()));
    if (col < 0 || col >= cols || row < 0 || row >= rows) return INFINITY;
    if (owner[row * cols + col] >= 0) return INFINITY;
    owner[row * cols + col] = static_cast<int>(i);
    (*nodes)[i] = Eigen::Vector2i(col, row);
    worst = std::max(worst, (g - Eigen::Vector2d(col, row)).norm());
  }
  return worst;
}

Eigen::Isometry3d Perturb(const Eigen::Isometry3d& X, const Eigen::Matrix<double, 6, 1>& delta) {
  Eigen::Isometry3d out = Eigen::Isometry3d::Identity();
  const Eigen::Vector3d w = delta.head<3>();
  const double angle = w.norm();
  const Eigen::Matrix3d R = angle > 0.0
                                ? Eigen::AngleAxisd(angle, w / angle).toRotationMatrix()
                                : Eigen::Matrix3d(Eigen::Matrix3d::Identity() + common::Skew(w));
  out.linear() = R * X.linear();
  out.translation() = X.translation() + delta.tail<3>();
  return out;
}

}  // namespace

std::string BoardPoseOptions::Validate() const {
  common::Problems bad;
  if (!(threshold_window_px == 0 || (threshold_window_px >= 3 && threshold_window_px % 2 == 1))) {
    bad.Add("threshold_window_px", threshold_window_px, "must be 0 (auto) or odd >= 3");
  }
  if (!(std::isfinite(threshold_offset) && threshold_offset > 0.0)) {
    bad.Add("threshold_offset", threshold_offset, "must be > 0 grey levels");
  }
  if (!(std::isfinite(min_dot_area_px) && min_dot_area_px > 0.0)) {
    bad.Add("min_dot_area_px", min_dot_area_px, "must be > 0");
  }
  if (!(max_dot_area_fraction > 0.0 && max_dot_area_fraction <= 1.0)) {
    bad.Add("max_dot_area_fraction", max_dot_area_fraction, "must be in (0, 1]");
  }
  if (!(max_fill_deviation > 0.0 && max_fill_deviation < 1.0)) {
    bad.Add("max_fill_deviation", max_fill_deviation, "must be in (0, 1)");
  }
  if (!(min_axis_ratio > 0.0 && min_axis_ratio <= 1.0)) {
    bad.Add("min_axis_ratio", min_axis_ratio, "must be in (0, 1]");
  }
  if (!(max_grid_residual > 0.0 && max_grid_residual < 0.5)) {
    bad.Add("max_grid_residual", max_grid_residual, "must be in (0, 0.5) cells");
  }
  if (max_iterations < 1) bad.Add("max_iterations", max_iterations, "must be >= 1");
  if (!(step_tolerance >= 0.0)) bad.Add("step_tolerance", step_tolerance, "must be >= 0");
  if (!(std::isfinite(max_rms_px) && max_rms_px > 0.0)) {
    bad.Add("max_rms_px", max_rms_px, "must be > 0 px");
  }
  return bad.Message();
}

std::string_view ToString(BoardPoseStatus status) {
  switch (status) {
    case BoardPoseStatus::kOk:
      return "ok";
    case BoardPoseStatus::kGridNotFound:
      return "grid not found";
    case BoardPoseStatus::kPoseFailed:
      return "pose failed";
  }
  return "unknown";
}

Eigen::Vector4d BoardPose::PlaneInC() const {
  const Eigen::Vector3d n = X_CS.linear().col(2);
  return Eigen::Vector4d(n.x(), n.y(), n.z(), -n.dot(X_CS.translation()));
}

bool ProjectedDiscCentroid(const CameraModel& camera, const Eigen::Isometry3d& X_CS,
                           const Eigen::Vector2d& p_S_centre, double radius, int samples,
                           Eigen::Vector2d* centroid) {
  std::array<Eigen::Vector2d, 256> polygon;
  samples = std::clamp(samples, 3, 256);
  for (int k = 0; k < samples; ++k) {
    const double phi = 2.0 * M_PI * k / samples;
    const Eigen::Vector3d p_S(p_S_centre.x() + radius * std::cos(phi),
                              p_S_centre.y() + radius * std::sin(phi), 0.0);
    if (camera.Project(X_CS * p_S, &polygon[k]) != ProjectionStatus::kOk) return false;
  }
  // Polygon (shoelace) area centroid.
  double area2 = 0.0;
  Eigen::Vector2d sum = Eigen::Vector2d::Zero();
  for (int k = 0; k < samples; ++k) {
    const Eigen::Vector2d& a = polygon[k];
    const Eigen::Vector2d& b = polygon[(k + 1) % samples];
    const double cross = a.x() * b.y() - b.x() * a.y();
    area2 += cross;
    sum += cross * (a + b);
  }
  if (std::abs(area2) < 1e-12) return false;
  *centroid = sum / (3.0 * area2);
  return true;
}

BoardPose DetectDotGrid(const vision::ImageView8& image, const CameraModel& camera,
                        const DotGrid& grid, const BoardPoseOptions& options) {
  std::string problems = options.Validate();
  const std::string grid_problems = grid.Validate("grid.");
  if (!grid_problems.empty()) problems += (problems.empty() ? "" : "; ") + grid_problems;
  if (image.data == nullptr || image.width != camera.width() || image.height != camera.height()) {
    problems += std::string(problems.empty() ? "" : "; ") + "image " + std::to_string(image.width) +
                "x" + std::to_string(image.height) + " (must be the camera's " +
                std::to_string(camera.width()) + "x" + std::to_string(camera.height()) + ")";
  }
  if (!problems.empty()) throw std::invalid_argument("DetectDotGrid: " + problems);

  BoardPose out;
  const cv::Mat grey(image.height, image.width, CV_8UC1, image.data, image.stride);
  int window = options.threshold_window_px;
  if (window == 0) window = std::max(51, (image.width / 8) | 1);
  cv::Mat dark;
  cv::adaptiveThreshold(grey, dark, 255, cv::ADAPTIVE_THRESH_MEAN_C, cv::THRESH_BINARY_INV, window,
                        options.threshold_offset);
  cv::Mat labels, stats, centroids;
  const int count = cv::connectedComponentsWithStats(dark, labels, stats, centroids, 8, CV_32S);

  // Per component: pixel moments (the thresholded ellipse).
  std::vector<Eigen::Matrix<double, 6, 1>> sums(count, Eigen::Matrix<double, 6, 1>::Zero());
  for (int v = 0; v < image.height; ++v) {
    const int* row = labels.ptr<int>(v);
    for (int u = 0; u < image.width; ++u) {
      const int label = row[u];
      if (label == 0) continue;
      Eigen::Matrix<double, 6, 1>& s = sums[label];
      s(0) += 1.0;
      s(1) += u;
      s(2) += v;
      s(3) += static_cast<double>(u) * u;
      s(4) += static_cast<double>(v) * v;
      s(5) += static_cast<double>(u) * v;
    }
  }
  const double max_area = options.max_dot_area_fraction * image.width * image.height;
  std::vector<Blob> blobs;
  for (int label = 1; label < count; ++label) {
    const Eigen::Matrix<double, 6, 1>& s = sums[label];
    const double area = s(0);
    if (area < options.min_dot_area_px || area > max_area) continue;
    Blob blob;
    blob.area = area;
    blob.mean = Eigen::Vector2d(s(1), s(2)) / area;
    blob.covariance << s(3) / area - blob.mean.x() * blob.mean.x(),
        s(5) / area - blob.mean.x() * blob.mean.y(), s(5) / area - blob.mean.x() * blob.mean.y(),
        s(4) / area - blob.mean.y() * blob.mean.y();
    const double det = blob.covariance.determinant();
    if (!(det > 0.0)) continue;
    // A filled ellipse of semi-axes (p, q) has area π p q and covariance diag(p², q²) / 4.
    const double fill = area / (4.0 * M_PI * std::sqrt(det));
    if (std::abs(fill - 1.0) > options.max_fill_deviation) continue;
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(blob.covariance);
    if (std::sqrt(eig.eigenvalues()(0) / eig.eigenvalues()(1)) < options.min_axis_ratio) continue;
    blobs.push_back(blob);
  }
  out.candidates = static_cast<int>(blobs.size());
  const int expected = grid.rows * grid.cols;
  if (out.candidates != expected) {
    out.status = BoardPoseStatus::kGridNotFound;
    out.message = "found " + std::to_string(out.candidates) + " dot-like blobs, expected " +
                  std::to_string(expected) + " (" + std::to_string(grid.rows) + " x " +
                  std::to_string(grid.cols) + "; the whole grid must be in view)";
    return out;
  }

  // Sub-pixel centres: the darkness centroid within the grown ellipse, the board's level from a
  // ring around it.
  std::vector<double> ring;
  for (Blob& blob : blobs) {
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(blob.covariance);
    const double minor = 2.0 * std::sqrt(eig.eigenvalues()(0));  // semi-axes (px)
    const double major = 2.0 * std::sqrt(eig.eigenvalues()(1));
    const Eigen::Matrix2d inverse = blob.covariance.inverse();
    // Mahalanobis radius 2 is the ellipse's boundary; grown by a margin along the minor axis.
    const double inner = 2.0 * (1.0 + kInnerMargin / minor);
    const double outer = 2.0 * (1.0 + kOuterMargin / minor);
    const int reach = static_cast<int>(std::ceil(major * (1.0 + kOuterMargin / minor))) + 1;
    const int u0 = std::max(0, static_cast<int>(blob.mean.x()) - reach);
    const int u1 = std::min(image.width - 1, static_cast<int>(blob.mean.x()) + reach);
    const int v0 = std::max(0, static_cast<int>(blob.mean.y()) - reach);
    const int v1 = std::min(image.height - 1, static_cast<int>(blob.mean.y()) + reach);
    ring.clear();
    for (int v = v0; v <= v1; ++v) {
      for (int u = u0; u <= u1; ++u) {
        const Eigen::Vector2d d = Eigen::Vector2d(u, v) - blob.mean;
        const double m = std::sqrt(d.dot(inverse * d));
        if (m > inner && m <= outer) ring.push_back(grey.at<uint8_t>(v, u));
      }
    }
    double level = 255.0;
    if (!ring.empty()) {
      std::nth_element(ring.begin(), ring.begin() + ring.size() / 2, ring.end());
      level = ring[ring.size() / 2];
    }
    double sum = 0.0;
    Eigen::Vector2d first = Eigen::Vector2d::Zero();
    for (int v = v0; v <= v1; ++v) {
      for (int u = u0; u <= u1; ++u) {
        const Eigen::Vector2d d = Eigen::Vector2d(u, v) - blob.mean;
        if (d.dot(inverse * d) > inner * inner) continue;
        const double w = std::max(0.0, level - grey.at<uint8_t>(v, u));
        sum += w;
        first += w * Eigen::Vector2d(u, v);
      }
    }
    blob.centroid = sum > 0.0 ? Eigen::Vector2d(first / sum) : blob.mean;
  }

  // Undistorted (normalised) coordinates: the grid's lines are straight there.
  std::vector<Eigen::Vector2d> normalized(blobs.size());
  for (size_t i = 0; i < blobs.size(); ++i) {
    Ray ray;
    if (camera.BackProject(blobs[i].centroid, &ray) != ProjectionStatus::kOk ||
        !(ray.d_C.z() > 0.0)) {
      out.status = BoardPoseStatus::kGridNotFound;
      out.message = "a dot at pixel (" + std::to_string(blobs[i].centroid.x()) + ", " +
                    std::to_string(blobs[i].centroid.y()) + ") cannot be back-projected";
      return out;
    }
    normalized[i] = ray.d_C.head<2>() / ray.d_C.z();
  }
  const std::vector<int> hull = ConvexHull(normalized);
  if (hull.size() < 4) {
    out.status = BoardPoseStatus::kGridNotFound;
    out.message = "the dots' convex hull has fewer than 4 corners";
    return out;
  }
  // The four hull vertices with the sharpest turns, in hull order.
  std::vector<std::pair<double, int>> turns;
  const int h = static_cast<int>(hull.size());
  for (int k = 0; k < h; ++k) {
    const Eigen::Vector2d a = normalized[hull[(k + h - 1) % h]], b = normalized[hull[k]],
                          c = normalized[hull[(k + 1) % h]];
    const Eigen::Vector2d e1 = (b - a).normalized(), e2 = (c - b).normalized();
    turns.push_back({std::atan2(e1.x() * e2.y() - e1.y() * e2.x(), e1.dot(e2)), k});
  }
  std::sort(turns.begin(), turns.end(), std::greater<>());
  std::array<int, 4> corner_k = {turns[0].second, turns[1].second, turns[2].second,
                                 turns[3].second};
  std::sort(corner_k.begin(), corner_k.end());
  const std::array<Eigen::Vector2d, 4> grid_corners = {
      Eigen::Vector2d(0, 0), Eigen::Vector2d(grid.cols - 1, 0),
      Eigen::Vector2d(grid.cols - 1, grid.rows - 1), Eigen::Vector2d(0, grid.rows - 1)};

  // Every labelling of the corners; keep the consistent ones.
  struct Candidate {
    Eigen::Matrix3d H;
    std::vector<Eigen::Vector2i> nodes;
    double residual;
  };
  std::vector<Candidate> valid;
  std::vector<Eigen::Vector2d> grid_points(blobs.size());
  for (int start = 0; start < 4; ++start) {
    for (int direction : {1, -1}) {
      std::vector<Eigen::Vector2d> from(4), to(4);
      for (int c = 0; c < 4; ++c) {
        from[c] = grid_corners[c];
        to[c] = normalized[hull[corner_k[(start + direction * c + 8) % 4]]];
      }
      Candidate candidate;
      candidate.H = FitHomography(from, to);
      candidate.residual =
          AssignNodes(candidate.H, normalized, grid.rows, grid.cols, &candidate.nodes);
      if (!(candidate.residual <= 0.5)) continue;
      // Refit with every dot, re-assign.
      for (size_t i = 0; i < blobs.size(); ++i) grid_points[i] = candidate.nodes[i].cast<double>();
      candidate.H = FitHomography(grid_points, normalized);
      candidate.residual =
          AssignNodes(candidate.H, normalized, grid.rows, grid.cols, &candidate.nodes);
      if (candidate.residual <= options.max_grid_residual) valid.push_back(candidate);
    }
  }
  // Right-handed S with z_S towards the camera: (e_col × e_row) < 0 in image coordinates (v down);
  // then x_S closest to +u.
  const Candidate* best = nullptr;
  double best_alignment = -2.0;
  for (const Candidate& candidate : valid) {
    const Eigen::Vector2d centre(0.5 * (grid.cols - 1), 0.5 * (grid.rows - 1));
    const Eigen::Vector2d o = Apply(candidate.H, centre);
    const Eigen::Vector2d e_col = Apply(candidate.H, centre + Eigen::Vector2d(1, 0)) - o;
    const Eigen::Vector2d e_row = Apply(candidate.H, centre + Eigen::Vector2d(0, 1)) - o;
    if (!(e_col.x() * e_row.y() - e_col.y() * e_row.x() < 0.0)) continue;
    const double alignment = e_col.normalized().x();
    if (alignment > best_alignment) {
      best_alignment = alignment;
      best = &candidate;
    }
  }
  if (best == nullptr) {
    out.status = BoardPoseStatus::kGridNotFound;
    out.message = "no ordering puts every dot within " + std::to_string(options.max_grid_residual) +
                  " cells of a distinct node of the " + std::to_string(grid.rows) + " x " +
                  std::to_string(grid.cols) + " grid";
    return out;
  }
  out.dots.resize(blobs.size());
  for (size_t i = 0; i < blobs.size(); ++i) {
    const Eigen::Vector2i node = best->nodes[i];
    DotObservation& dot = out.dots[node.y() * grid.cols + node.x()];
    dot.row = node.y();
    dot.col = node.x();
    dot.pixel = blobs[i].centroid;
    dot.area_px = blobs[i].area;
  }
  out.grid_residual = best->residual;
  out.status = BoardPoseStatus::kOk;
  return out;
}

BoardPose SolveBoardPose(const BoardPose& detection, const CameraModel& camera, const DotGrid& grid,
                         const BoardPoseOptions& options) {
  std::string problems = options.Validate();
  const std::string grid_problems = grid.Validate("grid.");
  if (!grid_problems.empty()) problems += (problems.empty() ? "" : "; ") + grid_problems;
  for (size_t i = 0; i < detection.dots.size(); ++i) {
    const DotObservation& d = detection.dots[i];
    if (d.row < 0 || d.row >= grid.rows || d.col < 0 || d.col >= grid.cols ||
        !d.pixel.allFinite()) {
      problems += std::string(problems.empty() ? "" : "; ") + "dots[" + std::to_string(i) +
                  "] (row " + std::to_string(d.row) + ", col " + std::to_string(d.col) +
                  ") is off the grid or not finite";
    }
  }
  if (!problems.empty()) throw std::invalid_argument("SolveBoardPose: " + problems);

  BoardPose out = detection;
  out.confidence = 0.0;
  auto fail = [&out](const std::string& why) {
    out.status = BoardPoseStatus::kPoseFailed;
    out.message = why;
    out.confidence = 0.0;
    return out;
  };
  const int n = static_cast<int>(detection.dots.size());
  if (n < 4) return fail("only " + std::to_string(n) + " dots (a planar pose needs >= 4)");

  // 1. IPPE on the undistorted coordinates.
  std::vector<cv::Point3d> object;
  std::vector<cv::Point2d> normalized;
  for (const DotObservation& d : detection.dots) {
    Ray ray;
    if (camera.BackProject(d.pixel, &ray) != ProjectionStatus::kOk || !(ray.d_C.z() > 0.0)) {
      return fail("dot (" + std::to_string(d.row) + ", " + std::to_string(d.col) +
                  ") cannot be back-projected");
    }
    const Eigen::Vector2d c = grid.DotCentre_S(d.row, d.col);
    object.emplace_back(c.x(), c.y(), 0.0);
    normalized.emplace_back(ray.d_C.x() / ray.d_C.z(), ray.d_C.y() / ray.d_C.z());
  }
  cv::Mat rvec, tvec;
  bool solved = false;
  try {
    solved = cv::solvePnP(object, normalized, cv::Mat::eye(3, 3, CV_64F), cv::Mat(), rvec, tvec,
                          false, cv::SOLVEPNP_IPPE);
  } catch (const cv::Exception& e) {
    return fail(std::string("planar PnP failed: ") + e.what());
  }
  if (!solved) return fail("planar PnP found no pose");
  cv::Mat R_cv;
  cv::Rodrigues(rvec, R_cv);
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) X.linear()(r, c) = R_cv.at<double>(r, c);
    X.translation()(r) = tvec.at<double>(r);
  }

  // 2. Gauss–Newton / Levenberg–Marquardt on the pixel residuals.
  auto residuals = [&](const Eigen::Isometry3d& pose, Eigen::VectorXd* r) {
    r->resize(2 * n);
    for (int i = 0; i < n; ++i) {
      const DotObservation& d = detection.dots[i];
      const Eigen::Vector2d c = grid.DotCentre_S(d.row, d.col);
      Eigen::Vector2d predicted;
      if (options.disc_centroid_model) {
        if (!ProjectedDiscCentroid(camera, pose, c, grid.dot_radius, kDiscSamples, &predicted)) {
          return false;
        }
      } else if (camera.Project(pose * Eigen::Vector3d(c.x(), c.y(), 0.0), &predicted) !=
                 ProjectionStatus::kOk) {
        return false;
      }
      r->segment<2>(2 * i) = d.pixel - predicted;
    }
    return true;
  };
  auto jacobian = [&](const Eigen::Isometry3d& pose, Eigen::MatrixXd* J) {
    J->resize(2 * n, 6);
    Eigen::VectorXd rp, rm;
    for (int k = 0; k < 6; ++k) {
      Eigen::Matrix<double, 6, 1> delta = Eigen::Matrix<double, 6, 1>::Zero();
      delta(k) = 1e-7;
      if (!residuals(Perturb(pose, delta), &rp) || !residuals(Perturb(pose, -delta), &rm)) {
        return false;
      }
      J->col(k) = (rp - rm) / 2e-7;
    }
    return true;
  };
  Eigen::VectorXd r;
  if (!residuals(X, &r)) return fail("a dot does not project at the PnP pose");
  double cost = r.squaredNorm();
  double lambda = 1e-6;
  Eigen::MatrixXd J;
  for (out.iterations = 0; out.iterations < options.max_iterations; ++out.iterations) {
    if (!jacobian(X, &J)) return fail("a dot does not project near the pose");
    const Matrix6d JtJ = J.transpose() * J;
    const Eigen::Matrix<double, 6, 1> Jtr = J.transpose() * r;
    bool improved = false;
    Eigen::Matrix<double, 6, 1> step;
    for (int attempt = 0; attempt < 10 && !improved; ++attempt) {
      Matrix6d A = JtJ;
      A.diagonal() *= 1.0 + lambda;
      // r = measured − predicted, J = ∂r/∂δ: the step minimises |r + J δ|².
      step = A.ldlt().solve(-Jtr);
      const Eigen::Isometry3d trial = Perturb(X, step);
      Eigen::VectorXd r_trial;
      if (residuals(trial, &r_trial) && r_trial.squaredNorm() <= cost) {
        X = trial;
        r = r_trial;
        cost = r.squaredNorm();
        lambda = std::max(lambda * 0.1, 1e-12);
        improved = true;
      } else {
        lambda *= 10.0;
      }
    }
    if (!improved || step.norm() <= options.step_tolerance) {
      out.converged = true;
      ++out.iterations;
      break;
    }
  }
  if (!jacobian(X, &J)) return fail("a dot does not project at the final pose");
  out.X_CS = X;
  out.rms_px = std::sqrt(cost / n);
  out.max_px = 0.0;
  for (int i = 0; i < n; ++i) out.max_px = std::max(out.max_px, r.segment<2>(2 * i).norm());
  const double sigma2 = n > 3 ? cost / (2.0 * n - 6.0) : 0.0;
  out.covariance = sigma2 * (J.transpose() * J).inverse();
  if (!out.converged) {
    return fail("the pose refinement did not converge in " +
                std::to_string(options.max_iterations) + " iterations");
  }
  if (out.rms_px > options.max_rms_px) {
    std::ostringstream why;
    why << "residual RMS " << out.rms_px << " px exceeds max_rms_px " << options.max_rms_px;
    return fail(why.str());
  }
  out.status = BoardPoseStatus::kOk;
  out.message.clear();
  out.confidence = std::max(0.0, 1.0 - out.grid_residual / 0.5) *
                   std::exp(-out.rms_px * out.rms_px / (2.0 * 0.3 * 0.3));
  return out;
}

BoardPose EstimateBoardPose(const vision::ImageView8& image, const CameraModel& camera,
                            const DotGrid& grid, const BoardPoseOptions& options) {
  const BoardPose detection = DetectDotGrid(image, camera, grid, options);
  if (!detection.ok()) return detection;
  return SolveBoardPose(detection, camera, grid, options);
}

}  // namespace kinevis::calibration
