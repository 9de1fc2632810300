// mrcal's lens models behind LensProjection (pipeline/core/lens_projection.h),
// so the Ceres adjustment projects through the calibrated camera's own model.
#pragma once

#include <memory>

#include "pipeline/core/camera.h"
#include "pipeline/core/lens_projection.h"

namespace omm {

class MrcalLensProjection : public LensProjection {
 public:
  // `camera` names the lens model and gives the intrinsics Project() is
  // usually called with (Project() fails if they do not fit the model).
  explicit MrcalLensProjection(CameraModel camera);
  int NumIntrinsics() const override;
  bool Project(const Eigen::Vector3d& p_cam, const double* intrinsics, Eigen::Vector2d* q_px,
               Matrix23d* dq_dp, RowMajorMatrix2Xd* dq_dintrinsics) const override;
  // Splined models: the core (fx, fy, cx, cy) is block 0, then each row of
  // knots in blocks of about order + 2 knots (both values of each); other
  // models: one block.
  std::vector<int> IntrinsicsBlockStarts() const override;
  std::vector<int> IntrinsicsBlocksNear(const Eigen::Vector3d& p_cam, const double* intrinsics,
                                        double radius_px) const override;

 private:
  struct Lens;                        // mrcal's parsed lens model
  std::shared_ptr<const Lens> lens_;  // null if the camera's model is invalid
  CameraModel camera_;
};

}  // namespace omm
