// Plane homographies b ~ H a between two images (3 x 3, acting on
// homogeneous pixels): the normalised DLT fits of Hartley & Zisserman,
// "Multiple View Geometry", 2nd ed., section 4.4, and the point transfer.
// Pure kernels on Eigen types; points are the columns of 2 x n matrices.
#pragma once

#include <cmath>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace omm {

// Hartley's normalisation of 2-D points (columns): the similarity T that
// moves their centroid to 0 and their mean distance from it to sqrt(2);
// the identity scale if all points coincide.
template <int Cols>
Eigen::Matrix3d HartleyNormaliser(const Eigen::Matrix<double, 2, Cols>& p) {
  const Eigen::Vector2d mean = p.rowwise().mean();
  const double spread = (p.colwise() - mean).colwise().norm().mean();
  const double s = spread > 0 ? std::sqrt(2.0) / spread : 1.0;
  Eigen::Matrix3d t;
  t << s, 0, -s * mean.x(), 0, s, -s * mean.y(), 0, 0, 1;
  return t;
}

// Homography b ~ H a from n >= 4 correspondences (a.col(i), b.col(i)) by the
// normalised DLT (H & Z alg. 4.2): the least-squares null vector of the DLT
// system, |H| = 1 in normalised coordinates, any sign, as the eigenvector of
// M^T M (M's condition number squared: on exact correspondences, errors of
// 3e-13 of the image measured with 4 spread points, 2e-15 with 30). With
// fewer constraints (3 collinear or repeated points) one of the many exact
// solutions, finite.
Eigen::Matrix3d FitHomography(const Eigen::Matrix2Xd& a, const Eigen::Matrix2Xd& b);

// The homography b ~ H a through exactly four points (RANSAC's samples): the
// 8 x 8 DLT system in Hartley's normalised coordinates with H(2, 2) = 1 there,
// solved directly, a tenth of FitHomography's eigenproblem. That fixes the
// scale unless H takes a's centroid to infinity (never so for the near-
// translations between tiles). Not finite if the sample is degenerate:
// three of a's or of b's points collinear (to a triangle of 1e-9 of their
// spread squared) or two coinciding.
Eigen::Matrix3d FitHomography4(const Eigen::Matrix<double, 2, 4>& a,
                               const Eigen::Matrix<double, 2, 4>& b);

// The transfer of point a by H: (H a)'s inhomogeneous coordinates.
inline Eigen::Vector2d Transfer(const Eigen::Matrix3d& h, const Eigen::Vector2d& a) {
  return (h * a.homogeneous()).hnormalized();
}

// d Transfer(h, a) / d a (2 x 2).
inline Eigen::Matrix2d TransferJacobian(const Eigen::Matrix3d& h, const Eigen::Vector2d& a) {
  const Eigen::Vector3d p = h * a.homogeneous();
  Eigen::Matrix2d j;
  for (int k = 0; k < 2; ++k) {
    j.col(k) = (h.block<2, 1>(0, k) * p.z() - p.head<2>() * h(2, k)) / (p.z() * p.z());
  }
  return j;
}

}  // namespace omm
