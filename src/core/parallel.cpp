#include <kelvin/core/parallel.h>

#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

namespace kelvin {

ThreadLimit::ThreadLimit(int threads) {
    if (threads > 0)
        m_control = new tbb::global_control(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
}
ThreadLimit::~ThreadLimit() { delete static_cast<tbb::global_control*>(m_control); }

int thread_count() { return int(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism)); }

void parallel_for_units(std::size_t count, const std::function<void(std::size_t)>& body) {
    if (count == 0) return;
    // Grain size 1 and simple_partitioner: each unit is one task. Which thread runs a unit never
    // influences its result, because a unit's inputs (random stream, output slot) depend on its index only.
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, count, 1),
        [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t u = r.begin(); u != r.end(); ++u) body(u);
        },
        tbb::simple_partitioner());
}

}  // namespace kelvin
