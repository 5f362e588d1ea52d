#pragma once

// Sub-pixel laser stripe extraction for the weld cell's triangulation scanner (issue 7,
// "Scanner" bullet 1; seed 004 §2–3: a camera and two laser line projectors, one fixed, one
// rotating). Input: an 8-bit grey image (vision::ImageView8) with the stripe of the rotating laser
// running roughly along the image rows (searched per COLUMN), the stripe of the fixed laser
// roughly along the columns (searched per ROW), either or both switched on. Output: one sub-pixel
// point per searched line and laser at most, with its width, contrast and a confidence, counts of
// what was rejected and why, and the sub-pixel intersection of the two stripes.
//
// Pixels as in camera_model.h: (u, v), u to the right, v down, (0, 0) the centre of the top-left
// pixel. All positions, widths and tolerances below are in pixels (px) of the image given;
// intensities in grey levels (0..255). The algorithm, its options and the accuracy measured on
// rendered seed-004 images are in docs/laser-stripes.md.
//
// Per search line (a column for the rotating laser, a row for the fixed one):
//  1. Candidates: pixels standing at least 0.8 · min_contrast above BOTH pixels
//     background_offset_px away along the line (a ridge test on single pixels, looser than the
//     contrast test of step 2 so that flank noise does not hide a peak; a run of such pixels is
//     one candidate). A line through the other laser's stripe is bright over a long run and has
//     no ridge there.
//  2. Per candidate: the peak pixel, the local background (a straight line through the means of
//     two flank windows beyond background_offset_px on either side), the contrast above it, the
//     support (pixels above background + threshold_fraction · contrast), the width (full width at
//     half the contrast, interpolated), saturated pixels, and the orientation test (the profile
//     must be narrower along this line than across it, otherwise it belongs to the other laser's
//     search). Rejected with a reason (StripeRejection) when one fails.
//  3. Sub-pixel centre by the chosen PeakLocator (centre of gravity, 3-point Gaussian or a
//     Levenberg–Marquardt Gaussian fit).
//  4. Per line: the strongest candidate, unless a second one is comparable (double peak / specular
//     reflection), which continuity with the neighbouring lines resolves or the line is rejected.
//  5. Continuity: points are chained across lines (jump <= max_jump_px per line, gaps of up to
//     max_gap_lines); chains shorter than min_chain_lines are rejected as isolated.
//  6. Confidence per point; the crossing: local quadratic fits of both stripes around it (each
//     to the chains nearest the crossing on either side, so that a step of the surface next to
//     it does not bend the fit), intersected, with its covariance from the fits.
//
// Cost and allocation: LaserStripeExtractor::Extract() does not allocate once the extractor has
// seen an image of that size and the result has been through one Extract() (or Reserve()) at
// that size: scratch lives in the extractor, points in the caller's LaserStripes (vector
// capacities are kept). One extractor per thread; distinct extractors may run in parallel.

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "vision/image/image_view.h"

