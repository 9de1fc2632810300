#include "pipeline/core/statistics.h"

#include <cmath>

#include <gtest/gtest.h>

namespace omm {
namespace {

TEST(Median, OddCountIsTheMiddleValue) { EXPECT_EQ(Median({5.0, -1.0, 3.0}), 3.0); }

TEST(Median, EvenCountIsTheUpperMiddleValue) { EXPECT_EQ(Median({4.0, 1.0, 3.0, 2.0}), 3.0); }

TEST(Median, EmptyIsNaN) { EXPECT_TRUE(std::isnan(Median({}))); }

}  // namespace
}  // namespace omm
