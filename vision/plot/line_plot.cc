#include "vision/plot/line_plot.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <stdexcept>

namespace kinevis::vision::plot {
namespace {

constexpr std::array<std::array<uint8_t, 3>, 8> kPalette = {{{31, 119, 180},
                                                             {214, 39, 40},
                                                             {44, 160, 44},
                                                             {255, 127, 14},
                                                             {148, 103, 189},
                                                             {140, 86, 75},
                                                             {227, 119, 194},
                                                             {127, 127, 127}}};
constexpr int kMarginLeft = 86, kMarginRight = 24, kMarginTop = 42, kMarginBottom = 58;
constexpr double kFontScale = 0.45;
const cv::Scalar kBlack(0, 0, 0), kGrid(225, 225, 225), kWhite(255, 255, 255);

cv::Scalar Bgr(const std::array<uint8_t, 3>& rgb) { return cv::Scalar(rgb[2], rgb[1], rgb[0]); }

bool Admissible(double x, double y, AxisScale scale) {
  return std::isfinite(x) && std::isfinite(y) && (scale == AxisScale::kLinear || y > 0);
}

// 1-2-5 tick step giving about `target` intervals over `span`.
double NiceStep(double span, int target) {
  const double raw = span / target;
  const double decade = std::pow(10.0, std::floor(std::log10(raw)));
  for (double m : {1.0, 2.0, 5.0, 10.0}) {
    if (m * decade >= raw) return m * decade;
  }
  return 10 * decade;
}

std::string Label(double v) {
  char buffer[32];
  if (v != 0 && (std::abs(v) < 1e-3 || std::abs(v) >= 1e5)) {
    std::snprintf(buffer, sizeof buffer, "%.0e", v);
  } else {
    std::snprintf(buffer, sizeof buffer, "%g", v);
  }
  return buffer;
}

void PutText(cv::Mat* image, const std::string& text, cv::Point at, double scale = kFontScale,
             int align = -1 /* -1 left, 0 centre, 1 right */) {
  int baseline = 0;
  const cv::Size size = cv::getTextSize(text, cv::FONT_HERSHEY_SIMPLEX, scale, 1, &baseline);
  if (align == 0) at.x -= size.width / 2;
  if (align == 1) at.x -= size.width;
  cv::putText(*image, text, at, cv::FONT_HERSHEY_SIMPLEX, scale, kBlack, 1, cv::LINE_AA);
}

}  // namespace

Eigen::Vector2d PlotLayout::ToPixel(double x, double y) const {
  const auto Y = [&](double v) { return y_scale == AxisScale::kLog10 ? std::log10(v) : v; };
  const double col = left + (x - x_min) / (x_max - x_min) * (right - left);
  const double row = bottom - (Y(y) - Y(y_min)) / (Y(y_max) - Y(y_min)) * (bottom - top);
  return Eigen::Vector2d(col, row);
}

std::string LinePlotOptions::Validate() const {
  std::ostringstream out;
  const auto bad = [&](const char* field, double value, const char* rule) {
    out << (out.tellp() > 0 ? "; " : "") << field << ": " << rule << ", got " << value;
  };
  if (width_px < 200) bad("width_px", width_px, "must be >= 200");
  if (height_px < 150) bad("height_px", height_px, "must be >= 150");
  if (!std::isfinite(x_min) || !std::isfinite(x_max)) bad("x_min/x_max", x_min, "must be finite");
  if (!std::isfinite(y_min) || !std::isfinite(y_max)) bad("y_min/y_max", y_min, "must be finite");
  if (y_scale == AxisScale::kLog10 && y_min < y_max && y_min <= 0) {
    bad("y_min", y_min, "must be > 0 on a log axis");
  }
  return out.str();
}

LinePlot::LinePlot(LinePlotOptions options) : options_(std::move(options)) {
  const std::string message = options_.Validate();
  if (!message.empty()) throw std::invalid_argument("LinePlot: " + message);
}

void LinePlot::AddSeries(Series series) {
  if (series.x.size() != series.y.size()) {
    throw std::invalid_argument("LinePlot: series '" + series.name + "': x has " +
                                std::to_string(series.x.size()) + " values, y has " +
                                std::to_string(series.y.size()));
  }
  if (series.thickness_px < 1) {
    throw std::invalid_argument("LinePlot: series '" + series.name +
                                "': thickness_px must be "
                                ">= 1, got " +
                                std::to_string(series.thickness_px));
  }
  series_.push_back(std::move(series));
}

std::array<uint8_t, 3> LinePlot::SeriesColor(int i) const {
  const Series& s = series_.at(static_cast<size_t>(i));
  return s.auto_color ? kPalette[static_cast<size_t>(i) % kPalette.size()] : s.rgb;
}

PlotLayout LinePlot::ComputeLayout() const {
  PlotLayout layout;
  layout.left = kMarginLeft;
  layout.top = kMarginTop;
  layout.right = options_.width_px - 1 - kMarginRight;
  layout.bottom = options_.height_px - 1 - kMarginBottom;
  layout.y_scale = options_.y_scale;
  double x_lo = std::numeric_limits<double>::infinity(), x_hi = -x_lo;
  double y_lo = x_lo, y_hi = -x_lo;
  for (const Series& s : series_) {
    for (size_t i = 0; i < s.x.size(); ++i) {
      if (!Admissible(s.x[i], s.y[i], options_.y_scale)) continue;
      x_lo = std::min(x_lo, s.x[i]);
      x_hi = std::max(x_hi, s.x[i]);
      y_lo = std::min(y_lo, s.y[i]);
      y_hi = std::max(y_hi, s.y[i]);
    }
  }
  if (!(x_lo <= x_hi)) x_lo = 0, x_hi = 1;
  if (x_lo == x_hi) x_lo -= 0.5, x_hi += 0.5;
  const bool log = options_.y_scale == AxisScale::kLog10;
  if (!(y_lo <= y_hi)) {
    y_lo = log ? 0.1 : 0.0;
    y_hi = log ? 1.0 : 1.0;
  }
  if (log) {
    // Whole decades.
    y_lo = std::pow(10.0, std::floor(std::log10(y_lo)));
    y_hi = std::pow(10.0, std::ceil(std::log10(y_hi)));
    if (y_lo == y_hi) y_hi *= 10;
  } else {
    if (y_lo == y_hi) {
      const double d = y_lo == 0 ? 1.0 : 0.1 * std::abs(y_lo);
      y_lo -= d;
      y_hi += d;
    } else {
      const double margin = 0.05 * (y_hi - y_lo);
      y_lo -= margin;
      y_hi += margin;
    }
  }
  layout.x_min = options_.x_min < options_.x_max ? options_.x_min : x_lo;
  layout.x_max = options_.x_min < options_.x_max ? options_.x_max : x_hi;
  layout.y_min = options_.y_min < options_.y_max ? options_.y_min : y_lo;
  layout.y_max = options_.y_min < options_.y_max ? options_.y_max : y_hi;
  return layout;
}

LinePlotSummary LinePlot::WritePng(const std::string& path) const {
  LinePlotSummary summary;
  const PlotLayout layout = ComputeLayout();
  cv::Mat image(options_.height_px, options_.width_px, CV_8UC3, kWhite);
  const cv::Rect area(layout.left, layout.top, layout.right - layout.left + 1,
                      layout.bottom - layout.top + 1);
  const bool log = layout.y_scale == AxisScale::kLog10;

  // Grid and tick labels.
  const double x_step = NiceStep(layout.x_max - layout.x_min, 8);
  for (double x = std::ceil(layout.x_min / x_step) * x_step; x <= layout.x_max + 1e-9 * x_step;
       x += x_step) {
    const int col = static_cast<int>(std::lround(layout.ToPixel(x, layout.y_min).x()));
    cv::line(image, {col, layout.top}, {col, layout.bottom}, kGrid, 1);
    cv::line(image, {col, layout.bottom}, {col, layout.bottom + 5}, kBlack, 1);
    PutText(&image, Label(std::abs(x) < 1e-12 * x_step ? 0.0 : x), {col, layout.bottom + 20},
            kFontScale, 0);
  }
  if (log) {
    for (double e = std::round(std::log10(layout.y_min)); e <= std::log10(layout.y_max) + 1e-9;
         e += 1) {
      const double y = std::pow(10.0, e);
      const int row = static_cast<int>(std::lround(layout.ToPixel(layout.x_min, y).y()));
      cv::line(image, {layout.left, row}, {layout.right, row}, kGrid, 1);
      cv::line(image, {layout.left - 5, row}, {layout.left, row}, kBlack, 1);
      PutText(&image, "1e" + std::to_string(static_cast<int>(e)), {layout.left - 8, row + 5},
              kFontScale, 1);
    }
  } else {
    const double y_step = NiceStep(layout.y_max - layout.y_min, 6);
    for (double y = std::ceil(layout.y_min / y_step) * y_step; y <= layout.y_max + 1e-9 * y_step;
         y += y_step) {
      const int row = static_cast<int>(std::lround(layout.ToPixel(layout.x_min, y).y()));
      cv::line(image, {layout.left, row}, {layout.right, row}, kGrid, 1);
      cv::line(image, {layout.left - 5, row}, {layout.left, row}, kBlack, 1);
      PutText(&image, Label(std::abs(y) < 1e-12 * y_step ? 0.0 : y), {layout.left - 8, row + 5},
              kFontScale, 1);
    }
  }
  cv::rectangle(image, area, kBlack, 1);
  PutText(&image, options_.title, {options_.width_px / 2, 26}, 0.6, 0);
  PutText(&image, options_.x_label, {(layout.left + layout.right) / 2, options_.height_px - 12},
          kFontScale, 0);
  {
    // The y label, rotated: drawn on a strip and turned 90°.
    int baseline = 0;
    const cv::Size size =
        cv::getTextSize(options_.y_label, cv::FONT_HERSHEY_SIMPLEX, kFontScale, 1, &baseline);
    if (size.width > 0 && size.width < options_.height_px) {
      cv::Mat strip(size.height + baseline + 4, size.width + 4, CV_8UC3, kWhite);
      cv::putText(strip, options_.y_label, {2, size.height + 2}, cv::FONT_HERSHEY_SIMPLEX,
                  kFontScale, kBlack, 1, cv::LINE_AA);
      cv::Mat turned;
      cv::rotate(strip, turned, cv::ROTATE_90_COUNTERCLOCKWISE);
      const int row0 = std::max(0, (layout.top + layout.bottom) / 2 - turned.rows / 2);
      if (row0 + turned.rows <= image.rows && 4 + turned.cols <= layout.left) {
        turned.copyTo(image(cv::Rect(4, row0, turned.cols, turned.rows)));
      }
    }
  }

  // Series: 8-connected lines (exact colours), clipped to the data area; a skipped point breaks
  // the line.
  int legend_row = layout.top + 18;
  for (size_t i = 0; i < series_.size(); ++i) {
    const Series& s = series_[i];
    const cv::Scalar colour = Bgr(SeriesColor(static_cast<int>(i)));
    int drawn = 0, skipped = 0;
    bool have_previous = false;
    cv::Point previous;
    for (size_t k = 0; k < s.x.size(); ++k) {
      if (!Admissible(s.x[k], s.y[k], layout.y_scale)) {
        ++skipped;
        have_previous = false;
        continue;
      }
      const Eigen::Vector2d p = layout.ToPixel(s.x[k], s.y[k]);
      const cv::Point point(static_cast<int>(std::lround(std::clamp(p.x(), -1e6, 1e6))),
                            static_cast<int>(std::lround(std::clamp(p.y(), -1e6, 1e6))));
      ++drawn;
      cv::Point a = have_previous ? previous : point, b = point;
      if (cv::clipLine(area, a, b)) cv::line(image, a, b, colour, s.thickness_px, cv::LINE_8);
      previous = point;
      have_previous = true;
    }
    if (skipped > 0) {
      summary.notes.push_back(
          "series '" + s.name + "': " + std::to_string(skipped) + " point(s) skipped (" +
          (log ? "NaN, infinite or <= 0 on the log axis" : "NaN or infinite") + ")");
    }
    if (drawn == 0) {
      summary.notes.push_back("series '" + s.name + "': nothing to draw (empty)");
      continue;
    }
    summary.points_drawn += drawn;
    summary.points_skipped += skipped;
    ++summary.series_drawn;
    // Legend entry, top right inside the data area.
    int baseline = 0;
    const cv::Size size =
        cv::getTextSize(s.name, cv::FONT_HERSHEY_SIMPLEX, kFontScale, 1, &baseline);
    const int x1 = layout.right - 12 - size.width - 8 - 28;
    cv::line(image, {x1, legend_row - 4}, {x1 + 24, legend_row - 4}, colour, 2, cv::LINE_8);
    PutText(&image, s.name, {x1 + 32, legend_row});
    legend_row += 18;
  }

  bool written = false;
  try {
    written = cv::imwrite(path, image);
  } catch (const cv::Exception& e) {
    throw std::runtime_error(path + ": cannot write PNG: " + e.what());
  }
  if (!written) throw std::runtime_error(path + ": cannot write PNG");
  return summary;
}

}  // namespace kinevis::vision::plot
