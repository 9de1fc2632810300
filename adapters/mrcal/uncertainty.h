// Projection uncertainty of a calibration, as mrcal 2.2 defines it
// (model_analysis.py: projection_uncertainty, _projection_uncertainty,
// _propagate_calibration_uncertainty; http://mrcal.secretsauce.net/uncertainty.html).
//
// Input noise. The observed mark centres carry i.i.d. noise of sigma
// (weighted) px. Unless given, sigma is estimated as mrcal does: the standard
// deviation (mean removed, ddof 0) of all x and y weighted residuals of the
// inlier marks at the optimum.
//
// State noise. With J the Jacobian of mrcal's measurement vector (board
// residuals, then regularisation) at the optimum and J_obs its board rows,
//   Var(b) = sigma^2 (J'J)^-1 J_obs' J_obs (J'J)^-1.
// mrcal works in its packed, unitless state b* (b = D b*, J* = J D^-1); so do
// we: Var(b*) from J* of mrcal_optimizer_callback, then Var(b) = D Var(b*) D.
//
// Projection of a camera-frame point p_cam (at a finite distance, mrcal's
// atinfinity=False) through a noisy solve. The camera frame is not observable
// on its own: it is tied to the plates. mrcal maps p_cam into every plate's
// frame with the solved poses, maps each back with the (noisy) poses and
// averages:  p_ref = 1/N sum_f T_f (T_f0^-1 p_cam), the camera at the
// reference, so
//   dq/db = [ dq/dintrinsics , dq/dp * dT_f(p_f)/drt_f / N  for every f ],
//   Var(q) = dq/db Var(b) dq/db'  (2x2 per point; joint 2N x 2N for N points).
// Summaries as mrcal's 'worstdirection-stdev' (sqrt of the larger eigenvalue)
// and 'rms-stdev' (sqrt(trace/2)).
//
// Linear algebra: the state is small (4 + distortions + 6 per plate + 2:
// ~120 for OPENCV8 and 18 plates, a few hundred for a splined model), so J'J is
// formed from Eigen's sparse J* and factored densely (Eigen::LDLT), and Var(b)
// is kept whole: any later quantity's variance is then a product.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/calibration_result.h"

namespace omm {

class CalibrationUncertainty {
 public:
  // Builds Var(b) at the record's state (which must be the optimum of its
  // problem). observed_sigma_px <= 0: estimate it from the residuals. Returns
  // nullopt, with *why_not set, if mrcal fails or J'J is singular.
  static std::optional<CalibrationUncertainty> Compute(const SolveRecord& record,
                                                       double observed_sigma_px = 0.0,
                                                       std::string* why_not = nullptr);

  double observed_sigma_px() const { return observed_sigma_px_; }

  // Var(b) in full units, Nstate x Nstate, mrcal's state order.
  const Eigen::MatrixXd& StateCovariance() const { return state_covariance_; }
  int NumStates() const { return static_cast<int>(state_covariance_.rows()); }

  // Var(intrinsics), full units, Nintrinsics x Nintrinsics in the lens
  // model's parameter order; rows/columns of parameters the solve held fixed
  // are 0.
  Eigen::MatrixXd IntrinsicsCovariance() const;

  // dq/db (2N x Nstate, full units; rows 2i, 2i+1 for point i) of the
  // projections of camera-frame points (3 x N, mm) under mrcal's mean-frames
  // handling described above, and the projections themselves.
  Eigen::MatrixXd ProjectionStateJacobian(const Eigen::Matrix3Xd& p_cam,
                                          Eigen::Matrix2Xd* q_px = nullptr) const;

  // Joint covariance of the projections of N camera-frame points, 2N x 2N px^2.
  Eigen::MatrixXd ProjectionCovariance(const Eigen::Matrix3Xd& p_cam) const;

  // Var(F) = dF/db Var(b) dF/db' for any F given dF/db (M x Nstate, full
  // units): the hook for later stages' own quantities.
  Eigen::MatrixXd Propagate(const Eigen::MatrixXd& dF_db) const;

 private:
  CameraModel camera_;
  std::vector<Eigen::Matrix<double, 6, 1>> rt_cam_from_board_mrcal_;  // frames_toref
  int istate_intrinsics_ = -1;  // -1: intrinsics not optimised
  int first_optimized_intrinsic_ = 0;
  int num_optimized_intrinsics_ = 0;
  int istate_frames_ = -1;  // -1: frames not optimised
  double observed_sigma_px_ = 0.0;
  Eigen::MatrixXd state_covariance_;
};

struct PointUncertainty {
  Eigen::Matrix2d covariance_px2 = Eigen::Matrix2d::Zero();
  double rms_stdev_px = 0.0;    // sqrt(trace / 2): mrcal's 'rms-stdev'
  double worst_stdev_px = 0.0;  // sqrt(max eigenvalue): 'worstdirection-stdev'
};

PointUncertainty SummarizeCovariance(const Eigen::Matrix2d& covariance_px2);

// Per-point uncertainty of projecting camera-frame points (3 x N, mm).
std::vector<PointUncertainty> ProjectionUncertainty(const CalibrationUncertainty& uncertainty,
                                                    const Eigen::Matrix3Xd& p_cam);

// The imager sampled on a grid_nx x grid_ny grid (mrcal.sample_imager:
// linspace(0, W-1) x linspace(0, H-1)), each pixel's ray at range distance_mm
// (p = distance * unit ray, mrcal's convention), and its uncertainty.
struct ImagerUncertainty {
  double distance_mm = 0.0;
  Eigen::Matrix2Xd q_px;  // grid pixels, row-major over the grid (x fastest)
  Eigen::Matrix3Xd p_cam;
  std::vector<PointUncertainty> points;
  double typical_worst_stdev_px = 0.0;  // median of worst_stdev_px
  double max_worst_stdev_px = 0.0;
  double typical_rms_stdev_px = 0.0;  // median of rms_stdev_px
};

// Camera-frame points of the grid described above (3 x nx*ny).
Eigen::Matrix3Xd ImagerGridPoints(const CameraModel& camera, double distance_mm, int grid_nx,
                                  int grid_ny, Eigen::Matrix2Xd* q_px = nullptr);

ImagerUncertainty ProjectionUncertaintyOverImager(const CalibrationUncertainty& uncertainty,
                                                  const CameraModel& camera, double distance_mm,
                                                  int grid_nx = 16, int grid_ny = 12);

}  // namespace omm
