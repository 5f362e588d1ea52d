#pragma once

// Synthetic chessboard images seen through a pinhole + Brown camera (vision/camera/
// pinhole_camera.h, OpenCV's model), for calibration tests. Deterministic: the same arguments
// give the same bytes.
//
// Board frame T: origin at the first inner corner, x along a row of inner corners (cols), y along
// a column (rows), z = x × y (into the board when its front faces the camera). Inner corner
// (i, j) is at (i s, j s, 0), i = 0..cols-1, j = 0..rows-1, s the square size (m): the order
// cv::findChessboardCorners reports for an upright board. The board has (cols+1) × (rows+1)
// squares spanning [-s, cols s] × [-s, rows s]; the square containing (0.5 s, 0.5 s) is black
// (so the top-left square at (-0.5 s, -0.5 s) is black too); a white margin of `margin_m` surrounds
// the squares; outside it the scene is a uniform grey background.
//
// Rendering: for each pixel the board coordinates are computed exactly at the pixel's four
// corners — undistort (cv::undistortPoints, iterated to 1e-12, each result checked by
// re-projecting it with cv::projectPoints), ray from the optical centre, intersection with the
// board plane — and interpolated bilinearly inside the pixel, where n × n samples are classified
// black / white / background and averaged (anti-aliasing). The bilinear error inside one pixel is
// of order 1e-4 px for the lenses in the tests (second derivative of the distortion over one
// pixel h: about f · 6|k1| r · h² / 8). Then an optional Gaussian blur (optics) and optional
// Gaussian grey-level noise from a seeded std::mt19937.

#include <Eigen/Geometry>
#include <cstdint>
#include <vector>

#include "vision/camera/pinhole_camera.h"

namespace kinevis::testing {

struct ChessboardTarget {
  int cols = 9;  // inner corners per row
  int rows = 6;  // inner corners per column
  double square_m = 0.025;
  double margin_m = 0.025;  // white border around the squares
};

struct RenderOptions {
  int samples_per_axis = 16;  // n: n × n samples per pixel, >= 1
  double black = 30.0;        // grey levels (0..255) of the squares, the margin, the background
  double white = 225.0;
  double background = 110.0;
  // Optics blur: Gaussian point-spread function, standard deviation in pixels (0: none), applied
  // before the noise (cv::GaussianBlur, kernel ±4σ, border replicated).
  double blur_sigma_px = 0.0;
  double noise_sigma = 0.0;  // standard deviation of added Gaussian noise (grey levels)
  unsigned noise_seed = 1;
};

// An 8-bit grey image, row-major, pixels[v * width + u].
struct GreyImage {
  int width = 0;
  int height = 0;
  std::vector<std::uint8_t> pixels;
};

// Renders the board at pose X_CT (pose of T in the camera frame C) through `camera` (image size
// camera.width × camera.height). Throws std::runtime_error if the undistortion of some pixel
// corner does not re-project within 1e-6 px (the lens folds over inside the image).
GreyImage RenderChessboard(const vision::PinholeBrownParameters& camera,
                           const Eigen::Isometry3d& X_CT, const ChessboardTarget& target,
                           const RenderOptions& options = {});

// An image with no board: the background with a few grey blobs and the noise of `options`.
GreyImage RenderEmptyScene(int width, int height, const RenderOptions& options = {});

// Projects the inner corners of `target` at X_CT with cv::projectPoints (board order, see above).
std::vector<Eigen::Vector2d> ProjectInnerCorners(const vision::PinholeBrownParameters& camera,
                                                 const Eigen::Isometry3d& X_CT,
                                                 const ChessboardTarget& target);

// `count` board poses for a calibration: the whole board (with margin, plus `border_px`) inside
// the image, the board centre at a distance where it spans 30–60 % of the image width, tilted
// 10°–45° about a random in-plane axis, rotated in-plane by at most ±20°, centred in the 9 cells
// of a 3 × 3 grid in turn and pushed towards the image edge of its cell as far as it fits, so that
// the corners cover the image. Poses whose squares would be narrower than 12 px or sheared beyond
// 55°–125° are rejected (findChessboardCorners fails on them). Deterministic for a given seed.
std::vector<Eigen::Isometry3d> CalibrationPoses(const vision::PinholeBrownParameters& camera,
                                                const ChessboardTarget& target, int count,
                                                unsigned seed, double border_px = 10.0);

}  // namespace kinevis::testing
