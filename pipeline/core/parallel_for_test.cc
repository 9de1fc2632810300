#include "pipeline/core/parallel_for.h"

#include <atomic>
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>

namespace omm {
namespace {

TEST(ParallelFor, RunsEveryIndexOnce) {
  std::vector<std::atomic<int>> counts(100);
  ParallelFor(100, 3, [&](int i) { ++counts[i]; });
  for (const auto& c : counts) EXPECT_EQ(c.load(), 1);
}

// Items 30, 70 and 90 throw: every item still runs, and the error rethrown is
// index 30's, whichever thread met which first.
TEST(ParallelFor, RethrowsTheLowestIndexsErrorAfterAllItemsRan) {
  for (int repeat = 0; repeat < 20; ++repeat) {
    std::atomic<int> ran{0};
    try {
      ParallelFor(100, 2, [&](int i) {
        ++ran;
        if (i == 30 || i == 70 || i == 90) throw std::runtime_error("item " + std::to_string(i));
      });
      ADD_FAILURE() << "no exception";
    } catch (const std::runtime_error& e) {
      EXPECT_STREQ(e.what(), "item 30");
    }
    EXPECT_EQ(ran.load(), 100);
  }
}

}  // namespace
}  // namespace omm
