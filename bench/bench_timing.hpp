// Timing helpers shared by the benchmark programs: wall clock, median, median over repeats.
#pragma once

#include <algorithm>
#include <chrono>
#include <functional>
#include <vector>

namespace bench {

inline double now_s() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

inline double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/// Median wall time of f over repeats after one untimed call (which also warms caches and
/// allocates work buffers); the repeat count adapts to about budget_s in total, at least 3.
inline double time_median(const std::function<void()>& f, int max_reps, double budget_s = 0.6) {
  double t0 = now_s();
  f();
  const double first = now_s() - t0;
  const int reps = std::max(3, std::min(max_reps, static_cast<int>(budget_s / (first + 1e-9))));
  std::vector<double> t;
  for (int r = 0; r < reps; ++r) {
    t0 = now_s();
    f();
    t.push_back(now_s() - t0);
  }
  return median(t);
}

}  // namespace bench
