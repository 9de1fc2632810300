// mrcal's lens models behind LensProjection (pipeline/core/lens_projection.h),
// so the Ceres adjustment projects through the calibrated camera's own model.
#pragma once

#include "pipeline/core/camera.h"
#include "pipeline/core/lens_projection.h"

namespace omm {

class MrcalLensProjection : public LensProjection {
 public:
  // `camera` names the lens model and gives the intrinsics Project() is
  // usually called with.
  explicit MrcalLensProjection(CameraModel camera);
  int NumIntrinsics() const override;
  bool Project(const Eigen::Vector3d& p_cam, const double* intrinsics, Eigen::Vector2d* q_px,
               Matrix23d* dq_dp, RowMajorMatrix2Xd* dq_dintrinsics) const override;

 private:
  CameraModel camera_;
};

}  // namespace omm
