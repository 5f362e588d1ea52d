#pragma once

// Sub-pixel detection of the DIAMOND tool marker (seed 001 §V-A, issue 8): the X-corner (saddle
// point) at the centre of the four-quadrant plate of vision/render/scenes/diamond_marker_scene.h,
// whose image is exactly the projection of the tool point T.
//
// Algorithm (the seed finds its marker with OpenCV's Harris corners; we do the same, then verify
// and refine):
//  1. Region: a square of ±search_half_window_px around a prediction when one is given (the last
//     detection, or the model's projection of the commanded joints), else the whole image.
//  2. Candidates: Harris response (cv::cornerHarris) in the region, non-maximum suppression, the
//     max_candidates strongest peaks above candidate_fraction of the strongest.
//  3. Refinement: cv::cornerSubPix (gradient orthogonality, ±refine_half_window_px), then an
//     iterated saddle-point fit: a quadric fitted by least squares to 5×5 samples of the
//     Gaussian-smoothed (σ = 1 px) image centred on the estimate, moved to its stationary point
//     until the step is below 1e-4 px (kept when it is a saddle and within 1 px of
//     cornerSubPix's point). On ideal area-sampled X-corners cornerSubPix alone leaves 0.07 px
//     mean, 0.11 px worst; the saddle iteration 0.011 / 0.021 px (measured).
//  4. Verification: intensities on a ring of ring_radius_px about the refined point must show the
//     X pattern: exactly four alternating bright / dark runs, each at least 45° long, bright runs
//     similar, dark runs similar. contrast = mean(bright) − mean(dark) (grey levels);
//     confidence = symmetry × contrast / (contrast + 3 σ_ring) in [0, 1], σ_ring the spread of
//     the samples inside the runs (noise, blur, a partly occluded quadrant lower it).
//  The best verified candidate (highest confidence) is the detection. Nothing verifies → not
//  found: the marker is absent, occluded across its centre, too close to the image border for
//  the ring, or too weak; the status says which. Never a guess.
//
// Units: pixels (OpenCV convention, camera_model.h: (0, 0) the centre of the top-left pixel),
// grey levels 0..255. Accuracy on rendered images (tests/vision/diamond/marker_detector_test.cc,
// docs/diamond-control.md): ≤ 0.04 px worst with 16× edge supersampling; with the worlds' 4×
// the renderer's own edge quantisation (≤ 1/8 px per edge) dominates (≤ 0.13 px worst).
// Thread-compatible: one detector per thread (it keeps scratch buffers); Detect() allocates only
// when the region grows.

#include <Eigen/Core>
#include <memory>
#include <string>

#include "vision/image/image_view.h"

namespace kinevis::vision {

struct MarkerDetectorOptions {
  // Half size of the search region around a prediction (px), >= ring_radius_px + 4.
  int search_half_window_px = 40;
  // Harris: block size (odd, 3..15), Sobel aperture (3, 5 or 7), k in (0, 0.25).
  int harris_block_size = 5;
  int harris_aperture = 3;
  double harris_k = 0.04;
  // Candidates kept after non-maximum suppression, 1..64, and their least response relative to
  // the strongest one in the region, in (0, 1).
  int max_candidates = 12;
  double candidate_fraction = 0.05;
  // cv::cornerSubPix half window (px), 2..20: must stay inside the marker's plate (smaller than
  // its half side in the image), or the outer edges pull the point.
  int refine_half_window_px = 4;
  // Radius of the verification ring (px), 3..50: inside the plate's image (smaller than its half
  // side in px), outside the blur of the centre.
  double ring_radius_px = 6.0;
  // Least contrast between bright and dark runs (grey levels), > 0; least confidence, [0, 1].
  double min_contrast = 30.0;
  double min_confidence = 0.5;

  // Empty when usable; otherwise every bad field and its value.
  std::string Validate() const;
};

enum class MarkerStatus {
  kFound,
  kNotFound,      // candidates, but none shows the X pattern (absent, occluded, too weak)
  kNoCorner,      // no Harris response at all in the region (uniform region)
  kOutsideImage,  // the prediction's search region does not overlap the image enough
  kNearBorder,    // the only X-like candidates are too close to the border for the ring
  kInvalidImage,  // null data, non-positive size or stride < width
};
const char* ToString(MarkerStatus status);

struct MarkerDetection {
  MarkerStatus status = MarkerStatus::kNotFound;
  Eigen::Vector2d pixel = Eigen::Vector2d::Zero();  // the marker centre (px), valid when found
  double confidence = 0.0;                          // [0, 1], 0 unless found
  double contrast = 0.0;                            // grey levels (best candidate's)
  int candidates = 0;                               // Harris peaks examined
  bool found() const { return status == MarkerStatus::kFound; }
};

class MarkerDetector {
 public:
  // Throws std::invalid_argument with options.Validate()'s message.
  explicit MarkerDetector(MarkerDetectorOptions options = {});
  ~MarkerDetector();
  MarkerDetector(MarkerDetector&&) noexcept;
  MarkerDetector& operator=(MarkerDetector&&) noexcept;

  const MarkerDetectorOptions& options() const { return options_; }

  // Detects the marker in an 8-bit grey image (not modified). prediction (px, may be null): where
  // to search (±search_half_window_px); null searches the whole image. Never throws.
  MarkerDetection Detect(const vision::ImageView8& image,
                         const Eigen::Vector2d* prediction = nullptr);

 private:
  struct Scratch;
  MarkerDetectorOptions options_;
  std::unique_ptr<Scratch> scratch_;
};

}  // namespace kinevis::vision
