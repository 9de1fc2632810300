// The Stitcher baseline: how many tiles its panorama holds. It leaves out,
// with status OK, a tile it cannot match (here one of another texture), so a
// benchmark's time for "the tiles" may be for fewer of them.
#include "adapters/opencv/opencv_stitcher.h"

#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

namespace omm {
namespace {

// Blurred uniform noise in [0, 1]: texture that ORB finds corners in.
ImageF Texture(int rows, int cols, uint64_t seed) {
  cv::Mat noise(rows, cols, CV_32F);
  cv::RNG(seed).fill(noise, cv::RNG::UNIFORM, 0.0, 1.0);
  cv::GaussianBlur(noise, noise, cv::Size(), 2.0);
  cv::normalize(noise, noise, 0.0, 1.0, cv::NORM_MINMAX);
  ImageF image(rows, cols);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) image(r, c) = noise.at<float>(r, c);
  return image;
}

TEST(OpenCvStitcher, CountsTheTilesItsPanoramaHolds) {
  // Three 640 px wide tiles of one strip, overlapping by 360 px, and one of
  // another texture that overlaps nothing.
  const ImageF strip = Texture(480, 1200, 1);
  std::vector<ImageF> tiles;
  for (const int left : {0, 280, 560}) tiles.push_back(strip.middleCols(left, 640));
  tiles.push_back(Texture(480, 640, 2));

  const OpenCvStitcherResult result = StitchScans(tiles);
  ASSERT_TRUE(result.ok) << result.status;
  EXPECT_EQ(result.tiles_used, 3);
  // The three composed: about the strip's width.
  EXPECT_NEAR(result.panorama.cols(), 1200, 20);
}

}  // namespace
}  // namespace omm
