#pragma once
// MCFluid in 3D: the cached Feynman–Kac Navier–Stokes solver of thesis Sections 5.3.2–5.3.4. Separate from the 2D
// solver (mcfluid.h) where the mathematics is: a vector vorticity carried with the stretching term, control variates
// over consecutive caches and smoke; the settings (SolverSettings<D>), the driver and the outputs are shared.
//
//     omega(t_i, x) = 1/n_d sum_j [ omega(t_{i-1}, x_j) + dt <(omega . grad) v>(t_{i-1}, x_j) ]          (Eq. 5.22)
//     x_j ~ N(x_a, 2 nu dt I),   x_a = backtrace of x over dt through the Monte Carlo velocity <v>
//     (omega . grad) v (x) ~ |omega| / h [ v(x + h/2 w) - v(x - h/2 w) ],  w = omega / |omega|          (Eq. 5.21)
//
// The cache holds omega(t_{i-1}) at the cell centres; the velocity at the cell centres is a Biot–Savart Monte
// Carlo estimate from that cache (biot_savart3.h), stored as a second grid: it is the backtrace's first stage
// and, interpolated, the velocity of the stretching segments (Sec. 5.3.3: "we fetch the cached velocities").
// RK4's later stages are Monte Carlo estimates at their own points. h is the smallest cell size.
//
// Effects on demand: nu = 0 draws no Gaussian displacement (n_d is then 1); without control variates no
// previous field is kept; `stretching` can be switched off only to study it (the physics needs it in 3D).
//
// Control variates (Eq. 5.23, Sec. 5.3.4): v(t) = BS[omega(t) - omega(t - dt)] + v(t - dt): the Monte Carlo
// samples go to the difference of two consecutive caches (importance-sampled by its magnitude) and the previous
// step's velocity is added (the cached value at cell centres, its interpolation at RK4 stage points). The
// initial velocity is estimated once with `initial_samples`.
//
// Determinism: a pass is split into z-slabs of cells (one unit per z index); unit k of pass p at step s draws
// from Random(seed, hash(hash(s, p), k)). Results are bit-identical whatever the thread count, and whatever the
// number of ranks of a distributed run (set_communicator): each rank runs a contiguous range of z indices of every
// pass, and the ranks exchange their cells (allgather) before the next pass reads the grids.
#include <kelvin/core/random.h>
#include <kelvin/fluid/biot_savart3.h>
#include <kelvin/fluid/energy_budget.h>
#include <kelvin/fluid/grid3.h>
#include <kelvin/fluid/mcfluid.h>
#include <kelvin/wos/wos.h>

#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

