// CheckpointSchedule (see include/kelvin/core/checkpoint.h).
#include <kelvin/core/checkpoint.h>
#include <kelvin/core/job.h>

#include <algorithm>
#include <climits>
#include <cmath>

namespace kelvin {

CheckpointSchedule::CheckpointSchedule(const RunContext& ctx)
    : m_seconds(ctx.checkpoint_seconds), m_sim_times(ctx.checkpoint_sim_times), m_work(ctx.checkpoint_work) {
    std::sort(m_seconds.begin(), m_seconds.end());
    std::sort(m_sim_times.begin(), m_sim_times.end());
    std::sort(m_work.begin(), m_work.end());
    m_active = bool(ctx.on_checkpoint) && (!m_seconds.empty() || !m_sim_times.empty() || !m_work.empty());
}

long long CheckpointSchedule::work_until_next(long long done) const {
    if (!m_active) return LLONG_MAX;
    for (std::size_t i = m_next_work; i < m_work.size(); ++i)
        if (m_work[i] > done) return m_work[i] - done;
    return LLONG_MAX;
}

double CheckpointSchedule::seconds_until_next(double elapsed) const {
    if (!m_active || m_next_seconds >= m_seconds.size()) return std::numeric_limits<double>::infinity();
    return std::max(0.0, m_seconds[m_next_seconds] - elapsed);
}

int CheckpointSchedule::reached(RunContext& ctx, const Checkpoint& state) {
    if (!m_active) return 0;
    Timer timer;
    int fired = 0;
    auto fire = [&](Checkpoint::Trigger trigger, std::size_t index, double target) {
        Checkpoint cp = state;
        cp.trigger = trigger;
        cp.index = int(index);
        cp.target = target;
        ctx.on_checkpoint(cp);
        ++fired;
    };
    for (; m_next_seconds < m_seconds.size() && state.seconds >= m_seconds[m_next_seconds]; ++m_next_seconds)
        fire(Checkpoint::Trigger::Seconds, m_next_seconds, m_seconds[m_next_seconds]);
    for (; m_next_work < m_work.size() && state.work >= double(m_work[m_next_work]); ++m_next_work)
        fire(Checkpoint::Trigger::Work, m_next_work, double(m_work[m_next_work]));
    if (state.sim_time >= 0)
        for (; m_next_sim < m_sim_times.size(); ++m_next_sim) {
            const double t = m_sim_times[m_next_sim];
            // Steps accumulate dt in floating point: t = 1 after 20 steps of 0.05 may read 0.99999999999.
            if (state.sim_time < t - 1e-9 * std::max(1.0, std::abs(t))) break;
            fire(Checkpoint::Trigger::SimTime, m_next_sim, t);
        }
    m_overhead += timer.seconds();
    return fired;
}

}  // namespace kelvin
