#include "adapters/opencv/opencv_calibration.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <thread>

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/error.h"
#include "pipeline/core/timing.h"

namespace omm {
namespace {

cv::Mat ToGray8(const GrayImage& image) {
  const cv::Mat as_float(image.height(), image.width(), CV_32F, const_cast<float*>(image.pixels.data()));
  cv::Mat gray8;
  as_float.convertTo(gray8, CV_8U, 255.0);
  return gray8;
}

// Reverses the rows of a mirrored grid (see the header).
void MakeProper(const BoardSpec& board, std::vector<cv::Point2f>* points) {
  auto at = [&](int r, int c) { return (*points)[static_cast<size_t>(r * board.cols + c)]; };
  cv::Point2f along_row(0, 0), down_column(0, 0);
  for (int r = 0; r < board.rows; ++r) along_row += at(r, board.cols - 1) - at(r, 0);
  for (int c = 0; c < board.cols; ++c) down_column += at(board.rows - 1, c) - at(0, c);
  if (along_row.x * down_column.y - along_row.y * down_column.x >= 0.0f) return;
  std::vector<cv::Point2f> flipped(points->size());
  for (int r = 0; r < board.rows; ++r) {
    for (int c = 0; c < board.cols; ++c) {
      flipped[static_cast<size_t>(r * board.cols + c)] = at(board.rows - 1 - r, c);
    }
  }
  *points = std::move(flipped);
}

// The board's points in image `gray8`, or the reason there are none.
bool Detect(const cv::Mat& gray8, const BoardSpec& board, const OpenCvCalibrationOptions& options,
            std::vector<cv::Point2f>* points, std::string* why_not) {
  const cv::Size pattern(board.cols, board.rows);
  if (board.type == BoardType::kChessboard) {
    if (!cv::findChessboardCorners(gray8, pattern, *points,
                                   cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE)) {
      *why_not = "findChessboardCorners failed";
      return false;
    }
    const int half = options.chessboard_subpix_half_window_px;
    cv::cornerSubPix(gray8, *points, cv::Size(half, half), cv::Size(-1, -1),
                     cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 30, 0.01));
    return true;
  }
  cv::SimpleBlobDetector::Params params;
  params.minArea = static_cast<float>(options.min_blob_area_px);
  params.maxArea = static_cast<float>(options.max_blob_area_fraction * gray8.total());
  params.filterByCircularity = true;
  params.minCircularity = static_cast<float>(options.min_circularity);
  const cv::Ptr<cv::FeatureDetector> detector = cv::SimpleBlobDetector::create(params);
  if (!cv::findCirclesGrid(gray8, pattern, *points, cv::CALIB_CB_SYMMETRIC_GRID, detector)) {
    *why_not = "findCirclesGrid failed";
    return false;
  }
  MakeProper(board, points);
  return true;
}

Eigen::Isometry3d ToIsometry(const cv::Mat& rvec, const cv::Mat& tvec) {
  cv::Mat r;
  cv::Rodrigues(rvec, r);
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) pose.linear()(i, j) = r.at<double>(i, j);
    pose.translation()(i) = tvec.at<double>(i);
  }
  return pose;
}

}  // namespace

std::string OpenCvCalibrationOptions::Check() const {
  if (!(min_blob_area_px > 0.0)) return "min_blob_area_px must be > 0";
  if (!(max_blob_area_fraction > 0.0 && max_blob_area_fraction < 1.0)) return "max_blob_area_fraction must be in (0, 1)";
  if (!(min_circularity >= 0.0 && min_circularity <= 1.0)) return "min_circularity must be in [0, 1]";
  if (chessboard_subpix_half_window_px < 2) return "chessboard_subpix_half_window_px must be >= 2";
  if (num_threads < 1) return "num_threads must be >= 1";
  return {};
}

