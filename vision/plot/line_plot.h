#pragma once

// A small line-plot writer for logs and experiment figures: titled axes, linear or log-10 y,
// several named series with a legend, ticks with labels, written as PNG. Drawing is OpenCV in
// the .cc; this header is std + Eigen only.
//
// Bad data are drawn around, never fatal: NaN/inf points and (on a log axis) points <= 0 are
// skipped (the line is broken there) and an empty series is left out of the plot; each such
// case is reported in LinePlotSummary::notes.

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace kinevis::vision::plot {

enum class AxisScale { kLinear, kLog10 };

struct Series {
  std::string name;       // legend text
  std::vector<double> x;  // same length as y
  std::vector<double> y;
  // RGB; all 0 with auto_color = true picks the next colour of the palette.
  std::array<uint8_t, 3> rgb{0, 0, 0};
  bool auto_color = true;
  int thickness_px = 2;  // >= 1
};

struct LinePlotOptions {
  int width_px = 900;   // >= 200
  int height_px = 560;  // >= 150
  std::string title;
  std::string x_label;
  std::string y_label;
  AxisScale y_scale = AxisScale::kLinear;
  // Fixed axis ranges when min < max (else from the data, with a margin on linear axes and whole
  // decades on log axes).
  double x_min = 0, x_max = 0;
  double y_min = 0, y_max = 0;
  std::string Validate() const;  // empty when usable, else every bad field and its value
};

// Where the data area lies in the image and the axis ranges used (after ComputeLayout()).
struct PlotLayout {
  int left = 0, top = 0, right = 0, bottom = 0;       // data area, pixels (right/bottom inclusive)
  double x_min = 0, x_max = 1, y_min = 0, y_max = 1;  // y in data units (not log)
  AxisScale y_scale = AxisScale::kLinear;
  // Pixel (column, row) of a data point; y must be > 0 on a log axis.
  Eigen::Vector2d ToPixel(double x, double y) const;
};

struct LinePlotSummary {
  int series_drawn = 0;
  int points_drawn = 0;
  int points_skipped = 0;
  std::vector<std::string> notes;  // why points or series were left out
};

class LinePlot {
 public:
  // Throws std::invalid_argument with options.Validate()'s message.
  explicit LinePlot(LinePlotOptions options);
  // Throws std::invalid_argument when x and y differ in length or thickness < 1.
  void AddSeries(Series series);
  // The layout the plot will be drawn with (axis ranges from the finite, admissible points).
  PlotLayout ComputeLayout() const;
  // Draws and writes a PNG. Throws std::runtime_error naming the file when it cannot be written.
  LinePlotSummary WritePng(const std::string& path) const;
  // The colour series i is drawn in (RGB).
  std::array<uint8_t, 3> SeriesColor(int i) const;
  const std::vector<Series>& series() const { return series_; }

 private:
  LinePlotOptions options_;
  std::vector<Series> series_;
};

}  // namespace kinevis::vision::plot
