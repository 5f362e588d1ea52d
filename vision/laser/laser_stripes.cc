#include "vision/laser/laser_stripes.h"

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <utility>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace kinevis::vision::laser {

namespace {

constexpr int kMaxImageSide = 16384;
constexpr double kFwhmPerSigma = 2.3548200450309493;  // 2 √(2 ln 2)
constexpr int kNoRun = -2;

// Grey levels along one search line (a column: step = stride; a row: step = 1).
struct LineView {
  const uint8_t* base = nullptr;
  std::ptrdiff_t step = 1;
  int length = 0;
  int operator[](int x) const { return base[static_cast<std::ptrdiff_t>(x) * step]; }
};

// Calls on_hit(x) for every x in [first, last) with m[x] >= max(a[x], b[x]) + threshold, in
// increasing order. a, m and b point at the same x = 0 (they may overlap: for the row search they
// are one row shifted by ∓k). threshold >= 1.
template <typename OnHit>
void RidgeScan(const uint8_t* a, const uint8_t* m, const uint8_t* b, int first, int last,
               int threshold, OnHit&& on_hit) {
  int x = first;
#if defined(__SSE2__)
  // 16 pixels per step; the candidates are a few per thousand pixels, so the bit loop is rare.
  const __m128i t = _mm_set1_epi8(static_cast<char>(threshold));
  const __m128i zero = _mm_setzero_si128();
  for (; x + 16 <= last; x += 16) {
    const __m128i va = _mm_loadu_si128(reinterpret_cast<const __m128i*>(a + x));
    const __m128i vb = _mm_loadu_si128(reinterpret_cast<const __m128i*>(b + x));
    const __m128i vm = _mm_loadu_si128(reinterpret_cast<const __m128i*>(m + x));
    const __m128i excess = _mm_subs_epu8(vm, _mm_max_epu8(va, vb));
    // excess >= t  <=>  t −sat excess == 0
    int bits = _mm_movemask_epi8(_mm_cmpeq_epi8(_mm_subs_epu8(t, excess), zero));
    while (bits != 0) {
      const int i = __builtin_ctz(static_cast<unsigned>(bits));
      on_hit(x + i);
      bits &= bits - 1;
    }
  }
#endif
  for (; x < last; ++x) {
    if (static_cast<int>(m[x]) >= std::max<int>(a[x], b[x]) + threshold) on_hit(x);
  }
}

}  // namespace

namespace internal {

// What Analyse() measured of one candidate.
struct PeakMeasurement {
  bool ok = false;
  StripeRejection reason = StripeRejection::kBorder;
  int peak = 0;  // peak pixel along the line
  int support_first = 0;
  int support_last = 0;
  double position = 0.0;
  double width = 0.0;
  double contrast = 0.0;
  double background = 0.0;
  double sigma = 0.0;
  double fit_rms = 0.0;  // kGaussianFit residual RMS (grey levels), 0 otherwise
  double noise = 0.0;    // σ_n from the flank windows (grey levels)
  double position_sigma = 0.0;
  int saturated = 0;
};

}  // namespace internal

using internal::PeakMeasurement;

double GaussianProfile(double amplitude, double centre, double sigma, double x,
                       Eigen::Vector3d* jacobian) {
  const double d = x - centre;
  const double inv_s2 = 1.0 / (sigma * sigma);
  const double e = std::exp(-0.5 * d * d * inv_s2);
  const double value = amplitude * e;
  if (jacobian != nullptr) {
    (*jacobian)(0) = e;                               // ∂/∂A
    (*jacobian)(1) = value * d * inv_s2;              // ∂/∂μ
    (*jacobian)(2) = value * d * d * inv_s2 / sigma;  // ∂/∂s
  }
  return value;
}

const char* ToString(StripeRejection reason) {
  switch (reason) {
    case StripeRejection::kBorder:
      return "border";
    case StripeRejection::kLowContrast:
      return "low contrast";
    case StripeRejection::kTooNarrow:
      return "too narrow";
    case StripeRejection::kTooWide:
      return "too wide";
    case StripeRejection::kSaturated:
      return "saturated";
    case StripeRejection::kOtherLaser:
      return "other laser";
    case StripeRejection::kFitFailed:
      return "fit failed";
    case StripeRejection::kDoublePeak:
      return "double peak";
    case StripeRejection::kCluttered:
      return "cluttered";
    case StripeRejection::kIsolated:
      return "isolated";
    case StripeRejection::kCount:
      break;
  }
  return "?";
}

const char* ToString(CrossingStatus status) {
  switch (status) {
    case CrossingStatus::kFound:
      return "found";
    case CrossingStatus::kNotSearched:
      return "not searched";
    case CrossingStatus::kStripeMissing:
      return "stripe missing";
    case CrossingStatus::kNoIntersection:
      return "no intersection";
    case CrossingStatus::kTooFewPoints:
      return "too few points";
    case CrossingStatus::kOneSided:
      return "one-sided";
    case CrossingStatus::kNoConvergence:
      return "no convergence";
  }
  return "?";
}

int StripeCounts::rejected_total() const {
  int total = 0;
  for (int r : rejected) total += r;
  return total;
}

std::string LaserStripeOptions::Validate() const {
  std::ostringstream bad;
  auto check = [&bad](bool ok, const char* name, double value, const char* range) {
    if (!ok) bad << name << " = " << value << " (must be " << range << "); ";
  };
  auto finite = [](double x) { return std::isfinite(x); };
  check(background_offset_px >= 2 && background_offset_px <= 32, "background_offset_px",
        background_offset_px, "in [2, 32]");
  check(background_window_px >= 1 && background_window_px <= 16, "background_window_px",
        background_window_px, "in [1, 16]");
  check(finite(min_contrast) && min_contrast >= 1.0 && min_contrast <= 254.0, "min_contrast",
        min_contrast, "in [1, 254]");
  check(finite(threshold_fraction) && threshold_fraction >= 0.05 && threshold_fraction <= 0.9,
        "threshold_fraction", threshold_fraction, "in [0.05, 0.9]");
  check(finite(min_width_px) && min_width_px >= 0.5, "min_width_px", min_width_px, ">= 0.5");
  check(finite(max_width_px) && max_width_px > min_width_px &&
            max_width_px <= 2.0 * background_offset_px,
        "max_width_px", max_width_px, "> min_width_px and <= 2 * background_offset_px");
  check(saturation_level >= 1 && saturation_level <= 255, "saturation_level", saturation_level,
        "in [1, 255]");
  check(max_saturated_pixels >= 0 && max_saturated_pixels <= 32, "max_saturated_pixels",
        max_saturated_pixels, "in [0, 32]");
  const int locator_value = static_cast<int>(locator);
  check(locator_value >= 0 && locator_value <= 2, "locator", locator_value, "a PeakLocator value");
  check(fit_max_iterations >= 1 && fit_max_iterations <= 100, "fit_max_iterations",
        fit_max_iterations, "in [1, 100]");
  check(finite(fit_tolerance_px) && fit_tolerance_px > 0.0, "fit_tolerance_px", fit_tolerance_px,
        "> 0");
  check(max_candidates_per_line >= 1 && max_candidates_per_line <= 16, "max_candidates_per_line",
        max_candidates_per_line, "in [1, 16]");
  check(finite(double_peak_ratio) && double_peak_ratio > 0.0 && double_peak_ratio <= 1.0,
        "double_peak_ratio", double_peak_ratio, "in (0, 1]");
  check(finite(max_jump_px) && max_jump_px > 0.0, "max_jump_px", max_jump_px, "> 0");
  check(max_gap_lines >= 0 && max_gap_lines <= 64, "max_gap_lines", max_gap_lines, "in [0, 64]");
  check(min_chain_lines >= 1 && min_chain_lines <= 1000, "min_chain_lines", min_chain_lines,
        "in [1, 1000]");
  check(crossing_fit_half_length_px >= 4 && crossing_fit_half_length_px <= 2000,
        "crossing_fit_half_length_px", crossing_fit_half_length_px, "in [4, 2000]");
  check(crossing_exclusion_px >= 0 && crossing_exclusion_px < crossing_fit_half_length_px,
        "crossing_exclusion_px", crossing_exclusion_px, "in [0, crossing_fit_half_length_px)");
  check(crossing_min_points >= 3 && crossing_min_points <= 1000, "crossing_min_points",
        crossing_min_points, "in [3, 1000]");
  std::string message = bad.str();
  if (!message.empty()) message.resize(message.size() - 2);  // the last "; "
  return message;
}

// One candidate peak on a line: the ridge run that found it and what Analyse() made of it.
struct LaserStripeExtractor::Candidate {
  int run_first = 0;  // ridge run along the line
  int run_last = 0;
  PeakMeasurement m;
};

// Per line: its candidates (in candidates_[line * max_candidates_per_line ...]) and its outcome.
struct LaserStripeExtractor::LineState {
  int count = 0;  // candidates recorded; > max_candidates_per_line = cluttered
  int chosen = -1;
  bool ambiguous = false;
  bool has_point = false;
  StripeRejection reason = StripeRejection::kBorder;  // when !has_point and count > 0
  double secondary_ratio = 0.0;
  int forward_pick = -1;  // an ambiguous line's candidate continuous with the lines before it
  int chain = -1;         // chain index of the point
};

LaserStripeExtractor::LaserStripeExtractor(const LaserStripeOptions& options) : options_(options) {
  const std::string bad = options.Validate();
  if (!bad.empty()) throw std::invalid_argument("LaserStripeOptions: " + bad);
}
LaserStripeExtractor::~LaserStripeExtractor() = default;
LaserStripeExtractor::LaserStripeExtractor(LaserStripeExtractor&&) noexcept = default;
LaserStripeExtractor& LaserStripeExtractor::operator=(LaserStripeExtractor&&) noexcept = default;

void LaserStripeExtractor::Reserve(int width, int height, LaserStripes* result) {
  if (width < 1 || height < 1 || width > kMaxImageSide || height > kMaxImageSide) {
    throw std::invalid_argument("LaserStripeExtractor: image size " + std::to_string(width) + "x" +
                                std::to_string(height) + " outside [1, 16384]^2");
  }
  const size_t lines = static_cast<size_t>(std::max(width, height));
  if (width != width_ || height != height_) {
    width_ = width;
    height_ = height;
    candidates_.resize(lines * options_.max_candidates_per_line);
    lines_.resize(lines);
    run_start_.resize(width);
    run_last_.resize(width);
    widths_.reserve(lines);
  }
  if (result != nullptr) {
    result->stripes[static_cast<int>(Stripe::kFixed)].points.reserve(height);
    result->stripes[static_cast<int>(Stripe::kRotating)].points.reserve(width);
  }
}

namespace {

// The straight-line background through the flank means, and the values above it.
struct Background {
  double left_mean = 0.0, right_mean = 0.0, left_x = 0.0, right_x = 1.0;
  double At(double x) const {
    return left_mean + (right_mean - left_mean) * (x - left_x) / (right_x - left_x);
  }
};

// Where the profile falls to `level` above the background walking from `peak` in direction `dir`
// (±1), interpolated linearly between the last pixel above and the first not above, within
// `limit` pixels; returns the distance from the peak (px) or `limit` when it does not fall.
double HalfCrossing(const LineView& g, const Background& bg, double level, int peak, int dir,
                    int limit) {
  int x = peak;
  double above = g[peak] - bg.At(peak);
  for (int i = 1; i <= limit; ++i) {
    const int next = peak + dir * i;
    if (next < 0 || next >= g.length) return limit;
    const double value = g[next] - bg.At(next);
    if (value <= level) {
      const double t = (above - level) / (above - value);
      return std::abs(x - peak) + t;
    }
    x = next;
    above = value;
  }
  return limit;
}

double CentreOfGravity(const LineView& g, const Background& bg, double zero, int first, int last) {
  double sum = 0.0, moment = 0.0;
  for (int x = first; x <= last; ++x) {
    const double w = g[x] - bg.At(x) - zero;
    if (w <= 0.0) continue;
    sum += w;
    moment += w * x;
  }
  return sum > 0.0 ? moment / sum : std::nan("");
}

}  // namespace

namespace {

constexpr int kMaxFitPixels = 2 * 32 + 8;  // support (< 2 · background_offset_px) + 2 · 2 + slack

// Levenberg–Marquardt (Marquardt's diagonal scaling) least squares of
// y(x) = A exp(−(x − μ)² / (2 s²)) to y = g − background over [first, last], saturated pixels left
// out. *amplitude, *centre, *sigma hold the start and receive the result. False when fewer than 4
// pixels remain or the fit does not converge.
bool FitGaussian(const LineView& g, const Background& bg, int first, int last, int saturation_level,
                 int max_iterations, double tolerance, double* amplitude, double* centre,
                 double* sigma, double* rms) {
  double xs[kMaxFitPixels];
  double ys[kMaxFitPixels];
  int n = 0;
  for (int x = first; x <= last && n < kMaxFitPixels; ++x) {
    if (g[x] >= saturation_level) continue;
    xs[n] = x;
    ys[n] = g[x] - bg.At(x);
    ++n;
  }
  if (n < 4) return false;
  Eigen::Vector3d theta(*amplitude, *centre, *sigma);
  auto cost = [&](const Eigen::Vector3d& t) {
    double c = 0.0;
    for (int i = 0; i < n; ++i) {
      const double r = ys[i] - GaussianProfile(t(0), t(1), t(2), xs[i], nullptr);
      c += r * r;
    }
    return c;
  };
  double current = cost(theta);
  double lambda = 1e-3;
  bool converged = false;
  for (int iteration = 0; iteration < max_iterations && !converged; ++iteration) {
    Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
    Eigen::Vector3d b = Eigen::Vector3d::Zero();
    for (int i = 0; i < n; ++i) {
      Eigen::Vector3d j;
      const double r = ys[i] - GaussianProfile(theta(0), theta(1), theta(2), xs[i], &j);
      H.noalias() += j * j.transpose();
      b += r * j;
    }
    bool accepted = false;
    for (int attempt = 0; attempt < 12 && !accepted; ++attempt) {
      Eigen::Matrix3d damped = H;
      damped.diagonal() *= 1.0 + lambda;
      damped.diagonal().array() += 1e-12;
      const Eigen::Vector3d step = damped.ldlt().solve(b);
      const Eigen::Vector3d trial = theta + step;
      if (step.allFinite() && trial(2) > 0.1) {
        const double c = cost(trial);
        if (c <= current) {
          accepted = true;
          theta = trial;
          current = c;
          lambda = std::max(lambda * 0.1, 1e-9);
          converged = std::abs(step(1)) < tolerance;
        }
      }
      if (!accepted) lambda *= 10.0;
    }
    // No step lowers the cost even with heavy damping: at the minimum to rounding.
    if (!accepted) converged = true;
  }
  if (!converged || !theta.allFinite()) return false;
  *amplitude = theta(0);
  *centre = theta(1);
  *sigma = theta(2);
  *rms = std::sqrt(current / n);
  return true;
}

// The image line `index` of a search (a column for the column search) and the line across it
// through pixel `x` of that line.
LineView SearchLine(const vision::ImageView8& image, bool column_search, int index) {
  if (column_search)
    return LineView{image.data + index, static_cast<std::ptrdiff_t>(image.stride), image.height};
  return LineView{image.data + static_cast<std::ptrdiff_t>(index) * image.stride, 1, image.width};
}

// Analyses the ridge run [run_first, run_last] of search line `line` (of length g.length).
PeakMeasurement Analyse(const vision::ImageView8& image, bool column_search, int line,
                        const LineView& g, int run_first, int run_last,
                        const LaserStripeOptions& o) {
  PeakMeasurement m;
  int p = run_first;
  for (int x = run_first + 1; x <= run_last; ++x) {
    if (g[x] > g[p]) p = x;
  }
  int plateau_end = p;  // a flat top (saturation): its middle
  while (plateau_end + 1 < g.length && g[plateau_end + 1] == g[p]) ++plateau_end;
  p = (p + plateau_end) / 2;
  m.peak = p;
  const int k = o.background_offset_px;
  const int w = o.background_window_px;
  if (p - k - w + 1 < 0 || p + k + w - 1 >= g.length) {
    m.reason = StripeRejection::kBorder;
    return m;
  }
  Background bg;
  double left = 0.0, right = 0.0;
  for (int i = 0; i < w; ++i) {
    left += g[p - k - i];
    right += g[p + k + i];
  }
  bg.left_mean = left / w;
  bg.right_mean = right / w;
  if (w > 1) {
    double scatter = 0.0;
    for (int i = 0; i < w; ++i) {
      scatter += (g[p - k - i] - bg.left_mean) * (g[p - k - i] - bg.left_mean) +
                 (g[p + k + i] - bg.right_mean) * (g[p + k + i] - bg.right_mean);
    }
    m.noise = std::sqrt(scatter / (2 * (w - 1)));
  }
  bg.left_x = p - k - 0.5 * (w - 1);
  bg.right_x = p + k + 0.5 * (w - 1);
  m.background = bg.At(p);
  m.contrast = g[p] - m.background;
  if (m.contrast < o.min_contrast) {
    m.reason = StripeRejection::kLowContrast;
    return m;
  }
  const double zero = o.threshold_fraction * m.contrast;
  int lo = p, hi = p;
  while (lo - 1 > p - k && g[lo - 1] - bg.At(lo - 1) > zero) --lo;
  while (hi + 1 < p + k && g[hi + 1] - bg.At(hi + 1) > zero) ++hi;
  m.support_first = lo;
  m.support_last = hi;
  const double half = 0.5 * m.contrast;
  const double left_half = HalfCrossing(g, bg, half, p, -1, k);
  const double right_half = HalfCrossing(g, bg, half, p, +1, k);
  m.width = left_half + right_half;
  if (lo == p - k + 1 || hi == p + k - 1 || left_half >= k || right_half >= k ||
      m.width > o.max_width_px) {
    m.reason = StripeRejection::kTooWide;
    return m;
  }
  if (m.width < o.min_width_px) {
    m.reason = StripeRejection::kTooNarrow;
    return m;
  }
  for (int x = lo; x <= hi; ++x) m.saturated += g[x] >= o.saturation_level ? 1 : 0;
  if (m.saturated > o.max_saturated_pixels) {
    m.reason = StripeRejection::kSaturated;
    return m;
  }
  // Orientation: across the line (through the peak pixel) the profile must be at least as wide
  // as along it, else the peak is a cut through the other laser's stripe.
  {
    const LineView across = SearchLine(image, !column_search, p);
    Background flat;
    flat.left_mean = flat.right_mean = m.background;
    const int limit = static_cast<int>(std::ceil(m.width)) + 2;
    const double across_width = HalfCrossing(across, flat, half, line, -1, limit) +
                                HalfCrossing(across, flat, half, line, +1, limit);
    if (across_width < m.width) {
      m.reason = StripeRejection::kOtherLaser;
      return m;
    }
  }
  const double cog = CentreOfGravity(g, bg, zero, lo, hi);
  double position = cog;
  if (o.locator != PeakLocator::kCentreOfGravity) {
    const double a = g[p - 1] - bg.At(p - 1);
    const double b = g[p] - bg.At(p);
    const double c = g[p + 1] - bg.At(p + 1);
    const bool clipped = g[p - 1] >= o.saturation_level || g[p] >= o.saturation_level ||
                         g[p + 1] >= o.saturation_level;
    if (!clipped && a > 0.5 && c > 0.5) {
      const double la = std::log(a), lb = std::log(b), lc = std::log(c);
      const double curvature = la - 2.0 * lb + lc;
      if (curvature < 0.0) {
        const double delta = 0.5 * (la - lc) / curvature;
        if (std::abs(delta) <= 1.0) position = p + delta;
      }
    }
  }
  m.sigma = m.width / kFwhmPerSigma;
  if (o.locator == PeakLocator::kGaussianFit) {
    double amplitude = m.saturated > 0 ? 1.2 * m.contrast : m.contrast;
    double centre = position;
    double sigma = std::max(0.5, m.sigma);
    double rms = 0.0;
    const int first = std::max(lo - 2, p - k + 1);
    const int last = std::min(hi + 2, p + k - 1);
    const bool fitted = FitGaussian(g, bg, first, last, o.saturation_level, o.fit_max_iterations,
                                    o.fit_tolerance_px, &amplitude, &centre, &sigma, &rms);
    if (!fitted || amplitude <= 0.0 || sigma < 0.2 || sigma > k || centre < lo - 1.0 ||
        centre > hi + 1.0) {
      m.reason = StripeRejection::kFitFailed;
      return m;
    }
    position = centre;
    m.sigma = sigma;
    m.fit_rms = rms;
  }
  if (!std::isfinite(position)) {
    m.reason = StripeRejection::kFitFailed;
    return m;
  }
  m.position = position;
  {
    double weight = 0.0, spread = 0.0;
    for (int x = lo; x <= hi; ++x) {
      const double wx = g[x] - bg.At(x) - zero;
      if (wx <= 0.0) continue;
      weight += wx;
      spread += (x - position) * (x - position);
    }
    m.position_sigma = weight > 0.0 ? m.noise * std::sqrt(spread) / weight : 0.0;
  }
  m.ok = true;
  return m;
}

}  // namespace

void LaserStripeExtractor::SearchStripe(const vision::ImageView8& image, Stripe stripe,
                                        StripeResult* result) {
  const LaserStripeOptions& o = options_;
  const bool column_search = stripe == Stripe::kRotating;
  const int lines = column_search ? image.width : image.height;
  const int length = column_search ? image.height : image.width;
  const int max_candidates = o.max_candidates_per_line;
  const int k = o.background_offset_px;
  StripeCounts& counts = result->counts;
  counts = StripeCounts{};
  counts.lines_searched = lines;
  result->points.clear();
  for (int line = 0; line < lines; ++line) lines_[line] = LineState{};

  auto add_run = [&](int line, int first, int last) {
    LineState& s = lines_[line];
    // Noise can split one ridge into runs a pixel or two apart: one candidate.
    if (s.count > 0 && s.count <= max_candidates) {
      Candidate& previous = candidates_[static_cast<size_t>(line) * max_candidates + s.count - 1];
      if (first - previous.run_last <= 3) {
        previous.run_last = last;
        return;
      }
    }
    if (s.count < max_candidates) {
      Candidate& c = candidates_[static_cast<size_t>(line) * max_candidates + s.count];
      c.run_first = first;
      c.run_last = last;
    }
    ++s.count;
  };

  // 1. Ridge runs.
  const int ridge = std::max(1, static_cast<int>(std::ceil(0.8 * o.min_contrast)));
  if (length > 2 * k) {
    if (column_search) {
      std::fill(run_last_.begin(), run_last_.begin() + image.width, kNoRun);
      for (int v = k; v < image.height - k; ++v) {
        const uint8_t* middle = image.data + static_cast<std::ptrdiff_t>(v) * image.stride;
        const std::ptrdiff_t offset = static_cast<std::ptrdiff_t>(k) * image.stride;
        RidgeScan(middle - offset, middle, middle + offset, 0, image.width, ridge, [&](int u) {
          if (run_last_[u] == v - 1) {
            run_last_[u] = v;
          } else {
            if (run_last_[u] != kNoRun) add_run(u, run_start_[u], run_last_[u]);
            run_start_[u] = run_last_[u] = v;
          }
        });
      }
      for (int u = 0; u < image.width; ++u) {
        if (run_last_[u] != kNoRun) add_run(u, run_start_[u], run_last_[u]);
      }
    } else {
      for (int v = 0; v < image.height; ++v) {
        const uint8_t* row = image.data + static_cast<std::ptrdiff_t>(v) * image.stride;
        int start = -1, last = -10;
        // x = u − k, so that no pointer is formed before the row.
        RidgeScan(row, row + k, row + 2 * k, 0, image.width - 2 * k, ridge, [&](int x) {
          const int u = x + k;
          if (u == last + 1) {
            last = u;
          } else {
            if (start >= 0) add_run(v, start, last);
            start = last = u;
          }
        });
        if (start >= 0) add_run(v, start, last);
      }
    }
  }

  // 2–4. Candidates, the choice per line.
  for (int line = 0; line < lines; ++line) {
    LineState& s = lines_[line];
    if (s.count == 0) continue;
    counts.candidates += std::min(s.count, max_candidates);
    if (s.count > max_candidates) {
      s.reason = StripeRejection::kCluttered;
      continue;
    }
    const LineView g = SearchLine(image, column_search, line);
    Candidate* c = &candidates_[static_cast<size_t>(line) * max_candidates];
    for (int i = 0; i < s.count; ++i) {
      c[i].m = Analyse(image, column_search, line, g, c[i].run_first, c[i].run_last, o);
    }
    // The same peak reached from two runs (or a shoulder of it): keep the stronger.
    for (int i = 0; i < s.count; ++i) {
      for (int j = 0; j < s.count; ++j) {
        if (i == j || !c[i].m.ok || !c[j].m.ok) continue;
        const bool overlap = c[i].m.support_first <= c[j].m.support_last &&
                             c[j].m.support_first <= c[i].m.support_last;
        if (overlap &&
            (c[j].m.contrast < c[i].m.contrast || (c[j].m.contrast == c[i].m.contrast && j > i))) {
          c[j].m.ok = false;
          c[j].m.reason = StripeRejection::kCount;  // a duplicate: neither point nor rejection
        }
      }
    }
    int best = -1, second = -1, best_failed = -1;
    for (int i = 0; i < s.count; ++i) {
      if (c[i].m.ok) {
        if (best < 0 || c[i].m.contrast > c[best].m.contrast) {
          second = best;
          best = i;
        } else if (second < 0 || c[i].m.contrast > c[second].m.contrast) {
          second = i;
        }
      } else if (c[i].m.reason != StripeRejection::kCount &&
                 (best_failed < 0 || c[i].m.contrast > c[best_failed].m.contrast)) {
        best_failed = i;
      }
    }
    if (best < 0) {
      s.reason = best_failed >= 0 ? c[best_failed].m.reason : StripeRejection::kLowContrast;
      continue;
    }
    s.chosen = best;
    s.has_point = true;
    if (second >= 0) {
      const double ratio = c[second].m.contrast / c[best].m.contrast;
      if (ratio >= o.double_peak_ratio) {
        s.ambiguous = true;
      } else {
        s.secondary_ratio = ratio;
        ++counts.secondary_peaks_ignored;
      }
    }
  }

  // Ambiguous lines: the candidate continuous with the unambiguous (or resolved) points before
  // it, and after it; both sweeps must agree where both have a reference.
  auto position_of = [&](int line, int index) {
    return candidates_[static_cast<size_t>(line) * max_candidates + index].m.position;
  };
  auto pick_near = [&](int line, double reference, int distance) {
    const LineState& s = lines_[line];
    const Candidate* c = &candidates_[static_cast<size_t>(line) * max_candidates];
    int pick = -1, matches = 0;
    for (int i = 0; i < s.count; ++i) {
      if (c[i].m.ok && std::abs(c[i].m.position - reference) <= o.max_jump_px * distance) {
        pick = i;
        ++matches;
      }
    }
    return matches == 1 ? pick : -1;
  };
  bool any_ambiguous = false;
  for (int line = 0; line < lines; ++line) any_ambiguous |= lines_[line].ambiguous;
  if (any_ambiguous) {
    int ref_line = std::numeric_limits<int>::min() / 2;
    double ref_position = 0.0;
    for (int line = 0; line < lines; ++line) {  // forward
      LineState& s = lines_[line];
      if (!s.has_point) continue;
      if (!s.ambiguous) {
        ref_line = line;
        ref_position = position_of(line, s.chosen);
        continue;
      }
      if (line - ref_line - 1 <= o.max_gap_lines) {
        const int pick = pick_near(line, ref_position, line - ref_line);
        if (pick >= 0) {
          s.forward_pick = pick;
          ref_line = line;
          ref_position = position_of(line, pick);
        }
      }
    }
    ref_line = std::numeric_limits<int>::max() / 2;
    for (int line = lines - 1; line >= 0; --line) {  // backward, then decide
      LineState& s = lines_[line];
      Candidate* c = &candidates_[static_cast<size_t>(line) * max_candidates];
      if (!s.has_point) continue;
      if (!s.ambiguous) {
        ref_line = line;
        ref_position = position_of(line, s.chosen);
        continue;
      }
      int backward = -1;
      if (ref_line - line - 1 <= o.max_gap_lines)
        backward = pick_near(line, ref_position, ref_line - line);
      const int forward = s.forward_pick;
      const int pick = forward >= 0 && backward >= 0 ? (forward == backward ? forward : -1)
                                                     : (forward >= 0 ? forward : backward);
      if (backward >= 0 && pick >= 0) {
        ref_line = line;
        ref_position = position_of(line, pick);
      }
      if (pick < 0) {
        s.has_point = false;
        s.reason = StripeRejection::kDoublePeak;
        continue;
      }
      s.chosen = pick;
      ++counts.double_peaks_resolved;
      double strongest_other = 0.0;
      for (int i = 0; i < s.count; ++i) {
        if (i != pick && c[i].m.ok) strongest_other = std::max(strongest_other, c[i].m.contrast);
      }
      s.secondary_ratio = std::min(1.0, strongest_other / c[pick].m.contrast);
    }
  }

  // 5. Chains.
  {
    int chain = 0, chain_first = -1, chain_length = 0, previous = -1;
    double previous_position = 0.0;
    auto close_chain = [&](int last_line) {
      if (chain_first < 0 || chain_length >= o.min_chain_lines) return;
      for (int line = chain_first; line <= last_line; ++line) {
        LineState& s = lines_[line];
        if (s.has_point && s.chain == chain) {
          s.has_point = false;
          s.reason = StripeRejection::kIsolated;
        }
      }
    };
    for (int line = 0; line < lines; ++line) {
      LineState& s = lines_[line];
      if (!s.has_point) continue;
      const double position = position_of(line, s.chosen);
      const bool continues =
          previous >= 0 && line - previous - 1 <= o.max_gap_lines &&
          std::abs(position - previous_position) <= o.max_jump_px * (line - previous);
      if (!continues) {
        close_chain(previous);
        ++chain;
        chain_first = line;
        chain_length = 0;
      }
      s.chain = chain;
      ++chain_length;
      previous = line;
      previous_position = position;
    }
    close_chain(previous);
  }

  // 6. Points, counts, confidence.
  widths_.clear();
  int last_chain = -1, chain_number = -1;
  for (int line = 0; line < lines; ++line) {
    const LineState& s = lines_[line];
    if (s.has_point) {
      if (s.chain != last_chain) {
        last_chain = s.chain;
        ++chain_number;
      }
      const PeakMeasurement& m =
          candidates_[static_cast<size_t>(line) * max_candidates + s.chosen].m;
      StripePoint point;
      point.line = line;
      point.position = m.position;
      point.pixel =
          column_search ? Eigen::Vector2d(line, m.position) : Eigen::Vector2d(m.position, line);
      point.width_px = m.width;
      point.contrast = m.contrast;
      point.background = m.background;
      point.sigma_px = m.sigma;
      point.saturated_pixels = m.saturated;
      point.position_sigma_px = m.position_sigma;
      point.chain = chain_number;
      // Provisional: the factors that need no neighbours.
      double confidence = 1.0 - std::exp(-m.contrast / (2.0 * o.min_contrast));
      confidence *= 1.0 - s.secondary_ratio;
      const double precision = m.position_sigma / 0.05;
      confidence /= 1.0 + precision * precision;
      if (m.saturated > 0) confidence *= 0.5;
      if (m.fit_rms > 0.0) {
        const double relative = m.fit_rms / m.contrast;
        confidence *= std::exp(-0.5 * (relative / 0.1) * (relative / 0.1));
      }
      point.confidence = confidence;
      result->points.push_back(point);
      widths_.push_back(m.width);
      ++counts.found;
    } else if (s.count == 0) {
      ++counts.lines_without_candidate;
    } else {
      ++counts.rejected[static_cast<int>(s.reason)];
    }
  }
  std::vector<StripePoint>& points = result->points;
  if (points.empty()) return;
  std::nth_element(widths_.begin(), widths_.begin() + widths_.size() / 2, widths_.end());
  const double median_width = widths_[widths_.size() / 2];
  for (size_t i = 0; i < points.size(); ++i) {
    StripePoint& point = points[i];
    const double dw = (point.width_px - median_width) / (0.25 * median_width);
    point.confidence *= std::exp(-0.5 * dw * dw);
    if (i > 0 && i + 1 < points.size() && points[i - 1].chain == point.chain &&
        points[i + 1].chain == point.chain) {
      const StripePoint& a = points[i - 1];
      const StripePoint& b = points[i + 1];
      const double t = static_cast<double>(point.line - a.line) / (b.line - a.line);
      const double r = (point.position - (a.position + t * (b.position - a.position))) / 0.5;
      point.confidence *= std::exp(-0.5 * r * r);
    }
    point.confidence = std::clamp(point.confidence, 1e-6, 1.0);
  }
}

namespace {

// Weighted least squares of position = a0 + a1 t + a2 t², t = (line − centre) / half_length,
// over the points with |line − centre| <= half_length. Returns the number of points used (and
// on each side of the centre).
struct LocalFit {
  Eigen::Vector3d a = Eigen::Vector3d::Zero();
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  double centre = 0.0;
  double half_length = 1.0;
  int points = 0;
  int below = 0;
  int above = 0;
  double rms = 0.0;
  double Value(double line) const {
    const double t = (line - centre) / half_length;
    return a(0) + t * (a(1) + t * a(2));
  }
  double Slope(double line) const {
    const double t = (line - centre) / half_length;
    return (a(1) + 2.0 * t * a(2)) / half_length;
  }
  double Variance(double line) const {
    const double t = (line - centre) / half_length;
    const Eigen::Vector3d phi(1.0, t, t * t);
    return phi.dot(covariance * phi);
  }
};

// Only the chains of the points nearest the centre on either side take part: a step of the
// surface next to the crossing starts another chain and would bend the quadratic.
bool FitLocal(const std::vector<StripePoint>& points, double centre, double half_length,
              double exclusion, LocalFit* fit) {
  fit->centre = centre;
  fit->half_length = half_length;
  int chain_below = -1, chain_above = -1;
  double nearest_below = half_length + 1.0, nearest_above = half_length + 1.0;
  for (const StripePoint& p : points) {
    const double d = p.line - centre;
    if (d <= 0.0 && -d < nearest_below) {
      nearest_below = -d;
      chain_below = p.chain;
    } else if (d > 0.0 && d < nearest_above) {
      nearest_above = d;
      chain_above = p.chain;
    }
  }
  auto selected = [&](const StripePoint& p) {
    return std::abs(p.line - centre) <= half_length && std::abs(p.line - centre) >= exclusion &&
           (p.chain == chain_below || p.chain == chain_above);
  };
  Eigen::Matrix3d N = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
  int n = 0, below = 0, above = 0;
  for (const StripePoint& p : points) {
    if (!selected(p)) continue;
    const double t = (p.line - centre) / half_length;
    const Eigen::Vector3d phi(1.0, t, t * t);
    N.noalias() += p.confidence * phi * phi.transpose();
    b += p.confidence * p.position * phi;
    ++n;
    below += p.line < centre ? 1 : 0;
    above += p.line > centre ? 1 : 0;
  }
  fit->points = n;
  fit->below = below;
  fit->above = above;
  if (n < 4) return false;
  const Eigen::LDLT<Eigen::Matrix3d> ldlt(N);
  if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) return false;
  fit->a = ldlt.solve(b);
  double weighted = 0.0, plain = 0.0;
  for (const StripePoint& p : points) {
    if (!selected(p)) continue;
    const double r = p.position - fit->Value(p.line);
    weighted += p.confidence * r * r;
    plain += r * r;
  }
  fit->rms = std::sqrt(plain / n);
  fit->covariance = weighted / (n - 3) * ldlt.solve(Eigen::Matrix3d::Identity());
  return fit->a.allFinite();
}

}  // namespace