namespace kelvin::fluid {

struct WosVelocityOptions;  // boundary.h
class WosVelocityField3;

/// omega(0, x) in 3D.
using InitialField3 = std::function<Vec3d(const Vec3d&)>;

struct MCFluid3Settings : SolverSettings<3> {
    int nx = 32, ny = 32, nz = 32;  ///< cache cells
    bool stretching = true;
    /// The previous step as control variate (Eq. 5.23): a second field of the estimator is built over the difference
    /// of two consecutive caches (VelocityState3::difference).
    bool control_variates = false;
    int initial_samples = 0;  ///< samples of the first velocity pass (0: `samples`)
    /// beta of the blended control variate: v = beta (v_prev + BS[omega - omega_prev]) + (1 - beta) BS[omega] with
    /// n_mc samples for each part when beta < 1 (the general control-variate form of thesis Sec. 6.2.1); 1 is Eq.
    /// 5.23, whose error is carried from step to step and accumulates, where with beta < 1 it decays as beta^k.
    double control_variate_blend = 1;
    /// Where each velocity pass spends its samples. Uniform: n_mc at every cell. Vorticity: the same total, each
    /// cell's share proportional to the largest |omega| over it and its 26 neighbours (the cells whose next value
    /// its velocity moves: the backtrace error multiplies grad omega, the stretching's omega grad u), between
    /// n_mc / AllocationFloor and AllocationCap n_mc (the total is less when the cap binds). Cells far from any
    /// vorticity, whose velocity changes nothing in the next state, get the fewest.
    bool vorticity_allocation = false;
    static constexpr int AllocationFloor = 8, AllocationCap = 32;
    /// Standard deviation, in cells, of the Gaussian that smooths the cached velocity the stretching segments read
    /// (0: the cache as estimated, the thesis' scheme). Each cell's estimate carries independent Monte Carlo noise,
    /// which the segment's difference over one cell divides by h, and which the stretching turns into energy; the
    /// velocity varies on the flow's scales, not the cell's, but a thin core's own stretching is smoothed too.
    /// AutoFilter (the default): DefaultStretchingFilter when the backtrace reads the cache, 0 with fresh estimates.
    double stretching_filter = AutoFilter;
    static constexpr double MaxStretchingFilter = 8, DefaultStretchingFilter = 0.75;
    /// What the backtrace's Runge–Kutta stages read (BacktraceVelocity, mcfluid.h). Estimates: a fresh Monte Carlo
    /// estimate at every stage point, the thesis' scheme. Cache: the state's cell estimates, extrapolated to mid-step
    /// (velocity_time) and smoothed by a Gaussian of `velocity_filter` cells (0: none), read by the monotone tricubic
    /// interpolant (the first stage at the cell's own centre); no estimate beyond the velocity pass. Auto (the
    /// default) is Cache without boundaries and Estimates with them, as in 2D (a stage estimate sees a solid thinner
    /// than a cell; the cache does not). settings() holds the resolved choices, the stretching filter's too.
    BacktraceVelocity backtrace_velocity = BacktraceVelocity::Auto;
    double velocity_filter = 1.0;
    /// The kernel of both smoothings (grid.h). Twicing here, where 2D's default is the Gaussian: a 3D ring's core is
    /// a few cells wide, and the Gaussian's second-order bias slows it (two cells per core radius: 0.945 of the
    /// exact distance over t = 0.4 with the Gaussian of one cell, 0.977 with these defaults; docs/fluid.md).
    FilterKernel filter_kernel = FilterKernel::Twicing;
};

/// Cumulative work of the 3D solver, per effect. In a distributed run the counters are the whole run's (summed over
/// the ranks); the seconds are this rank's own, with the time spent exchanging cells.
struct FluidWork3 {
    uint64_t biot_savart_evals = 0;
    uint64_t velocity_queries = 0;
    uint64_t advection_backtraces = 0;
    uint64_t diffusion_samples = 0;        ///< Gaussian displacements (0 when inviscid)
    uint64_t stretching_evals = 0;         ///< vortex-segment stretching estimates (Eq. 5.21)
    uint64_t control_variate_queries = 0;  ///< velocity estimates that used the previous step as control variate
    uint64_t smoke_lookups = 0;            ///< smoke density values read (0 without smoke)
    uint64_t wos_walks = 0;                ///< Walk-on-Spheres walks (boundaries only)
    uint64_t wos_steps = 0;                ///< spheres crossed by those walks
    uint64_t wos_truncated = 0;            ///< walks that hit max_steps (ended at the nearest boundary, counted)
    uint64_t wos_invalid = 0;              ///< walks with a non-finite distance or value (counted as zero)
    uint64_t wos_boundary_queries = 0;     ///< velocity queries within epsilon of a boundary (moved to the shell)
    uint64_t distance_queries = 0;         ///< stretching-segment distance queries (boundaries only)
    uint64_t solid_cells = 0;              ///< cells inside solids (their vorticity and velocity are zero)
    uint64_t solid_departures = 0;         ///< backtraces that ended inside a solid and were moved to its surface
    uint64_t invalid_velocity = 0;
    uint64_t invalid_vorticity = 0;
    double seconds_velocity = 0;
    double seconds_advection = 0;  ///< backtraces (incl. RK stages), diffusion, stretching, interpolation
    double seconds_energy = 0;     ///< the paired energy's passes (energy_passes)
};

/// Integral diagnostics of a 3D state (midpoint rule over the cells).
struct FluidDiagnostics3 {
    long long step = 0;
    double time = 0;
    double kinetic_energy = 0;      ///< 1/2 int |u|^2 minus the estimated Monte Carlo noise energy
    double kinetic_energy_raw = 0;  ///< 1/2 int |u_hat|^2
    double enstrophy = 0;           ///< 1/2 int |omega|^2
    double helicity = 0;            ///< int u . omega
    Vec3d impulse{0.0};             ///< 1/2 int x cross omega
    Vec3d centroid{0.0};            ///< int |omega| x / int |omega| (the domain's centre for an empty field)
    /// int x w / int w with w = (x cross omega) . I / |I|, I the impulse: Saffman's impulse centroid of a ring (its
    /// signed weights let noise cancel); the |omega| centroid where there is no impulse
    Vec3d impulse_centroid{0.0};
    double max_abs_vorticity = 0;
    double divergence_rms = 0;  ///< RMS of div u by central differences of the cached velocity (interior cells)
    double smoke_mass = 0;      ///< integral of the smoke density (0 without smoke)
};

/// Smoke: a passive density carried along the solver's backtraces (no diffusion), set to `initial` inside a
/// sphere at t = 0 and fed at `rate` per unit time inside it.
struct Smoke3 {
    Vec3d center{0.0};
    double radius = 0.25;
    double initial = 1;
    double rate = 0;
};

/// The 3D solver. Cancellable (core/interrupt.h): step() and the velocity pass poll the token set with
/// set_cancel_token() (or a process-wide interrupt, or the time limit's token) once per cell, and the estimators
/// within their sample loops.
class MCFluid3Solver : public Cancellable {
public:
    MCFluid3Solver(const MCFluid3Settings& settings, const InitialField3& initial);
    ~MCFluid3Solver();

