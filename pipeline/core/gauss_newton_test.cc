#include "pipeline/core/gauss_newton.h"

#include <algorithm>
#include <cmath>

#include <gtest/gtest.h>

#include "pipeline/core/error.h"

namespace omm {
namespace {

// Dennis and Schnabel's example of a nonzero-residual problem, with a second
// unknown that a linear residual fixes: r = (x + 1, lambda x^2 + x - 1,
// 3 (y - 2)). Its minimum is at x = 0, y = 2 for every lambda (the
// gradient 2 (x + 1) + 2 (lambda x^2 + x - 1)(2 lambda x + 1) vanishes at
// x = 0), where r = (1, -1, 0). There Gauss-Newton neglects the curvature
// r_2 r_2'' = -2 lambda against J^T J = 2: its steps in x shrink by the
// ratio |lambda|.
bool DennisSchnabel(double lambda, const Eigen::VectorXd& s, Eigen::VectorXd* r,
                    Eigen::SparseMatrix<double, Eigen::RowMajor>* J) {
  const double x = s(0), y = s(1);
  *r = Eigen::Vector3d(x + 1.0, lambda * x * x + x - 1.0, 3.0 * (y - 2.0));
  J->resize(3, 2);
  J->setZero();
  J->insert(0, 0) = 1.0;
  J->insert(1, 0) = 2.0 * lambda * x + 1.0;
  J->insert(2, 1) = 3.0;
  J->makeCompressed();
  return true;
}

constexpr double kStepTolerance = 1e-7;

GaussNewtonSummary Minimize(double lambda, bool line_search, Eigen::VectorXd* state) {
  GaussNewtonOptions options;
  options.max_iterations = 1000;
  options.step_tolerance = kStepTolerance;
  options.line_search = line_search;
  *state = Eigen::Vector2d(0.3, 0.0);
  return MinimizeByGaussNewton(
      [lambda](const Eigen::VectorXd& s, Eigen::VectorXd* r,
               Eigen::SparseMatrix<double, Eigen::RowMajor>* J) {
        return DennisSchnabel(lambda, s, r, J);
      },
      options, state);
}

// lambda = 0.85: Gauss-Newton's steps are 0.15 of the way (too short);
// -0.85: 1.85 times it, -1.5: 2.5 times it (too long, across the minimum).
TEST(GaussNewton, LineSearchCrossesWhereGaussNewtonStepsAreTooShortOrTooLong) {
  for (const double lambda : {0.85, -0.85, -1.5}) {
    SCOPED_TRACE(lambda);
    Eigen::VectorXd plain, searched;
    const GaussNewtonSummary slow = Minimize(lambda, false, &plain);
    const GaussNewtonSummary fast = Minimize(lambda, true, &searched);
    ASSERT_TRUE(fast.converged);
    EXPECT_LT(fast.iterations, 12);
    EXPECT_GT(fast.scaled, 0);
    // The minimum's neighbourhood where a step of the tolerance is left.
    EXPECT_LT(std::abs(searched(0)), 10.0 * kStepTolerance);
    EXPECT_NEAR(searched(1), 2.0, 1e-14);
    EXPECT_NEAR(fast.final_cost, 2.0, 1e-12);
    if (lambda < 0.0) {
      // Too long: Gauss-Newton's steps alone stop where one raises the cost,
      // short of the minimum.
      EXPECT_FALSE(slow.converged);
      EXPECT_GT(std::abs(plain(0)), 1e-3);
    } else {
      // Too short: plain steps below 1e-7 from x < 1e-7 / 0.15 on, from 0.3
      // log(0.3 x 0.15 / 1e-7) / log(1 / 0.85) = 80 of them (fewer where the
      // first, beyond the linear regime, shrink faster).
      ASSERT_TRUE(slow.converged);
      EXPECT_GT(slow.iterations, 60);
      EXPECT_LT(std::abs(plain(0)), kStepTolerance / 0.15);
    }
  }
}

TEST(GaussNewton, CostsAreReported) {
  Eigen::VectorXd state;
  const GaussNewtonSummary summary = Minimize(0.85, true, &state);
  EXPECT_DOUBLE_EQ(summary.initial_cost, 1.3 * 1.3 + std::pow(0.85 * 0.09 + 0.3 - 1.0, 2) + 36.0);
  EXPECT_NEAR(summary.final_cost, 2.0, 1e-12);
}

TEST(GaussNewton, QuadraticCostNeedsNoLineSearch) {
  // With lambda = 0 the residuals are linear: one step to the minimum.
  Eigen::VectorXd state;
  const GaussNewtonSummary summary = Minimize(0.0, true, &state);
  EXPECT_TRUE(summary.converged);
  EXPECT_LE(summary.iterations, 2);
  EXPECT_EQ(summary.scaled, 0);
  EXPECT_NEAR(state(0), 0.0, 1e-14);
}

TEST(GaussNewton, StopsWhereTheResidualsCannotBeEvaluated) {
  Eigen::VectorXd state = Eigen::Vector2d(0.3, 0.0);
  const GaussNewtonSummary summary = MinimizeByGaussNewton(
      [](const Eigen::VectorXd& s, Eigen::VectorXd* r,
         Eigen::SparseMatrix<double, Eigen::RowMajor>* J) {
        return s(1) == 0.0 && DennisSchnabel(0.85, s, r, J);  // only at the start
      },
      GaussNewtonOptions(), &state);
  EXPECT_FALSE(summary.converged);
  EXPECT_EQ(summary.iterations, 0);
  EXPECT_EQ(state, Eigen::VectorXd(Eigen::Vector2d(0.3, 0.0)));
}

// Against the dense product, on a banded J with empty rows and columns, both
// compressed and with room left in its rows (uncompressed).
TEST(DenseNormalMatrix, EqualsTheDenseProduct) {
  Eigen::SparseMatrix<double, Eigen::RowMajor> J(40, 12);
  J.reserve(Eigen::VectorXi::Constant(40, 6));
  for (int row = 0; row < 40; ++row) {
    if (row % 7 == 3) continue;
    for (int col = row % 9; col < std::min(12, row % 9 + 4); ++col) {
      if (col == 10) continue;
      J.insert(row, col) = std::sin(1.0 + row * 12 + col);
    }
  }
  const Eigen::MatrixXd dense = Eigen::MatrixXd(J);
  const Eigen::MatrixXd expected = dense.transpose() * dense;
  ASSERT_FALSE(J.isCompressed());
  EXPECT_LE((DenseNormalMatrix(J) - expected).cwiseAbs().maxCoeff(), 1e-14);
  J.makeCompressed();
  const Eigen::MatrixXd normal = DenseNormalMatrix(J);
  EXPECT_LE((normal - expected).cwiseAbs().maxCoeff(), 1e-14);
  EXPECT_EQ(normal, normal.transpose());
  EXPECT_EQ(normal.col(10).squaredNorm(), 0.0);
}

TEST(GaussNewtonOptions, InvalidOptionsAreNamed) {
  GaussNewtonOptions options;
  options.max_scale = 1.0;
  EXPECT_NE(options.Check().find("max_scale"), std::string::npos);
  Eigen::VectorXd state = Eigen::Vector2d(0.3, 0.0);
  EXPECT_THROW(MinimizeByGaussNewton(
                   [](const Eigen::VectorXd& s, Eigen::VectorXd* r,
                      Eigen::SparseMatrix<double, Eigen::RowMajor>* J) {
                     return DennisSchnabel(0.85, s, r, J);
                   },
                   options, &state),
               InputError);
}

}  // namespace
}  // namespace omm
