// Projection through a mrcal lens model, on Eigen types.
//
// q = project(p; lens_model, intrinsics): camera-frame points p (mm, z forward)
// to pixels q (centre of the top-left pixel at (0, 0)). These wrap
// mrcal_project / mrcal_unproject (mrcal 2.2) so no mrcal type leaves this
// adapter.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pipeline/core/camera.h"

namespace omm {

// True if `lens_model` is a mrcal lens-model name mrcal can use (configured
// where the model needs a configuration).
bool IsValidLensModel(const std::string& lens_model);

// Number of intrinsics of a lens model (4 core + distortions); -1 if invalid.
int LensModelNumParams(const std::string& lens_model);

// Projects N camera-frame points (3 x N) to pixels (2 x N). Optional outputs:
// dq_dp (2N x 3: rows 2i, 2i+1 are point i's dq/dp), dq_dintrinsics
// (2N x Nintrinsics, same row layout). Returns false if mrcal refuses.
bool ProjectPoints(const CameraModel& camera, const Eigen::Matrix3Xd& p_cam,
                   Eigen::Matrix2Xd* q_px, Eigen::MatrixXd* dq_dp = nullptr,
                   Eigen::MatrixXd* dq_dintrinsics = nullptr);

// Unprojects pixels (2 x N) to camera-frame directions (3 x N) with z = 1
// (observation rays). Iterative inside mrcal: far slower than ProjectPoints.
bool UnprojectPixels(const CameraModel& camera, const Eigen::Matrix2Xd& q_px,
                     Eigen::Matrix3Xd* v_cam);

// The first of the pixels (2 x N) that the lens maps to no ray in front of
// the camera projecting back within tolerance_px; nullopt if every one does.
// mrcal's unprojection leaves NaN where it finds no ray: beyond the fold of a
// strong radial polynomial, or where a splined model extrapolates past the
// knots that marks constrained.
std::optional<Eigen::Vector2d> FirstUnmappedPixel(const CameraModel& camera,
                                                  const Eigen::Matrix2Xd& q_px,
                                                  double tolerance_px);

// Which of the camera-frame points p_cam (3 x N) the lens folds into the
// image: their pixels q_px (2 x N, ProjectPoints') lie within near_px of the
// image, but each pixel's ray (UnprojectPixels) points more than 1e-4 rad
// away from its point. Beyond the fold of a strong radial polynomial the
// lens maps points far outside its field back into the image (OPENCV8 takes
// a point 57 deg off the axis of a 16-deg-wide lens to a pixel whose ray
// points elsewhere). False for points behind the camera, pixels farther out,
// and every point if the lens model is invalid.
std::vector<bool> FoldedIntoTheImage(const CameraModel& camera, const Eigen::Matrix3Xd& p_cam,
                                     const Eigen::Matrix2Xd& q_px, double near_px);

}  // namespace omm
