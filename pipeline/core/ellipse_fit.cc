#include "pipeline/core/ellipse_fit.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include "pipeline/core/statistics.h"

namespace omm {
namespace {

struct Axes {
  double major, minor;
  Eigen::Vector2d u, v;  // unit major and minor directions
};

Axes AxesOf(const Eigen::Matrix2d& shape) {
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(shape);
  // Ascending eigenvalues: the smallest one belongs to the major axis.
  Axes axes;
  axes.major = 1.0 / std::sqrt(eig.eigenvalues()(0));
  axes.minor = 1.0 / std::sqrt(eig.eigenvalues()(1));
  axes.u = eig.eigenvectors().col(0);
  axes.v = Eigen::Vector2d(-axes.u.y(), axes.u.x());
  return axes;
}

Eigen::Vector2d PointOn(const Ellipse& ellipse, double t, const Axes& axes) {
  return ellipse.centre_px + axes.major * std::cos(t) * axes.u + axes.minor * std::sin(t) * axes.v;
}

bool IsPositiveDefinite(const Eigen::Matrix2d& m) {
  return m(0, 0) > 0.0 && m.determinant() > 0.0;
}

// Conic coefficients (A..F) to centre and shape; nullopt if not a real ellipse.
std::optional<Ellipse> EllipseFromConic(const Eigen::Matrix<double, 6, 1>& k) {
  const double a = k(0), b = k(1), c = k(2), d = k(3), e = k(4), f = k(5);
  Eigen::Matrix2d quad;
  quad << a, 0.5 * b, 0.5 * b, c;
  if (quad.determinant() <= 0.0) return std::nullopt;
  Ellipse ellipse;
  ellipse.centre_px = (2.0 * quad).ldlt().solve(Eigen::Vector2d(-d, -e));
  const double f0 = f + 0.5 * (d * ellipse.centre_px.x() + e * ellipse.centre_px.y());
  if (f0 == 0.0) return std::nullopt;
  ellipse.shape = -quad / f0;
  if (!IsPositiveDefinite(ellipse.shape)) return std::nullopt;
  return ellipse;
}

// Residuals d (Sampson distances) and, if wanted, their Jacobian with respect
// to (c_x, c_y, M_00, M_01, M_11).
void SampsonResiduals(const Ellipse& ellipse, const Eigen::Matrix2Xd& points_px,
                      const std::vector<int>& use, Eigen::VectorXd* d,
                      Eigen::Matrix<double, Eigen::Dynamic, 5>* jacobian) {
  const Eigen::Matrix2d& m = ellipse.shape;
  d->resize(static_cast<Eigen::Index>(use.size()));
  if (jacobian) jacobian->resize(static_cast<Eigen::Index>(use.size()), 5);
  for (size_t i = 0; i < use.size(); ++i) {
    const Eigen::Vector2d u = points_px.col(use[i]) - ellipse.centre_px;
    const Eigen::Vector2d g = m * u;
    const double n = std::max(g.norm(), 1e-300);
    const double q = u.dot(g) - 1.0;
    (*d)(static_cast<Eigen::Index>(i)) = 0.5 * q / n;
    if (!jacobian) continue;
    // dQ and dg for each parameter; dd = dQ / 2n - Q dn / 2n^2, dn = g.dg / n.
    Eigen::Matrix<double, 1, 5> dq;
    dq << -2.0 * g.x(), -2.0 * g.y(), u.x() * u.x(), 2.0 * u.x() * u.y(), u.y() * u.y();
    Eigen::Matrix<double, 2, 5> dg;
    dg.col(0) = -m.col(0);
    dg.col(1) = -m.col(1);
    dg.col(2) << u.x(), 0.0;
    dg.col(3) << u.y(), u.x();
    dg.col(4) << 0.0, u.y();
    const Eigen::Matrix<double, 1, 5> dn = g.transpose() * dg / n;
    jacobian->row(static_cast<Eigen::Index>(i)) = dq / (2.0 * n) - q * dn / (2.0 * n * n);
  }
}

Ellipse Updated(const Ellipse& ellipse, const Eigen::Matrix<double, 5, 1>& step) {
  Ellipse out = ellipse;
  out.centre_px += step.head<2>();
  out.shape(0, 0) += step(2);
  out.shape(0, 1) += step(3);
  out.shape(1, 0) += step(3);
  out.shape(1, 1) += step(4);
  return out;
}

// Gauss-Newton with step halving on the points listed in `use`.
Ellipse RefineGeometric(Ellipse ellipse, const Eigen::Matrix2Xd& points_px, const std::vector<int>& use,
                        const EllipseFitOptions& options) {
  Eigen::VectorXd d;
  Eigen::Matrix<double, Eigen::Dynamic, 5> jacobian;
  SampsonResiduals(ellipse, points_px, use, &d, &jacobian);
  double cost = d.squaredNorm();
  for (int it = 0; it < options.max_iterations; ++it) {
    const Eigen::Matrix<double, 5, 5> jtj = jacobian.transpose() * jacobian;
    const Eigen::Matrix<double, 5, 1> step = -jtj.ldlt().solve(jacobian.transpose() * d);
    if (!step.allFinite()) break;
    double scale = 1.0;
    bool improved = false;
    for (int halving = 0; halving < 8 && !improved; ++halving, scale *= 0.5) {
      const Ellipse trial = Updated(ellipse, scale * step);
      if (!IsPositiveDefinite(trial.shape)) continue;
      Eigen::VectorXd d_trial;
      SampsonResiduals(trial, points_px, use, &d_trial, nullptr);
      if (d_trial.squaredNorm() <= cost) {
        ellipse = trial;
        cost = d_trial.squaredNorm();
        improved = true;
      }
    }
    if (!improved) break;
    SampsonResiduals(ellipse, points_px, use, &d, &jacobian);
    if (scale * step.head<2>().norm() < options.step_tolerance_px) break;
  }
  return ellipse;
}

}  // namespace

double Ellipse::SemiMajorPx() const { return AxesOf(shape).major; }
double Ellipse::SemiMinorPx() const { return AxesOf(shape).minor; }

double Ellipse::AngleRad() const {
  const Eigen::Vector2d u = AxesOf(shape).u;
  double angle = std::atan2(u.y(), u.x());
  if (angle <= -0.5 * std::numbers::pi) angle += std::numbers::pi;
  if (angle > 0.5 * std::numbers::pi) angle -= std::numbers::pi;
  return angle;
}

Eigen::Vector2d Ellipse::PointAt(double t) const { return PointOn(*this, t, AxesOf(shape)); }

Eigen::Vector2d Ellipse::NormalAt(double t) const {
  return (shape * (PointAt(t) - centre_px)).normalized();
}

void Ellipse::SampleBoundary(int count, Eigen::Matrix2Xd* points, Eigen::Matrix2Xd* normals) const {
  const Axes axes = AxesOf(shape);
  points->resize(2, count);
  normals->resize(2, count);
  for (int k = 0; k < count; ++k) {
    const Eigen::Vector2d p = PointOn(*this, 2.0 * std::numbers::pi * k / count, axes);
    points->col(k) = p;
    normals->col(k) = (shape * (p - centre_px)).normalized();
  }
}

Ellipse Ellipse::FromAxes(const Eigen::Vector2d& centre_px, double semi_major_px, double semi_minor_px,
                          double angle_rad) {
  Eigen::Matrix2d rotation;
  rotation << std::cos(angle_rad), -std::sin(angle_rad), std::sin(angle_rad), std::cos(angle_rad);
  Ellipse ellipse;
  ellipse.centre_px = centre_px;
  ellipse.shape = rotation *
                  Eigen::Vector2d(1.0 / (semi_major_px * semi_major_px),
                                  1.0 / (semi_minor_px * semi_minor_px))
                      .asDiagonal() *
                  rotation.transpose();
  return ellipse;
}

Eigen::VectorXd EllipseSampsonDistances(const Ellipse& ellipse, const Eigen::Matrix2Xd& points_px) {
  std::vector<int> all(static_cast<size_t>(points_px.cols()));
  for (size_t i = 0; i < all.size(); ++i) all[i] = static_cast<int>(i);
  Eigen::VectorXd d;
  SampsonResiduals(ellipse, points_px, all, &d, nullptr);
  return d;
}

std::optional<Ellipse> FitEllipseDirect(const Eigen::Matrix2Xd& points_px) {
  const Eigen::Index n = points_px.cols();
  if (n < 5) return std::nullopt;
  const Eigen::Vector2d mean = points_px.rowwise().mean();
  const Eigen::Matrix2Xd centred = points_px.colwise() - mean;
  const double rms = std::sqrt(centred.colwise().squaredNorm().mean());
  if (!(rms > 0.0)) return std::nullopt;
  const Eigen::Matrix2Xd p = centred / rms;

  Eigen::MatrixX3d d1(n, 3), d2(n, 3);
  d1.col(0) = p.row(0).cwiseAbs2().transpose();
  d1.col(1) = (p.row(0).array() * p.row(1).array()).transpose();
  d1.col(2) = p.row(1).cwiseAbs2().transpose();
  d2.col(0) = p.row(0).transpose();
  d2.col(1) = p.row(1).transpose();
  d2.col(2).setOnes();
  const Eigen::Matrix3d s1 = d1.transpose() * d1;
  const Eigen::Matrix3d s2 = d1.transpose() * d2;
  const Eigen::Matrix3d s3 = d2.transpose() * d2;
  const Eigen::Matrix3d t = -s3.ldlt().solve(s2.transpose());
  const Eigen::Matrix3d m = s1 + s2 * t;
  // Premultiply by the inverse of the constraint matrix of 4AC - B^2.
  Eigen::Matrix3d reduced;
  reduced.row(0) = 0.5 * m.row(2);
  reduced.row(1) = -m.row(1);
  reduced.row(2) = 0.5 * m.row(0);
  const Eigen::EigenSolver<Eigen::Matrix3d> eig(reduced);
  std::optional<Ellipse> best;
  for (int i = 0; i < 3; ++i) {
    const Eigen::Vector3d a1 = eig.eigenvectors().col(i).real();
    if (4.0 * a1(0) * a1(2) - a1(1) * a1(1) <= 0.0) continue;
    Eigen::Matrix<double, 6, 1> conic;
    conic << a1, t * a1;
    best = EllipseFromConic(conic);
    if (best) break;
  }
  if (!best) return std::nullopt;
  best->centre_px = mean + rms * best->centre_px;
  best->shape /= rms * rms;
  return best;
}

std::string EllipseFitOptions::Check() const {
  if (max_iterations < 1) return "max_iterations must be >= 1";
  if (!(step_tolerance_px > 0.0)) return "step_tolerance_px must be > 0";
  if (!(outlier_threshold_mads > 0.0)) return "outlier_threshold_mads must be > 0";
  if (!(outlier_floor_px >= 0.0)) return "outlier_floor_px must be >= 0";
  if (max_rejection_rounds < 0) return "max_rejection_rounds must be >= 0";
  if (min_points < 6) return "min_points must be >= 6 (5 parameters and a residual)";
  return {};
}

EllipseFit FitEllipse(const Eigen::Matrix2Xd& points_px, const EllipseFitOptions& options) {
  EllipseFit fit;
  const int n = static_cast<int>(points_px.cols());
  fit.inlier.assign(static_cast<size_t>(n), true);
  if (n < options.min_points) {
    fit.why_failed = "too few edge points";
    return fit;
  }
  const std::optional<Ellipse> direct = FitEllipseDirect(points_px);
  if (!direct) {
    fit.why_failed = "edge points do not lie on an ellipse";
    return fit;
  }
  Ellipse ellipse = *direct;
  std::vector<int> use;
  // The inliers' indices into `use`; false when too few are left to fit.
  const auto collect_inliers = [&] {
    use.clear();
    for (int i = 0; i < n; ++i) {
      if (fit.inlier[static_cast<size_t>(i)]) use.push_back(i);
    }
    if (static_cast<int>(use.size()) >= options.min_points) return true;
    fit.why_failed = "too few edge points after outlier rejection";
    return false;
  };
  for (int round = 0; round <= options.max_rejection_rounds; ++round) {
    if (!collect_inliers()) return fit;
    ellipse = RefineGeometric(ellipse, points_px, use, options);
    const Eigen::VectorXd d = EllipseSampsonDistances(ellipse, points_px);
    std::vector<double> abs_inlier;
    for (const int i : use) abs_inlier.push_back(std::abs(d(i)));
    const double threshold =
        std::max(options.outlier_threshold_mads * 1.4826 * Median(abs_inlier), options.outlier_floor_px);
    bool changed = false;
    for (int i = 0; i < n; ++i) {
      const bool keep = std::abs(d(i)) <= threshold;
      changed |= keep != fit.inlier[static_cast<size_t>(i)];
      fit.inlier[static_cast<size_t>(i)] = keep;
    }
    if (!changed) break;
  }
  if (!collect_inliers()) return fit;
  Eigen::VectorXd d;
  Eigen::Matrix<double, Eigen::Dynamic, 5> jacobian;
  SampsonResiduals(ellipse, points_px, use, &d, &jacobian);
  fit.ellipse = ellipse;
  fit.num_inliers = static_cast<int>(use.size());
  fit.rms_px = std::sqrt(d.squaredNorm() / fit.num_inliers);
  const double s2 = d.squaredNorm() / (fit.num_inliers - 5);
  const Eigen::Matrix<double, 5, 5> jtj_inv =
      (jacobian.transpose() * jacobian).ldlt().solve(Eigen::Matrix<double, 5, 5>::Identity());
  fit.centre_cov_px2 = s2 * jtj_inv.topLeftCorner<2, 2>();
  const Eigen::Matrix<double, 2, Eigen::Dynamic> sensitivity =
      -jtj_inv.topRows<2>() * jacobian.transpose();
  fit.centre_sensitivity.setZero(2, n);
  for (size_t k = 0; k < use.size(); ++k) fit.centre_sensitivity.col(use[k]) = sensitivity.col(static_cast<Eigen::Index>(k));
  fit.ok = fit.centre_cov_px2.allFinite();
  if (!fit.ok) fit.why_failed = "degenerate edge-point configuration";
  return fit;
}

}  // namespace omm
