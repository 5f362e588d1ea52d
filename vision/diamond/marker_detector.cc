#include "vision/diamond/marker_detector.h"

#include <Eigen/LU>
#include <algorithm>
#include <array>
#include <cmath>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <stdexcept>
#include <vector>

#include "common/config_error.h"

namespace kinevis::vision {
namespace {

constexpr int kRingSamples = 64;

// Bilinear sample of an 8-bit image at (x, y) (pixel centres at integers); the caller keeps
// (x, y) at least one pixel inside the image.
double Bilinear(const cv::Mat& image, double x, double y) {
  const int x0 = static_cast<int>(std::floor(x));
  const int y0 = static_cast<int>(std::floor(y));
  const double fx = x - x0;
  const double fy = y - y0;
  const uint8_t* r0 = image.ptr<uint8_t>(y0);
  const uint8_t* r1 = image.ptr<uint8_t>(y0 + 1);
  return (1 - fy) * ((1 - fx) * r0[x0] + fx * r0[x0 + 1]) +
         fy * ((1 - fx) * r1[x0] + fx * r1[x0 + 1]);
}

struct RingCheck {
  bool inside = false;  // the ring lies inside the image
  bool x_pattern = false;
  double contrast = 0.0;
  double confidence = 0.0;
};

// The X pattern on a ring about p (see the header): four alternating runs about the mid level,
// each at least 45° long.
RingCheck CheckRing(const cv::Mat& image, const Eigen::Vector2d& p, double radius) {
  RingCheck check;
  if (p.x() - radius < 1.0 || p.y() - radius < 1.0 || p.x() + radius > image.cols - 2.0 ||
      p.y() + radius > image.rows - 2.0) {
    return check;
  }
  check.inside = true;
  std::array<double, kRingSamples> s{};
  double lo = 255.0, hi = 0.0;
  for (int k = 0; k < kRingSamples; ++k) {
    const double a = 2.0 * M_PI * k / kRingSamples;
    s[k] = Bilinear(image, p.x() + radius * std::cos(a), p.y() + radius * std::sin(a));
    lo = std::min(lo, s[k]);
    hi = std::max(hi, s[k]);
  }
  const double mid = 0.5 * (lo + hi);
  std::array<bool, kRingSamples> bright{};
  for (int k = 0; k < kRingSamples; ++k) bright[k] = s[k] > mid;
  int first_change = -1, changes = 0;
  for (int k = 0; k < kRingSamples; ++k) {
    if (bright[k] != bright[(k + 1) % kRingSamples]) {
      if (first_change < 0) first_change = k;
      ++changes;
    }
  }
  if (changes != 4) return check;
  // Walk the four runs starting after the first change.
  std::array<double, 4> mean{}, sq{};
  std::array<int, 4> length{}, used{};
  std::array<bool, 4> run_bright{};
  int run = 0;
  const int start = (first_change + 1) % kRingSamples;
  std::array<int, 4> begin{};
  begin[0] = 0;
  for (int i = 0; i < kRingSamples; ++i) {
    const int k = (start + i) % kRingSamples;
    if (i > 0 && bright[k] != bright[(k + kRingSamples - 1) % kRingSamples]) {
      ++run;
      begin[run] = i;
    }
    run_bright[run] = bright[k];
    ++length[run];
  }
  for (int r = 0; r < 4; ++r) {
    if (length[r] < kRingSamples / 8) return check;
    // The samples next to a transition are mixed: left out of the means and the spread.
    for (int i = begin[r] + 1; i < begin[r] + length[r] - 1; ++i) {
      const double v = s[(start + i) % kRingSamples];
      mean[r] += v;
      sq[r] += v * v;
      ++used[r];
    }
    if (used[r] == 0) return check;
  }
  double var = 0.0;
  int n = 0;
  for (int r = 0; r < 4; ++r) {
    const double m = mean[r] / used[r];
    var += sq[r] - used[r] * m * m;
    n += used[r];
    mean[r] = m;
  }
  const double sigma = std::sqrt(std::max(0.0, var / std::max(1, n - 4)));
  // Runs alternate (four changes): 0 and 2 have one brightness, 1 and 3 the other.
  const int b = run_bright[0] ? 0 : 1;
  const double b1 = mean[b], b2 = mean[b + 2], d1 = mean[1 - b], d2 = mean[3 - b];
  check.contrast = 0.5 * (b1 + b2) - 0.5 * (d1 + d2);
  if (!(check.contrast > 0)) return check;
  const double symmetry =
      std::clamp(1.0 - (std::abs(b1 - b2) + std::abs(d1 - d2)) / (2.0 * check.contrast), 0.0, 1.0);
  check.confidence = symmetry * check.contrast / (check.contrast + 3.0 * sigma);
  check.x_pattern = true;
  return check;
}

// Saddle point of the smoothed intensities near p: a quadric a x² + b xy + c y² + d x + e y + f
// fitted by least squares to the 5×5 samples (bilinear, 1 px apart) of the smoothed image
// centred on the current estimate, whose stationary point is the next estimate, until the step
// is below 1e-4 px (at most 20 steps). Why iterate: an X-corner's smoothed intensity is even
// about its centre, so the fit on a window centred there has no linear terms and its stationary
// point is the centre exactly; a window centred elsewhere is biased by the profile's departure
// from a quadric (a single fit on the pixel grid leaves ~0.05–0.1 px; measured). false when the
// fit is not a saddle, leaves the image or does not converge. smoothed: CV_32F.
bool SaddleFit(const cv::Mat& smoothed, const Eigen::Vector2d& start, Eigen::Vector2d* saddle) {
  // The normal equations of the fixed 5×5 design, inverted once.
  static const Eigen::Matrix<double, 6, 25> kPseudoInverse = [] {
    Eigen::Matrix<double, 25, 6> A;
    int k = 0;
    for (int dy = -2; dy <= 2; ++dy) {
      for (int dx = -2; dx <= 2; ++dx, ++k) A.row(k) << dx * dx, dx * dy, dy * dy, dx, dy, 1.0;
    }
    return Eigen::Matrix<double, 6, 25>((A.transpose() * A).inverse() * A.transpose());
  }();
  Eigen::Vector2d p = start;
  for (int iteration = 0; iteration < 20; ++iteration) {
    if (!(p.x() >= 3 && p.y() >= 3 && p.x() <= smoothed.cols - 4 && p.y() <= smoothed.rows - 4)) {
      return false;
    }
    const int x0 = static_cast<int>(std::floor(p.x()));
    const int y0 = static_cast<int>(std::floor(p.y()));
    const double fx = p.x() - x0, fy = p.y() - y0;
    Eigen::Matrix<double, 25, 1> b;
    int k = 0;
    for (int dy = -2; dy <= 2; ++dy) {
      const float* r0 = smoothed.ptr<float>(y0 + dy);
      const float* r1 = smoothed.ptr<float>(y0 + dy + 1);
      for (int dx = -2; dx <= 2; ++dx, ++k) {
        const int x = x0 + dx;
        b[k] = (1 - fy) * ((1 - fx) * r0[x] + fx * r0[x + 1]) +
               fy * ((1 - fx) * r1[x] + fx * r1[x + 1]);
      }
    }
    const Eigen::Matrix<double, 6, 1> c = kPseudoInverse * b;
    Eigen::Matrix2d H;
    H << 2 * c[0], c[1], c[1], 2 * c[2];
    if (!(H.determinant() < 0)) return false;
    const Eigen::Vector2d step = H.lu().solve(-Eigen::Vector2d(c[3], c[4]));
    if (!step.allFinite() || step.norm() > 2.0) return false;
    p += step;
    if (step.norm() < 1e-4) {
      *saddle = p;
      return true;
    }
  }
  return false;
}

}  // namespace

std::string MarkerDetectorOptions::Validate() const {
  common::Problems problems;
  const auto bad = [&problems](const char* field, double value, const char* rule) {
    problems.Add(field, value, rule);
  };
  if (!(std::isfinite(ring_radius_px) && ring_radius_px >= 3 && ring_radius_px <= 50)) {
    bad("ring_radius_px", ring_radius_px, "must be in [3, 50]");
  } else if (search_half_window_px < ring_radius_px + 4) {
    bad("search_half_window_px", search_half_window_px, "must be >= ring_radius_px + 4");
  }
  if (harris_block_size < 3 || harris_block_size > 15 || harris_block_size % 2 == 0) {
    bad("harris_block_size", harris_block_size, "must be odd, 3..15");
  }
  if (harris_aperture != 3 && harris_aperture != 5 && harris_aperture != 7) {
    bad("harris_aperture", harris_aperture, "must be 3, 5 or 7");
  }
  if (!(harris_k > 0 && harris_k < 0.25)) bad("harris_k", harris_k, "must be in (0, 0.25)");
  if (max_candidates < 1 || max_candidates > 64) {
    bad("max_candidates", max_candidates, "must be in 1..64");
  }
  if (!(candidate_fraction > 0 && candidate_fraction < 1)) {
    bad("candidate_fraction", candidate_fraction, "must be in (0, 1)");
  }
  if (refine_half_window_px < 2 || refine_half_window_px > 20) {
    bad("refine_half_window_px", refine_half_window_px, "must be in 2..20");
  }
  if (!(std::isfinite(min_contrast) && min_contrast > 0)) {
    bad("min_contrast", min_contrast, "must be > 0 grey levels");
  }
  if (!(min_confidence >= 0 && min_confidence <= 1)) {
    bad("min_confidence", min_confidence, "must be in [0, 1]");
  }
  return problems.Message();
}

const char* ToString(MarkerStatus status) {
  switch (status) {
    case MarkerStatus::kFound:
      return "found";
    case MarkerStatus::kNotFound:
      return "no X-corner verified";
    case MarkerStatus::kNoCorner:
      return "no corner response";
    case MarkerStatus::kOutsideImage:
      return "search region outside the image";
    case MarkerStatus::kNearBorder:
      return "marker too close to the image border";
    case MarkerStatus::kInvalidImage:
      return "invalid image";
  }
  return "?";
}

struct MarkerDetector::Scratch {
  cv::Mat response;
  cv::Mat dilated;
  cv::Mat smoothed;
  std::vector<std::pair<float, cv::Point>> peaks;
  std::vector<cv::Point2f> corner{1};
};

MarkerDetector::MarkerDetector(MarkerDetectorOptions options)
    : options_(options), scratch_(std::make_unique<Scratch>()) {
  const std::string problems = options.Validate();
  if (!problems.empty()) throw std::invalid_argument("MarkerDetector: " + problems);
}

MarkerDetector::~MarkerDetector() = default;
MarkerDetector::MarkerDetector(MarkerDetector&&) noexcept = default;
MarkerDetector& MarkerDetector::operator=(MarkerDetector&&) noexcept = default;

MarkerDetection MarkerDetector::Detect(const vision::ImageView8& image,
                                       const Eigen::Vector2d* prediction) {
  MarkerDetection result;
  if (image.data == nullptr || image.width <= 0 || image.height <= 0 ||
      image.stride < static_cast<size_t>(image.width)) {
    result.status = MarkerStatus::kInvalidImage;
    return result;
  }
  const cv::Mat full(image.height, image.width, CV_8UC1, image.data, image.stride);
  const int ring = static_cast<int>(std::ceil(options_.ring_radius_px));
  cv::Rect region(0, 0, image.width, image.height);
  if (prediction != nullptr) {
    if (!prediction->allFinite()) {
      result.status = MarkerStatus::kOutsideImage;
      return result;
    }
    const int w = options_.search_half_window_px;
    const double px = std::clamp(prediction->x(), -1e6, 1e6);
    const double py = std::clamp(prediction->y(), -1e6, 1e6);
    const cv::Rect wanted(static_cast<int>(std::lround(px)) - w,
                          static_cast<int>(std::lround(py)) - w, 2 * w + 1, 2 * w + 1);
    region = wanted & region;
  }
  // The region must hold at least one ring with its margin.
  if (region.width < 2 * ring + 5 || region.height < 2 * ring + 5) {
    result.status = MarkerStatus::kOutsideImage;
    return result;
  }
  Scratch& s = *scratch_;
  const cv::Mat roi = full(region);
  cv::cornerHarris(roi, s.response, options_.harris_block_size, options_.harris_aperture,
                   options_.harris_k);
  double max_response = 0.0;
  cv::minMaxLoc(s.response, nullptr, &max_response);
  if (!(max_response > 0.0)) {
    result.status = MarkerStatus::kNoCorner;
    return result;
  }
  const int nms = 2 * options_.refine_half_window_px + 1;
  cv::dilate(s.response, s.dilated, cv::getStructuringElement(cv::MORPH_RECT, {nms, nms}));
  const float threshold = static_cast<float>(options_.candidate_fraction * max_response);
  s.peaks.clear();
  for (int y = 0; y < s.response.rows; ++y) {
    const float* r = s.response.ptr<float>(y);
    const float* d = s.dilated.ptr<float>(y);
    for (int x = 0; x < s.response.cols; ++x) {
      if (r[x] >= threshold && r[x] >= d[x]) s.peaks.emplace_back(r[x], cv::Point(x, y));
    }
  }
  const size_t keep = std::min<size_t>(s.peaks.size(), options_.max_candidates);
  std::partial_sort(s.peaks.begin(), s.peaks.begin() + static_cast<std::ptrdiff_t>(keep),
                    s.peaks.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
  result.candidates = static_cast<int>(keep);

  // Smoothed copy for the saddle fit (σ = 1 px: the quadric model holds over ±2 px).
  cv::GaussianBlur(roi, s.smoothed, cv::Size(7, 7), 1.0, 1.0, cv::BORDER_REPLICATE);
  s.smoothed.convertTo(s.smoothed, CV_32F);

  bool near_border = false;
  double best_confidence = -1.0;
  const cv::TermCriteria criteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 40, 1e-3);
  const int win = options_.refine_half_window_px;
  for (size_t i = 0; i < keep; ++i) {
    const cv::Point c = s.peaks[i].second + region.tl();
    if (c.x < win + 1 || c.y < win + 1 || c.x > image.width - win - 2 ||
        c.y > image.height - win - 2) {
      near_border = true;
      continue;
    }
    s.corner[0] = cv::Point2f(static_cast<float>(c.x), static_cast<float>(c.y));
    cv::cornerSubPix(full, s.corner, {win, win}, {-1, -1}, criteria);
    Eigen::Vector2d p(s.corner[0].x, s.corner[0].y);
    if (!p.allFinite() || std::abs(p.x() - c.x) > win || std::abs(p.y() - c.y) > win) continue;
    Eigen::Vector2d saddle;
    if (SaddleFit(s.smoothed, p - Eigen::Vector2d(region.x, region.y), &saddle)) {
      saddle += Eigen::Vector2d(region.x, region.y);
      if ((saddle - p).norm() < 1.0) p = saddle;
    }
    const RingCheck check = CheckRing(full, p, options_.ring_radius_px);
    if (!check.inside) {
      near_border = true;
      continue;
    }
    if (!check.x_pattern) continue;
    if (check.confidence > best_confidence) {
      best_confidence = check.confidence;
      result.contrast = check.contrast;
      result.pixel = p;
      result.confidence = check.confidence;
    }
  }
  if (best_confidence >= options_.min_confidence && result.contrast >= options_.min_contrast) {
    result.status = MarkerStatus::kFound;
    return result;
  }
  result.status =
      best_confidence < 0 && near_border ? MarkerStatus::kNearBorder : MarkerStatus::kNotFound;
  result.confidence = 0.0;
  return result;
}

}  // namespace kinevis::vision