    const MCFluid3Settings& settings() const { return m_settings; }
    double delta() const { return m_delta; }
    /// Whether steps read the velocity at mid-step (velocity_time resolved).
    bool midstep() const { return m_midstep; }
    double time() const { return m_time; }
    long long step_index() const { return m_step; }
    /// Length of the stretching segments away from boundaries (the smallest cell size h); near a boundary a
    /// segment at x is min(h, 2 distance(x)) long (Sec. 5.3.3), so both ends stay in the fluid.
    double segment_length() const { return m_segment; }
    /// The boundaries of the current state (null without boundaries).
    const WosVelocityField3* boundary_field() const { return m_wos; }

    /// One step of length dt; false (state unchanged) when the cancel token or a process-wide interrupt stopped it.
    bool step(double dt);
    bool step() { return step(m_settings.dt); }

    const VectorGrid3& vorticity_grid() const { return m_omega; }
    /// Velocity at the cell centres of the current state (estimated on first use) and its variance.
    const VectorGrid3& velocity_grid();
    const VectorGrid3& velocity_variance();
    /// False when a stop (cancel token or interrupt) cut the velocity pass short (the grids then hold zeros).
    bool velocity_available();
    FluidDiagnostics3 diagnostics() { return diagnostics(true); }
    /// Without the velocity (`with_velocity` false: no velocity pass runs), the energies, helicity and divergence are
    /// NaN.
    FluidDiagnostics3 diagnostics(bool with_velocity);

    // ----- pointwise queries of the current state (hosts, docs/host-api.md).
    /// omega at x: the cache interpolated as the solver interpolates it (trilinear or nearest).
    Vec3d vorticity_at(Vec3d x) const { return m_omega.sample(x, m_settings.interpolation); }
    /// The velocity at x: a fresh Monte Carlo estimate with the solver's n_mc samples (Biot–Savart, or
    /// Walk-on-Spheres with boundaries; without control variates), on a random stream fixed by (seed, step, x),
    /// so the same query gives the same answer.
    Vec3d velocity_at(Vec3d x) const;

    /// A Monte Carlo estimate of the current state's velocity at x with n samples (without control variates):
    /// Biot–Savart, or Walk-on-Spheres with boundaries (then the walks count into `walks`).
    VelocityEstimate3 velocity_estimate(Vec3d x, int n, Random& rng) const;
    VelocityEstimate3 velocity_estimate(Vec3d x, int n, Random& rng, wos::WalkCounters& walks) const;

