// Chessboard calibration against synthetic images rendered through a known pinhole + Brown
// camera (tests/utilities/chessboard_images.h): recovery of the intrinsics, refused images named,
// too few images reported, degenerate data warned about, overlays written.

#include "calibration/camera/chessboard_calibration.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "common/units.h"
#include "tests/utilities/chessboard_images.h"

namespace kinevis::calibration {
namespace {

using testing::ChessboardTarget;
using ::testing::ContainsRegex;
using testing::GreyImage;
using ::testing::HasSubstr;

constexpr unsigned kPoseSeed = 7;

vision::PinholeBrownParameters TrueCamera() {
  vision::PinholeBrownParameters c;
  c.width = 640;
  c.height = 480;
  c.fx = 602.5;
  c.fy = 598.0;
  c.cx = 322.4;
  c.cy = 236.8;
  c.distortion = {-0.25, 0.08, 4e-4, -3e-4, 0, 0, 0, 0};
  return c;
}

CalibrationImage ToCalibrationImage(const GreyImage& g, const std::string& name) {
  return {name, g.width, g.height, g.pixels};
}

ChessboardCalibrationOptions Options() {
  ChessboardCalibrationOptions o;
  o.board_cols = 9;
  o.board_rows = 6;
  o.square_m = 0.025;
  return o;
}

// A sharp lens: Gaussian point-spread function of σ = 0.8 px, 16 × 16 samples per pixel.
testing::RenderOptions Rendering() {
  testing::RenderOptions o;
  o.samples_per_axis = 16;
  o.blur_sigma_px = 0.8;
  return o;
}

// 18 views with good spread (rendered once, shared by the tests).
const std::vector<CalibrationImage>& GoodViews() {
  static const std::vector<CalibrationImage> views = [] {
    std::vector<CalibrationImage> out;
    const ChessboardTarget target;
    const auto poses = testing::CalibrationPoses(TrueCamera(), target, 18, kPoseSeed);
    const testing::RenderOptions ro = Rendering();
    for (size_t k = 0; k < poses.size(); ++k) {
      out.push_back(
          ToCalibrationImage(testing::RenderChessboard(TrueCamera(), poses[k], target, ro),
                             "view" + std::to_string(k) + ".png"));
    }
    return out;
  }();
  return views;
}

// Measured with kPoseSeed = 7: Δfx 0.37, Δfy 0.40, Δcx -0.27, Δcy 0.01 px, Δk1 2e-4, Δk2 -9e-4,
// Δp1,2 < 2e-5, RMS 0.030 px, σ(fx) 0.41 px; detected corners vs truth RMS 0.030 px. Over seeds
// 1–8 the largest |Δ| of fx, fy, cx, cy was 0.71 px, |Δk1| 1.2e-3, |Δk2| 2.6e-3, |Δp| 1.1e-4.
// Margins: ~3× the seed-7 error for the pinhole parameters (1.2 px = 0.2 % of f), and above the
// spread over seeds for the distortion. The error is the corner detector's (cornerSubPix on a
// blurred, anti-aliased edge), not noise: the images are noiseless.
TEST(ChessboardCalibrationTest, RecoversIntrinsicsFromNoiselessImages) {
  const ChessboardCalibrationResult r = CalibrateChessboard(GoodViews(), Options());
  ASSERT_TRUE(r.calibrated) << r.message;
  const vision::PinholeBrownParameters t = TrueCamera();
  const vision::PinholeBrownParameters& e = r.parameters;
  std::printf(
      "error fx %.4f fy %.4f cx %.4f cy %.4f k1 %.2e k2 %.2e p1 %.2e p2 %.2e px; "
      "rms %.4f px; std fx %.3f cx %.3f; coverage %.2f; max tilt %.1f deg\n",
      e.fx - t.fx, e.fy - t.fy, e.cx - t.cx, e.cy - t.cy, e.distortion[0] - t.distortion[0],
      e.distortion[1] - t.distortion[1], e.distortion[2] - t.distortion[2],
      e.distortion[3] - t.distortion[3], r.rms_px, r.stddev.fx, r.stddev.cx, r.coverage,
      r.max_tilt_rad * 180 / common::kPi);
  EXPECT_EQ(e.width, 640);
  EXPECT_EQ(e.height, 480);
  EXPECT_NEAR(e.fx, t.fx, 1.2);
  EXPECT_NEAR(e.fy, t.fy, 1.2);
  EXPECT_NEAR(e.cx, t.cx, 1.2);
  EXPECT_NEAR(e.cy, t.cy, 1.2);
  EXPECT_NEAR(e.distortion[0], t.distortion[0], 3e-3);
  EXPECT_NEAR(e.distortion[1], t.distortion[1], 6e-3);
  EXPECT_NEAR(e.distortion[2], t.distortion[2], 3e-4);
  EXPECT_NEAR(e.distortion[3], t.distortion[3], 3e-4);
  // The reported standard deviations are honest: every error within 3σ.
  EXPECT_LT(std::abs(e.fx - t.fx), 3 * r.stddev.fx);
  EXPECT_LT(std::abs(e.fy - t.fy), 3 * r.stddev.fy);
  EXPECT_LT(std::abs(e.cx - t.cx), 3 * r.stddev.cx);
  EXPECT_LT(std::abs(e.cy - t.cy), 3 * r.stddev.cy);
  EXPECT_LT(std::abs(e.distortion[0] - t.distortion[0]), 3 * r.stddev.distortion[0]);
  EXPECT_EQ(e.distortion[4], 0.0);  // k3 fixed by default
  EXPECT_LT(r.rms_px, 0.1);
  EXPECT_EQ(r.used_images, 18);
  for (const ImageReport& image : r.images) {
    EXPECT_EQ(image.status, ImageStatus::kUsed) << image.name;
    EXPECT_LT(image.rms_px, 0.1) << image.name;
    EXPECT_LT(image.max_px, 0.3) << image.name;
    EXPECT_GE(image.rms_px, 0.0);
    EXPECT_EQ(image.corners_px.size(), 54u);
    EXPECT_EQ(image.reprojected_px.size(), 54u);
  }
  EXPECT_GT(r.coverage, 0.5);
  EXPECT_TRUE(r.warnings.empty()) << r.warnings.front();
  // Standard deviations are reported for the free parameters and zero for k3.
  EXPECT_GT(r.stddev.fx, 0.0);
  EXPECT_LT(r.stddev.fx, 1.0);
  EXPECT_GT(r.stddev.distortion[0], 0.0);
  EXPECT_EQ(r.stddev.distortion[4], 0.0);
}

// Sensor noise (σ = 2 grey levels on a 30..225 contrast): the errors grow but stay within 3σ of
// the reported standard deviations.
TEST(ChessboardCalibrationTest, NoisyImagesStayWithinTheReportedUncertainty) {
  const ChessboardTarget target;
  const auto poses = testing::CalibrationPoses(TrueCamera(), target, 18, kPoseSeed);
  std::vector<CalibrationImage> views;
  testing::RenderOptions noisy = Rendering();
  noisy.noise_sigma = 2.0;
  for (size_t k = 0; k < poses.size(); ++k) {
    noisy.noise_seed = 100 + static_cast<unsigned>(k);
    views.push_back(
        ToCalibrationImage(testing::RenderChessboard(TrueCamera(), poses[k], target, noisy),
                           "noisy" + std::to_string(k)));
  }
  const ChessboardCalibrationResult r = CalibrateChessboard(views, Options());
  ASSERT_TRUE(r.calibrated) << r.message;
  const vision::PinholeBrownParameters t = TrueCamera();
  const vision::PinholeBrownParameters& e = r.parameters;
  std::printf(
      "noisy: error fx %.4f fy %.4f cx %.4f cy %.4f px, k1 %.2e; rms %.4f px; std fx %.3f\n",
      e.fx - t.fx, e.fy - t.fy, e.cx - t.cx, e.cy - t.cy, e.distortion[0] - t.distortion[0],
      r.rms_px, r.stddev.fx);
  EXPECT_EQ(r.used_images, 18);
  EXPECT_LT(r.rms_px, 0.1);
  EXPECT_LT(std::abs(e.fx - t.fx), 3 * r.stddev.fx);
  EXPECT_LT(std::abs(e.fy - t.fy), 3 * r.stddev.fy);
  EXPECT_LT(std::abs(e.cx - t.cx), 3 * r.stddev.cx);
  EXPECT_LT(std::abs(e.cy - t.cy), 3 * r.stddev.cy);
  // The contract's σ (one identifiability analysis of the reprojection Jacobian from
  // cv::projectPoints) agree with cv::calibrateCamera's own standard deviations up to OpenCV's
  // degrees of freedom: it divides Σ r² by (points − parameters), where there are two residuals
  // per point, so its σ are larger by √((2N − p)/(N − p)) (≈ 1.46 here).
  const EstimationReport& c = r.estimation;
  EXPECT_EQ(c.Validate(), "");
  EXPECT_EQ(c.status, EstimationStatus::kConverged);
  const double points = c.residuals[0].count / 2.0;
  const double parameters = c.identifiability.rank;
  const double opencv = std::sqrt((2 * points - parameters) / (points - parameters));
  EXPECT_NEAR(opencv * c.Find("fx")->sigma, r.stddev.fx, 0.01 * r.stddev.fx);
  EXPECT_NEAR(opencv * c.Find("cy")->sigma, r.stddev.cy, 0.01 * r.stddev.cy);
  EXPECT_NEAR(opencv * c.Find("k1")->sigma, r.stddev.distortion[0], 0.01 * r.stddev.distortion[0]);
  EXPECT_FALSE(c.Find("k3")->estimated);  // Options() keeps fix_k3
  EXPECT_EQ(c.Find("k3")->sigma, 0.0);
  EXPECT_EQ(c.Find("fx")->unit, "px");
  EXPECT_EQ(c.identifiability.rank, c.identifiability.parameters);
  EXPECT_NEAR(c.residuals[0].rms * std::sqrt(2.0), r.rms_px, 1e-9);
}

// The pose of each board is recovered too (up to the 180° ambiguity of an odd × even board's
// corner order, which the test resolves by trying both).
TEST(ChessboardCalibrationTest, RecoversBoardPoses) {
  const ChessboardTarget target;
  const auto poses = testing::CalibrationPoses(TrueCamera(), target, 18, kPoseSeed);
  const ChessboardCalibrationResult r = CalibrateChessboard(GoodViews(), Options());
  ASSERT_TRUE(r.calibrated);
  // Rotating T by 180° about its z axis through the board centre relabels the corners in
  // reverse order.
  Eigen::Isometry3d flip = Eigen::Isometry3d::Identity();
  flip.linear() = Eigen::AngleAxisd(common::kPi, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  flip.translation() = Eigen::Vector3d(8 * 0.025, 5 * 0.025, 0);
  double worst_mm = 0;
  for (size_t k = 0; k < poses.size(); ++k) {
    const Eigen::Isometry3d& X = r.images[k].X_CT;
    const double direct = (X.translation() - poses[k].translation()).norm();
    const double flipped = (X.translation() - (poses[k] * flip).translation()).norm();
    worst_mm = std::max(worst_mm, 1000 * std::min(direct, flipped));
  }
  std::printf("worst board position error %.3f mm\n", worst_mm);
  EXPECT_LT(worst_mm, 2.5);  // measured 0.87 mm (board 0.3–0.8 m away)
}

// The detector against the renderer's ground truth: the corners of every view, compared with
// their true projections (either corner order).
TEST(ChessboardCalibrationTest, DetectedCornersMatchTrueProjections) {
  const ChessboardTarget target;
  const auto poses = testing::CalibrationPoses(TrueCamera(), target, 18, kPoseSeed);
  const ChessboardCalibrationResult r = CalibrateChessboard(GoodViews(), Options());
  ASSERT_TRUE(r.calibrated);
  double sum_sq = 0, worst = 0;
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  int n = 0;
  for (size_t k = 0; k < poses.size(); ++k) {
    const auto truth = testing::ProjectInnerCorners(TrueCamera(), poses[k], target);
    const auto& found = r.images[k].corners_px;
    ASSERT_EQ(found.size(), truth.size());
    double direct = 0, reversed = 0;
    for (size_t i = 0; i < truth.size(); ++i) {
      direct += (found[i] - truth[i]).squaredNorm();
      reversed += (found[i] - truth[truth.size() - 1 - i]).squaredNorm();
    }
    for (size_t i = 0; i < truth.size(); ++i) {
      const Eigen::Vector2d e = found[i] - truth[direct <= reversed ? i : truth.size() - 1 - i];
      sum_sq += e.squaredNorm();
      worst = std::max(worst, e.norm());
      mean += e;
      ++n;
    }
  }
  mean /= n;
  const double rms = std::sqrt(sum_sq / n);
  std::printf("corner error vs truth: rms %.4f px, max %.4f px, mean (%.4f, %.4f) px\n", rms, worst,
              mean.x(), mean.y());
  EXPECT_LT(rms, 0.1);
  EXPECT_LT(worst, 0.3);
  EXPECT_LT(mean.norm(), 0.02);  // no half-pixel convention error
}

TEST(ChessboardCalibrationTest, ImageWithoutBoardAndImageOfAnotherSizeAreRefusedByName) {
  std::vector<CalibrationImage> images(GoodViews().begin(), GoodViews().begin() + 6);
  images.insert(images.begin() + 2,
                ToCalibrationImage(testing::RenderEmptyScene(640, 480), "no_board.png"));
  vision::PinholeBrownParameters small = TrueCamera();
  small.width = 320;
  small.height = 240;
  small.fx /= 2;
  small.fy /= 2;
  small.cx /= 2;
  small.cy /= 2;
  images.push_back(ToCalibrationImage(
      testing::RenderChessboard(small, testing::CalibrationPoses(small, {}, 1, 3)[0], {}),
      "small.png"));
  const ChessboardCalibrationResult r = CalibrateChessboard(images, Options());
  ASSERT_TRUE(r.calibrated) << r.message;
  EXPECT_EQ(r.used_images, 6);
  ASSERT_EQ(r.images.size(), 8u);
  EXPECT_EQ(r.images[2].name, "no_board.png");
  EXPECT_EQ(r.images[2].status, ImageStatus::kBoardNotFound);
  EXPECT_EQ(r.images[7].status, ImageStatus::kSizeMismatch);
  EXPECT_THAT(r.images[7].reason, HasSubstr("320x240 differs from the first image's 640x480"));
  EXPECT_THAT(r.RefusedSummary(),
              ContainsRegex("no_board\\.png \\(board not found \\(9x6 inner corners\\)\\), "
                            "small\\.png \\(image size 320x240"));
  EXPECT_NEAR(r.parameters.fx, TrueCamera().fx, 5.0);  // 6 views: measured 2.6 px
}

TEST(ChessboardCalibrationTest, TooFewUsableImagesIsReportedNotCalibrated) {
  std::vector<CalibrationImage> images(GoodViews().begin(), GoodViews().begin() + 2);
  images.push_back(ToCalibrationImage(testing::RenderEmptyScene(640, 480), "blank.png"));
  const ChessboardCalibrationResult r = CalibrateChessboard(images, Options());
  EXPECT_FALSE(r.calibrated);
  EXPECT_EQ(r.used_images, 2);
  EXPECT_THAT(r.message, HasSubstr("only 2 of 3 images usable (minimum 3)"));
  EXPECT_THAT(r.message, HasSubstr("blank.png (board not found"));
  EXPECT_EQ(r.estimation.status, EstimationStatus::kInsufficientData);
  EXPECT_EQ(r.estimation.message, r.message);

  // With the minimum lowered the two views calibrate, with a warning.
  ChessboardCalibrationOptions o = Options();
  o.min_images = 2;
  const ChessboardCalibrationResult two = CalibrateChessboard(images, o);
  EXPECT_TRUE(two.calibrated) << two.message;
  EXPECT_THAT(two.warnings, ::testing::Contains(HasSubstr("only 2 usable images")));
}

TEST(ChessboardCalibrationTest, FrontoParallelBoardsInTheCentreAreWarnedAbout) {
  const ChessboardTarget target;
  std::vector<CalibrationImage> images;
  for (int k = 0; k < 5; ++k) {
    Eigen::Isometry3d X_CT = Eigen::Isometry3d::Identity();
    X_CT.linear() =
        Eigen::AngleAxisd(0.02 * k, Eigen::Vector3d(1, 1, 0).normalized()).toRotationMatrix();
    X_CT.translation() = Eigen::Vector3d(-0.1 + 0.004 * k, -0.0625, 0.55);
    images.push_back(ToCalibrationImage(testing::RenderChessboard(TrueCamera(), X_CT, target),
                                        "flat" + std::to_string(k) + ".png"));
  }
  const ChessboardCalibrationResult r = CalibrateChessboard(images, Options());
  ASSERT_TRUE(r.calibrated) << r.message;
  EXPECT_LT(r.max_tilt_rad, 15 * common::kPi / 180);
  EXPECT_LT(r.coverage, 0.5);
  EXPECT_THAT(r.warnings, ::testing::Contains(HasSubstr("nearly fronto-parallel")));
  EXPECT_THAT(r.warnings, ::testing::Contains(HasSubstr("cover only")));
}

TEST(ChessboardCalibrationTest, RationalModelFitsTheSameCamera) {
  ChessboardCalibrationOptions o = Options();
  o.rational_model = true;
  o.fix_k3 = false;
  const ChessboardCalibrationResult r = CalibrateChessboard(GoodViews(), o);
  ASSERT_TRUE(r.calibrated);
  EXPECT_LT(r.rms_px, 0.1);
  EXPECT_NEAR(r.parameters.fx, TrueCamera().fx, 3.0);
  EXPECT_GT(r.stddev.distortion[5], 0.0);  // k4 estimated
}

TEST(ChessboardCalibrationTest, FilesAreLoadedAndUnreadableOnesRefused) {
  std::vector<std::string> paths;
  for (int k = 0; k < 4; ++k) {
    const CalibrationImage& v = GoodViews()[k];
    const std::string path = ::testing::TempDir() + "kinevis_chessboard_" + v.name;
    cv::Mat m(v.height, v.width, CV_8U, const_cast<std::uint8_t*>(v.grey.data()));
    ASSERT_TRUE(cv::imwrite(path, m));
    paths.push_back(path);
  }
  paths.push_back(::testing::TempDir() + "kinevis_chessboard_missing.png");
  std::remove(paths.back().c_str());
  const ChessboardCalibrationResult r = CalibrateChessboardFiles(paths, Options());
  ASSERT_TRUE(r.calibrated) << r.message;
  EXPECT_EQ(r.used_images, 4);
  EXPECT_EQ(r.images[4].status, ImageStatus::kUnreadable);
  EXPECT_THAT(r.RefusedSummary(), HasSubstr("kinevis_chessboard_missing.png (cannot be read"));
  const CalibrationImage loaded = LoadCalibrationImage(paths[0]);
  EXPECT_EQ(loaded.grey, GoodViews()[0].grey);  // PNG is lossless
  EXPECT_THROW(LoadCalibrationImage(paths.back()), std::runtime_error);
}

TEST(ChessboardCalibrationTest, OverlayPngHasTheImageSizeAndMarksCorners) {
  const ChessboardCalibrationResult r = CalibrateChessboard(GoodViews(), Options());
  ASSERT_TRUE(r.calibrated);
  const std::string path = ::testing::TempDir() + "kinevis_chessboard_overlay.png";
  std::remove(path.c_str());
  WriteOverlayPng(GoodViews()[0], r.images[0], path);
  const cv::Mat overlay = cv::imread(path, cv::IMREAD_COLOR);
  ASSERT_FALSE(overlay.empty());
  EXPECT_EQ(overlay.cols, 640);
  EXPECT_EQ(overlay.rows, 480);
  // A reprojected corner is drawn red (BGR), a point on a detected corner's circle green.
  const Eigen::Vector2d c = r.images[0].reprojected_px[10];
  const cv::Vec3b centre = overlay.at<cv::Vec3b>(static_cast<int>(std::lround(c.y())),
                                                 static_cast<int>(std::lround(c.x())));
  EXPECT_GT(centre[2], 150);
  EXPECT_LT(centre[1], 100);
  int green = 0;
  for (int dv = -5; dv <= 5; ++dv) {
    for (int du = -5; du <= 5; ++du) {
      const cv::Vec3b p =
          overlay.at<cv::Vec3b>(static_cast<int>(c.y()) + dv, static_cast<int>(c.x()) + du);
      if (p[1] > 150 && p[0] < 100 && p[2] < 100) ++green;
    }
  }
  EXPECT_GT(green, 5);
  ImageReport unused = r.images[0];
  unused.status = ImageStatus::kBoardNotFound;
  EXPECT_THROW(WriteOverlayPng(GoodViews()[0], unused, path), std::invalid_argument);
  EXPECT_THROW(WriteOverlayPng(GoodViews()[0], r.images[0], "/nonexistent-dir/o.png"),
               std::runtime_error);
}

TEST(ChessboardCalibrationTest, ValidateNamesEveryBadField) {
  ChessboardCalibrationOptions o;
  o.board_cols = 1;
  o.board_rows = 0;
  o.square_m = -0.01;
  o.min_images = 0;
  o.subpix_half_window_px = -3;
  const std::string message = o.Validate();
  EXPECT_THAT(message, HasSubstr("board_cols = 1"));
  EXPECT_THAT(message, HasSubstr("board_rows = 0"));
  EXPECT_THAT(message, HasSubstr("square_m = -0.01"));
  EXPECT_THAT(message, HasSubstr("min_images = 0"));
  EXPECT_THAT(message, HasSubstr("subpix_half_window_px = -3"));
  EXPECT_EQ(Options().Validate(), "");
  EXPECT_THROW(CalibrateChessboard({}, o), std::invalid_argument);
  o = Options();
  o.square_m = std::nan("");
  EXPECT_THAT(o.Validate(), HasSubstr("square_m = nan"));
}

}  // namespace
}  // namespace kinevis::calibration