namespace kinevis::vision::laser {

// Which stripe. Index into LaserStripes::stripes (the same order as render::LaserId).
enum class Stripe {
  kFixed = 0,     // the fixed laser: roughly along the columns, searched per row
  kRotating = 1,  // the rotating laser: roughly along the rows, searched per column
};
inline constexpr int kStripeCount = 2;

// How the sub-pixel centre of a peak is located along its search line.
enum class PeakLocator {
  // Centre of gravity of (g − background − threshold_fraction · contrast) over the support:
  // weights fall to zero at the support's ends, which keeps the truncation bias small. Saturated
  // pixels enter with their clipped value (a symmetric clip does not move the centre).
  kCentreOfGravity,
  // Vertex of the parabola through ln(g − background) at the peak pixel and its two neighbours:
  // exact for a point-sampled Gaussian. Falls back to the centre of gravity when one of the
  // three is saturated or not above the background.
  kGaussian3Point,
  // Levenberg–Marquardt least squares of A exp(−(x − μ)² / (2 s²)) to (g − background) over the
  // support widened by 2 px on each side, saturated pixels left out (they only bound the value
  // from below), started from the 3-point estimate. The most robust to saturation, ~3× slower.
  kGaussianFit,
};

// Why a candidate (or a line) was rejected. kCount is the number of reasons.
enum class StripeRejection {
  kBorder = 0,   // too close to the image border for the flank windows
  kLowContrast,  // peak − local background < min_contrast
  kTooNarrow,    // width < min_width_px: a hot pixel or a noise spike
  kTooWide,      // the support reaches background_offset_px or width > max_width_px
  kSaturated,    // more than max_saturated_pixels saturated pixels in the support
  kOtherLaser,   // wider along this line than across it: the other laser's stripe
  kFitFailed,    // kGaussianFit did not converge to a plausible peak
  kDoublePeak,   // two comparable peaks on the line that continuity could not tell apart
  kCluttered,    // more than max_candidates_per_line candidates on the line
  kIsolated,     // not part of a chain of at least min_chain_lines lines
  kCount,
};
inline constexpr int kStripeRejectionCount = static_cast<int>(StripeRejection::kCount);
// "border", "low contrast", "too narrow", "too wide", "saturated", "other laser", "fit failed",
// "double peak", "cluttered", "isolated".
const char* ToString(StripeRejection reason);

struct LaserStripeOptions {
  // Which stripes to search (an image with one laser off may still search both: the other then
  // finds nothing; switching it off saves its time).
  bool search_fixed = true;
  bool search_rotating = true;
  // Ridge test and local background: a candidate pixel exceeds both pixels background_offset_px
  // away along the line by >= min_contrast; the background is a straight line through the means
  // of the background_window_px pixels starting background_offset_px from the peak on either
  // side. background_offset_px in [2, 32] must exceed the stripe's half support (a stripe up to
  // ~2·offset − 2 px wide is measured); background_window_px in [1, 16].
  int background_offset_px = 8;
  int background_window_px = 3;
  // Smallest peak height above the local background (grey levels), in [1, 254]. With image noise
  // σ_n keep it >= 6 σ_n.
  double min_contrast = 30.0;
  // Support of a peak: the contiguous pixels around it above background + threshold_fraction ·
  // contrast; in [0.05, 0.9]. Also the zero level of the centre-of-gravity weights.
  double threshold_fraction = 0.2;
  // Accepted full width at half the contrast along the search line (px): [min, max] with
  // 0.5 <= min_width_px < max_width_px <= 2 · background_offset_px.
  double min_width_px = 1.2;
  double max_width_px = 12.0;
  // A pixel at or above saturation_level (grey level, [1, 255]) is saturated; a candidate with
  // more than max_saturated_pixels ([0, 32]) of them in its support is rejected.
  int saturation_level = 255;
  int max_saturated_pixels = 3;
  PeakLocator locator = PeakLocator::kGaussian3Point;
  // kGaussianFit: iterations [1, 100] and the convergence tolerance on the centre (px, > 0).
  int fit_max_iterations = 10;
  double fit_tolerance_px = 1e-4;
  // Candidates kept per line, [1, 16]; a line with more is rejected as cluttered.
  int max_candidates_per_line = 4;
  // A second candidate whose contrast is at least double_peak_ratio ((0, 1]) of the strongest's
  // makes the line ambiguous (resolved by continuity, else kDoublePeak); a weaker one is ignored
  // (and lowers the confidence).
  double double_peak_ratio = 0.5;
  // Continuity: consecutive points of a chain differ by at most max_jump_px (> 0) per line of
  // distance, across gaps of at most max_gap_lines ([0, 64]) lines without a point; chains of
  // fewer than min_chain_lines ([1, 1000]) points are rejected as isolated.
  double max_jump_px = 2.0;
  int max_gap_lines = 3;
  int min_chain_lines = 5;
  // Crossing: each stripe is fitted (quadratic in the line coordinate, weighted by confidence)
  // over its points within crossing_fit_half_length_px (lines, [4, 2000]) of the crossing; at
  // least crossing_min_points ([3, 1000]) points per stripe, on both sides of the crossing.
  int crossing_fit_half_length_px = 60;
  int crossing_min_points = 10;
  // Points within this many lines of the crossing ([0, crossing_fit_half_length_px)) are left out
  // of the fits: the other stripe's tail lies under them.
  int crossing_exclusion_px = 6;

