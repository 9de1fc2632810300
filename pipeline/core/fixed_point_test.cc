#include "pipeline/core/fixed_point.h"

#include <cmath>

#include <gtest/gtest.h>
#include <Eigen/LU>

namespace omm {
namespace {

// Rounds of x <- next(x, G) from x0 until |G(x) - x| < tolerance.
template <typename Next>
int RoundsToSettle(const Eigen::MatrixXd& a, const Eigen::VectorXd& b, Eigen::VectorXd x,
                   double tolerance, Next next, Eigen::VectorXd* settled) {
  const auto G = [&](const Eigen::VectorXd& v) { return Eigen::VectorXd(a * v + b); };
  Eigen::VectorXd x_prev, g_prev;
  int rounds = 0;
  for (; rounds < 200; ++rounds) {
    const Eigen::VectorXd g = G(x);
    if ((g - x).cwiseAbs().maxCoeff() < tolerance) break;
    Eigen::VectorXd x_next = x_prev.size() == 0 ? g : next(x_prev, g_prev, x, g);
    x_prev = x, g_prev = g;
    x = x_next;
  }
  *settled = x;
  return rounds;
}

// G(x) = A x + b with A = rho on one direction and 0 elsewhere: the
// perspective-bias settle of a splined calibration (rho ~ 0.57 a round).
TEST(AndersonStep, OneSlowModeSettlesInThreeRoundsWherePlainIterationTakesMany) {
  const int n = 20;
  Eigen::VectorXd u = Eigen::VectorXd::LinSpaced(n, -1.0, 2.0).normalized();
  Eigen::MatrixXd a = 0.57 * u * u.transpose();
  Eigen::VectorXd b = Eigen::VectorXd::LinSpaced(n, 0.3, -0.1);
  const Eigen::VectorXd x_star = (Eigen::MatrixXd::Identity(n, n) - a).partialPivLu().solve(b);
  const auto plain = [](const auto&, const auto&, const auto&, const Eigen::VectorXd& g) {
    return g;
  };
  const auto anderson = [](const Eigen::VectorXd& xp, const Eigen::VectorXd& gp,
                           const Eigen::VectorXd& x,
                           const Eigen::VectorXd& g) { return AndersonStep(xp, gp, x, g); };
  Eigen::VectorXd settled_plain, settled_anderson;
  const int rounds_plain =
      RoundsToSettle(a, b, Eigen::VectorXd::Zero(n), 1e-6, plain, &settled_plain);
  const int rounds_anderson =
      RoundsToSettle(a, b, Eigen::VectorXd::Zero(n), 1e-6, anderson, &settled_anderson);
  // Plain: the change shrinks by 0.57 a round from ~0.3.
  EXPECT_GE(rounds_plain, 20);
  // Anderson: a plain step (the fast directions' error vanishes), a secant
  // step from a pair not yet on the slow mode alone, then one from a pair
  // on it lands on x*.
  EXPECT_LE(rounds_anderson, 3);
  EXPECT_LT((settled_anderson - x_star).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_LT((settled_plain - x_star).cwiseAbs().maxCoeff(), 2e-6);
}

// Two slow modes of different rates: no single secant step removes both,
// but the iteration still settles, in fewer rounds than plain iteration.
TEST(AndersonStep, TwoModesSettleFasterThanPlainIteration) {
  const int n = 12;
  const Eigen::VectorXd u = Eigen::VectorXd::LinSpaced(n, 1.0, 3.0).normalized();
  Eigen::VectorXd v = Eigen::VectorXd::LinSpaced(n, -2.0, 1.0);
  v -= v.dot(u) * u;
  v.normalize();
  const Eigen::MatrixXd a = 0.8 * u * u.transpose() + 0.5 * v * v.transpose();
  const Eigen::VectorXd b = Eigen::VectorXd::Ones(n);
  const Eigen::VectorXd x_star = (Eigen::MatrixXd::Identity(n, n) - a).partialPivLu().solve(b);
  Eigen::VectorXd settled_plain, settled_anderson;
  const int rounds_plain = RoundsToSettle(
      a, b, Eigen::VectorXd::Zero(n), 1e-6,
      [](const auto&, const auto&, const auto&, const Eigen::VectorXd& g) { return g; },
      &settled_plain);
  const int rounds_anderson = RoundsToSettle(
      a, b, Eigen::VectorXd::Zero(n), 1e-6,
      [](const Eigen::VectorXd& xp, const Eigen::VectorXd& gp, const Eigen::VectorXd& x,
         const Eigen::VectorXd& g) { return AndersonStep(xp, gp, x, g); },
      &settled_anderson);
  EXPECT_LT(rounds_anderson, rounds_plain / 2);
  EXPECT_LT((settled_anderson - x_star).cwiseAbs().maxCoeff(), 1e-5);
}

// A residual that has not changed gives no secant: the plain step.
TEST(AndersonStep, EqualResidualsGiveThePlainStep) {
  const Eigen::Vector3d x_prev(0, 0, 0), g_prev(1, 1, 1), x(1, 2, 3), g(2, 3, 4);
  EXPECT_EQ(AndersonStep(x_prev, g_prev, x, g), g);
}

// The secant's reach is bounded: residuals that barely differ (rho near 1)
// would extrapolate without limit.
TEST(AndersonStep, ExtrapolationIsHeldToMinGamma) {
  const Eigen::VectorXd x_prev = Eigen::VectorXd::Constant(1, 0.0);
  const Eigen::VectorXd g_prev = Eigen::VectorXd::Constant(1, 1.0);  // f = 1
  const Eigen::VectorXd x = Eigen::VectorXd::Constant(1, 1.0);
  const Eigen::VectorXd g = Eigen::VectorXd::Constant(1, 1.999);  // f = 0.999
  // Unbounded: gamma = 0.999 / -0.001 = -999, x = 1.999 + 999 * 0.999.
  const AndersonStepOptions options;
  EXPECT_NEAR(AndersonStep(x_prev, g_prev, x, g)(0), 1.999 - options.min_gamma * 0.999, 1e-12);
}

}  // namespace
}  // namespace omm
