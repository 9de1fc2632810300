// The table priors' data snooping on an exact linear model of the final
// adjustment: features give each tile's position, to tau, in a frame of
// their own (an unknown similarity of the part frame: only the priors fix
// it); the priors give each to sigma. The least-squares solve gives the
// adjusted positions and their covariance as the Ceres adjustment does.
#include "pipeline/mosaic/table_prior_check.h"

#include <algorithm>
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

// 3 x 3 tiles 100 mm apart, the table scattering by `scatter_mm` (the
// solve weighs its priors by kSigma); `blunders` added to their tiles'
// commanded positions; tiles in `unseen` have no feature.
struct Table {
  std::vector<std::pair<int, Eigen::Vector2d>> blunders;
  std::vector<int> unseen;
  double scatter_mm = kSigma;
};

// One draw of the priors and the features, solved with and without priors.
class Project {
 public:
  Project(std::mt19937& random, const Table& table) : unseen_(table.unseen) {
    std::normal_distribution<double> normal;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) truth_.emplace_back(100.0 * c, 100.0 * r);
    for (int i = 0; i < kTiles; ++i) {
      commanded_.push_back(truth_[i] +
                           table.scatter_mm * Eigen::Vector2d(normal(random), normal(random)));
      features_.emplace_back(normal(random), normal(random));  // (y - y_truth) / tau
    }
    for (const auto& [tile, offset] : table.blunders) commanded_[tile] += offset;
  }

  // Unknowns: dT_i (2n), then the features' frame (da, db, u_x, u_y),
  // linearised at the truth: y_i = T_i + [x -y; y x] (da, db) + u.
  Adjusted Solve(const std::vector<int>& without_prior = {}) const {
    const int num_unknowns = 2 * kTiles + 4;
    std::vector<Eigen::RowVectorXd> rows;
    std::vector<double> values;
    const auto has = [](const std::vector<int>& v, int i) {
      return std::find(v.begin(), v.end(), i) != v.end();
    };
    for (int i = 0; i < kTiles; ++i) {
      for (int k = 0; k < 2 && !has(without_prior, i); ++k) {
        Eigen::RowVectorXd prior = Eigen::RowVectorXd::Zero(num_unknowns);
        prior(2 * i + k) = 1.0 / kSigma;
        rows.push_back(prior);
        values.push_back((commanded_[i](k) - truth_[i](k)) / kSigma);
      }
      if (has(unseen_, i)) continue;
      const double x = truth_[i].x(), y = truth_[i].y();
      const Eigen::Matrix2d frame{{x, -y}, {y, x}};
      for (int k = 0; k < 2; ++k) {
        Eigen::RowVectorXd feature = Eigen::RowVectorXd::Zero(num_unknowns);
        feature(2 * i + k) = 1.0 / kTau;
        feature.segment<2>(2 * kTiles) = frame.row(k) / kTau;
        feature(2 * kTiles + 2 + k) = 1.0 / kTau;
        rows.push_back(feature);
        values.push_back(features_[i](k));
      }
    }
    Eigen::MatrixXd jacobian(rows.size(), num_unknowns);
    Eigen::VectorXd rhs(rows.size());
    for (size_t r = 0; r < rows.size(); ++r) {
      jacobian.row(r) = rows[r];
      rhs(r) = values[r];
    }
    const Eigen::MatrixXd inverse = (jacobian.transpose() * jacobian).inverse();
    const Eigen::VectorXd delta = inverse * (jacobian.transpose() * rhs);
    const int first = PlaneSceneCovarianceSize(0, 0, 0);
    Adjusted out;
    out.commanded = commanded_;
    out.covariance = Eigen::MatrixXd::Zero(first + 2 * kTiles, first + 2 * kTiles);
    out.covariance.bottomRightCorner(2 * kTiles, 2 * kTiles) =
        inverse.topLeftCorner(2 * kTiles, 2 * kTiles);
    for (int i = 0; i < kTiles; ++i) out.adjusted.push_back(truth_[i] + delta.segment<2>(2 * i));
    return out;
  }

  // The search for wrong positions, its solves this model's.
  WrongTablePriors FindWrong() const {
    const auto as_solve = [](const Adjusted& a) {
      return TablePriorSolve{true, a.adjusted, a.covariance};
    };
    return FindWrongTablePriors(
        commanded_, kSigma, as_solve(Solve()),
        [&](const std::vector<int>& without) { return as_solve(Solve(without)); },
        TablePriorCheckOptions{});
  }

 private:
  static constexpr int kTiles = 9;
  std::vector<int> unseen_;
  std::vector<Eigen::Vector2d> truth_, commanded_, features_;
};

Adjusted Solve(std::mt19937& random, const Table& table) { return Project(random, table).Solve(); }

std::vector<TablePriorTest> TestAll(const Adjusted& a) {
  return TestTablePriors(a.commanded, a.adjusted, a.covariance, kSigma, {},
                         TablePriorCheckOptions{});
}

