// A gray image as the pipeline sees it, whatever the file's format.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

namespace omm {

// Row-major so that (row, col) addressing matches image files; rows = height.
using ImageF = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

struct GrayImage {
  // Intensities scaled to [0, 1] of the file's full scale (255 or 65535).
  ImageF pixels;
  // Bits per sample in the file the image came from (8 or 16); the digital
  // number of a pixel is pixels * (2^bit_depth - 1).
  int bit_depth = 8;

  int width() const { return static_cast<int>(pixels.cols()); }
  int height() const { return static_cast<int>(pixels.rows()); }
};

// An image's gray samples as its file holds them: digital numbers of 8 or 16
// bits. What is kept of an image between stages (1 or 2 bytes a pixel, not
// GrayImage's 4); adapters/opencv/image_io.h converts it to a GrayImage
// exactly as reading the file would.
struct StoredImage {
  int width = 0;
  int height = 0;
  int bit_depth = 8;  // 8 or 16
  // Row-major, width * height * bit_depth / 8 bytes; 16-bit samples are
  // native-endian std::uint16_t.
  std::vector<std::uint8_t> samples;
};

}  // namespace omm
