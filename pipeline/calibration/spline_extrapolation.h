// A splined lens beyond the calibration marks, guided by a parametric fit.
//
// Why. A splined model follows any smooth lens where the marks were, but
// beyond them mrcal's regularisation pulls its control points toward the bare
// stereographic projection. On lens-mismatch seed 341 (marks reaching x
// 127..1461, y 128..1076 of 1600 x 1200 px) the spline was 0.02 px from the
// truth within 50 px of a mark and 7.5 px RMS (27 px at worst) more than
// 200 px from one, where the OPENCV8 fit of the same images, ~0.8 px off
// everywhere, was 2.6 px off. The tiles and the user's own checks use the
// whole imager.
//
// Model. Two estimates of the projection of each pixel's ray: the spline's,
// with its stated projection 1-sigma sigma_s (mrcal's uncertainty: ~0.01 px
// among the marks, growing without bound beyond them), and the parametric
// fit's, aligned to the spline by the rigid motion that best maps the one's
// rays on the other's where the spline is far the surer (its surer half if
// that is nowhere: a parametric fit as good as the marks). The parametric
// fit's 1-sigma sigma_p combines its misfit (its residual sigma over the
// marks) and its own projection uncertainty with that misfit taken as noise
// (as mrcal does), which grows where its fit extrapolates: a rational
// OPENCV8 can fold in the corners (lens-mismatch seed 347: 13.8 px off there,
// the spline 4.2). On a grid over the imager both are targets for the
// spline's control points, weighted 1/sigma:
//   min_c  sum_k |q(c; p_s,k) - q_k|^2 / sigma_s,k^2 + |q(c; p_p,k) - q_k|^2 / sigma_p,k^2
// (p_s,k, p_p,k: pixel q_k's ray under each; a pixel the parametric model maps
// to no ray, beyond the fold of a strong radial term, has no second term).
// Where the marks were, on a lens the parametric model cannot represent,
// sigma_s << sigma_p and the spline is unchanged (to (sigma_s / sigma_p)^2 of
// the difference; on one it can, the two are averaged there too); far beyond
// them it follows the parametric model. The spline's projection is linear in
// its control points (q = f (u + du(u)) + c, du a B-spline of u), so one
// least-squares step is the exact minimum; the core (f, c) is kept.
//
// The result is no longer mrcal's optimum of its own problem: the solve
// record keeps the extrapolated intrinsics, whose projection of the marks is
// the same to well below their noise, and the stated uncertainty stays
// mrcal's (conservative beyond the marks).
#pragma once

#include <string>

#include <Eigen/Core>

#include "pipeline/core/calibration_result.h"
#include "pipeline/core/camera.h"

namespace omm {

class CalibrationUncertainty;

struct SplineExtrapolationOptions {
  // Targets: a grid_nx x grid_ny grid spanning the imager, ~80 px apart on
  // 1600 x 1200 px (two per knot interval of the stage's 10-knot spline;
  // 41 x 31 cost 0.05 s more and did no better over 14 seeds).
  int grid_nx = 21;
  int grid_ny = 16;
  // The parametric model is aligned to the spline where sigma_s is below
  // this fraction of the parametric model's misfit (or below its median).
  double align_below_fraction = 0.1;

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

struct SplineExtrapolation {
  bool applied = false;
  std::string why_not;           // when !applied
  std::string parametric_model;  // the lens model followed beyond the marks
  Eigen::VectorXd intrinsics;    // the spline's, extrapolated (same core)
  // The largest change of the spline's projection over the grid and at the
  // marks, px.
  double max_change_px = 0.0;
  double max_change_at_marks_px = 0.0;
  // Grid points where the parametric model has no ray (beyond its fold):
  // no target there.
  int num_without_parametric_ray = 0;
};

// `spline`: a solved LENSMODEL_SPLINED_* camera and `uncertainty` its
// solve's; `parametric`: a parametric camera solved on the same
// observations, with residual sigma `parametric_sigma_px`; `distance_mm`:
// the range the rays are taken at (the working distance); `marks_cam`: the
// solve's inlier marks in the camera frame (3 x N, mm), where the change is
// reported.
SplineExtrapolation ExtrapolateSplineByParametric(
    const CameraModel& spline, const CalibrationUncertainty& uncertainty,
    const CameraModel& parametric, const CalibrationUncertainty& parametric_uncertainty,
    double parametric_sigma_px, double distance_mm, const Eigen::Matrix3Xd& marks_cam,
    const SplineExtrapolationOptions& options = {});

// What an applied `extrapolation` did, for the lens choice's why: where the
// spline follows the parametric fit (whose residual sigma is
// `parametric_sigma_px`), how far it moved, and at how many grid points of
// `options` that fit has no ray. Empty if it was not applied.
std::string DescribeSplineExtrapolation(const SplineExtrapolation& extrapolation,
                                        double parametric_sigma_px,
                                        const SplineExtrapolationOptions& options = {});

// The solve's inlier marks through its solved poses, in the camera frame
// (3 x N, mm): ExtrapolateSplineByParametric's marks_cam.
Eigen::Matrix3Xd InlierMarksInCamera(const CalibrationResult& result);

}  // namespace omm
