#pragma once
// Checkpoints: a run reports intermediate results (the image so far, the simulation state) at scheduled
// compute times, work counts or simulated times, without restarting. RunContext (job.h) carries the
// schedule and the callback; every loop that does a job's work drives a CheckpointSchedule:
//
//   - run_passes (src/render/integrator.cpp), hence every SamplingIntegrator and every integrator built on
//     run_passes (the MLT family);
//   - the mcfluid step loop (src/plugins/fluid/mcfluid.cpp), once per step (and once for the initial state).
//
// A loop with its own structure follows the same contract (see CheckpointSchedule below); `kelvin converge`
// (docs/convergence.md) is the main consumer.
#include <kelvin/core/image.h>
#include <kelvin/core/metrics.h>

#include <functional>
#include <limits>
#include <optional>
#include <string>
#include <vector>

namespace kelvin {

struct RunContext;

/// What a job reports at a checkpoint. Accessors are valid only during the callback.
struct Checkpoint {
    enum class Trigger { Seconds, Work, SimTime };
    Trigger trigger = Trigger::Work;
    int index = 0;      ///< position in the trigger's list (RunContext::checkpoint_seconds, _work, _sim_times)
    double target = 0;  ///< the scheduled value: seconds, work units or simulated time
    /// Compute seconds on the job's own clock (the one its time limit and time checkpoints use), excluding
    /// time spent in checkpoint callbacks. A consumer comparing whole runs times Job::run itself, as
    /// `kelvin converge` does, so that setup the job's clock may not count is charged too.
    double seconds = 0;
    double work = 0;  ///< work done so far: spp (renders), steps (simulations)
    std::string work_unit;
    /// The result so far, computed on call: the developed image (renders, normalised exactly like the final
    /// image) or the field image of the current state (simulations). Empty when the job has none.
    std::function<Bitmap()> image;

    // ----- simulations (sim_time >= 0); renders leave these empty
    double sim_time = -1;  ///< simulated time of the state
    CellGrid2 grid;        ///< the cell-centred grid of the fields
    /// Values of a named field ("vorticity", "u", "v") at the cell centres, row 0 at grid.min.y. Returns
    /// false when the job has no such field. Asking never changes the simulation.
    std::function<bool(const std::string& name, std::vector<double>& values)> field;
    /// The exact value of a named field at (t, x) when the job knows one (Taylor–Green, Lamb–Oseen initial
    /// conditions), std::nullopt otherwise. Empty when the job knows no exact solution at all.
    std::function<std::optional<double>(const std::string& name, double t, Vec2d x)> exact;

    // ----- 3D simulations (dimension 3): grid3 and exact3 replace grid and exact. Fields are components:
    // "vorticity_x", "vorticity_y", "vorticity_z", "u", "v", "w" (i fastest, then j, then k); `kelvin converge`
    // compares "vorticity" and "velocity" as vectors of three of them.
    int dimension = 2;
    CellGrid3 grid3;
    std::function<std::optional<double>(const std::string& name, double t, Vec3d x)> exact3;
};

using CheckpointCallback = std::function<void(const Checkpoint&)>;

/// The checkpoint schedule of one run (a copy of the context's lists, sorted). Use:
///
///     CheckpointSchedule cps(ctx);
///     while (working) {
///         chunk = std::min(chunk, cps.work_until_next(done));          // land exactly on work checkpoints
///         ... do `chunk` units of work ...
///         const double elapsed = timer.seconds() - cps.overhead();     // compute time only
///         Checkpoint cp; cp.seconds = elapsed; cp.work = done; cp.image = develop; ...
///         cps.reached(ctx, cp);                                        // fires every checkpoint now due
///         if (ctx.time_limit > 0 && elapsed >= ctx.time_limit) break;  // after the checkpoints
///     }
///
/// Each scheduled checkpoint fires at most once, at the first call whose seconds / work / sim_time reaches
/// it; several may fire in one call (in the order seconds, work, simulated time, each ascending). Work
/// checkpoints are exact when the loop clamps its chunks with work_until_next(); time checkpoints fire at
/// the end of the chunk that crosses them (Checkpoint::seconds says when exactly).
class CheckpointSchedule {
public:
    explicit CheckpointSchedule(const RunContext& ctx);
    /// A callback is set and something is scheduled.
    bool active() const { return m_active; }
    /// Work units that may be done, starting from `done`, without stepping over a work checkpoint
    /// (LLONG_MAX when none is ahead).
    long long work_until_next(long long done) const;
    /// Seconds from `elapsed` to the next pending time checkpoint (+inf when none).
    double seconds_until_next(double elapsed) const;
    /// Fire every pending checkpoint reached by `state` (its seconds, work and, for simulations, sim_time);
    /// trigger, index and target are filled in. Returns how many fired.
    int reached(RunContext& ctx, const Checkpoint& state);
    /// Seconds spent inside checkpoint callbacks so far (subtract them from elapsed time).
    double overhead() const { return m_overhead; }

private:
    bool m_active = false;
    std::vector<double> m_seconds, m_sim_times;
    std::vector<long long> m_work;
    std::size_t m_next_seconds = 0, m_next_work = 0, m_next_sim = 0;
    double m_overhead = 0;
};

}  // namespace kelvin
