#pragma once
// The checks every fluid run loop makes (mcfluid in 2D and 3D, the baselines stable_fluids, flip and
// vortex_particles), in one place so that the loops cannot disagree:
//
//  - the run's frames folder is usable before any work (check_frames_folder);
//  - the memory a run will need, estimated from its resolution before anything is allocated (memory_estimate_2d/3d,
//    checked with core/memory.h's check_memory at scene load);
//  - every state is representable before it is written: diagnostics finite in double (the CSV), every field value
//    finite as the float32 that EXR and VDB files store (StepChecks::state); the initial state is refused at
//    setup naming the initial vorticity's strength parameter (exit 2), a later state stops the run (exit 1)
//    naming the quantity, the cell and the step, with the outputs of the earlier steps kept;
//  - the time step against the flow: the CFL number max |u| dt / h of every state (the CSV's `cfl` column, the
//    run's maximum in --stats as fluid.cfl_max), a warning above cfl_warn_bound, a refusal naming dt when a step would
//    carry the flow farther than the domain's smallest side (StepChecks::cfl);
//  - the time limit inside a step (TimeLimitWatch): a token the solvers poll with their interrupt checks.
#include <kelvin/core/error.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/properties.h>
#include <kelvin/core/stats.h>
#include <kelvin/fluid/output.h>

#include <condition_variable>
#include <cstdint>
#include <limits>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

namespace kelvin::fluid {

/// float32's largest finite value: EXR and VDB fields store 32-bit floats, so a double above it is written as inf.
inline constexpr double FloatMax = double(std::numeric_limits<float>::max());

/// The largest ratio of a cell's sides a simulation accepts (refused at parse time, naming the cache): the cache's
/// interpolation, the isotropic mollifier and the near field's quadrature (whose cost grows with the ratio) assume
/// cells of comparable sides. Well above any scene's (they use near-cubic cells; the derived resolutions round).
inline constexpr double MaxCellAspect = 64;

/// The CFL number above which a run warns (once), by method. Semi-Lagrangian transport (mcfluid, stable_fluids) is
/// stable at any CFL number, but its backtrace freezes the velocity over the step, so its error grows with the
/// distance it crosses: CflWarnSemiLagrangian = 20 cells. The bound is well above what the largest Monte Carlo
/// velocity samples give the shipped scenes at their defaults (up to 15: max |u| of a noisy estimate is set by its
/// noise near the walls, not by the flow). Particle methods (vortex_particles, flip) move their particles along the
/// velocity with explicit stages, and a particle that crosses more than a few cells per step skips the cells
/// between (FLIP's usual bound, Bridson 2015): CflWarnParticles = 5.
inline constexpr double CflWarnSemiLagrangian = 20;
inline constexpr double CflWarnParticles = 5;
/// The warning bound of the solver `who` ("mcfluid", "stable_fluids", "flip", "vortex_particles").
double cfl_warn_bound(const std::string& who);

/// Where the scene gave what the checks blame, for errors that name the parameter (exit 2).
struct RunSources {
    SourceLoc dt;                  ///< the simulation's dt (its element when the scene left it at the default)
    SourceLoc vorticity;           ///< the <vorticity> element
    std::string vorticity_plugin;  ///< "vortex_ring"
    std::string strength;          ///< the parameter that scales it ("circulation"); empty: not known
    /// From the simulation's properties (dt, the <vorticity> child) and the field's strength_parameter().
    static RunSources from(const Properties& props, const std::string& vorticity_plugin, const std::string& strength);
};

/// The bound of a length parameter of an estimator or boundary against the domain (scene load, exit 2): "" when
/// `value` is below `fraction` x `smaller_side` (the domain's smaller side), otherwise one line naming the parameter,
/// both sizes and `why` (what the parameter would do at that size).
std::string check_scale(const std::string& name, double value, double smaller_side, double fraction,
                        const std::string& why);

/// A named scalar of a state (a diagnostic written to the CSV).
struct NamedValue {
    double value;
    const char* name;
};

/// Throws InputError (exit 2) when the frames folder of `paths` (beside -o) cannot be a folder: it exists and is
/// not one, or a parent of it is a file. `who` names the solver. Called by every run loop before any work.
void check_frames_folder(const OutputPaths& paths, const std::string& who);

/// Bytes a 2D run of `solver` ("mcfluid", "stable_fluids", "flip", "vortex_particles") on an nx x ny grid will
/// need at its peak: the solver's grids and tables per cell, the images of an output, and the process itself.
double memory_estimate_2d(const std::string& solver, long long nx, long long ny, bool dye);
/// The same for 3D mcfluid: its vector grids (with control variates the previous state's too), the estimator's
/// tables, smoke and solids, and the VDB frame written from them.
double memory_estimate_3d(long long nx, long long ny, long long nz, bool control_variates, bool smoke, bool boundaries,
                          bool vdb);

/// The same for the 3D grid baselines (stable_fluids, or flip with `particles_per_cell`): the MAC faces and their
/// copies, the pressure solver (multigrid levels with solids), the FFT buffers, the output grids and, for FLIP, the
/// particles and the copies a stop restores (measured: 180 B per cell for stable_fluids, 1.1 kB for flip at 8 per
/// cell).
double memory_estimate_3d_grid(bool flip, int particles_per_cell, long long nx, long long ny, long long nz);

/// The checks of one run, step by step.
class StepChecks {
public:
    /// `h`: the smallest cell size; `extent`: the domain's smallest side; `cells_across` = extent / h.
    StepChecks(std::string who, RunSources sources, double h, double extent);

