#include "adapters/mrcal/mrcal_lens_projection.h"

#include <algorithm>
#include <utility>

#include "adapters/mrcal/lens.h"

namespace omm {

MrcalLensProjection::MrcalLensProjection(CameraModel camera) : camera_(std::move(camera)) {}

int MrcalLensProjection::NumIntrinsics() const {
  return static_cast<int>(camera_.intrinsics.size());
}

bool MrcalLensProjection::Project(const Eigen::Vector3d& p_cam, const double* intrinsics,
                                  Eigen::Vector2d* q_px, Matrix23d* dq_dp,
                                  RowMajorMatrix2Xd* dq_dintrinsics) const {
  // ProjectPoints takes a CameraModel: copy it only when the intrinsics differ
  // from the held ones (they do not while the intrinsics are held constant,
  // the common case), which keeps this call allocation-light and thread-safe.
  const double* held = camera_.intrinsics.data();
  const bool same = std::equal(held, held + NumIntrinsics(), intrinsics);
  CameraModel changed;
  if (!same) {
    changed = camera_;
    changed.intrinsics = Eigen::Map<const Eigen::VectorXd>(intrinsics, NumIntrinsics());
  }
  Eigen::Matrix2Xd q;
  Eigen::MatrixXd dp, di;
  if (!ProjectPoints(same ? camera_ : changed, p_cam, &q, dq_dp ? &dp : nullptr,
                     dq_dintrinsics ? &di : nullptr)) {
    return false;
  }
  *q_px = q.col(0);
  if (dq_dp) *dq_dp = dp;
  if (dq_dintrinsics) *dq_dintrinsics = di;
  return true;
}

}  // namespace omm
