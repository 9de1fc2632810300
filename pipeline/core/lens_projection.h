// A lens model's projection with its analytic derivatives, as an interface.
//
// Optimisers (adapters/ceres) need q = project(p_cam; intrinsics) and its
// Jacobians but must not depend on the adapter that implements the lens model
// (adapters/mrcal): the stage that wires them passes an implementation of this
// interface (adapters/mrcal/mrcal_lens_projection.h wraps mrcal_project).
#pragma once

#include <vector>

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

  // The intrinsics in blocks over which dq_dintrinsics is sparse (a splined
  // model's projection depends on its core and the few knots around the
  // point): block b is intrinsics [starts[b], starts[b + 1]), starts running
  // from 0 to NumIntrinsics(). An optimiser that gives each block its own
  // parameters sees that sparsity. Default: one block.
  virtual std::vector<int> IntrinsicsBlockStarts() const { return {0, NumIntrinsics()}; }

  // The blocks (ascending indices into IntrinsicsBlockStarts()) that q
  // depends on at p_cam and at every point whose pixel is within radius_px of
  // its pixel (to first order in the projection). Default: all.
  virtual std::vector<int> IntrinsicsBlocksNear(const Eigen::Vector3d& /*p_cam*/,
                                                const double* /*intrinsics*/,
                                                double /*radius_px*/) const {
    std::vector<int> all(IntrinsicsBlockStarts().size() - 1);
    for (int b = 0; b < static_cast<int>(all.size()); ++b) all[b] = b;
    return all;
  }
};

}  // namespace omm