void LaserStripeExtractor::FindCrossing(LaserStripes* result) const {
  StripeCrossing& crossing = result->crossing;
  crossing = StripeCrossing{};
  if (!options_.search_fixed || !options_.search_rotating) return;                // kNotSearched
  const std::vector<StripePoint>& fixed = result->stripe(Stripe::kFixed).points;  // u(v)
  const std::vector<StripePoint>& rotating = result->stripe(Stripe::kRotating).points;  // v(u)
  const int min_points = options_.crossing_min_points;
  if (static_cast<int>(fixed.size()) < min_points ||
      static_cast<int>(rotating.size()) < min_points) {
    crossing.status = CrossingStatus::kStripeMissing;
    return;
  }
  // Start: the column of the fixed stripe's middle point and the row of the rotating stripe's
  // (in line order); each stripe runs roughly along its lines, and the local fits below move
  // the centre to the crossing.
  double u = fixed[fixed.size() / 2].position;
  double v = rotating[rotating.size() / 2].position;
  const double L = options_.crossing_fit_half_length_px;
  const int min_side = std::max(2, min_points / 4);
  LocalFit fit_f, fit_r;
  for (int iteration = 1; iteration <= 30; ++iteration) {
    crossing.iterations = iteration;
    const bool ok_r = FitLocal(rotating, u, L, options_.crossing_exclusion_px, &fit_r);
    const bool ok_f = FitLocal(fixed, v, L, options_.crossing_exclusion_px, &fit_f);
    crossing.rotating_points = fit_r.points;
    crossing.fixed_points = fit_f.points;
    if (fit_r.points < min_points || fit_f.points < min_points) {
      crossing.status = CrossingStatus::kTooFewPoints;
      return;
    }
    if (fit_r.below < min_side || fit_r.above < min_side || fit_f.below < min_side ||
        fit_f.above < min_side) {
      crossing.status = CrossingStatus::kOneSided;
      return;
    }
    if (!ok_r || !ok_f) {
      crossing.status = CrossingStatus::kNoIntersection;
      return;
    }
    // Newton on v = R(u), u = F(v).
    double uu = u, vv = v;
    bool solved = false;
    for (int step = 0; step < 30; ++step) {
      const double g1 = vv - fit_r.Value(uu);
      const double g2 = uu - fit_f.Value(vv);
      const double r1 = fit_r.Slope(uu), f1 = fit_f.Slope(vv);
      // J = ∂(g1, g2)/∂(u, v) = [[−R', 1], [1, −F']], det J = R'F' − 1; the step −J⁻¹ g.
      const double det = r1 * f1 - 1.0;
      if (std::abs(det) < 1e-6) break;  // the stripes are parallel here
      const double du = (f1 * g1 + g2) / det;
      const double dv = (g1 + r1 * g2) / det;
      uu += du;
      vv += dv;
      if (!std::isfinite(uu) || !std::isfinite(vv)) break;
      if (std::abs(du) + std::abs(dv) < 1e-9) {
        solved = true;
        break;
      }
    }
    if (!solved || uu < 0.0 || vv < 0.0 || uu > width_ - 1 || vv > height_ - 1) {
      crossing.status = CrossingStatus::kNoIntersection;
      return;
    }
    const double move = std::hypot(uu - u, vv - v);
    u = uu;
    v = vv;
    if (move < 1e-3) {
      crossing.status = CrossingStatus::kFound;
      crossing.pixel = Eigen::Vector2d(u, v);
      crossing.rotating_rms_px = fit_r.rms;
      crossing.fixed_rms_px = fit_f.rms;
      // dx = J⁻¹ (δR, δF) for errors δR, δF of the two fitted curves at the crossing.
      Eigen::Matrix2d J;
      J << -fit_r.Slope(u), 1.0, 1.0, -fit_f.Slope(v);
      const Eigen::Matrix2d Ji = J.inverse();
      const Eigen::Matrix2d S = Eigen::Vector2d(fit_r.Variance(u), fit_f.Variance(v)).asDiagonal();
      crossing.covariance = Ji * S * Ji.transpose();
      return;
    }
  }
  crossing.status = CrossingStatus::kNoConvergence;
}

void LaserStripeExtractor::Extract(const vision::ImageView8& image, LaserStripes* result) {
  if (image.data == nullptr)
    throw std::invalid_argument("LaserStripeExtractor: image data is null");
  if (image.stride < static_cast<size_t>(std::max(image.width, 0))) {
    throw std::invalid_argument("LaserStripeExtractor: image stride " +
                                std::to_string(image.stride) + " below its width " +
                                std::to_string(image.width));
  }
  if (result == nullptr) throw std::invalid_argument("LaserStripeExtractor: result is null");
  Reserve(image.width, image.height, result);
  for (Stripe s : {Stripe::kFixed, Stripe::kRotating}) {
    StripeResult& stripe = result->stripes[static_cast<int>(s)];
    const bool on = s == Stripe::kFixed ? options_.search_fixed : options_.search_rotating;
    if (on) {
      SearchStripe(image, s, &stripe);
    } else {
      stripe.points.clear();
      stripe.counts = StripeCounts{};
    }
  }
  FindCrossing(result);
}

}  // namespace kinevis::vision::laser
