#include "adapters/mrcal/lens.h"

#include <cmath>
#include <vector>

#include <Eigen/Geometry>

#include "adapters/mrcal/mrcal_c.h"

namespace omm {
namespace {

bool ParseLensModel(const std::string& name, mrcal_lensmodel_t* lensmodel) {
  return mrcal_lensmodel_from_name(lensmodel, name.c_str()) &&
         mrcal_lensmodel_type_is_valid(lensmodel->type);
}

}  // namespace

bool IsValidLensModel(const std::string& lens_model) {
  mrcal_lensmodel_t lensmodel;
  return ParseLensModel(lens_model, &lensmodel);
}

int LensModelNumParams(const std::string& lens_model) {
  mrcal_lensmodel_t lensmodel;
  if (!ParseLensModel(lens_model, &lensmodel)) return -1;
  return mrcal_lensmodel_num_params(&lensmodel);
}

bool ProjectPoints(const CameraModel& camera, const Eigen::Matrix3Xd& p_cam,
                   Eigen::Matrix2Xd* q_px, Eigen::MatrixXd* dq_dp,
                   Eigen::MatrixXd* dq_dintrinsics) {
  mrcal_lensmodel_t lensmodel;
  if (!ParseLensModel(camera.lens_model, &lensmodel)) return false;
  const int n_intrinsics = mrcal_lensmodel_num_params(&lensmodel);
  if (camera.intrinsics.size() != n_intrinsics) return false;
  const int n = static_cast<int>(p_cam.cols());
  // Eigen's column-major 3 x N / 2 x N layouts are exactly mrcal's arrays of
  // mrcal_point3_t / mrcal_point2_t.
  q_px->resize(2, n);
  std::vector<mrcal_point3_t> dq_dp_buf(dq_dp ? 2 * n : 0);
  // mrcal 2.2 fills dq_dp correctly for N > 1 only when dq_dintrinsics is
  // requested too (without it, every point but the first gets zeros), so ask
  // for both whenever dq_dp is wanted.
  const bool want_dq_di = dq_dintrinsics != nullptr || dq_dp != nullptr;
  std::vector<double> dq_di_buf(want_dq_di ? 2 * n * n_intrinsics : 0);
  const bool ok = mrcal_project(
      reinterpret_cast<mrcal_point2_t*>(q_px->data()), dq_dp ? dq_dp_buf.data() : nullptr,
      want_dq_di ? dq_di_buf.data() : nullptr,
      reinterpret_cast<const mrcal_point3_t*>(p_cam.data()), n, &lensmodel,
      camera.intrinsics.data());
  if (!ok) return false;
  if (dq_dp) {
    dq_dp->resize(2 * n, 3);
    for (int i = 0; i < 2 * n; ++i) {
      for (int k = 0; k < 3; ++k) (*dq_dp)(i, k) = dq_dp_buf[i].xyz[k];
    }
  }
  if (dq_dintrinsics) {
    dq_dintrinsics->resize(2 * n, n_intrinsics);
    for (int i = 0; i < 2 * n; ++i) {
      for (int k = 0; k < n_intrinsics; ++k) {
        (*dq_dintrinsics)(i, k) = dq_di_buf[static_cast<size_t>(i) * n_intrinsics + k];
      }
    }
  }
  return true;
}

bool UnprojectPixels(const CameraModel& camera, const Eigen::Matrix2Xd& q_px,
                     Eigen::Matrix3Xd* v_cam) {
  mrcal_lensmodel_t lensmodel;
  if (!ParseLensModel(camera.lens_model, &lensmodel)) return false;
  if (camera.intrinsics.size() != mrcal_lensmodel_num_params(&lensmodel)) return false;
  const int n = static_cast<int>(q_px.cols());
  v_cam->resize(3, n);
  if (!mrcal_unproject(reinterpret_cast<mrcal_point3_t*>(v_cam->data()),
                       reinterpret_cast<const mrcal_point2_t*>(q_px.data()), n, &lensmodel,
                       camera.intrinsics.data())) {
    return false;
  }
  for (int i = 0; i < n; ++i) v_cam->col(i) /= (*v_cam)(2, i);
  return true;
}

std::optional<Eigen::Vector2d> FirstUnmappedPixel(const CameraModel& camera,
                                                  const Eigen::Matrix2Xd& q_px,
                                                  double tolerance_px) {
  Eigen::Matrix3Xd v;
  Eigen::Matrix2Xd q_back;
  if (q_px.cols() == 0) return std::nullopt;
  if (!UnprojectPixels(camera, q_px, &v)) return q_px.col(0);
  // Rays with z = 1 (UnprojectPixels): a failed one is NaN, or points behind.
  Eigen::Matrix3Xd p = v;
  for (Eigen::Index i = 0; i < p.cols(); ++i) {
    if (!p.col(i).allFinite()) p.col(i) = Eigen::Vector3d::UnitZ();  // projected, then refused below
  }
  if (!ProjectPoints(camera, p, &q_back)) return q_px.col(0);
  for (Eigen::Index i = 0; i < q_px.cols(); ++i) {
    if (!v.col(i).allFinite() || !((q_back.col(i) - q_px.col(i)).norm() <= tolerance_px))
      return q_px.col(i);
  }
  return std::nullopt;
}

std::vector<bool> FoldedIntoTheImage(const CameraModel& camera, const Eigen::Matrix3Xd& p_cam,
                                     const Eigen::Matrix2Xd& q_px, double near_px) {
  // 1e-4 rad is 0.27 px at a 2670 px focal length and far above the
  // unprojection's error; a folded point's ray is degrees away.
  constexpr double kMaxRayAngleRad = 1e-4;
  std::vector<bool> folded(static_cast<size_t>(p_cam.cols()), false);
  std::vector<Eigen::Index> near;
  for (Eigen::Index i = 0; i < p_cam.cols(); ++i) {
    if (p_cam(2, i) > 0 && q_px.col(i).allFinite() && q_px(0, i) > -near_px &&
        q_px(1, i) > -near_px && q_px(0, i) < camera.width_px - 1 + near_px &&
        q_px(1, i) < camera.height_px - 1 + near_px) {
      near.push_back(i);
    }
  }
  Eigen::Matrix2Xd q_near(2, near.size());
  for (size_t k = 0; k < near.size(); ++k) q_near.col(k) = q_px.col(near[k]);
  Eigen::Matrix3Xd rays;
  if (near.empty() || !UnprojectPixels(camera, q_near, &rays)) return folded;
  for (size_t k = 0; k < near.size(); ++k) {
    const Eigen::Vector3d ray = rays.col(k);
    const Eigen::Vector3d point = p_cam.col(near[k]);
    folded[static_cast<size_t>(near[k])] =
        !ray.allFinite() || std::atan2(ray.cross(point).norm(), ray.dot(point)) > kMaxRayAngleRad;
  }
  return folded;
}

}  // namespace omm
