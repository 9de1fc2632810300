// Ellipse fitting to sub-pixel edge points: a direct algebraic fit followed by
// a geometric refinement with outlier rejection.
//
// Model. An ellipse is the set of points p with
//     (p - c)^T M (p - c) = 1,
// c the centre (px) and M a symmetric positive-definite 2x2 matrix (1/px^2).
// Its semi-axes are 1/sqrt(eigenvalues of M). This parameterisation
// (c_x, c_y, M_00, M_01, M_11) has no singularity at a circle, unlike
// (centre, axes, angle).
//
// Direct fit: Halir & Flusser, "Numerically stable direct least squares
// fitting of ellipses" (WSCG 1998), a stable form of Fitzgibbon, Pilu & Fisher
// (PAMI 1999): minimises the algebraic distance of the conic
// A x^2 + B xy + C y^2 + D x + E y + F = 0 under 4AC - B^2 = 1, on points
// normalised to zero mean and unit RMS radius (Hartley) for conditioning.
//
// Geometric refinement: Gauss-Newton on the Sampson distance
//     d(p) = Q(p) / |grad Q(p)|,  Q(p) = (p - c)^T M (p - c) - 1,
// the first-order approximation of the orthogonal distance to the curve; it is
// exact to O(d^2) and symmetric about the centre, so it does not bias c.
// Outliers: points with |d| > max(k * 1.4826 * MAD, floor) are dropped and the
// fit repeated until the inlier set is stable.
//
// Centre covariance: s^2 [(J^T J)^-1]_cc, s^2 = sum d^2 / (n - 5), the usual
// Gauss-Newton estimate for independent, equal-variance edge points.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace omm {

struct Ellipse {
  Eigen::Vector2d centre_px = Eigen::Vector2d::Zero();
  // (p - c)^T shape (p - c) = 1 on the curve; symmetric positive-definite, 1/px^2.
  Eigen::Matrix2d shape = Eigen::Matrix2d::Identity();

  // Semi-axes (major >= minor), px, and the angle of the major axis from +x
  // towards +y, radians in (-pi/2, pi/2].
  double SemiMajorPx() const;
  double SemiMinorPx() const;
  double AngleRad() const;
  // The curve point at parametric angle t: c + a cos t u + b sin t v (u, v the
  // major and minor axis directions), and its unit outward normal.
  Eigen::Vector2d PointAt(double t) const;
  Eigen::Vector2d NormalAt(double t) const;
  // PointAt and NormalAt at t_k = 2 pi k / count, k = 0..count-1, into the
  // columns of points and normals (one eigen-decomposition for all).
  void SampleBoundary(int count, Eigen::Matrix2Xd* points, Eigen::Matrix2Xd* normals) const;

  static Ellipse FromAxes(const Eigen::Vector2d& centre_px, double semi_major_px,
                          double semi_minor_px, double angle_rad);
};

// Sampson distance of each point to the ellipse (px), positive outside.
Eigen::VectorXd EllipseSampsonDistances(const Ellipse& ellipse, const Eigen::Matrix2Xd& points_px);

// Direct algebraic fit (Halir & Flusser). Needs >= 5 points in general
// position; nullopt if the best conic is not an ellipse.
std::optional<Ellipse> FitEllipseDirect(const Eigen::Matrix2Xd& points_px);

struct EllipseFitOptions {
  int max_iterations = 20;             // Gauss-Newton iterations per inlier set
  double step_tolerance_px = 1e-9;     // stop when the centre moves less, px
  double outlier_threshold_mads = 4.0;  // reject |d| > this * robust sigma
  double outlier_floor_px = 0.05;      // ... but never below this, px
  int max_rejection_rounds = 4;        // refits after dropping outliers
  int min_points = 8;                  // fewer inliers: the fit fails

  // Empty if valid, else what is wrong.
  std::string Check() const;
};

struct EllipseFit {
  bool ok = false;
  std::string why_failed;  // set when !ok
  Ellipse ellipse;
  Eigen::Matrix2d centre_cov_px2 = Eigen::Matrix2d::Zero();  // 1-sigma^2 of the centre
  double rms_px = 0.0;        // RMS Sampson distance of the inliers
  int num_inliers = 0;
  std::vector<bool> inlier;  // per input point
  // Linear response of the centre to the data, 2 x (number of input points):
  // column i is d centre / d d_i, the centre's move per px that point i moves
  // across the curve (along the curve's normal), -[(J^T J)^-1 J^T]_c; zero for
  // outliers. With correlated or unequal edge-point noise, the centre's
  // covariance is S cov(d) S^T (subpixel_edges.h propagates pixel noise this way).
  Eigen::Matrix2Xd centre_sensitivity;
};

// Direct fit, then geometric refinement with outlier rejection.
EllipseFit FitEllipse(const Eigen::Matrix2Xd& points_px, const EllipseFitOptions& options = {});

}  // namespace omm
