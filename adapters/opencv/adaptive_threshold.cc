#include "adapters/opencv/adaptive_threshold.h"

#include <algorithm>
#include <cmath>
#include <cstdint>

#include <opencv2/imgproc.hpp>

namespace omm {

cv::Mat AdaptiveDarkMask(const cv::Mat& gray8, int window, double offset) {
  CV_Assert(gray8.type() == CV_8UC1 && window % 2 == 1 && window > 1);
  cv::Mat mean;
  cv::boxFilter(gray8, mean, CV_8U, cv::Size(window, window), cv::Point(-1, -1), true,
                cv::BORDER_REPLICATE | cv::BORDER_ISOLATED);
  // src - mean lies in [-255, 255], so the test runs in 16-bit lanes (twice
  // as many per vector as int's) with the offset clamped to where it still
  // decides anything.
  const auto limit = static_cast<std::int16_t>(-std::clamp(std::floor(offset), -256.0, 256.0));
  cv::Mat dark(gray8.size(), CV_8UC1);
  // The width in a local: a store through uchar* may alias gray8.cols, and
  // reloading it every pixel keeps the loop from being vectorised.
  const int cols = gray8.cols;
  for (int r = 0; r < gray8.rows; ++r) {
    const uchar* src = gray8.ptr<uchar>(r);
    const uchar* m = mean.ptr<uchar>(r);
    uchar* out = dark.ptr<uchar>(r);
    for (int c = 0; c < cols; ++c) {
      out[c] = static_cast<std::int16_t>(src[c] - m[c]) <= limit ? 255 : 0;
    }
  }
  return dark;
}

}  // namespace omm