    const FluidWork3& work() const { return m_work; }

    /// The ranks the passes are spread over (core/distributed.h); null (the default): this process alone. As for
    /// MCFluidSolver::set_communicator: every rank makes the same calls in the same order, each pass is a
    /// collective, and every rank then holds the whole state (vorticity, velocity, smoke) of a single process.
    void set_communicator(Communicator* comm);

    /// Adds smoke (before the first step). Without it no scalar is advected.
    void set_smoke(const Smoke3& smoke);
    /// The smoke density at the cell centres (null without smoke).
    const Grid3* smoke() const { return m_smoke ? &m_density : nullptr; }

    /// The energy budget (energy_budget.h, "In 3D"): when on, every step also measures where its energy went (five
    /// deterministic re-runs of the step and their FFT energies; no random draws, so the simulation is unchanged).
    /// Inviscid runs without boundaries only (RuntimeError otherwise).
    void set_energy_budget(bool on);
    /// The last step's budget and the sum over the steps so far (null when the budget is off).
    const EnergyBudget* energy_budget_step() const { return m_flow ? &m_budget_step : nullptr; }
    const EnergyBudget* energy_budget_total() const { return m_flow ? &m_budget_total : nullptr; }

    /// The state's energy from independent velocity passes (energy_budget.h, PairedEnergy): `passes` (0: off, or 2
    /// and more; 3 and more for an error bar) fresh fields and direct cell passes (settings().samples each) per
    /// measured state, on streams of their own (the run's draws are unchanged). Any boundaries.
    void set_energy_passes(int passes);
    int energy_passes() const { return m_energy_passes; }
    /// The current state's paired energy (measured on first use per state; empty when off or stopped).
    PairedEnergy paired_energy();

    enum StreamTag : uint64_t { TagVelocity = 1, TagAdvection = 2, TagQuery = 3, TagField = 5, TagEnergy = 6 };
    struct SlabWork;  ///< the work of one z-slab of a pass (defined in mcfluid3.cpp)

private:
    bool ensure_velocity();
    /// The estimator's input for the current state, its draws on `stream`.
    VelocityState3 velocity_state(uint64_t stream) const;
    /// Counts the walks of `field`'s harmonic cache (if it has boundaries) in the work counters.
    void add_cache_walks(const VelocityField3& field);
    /// The velocity of the current state at x with n samples: through the control variate when one is kept
    /// (`previous` is then the previous velocity at x), Biot–Savart or Walk-on-Spheres.
    VelocityEstimate3 estimate_at(Vec3d x, int n, Random& rng, SlabWork& w) const;
    Vec3d stage_velocity(Vec3d x, int n, Random& rng, SlabWork& w) const;
    /// The samples of each cell's velocity estimates in this state's passes (vorticity_allocation), for a pass of n
    /// samples per cell on average; empty when uniform.
    void allocate_samples(int n);
    /// With control variates and control_variate_blend beta < 1: e (the control-variate estimate at x) becomes
    /// beta e + (1 - beta) x a direct estimate with n samples, variances combined likewise.
    void blend_direct(Vec3d x, int n, Random& rng, SlabWork& w, VelocityEstimate3& e) const;
    void rebuild_estimators();
    // The energy budget (energy_budget3.cpp).
    /// omega at the cells after a step of dt through the deterministic velocity u at the cell centres (read between
    /// them by the cubic interpolant), the backtrace in `substeps` steps of the scene's integrator, then stretched
    /// into `as_run` as the run stretches (the vortex segment on u read with the cache's interpolation) and into
    /// `exact` exactly for the frozen u (either may be null; without `stretching` neither is stretched). With `last`,
    /// u is extrapolated as the run extrapolates it (velocity_time): u + f (u - last), the difference read
    /// trilinearly. With `stretch`, the as-run stretching reads it instead of u (the cached backtrace: u is then the
    /// smoothed, extrapolated velocity the stages read, `stretch` the cell velocity).
    void budget_step(const VectorGrid3& u, double dt, int substeps, VectorGrid3* as_run, VectorGrid3* exact,
                     const VectorGrid3* last = nullptr, double f = 0, const VectorGrid3* stretch = nullptr) const;
    /// The step's budget (m_budget_step); false when a stop came between its passes (the step is then discarded).
    bool measure_budget(double dt);
    /// MacCormack's correction of m_next (VorticityTransport::MacCormack): the advected values m_advected traced
    /// forward through the cached velocity, half the difference to the old state added back where it stays within
    /// the cells around the departure point; false when stopped.
    bool maccormack_correction(double dt);

