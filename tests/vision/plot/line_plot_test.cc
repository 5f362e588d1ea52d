#include "vision/plot/line_plot.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <string>

namespace kinevis::vision::plot {
namespace {

using ::testing::HasSubstr;

std::string TempPng(const std::string& name) { return ::testing::TempDir() + "/" + name + ".png"; }

bool HasColour(const cv::Mat& image, int row, int col, const std::array<uint8_t, 3>& rgb) {
  const cv::Vec3b bgr = image.at<cv::Vec3b>(row, col);
  return bgr[0] == rgb[2] && bgr[1] == rgb[1] && bgr[2] == rgb[0];
}

// Rows of column `col` that carry the colour.
std::vector<int> RowsWithColour(const cv::Mat& image, int col, const std::array<uint8_t, 3>& rgb) {
  std::vector<int> rows;
  for (int r = 0; r < image.rows; ++r) {
    if (HasColour(image, r, col, rgb)) rows.push_back(r);
  }
  return rows;
}

TEST(LinePlotTest, AHorizontalLineLandsOnTheRowItsValueMapsTo) {
  LinePlotOptions o;
  o.width_px = 640;
  o.height_px = 400;
  o.title = "test";
  o.x_label = "t (s)";
  o.y_label = "value";
  LinePlot plot(o);
  Series ramp{"ramp", {0, 1, 2, 3, 4}, {0, 1, 2, 3, 4}};
  Series flat{"flat", {0, 4}, {1.5, 1.5}};
  flat.thickness_px = 1;
  plot.AddSeries(ramp);
  plot.AddSeries(flat);
  const std::string path = TempPng("linear");
  const LinePlotSummary summary = plot.WritePng(path);
  EXPECT_EQ(summary.series_drawn, 2);
  EXPECT_EQ(summary.points_drawn, 7);
  EXPECT_TRUE(summary.notes.empty());

  const cv::Mat image = cv::imread(path, cv::IMREAD_COLOR);
  ASSERT_FALSE(image.empty());
  EXPECT_EQ(image.cols, 640);
  EXPECT_EQ(image.rows, 400);
  const PlotLayout layout = plot.ComputeLayout();
  EXPECT_EQ(layout.x_min, 0);
  EXPECT_EQ(layout.x_max, 4);
  // A quarter of the way along x (clear of the legend, top right): the flat line is on the row
  // y = 1.5 maps to, and only there.
  const int col = static_cast<int>(std::lround(layout.ToPixel(1.0, 1.5).x()));
  const int row = static_cast<int>(std::lround(layout.ToPixel(1.0, 1.5).y()));
  const std::vector<int> rows = RowsWithColour(image, col, plot.SeriesColor(1));
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_EQ(rows[0], row);
  // The ramp passes through (1, 1) and (3, 3).
  for (double v : {1.0, 3.0}) {
    const Eigen::Vector2d p = layout.ToPixel(v, v);
    const std::vector<int> r =
        RowsWithColour(image, static_cast<int>(std::lround(p.x())), plot.SeriesColor(0));
    ASSERT_FALSE(r.empty());
    EXPECT_NEAR(r.front(), p.y(), 2.0);
  }
  // y grows upwards.
  EXPECT_LT(layout.ToPixel(0, 4).y(), layout.ToPixel(0, 0).y());
}

TEST(LinePlotTest, LogAxisPutsDecadesEvenlyAndSkipsNonPositiveAndNanPoints) {
  LinePlotOptions o;
  o.y_scale = AxisScale::kLog10;
  LinePlot plot(o);
  Series decay{"decay", {}, {}};
  for (int k = 0; k <= 50; ++k) {
    decay.x.push_back(0.1 * k);
    decay.y.push_back(std::exp(-2.0 * 0.1 * k));
  }
  decay.y[10] = 0.0;           // not on a log axis
  decay.y[20] = std::nan("");  // a gap
  Series level{"1e-3", {0, 5}, {1e-3, 1e-3}};
  level.thickness_px = 1;
  plot.AddSeries(decay);
  plot.AddSeries(level);
  plot.AddSeries(Series{"empty", {}, {}});
  const std::string path = TempPng("log");
  const LinePlotSummary summary = plot.WritePng(path);
  EXPECT_EQ(summary.series_drawn, 2);
  EXPECT_EQ(summary.points_skipped, 2);
  ASSERT_EQ(summary.notes.size(), 2u);
  EXPECT_THAT(summary.notes[0], HasSubstr("'decay': 2 point(s) skipped"));
  EXPECT_THAT(summary.notes[1], HasSubstr("'empty': nothing to draw"));

  const PlotLayout layout = plot.ComputeLayout();
  EXPECT_DOUBLE_EQ(layout.y_max, 1.0);
  EXPECT_NEAR(layout.y_min, 1e-5, 1e-20);  // exp(−10) = 4.5e-5 -> the decade below
  // Decades are evenly spaced.
  const double d1 = layout.ToPixel(0, 1e-1).y() - layout.ToPixel(0, 1.0).y();
  const double d2 = layout.ToPixel(0, 1e-4).y() - layout.ToPixel(0, 1e-3).y();
  EXPECT_NEAR(d1, d2, 1e-9);
  const cv::Mat image = cv::imread(path, cv::IMREAD_COLOR);
  ASSERT_FALSE(image.empty());
  EXPECT_EQ(image.cols, o.width_px);
  const Eigen::Vector2d p = layout.ToPixel(1.0, 1e-3);
  const std::vector<int> rows =
      RowsWithColour(image, static_cast<int>(std::lround(p.x())), plot.SeriesColor(1));
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_EQ(rows[0], static_cast<int>(std::lround(p.y())));
  // The decay at t = 3 s (y = e^-6 = 2.5e-3) lies on its mapped row.
  const Eigen::Vector2d q = layout.ToPixel(3.0, std::exp(-6.0));
  const std::vector<int> decay_rows =
      RowsWithColour(image, static_cast<int>(std::lround(q.x())), plot.SeriesColor(0));
  ASSERT_FALSE(decay_rows.empty());
  EXPECT_NEAR(0.5 * (decay_rows.front() + decay_rows.back()), q.y(), 2.0);
}

TEST(LinePlotTest, BadInputIsRefusedOrExplained) {
  LinePlotOptions o;
  o.width_px = 10;
  o.height_px = 20;
  o.y_scale = AxisScale::kLog10;
  o.y_min = -1;
  o.y_max = 1;
  const std::string message = o.Validate();
  EXPECT_THAT(message, HasSubstr("width_px: must be >= 200, got 10"));
  EXPECT_THAT(message, HasSubstr("height_px: must be >= 150, got 20"));
  EXPECT_THAT(message, HasSubstr("y_min: must be > 0 on a log axis, got -1"));
  EXPECT_THROW(LinePlot{o}, std::invalid_argument);
  LinePlot plot(LinePlotOptions{});
  EXPECT_THROW(plot.AddSeries(Series{"bad", {1, 2}, {1}}), std::invalid_argument);
  // No data at all still gives an (empty) figure; an unwritable path is an error naming it.
  EXPECT_EQ(plot.WritePng(TempPng("empty")).series_drawn, 0);
  try {
    plot.WritePng("/nonexistent-dir/x.png");
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_THAT(e.what(), HasSubstr("/nonexistent-dir/x.png"));
  }
}

}  // namespace
}  // namespace kinevis::vision::plot
