// The difference between two cameras' projections, after the rigid motion
// between their frames that explains it best (mrcal 2.2's projection_diff with
// use_uncertainties=False and an implied transformation at a finite distance).
//
// For pixels q_i on a grid over the imager, p_i = distance * unit ray of q_i
// through camera A. Fit T = B_from_A (rt) minimising
//   sum_i |project_B(T p_i) - q_i|^2
// (Levenberg-Marquardt, analytic gradients), and report the residual
// |project_B(T p_i) - q_i| in px. Unlike mrcal, which fits the transform on
// unit rays within a focus radius around the centre, we fit in pixels over the
// whole grid: the number reported is then exactly the quantity minimised, the
// stricter and simpler reading of "best rigid transform fitted".
#pragma once

#include <Eigen/Core>

#include "pipeline/core/calibration_result.h"
#include "pipeline/core/camera.h"

namespace omm {

struct ProjectionDiff {
  bool converged = false;
  double rms_px = 0.0;
  double max_px = 0.0;
  Vector6d rt_b_from_a = Vector6d::Zero();
  Eigen::Matrix2Xd q_px;   // grid pixels
  Eigen::VectorXd diff_px;  // per grid pixel
};

// The kernel: fits T minimising sum_i |project_B(T p_i) - q_i|^2 from T = 0
// for given points p (3 x N, A's frame) and pixels q (2 x N).
ProjectionDiff FitRigidToProjections(const Eigen::Matrix3Xd& p, const Eigen::Matrix2Xd& q_px,
                                     const CameraModel& camera_b);

// Preconditions: both cameras have the same imager size (assert); a grid of
// 2 x 2 or more (with fewer points the result is not converged).
ProjectionDiff FitProjectionDiff(const CameraModel& camera_a, const CameraModel& camera_b,
                                 double distance_mm, int grid_nx = 40, int grid_ny = 30);

// FitProjectionDiff(...).rms_px.
double ProjectionDiffRms(const CameraModel& camera_a, const CameraModel& camera_b,
                         double distance_mm, int grid_nx = 40, int grid_ny = 30);

}  // namespace omm
