// A lens model's projection with its analytic derivatives, as an interface.
//
// Optimisers (adapters/ceres) need q = project(p_cam; intrinsics) and its
// Jacobians but must not depend on the adapter that implements the lens model
// (adapters/mrcal): the stage that wires them passes an implementation of this
// interface (adapters/mrcal/mrcal_lens_projection.h wraps mrcal_project).
#pragma once

#include <Eigen/Core>

namespace omm {

using Matrix23d = Eigen::Matrix<double, 2, 3>;
using RowMajorMatrix2Xd = Eigen::Matrix<double, 2, Eigen::Dynamic, Eigen::RowMajor>;

class LensProjection {
 public:
  virtual ~LensProjection() = default;

  // Length of the intrinsics vector (mrcal's: fx, fy, cx, cy, distortions).
  virtual int NumIntrinsics() const = 0;

  // Projects one camera-frame point p_cam (mm, z forward) with the given
  // intrinsics (NumIntrinsics() values) to q_px (centre of the top-left pixel
  // at (0, 0)). If non-null, also dq_dp (2 x 3) and dq_dintrinsics
  // (2 x NumIntrinsics, resized by the callee only if its size is wrong).
  // Returns false where the model cannot project (e.g. behind the camera).
  // Must be safe to call concurrently from several threads.
  virtual bool Project(const Eigen::Vector3d& p_cam, const double* intrinsics,
                       Eigen::Vector2d* q_px, Matrix23d* dq_dp,
                       RowMajorMatrix2Xd* dq_dintrinsics) const = 0;
};

}  // namespace omm
