// For the image readers' tests: OpenCV's imgcodecs as the reference decoder
// that omm's own readers (adapters/png, tiff, jpeg, netpbm) are checked
// against, and patterned images for it to encode. omm itself does not link
// imgcodecs (image_io.h says why).
#pragma once

#include <algorithm>
#include <cmath>
#include <optional>
#include <stdexcept>
#include <string_view>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/image.h"

namespace omm::testing {

// The file's image as OpenCV reads it (any depth, colour converted to gray
// by cvtColor), as gray samples.
inline StoredImage OpenCvGrayDecode(std::string_view bytes) {
  cv::Mat raw = cv::imdecode(
      cv::Mat(1, static_cast<int>(bytes.size()), CV_8U, const_cast<char*>(bytes.data())),
      cv::IMREAD_ANYDEPTH | cv::IMREAD_ANYCOLOR);
  if (raw.channels() == 3) cv::cvtColor(raw, raw, cv::COLOR_BGR2GRAY);
  if (raw.channels() == 4) cv::cvtColor(raw, raw, cv::COLOR_BGRA2GRAY);
  StoredImage image;
  image.width = raw.cols;
  image.height = raw.rows;
  image.bit_depth = raw.depth() == CV_16U ? 16 : 8;
  image.samples.assign(raw.data, raw.data + raw.total() * raw.elemSize());
  return image;
}

// A smooth pattern with fine detail in every channel, over the type's range
// (CV_8U or CV_16U, 1 to 4 channels).
inline cv::Mat PatternMat(int width, int height, int type) {
  cv::Mat mat(height, width, type);
  const double full = CV_MAT_DEPTH(type) == CV_16U ? 65535.0 : 255.0;
  const int channels = CV_MAT_CN(type);
  for (int r = 0; r < height; ++r) {
    for (int c = 0; c < width; ++c) {
      for (int k = 0; k < channels; ++k) {
        const double v = 0.5 + 0.3 * std::sin(0.05 * r * c / (1 + r % 7) + k) +
                         0.15 * std::cos(0.9 * c + 0.4 * r * (k + 1));
        const double sample = std::round(std::clamp(v, 0.0, 1.0) * full);
        if (CV_MAT_DEPTH(type) == CV_16U) {
          mat.ptr<ushort>(r)[c * channels + k] = static_cast<ushort>(sample);
        } else {
          mat.ptr<uchar>(r)[c * channels + k] = static_cast<uchar>(sample);
        }
      }
    }
  }
  return mat;
}

// Whether a reader's image `ours` is OpenCV's `theirs` (OpenCvGrayDecode):
// the same size, depth and samples; the failure says which differ.
inline ::testing::AssertionResult SameImage(const StoredImage& ours, const StoredImage& theirs) {
  if (ours.width != theirs.width || ours.height != theirs.height) {
    return ::testing::AssertionFailure() << ours.width << " x " << ours.height << " px, OpenCV's "
                                         << theirs.width << " x " << theirs.height;
  }
  if (ours.bit_depth != theirs.bit_depth) {
    return ::testing::AssertionFailure() << ours.bit_depth << " bit, OpenCV's " << theirs.bit_depth;
  }
  if (ours.samples != theirs.samples) return ::testing::AssertionFailure() << "samples differ";
  return ::testing::AssertionSuccess();
}

// The image of a reader that leaves other formats (nullopt); throws if it
// left this one.
inline StoredImage Taken(std::optional<StoredImage> image) {
  if (!image) throw std::runtime_error("the reader did not take the file");
  return std::move(*image);
}

inline std::string_view View(const std::vector<uchar>& bytes) {
  return {reinterpret_cast<const char*>(bytes.data()), bytes.size()};
}

}  // namespace omm::testing
