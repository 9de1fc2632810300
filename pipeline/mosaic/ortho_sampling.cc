#include "pipeline/mosaic/ortho_sampling.h"

#include <algorithm>

namespace omm {

ImageMask ClippedSupport(const ImageF& image) {
  if (image.size() == 0 || image.maxCoeff() < 1.0f) return {};
  const int rows = static_cast<int>(image.rows()), cols = static_cast<int>(image.cols());
  // Separably: the support's columns floor(q) - 1 .. floor(q) + 2 per row,
  // then its rows.
  ImageMask across = ImageMask::Zero(rows, cols);
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      if (image(r, c) < 1.0f) continue;
      for (int x = std::max(c - 2, 0); x <= std::min(c + 1, cols - 1); ++x) across(r, x) = 1;
    }
  }
  ImageMask clipped = ImageMask::Zero(rows, cols);
  for (int r = 0; r < rows; ++r) {
    for (int y = std::max(r - 2, 0); y <= std::min(r + 1, rows - 1); ++y)
      clipped.row(y) = clipped.row(y).cwiseMax(across.row(r));
  }
  return clipped;
}

}  // namespace omm
