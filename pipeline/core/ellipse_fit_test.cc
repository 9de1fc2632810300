#include "pipeline/core/ellipse_fit.h"

#include <cmath>
#include <numbers>
#include <random>

#include <gtest/gtest.h>

namespace omm {
namespace {

Eigen::Matrix2Xd PointsOn(const Ellipse& ellipse, int n) {
  Eigen::Matrix2Xd points(2, n);
  for (int i = 0; i < n; ++i) points.col(i) = ellipse.PointAt(2.0 * std::numbers::pi * i / n);
  return points;
}

TEST(EllipseFit, AxesRoundTrip) {
  const Ellipse e = Ellipse::FromAxes({3.0, -2.0}, 21.0, 14.0, 0.4);
  EXPECT_NEAR(e.SemiMajorPx(), 21.0, 1e-12);
  EXPECT_NEAR(e.SemiMinorPx(), 14.0, 1e-12);
  EXPECT_NEAR(e.AngleRad(), 0.4, 1e-12);
  // Points are on the curve and normals are the gradient direction.
  for (double t : {0.0, 1.0, 2.5, 4.0}) {
    const Eigen::Vector2d u = e.PointAt(t) - e.centre_px;
    EXPECT_NEAR(u.dot(e.shape * u), 1.0, 1e-12);
    EXPECT_NEAR(e.NormalAt(t).dot(Eigen::Vector2d(-(e.shape * u).y(), (e.shape * u).x())), 0.0, 1e-12);
  }
}

TEST(EllipseFit, DirectFitIsExactOnExactPoints) {
  const Ellipse truth = Ellipse::FromAxes({812.3, 590.7}, 25.0, 17.5, -1.1);
  const auto fit = FitEllipseDirect(PointsOn(truth, 40));
  ASSERT_TRUE(fit.has_value());
  EXPECT_LT((fit->centre_px - truth.centre_px).norm(), 1e-9);
  EXPECT_LT((fit->shape - truth.shape).norm() / truth.shape.norm(), 1e-9);
}

TEST(EllipseFit, SampsonDistanceIsRadialDistanceForACircle) {
  const Ellipse circle = Ellipse::FromAxes({0.0, 0.0}, 10.0, 10.0, 0.0);
  Eigen::Matrix2Xd p(2, 2);
  p << 10.1, 0.0, 0.0, -9.9;
  const Eigen::VectorXd d = EllipseSampsonDistances(circle, p);
  EXPECT_NEAR(d(0), 0.1, 1e-3);
  EXPECT_NEAR(d(1), -0.1, 1e-3);
}

TEST(EllipseFit, RejectsOutliersAndRecoversTheCentre) {
  const Ellipse truth = Ellipse::FromAxes({100.25, 80.75}, 20.0, 15.0, 0.3);
  Eigen::Matrix2Xd points = PointsOn(truth, 120);
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 0.02);
  for (int i = 0; i < points.cols(); ++i) points.col(i) += truth.NormalAt(2.0 * std::numbers::pi * i / 120) * noise(rng);
  // Ten points pushed 1-3 px off (a burr or a label touching the mark).
  for (int i = 0; i < 10; ++i) points.col(i * 3) += truth.NormalAt(2.0 * std::numbers::pi * i * 3 / 120) * (1.0 + 0.2 * i);
  const EllipseFit fit = FitEllipse(points);
  ASSERT_TRUE(fit.ok) << fit.why_failed;
  EXPECT_EQ(fit.num_inliers, 110);
  for (int i = 0; i < 10; ++i) EXPECT_FALSE(fit.inlier[static_cast<size_t>(i * 3)]);
  EXPECT_LT((fit.ellipse.centre_px - truth.centre_px).norm(), 0.01);
  EXPECT_NEAR(fit.rms_px, 0.02, 0.005);
}

// The predicted centre covariance matches the scatter over noise draws: a
// wrong Jacobian or residual scale shows here.
TEST(EllipseFit, CentreCovarianceMatchesScatter) {
  const Ellipse truth = Ellipse::FromAxes({50.0, 40.0}, 21.5, 16.0, 0.7);
  const int n = 100, trials = 400;
  const double sigma_px = 0.05;
  std::mt19937 rng(11);
  std::normal_distribution<double> noise(0.0, sigma_px);
  Eigen::Matrix2d scatter = Eigen::Matrix2d::Zero(), predicted = Eigen::Matrix2d::Zero();
  for (int trial = 0; trial < trials; ++trial) {
    Eigen::Matrix2Xd points = PointsOn(truth, n);
    for (int i = 0; i < n; ++i) points.col(i) += truth.NormalAt(2.0 * std::numbers::pi * i / n) * noise(rng);
    EllipseFitOptions options;
    options.max_rejection_rounds = 0;
    const EllipseFit fit = FitEllipse(points, options);
    ASSERT_TRUE(fit.ok);
    const Eigen::Vector2d e = fit.ellipse.centre_px - truth.centre_px;
    scatter += e * e.transpose() / trials;
    predicted += fit.centre_cov_px2 / trials;
  }
  // 400 draws: the variance estimate is good to ~7% (1 sigma); allow 25%.
  EXPECT_NEAR(scatter(0, 0) / predicted(0, 0), 1.0, 0.25);
  EXPECT_NEAR(scatter(1, 1) / predicted(1, 1), 1.0, 0.25);
}

// centre_sensitivity is the centre's derivative with respect to each point's
// move across the curve: compare with refits after moving single points.
TEST(EllipseFit, CentreSensitivityMatchesFiniteDifferences) {
  const Ellipse truth = Ellipse::FromAxes({50.0, 40.0}, 21.5, 16.0, 0.7);
  const int n = 60;
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0.0, 0.05);
  Eigen::Matrix2Xd points = PointsOn(truth, n);
  for (int i = 0; i < n; ++i) points.col(i) += truth.NormalAt(2.0 * std::numbers::pi * i / n) * noise(rng);
  EllipseFitOptions options;
  options.max_rejection_rounds = 0;
  const EllipseFit fit = FitEllipse(points, options);
  ASSERT_TRUE(fit.ok);
  ASSERT_EQ(fit.centre_sensitivity.cols(), n);
  const double step_px = 1e-4;
  for (int i : {0, 7, 23, 41}) {
    // The curve's normal at the point (the Sampson distance's gradient).
    const Eigen::Vector2d normal = (fit.ellipse.shape * (points.col(i) - fit.ellipse.centre_px)).normalized();
    Eigen::Matrix2Xd moved = points;
    moved.col(i) += step_px * normal;
    const EllipseFit refit = FitEllipse(moved, options);
    const Eigen::Vector2d numeric = (refit.ellipse.centre_px - fit.ellipse.centre_px) / step_px;
    // First order in the step and in the residuals (0.05 px on a ~20 px ellipse).
    EXPECT_LT((numeric - fit.centre_sensitivity.col(i)).norm(), 0.02 * fit.centre_sensitivity.col(i).norm() + 1e-6)
        << i;
  }
}

TEST(EllipseFit, FailsCleanlyOnTooFewPoints) {
  const EllipseFit fit = FitEllipse(PointsOn(Ellipse::FromAxes({0, 0}, 5, 4, 0), 5));
  EXPECT_FALSE(fit.ok);
  EXPECT_FALSE(fit.why_failed.empty());
}

}  // namespace
}  // namespace omm
