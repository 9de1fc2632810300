// fn(i) for i in [0, n) on up to num_threads threads (the caller's one of
// them), indices handed out one at a time: for a few dozen coarse work items
// of uneven cost (tiles, pairs of tiles), where a thread pool would not pay.
// Every item runs even when some throw; then the exception of the lowest
// index that threw is rethrown, so the error does not depend on the threads'
// order (e.g. the first corrupt file in file order).
#pragma once

#include <sched.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <exception>
#include <numeric>
#include <thread>
#include <vector>

namespace omm {

// The hardware threads this process may run on (its CPU affinity: a
// container's or taskset's limit, where std::thread::hardware_concurrency
// counts the host's), 2 if the system does not say: the default thread count
// of one project's work.
inline int HardwareThreads() {
  cpu_set_t cpus;
  if (sched_getaffinity(0, sizeof(cpus), &cpus) == 0 && CPU_COUNT(&cpus) > 0)
    return CPU_COUNT(&cpus);
  const unsigned n = std::thread::hardware_concurrency();
  return n > 0 ? static_cast<int>(n) : 2;
}

// Makes the calling thread yield its core to the process's other threads
// (nice +10; the threads it then starts inherit that): for work that should
// only fill the cores they leave idle. Linux's nice is per thread.
inline void YieldCoresToOtherThreads() {
  setpriority(PRIO_PROCESS, static_cast<id_t>(gettid()), 10);
}

template <typename Fn>
void ParallelFor(int n, int num_threads, Fn fn) {
  std::vector<std::exception_ptr> errors(std::max(n, 0));
  std::atomic<int> next{0};
  const auto work = [&] {
    for (int i = next++; i < n; i = next++) {
      try {
        fn(i);
      } catch (...) {
        errors[i] = std::current_exception();
      }
    }
  };
  std::vector<std::thread> threads;
  for (int t = 1; t < std::min(num_threads, n); ++t) threads.emplace_back(work);
  work();
  for (std::thread& t : threads) t.join();
  for (const std::exception_ptr& error : errors) {
    if (error) std::rethrow_exception(error);
  }
}

// The indices of `costs` from the largest to the smallest (equal ones in
// index order): the order to hand ParallelFor items of uneven cost in, so
// that no costly one starts last and keeps one thread busy alone.
inline std::vector<int> CostliestFirst(const std::vector<double>& costs) {
  std::vector<int> order(costs.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(),
                   [&](int a, int b) { return costs[a] > costs[b]; });
  return order;
}

}  // namespace omm
