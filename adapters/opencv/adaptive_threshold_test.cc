#include "adapters/opencv/adaptive_threshold.h"

#include <algorithm>
#include <cmath>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

namespace omm {
namespace {

// Pixels where the two masks differ.
int Differences(const cv::Mat& a, const cv::Mat& b) {
  cv::Mat diff;
  cv::compare(a, b, diff, cv::CMP_NE);
  return cv::countNonZero(diff);
}

cv::Mat Reference(const cv::Mat& gray8, int window, double offset) {
  cv::Mat dark;
  cv::adaptiveThreshold(gray8, dark, 255, cv::ADAPTIVE_THRESH_MEAN_C, cv::THRESH_BINARY_INV, window,
                        offset);
  return dark;
}

// Bit for bit OpenCV's mask, on noise (every level, so both outcomes of the
// test occur near every threshold; offsets of both signs, fractional, and
// beyond the 8-bit range) and on smooth dark dots on a bright ramp (the
// coarse stage's kind of image), with windows larger than the image and odd
// sizes (the borders and any vector loop's tail).
TEST(AdaptiveDarkMask, EqualsOpenCvAdaptiveThreshold) {
  cv::RNG rng(20261123);
  for (const cv::Size size :
       {cv::Size(1, 1), cv::Size(7, 5), cv::Size(33, 17), cv::Size(160, 121)}) {
    cv::Mat noise(size, CV_8UC1);
    rng.fill(noise, cv::RNG::UNIFORM, 0, 256);
    cv::Mat dots(size, CV_8UC1);
    for (int r = 0; r < size.height; ++r) {
      for (int c = 0; c < size.width; ++c) {
        const double ramp = 120.0 + 100.0 * c / std::max(1, size.width - 1);
        const double dot = std::cos(0.4 * c) * std::cos(0.3 * r) > 0.6 ? -90.0 : 0.0;
        dots.at<uchar>(r, c) = cv::saturate_cast<uchar>(ramp + dot + rng.gaussian(3.0));
      }
    }
    for (const cv::Mat& image : {noise, dots}) {
      for (const int window : {3, 5, 11, 101}) {
        for (const double offset : {0.0, 0.5, 10.2, -3.7, 255.0, 300.0, -300.0}) {
          const cv::Mat ours = AdaptiveDarkMask(image, window, offset);
          ASSERT_EQ(ours.type(), CV_8UC1);
          ASSERT_EQ(ours.size(), image.size());
          EXPECT_EQ(Differences(ours, Reference(image, window, offset)), 0)
              << size << " window " << window << " offset " << offset;
        }
      }
    }
  }
}

}  // namespace
}  // namespace omm
