#pragma once
// Parallel work splitting on oneTBB. Kelvin's determinism rule lives here: callers split work into a fixed
// number of units (independent of the thread count), each unit owns its random stream and its output slot,
// and results are merged in unit order afterwards.
#include <cstddef>
#include <functional>

namespace kelvin {

/// Limit the worker threads used by every parallel_for_units call (0 = all hardware threads).
/// Lives for the lifetime of the object (RAII over tbb::global_control).
class ThreadLimit {
public:
    explicit ThreadLimit(int threads);
    ~ThreadLimit();
    ThreadLimit(const ThreadLimit&) = delete;
    ThreadLimit& operator=(const ThreadLimit&) = delete;

private:
    void* m_control = nullptr;
};

/// Number of threads parallel loops currently use.
int thread_count();

/// Run body(unit) for unit in [0, count), in parallel, one unit at a time per call (no batching that would
/// depend on the thread count). Exceptions thrown by a unit are rethrown in the caller.
void parallel_for_units(std::size_t count, const std::function<void(std::size_t unit)>& body);

}  // namespace kelvin
