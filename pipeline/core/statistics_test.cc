#include "pipeline/core/statistics.h"

#include <cmath>

#include <gtest/gtest.h>

namespace omm {
namespace {

TEST(Median, OddCountIsTheMiddleValue) { EXPECT_EQ(Median({5.0, -1.0, 3.0}), 3.0); }

TEST(Median, EvenCountIsTheUpperMiddleValue) { EXPECT_EQ(Median({4.0, 1.0, 3.0, 2.0}), 3.0); }

TEST(Median, EmptyIsNaN) { EXPECT_TRUE(std::isnan(Median({}))); }

// Against the exact quantiles (scipy.stats.chi2.ppf(0.999, dof)): closed
// forms for 1 and 2 dof, Wilson-Hilferty from 3.
TEST(ChiSquareQuantile, MatchesTheExactOnesAtTheGuardsProbability) {
  const double exact[] = {10.828, 13.816, 16.266, 18.467, 20.515, 22.458};
  for (int dof = 1; dof <= 6; ++dof) {
    EXPECT_NEAR(ChiSquareQuantile(0.999, dof) / exact[dof - 1], 1.0, dof <= 2 ? 1e-4 : 0.02) << dof;
  }
}

}  // namespace
}  // namespace omm