  // Empty when usable, otherwise one message naming every bad field and its value.
  std::string Validate() const;
};

// One stripe point.
struct StripePoint {
  Eigen::Vector2d pixel = Eigen::Vector2d::Zero();  // (u, v) sub-pixel along the search line
  int line = 0;                                     // the column (rotating) or row (fixed) searched
  double position = 0.0;    // sub-pixel coordinate along the line: v (rotating) or u (fixed)
  double width_px = 0.0;    // full width at half the contrast, along the line (px)
  double contrast = 0.0;    // peak grey level above the local background (clipped if saturated)
  double background = 0.0;  // local background at the centre (grey levels)
  double sigma_px = 0.0;    // kGaussianFit: the fitted s (px); otherwise width_px / 2.3548
  int saturated_pixels = 0;
  // 1-σ uncertainty of `position` (px) from the image noise: σ_n (grey levels, the scatter of the
  // flank windows' pixels about their means, 2 (background_window_px − 1) degrees of freedom)
  // propagated through the centre of gravity, σ_n √Σ(x − c)² / Σw. 0 when
  // background_window_px = 1 (no estimate).
  double position_sigma_px = 0.0;
  // The continuous chain (step 5) the point belongs to, numbered from 0 in line order: a new
  // chain starts at a jump (a step of the surface, an occlusion) or a gap of more lines.
  int chain = 0;
  // Heuristic in (0, 1]: product of factors for contrast (1 − exp(−contrast / (2 min_contrast))),
  // precision (1 / (1 + (position_sigma_px / 0.05 px)²)), width agreement with the stripe's median
  // width, a weaker second peak on the line (1 − its relative contrast), saturation (× 0.5) and
  // agreement with the neighbouring points (Gaussian in the deviation from their mean, scale 0.5
  // px). 1 = clean.
  double confidence = 0.0;
};

// What the search of one stripe did. Every searched line ends in exactly one state:
// lines_searched == lines_without_candidate + found + Σ rejected[reason].
struct StripeCounts {
  int lines_searched = 0;           // columns (rotating) or rows (fixed) scanned
  int lines_without_candidate = 0;  // no ridge at all
  int found = 0;                    // lines with an accepted point (== points.size())
  // Lines without a point, by the reason of their strongest candidate (or of the line).
  std::array<int, kStripeRejectionCount> rejected{};
  int candidates = 0;               // candidates examined, over all lines
  int secondary_peaks_ignored = 0;  // lines whose weaker second peak was ignored
  int double_peaks_resolved = 0;    // ambiguous lines resolved by continuity
  int rejected_total() const;
};

struct StripeResult {
  std::vector<StripePoint> points;  // in increasing line order
  StripeCounts counts;
};

enum class CrossingStatus {
  kFound,
  kNotSearched,     // a stripe's search was off
  kStripeMissing,   // a stripe has fewer than crossing_min_points points
  kNoIntersection,  // the stripes' fits do not meet inside the image
  kTooFewPoints,    // fewer than crossing_min_points points of a stripe near the crossing
  kOneSided,        // a stripe's points near the crossing are all on one side of it
  kNoConvergence,   // the local fits and their intersection did not settle
};
const char* ToString(CrossingStatus status);

// The intersection of the two stripes (seed 004 §2, P_int, "(x_int, y_int)" of eq. (7), (11)).
struct StripeCrossing {
  CrossingStatus status = CrossingStatus::kNotSearched;
  Eigen::Vector2d pixel = Eigen::Vector2d::Constant(0.0);  // (u, v) px; valid when kFound
  // Covariance of pixel (px²) from the two fits' parameter covariances (residual-scaled).
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Zero();
  int fixed_points = 0;  // points used in each local fit
  int rotating_points = 0;
  double fixed_rms_px = 0.0;  // RMS residual of each fit along its search line
  double rotating_rms_px = 0.0;
  int iterations = 0;
  bool found() const { return status == CrossingStatus::kFound; }
};

struct LaserStripes {
  std::array<StripeResult, kStripeCount> stripes;  // indexed by Stripe
  StripeCrossing crossing;
  const StripeResult& stripe(Stripe s) const { return stripes[static_cast<int>(s)]; }
};

class LaserStripeExtractor {
 public:
  // Throws std::invalid_argument naming every bad option (LaserStripeOptions::Validate()).
  explicit LaserStripeExtractor(const LaserStripeOptions& options);
  ~LaserStripeExtractor();
  LaserStripeExtractor(LaserStripeExtractor&&) noexcept;
  LaserStripeExtractor& operator=(LaserStripeExtractor&&) noexcept;

  const LaserStripeOptions& options() const { return options_; }

  // Sizes the scratch for width × height images and the result's point vectors; then Extract()
  // at that size does not allocate. Throws std::invalid_argument for a size outside
  // [1, 16384]².
  void Reserve(int width, int height, LaserStripes* result);

  // Extracts both stripes (those enabled) and their crossing from `image` into *result (cleared
  // first). Throws std::invalid_argument for a null image, a size outside [1, 16384]² or a stride
  // below the width. An image with no stripe gives no points (counts say why), not an error.
  void Extract(const vision::ImageView8& image, LaserStripes* result);

 private:
  struct Candidate;
  struct LineState;
  void SearchStripe(const vision::ImageView8& image, Stripe stripe, StripeResult* result);
  void FindCrossing(LaserStripes* result) const;

  LaserStripeOptions options_;
  int width_ = 0;
  int height_ = 0;
  std::vector<Candidate> candidates_;  // max_candidates_per_line per line
  std::vector<LineState> lines_;
  std::vector<int> run_start_;  // per column, column search: start row of the open ridge run
  std::vector<int> run_last_;   // per column: last row of the open ridge run (−2 = none)
  std::vector<uint8_t> mask_;   // one row of the ridge test
  std::vector<double> widths_;  // scratch for the median width
};

// The Gaussian profile of kGaussianFit: value A exp(−(x − μ)² / (2 s²)) at x (px) and, when
// `jacobian` is not null, its derivatives with respect to (A, μ, s). No check on s (must be > 0).
// Exposed for the finite-difference test of the analytic Jacobian.
double GaussianProfile(double amplitude, double centre, double sigma, double x,
                       Eigen::Vector3d* jacobian);

}  // namespace kinevis::vision::laser
