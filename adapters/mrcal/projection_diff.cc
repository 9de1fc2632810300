#include "adapters/mrcal/projection_diff.h"

#include <cassert>
#include <cmath>

#include <Eigen/Dense>

#include "adapters/mrcal/lens.h"
#include "adapters/mrcal/mrcal_c.h"
#include "adapters/mrcal/uncertainty.h"

namespace omm {
namespace {

// Residuals project_B(T p_i) - q_i (2N) and optionally their gradient in rt.
bool Residuals(const CameraModel& camera_b, const Vector6d& rt, const Eigen::Matrix3Xd& p,
               const Eigen::Matrix2Xd& q, Eigen::VectorXd* r, Eigen::MatrixXd* dr_drt) {
  const int n = static_cast<int>(p.cols());
  Eigen::Matrix3Xd p_b(3, n);
  Eigen::MatrixXd dpb_drt(3 * n, 6);
  for (int i = 0; i < n; ++i) {
    double J[18];
    mrcal_transform_point_rt(p_b.col(i).data(), J, nullptr, rt.data(), p.col(i).data());
    dpb_drt.middleRows<3>(3 * i) = Eigen::Map<Eigen::Matrix<double, 3, 6, Eigen::RowMajor>>(J);
  }
  Eigen::Matrix2Xd q_b;
  // dq_dintrinsics is requested only because mrcal 2.2's mrcal_project fills
  // dq_dp for every point only when it is (without it, every point's gradient
  // lands in the first slot).
  Eigen::MatrixXd dq_dp, dq_dintrinsics;
  if (!ProjectPoints(camera_b, p_b, &q_b, dr_drt ? &dq_dp : nullptr,
                     dr_drt ? &dq_dintrinsics : nullptr)) {
    return false;
  }
  const Eigen::Matrix2Xd diff = q_b - q;
  *r = Eigen::Map<const Eigen::VectorXd>(diff.data(), 2 * n);
  if (dr_drt) {
    dr_drt->resize(2 * n, 6);
    for (int i = 0; i < n; ++i) {
      dr_drt->middleRows<2>(2 * i) = dq_dp.middleRows<2>(2 * i) * dpb_drt.middleRows<3>(3 * i);
    }
  }
  return true;
}

}  // namespace

ProjectionDiff FitRigidToProjections(const Eigen::Matrix3Xd& p, const Eigen::Matrix2Xd& q_px,
                                     const CameraModel& camera_b) {
  ProjectionDiff result;
  result.q_px = q_px;
  if (p.cols() < 3) return result;  // fewer points than the rigid motion's 6 unknowns
  Vector6d rt = Vector6d::Zero();
  Eigen::VectorXd r;
  Eigen::MatrixXd J;
  if (!Residuals(camera_b, rt, p, result.q_px, &r, &J)) return result;
  double cost = r.squaredNorm();
  double lambda = 1e-6;
  for (int iteration = 0; iteration < 50; ++iteration) {
    Eigen::Matrix<double, 6, 6> A = J.transpose() * J;
    const Eigen::Matrix<double, 6, 1> g = J.transpose() * r;
    A.diagonal() *= 1.0 + lambda;
    const Vector6d step = -A.ldlt().solve(g);
    Eigen::VectorXd r_new;
    Eigen::MatrixXd J_new;
    if (Residuals(camera_b, rt + step, p, result.q_px, &r_new, &J_new) &&
        r_new.squaredNorm() <= cost) {
      const double decrease = cost - r_new.squaredNorm();
      rt += step;
      r = r_new;
      J = J_new;
      cost = r.squaredNorm();
      lambda = std::max(lambda * 0.1, 1e-12);
      if (decrease <= 1e-14 * std::max(cost, 1e-30) || step.norm() < 1e-14) {
        result.converged = true;
        break;
      }
    } else {
      lambda *= 10.0;
      if (lambda > 1e8) {
        result.converged = true;  // no step decreases the cost: at the minimum
        break;
      }
    }
  }
  const int n = static_cast<int>(p.cols());
  result.rt_b_from_a = rt;
  result.diff_px.resize(n);
  for (int i = 0; i < n; ++i) result.diff_px[i] = r.segment<2>(2 * i).norm();
  result.rms_px = std::sqrt(r.squaredNorm() / n);
  result.max_px = result.diff_px.maxCoeff();
  return result;
}

ProjectionDiff FitProjectionDiff(const CameraModel& camera_a, const CameraModel& camera_b,
                                 double distance_mm, int grid_nx, int grid_ny) {
  assert(camera_a.width_px == camera_b.width_px && camera_a.height_px == camera_b.height_px);
  Eigen::Matrix2Xd q_px;
  const Eigen::Matrix3Xd p = ImagerGridPoints(camera_a, distance_mm, grid_nx, grid_ny, &q_px);
  return FitRigidToProjections(p, q_px, camera_b);
}

double ProjectionDiffRms(const CameraModel& camera_a, const CameraModel& camera_b,
                         double distance_mm, int grid_nx, int grid_ny) {
  return FitProjectionDiff(camera_a, camera_b, distance_mm, grid_nx, grid_ny).rms_px;
}

}  // namespace omm