OpenCvCalibration OpenCvCalibrate(const std::vector<GrayImage>& images, const std::vector<std::string>& names,
                                  const BoardSpec& board, const OpenCvCalibrationOptions& options) {
  if (std::string why = options.Check(); !why.empty()) throw InputError("", "OpenCV calibration options: " + why);
  if (!names.empty() && names.size() != images.size()) throw InputError("", "OpenCV calibration: one name per image");
  OpenCvCalibration result;
  if (images.empty()) {
    result.brief = "no images";
    return result;
  }
  const cv::Size size(images.front().width(), images.front().height());
  for (const GrayImage& image : images) {
    if (image.width() != size.width || image.height() != size.height) {
      throw InputError("", "OpenCV calibration: all images must have one size");
    }
  }

  const auto detection_start = std::chrono::steady_clock::now();
  const size_t n_images = images.size();
  std::vector<std::vector<cv::Point2f>> detected(n_images);
  std::vector<std::string> why_not(n_images);
  std::vector<char> found(n_images, 0);
  std::atomic<size_t> next{0};
  auto worker = [&] {
    for (size_t i = next++; i < n_images; i = next++) {
      found[i] = Detect(ToGray8(images[i]), board, options, &detected[i], &why_not[i]);
    }
  };
  std::vector<std::thread> threads;
  for (int t = 1; t < options.num_threads; ++t) threads.emplace_back(worker);
  worker();
  for (std::thread& thread : threads) thread.join();
  result.detection_seconds = SecondsSince(detection_start);

  const Eigen::Matrix3Xd plate = BoardPoints(board);
  std::vector<cv::Point3f> object;
  for (Eigen::Index m = 0; m < plate.cols(); ++m) {
    object.emplace_back(static_cast<float>(plate(0, m)), static_cast<float>(plate(1, m)), 0.0f);
  }
  std::vector<std::vector<cv::Point3f>> object_points;
  std::vector<std::vector<cv::Point2f>> image_points;
  result.per_image.resize(n_images);
  for (size_t i = 0; i < n_images; ++i) {
    OpenCvImageStatus& status = result.per_image[i];
    if (!names.empty()) status.image = names[i];
    status.used = found[i];
    status.why_not_used = why_not[i];
    if (!found[i]) continue;
    object_points.push_back(object);
    image_points.push_back(detected[i]);
  }
  const std::string model = options.rational_model ? "LENSMODEL_OPENCV8" : "LENSMODEL_OPENCV5";
  if (image_points.size() < 3) {
    result.brief = model + ": only " + std::to_string(image_points.size()) + " images detected (need 3)";
    return result;
  }

  int flags = options.rational_model ? cv::CALIB_RATIONAL_MODEL : 0;
  cv::Mat camera_matrix = cv::Mat::eye(3, 3, CV_64F);
  if (options.fix_aspect_ratio) flags |= cv::CALIB_FIX_ASPECT_RATIO;  // keeps fx / fy of the guess: 1
  cv::Mat dist;
  std::vector<cv::Mat> rvecs, tvecs;
  const auto solve_start = std::chrono::steady_clock::now();
  result.rms_px = cv::calibrateCamera(object_points, image_points, size, camera_matrix, dist, rvecs, tvecs, flags);
  result.solve_seconds = SecondsSince(solve_start);

  const int n_dist = options.rational_model ? 8 : 5;
  result.camera.lens_model = model;
  result.camera.width_px = size.width;
  result.camera.height_px = size.height;
  result.camera.intrinsics.resize(4 + n_dist);
  result.camera.intrinsics << camera_matrix.at<double>(0, 0), camera_matrix.at<double>(1, 1),
      camera_matrix.at<double>(0, 2), camera_matrix.at<double>(1, 2), Eigen::VectorXd::Zero(n_dist);
  for (int k = 0; k < n_dist && k < static_cast<int>(dist.total()); ++k) {
    result.camera.intrinsics(4 + k) = dist.at<double>(k);
  }
  size_t used = 0;
  for (size_t i = 0; i < n_images; ++i) {
    if (!found[i]) continue;
    std::vector<cv::Point2f> projected;
    cv::projectPoints(object, rvecs[used], tvecs[used], camera_matrix, dist, projected);
    double sum_sq = 0.0;
    for (size_t m = 0; m < projected.size(); ++m) {
      const cv::Point2f d = projected[m] - detected[i][m];
      sum_sq += d.dot(d);
    }
    result.per_image[i].rms_px = std::sqrt(sum_sq / static_cast<double>(projected.size()));
    result.cam_from_plate.push_back(ToIsometry(rvecs[used], tvecs[used]));
    ++used;
  }
  result.usable = std::isfinite(result.rms_px);
  char brief[160];
  std::snprintf(brief, sizeof(brief), "%s (OpenCV calibrateCamera): %zu of %zu images, rms %.3f px", model.c_str(),
                used, n_images, result.rms_px);
  result.brief = brief;
  return result;
}

}  // namespace omm
