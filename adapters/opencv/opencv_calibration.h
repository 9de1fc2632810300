// OpenCV's own calibration pipeline, as a typical user runs it: the baseline
// omm's detector + mrcal solve is compared with (benchmarks/, tests).
//
// Detection per image:
// - caltab and circles: cv::findCirclesGrid (CALIB_CB_SYMMETRIC_GRID) on the
//   whole image, with a SimpleBlobDetector a user would tune for these plates:
//   dark blobs of mark-like size, circularity >= min_circularity (which drops
//   the caltab's corner triangle, circularity 0.54; a dot seen at 45 deg
//   keeps > 0.95); the centres are OpenCV's blob centres (centroids of the
//   thresholded blobs, merged over thresholds). No perspective-bias correction.
// - chessboard: cv::findChessboardCorners + cv::cornerSubPix with a fixed
//   window (OpenCV's sample uses 11 x 11).
// Images where detection fails are skipped and listed with the reason.
// For the symmetric grids OpenCV may return a mirrored order; it is reversed
// so that the board is seen from its printed side (a mirrored board has no
// rigid pose). Its remaining 90/180-degree ambiguity does not matter to the
// intrinsics: the board's points map onto themselves.
//
// Solve: cv::calibrateCamera on all detected images with the plate points of
// BoardPoints (z = 0), the 5-parameter model (k1, k2, p1, p2, k3) or, with
// rational_model, CALIB_RATIONAL_MODEL's 8 (k1, k2, p1, p2, k3, k4, k5, k6).
// The result is returned as LENSMODEL_OPENCV5 / LENSMODEL_OPENCV8, whose
// parameter order is OpenCV's: fx, fy, cx, cy, k1, k2, p1, p2, k3[, k4, k5, k6].
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "pipeline/core/board.h"
#include "pipeline/core/camera.h"
#include "pipeline/core/image.h"

namespace omm {

struct OpenCvCalibrationOptions {
  bool rational_model = false;    // CALIB_RATIONAL_MODEL (OPENCV8) instead of OPENCV5
  bool fix_aspect_ratio = false;  // CALIB_FIX_ASPECT_RATIO (fx / fy held at 1)
  // Blob detector for the dot grids.
  double min_blob_area_px = 25.0;        // px^2
  double max_blob_area_fraction = 0.01;  // of the image area
  double min_circularity = 0.8;          // 4 pi area / perimeter^2
  int chessboard_subpix_half_window_px = 11;  // cornerSubPix winSize (half), px
  int num_threads = 1;  // detection threads (calibrateCamera itself is serial)

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

struct OpenCvImageStatus {
  std::string image;
  bool used = false;
  std::string why_not_used;  // set when !used
  double rms_px = 0.0;       // reprojection rms of this image's points (per point, 2D), px
};

struct OpenCvCalibration {
  bool usable = false;
  std::string brief;  // one line: model, images, rms (or why not usable)
  CameraModel camera;  // LENSMODEL_OPENCV5 or LENSMODEL_OPENCV8
  double rms_px = 0.0;  // calibrateCamera's return: rms over all points (2D distance), px
  std::vector<OpenCvImageStatus> per_image;  // parallel to the input images
  // Pose of each USED image's plate, in input order of the used images.
  std::vector<Eigen::Isometry3d> cam_from_plate;
  double detection_seconds = 0.0;  // wall time of the detection
  double solve_seconds = 0.0;      // wall time of calibrateCamera
};

// Calibrates from `images` (names: same size as images, or empty). All
// images must have one size. Throws InputError if the options are invalid or
// the images differ in size; fewer than 3 detected images is a result with
// usable == false.
OpenCvCalibration OpenCvCalibrate(const std::vector<GrayImage>& images, const std::vector<std::string>& names,
                                  const BoardSpec& board, const OpenCvCalibrationOptions& options = {});

}  // namespace omm
