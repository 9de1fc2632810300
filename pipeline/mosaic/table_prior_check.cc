#include "pipeline/mosaic/table_prior_check.h"

#include <algorithm>
#include <cassert>
#include <cmath>

#include <Eigen/Eigenvalues>

#include "pipeline/core/plane_scene.h"
#include "pipeline/core/statistics.h"

namespace omm {

std::string TablePriorCheckOptions::Check() const {
  if (!(false_alarm_probability > 0.0 && false_alarm_probability < 1.0))
    return "false_alarm_probability must be in (0, 1)";
  if (!(min_redundancy > 0.0 && min_redundancy <= 1.0)) return "min_redundancy must be in (0, 1]";
  return "";
}

namespace {

// T_0's index in PlaneScene::covariance, after r and t.
const int kFirstTable = PlaneSceneCovarianceSize(0, 0, 0);

// Whether `covariance` holds the table positions of `num_tiles` tiles.
bool HasTableBlocks(const Eigen::MatrixXd& covariance, size_t num_tiles, double sigma_mm) {
  return covariance.rows() >= kFirstTable + 2 * static_cast<int>(num_tiles) && sigma_mm > 0.0;
}

// Tile i's residual, adjusted minus commanded, and its w^2 against the
// residual's covariance: sigma^2 I - C_i with its prior in the solve, sigma^2
// I + C_i left out (a prediction). Empty where the features check too
// little of it (options.min_redundancy).
std::optional<TablePriorTest> TestPosition(int i, const std::vector<Eigen::Vector2d>& commanded_mm,
                                           const std::vector<Eigen::Vector2d>& adjusted_mm,
                                           const Eigen::MatrixXd& covariance, double variance,
                                           bool left_out, const TablePriorCheckOptions& options) {
  const Eigen::Matrix2d block = covariance.block<2, 2>(kFirstTable + 2 * i, kFirstTable + 2 * i);
  const Eigen::Matrix2d residual_covariance = variance * Eigen::Matrix2d::Identity() +
                                              (left_out ? 0.5 : -0.5) * (block + block.transpose());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eigen(residual_covariance);
  if (!(eigen.eigenvalues()(0) >= options.min_redundancy * variance)) return std::nullopt;
  TablePriorTest test;
  test.tile = i;
  test.residual_mm = adjusted_mm[i] - commanded_mm[i];
  test.w2 = test.residual_mm.dot(residual_covariance.ldlt().solve(test.residual_mm));
  return test;
}

bool Contains(const std::vector<int>& tiles, int i) {
  return std::find(tiles.begin(), tiles.end(), i) != tiles.end();
}

}  // namespace

std::vector<TablePriorTest> TestTablePriors(const std::vector<Eigen::Vector2d>& commanded_mm,
                                            const std::vector<Eigen::Vector2d>& adjusted_mm,
                                            const Eigen::MatrixXd& covariance, double sigma_mm,
                                            const std::vector<int>& without_prior,
                                            const TablePriorCheckOptions& options) {
  assert(options.Check().empty());
  assert(adjusted_mm.size() == commanded_mm.size());
  std::vector<TablePriorTest> tests;
  if (!HasTableBlocks(covariance, commanded_mm.size(), sigma_mm)) return tests;
  for (int i = 0; i < static_cast<int>(commanded_mm.size()); ++i) {
    if (Contains(without_prior, i)) continue;
    if (const std::optional<TablePriorTest> test = TestPosition(
            i, commanded_mm, adjusted_mm, covariance, sigma_mm * sigma_mm, false, options)) {
      tests.push_back(*test);
    }
  }
  return tests;
}

double TablePriorBound(int num_tested, const TablePriorCheckOptions& options) {
  // chi-square(2)'s (1 - a) quantile in closed form: -2 ln(a).
  return -2.0 * std::log(options.false_alarm_probability / std::max(1, num_tested));
}

std::optional<TablePriorTest> WorstTablePriorOutlier(const std::vector<TablePriorTest>& tests,
                                                     const TablePriorCheckOptions& options) {
  if (tests.empty()) return std::nullopt;
  const auto worst = std::max_element(
      tests.begin(), tests.end(),
      [](const TablePriorTest& a, const TablePriorTest& b) { return a.w2 < b.w2; });
  if (!(worst->w2 > TablePriorBound(static_cast<int>(tests.size()), options))) return std::nullopt;
  return *worst;
}

bool LeftOutPriorsStandOut(const std::vector<Eigen::Vector2d>& commanded_mm,
                           const std::vector<Eigen::Vector2d>& adjusted_mm,
                           const Eigen::MatrixXd& covariance, double sigma_mm,
                           const std::vector<int>& without_prior,
                           const TablePriorCheckOptions& options) {
  assert(adjusted_mm.size() == commanded_mm.size());
  if (!HasTableBlocks(covariance, commanded_mm.size(), sigma_mm)) return false;
  std::vector<double> all_w2, left_out_w2;
  for (int i = 0; i < static_cast<int>(commanded_mm.size()); ++i) {
    const bool left_out = Contains(without_prior, i);
    const std::optional<TablePriorTest> test = TestPosition(
        i, commanded_mm, adjusted_mm, covariance, sigma_mm * sigma_mm, left_out, options);
    if (!test) continue;
    all_w2.push_back(test->w2);
    if (left_out) left_out_w2.push_back(test->w2);
  }
  if (left_out_w2.empty()) return false;
  const double scatter2 = std::max(1.0, Median(all_w2) / (2.0 * std::log(2.0)));
  // Each left-out position was found by the Bonferroni bound already: its
  // confirmation is one test at the false-alarm probability.
  const double bound = TablePriorBound(1, options);
  return std::all_of(left_out_w2.begin(), left_out_w2.end(),
                     [&](double w2) { return w2 / scatter2 > bound; });
}

TableSigmaEstimate EstimateTableSigma(const std::vector<Eigen::Vector2d>& commanded_mm,
                                      const std::vector<Eigen::Vector2d>& adjusted_mm,
                                      const Eigen::MatrixXd& covariance, double sigma_mm,
                                      const std::vector<int>& without_prior) {
  assert(adjusted_mm.size() == commanded_mm.size());
  TableSigmaEstimate estimate;
  if (!HasTableBlocks(covariance, commanded_mm.size(), sigma_mm)) return estimate;
  const double variance = sigma_mm * sigma_mm;
  double sum_squares = 0.0;
  for (int i = 0; i < static_cast<int>(commanded_mm.size()); ++i) {
    if (Contains(without_prior, i)) continue;
    sum_squares += (adjusted_mm[i] - commanded_mm[i]).squaredNorm();
    estimate.redundancy +=
        2.0 - covariance.block<2, 2>(kFirstTable + 2 * i, kFirstTable + 2 * i).trace() / variance;
  }
  if (!(estimate.redundancy >= 1.0)) return estimate;
  estimate.ok = true;
  estimate.sigma_mm = std::sqrt(sum_squares / estimate.redundancy);
  return estimate;
}

bool TableSigmaConsistent(const TableSigmaEstimate& estimate, double stated_mm) {
  if (!estimate.ok) return true;
  const double ratio = estimate.sigma_mm / stated_mm;
  const int dof = std::max(1, static_cast<int>(std::lround(estimate.redundancy)));
  return estimate.redundancy * ratio * ratio <= ChiSquareQuantile(0.999, dof);
}

WrongTablePriors FindWrongTablePriors(
    const std::vector<Eigen::Vector2d>& commanded_mm, double sigma_mm, const TablePriorSolve& first,
    const std::function<TablePriorSolve(const std::vector<int>&)>& solve_without,
    const TablePriorCheckOptions& options) {
  WrongTablePriors kept, trial;
  const size_t max_left_out = commanded_mm.size() / 3;
  TablePriorSolve latest = first;
  while (latest.usable && trial.tiles.size() < max_left_out) {
    const std::vector<TablePriorTest> tests = TestTablePriors(
        commanded_mm, latest.adjusted_mm, latest.covariance, sigma_mm, trial.tiles, options);
    const std::optional<TablePriorTest> worst = WorstTablePriorOutlier(tests, options);
    if (!worst) break;
    trial.tiles.insert(std::upper_bound(trial.tiles.begin(), trial.tiles.end(), worst->tile),
                       worst->tile);
    trial.found.emplace_back(*worst, TablePriorBound(static_cast<int>(tests.size()), options));
    ++trial.solve;
    latest = solve_without(trial.tiles);
    if (latest.usable &&
        TableSigmaConsistent(EstimateTableSigma(commanded_mm, latest.adjusted_mm, latest.covariance,
                                                sigma_mm, trial.tiles),
                             sigma_mm) &&
        LeftOutPriorsStandOut(commanded_mm, latest.adjusted_mm, latest.covariance, sigma_mm,
                              trial.tiles, options)) {
      kept = trial;
    }
  }
  return kept;
}

}  // namespace omm
