#pragma once
// Helpers shared by the command-line benchmarks (bench_mlt, bench_mmlt): the calling thread's CPU time, and the
// median of a sample.
#include <algorithm>
#include <ctime>
#include <vector>

namespace kelvin::bench {

/// CPU seconds used by the calling thread (CLOCK_THREAD_CPUTIME_ID).
inline double thread_cpu_seconds() {
    timespec ts{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

inline double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    const std::size_t n = v.size();
    return n == 0 ? 0.0 : n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

}  // namespace kelvin::bench
