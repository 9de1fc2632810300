// Ceres cost functions of the planar bundle adjustment (pipeline/core/
// plane_scene.h states the model). Internal to adapters/ceres: the rest of the
// pipeline calls plane_bundle.h, which exposes no Ceres type.
//
// All Jacobians are analytic. The projection's dq/dp_cam and dq/dintrinsics
// come from a LensProjection (mrcal's analytic gradients); the rest is the
// chain rule through p_cam = R(r) X + t, X = P + T:
//   dp_cam/dr = -R [X]x J_r(r)   (J_r: SO(3)'s right Jacobian at r, so that
//                                  R(r + dr) = R(r) Exp(J_r(r) dr) to first order),
//   dp_cam/dt = I,   dp_cam/dT = dp_cam/dP = R[:, 0:2] (both in the plane).
#pragma once

#include <atomic>
#include <utility>
#include <vector>

#include <ceres/ceres.h>

#include <Eigen/Core>

#include "pipeline/core/lens_projection.h"

namespace omm {

// SO(3)'s right Jacobian of the angle-axis vector r:
// J_r = I - (1 - cos a)/a^2 [r]x + (a - sin a)/a^3 [r]x^2, a = |r|.
Eigen::Matrix3d RightJacobianSO3(const Eigen::Vector3d& r);

// How a reprojection cost takes the intrinsics k (N = lens.NumIntrinsics()).
// Default (no ranges): one parameter block, all of k. Else one block per
// (start, size) in `ranges` (ascending, disjoint), k[start, start + size),
// and the intrinsics in no range read from `others` (N values; those in a
// range are ignored): exact while the projection does not depend on them
// (LensProjection::IntrinsicsBlocksNear), which Evaluate checks through
// dq/dintrinsics. Where it does, Evaluate fails and counts in *num_outside.
struct IntrinsicsBlocks {
  std::vector<std::pair<int, int>> ranges;
  const double* others = nullptr;
  std::atomic<int>* num_outside = nullptr;  // may be null
};

// The part-frame point X = P + T that a track's point P is at with the table
// at T (both in the plane z = 0), mm.
Eigen::Vector3d MovedTrackPoint(const double* table_pos_mm, const double* point_xy_mm);
// A plate mark's X = (x + s M(theta) (u, v), h) + T (PlateMarkReprojectionCost).
Eigen::Vector3d MovedPlateMark(const double* table_pos_mm, const double* plate_pose,
                               double height_mm, double plate_scale,
                               const Eigen::Vector2d& mark_uv_mm);

// Residual (2, dimensionless): (weight / sigma_px) (q(R (P + T) + t) - q_px),
// q through `lens`, P = (P_x, P_y, 0), T = (T_x, T_y, 0).
// Parameter blocks: r (3, angle-axis, rad), t (3, mm), T (2, mm), P (2, mm),
// then the intrinsics (IntrinsicsBlocks). A point the lens cannot project
// makes Evaluate fail (Ceres then shortens the step).
class TrackReprojectionCost : public ceres::CostFunction {
 public:
  TrackReprojectionCost(const LensProjection& lens, const Eigen::Vector2d& q_px,
                        double weight_over_sigma_px);
  // The residual scaled by a 2 x 2 matrix (weight * shape / sigma_px,
  // TrackObservation) instead.
  TrackReprojectionCost(const LensProjection& lens, const Eigen::Vector2d& q_px,
                        const Eigen::Matrix2d& scale, IntrinsicsBlocks intrinsics = {});
  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

 private:
  const LensProjection& lens_;
  Eigen::Vector2d q_px_;
  Eigen::Matrix2d scale_;  // weight shape / sigma_px, 1/px
  IntrinsicsBlocks intrinsics_;
};

// Residual (2, dimensionless): (weight / sigma_px) (q(R (P + T) + t) - q_px)
// for a plate mark with plate coordinates (u, v):
//   P = (x, y, h) + s M(theta) (u, v, 0)-in-plane, M(theta) = [c  s; s  -c].
// Parameter blocks: r (3), t (3), T (2), plate pose (x mm, y mm, theta rad),
// plate height h (1, mm), plate scale s (1), then the intrinsics
// (IntrinsicsBlocks).
class PlateMarkReprojectionCost : public ceres::CostFunction {
 public:
  PlateMarkReprojectionCost(const LensProjection& lens, const Eigen::Vector2d& mark_uv_mm,
                            const Eigen::Vector2d& q_px, double weight_over_sigma_px,
                            IntrinsicsBlocks intrinsics = {});
  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

 private:
  const LensProjection& lens_;
  Eigen::Vector2d mark_uv_mm_;
  Eigen::Vector2d q_px_;
  double scale_;
  IntrinsicsBlocks intrinsics_;
};

// Residual (2, dimensionless): (T - T_commanded) / sigma_mm. Block: T (2, mm).
class TablePriorCost : public ceres::SizedCostFunction<2, 2> {
 public:
  TablePriorCost(const Eigen::Vector2d& commanded_mm, double sigma_mm);
  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

 private:
  Eigen::Vector2d commanded_mm_;
  double sigma_mm_;
};

// Residual (N, dimensionless): U (k - k_calibrated), U^T U = the calibration's
// information matrix (U from its Cholesky factor), so the cost is the
// Gaussian prior's 0.5 (k - k0)^T Info (k - k0). Blocks: the intrinsics k
// (N), or k[block_starts[b], block_starts[b + 1]) for each b
// (LensProjection::IntrinsicsBlockStarts).
class IntrinsicsPriorCost : public ceres::CostFunction {
 public:
  // `information` (N x N) must be positive definite over the intrinsics not
  // in `held` (ascending); those have no residual and a zero Jacobian.
  IntrinsicsPriorCost(const Eigen::VectorXd& calibrated, const Eigen::MatrixXd& information,
                      const std::vector<int>& held, std::vector<int> block_starts = {});
  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

 private:
  Eigen::VectorXd calibrated_;
  std::vector<int> free_;             // the residuals' intrinsics
  Eigen::MatrixXd sqrt_information_;  // U of the free block, upper triangular
  std::vector<int> block_starts_;     // {0, N} for one block
};

}  // namespace omm
