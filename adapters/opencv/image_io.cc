#include "adapters/opencv/image_io.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <system_error>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/error.h"

namespace omm {
namespace {

cv::Mat ReadRaw(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    throw InputError(path.string(), "image file not found");
  }
  cv::Mat raw;
  try {
    raw = cv::imread(path.string(), cv::IMREAD_ANYDEPTH | cv::IMREAD_ANYCOLOR);
  } catch (const cv::Exception& e) {
    throw InputError(path.string(), std::string("cannot decode image: ") + e.what());
  }
  if (raw.empty()) {
    throw InputError(path.string(),
                     "cannot decode image (corrupt, truncated or not a PNG/TIFF/JPEG file)");
  }
  if (raw.depth() != CV_8U && raw.depth() != CV_16U) {
    throw InputError(path.string(), "expected an 8- or 16-bit image");
  }
  return raw;
}

}  // namespace

GrayImage ReadGrayImage(const std::filesystem::path& path) {
  cv::Mat raw = ReadRaw(path);
  if (raw.channels() == 3) {
    cv::cvtColor(raw, raw, cv::COLOR_BGR2GRAY);
  } else if (raw.channels() == 4) {
    cv::cvtColor(raw, raw, cv::COLOR_BGRA2GRAY);
  } else if (raw.channels() != 1) {
    throw InputError(path.string(), "expected a gray or color image");
  }
  GrayImage image;
  image.bit_depth = raw.depth() == CV_16U ? 16 : 8;
  image.pixels.resize(raw.rows, raw.cols);
  // ImageF is row-major and contiguous: convert straight into its storage.
  cv::Mat as_float(raw.rows, raw.cols, CV_32F, image.pixels.data());
  raw.convertTo(as_float, CV_32F, 1.0 / ((1 << image.bit_depth) - 1));
  return image;
}

Eigen::Vector2i ReadImageSize(const std::filesystem::path& path) {
  // imgcodecs has no header-only query; decoding is the honest check that the
  // file is not corrupt anyway.
  const cv::Mat raw = ReadRaw(path);
  return {raw.cols, raw.rows};
}

void WriteGrayImage(const std::filesystem::path& path, const ImageF& pixels, int bit_depth) {
  if (bit_depth != 8 && bit_depth != 16) {
    throw InputError(path.string(), "can write 8- or 16-bit images only");
  }
  const cv::Mat as_float(static_cast<int>(pixels.rows()), static_cast<int>(pixels.cols()), CV_32F,
                         const_cast<float*>(pixels.data()));
  cv::Mat out;
  const double full_scale = (1 << bit_depth) - 1;
  as_float.convertTo(out, bit_depth == 16 ? CV_16U : CV_8U, full_scale);  // saturating, rounded
  std::filesystem::path tmp = path;
  tmp += ".tmp" + path.extension().string();
  bool ok = false;
  try {
    ok = cv::imwrite(tmp.string(), out);
  } catch (const cv::Exception&) {
    ok = false;
  }
  std::error_code ec;
  if (ok) std::filesystem::rename(tmp, path, ec);
  if (!ok || ec) {
    std::filesystem::remove(tmp, ec);
    throw InputError(path.string(), "cannot write image");
  }
}

std::string EncodePreviewPng(const ImageF& pixels, int max_width_px) {
  if (pixels.size() == 0 || max_width_px < 1) {
    throw std::invalid_argument("EncodePreviewPng: empty image or max_width_px < 1");
  }
  const cv::Mat as_float(static_cast<int>(pixels.rows()), static_cast<int>(pixels.cols()), CV_32F,
                         const_cast<float*>(pixels.data()));
  cv::Mat shrunk = as_float;
  if (as_float.cols > max_width_px) {
    const double scale = static_cast<double>(max_width_px) / as_float.cols;
    const int height = std::max(1, static_cast<int>(std::lround(as_float.rows * scale)));
    cv::resize(as_float, shrunk, cv::Size(max_width_px, height), 0, 0, cv::INTER_AREA);
  }
  cv::Mat out;
  shrunk.convertTo(out, CV_8U, 255.0);  // saturating, rounded
  std::vector<uchar> bytes;
  if (!cv::imencode(".png", out, bytes)) throw std::runtime_error("cv::imencode failed for PNG");
  return {bytes.begin(), bytes.end()};
}

}  // namespace omm