    MCFluid3Settings m_settings;
    Communicator* m_comm;  ///< never null (the local communicator by default)
    double m_delta = 0, m_segment = 0;
    VectorGrid3 m_vel_stretch;    ///< the velocity the stretching reads (m_vel smoothed by stretching_filter)
    VectorGrid3 m_vel_backtrace;  ///< backtrace_velocity cache: the velocity the stages read (smoothed m_vel)
    std::vector<char> m_fluid;    ///< with walls and stretching_filter: cells whose centre is in the fluid
    /// The velocity the stretching segments read: `u` itself, or smoothed into `into` (stretching_filter).
    const VectorGrid3& stretching_velocity(const VectorGrid3& u, VectorGrid3& into) const;
    /// What the cached backtrace's stages read (backtrace_velocity cache): u + f (u - last) (without `last`, u),
    /// smoothed by velocity_filter, into `into`.
    void cached_backtrace_velocity(const VectorGrid3& u, const VectorGrid3* last, double f, VectorGrid3& into) const;
    double m_time = 0;
    long long m_step = 0;
    VectorGrid3 m_omega, m_next;
    std::vector<int> m_alloc;        ///< vorticity_allocation: each cell's samples in this state's passes
    int m_alloc_n = 0;               ///< the mean samples per cell m_alloc was made for
    VectorGrid3 m_advected;          ///< MacCormack: each cell's looked-up value before diffusion and stretching
    std::vector<Vec3d> m_departure;  ///< MacCormack: each cell's departure point (wrapped)
    VectorGrid3 m_vel, m_var;
    bool m_velocity_valid = false;
    std::shared_ptr<const PeriodicKernel3> m_periodic;
    std::unique_ptr<VelocityField3> m_field;  ///< the state's velocity (settings().estimator)
    // Control variates: the previous state's vorticity and velocity, and the field over the difference.
    VectorGrid3 m_prev_omega, m_prev_vel, m_prev_var, m_diff;
    /// The last state's velocity (and, with the energy budget, vorticity): the mid-step velocity's extrapolation.
    VectorGrid3 m_last_vel, m_last_omega;
    bool m_have_last = false;
    bool m_midstep = false;
    double m_last_dt = 0;     ///< the step that led from the last state to the current one
    double m_mid_factor = 0;  ///< the current step's dt / (2 m_last_dt), 0 without a last state
    /// (u_n - u_{n-1}) dt_n / (2 dt_{n-1}) at x: what the mid-step velocity adds to the velocity at the step's start
    /// (zero without a last state).
    Vec3d midstep_correction(const Vec3d& x) const;
    bool m_have_prev = false;
    std::unique_ptr<VelocityField3> m_diff_field;
    /// Boundaries: m_field->boundaries(), the free-slip field of the state (null without boundaries).
    const WosVelocityField3* m_wos = nullptr;
    std::vector<uint8_t> m_solid;  ///< cells inside a solid (static: computed once)
    FluidWork3 m_work;
    std::unique_ptr<Smoke3> m_smoke;
    Grid3 m_density, m_density_next;
    std::unique_ptr<FlowFFT3> m_flow;  ///< the energy budget's FFTs (null: no budget)
    EnergyBudget m_budget_step, m_budget_total;
    int m_energy_passes = 0;
    PairedEnergy m_paired;  ///< of step m_paired_step
    long long m_paired_step = -1;
};

}  // namespace kelvin::fluid
