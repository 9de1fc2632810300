// The table priors' data snooping on an exact linear model of the final
// adjustment: features give each tile's position, to tau, in a frame of
// their own (an unknown similarity of the part frame: only the priors fix
// it); the priors give each to sigma. The least-squares solve gives the
// adjusted positions and their covariance as the Ceres adjustment does.
#include "pipeline/mosaic/table_prior_check.h"

#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Dense>

#include "pipeline/core/plane_scene.h"

namespace omm {
namespace {

constexpr double kSigma = 0.02;  // table, mm
constexpr double kTau = 0.0015;  // features, mm (~0.01 px)

struct Adjusted {
  std::vector<Eigen::Vector2d> commanded, adjusted;
  Eigen::MatrixXd covariance;  // laid out as PlaneScene::covariance: T_i at 6 + 2i
};

// 3 x 3 tiles 100 mm apart; `blunder` added to tile `blunder_tile`'s
// commanded position; tiles in `unseen` have no feature. The table
// scatters by `scatter_mm`; the solve weighs its priors by kSigma.
Adjusted Solve(std::mt19937& random, int blunder_tile, const Eigen::Vector2d& blunder,
               const std::vector<int>& unseen = {}, double scatter_mm = kSigma) {
  std::normal_distribution<double> normal;
  const int n = 9;
  std::vector<Eigen::Vector2d> truth;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) truth.emplace_back(100.0 * c, 100.0 * r);
  // Unknowns: dT_i (2n), then the features' frame (da, db, u_x, u_y),
  // linearised at the truth: y_i = T_i + [x -y; y x] (da, db) + u.
  const int num_unknowns = 2 * n + 4;
  std::vector<Eigen::RowVectorXd> rows;
  std::vector<double> values;
  Adjusted out;
  for (int i = 0; i < n; ++i) {
    Eigen::Vector2d commanded =
        truth[i] + scatter_mm * Eigen::Vector2d(normal(random), normal(random));
    if (i == blunder_tile) commanded += blunder;
    out.commanded.push_back(commanded);
    for (int k = 0; k < 2; ++k) {
      Eigen::RowVectorXd prior = Eigen::RowVectorXd::Zero(num_unknowns);
      prior(2 * i + k) = 1.0 / kSigma;
      rows.push_back(prior);
      values.push_back((commanded(k) - truth[i](k)) / kSigma);
    }
    if (std::find(unseen.begin(), unseen.end(), i) != unseen.end()) continue;
    const double x = truth[i].x(), y = truth[i].y();
    const Eigen::Matrix2d frame{{x, -y}, {y, x}};
    for (int k = 0; k < 2; ++k) {
      Eigen::RowVectorXd feature = Eigen::RowVectorXd::Zero(num_unknowns);
      feature(2 * i + k) = 1.0 / kTau;
      feature.segment<2>(2 * n) = frame.row(k) / kTau;
      feature(2 * n + 2 + k) = 1.0 / kTau;
      rows.push_back(feature);
      values.push_back(normal(random));  // (y - y_truth) / tau
    }
  }
  Eigen::MatrixXd jacobian(rows.size(), num_unknowns);
  Eigen::VectorXd rhs(rows.size());
  for (size_t r = 0; r < rows.size(); ++r) {
    jacobian.row(r) = rows[r];
    rhs(r) = values[r];
  }
  const Eigen::MatrixXd information = jacobian.transpose() * jacobian;
  const Eigen::MatrixXd inverse = information.inverse();
  const Eigen::VectorXd delta = inverse * (jacobian.transpose() * rhs);
  const int first = PlaneSceneCovarianceSize(0, 0, 0);
  out.covariance = Eigen::MatrixXd::Zero(first + 2 * n, first + 2 * n);
  out.covariance.bottomRightCorner(2 * n, 2 * n) = inverse.topLeftCorner(2 * n, 2 * n);
  for (int i = 0; i < n; ++i) out.adjusted.push_back(truth[i] + delta.segment<2>(2 * i));
  return out;
}

std::vector<TablePriorTest> TestAll(const Adjusted& a) {
  return TestTablePriors(a.commanded, a.adjusted, a.covariance, kSigma, {},
                         TablePriorCheckOptions{});
}

TEST(TablePriorCheck, RightPriorsGiveChiSquareTwoAndRarelyAFlag) {
  std::mt19937 random(7);
  double sum_w2 = 0.0;
  int num_tests = 0, num_flagged = 0;
  for (int draw = 0; draw < 300; ++draw) {
    const std::vector<TablePriorTest> tests = TestAll(Solve(random, -1, Eigen::Vector2d::Zero()));
    ASSERT_EQ(tests.size(), 9u);  // every tile tied: all checkable
    for (const TablePriorTest& t : tests) sum_w2 += t.w2;
    num_tests += static_cast<int>(tests.size());
    num_flagged += WorstTablePriorOutlier(tests, TablePriorCheckOptions{}).has_value();
  }
  // E[w^2] = 2; the mean of 2700 (sd of the mean ~0.04 if independent).
  std::printf("mean w2 %.3f flagged %d\n", sum_w2 / num_tests, num_flagged);
  EXPECT_NEAR(sum_w2 / num_tests, 2.0, 0.15);
  EXPECT_LE(num_flagged, 2);  // 1e-3 per project: 0.3 expected in 300
}

TEST(TablePriorCheck, FindsACornerTileOffBySevenSigma) {
  std::mt19937 random(11);
  int found = 0;
  for (int draw = 0; draw < 50; ++draw) {
    const Adjusted a = Solve(random, 0, Eigen::Vector2d(0.15, 0.0));
    const auto worst = WorstTablePriorOutlier(TestAll(a), TablePriorCheckOptions{});
    found += worst.has_value() && worst->tile == 0;
    if (worst) {
      EXPECT_EQ(worst->tile, 0);
    }
  }
  EXPECT_GE(found, 48);
  EXPECT_NEAR(TablePriorBound(9, TablePriorCheckOptions{}), 18.2, 0.05);
}

TEST(TablePriorCheck, ATileNoFeatureTiesIsNotTestedAndSkippedTilesAreLeftOut) {
  std::mt19937 random(13);
  const Adjusted a = Solve(random, 4, Eigen::Vector2d(3.0, 0.0), /*unseen=*/{4});
  const std::vector<TablePriorTest> tests = TestAll(a);
  ASSERT_EQ(tests.size(), 8u);
  for (const TablePriorTest& t : tests) EXPECT_NE(t.tile, 4);
  EXPECT_FALSE(WorstTablePriorOutlier(tests, TablePriorCheckOptions{}).has_value());
  const std::vector<TablePriorTest> without_two = TestTablePriors(
      a.commanded, a.adjusted, a.covariance, kSigma, {2, 7}, TablePriorCheckOptions{});
  EXPECT_EQ(without_two.size(), 6u);
  EXPECT_TRUE(TestTablePriors(a.commanded, a.adjusted, Eigen::MatrixXd(), kSigma, {},
                              TablePriorCheckOptions{})
                  .empty());
}

// Right sigma: (sigma_hat / sigma)^2 averages 1, with a redundancy of ~14
// for 9 tiles (18 priors less the similarity's 4); a table scattering twice
// its stated sigma shows as twice.
TEST(TablePriorCheck, TheTablesScatterIsEstimated) {
  std::mt19937 random(17);
  double sum_ratio2 = 0.0;
  for (int draw = 0; draw < 200; ++draw) {
    const Adjusted a = Solve(random, -1, Eigen::Vector2d::Zero());
    const TableSigmaEstimate e =
        EstimateTableSigma(a.commanded, a.adjusted, a.covariance, kSigma, {});
    ASSERT_TRUE(e.ok);
    // 14 if the features fixed the relative positions exactly; their own
    // noise takes at most (tau / sigma)^2 of each of the 18 priors' dof.
    EXPECT_LT(e.redundancy, 14.0);
    EXPECT_GT(e.redundancy, 14.0 - 18.0 * (kTau / kSigma) * (kTau / kSigma));
    sum_ratio2 += std::pow(e.sigma_mm / kSigma, 2);
  }
  EXPECT_NEAR(sum_ratio2 / 200, 1.0, 0.08);  // 3 sd of the mean (chi-square(14) / 14)
  // A table that scatters twice what table.sigma_mm says.
  double sum_twice = 0.0;
  for (int draw = 0; draw < 200; ++draw) {
    const Adjusted a = Solve(random, -1, Eigen::Vector2d::Zero(), {}, 2.0 * kSigma);
    sum_twice += std::pow(
        EstimateTableSigma(a.commanded, a.adjusted, a.covariance, kSigma, {}).sigma_mm / kSigma, 2);
  }
  EXPECT_NEAR(sum_twice / 200, 4.0, 0.32);  // 3 sd of the mean
  // Without a covariance there is no estimate.
  const Adjusted a = Solve(random, -1, Eigen::Vector2d::Zero());
  EXPECT_FALSE(EstimateTableSigma(a.commanded, a.adjusted, Eigen::MatrixXd(), kSigma, {}).ok);
}

TEST(TablePriorCheck, OptionsAreChecked) {
  EXPECT_TRUE(TablePriorCheckOptions{}.Check().empty());
  TablePriorCheckOptions options;
  options.false_alarm_probability = 0.0;
  EXPECT_FALSE(options.Check().empty());
  options = {};
  options.min_redundancy = 1.5;
  EXPECT_FALSE(options.Check().empty());
}

}  // namespace
}  // namespace omm
