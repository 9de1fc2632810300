#include "adapters/mrcal/uncertainty.h"

#include <algorithm>
#include <cassert>
#include <cmath>

#include <Eigen/Dense>

#include "adapters/mrcal/lens.h"
#include "adapters/mrcal/mrcal_problem.h"
#include "pipeline/core/gauss_newton.h"
#include "pipeline/core/statistics.h"

namespace omm {
namespace {

}  // namespace

std::optional<CalibrationUncertainty> CalibrationUncertainty::Compute(const SolveRecord& record,
                                                                      double observed_sigma_px,
                                                                      std::string* why_not) {
  auto fail = [&](const std::string& why) -> std::optional<CalibrationUncertainty> {
    if (why_not) *why_not = why;
    return std::nullopt;
  };
  const mrcal_internal::Problem problem = mrcal_internal::ToProblem(record);
  Eigen::VectorXd x;
  Eigen::SparseMatrix<double, Eigen::RowMajor> J_packed;
  if (!mrcal_internal::EvaluateCallback(problem, &x, &J_packed)) {
    return fail("mrcal_optimizer_callback failed");
  }
  CalibrationUncertainty u;
  u.camera_ = record.camera;
  const int n_state = problem.NumStates();
  const int n_frames = static_cast<int>(problem.frames_toref.size());
  const int n_obs = static_cast<int>(problem.observations.size());
  const mrcal_problem_selections_t& sel = problem.selections;
  if (sel.do_optimize_intrinsics_core || sel.do_optimize_intrinsics_distortions) {
    u.istate_intrinsics_ = mrcal_state_index_intrinsics(0, 1, 0, n_frames, 0, 0, n_obs, sel,
                                                        &problem.lensmodel);
    const int n_intrinsics = static_cast<int>(record.camera.intrinsics.size());
    const bool has_core = mrcal_lensmodel_metadata(&problem.lensmodel).has_core;
    const int n_core = has_core ? 4 : 0;
    u.first_optimized_intrinsic_ = sel.do_optimize_intrinsics_core ? 0 : n_core;
    const int end = sel.do_optimize_intrinsics_distortions ? n_intrinsics : n_core;
    u.num_optimized_intrinsics_ = end - u.first_optimized_intrinsic_;
  }
  if (sel.do_optimize_frames) {
    u.istate_frames_ =
        mrcal_state_index_frames(0, 1, 0, n_frames, 0, 0, n_obs, sel, &problem.lensmodel);
  }
  for (const mrcal_pose_t& pose : problem.frames_toref) {
    Eigen::Matrix<double, 6, 1> rt;
    rt << pose.r.x, pose.r.y, pose.r.z, pose.t.x, pose.t.y, pose.t.z;
    u.rt_cam_from_board_mrcal_.push_back(rt);
  }

  // Input noise: std of the inlier board residuals (mrcal.residuals_chessboard).
  if (observed_sigma_px > 0.0) {
    u.observed_sigma_px_ = observed_sigma_px;
  } else {
    double sum = 0.0, sum_sq = 0.0;
    int count = 0;
    for (size_t k = 0; k < problem.pool.size(); ++k) {
      if (problem.pool[k].z <= 0.0) continue;
      for (int d = 0; d < 2; ++d) {
        const double r = x[2 * static_cast<Eigen::Index>(k) + d];
        sum += r;
        sum_sq += r * r;
        ++count;
      }
    }
    if (count == 0) return fail("no inlier observations");
    const double mean = sum / count;
    u.observed_sigma_px_ = std::sqrt(std::max(0.0, sum_sq / count - mean * mean));
  }

  // Var(b*) = sigma^2 H^-1 J*obs' J*obs H^-1, H = J*'J*; then Var(b) = D Var(b*) D.
  const Eigen::MatrixXd H = DenseNormalMatrix(J_packed);
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(H);
  if (ldlt.info() != Eigen::Success || !ldlt.isPositive() ||
      ldlt.vectorD().minCoeff() <= 1e-12 * ldlt.vectorD().maxCoeff()) {
    return fail("J'J is singular: the calibration does not constrain its state");
  }
  // The Gram matrix of J*obs H^-1 (its lower half, by a rank update),
  // positive semi-definite by construction, as the intrinsics prior needs (a
  // rational model's nearly redundant parameters leave correlation
  // eigenvalues at the rounding level). Forming
  // H^-1 J*obs' J*obs H^-1 from a factor of J*obs' J*obs instead is 4x
  // faster on a splined model but squares J*obs' conditioning: on the demo's
  // OPENCV8 solve its error grows from 5e-11 to 6e-7 of H^-1's scale.
  const int n_obs_rows = problem.NumMeasurementsBoards();
  const Eigen::SparseMatrix<double, Eigen::RowMajor> J_obs = J_packed.topRows(n_obs_rows);
  const Eigen::MatrixXd H_inv = ldlt.solve(Eigen::MatrixXd::Identity(n_state, n_state));
  const Eigen::MatrixXd JobsHinv = J_obs * H_inv;
  Eigen::MatrixXd covariance_packed = Eigen::MatrixXd::Zero(n_state, n_state);
  covariance_packed.selfadjointView<Eigen::Lower>().rankUpdate(JobsHinv.transpose());
  const Eigen::VectorXd D = mrcal_internal::UnpackScale(problem);
  u.state_covariance_ = u.observed_sigma_px_ * u.observed_sigma_px_ * D.asDiagonal() *
                        Eigen::MatrixXd(covariance_packed.selfadjointView<Eigen::Lower>()) *
                        D.asDiagonal();
  return u;
}

Eigen::MatrixXd CalibrationUncertainty::IntrinsicsCovariance() const {
  const int n = static_cast<int>(camera_.intrinsics.size());
  Eigen::MatrixXd covariance = Eigen::MatrixXd::Zero(n, n);
  if (istate_intrinsics_ < 0) return covariance;
  const int k = num_optimized_intrinsics_;
  covariance.block(first_optimized_intrinsic_, first_optimized_intrinsic_, k, k) =
      state_covariance_.block(istate_intrinsics_, istate_intrinsics_, k, k);
  return covariance;
}

Eigen::MatrixXd CalibrationUncertainty::ProjectionStateJacobian(const Eigen::Matrix3Xd& p_cam,
                                                                Eigen::Matrix2Xd* q_px) const {
  const int n = static_cast<int>(p_cam.cols());
  Eigen::Matrix2Xd q;
  Eigen::MatrixXd dq_dp, dq_dintrinsics;
  const bool projected = ProjectPoints(camera_, p_cam, &q, &dq_dp, &dq_dintrinsics);
  assert(projected);
  (void)projected;
  if (q_px) *q_px = q;
  Eigen::MatrixXd dq_db = Eigen::MatrixXd::Zero(2 * n, NumStates());
  if (istate_intrinsics_ >= 0) {
    dq_db.middleCols(istate_intrinsics_, num_optimized_intrinsics_) =
        dq_dintrinsics.middleCols(first_optimized_intrinsic_, num_optimized_intrinsics_);
  }
  if (istate_frames_ >= 0) {
    const int n_frames = static_cast<int>(rt_cam_from_board_mrcal_.size());
    for (int f = 0; f < n_frames; ++f) {
      const Eigen::Matrix<double, 6, 1>& rt = rt_cam_from_board_mrcal_[f];
      for (int i = 0; i < n; ++i) {
        // p_f = T_f^-1 p_cam, then d(T_f p_f)/drt_f at the solved T_f.
        double p_frame[3];
        mrcal_transform_point_rt_inverted(p_frame, nullptr, nullptr, rt.data(),
                                          p_cam.col(i).data());
        double dpref_drt[18];  // 3 x 6 row-major
        double p_back[3];
        mrcal_transform_point_rt(p_back, dpref_drt, nullptr, rt.data(), p_frame);
        const Eigen::Map<const Eigen::Matrix<double, 3, 6, Eigen::RowMajor>> J(dpref_drt);
        dq_db.block<2, 6>(2 * i, istate_frames_ + 6 * f) =
            dq_dp.block<2, 3>(2 * i, 0) * J / static_cast<double>(n_frames);
      }
    }
  }
  return dq_db;
}

Eigen::MatrixXd CalibrationUncertainty::ProjectionCovariance(const Eigen::Matrix3Xd& p_cam) const {
  return Propagate(ProjectionStateJacobian(p_cam));
}

Eigen::MatrixXd CalibrationUncertainty::Propagate(const Eigen::MatrixXd& dF_db) const {
  return dF_db * state_covariance_ * dF_db.transpose();
}

PointUncertainty SummarizeCovariance(const Eigen::Matrix2d& covariance_px2) {
  PointUncertainty point;
  point.covariance_px2 = covariance_px2;
  const double a = covariance_px2(0, 0), b = covariance_px2(1, 0), c = covariance_px2(1, 1);
  point.rms_stdev_px = std::sqrt(std::max(0.0, 0.5 * (a + c)));
  point.worst_stdev_px =
      std::sqrt(std::max(0.0, 0.5 * (a + c) + std::sqrt(0.25 * (a - c) * (a - c) + b * b)));
  return point;
}

std::vector<PointUncertainty> ProjectionUncertainty(const CalibrationUncertainty& uncertainty,
                                                    const Eigen::Matrix3Xd& p_cam) {
  std::vector<PointUncertainty> points;
  const Eigen::MatrixXd dq_db = uncertainty.ProjectionStateJacobian(p_cam);
  for (int i = 0; i < p_cam.cols(); ++i) {
    points.push_back(SummarizeCovariance(uncertainty.Propagate(dq_db.middleRows(2 * i, 2))));
  }
  return points;
}

Eigen::Matrix3Xd ImagerGridPoints(const CameraModel& camera, double distance_mm, int grid_nx,
                                  int grid_ny, Eigen::Matrix2Xd* q_px) {
  Eigen::Matrix2Xd q(2, grid_nx * grid_ny);
  for (int j = 0; j < grid_ny; ++j) {
    for (int i = 0; i < grid_nx; ++i) {
      q.col(j * grid_nx + i) << i * (camera.width_px - 1.0) / (grid_nx - 1),
          j * (camera.height_px - 1.0) / (grid_ny - 1);
    }
  }
  Eigen::Matrix3Xd v;
  const bool unprojected = UnprojectPixels(camera, q, &v);
  assert(unprojected);
  (void)unprojected;
  v.colwise().normalize();
  if (q_px) *q_px = q;
  return distance_mm * v;
}

ImagerUncertainty ProjectionUncertaintyOverImager(const CalibrationUncertainty& uncertainty,
                                                  const CameraModel& camera, double distance_mm,
                                                  int grid_nx, int grid_ny) {
  ImagerUncertainty result;
  result.distance_mm = distance_mm;
  result.p_cam = ImagerGridPoints(camera, distance_mm, grid_nx, grid_ny, &result.q_px);
  result.points = ProjectionUncertainty(uncertainty, result.p_cam);
  std::vector<double> worst, rms;
  for (const PointUncertainty& point : result.points) {
    worst.push_back(point.worst_stdev_px);
    rms.push_back(point.rms_stdev_px);
  }
  result.typical_worst_stdev_px = Median(worst);
  result.max_worst_stdev_px = worst.empty() ? 0.0 : *std::max_element(worst.begin(), worst.end());
  result.typical_rms_stdev_px = Median(rms);
  return result;
}

}  // namespace omm
