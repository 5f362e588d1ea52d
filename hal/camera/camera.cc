#include "hal/camera/camera.h"

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "hal/common/error.h"

namespace kinevis::hal {

const char* ToString(PixelFormat format) {
  switch (format) {
    case PixelFormat::kMono8:
      return "mono8";
    case PixelFormat::kBgr8:
      return "bgr8";
    case PixelFormat::kRgb8:
      return "rgb8";
    case PixelFormat::kMono16:
      return "mono16";
  }
  return "?";
}

std::optional<PixelFormat> ParsePixelFormat(std::string_view text) {
  for (PixelFormat f :
       {PixelFormat::kMono8, PixelFormat::kBgr8, PixelFormat::kRgb8, PixelFormat::kMono16}) {
    if (text == ToString(f)) return f;
  }
  return std::nullopt;
}

int BytesPerPixel(PixelFormat format) {
  switch (format) {
    case PixelFormat::kMono8:
      return 1;
    case PixelFormat::kBgr8:
    case PixelFormat::kRgb8:
      return 3;
    case PixelFormat::kMono16:
      return 2;
  }
  return 1;
}

void Image::Resize(int new_width, int new_height, PixelFormat new_format) {
  width = new_width < 0 ? 0 : new_width;
  height = new_height < 0 ? 0 : new_height;
  format = new_format;
  stride = static_cast<size_t>(width) * static_cast<size_t>(BytesPerPixel(format));
  // resize() never gives capacity back, so a buffer sized once is reused by every later frame.
  data.resize(stride * static_cast<size_t>(height));
}

void SaveImage(const Image& image, const std::string& path) {
  const size_t row_bytes =
      static_cast<size_t>(image.width) * static_cast<size_t>(BytesPerPixel(image.format));
  if (image.width <= 0 || image.height <= 0 || image.stride < row_bytes ||
      image.data.size() < image.stride * static_cast<size_t>(image.height)) {
    throw common::ConfigError("save image \"" + path + "\": the image is empty or inconsistent (" +
                              std::to_string(image.width) + "x" + std::to_string(image.height) +
                              " " + ToString(image.format) + ", stride " +
                              std::to_string(image.stride) + ", " +
                              std::to_string(image.data.size()) + " bytes)");
  }
  int type = CV_8UC1;
  switch (image.format) {
    case PixelFormat::kMono8:
      type = CV_8UC1;
      break;
    case PixelFormat::kBgr8:
    case PixelFormat::kRgb8:
      type = CV_8UC3;
      break;
    case PixelFormat::kMono16:
      type = CV_16UC1;
      break;
  }
  // imwrite only reads the pixels; the const_cast builds a header over them without copying.
  const cv::Mat view(image.height, image.width, type, const_cast<uint8_t*>(image.data.data()),
                     image.stride);
  cv::Mat bgr;
  if (image.format == PixelFormat::kRgb8) cv::cvtColor(view, bgr, cv::COLOR_RGB2BGR);
  bool written = false;
  std::string why;
  try {
    written = cv::imwrite(path, image.format == PixelFormat::kRgb8 ? bgr : view);
  } catch (const cv::Exception& e) {
    why = e.what();
  }
  if (!written) {
    throw HalError(path, "write image",
                   why.empty() ? "OpenCV could not write it (no such directory, no permission, "
                                 "or an extension it has no encoder for)"
                               : why);
  }
}

CameraCounters AtomicCameraCounters::Snapshot() const {
  CameraCounters c;
  c.frames = frames.load(std::memory_order_relaxed);
  c.timeouts = timeouts.load(std::memory_order_relaxed);
  c.dropped = dropped.load(std::memory_order_relaxed);
  c.duplicates = duplicates.load(std::memory_order_relaxed);
  c.decode_errors = decode_errors.load(std::memory_order_relaxed);
  return c;
}

}  // namespace kinevis::hal
