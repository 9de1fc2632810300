// Which table positions the features contradict: a tile whose table.csv
// position is off by much more than table.sigma_mm (a typing error, a
// position logged for the wrong tile, a table that did not reach its
// target) pulls the adjustment's scale and rotation with it, and so every
// distance, silently. Baarda's data snooping on the table priors finds it.
//
// The prior of tile i is the observation T_i,commanded = T_i + e_i, e_i ~
// N(0, sigma^2 I). After the adjustment its residual r_i = T_i,adjusted -
// T_i,commanded has covariance sigma^2 I - C_i, C_i the adjusted T_i's
// 2 x 2 block of the scene covariance (the residual of an observation in a
// least-squares fit: its own covariance minus that of the fitted value).
// Then w_i^2 = r_i' (sigma^2 I - C_i)^-1 r_i is chi-square with 2 dof when
// the priors are right. The features fix the tiles' relative positions, so
// the priors only have the similarity's 4 dof to carry: with 9 tiles, 14 of
// their 18 dof are redundant and a corner tile 0.15 mm off at sigma 0.02 mm
// is found (48 of 50 draws or more in the test; at 0.1 mm, w^2 ~ 17.5 sits
// at the bound). A tile that the features do not tie (held by its prior) has
// sigma^2 I - C_i ~ 0: it cannot be checked and is not.
#pragma once

#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace omm {

struct TablePriorCheckOptions {
  // Probability that a project whose priors are all right has one flagged:
  // the bound on w^2 is chi-square(2)'s (1 - p / m) quantile, m the tiles
  // tested (Bonferroni): 18.2 for 9 tiles at 1e-3.
  double false_alarm_probability = 1e-3;
  // A tile is tested when the smallest eigenvalue of (sigma^2 I - C_i) /
  // sigma^2 (its redundancy: how much of the prior the features check)
  // reaches this.
  double min_redundancy = 0.1;

  std::string Check() const;  // empty if valid, else what is wrong
};

struct TablePriorTest {
  int tile = -1;
  Eigen::Vector2d residual_mm = Eigen::Vector2d::Zero();  // adjusted minus commanded
  double w2 = 0.0;                                        // r' (sigma^2 I - C)^-1 r
};

// Each tile that can be tested, in order. `covariance`: the scene
// covariance (PlaneScene::covariance, T_i at rows 6 + 2i); tiles in
// `without_prior` (their prior already left out) are not tested. Empty
// without a covariance.
std::vector<TablePriorTest> TestTablePriors(const std::vector<Eigen::Vector2d>& commanded_mm,
                                            const std::vector<Eigen::Vector2d>& adjusted_mm,
                                            const Eigen::MatrixXd& covariance, double sigma_mm,
                                            const std::vector<int>& without_prior,
                                            const TablePriorCheckOptions& options);

// The bound on w^2 when `num_tested` tiles are tested (options' comment).
double TablePriorBound(int num_tested, const TablePriorCheckOptions& options);

// The test with the largest w^2 if it exceeds the bound for tests.size().
std::optional<TablePriorTest> WorstTablePriorOutlier(const std::vector<TablePriorTest>& tests,
                                                     const TablePriorCheckOptions& options);

// Whether the positions left out stand out from the others, after the solve
// without their priors: leaving out the worst few of a table that scatters
// several times its stated sigma leaves the rest consistent with it by
// selection, as wrong positions would. Each left-out position is tested as
// a prediction (residual covariance sigma^2 I + C_i), with sigma widened to
// the scatter of all the tiles estimated robustly (the median w^2 over the
// tiles, a third of them wrong or not, over chi-square(2)'s median 2 ln 2),
// against chi-square(2)'s 1 - false_alarm_probability quantile. True if
// every left-out position still exceeds it. On the exact linear model
// (table_prior_check_test, 1000 draws), a table scattering 4 (2) times its
// stated sigma then has no position left out in 98.9 % (93.8 %), against
// 88 % (61 %) by the consistency of the rest alone. One, two, three tiles
// 0.2 mm off (10 sigma) are found in 99.8, 98.4, 92.7 %; 0.15 mm off in
// 93, 81, 59 %. Weighing the median by its expectation were the left-out
// ones wrong would find 97, 94, 91 % of the latter, but leave out
// positions of a table scattering 4 times its sigma in 5.8 %, the stated
// sigma then kept: sigmas too small. A wrong position missed leaves the
// others inconsistent instead, and the priors are then weighed by the
// scatter (mosaic_stage.cc): sigmas wider, and true.
bool LeftOutPriorsStandOut(const std::vector<Eigen::Vector2d>& commanded_mm,
                           const std::vector<Eigen::Vector2d>& adjusted_mm,
                           const Eigen::MatrixXd& covariance, double sigma_mm,
                           const std::vector<int>& without_prior,
                           const TablePriorCheckOptions& options);

// How far the table positions scatter about where the features put them,
// against table.sigma_mm: the variance component of the priors (Förstner),
// sigma_hat^2 = sum |r_i|^2 / redundancy, the redundancy sum_i tr(I - C_i /
// sigma^2) over the priors used (about 14 of 18 for 9 tiles). When the
// stated sigma is right, redundancy (sigma_hat / sigma)^2 is chi-square with
// that many dof. Every measurement's table part scales with the stated
// sigma, so one the data contradict is worth saying.
struct TableSigmaEstimate {
  bool ok = false;  // a covariance and a redundancy of 1 or more
  double sigma_mm = 0.0;
  double redundancy = 0.0;
};
TableSigmaEstimate EstimateTableSigma(const std::vector<Eigen::Vector2d>& commanded_mm,
                                      const std::vector<Eigen::Vector2d>& adjusted_mm,
                                      const Eigen::MatrixXd& covariance, double sigma_mm,
                                      const std::vector<int>& without_prior);

// Whether the estimate is what table.sigma_mm says: redundancy (estimate /
// stated)^2 within chi-square's 99.9 % quantile (true without an estimate).
bool TableSigmaConsistent(const TableSigmaEstimate& estimate, double stated_mm);

// An adjustment solved without some tiles' table priors, as the search
// below needs it.
struct TablePriorSolve {
  bool usable = false;
  std::vector<Eigen::Vector2d> adjusted_mm;  // each tile's adjusted T_i
  Eigen::MatrixXd covariance;                // PlaneScene::covariance's layout
};

struct WrongTablePriors {
  std::vector<int> tiles;  // ascending: the priors to leave out (none: all kept)
  // Each one as found, with the bound it exceeded.
  std::vector<std::pair<TablePriorTest, double>> found;
  // Which solve has them left out: 0 the one given, k the k-th call of
  // `solve_without`.
  int solve = 0;
};

// The search for wrong table positions: the worst beyond the bound
// (WorstTablePriorOutlier) has its prior left out and the adjustment is
// solved again (`solve_without`, given the ascending tiles to leave out),
// while one is found, for a third of the tiles at most. The leave-outs are
// kept up to the last solve after which the remaining priors agree with
// `sigma_mm` (TableSigmaConsistent) and the left-out ones stand out from
// them (LeftOutPriorsStandOut): one, two or three wrong positions are
// found; a table scattering more than its stated sigma has none left out,
// and EstimateTableSigma on the first solve says so.
WrongTablePriors FindWrongTablePriors(
    const std::vector<Eigen::Vector2d>& commanded_mm, double sigma_mm, const TablePriorSolve& first,
    const std::function<TablePriorSolve(const std::vector<int>&)>& solve_without,
    const TablePriorCheckOptions& options);

}  // namespace omm
