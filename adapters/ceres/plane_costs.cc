#include "adapters/ceres/plane_costs.h"

#include <cmath>
#include <cstdint>

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
// blocks (the intrinsics' first, IntrinsicsBlocks giving the rest). On
// return *dres_dx holds d residual / dX when X's Jacobian is needed by the
// caller (want_dx).
bool ReprojectMovedPoint(const LensProjection& lens, const Eigen::Vector2d& q_observed_px,
                         double scale, double const* const* parameters,
                         const IntrinsicsBlocks& blocks, const Eigen::Vector3d& x_part,
                         double* residuals, double** jacobians, int index_r, int index_t,
                         int index_intrinsics, bool want_dx, Matrix23d* dres_dx) {
  const Eigen::Map<const Eigen::Vector3d> r(parameters[index_r]);
  const Eigen::Map<const Eigen::Vector3d> t(parameters[index_t]);
  const Eigen::Matrix3d cam_from_part = RotationFromAngleAxis(r);
  const Eigen::Vector3d p_cam = cam_from_part * x_part + t;
  const int n = lens.NumIntrinsics();
  const int num_blocks = blocks.ranges.empty() ? 1 : static_cast<int>(blocks.ranges.size());
  double* const* dres_dintrinsics = jacobians != nullptr ? jacobians + index_intrinsics : nullptr;

  const bool want_pose = jacobians != nullptr && (jacobians[index_r] != nullptr ||
                                                  jacobians[index_t] != nullptr);
  bool want_intrinsics = false;
  for (int k = 0; k < num_blocks && dres_dintrinsics != nullptr; ++k)
    want_intrinsics = want_intrinsics || dres_dintrinsics[k] != nullptr;
  const bool want_dp = want_pose || want_dx;

  // The whole k: the blocks' values over the others'. Their gradient tells
  // whether the projection depends on an intrinsic in no block.
  const double* intrinsics = parameters[index_intrinsics];
  Eigen::VectorXd assembled;
  if (!blocks.ranges.empty()) {
    assembled = Eigen::Map<const Eigen::VectorXd>(blocks.others, n);
    for (int k = 0; k < num_blocks; ++k) {
      const auto [start, size] = blocks.ranges[k];
      assembled.segment(start, size) =
          Eigen::Map<const Eigen::VectorXd>(parameters[index_intrinsics + k], size);
    }
    intrinsics = assembled.data();
  }
  const bool need_dq_dintrinsics = want_intrinsics || !blocks.ranges.empty();

  Eigen::Vector2d q_px;
  Matrix23d dq_dp;
  RowMajorMatrix2Xd dq_dintrinsics;
  if (!lens.Project(p_cam, intrinsics, &q_px, want_dp ? &dq_dp : nullptr,
                    need_dq_dintrinsics ? &dq_dintrinsics : nullptr)) {
    return false;
  }
  if (!blocks.ranges.empty()) {
    int next = 0;  // first intrinsic after the ranges seen so far
    for (int k = 0; k <= num_blocks; ++k) {
      const int end = k < num_blocks ? blocks.ranges[k].first : n;
      if (end > next && (dq_dintrinsics.middleCols(next, end - next).array() != 0.0).any()) {
        if (blocks.num_outside != nullptr) ++*blocks.num_outside;
        return false;
      }
      if (k < num_blocks) next = blocks.ranges[k].first + blocks.ranges[k].second;
    }
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
  for (int k = 0; k < num_blocks; ++k) {
    if (dres_dintrinsics[k] == nullptr) continue;
    const auto [start, size] = blocks.ranges.empty() ? std::pair{0, n} : blocks.ranges[k];
    Eigen::Map<RowMajorMatrix2Xd>{dres_dintrinsics[k], 2, size} =
        scale * dq_dintrinsics.middleCols(start, size);
  }
  if (want_dx) *dres_dx = dres_dp * cam_from_part;
  return true;
}

std::vector<int> BlockSizes(const IntrinsicsBlocks& blocks, int num_intrinsics) {
  if (blocks.ranges.empty()) return {num_intrinsics};
  std::vector<int> sizes;
  for (const auto& [start, size] : blocks.ranges) sizes.push_back(size);
  return sizes;
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
                                             const Eigen::Matrix2d& scale,
                                             IntrinsicsBlocks intrinsics)
    : lens_(lens), q_px_(q_px), scale_(scale), intrinsics_(std::move(intrinsics)) {
  set_num_residuals(2);
  *mutable_parameter_block_sizes() = {3, 3, 2, 2};
  for (int size : BlockSizes(intrinsics_, lens.NumIntrinsics()))
    mutable_parameter_block_sizes()->push_back(size);
}

Eigen::Vector3d MovedTrackPoint(const double* table_pos_mm, const double* point_xy_mm) {
  return {point_xy_mm[0] + table_pos_mm[0], point_xy_mm[1] + table_pos_mm[1], 0.0};
}

Eigen::Vector3d MovedPlateMark(const double* table_pos_mm, const double* plate_pose,
                               double height_mm, double plate_scale,
                               const Eigen::Vector2d& mark_uv_mm) {
  const double c = std::cos(plate_pose[2]);
  const double s = std::sin(plate_pose[2]);
  const double u = mark_uv_mm.x();
  const double v = mark_uv_mm.y();
  return {plate_pose[0] + plate_scale * (c * u + s * v) + table_pos_mm[0],
          plate_pose[1] + plate_scale * (s * u - c * v) + table_pos_mm[1], height_mm};
}

bool TrackReprojectionCost::Evaluate(double const* const* parameters, double* residuals,
                                     double** jacobians) const {
  const Eigen::Vector3d x_part = MovedTrackPoint(parameters[2], parameters[3]);
  const bool want_dx =
      jacobians != nullptr && (jacobians[2] != nullptr || jacobians[3] != nullptr);
  Matrix23d dres_dx;
  // In px, then scaled by the matrix.
  if (!ReprojectMovedPoint(lens_, q_px_, 1.0, parameters, intrinsics_, x_part, residuals, jacobians,
                           0, 1, 4, want_dx, &dres_dx)) {
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
  const std::vector<int32_t>& sizes = parameter_block_sizes();
  for (size_t k = 4; k < sizes.size(); ++k) {
    if (jacobians[k] == nullptr) continue;
    Eigen::Map<RowMajorMatrix2Xd> j(jacobians[k], 2, sizes[k]);
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
                                                     double weight_over_sigma_px,
                                                     IntrinsicsBlocks intrinsics)
    : lens_(lens),
      mark_uv_mm_(mark_uv_mm),
      q_px_(q_px),
      scale_(weight_over_sigma_px),
      intrinsics_(std::move(intrinsics)) {
  set_num_residuals(2);
  *mutable_parameter_block_sizes() = {3, 3, 2, 3, 1, 1};
  for (int size : BlockSizes(intrinsics_, lens.NumIntrinsics()))
    mutable_parameter_block_sizes()->push_back(size);
}

bool PlateMarkReprojectionCost::Evaluate(double const* const* parameters, double* residuals,
                                         double** jacobians) const {
  const double* pose = parameters[3];  // x, y, theta
  const double plate_scale = parameters[5][0];
  const double c = std::cos(pose[2]);
  const double s = std::sin(pose[2]);
  const double u = mark_uv_mm_.x();
  const double v = mark_uv_mm_.y();
  const Eigen::Vector2d m_uv(c * u + s * v, s * u - c * v);         // M(theta) (u, v)
  const Eigen::Vector2d dm_uv_dtheta(-s * u + c * v, c * u + s * v);  // M'(theta) (u, v)
  const Eigen::Vector3d x_part =
      MovedPlateMark(parameters[2], pose, parameters[4][0], plate_scale, mark_uv_mm_);
  bool want_dx = false;
  if (jacobians != nullptr) {
    for (int block : {2, 3, 4, 5}) want_dx = want_dx || jacobians[block] != nullptr;
  }
  Matrix23d dres_dx;
  if (!ReprojectMovedPoint(lens_, q_px_, scale_, parameters, intrinsics_, x_part, residuals,
                           jacobians, 0, 1, 6, want_dx, &dres_dx)) {
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
                                         const std::vector<int>& held,
                                         std::vector<int> block_starts)
    : calibrated_(calibrated),
      free_(FreeIntrinsics(static_cast<int>(calibrated.size()), held)),
      sqrt_information_(Eigen::LLT<Eigen::MatrixXd>(information(free_, free_)).matrixU()),
      block_starts_(std::move(block_starts)) {
  if (block_starts_.empty()) block_starts_ = {0, static_cast<int>(calibrated.size())};
  set_num_residuals(static_cast<int>(free_.size()));
  for (size_t b = 0; b + 1 < block_starts_.size(); ++b)
    mutable_parameter_block_sizes()->push_back(block_starts_[b + 1] - block_starts_[b]);
}

bool IntrinsicsPriorCost::Evaluate(double const* const* parameters, double* residuals,
                                   double** jacobians) const {
  const int n = static_cast<int>(calibrated_.size()), f = static_cast<int>(free_.size());
  const int num_blocks = static_cast<int>(block_starts_.size()) - 1;
  Eigen::VectorXd intrinsics(n);
  for (int b = 0; b < num_blocks; ++b) {
    const int size = block_starts_[b + 1] - block_starts_[b];
    intrinsics.segment(block_starts_[b], size) =
        Eigen::Map<const Eigen::VectorXd>(parameters[b], size);
  }
  Eigen::Map<Eigen::VectorXd>{residuals, f} = sqrt_information_ * (intrinsics - calibrated_)(free_);
  if (jacobians == nullptr) return true;
  // Column j of the whole Jacobian: U's column of j's place in free_, or 0.
  for (int b = 0, next_free = 0; b < num_blocks; ++b) {
    const int start = block_starts_[b], size = block_starts_[b + 1] - start;
    while (next_free < f && free_[next_free] < start) ++next_free;
    if (jacobians[b] == nullptr) continue;
    Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> jacobian(
        jacobians[b], f, size);
    jacobian.setZero();
    for (int j = next_free; j < f && free_[j] < start + size; ++j)
      jacobian.col(free_[j] - start) = sqrt_information_.col(j);
  }
  return true;
}

}  // namespace omm
