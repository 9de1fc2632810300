#include "pipeline/core/parallel_for.h"

#include <sched.h>

#include <atomic>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

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

TEST(CostliestFirst, OrdersByCostDescendingEqualOnesByIndex) {
  EXPECT_EQ(CostliestFirst({12.0, 50.0, 40.0, 50.0, 0.0}), (std::vector<int>{1, 3, 2, 0, 4}));
  EXPECT_TRUE(CostliestFirst({}).empty());
}

// The CPUs the caller may run on, not the machine's: a thread limited to
// one CPU (as taskset or a container limits a process) counts one.
TEST(HardwareThreads, CountsTheCpusTheCallerMayUse) {
  cpu_set_t allowed;
  ASSERT_EQ(sched_getaffinity(0, sizeof(allowed), &allowed), 0);
  EXPECT_EQ(HardwareThreads(), CPU_COUNT(&allowed));
  int first = 0;
  while (!CPU_ISSET(first, &allowed)) ++first;
  int limited = 0;
  std::thread([&] {
    cpu_set_t one;
    CPU_ZERO(&one);
    CPU_SET(first, &one);
    if (sched_setaffinity(0, sizeof(one), &one) == 0) limited = HardwareThreads();
  }).join();
  EXPECT_EQ(limited, 1);
}

}  // namespace
}  // namespace omm
