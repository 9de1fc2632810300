#include "adapters/mrcal/mrcal_lens_projection.h"

#include <utility>

#include "adapters/mrcal/mrcal_c.h"

namespace omm {

struct MrcalLensProjection::Lens {
  mrcal_lensmodel_t model;
};

MrcalLensProjection::MrcalLensProjection(CameraModel camera) : camera_(std::move(camera)) {
  auto lens = std::make_shared<Lens>();
  if (mrcal_lensmodel_from_name(&lens->model, camera_.lens_model.c_str()) &&
      mrcal_lensmodel_type_is_valid(lens->model.type) &&
      mrcal_lensmodel_num_params(&lens->model) == camera_.intrinsics.size())
    lens_ = std::move(lens);
}

int MrcalLensProjection::NumIntrinsics() const {
  return static_cast<int>(camera_.intrinsics.size());
}

bool MrcalLensProjection::Project(const Eigen::Vector3d& p_cam, const double* intrinsics,
                                  Eigen::Vector2d* q_px, Matrix23d* dq_dp,
                                  RowMajorMatrix2Xd* dq_dintrinsics) const {
  // mrcal_project on the one point, the lens model parsed once: the Ceres
  // costs call this per residual (ProjectPoints' parsing and buffers were
  // half of its cost). With one point mrcal's dq_dp is right without
  // dq_dintrinsics (lens.cc's caveat is about the points after the first).
  if (lens_ == nullptr) return false;
  mrcal_point3_t dq_dp_rows[2];
  if (dq_dintrinsics != nullptr) {
    dq_dintrinsics->resize(2, NumIntrinsics());
    dq_dintrinsics->setZero();
  }
  if (!mrcal_project(
          reinterpret_cast<mrcal_point2_t*>(q_px->data()), dq_dp != nullptr ? dq_dp_rows : nullptr,
          dq_dintrinsics != nullptr ? dq_dintrinsics->data() : nullptr,
          reinterpret_cast<const mrcal_point3_t*>(p_cam.data()), 1, &lens_->model, intrinsics))
    return false;
  if (dq_dp != nullptr) {
    for (int i = 0; i < 2; ++i)
      for (int k = 0; k < 3; ++k) (*dq_dp)(i, k) = dq_dp_rows[i].xyz[k];
  }
  return true;
}

}  // namespace omm
