#include "adapters/ceres/plane_costs.h"

#include <cmath>

#include <Eigen/Cholesky>
#include <Eigen/Geometry>

#include "pipeline/core/plane_scene.h"

namespace omm {
namespace {

using RowMajorMatrix23d = Eigen::Matrix<double, 2, 3, Eigen::RowMajor>;
using RowMajorMatrix22d = Eigen::Matrix<double, 2, 2, Eigen::RowMajor>;

Eigen::Matrix3d Skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return m;
}

// The part shared by both reprojection costs: residual of the moved part
// point X = P + T and its Jacobians with respect to r, t, X and the
// intrinsics. `jacobians` is Ceres' array; index_r/t/intrinsics name the
// blocks. On return *dres_dx holds d residual / dX when X's Jacobian is
// needed by the caller (want_dx).
bool ReprojectMovedPoint(const LensProjection& lens, const Eigen::Vector2d& q_observed_px,
                         double scale, const double* r_data, const double* t_data,
                         const double* intrinsics, const Eigen::Vector3d& x_part,
                         double* residuals, double** jacobians, int index_r, int index_t,
                         int index_intrinsics, bool want_dx, Matrix23d* dres_dx) {
  const Eigen::Map<const Eigen::Vector3d> r(r_data);
  const Eigen::Map<const Eigen::Vector3d> t(t_data);
  const Eigen::Matrix3d cam_from_part = RotationFromAngleAxis(r);
  const Eigen::Vector3d p_cam = cam_from_part * x_part + t;

  const bool want_pose = jacobians != nullptr && (jacobians[index_r] != nullptr ||
                                                  jacobians[index_t] != nullptr);
  const bool want_intrinsics = jacobians != nullptr && jacobians[index_intrinsics] != nullptr;
  const bool want_dp = want_pose || want_dx;

  Eigen::Vector2d q_px;
  Matrix23d dq_dp;
  RowMajorMatrix2Xd dq_dintrinsics;
  if (!lens.Project(p_cam, intrinsics, &q_px, want_dp ? &dq_dp : nullptr,
                    want_intrinsics ? &dq_dintrinsics : nullptr)) {
    return false;
  }
  Eigen::Map<Eigen::Vector2d>{residuals} = scale * (q_px - q_observed_px);
  if (jacobians == nullptr) return true;

  const Matrix23d dres_dp = scale * dq_dp;
  if (jacobians[index_r] != nullptr) {
    Eigen::Map<RowMajorMatrix23d>{jacobians[index_r]} =
        -dres_dp * cam_from_part * Skew(x_part) * RightJacobianSO3(r);
  }
  if (jacobians[index_t] != nullptr) {
    Eigen::Map<RowMajorMatrix23d>{jacobians[index_t]} = dres_dp;
  }
  if (want_intrinsics) {
    Eigen::Map<RowMajorMatrix2Xd>{jacobians[index_intrinsics], 2, lens.NumIntrinsics()} =
        scale * dq_dintrinsics;
  }
  if (want_dx) *dres_dx = dres_dp * cam_from_part;
  return true;
}

}  // namespace

Eigen::Matrix3d RightJacobianSO3(const Eigen::Vector3d& r) {
  const double a2 = r.squaredNorm();
  const Eigen::Matrix3d k = Skew(r);
  double c1, c2;  // (1 - cos a)/a^2, (a - sin a)/a^3
  if (a2 < 1e-8) {
    // Taylor series; the next terms are O(a^2) relative, below 1e-8 here.
    c1 = 0.5 - a2 / 24.0;
    c2 = 1.0 / 6.0 - a2 / 120.0;
  } else {
    const double a = std::sqrt(a2);
    c1 = (1.0 - std::cos(a)) / a2;
    c2 = (a - std::sin(a)) / (a2 * a);
  }
  return Eigen::Matrix3d::Identity() - c1 * k + c2 * k * k;
}

TrackReprojectionCost::TrackReprojectionCost(const LensProjection& lens,
                                             const Eigen::Vector2d& q_px,
                                             double weight_over_sigma_px)
    : TrackReprojectionCost(lens, q_px, weight_over_sigma_px * Eigen::Matrix2d::Identity()) {}

TrackReprojectionCost::TrackReprojectionCost(const LensProjection& lens,
                                             const Eigen::Vector2d& q_px,
                                             const Eigen::Matrix2d& scale)
    : lens_(lens), q_px_(q_px), scale_(scale) {
  set_num_residuals(2);
  *mutable_parameter_block_sizes() = {3, 3, 2, 2, lens.NumIntrinsics()};
}

bool TrackReprojectionCost::Evaluate(double const* const* parameters, double* residuals,
                                     double** jacobians) const {
  const Eigen::Map<const Eigen::Vector2d> table_pos(parameters[2]);
  const Eigen::Map<const Eigen::Vector2d> point_xy(parameters[3]);
  const Eigen::Vector3d x_part(point_xy.x() + table_pos.x(), point_xy.y() + table_pos.y(), 0.0);
  const bool want_dx =
      jacobians != nullptr && (jacobians[2] != nullptr || jacobians[3] != nullptr);
  Matrix23d dres_dx;
  // In px, then scaled by the matrix.
  if (!ReprojectMovedPoint(lens_, q_px_, 1.0, parameters[0], parameters[1], parameters[4], x_part,
                           residuals, jacobians, 0, 1, 4, want_dx, &dres_dx)) {
    return false;
  }
  Eigen::Map<Eigen::Vector2d> res(residuals);
  res = scale_ * res;
  if (jacobians == nullptr) return true;
  for (int block : {0, 1}) {
    if (jacobians[block] != nullptr) {
      Eigen::Map<RowMajorMatrix23d> j(jacobians[block]);
      j = scale_ * j;
    }
  }
  if (jacobians[4] != nullptr) {
    Eigen::Map<RowMajorMatrix2Xd> j(jacobians[4], 2, lens_.NumIntrinsics());
    j = scale_ * j;
  }
  // T and P enter only through X = P + T (in-plane): both Jacobians are the
  // first two columns of dres/dX.
  for (int block : {2, 3}) {
    if (jacobians[block] != nullptr) {
      Eigen::Map<RowMajorMatrix22d>{jacobians[block]} = scale_ * dres_dx.leftCols<2>();
    }
  }
  return true;
}

