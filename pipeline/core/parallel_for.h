// fn(i) for i in [0, n) on up to num_threads threads (the caller's one of
// them), indices handed out one at a time: for a few dozen coarse work items
// of uneven cost (tiles, pairs of tiles), where a thread pool would not pay.
#pragma once

#include <algorithm>
#include <atomic>
#include <thread>
#include <vector>

namespace omm {

template <typename Fn>
void ParallelFor(int n, int num_threads, Fn fn) {
  std::atomic<int> next{0};
  const auto work = [&] {
    for (int i = next++; i < n; i = next++) fn(i);
  };
  std::vector<std::thread> threads;
  for (int t = 1; t < std::min(num_threads, n); ++t) threads.emplace_back(work);
  work();
  for (std::thread& t : threads) t.join();
}

}  // namespace omm
