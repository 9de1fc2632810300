// Clocks for stage timings and benchmarks.
#pragma once

#include <chrono>
#include <ctime>

namespace omm {

// Wall time since `start`, s.
inline double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// CPU time of this process (all its threads), s. On a shared machine the wall
// time also counts other processes' load; the CPU time does not.
inline double ProcessCpuSeconds() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

}  // namespace omm
