// A gray image as the pipeline sees it, whatever the file's format.
#pragma once

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

}  // namespace omm
