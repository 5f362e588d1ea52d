#pragma once

// The image type every feature extractor and the renderer take: a non-owning view of an 8-bit
// grey image. hal::Image (mono8) and cv::Mat (CV_8UC1) both provide one without copying:
//
//   vision::ImageView8 view{image.data.data(), image.width, image.height, image.stride};

#include <cstddef>
#include <cstdint>

namespace kinevis::vision {

// Row-major, `stride` bytes per row (>= width); pixel (u, v) is data[v * stride + u].
struct ImageView8 {
  uint8_t* data = nullptr;
  int width = 0;
  int height = 0;
  size_t stride = 0;
};

}  // namespace kinevis::vision
