#pragma once
// Helpers shared by the benchmarks: the calling thread's CPU time, the median of a sample, and the thread count
// from KELVIN_BENCH_THREADS.
#include <algorithm>
#include <cstdlib>
#include <ctime>
#include <vector>

namespace kelvin::bench {

/// CPU seconds used by the calling thread (CLOCK_THREAD_CPUTIME_ID).
inline double thread_cpu_seconds() {
    timespec ts{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

/// CPU seconds used by the whole process, every thread (CLOCK_PROCESS_CPUTIME_ID): the figure to report on a
/// loaded machine, where wall time measures the other processes.
inline double process_cpu_seconds() {
    timespec ts{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

inline double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    const std::size_t n = v.size();
    return n == 0 ? 0.0 : n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/// Worker threads for a benchmark: KELVIN_BENCH_THREADS, or 0 (all cores) when unset.
inline int bench_threads() {
    const char* env = std::getenv("KELVIN_BENCH_THREADS");
    return env ? std::atoi(env) : 0;
}

}  // namespace kelvin::bench
