#include "adapters/opencv/opencv_stitcher.h"

#include <chrono>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/stitching.hpp>

#include "pipeline/core/error.h"

namespace omm {
namespace {

const char* StatusName(cv::Stitcher::Status status) {
  switch (status) {
    case cv::Stitcher::OK: return "OK";
    case cv::Stitcher::ERR_NEED_MORE_IMGS: return "ERR_NEED_MORE_IMGS";
    case cv::Stitcher::ERR_HOMOGRAPHY_EST_FAIL: return "ERR_HOMOGRAPHY_EST_FAIL";
    case cv::Stitcher::ERR_CAMERA_PARAMS_ADJUST_FAIL: return "ERR_CAMERA_PARAMS_ADJUST_FAIL";
  }
  return "unknown status";
}

cv::Mat AsMat(const ImageF& image) {
  return cv::Mat(static_cast<int>(image.rows()), static_cast<int>(image.cols()), CV_32F,
                 const_cast<float*>(image.data()));
}

}  // namespace

std::string OpenCvStitcherOptions::Check() const {
  if (num_threads < 1) return "num_threads must be >= 1";
  return "";
}

OpenCvStitcherResult StitchScans(const std::vector<ImageF>& tiles,
                                 const OpenCvStitcherOptions& options) {
  if (const std::string why = options.Check(); !why.empty()) {
    throw InputError("OpenCvStitcherOptions", why);
  }
  if (tiles.empty()) throw InputError("StitchScans", "no tiles");
  std::vector<cv::Mat> images;
  for (const ImageF& tile : tiles) {
    cv::Mat gray8, bgr;
    AsMat(tile).convertTo(gray8, CV_8U, 255.0);
    cv::cvtColor(gray8, bgr, cv::COLOR_GRAY2BGR);
    images.push_back(bgr);
  }
  const int threads_before = cv::getNumThreads();
  cv::setNumThreads(options.num_threads);
  const auto start = std::chrono::steady_clock::now();
  cv::Ptr<cv::Stitcher> stitcher = cv::Stitcher::create(cv::Stitcher::SCANS);
  cv::Mat panorama;
  const cv::Stitcher::Status status = stitcher->stitch(images, panorama);
  OpenCvStitcherResult result;
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  cv::setNumThreads(threads_before);
  result.status = StatusName(status);
  result.ok = status == cv::Stitcher::OK && !panorama.empty();
  if (!result.ok) return result;
  result.tiles_used = static_cast<int>(stitcher->component().size());
  cv::Mat gray8, gray;
  cv::cvtColor(panorama, gray8, cv::COLOR_BGR2GRAY);
  gray8.convertTo(gray, CV_32F, 1.0 / 255.0);
  result.panorama.resize(gray.rows, gray.cols);
  for (int r = 0; r < gray.rows; ++r) {
    const float* row = gray.ptr<float>(r);
    for (int c = 0; c < gray.cols; ++c) result.panorama(r, c) = row[c];
  }
  return result;
}

Eigen::Vector2d FindPatch(const ImageF& image, const ImageF& patch, double* score) {
  cv::Mat response;
  cv::matchTemplate(AsMat(image), AsMat(patch), response, cv::TM_CCOEFF_NORMED);
  double best = 0.0;
  cv::Point at;
  cv::minMaxLoc(response, nullptr, &best, nullptr, &at);
  if (score) *score = best;
  return {at.x + 0.5 * (static_cast<double>(patch.cols()) - 1.0),
          at.y + 0.5 * (static_cast<double>(patch.rows()) - 1.0)};
}

}  // namespace omm