TEST(TablePriorCheck, RightPriorsGiveChiSquareTwoAndRarelyAFlag) {
  std::mt19937 random(7);
  double sum_w2 = 0.0;
  int num_tests = 0, num_flagged = 0;
  for (int draw = 0; draw < 300; ++draw) {
    const std::vector<TablePriorTest> tests = TestAll(Solve(random, {}));
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
    const Adjusted a = Solve(random, {{{0, Eigen::Vector2d(0.15, 0.0)}}});
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
  const Adjusted a = Solve(random, {{{4, Eigen::Vector2d(3.0, 0.0)}}, /*unseen=*/{4}});
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
    const Adjusted a = Solve(random, {});
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
    const Adjusted a = Solve(random, {{}, {}, 2.0 * kSigma});
    sum_twice += std::pow(
        EstimateTableSigma(a.commanded, a.adjusted, a.covariance, kSigma, {}).sigma_mm / kSigma, 2);
  }
  EXPECT_NEAR(sum_twice / 200, 4.0, 0.32);  // 3 sd of the mean
  // Without a covariance there is no estimate.
  const Adjusted a = Solve(random, {});
  EXPECT_FALSE(EstimateTableSigma(a.commanded, a.adjusted, Eigen::MatrixXd(), kSigma, {}).ok);
}

// The search: one, two or three wrong positions are found and nothing
// else; right priors have none left out.
TEST(TablePriorCheck, TheSearchFindsOneTwoOrThreeWrongPositions) {
  std::mt19937 random(23);
  int none = 0;
  for (int draw = 0; draw < 300; ++draw) none += Project(random, {}).FindWrong().tiles.empty();
  EXPECT_GE(none, 299);
  const Eigen::Vector2d dx(0.3, 0.0), dy(0.0, -0.3), dxy(0.2, 0.2);
  int one = 0, two = 0, three = 0;
  for (int draw = 0; draw < 50; ++draw) {
    // 7.5 sigma: at the edge of the test's power (FindsACornerTileOffBySevenSigma).
    one += Project(random, {{{0, Eigen::Vector2d(0.15, 0.0)}}}).FindWrong().tiles ==
           std::vector<int>{0};
    two += Project(random, {{{0, dx}, {8, dy}}}).FindWrong().tiles == std::vector<int>{0, 8};
    three += Project(random, {{{0, dx}, {8, dy}, {4, dxy}}}).FindWrong().tiles ==
             std::vector<int>{0, 4, 8};
  }
  EXPECT_GE(one, 45);  // 96 of 100 in a longer run
  EXPECT_GE(two, 49);
  EXPECT_GE(three, 49);
  // The one they are found in, each with its bound.
  const WrongTablePriors wrong = Project(random, {{{0, dx}, {8, dy}}}).FindWrong();
  ASSERT_EQ(wrong.found.size(), 2u);
  EXPECT_EQ(wrong.solve, 2);
  EXPECT_NEAR(wrong.found[0].second, 18.2, 0.05);  // 9 tiles tested
  EXPECT_NEAR(wrong.found[1].second, 18.0, 0.05);  // 8
}

// Leaving out a scattering table's worst positions leaves the others
// consistent with a too small stated sigma by selection: the left-out ones
// do not stand out from the scatter of all, and none is left out.
TEST(TablePriorCheck, ATableScatteringMoreThanStatedHasNoneLeftOut) {
  std::mt19937 random(29);
  int none_at_4 = 0, none_at_2 = 0;
  for (int draw = 0; draw < 50; ++draw) {
    none_at_4 += Project(random, {{}, {}, 4.0 * kSigma}).FindWrong().tiles.empty();
    none_at_2 += Project(random, {{}, {}, 2.0 * kSigma}).FindWrong().tiles.empty();
  }
  // 989 and 938 of 1000 in a longer run; by the consistency test alone 88
  // and 61 of 100.
  EXPECT_GE(none_at_4, 49);
  EXPECT_GE(none_at_2, 42);
}

// Two or three positions off by 10 sigma each: the scatter they are
// weighed against includes them (LeftOutPriorsStandOut), which costs some
// power against several at once.
TEST(TablePriorCheck, TheSearchFindsSeveralModeratelyWrongPositions) {
  std::mt19937 random(31);
  const Eigen::Vector2d dx(0.2, 0.0), dy(0.0, -0.2), dxy(0.14, 0.14);
  int two = 0, three = 0;
  for (int draw = 0; draw < 50; ++draw) {
    two += Project(random, {{{0, dx}, {8, dy}}}).FindWrong().tiles == std::vector<int>{0, 8};
    three += Project(random, {{{0, dx}, {8, dy}, {4, dxy}}}).FindWrong().tiles ==
             std::vector<int>{0, 4, 8};
  }
  EXPECT_GE(two, 47);  // 984 of 1000 in a longer run
  EXPECT_GE(three, 43);  // 927 of 1000
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
