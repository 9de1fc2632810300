#include "pipeline/mosaic/homography.h"

#include <cmath>
#include <limits>

#include <Eigen/Dense>

namespace omm {
namespace {

// Twice the smallest triangle area a 4-point sample may span in Hartley's
// normalised coordinates (mean distance sqrt(2) from the centroid): 1e-9
// is a point 1e-9 of the sample's spread off the line through two others
// (1e-6 px over 1600 px), six orders above round-off.
constexpr double kMinTriangleArea2 = 1e-9;

}  // namespace

Eigen::Matrix3d FitHomography(const Eigen::Matrix2Xd& a, const Eigen::Matrix2Xd& b) {
  const Eigen::Matrix3d ta = HartleyNormaliser(a), tb = HartleyNormaliser(b);
  // The null vector of the DLT system M h = 0 as the eigenvector of M^T M
  // with the smallest eigenvalue: a 9 x 9 problem whatever the point count
  // (the SVD of the 2n x 9 M cost more than the matching in RANSAC). In
  // Hartley's normalised coordinates M^T M's conditioning is harmless.
  Eigen::Matrix<double, 9, 9> mtm = Eigen::Matrix<double, 9, 9>::Zero();
  for (Eigen::Index i = 0; i < a.cols(); ++i) {
    const Eigen::Vector3d x = ta * a.col(i).homogeneous();
    const Eigen::Vector3d y = tb * b.col(i).homogeneous();
    Eigen::Matrix<double, 9, 1> r0, r1;
    r0 << 0, 0, 0, -y.z() * x, y.y() * x;
    r1 << y.z() * x, 0, 0, 0, -y.x() * x;
    mtm.selfadjointView<Eigen::Lower>().rankUpdate(r0);
    mtm.selfadjointView<Eigen::Lower>().rankUpdate(r1);
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 9, 9>> eigen(
      mtm.selfadjointView<Eigen::Lower>());
  const Eigen::Matrix<double, 9, 1> h = eigen.eigenvectors().col(0);
  Eigen::Matrix3d hn;
  hn << h(0), h(1), h(2), h(3), h(4), h(5), h(6), h(7), h(8);
  return tb.inverse() * hn * ta;
}

Eigen::Matrix3d FitHomography4(const Eigen::Matrix<double, 2, 4>& a,
                               const Eigen::Matrix<double, 2, 4>& b) {
  const Eigen::Matrix3d ta = HartleyNormaliser(a), tb = HartleyNormaliser(b);
  Eigen::Matrix<double, 2, 4> xs, ys;
  Eigen::Matrix<double, 8, 8> m;
  Eigen::Matrix<double, 8, 1> rhs;
  for (int i = 0; i < 4; ++i) {
    const Eigen::Vector2d x = xs.col(i) = (ta * a.col(i).homogeneous()).head<2>();
    const Eigen::Vector2d y = ys.col(i) = (tb * b.col(i).homogeneous()).head<2>();
    m.row(2 * i) << x.x(), x.y(), 1, 0, 0, 0, -y.x() * x.x(), -y.x() * x.y();
    m.row(2 * i + 1) << 0, 0, 0, x.x(), x.y(), 1, -y.y() * x.x(), -y.y() * x.y();
    rhs.segment<2>(2 * i) = y;
  }
  // Three collinear points leave m singular only up to round-off, and the
  // solve returns a finite H through the sample that holds nowhere else.
  // Normalised, a spread sample's triangles have areas of order 1; a
  // collinear triple's is round-off (~1e-16).
  for (int skip = 0; skip < 4; ++skip) {
    const int i = skip == 0 ? 1 : 0, j = skip <= 1 ? 2 : 1, k = skip <= 2 ? 3 : 2;
    for (const Eigen::Matrix<double, 2, 4>* p : {&xs, &ys}) {
      const Eigen::Vector2d u = p->col(j) - p->col(i), v = p->col(k) - p->col(i);
      if (std::abs(u.x() * v.y() - u.y() * v.x()) < kMinTriangleArea2)
        return Eigen::Matrix3d::Constant(std::numeric_limits<double>::quiet_NaN());
    }
  }
  const Eigen::Matrix<double, 8, 1> h = m.partialPivLu().solve(rhs);
  Eigen::Matrix3d hn;
  hn << h(0), h(1), h(2), h(3), h(4), h(5), h(6), h(7), 1;
  return tb.inverse() * hn * ta;
}

}  // namespace omm