    /// The first diagnostic that is not finite, or the first field value that is not finite as a float32, as
    /// "velocity u = 3.1e+39 at cell (4, 7)" (empty: all representable).
    static std::string unrepresentable(const std::vector<NamedValue>& scalars, const std::vector<FieldValues>& fields);

    /// A state before any of it is output: "" when it can be written, otherwise the one-line message. At step 0
    /// the problem is the input's: throws InputError naming the vorticity's strength parameter. `replaced`: the
    /// non-finite estimates the solver replaced by zero in this state (more than 1 % of `cells`: the flow
    /// overflowed as a whole). Counted (fluid.non_finite_states).
    std::string state(long long step, const std::vector<NamedValue>& scalars, const std::vector<FieldValues>& fields,
                      uint64_t replaced = 0, std::size_t cells = 0);

    /// The CFL number of a state whose largest speed is `max_speed`, for a step of length `dt` from it; warns once
    /// above cfl_warn_bound(who) (naming dt and the step) and throws InputError naming dt when max_speed dt exceeds the
    /// domain's smallest side (a step would carry the flow out of the domain). Records the run's maximum. The
    /// run's last state (`last`: no step follows) is only recorded.
    double cfl(long long step, double max_speed, double dt, bool last = false);
    double max_cfl() const { return m_max_cfl; }
    /// fluid.cfl_max, fluid.cfl_warnings, fluid.non_finite_states into `stats`.
    void report(Stats& stats) const;

private:
    std::string m_who;
    RunSources m_src;
    double m_h, m_extent, m_warn;
    double m_max_cfl = 0;
    bool m_warned = false;
    uint64_t m_non_finite = 0;
};

/// The diagnostics of a 2D state that the CSV writes, by name (`energy`: with the kinetic energies; false when the
/// state's velocity was not estimated).
std::vector<NamedValue> diagnostic_values(const FluidDiagnostics& d, bool energy = true);

/// The largest |u| of velocity components given as fields of one grid (2 or 3 of them, same size).
double max_speed(const std::vector<const std::vector<double>*>& components);

/// The run's time limit inside a step: a watch thread cancels token() when `seconds` have passed since
/// construction (none when seconds <= 0). The solvers poll it with their interrupt checks
/// (Cancellable::set_time_limit_token), so a step that would run past the limit stops within a poll and is
/// discarded; the loop then ends as at a step boundary.
class TimeLimitWatch {
public:
    explicit TimeLimitWatch(double seconds);
    ~TimeLimitWatch();
    TimeLimitWatch(const TimeLimitWatch&) = delete;
    TimeLimitWatch& operator=(const TimeLimitWatch&) = delete;
    const CancelToken& token() const { return m_token; }
    /// True once the limit has passed (the token is cancelled).
    bool passed() const { return m_token.cancelled(); }
    /// Moves the limit to `seconds` after construction (a loop excludes the time spent in checkpoint callbacks).
    void set_limit(double seconds);

private:
    CancelToken m_token;
    std::mutex m_mutex;
    std::condition_variable m_cv;
    double m_seconds = 0;
    bool m_done = false;
    std::thread m_thread;
};

}  // namespace kelvin::fluid
