// The coarse stage's dark mask: cv::adaptiveThreshold(ADAPTIVE_THRESH_MEAN_C,
// THRESH_BINARY_INV) computed with the same box mean (cv::boxFilter,
// replicated border) and the same integer test, src - mean <= -floor(offset),
// as a plain loop the compiler vectorises. OpenCV's test goes through a
// 768-entry lookup table byte by byte: 0.35 G of cv::adaptiveThreshold's
// 0.75 G instructions on the demo's 18 calibration images, 0.05 G here.
// Internal to the OpenCV adapter (cv::Mat in and out).
#pragma once

#include <opencv2/core.hpp>

namespace omm {

// 255 where gray8 <= (its window x window box mean) - floor(offset), else 0:
// bit for bit cv::adaptiveThreshold(gray8, dark, 255, ADAPTIVE_THRESH_MEAN_C,
// THRESH_BINARY_INV, window, offset). Preconditions: gray8 is CV_8UC1 and
// window is odd and > 1.
cv::Mat AdaptiveDarkMask(const cv::Mat& gray8, int window, double offset);

}  // namespace omm