PlateMarkReprojectionCost::PlateMarkReprojectionCost(const LensProjection& lens,
                                                     const Eigen::Vector2d& mark_uv_mm,
                                                     const Eigen::Vector2d& q_px,
                                                     double weight_over_sigma_px)
    : lens_(lens), mark_uv_mm_(mark_uv_mm), q_px_(q_px), scale_(weight_over_sigma_px) {
  set_num_residuals(2);
  *mutable_parameter_block_sizes() = {3, 3, 2, 3, 1, 1, lens.NumIntrinsics()};
}

bool PlateMarkReprojectionCost::Evaluate(double const* const* parameters, double* residuals,
                                         double** jacobians) const {
  const Eigen::Map<const Eigen::Vector2d> table_pos(parameters[2]);
  const double* pose = parameters[3];  // x, y, theta
  const double height = parameters[4][0];
  const double plate_scale = parameters[5][0];
  const double c = std::cos(pose[2]);
  const double s = std::sin(pose[2]);
  const double u = mark_uv_mm_.x();
  const double v = mark_uv_mm_.y();
  const Eigen::Vector2d m_uv(c * u + s * v, s * u - c * v);         // M(theta) (u, v)
  const Eigen::Vector2d dm_uv_dtheta(-s * u + c * v, c * u + s * v);  // M'(theta) (u, v)
  const Eigen::Vector3d x_part(pose[0] + plate_scale * m_uv.x() + table_pos.x(),
                               pose[1] + plate_scale * m_uv.y() + table_pos.y(), height);
  bool want_dx = false;
  if (jacobians != nullptr) {
    for (int block : {2, 3, 4, 5}) want_dx = want_dx || jacobians[block] != nullptr;
  }
  Matrix23d dres_dx;
  if (!ReprojectMovedPoint(lens_, q_px_, scale_, parameters[0], parameters[1], parameters[6],
                           x_part, residuals, jacobians, 0, 1, 6, want_dx, &dres_dx)) {
    return false;
  }
  if (!want_dx) return true;
  if (jacobians[2] != nullptr) {
    Eigen::Map<RowMajorMatrix22d>{jacobians[2]} = dres_dx.leftCols<2>();
  }
  if (jacobians[3] != nullptr) {
    Eigen::Map<RowMajorMatrix23d> d_pose(jacobians[3]);
    d_pose.leftCols<2>() = dres_dx.leftCols<2>();
    d_pose.col(2) = dres_dx.leftCols<2>() * (plate_scale * dm_uv_dtheta);
  }
  if (jacobians[4] != nullptr) {
    Eigen::Map<Eigen::Vector2d>{jacobians[4]} = dres_dx.col(2);
  }
  if (jacobians[5] != nullptr) {
    Eigen::Map<Eigen::Vector2d>{jacobians[5]} = dres_dx.leftCols<2>() * m_uv;
  }
  return true;
}

TablePriorCost::TablePriorCost(const Eigen::Vector2d& commanded_mm, double sigma_mm)
    : commanded_mm_(commanded_mm), sigma_mm_(sigma_mm) {}

bool TablePriorCost::Evaluate(double const* const* parameters, double* residuals,
                              double** jacobians) const {
  const Eigen::Map<const Eigen::Vector2d> table_pos(parameters[0]);
  Eigen::Map<Eigen::Vector2d>{residuals} = (table_pos - commanded_mm_) / sigma_mm_;
  if (jacobians != nullptr && jacobians[0] != nullptr) {
    Eigen::Map<RowMajorMatrix22d>{jacobians[0]} = Eigen::Matrix2d::Identity() / sigma_mm_;
  }
  return true;
}

IntrinsicsPriorCost::IntrinsicsPriorCost(const Eigen::VectorXd& calibrated,
                                         const Eigen::MatrixXd& information,
                                         const std::vector<int>& held)
    : calibrated_(calibrated),
      free_(FreeIntrinsics(static_cast<int>(calibrated.size()), held)),
      sqrt_information_(Eigen::LLT<Eigen::MatrixXd>(information(free_, free_)).matrixU()) {
  set_num_residuals(static_cast<int>(free_.size()));
  *mutable_parameter_block_sizes() = {static_cast<int>(calibrated.size())};
}

bool IntrinsicsPriorCost::Evaluate(double const* const* parameters, double* residuals,
                                   double** jacobians) const {
  const int n = static_cast<int>(calibrated_.size()), f = static_cast<int>(free_.size());
  const Eigen::Map<const Eigen::VectorXd> intrinsics(parameters[0], n);
  Eigen::Map<Eigen::VectorXd>{residuals, f} = sqrt_information_ * (intrinsics - calibrated_)(free_);
  if (jacobians != nullptr && jacobians[0] != nullptr) {
    Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> jacobian(
        jacobians[0], f, n);
    jacobian.setZero();
    jacobian(Eigen::all, free_) = sqrt_information_;
  }
  return true;
}

}  // namespace omm
