#include "pipeline/calibration/spline_extrapolation.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>
#include <Eigen/Cholesky>
#include <Eigen/Geometry>

#include "adapters/mrcal/lens.h"
#include "adapters/mrcal/projection_diff.h"
#include "adapters/mrcal/uncertainty.h"
#include "pipeline/core/board.h"
#include "pipeline/core/plane_scene.h"
#include "pipeline/core/statistics.h"

namespace omm {

std::string SplineExtrapolationOptions::Check() const {
  if (grid_nx < 4 || grid_ny < 4) return "grid_nx and grid_ny must be >= 4";
  if (!(align_below_fraction > 0.0)) return "align_below_fraction must be positive";
  return "";
}

SplineExtrapolation ExtrapolateSplineByParametric(
    const CameraModel& spline, const CalibrationUncertainty& uncertainty,
    const CameraModel& parametric, const CalibrationUncertainty& parametric_uncertainty,
    double parametric_sigma_px, double distance_mm, const Eigen::Matrix3Xd& marks_cam,
    const SplineExtrapolationOptions& options) {
  SplineExtrapolation result;
  result.intrinsics = spline.intrinsics;
  result.parametric_model = parametric.lens_model;
  if (spline.lens_model.find("SPLINED") == std::string::npos) {
    result.why_not = "not a splined model";
    return result;
  }
  if (!(parametric_sigma_px > 0.0)) {
    result.why_not = "the parametric model's sigma is not positive";
    return result;
  }
  const ImagerUncertainty grid = ProjectionUncertaintyOverImager(uncertainty, spline, distance_mm,
                                                                 options.grid_nx, options.grid_ny);
  const Eigen::Matrix2Xd& q = grid.q_px;
  const Eigen::Index n = q.cols();
  Eigen::VectorXd sigma_s(n);
  // (Floored: a weight must stay finite.)
  for (Eigen::Index k = 0; k < n; ++k) sigma_s(k) = std::max(grid.points[k].worst_stdev_px, 1e-9);

  // The parametric camera's frame differs from the spline's by a small
  // rigid motion (each solve has its own plate poses): fitted, as mrcal's
  // projection_diff fits one, where the spline is far surer than the
  // parametric model's misfit, or over its surer half if that is nowhere
  // (a parametric model that fits the marks to their noise).
  const double align_below = std::max(options.align_below_fraction * parametric_sigma_px,
                                      Median(std::vector<double>(sigma_s.begin(), sigma_s.end())));
  std::vector<Eigen::Index> surer;
  for (Eigen::Index k = 0; k < n; ++k)
    if (sigma_s(k) <= align_below) surer.push_back(k);
  const ProjectionDiff aligned =
      FitRigidToProjections(grid.p_cam(Eigen::all, surer), q(Eigen::all, surer), parametric);
  if (!aligned.converged) {
    result.why_not = "the parametric model could not be aligned to the spline";
    return result;
  }
  Eigen::Matrix3Xd rays;
  if (!UnprojectPixels(parametric, q, &rays)) {
    result.why_not = "the parametric model does not map the imager";
    return result;
  }
  // Where it has no ray (beyond the fold of a strong radial term mrcal's
  // unprojection gives NaN) it is no target: the spline keeps its own there.
  std::vector<Eigen::Index> mapped;
  for (Eigen::Index k = 0; k < n; ++k)
    if (rays.col(k).allFinite()) mapped.push_back(k);
  result.num_without_parametric_ray =
      static_cast<int>(n - static_cast<Eigen::Index>(mapped.size()));
  if (mapped.empty()) {
    result.why_not = "the parametric model maps no pixel of the grid to a ray";
    return result;
  }
  const Eigen::Index m = static_cast<Eigen::Index>(mapped.size());
  Eigen::Matrix3Xd p_parametric(3, m);
  for (Eigen::Index j = 0; j < m; ++j)
    p_parametric.col(j) = distance_mm * rays.col(mapped[j]).normalized();
  // Its 1-sigma: the misfit, and its own projection uncertainty (the misfit
  // taken as noise, as mrcal does), which grows where its fit extrapolates.
  Eigen::VectorXd sigma_p(m);
  {
    const std::vector<PointUncertainty> own =
        ProjectionUncertainty(parametric_uncertainty, p_parametric);
    for (Eigen::Index j = 0; j < m; ++j)
      sigma_p(j) = std::hypot(parametric_sigma_px, own[j].worst_stdev_px);
  }
  // Its rays at the same range, into the spline's frame: p_s = R' (p_p - t).
  const Eigen::Matrix3d r = RotationFromAngleAxis(aligned.rt_b_from_a.head<3>());
  const Eigen::Vector3d t = aligned.rt_b_from_a.tail<3>();
  for (Eigen::Index j = 0; j < m; ++j)
    p_parametric.col(j) = r.transpose() * (p_parametric.col(j) - t);

  // Both targets' residuals and their gradients in the control points (the
  // intrinsics after the core's 4): the n spline targets, then the m
  // parametric ones.
  Eigen::Matrix3Xd p(3, n + m);
  p << grid.p_cam, p_parametric;
  Eigen::Matrix2Xd q_now;
  Eigen::MatrixXd dq_dintrinsics;
  if (!ProjectPoints(spline, p, &q_now, nullptr, &dq_dintrinsics)) {
    result.why_not = "mrcal refused to project through the spline";
    return result;
  }
  const int num_control = static_cast<int>(spline.intrinsics.size()) - 4;
  Eigen::MatrixXd normal = Eigen::MatrixXd::Zero(num_control, num_control);
  Eigen::VectorXd gradient = Eigen::VectorXd::Zero(num_control);
  for (Eigen::Index k = 0; k < n + m; ++k) {
    const double weight = k < n ? 1.0 / sigma_s(k) : 1.0 / sigma_p(k - n);
    const Eigen::MatrixXd j = weight * dq_dintrinsics.middleRows(2 * k, 2).rightCols(num_control);
    const Eigen::Vector2d residual = weight * (q_now.col(k) - q.col(k < n ? k : mapped[k - n]));
    normal.selfadjointView<Eigen::Lower>().rankUpdate(j.transpose());
    gradient += j.transpose() * residual;
  }
  // Control points no target reaches (their knots beyond the imager) keep
  // their values: a ridge far below every reached one's information.
  const double ridge = 1e-12 * normal.diagonal().maxCoeff();
  normal.diagonal().array() += ridge;
  const Eigen::VectorXd step = -normal.selfadjointView<Eigen::Lower>().ldlt().solve(gradient);
  if (!step.allFinite()) {
    result.why_not = "the least-squares step is not finite";
    return result;
  }
  result.intrinsics.tail(num_control) += step;

  // How far the spline's projection of its own rays and of the marks moved.
  CameraModel extrapolated = spline;
  extrapolated.intrinsics = result.intrinsics;
  Eigen::Matrix3Xd p_check(3, n + marks_cam.cols());
  p_check << grid.p_cam, marks_cam;
  Eigen::Matrix2Xd q_before, q_after;
  if (!ProjectPoints(spline, p_check, &q_before) ||
      !ProjectPoints(extrapolated, p_check, &q_after)) {
    result.why_not = "mrcal refused to project through the extrapolated spline";
    result.intrinsics = spline.intrinsics;
    return result;
  }
  const Eigen::VectorXd change = (q_after - q_before).colwise().norm();
  result.max_change_px = change.head(n).maxCoeff();
  if (marks_cam.cols() > 0)
    result.max_change_at_marks_px = change.tail(marks_cam.cols()).maxCoeff();
  result.applied = true;
  return result;
}

std::string DescribeSplineExtrapolation(const SplineExtrapolation& extrapolation,
                                        double parametric_sigma_px,
                                        const SplineExtrapolationOptions& options) {
  if (!extrapolation.applied) return "";
  std::string text = fmt::format(
      "beyond the marks, where its 1-sigma exceeds that of {}'s fit (its misfit {:.3f} px and "
      "its own uncertainty), the spline follows that fit (moved by up to {:.3f} px; {:.4f} px at "
      "the marks)",
      extrapolation.parametric_model, parametric_sigma_px, extrapolation.max_change_px,
      extrapolation.max_change_at_marks_px);
  if (extrapolation.num_without_parametric_ray > 0) {
    text += fmt::format(
        " except at {} of the {} x {} grid's points, where that fit has no ray (beyond its fold)",
        extrapolation.num_without_parametric_ray, options.grid_nx, options.grid_ny);
  }
  return text;
}

Eigen::Matrix3Xd InlierMarksInCamera(const CalibrationResult& result) {
  const Eigen::Matrix3Xd board = BoardPoints(result.record.board);
  std::vector<Eigen::Vector3d> marks;
  for (size_t i = 0; i < result.record.images.size(); ++i) {
    for (Eigen::Index k = 0; k < board.cols(); ++k)
      if (!result.record.images[i].outlier[k])
        marks.push_back(result.cam_from_plate[i] * board.col(k));
  }
  Eigen::Matrix3Xd marks_cam(3, static_cast<Eigen::Index>(marks.size()));
  for (size_t k = 0; k < marks.size(); ++k) marks_cam.col(static_cast<Eigen::Index>(k)) = marks[k];
  return marks_cam;
}

}  // namespace omm
