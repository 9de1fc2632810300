// The result of a camera calibration solve, and the record that lets a later
// run recompute everything from it (residuals, outliers, the projection
// uncertainty) without the images.
//
// The solve is mrcal's (adapters/mrcal/calibrate.h): one camera at the
// reference frame, the plate's poses as "frames", a lens model, optional plate
// warp. Conventions are those of camera.h: cam_from_plate maps plate points
// (board.h's BoardPoints: centred on the plate, mm, z = 0 on its face) into the
// camera frame; rotations are angle-axis (mrcal's r), rt = (r, t).
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "pipeline/core/board.h"
#include "pipeline/core/camera.h"

namespace omm {

using Vector6d = Eigen::Matrix<double, 6, 1>;

// What the solve optimises (mrcal_problem_selections_t in our words). The
// camera sits at the reference, so there are no extrinsics.
struct CalibrationProblem {
  bool optimize_intrinsics_core = true;         // fx, fy, cx, cy
  bool optimize_intrinsics_distortions = true;  // the lens model's other parameters
  bool optimize_frames = true;                  // the plate poses
  bool optimize_calobject_warp = false;         // the plate's 2-parameter flex
  bool apply_regularization = true;             // mrcal's regularisation terms
  bool apply_outlier_rejection = true;          // mrcal may flag new outliers
};

// One image of the plate as the solve used it.
struct SolveImage {
  std::string image;  // file name in calib/
  // Observed mark centres, BoardPoints' order (2 x rows*cols), px.
  Eigen::Matrix2Xd q_px;
  // mrcal's weight per mark (residual = weight * (q - q_observed)); a mark
  // with weight 0 was not observed and is never used.
  Eigen::VectorXd weight;
  // Marks the solve ignored: unobserved (weight 0) or rejected as outliers.
  std::vector<bool> outlier;
  Vector6d rt_cam_from_plate = Vector6d::Zero();  // the solved plate pose
};

// Everything needed to rebuild mrcal's optimisation problem at the optimum:
// with it, mrcal_optimizer_callback reproduces the residuals and Jacobian, and
// so the uncertainty. Saved as JSON (adapters/mrcal/solve_record_json.h).
struct SolveRecord {
  BoardSpec board;
  CameraModel camera;  // lens model, solved intrinsics, imager size
  std::vector<SolveImage> images;
  Eigen::Vector2d calobject_warp = Eigen::Vector2d::Zero();  // mrcal's (x2, y2)
  CalibrationProblem problem;
};

struct ImageResidual {
  std::string image;
  // Over the image's inlier marks, per coordinate as mrcal reports it:
  // sqrt(sum |weight * dq|^2 / (2 * num_inliers)).
  double rms_px = 0.0;
  int num_inliers = 0;
  int num_outliers = 0;  // outliers found by the solve (not unobserved marks)
};

// What a calibration produced. When !usable, `brief` says why and the other
// fields may be empty.
struct CalibrationResult {
  bool usable = false;
  std::string brief;  // one line: model, images, rms, outliers
  CameraModel camera;
  double rms_px = 0.0;  // mrcal's rms_reproj_error__pixels: per coordinate, inliers
  int num_observations_used = 0;  // inlier marks
  int num_outliers = 0;           // marks flagged as outliers by the solve
  std::vector<ImageResidual> per_image;  // parallel to record.images
  std::vector<Eigen::Isometry3d> cam_from_plate;  // parallel to record.images
  Eigen::Vector2d calobject_warp = Eigen::Vector2d::Zero();
  std::vector<std::string> images_not_used;  // unusable observations, by name
  SolveRecord record;
};

}  // namespace omm
