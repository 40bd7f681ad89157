#pragma once
// MCFluid in 2D: the practical single-grid cached solver of thesis Section 5.3.3 and the recursive,
// cache-free estimator of Algorithm C.1 (Appendix C). Both evaluate the same semi-discrete scheme
//
//     omega(t_i, x) = 1/n_d sum_j omega(t_{i-1}, x_a + sqrt(2 nu dt) xi_j),   xi_j ~ N(0, I)     (Eq. 5.22)
//     x_a = backtrace of x over dt through the Biot–Savart Monte Carlo velocity  (Eqs. 5.3, 5.5, 3.139–3.144)
//
// (2D: no stretching term). The cached solver stores omega(t_{i-1}) at cell centres and draws the
// Biot–Savart samples from that cache; the recursive estimator evaluates omega(t_{i-1}, y) at every sample
// by recursion down to the initial condition (exponential cost: short horizons, validation, pointwise
// queries).
//
// Determinism: a step is split into rows of cells; row r of pass p at step s draws from
// Random(seed, hash(hash(s, p), r)). Results are bit-identical whatever the thread count, and whatever the number of
// ranks of a distributed run (set_communicator): each rank runs a contiguous slab of rows of every pass, and the
// ranks exchange their slabs (allgather) before the next pass reads the grids.
#include <kelvin/core/random.h>
#include <kelvin/fluid/biot_savart.h>
#include <kelvin/fluid/dye.h>
#include <kelvin/fluid/energy_budget.h>
#include <kelvin/fluid/grid.h>
#include <kelvin/fluid/solver.h>
#include <kelvin/fluid/velocity.h>
#include <kelvin/wos/wos.h>

#include <atomic>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <optional>

namespace kelvin {
class Communicator;  // core/distributed.h
}

namespace kelvin::fluid {

struct WosVelocityOptions;  // boundary.h
class WosVelocityField;

enum class Advection { Euler, RK4 };
const char* to_string(Advection a);

/// How a backtrace reads the previous state at its departure point (the scene's `transport`). Linear: the cache's
/// bi/trilinear interpolant (the thesis' Section 5.3.3 scheme; like every semi-Lagrangian method on a linear
/// interpolant it diffuses: each step averages neighbouring cells, and over a few hundred steps a vortex loses a
/// quarter to a half of its energy). Cubic: the monotone cubic interpolant (Grid2::sample_cubic, Grid3::cubic_stencil)
/// — third order, clamped so it makes no new extrema. MacCormack: the cubic lookup plus the error-compensating
/// correction of Selle et al. (2008): the step's result is traced forward again through the (cached) velocity,
/// half the difference to the previous state is added back, and the result is clamped to the range of the cells around
/// the departure point (reverting to the plain lookup where the clamp bites); it cancels the lookup's leading error
/// term, for one more lookup and a forward trace through the cached cell-centre velocity (no new Monte Carlo
/// queries). With viscosity the correction is of the advection only (the diffusion is not undone); in 3D it corrects
/// the lookup before the stretching, per component (the stretching of the step is kept), and smoke is carried by the
/// cubic lookup. The 2D energy budget models the correction (each re-run applies it), the 3D one does not (refused).
/// The Biot–Savart source stays the cache's `interpolation` in every case.
enum class VorticityTransport { Linear, Cubic, MacCormack };
const char* to_string(VorticityTransport t);

/// omega(0, x).
using InitialField = std::function<double(const Vec2d&)>;

/// The velocity a step's backtrace reads (the scene's `velocity_time`). Midstep: extrapolated from the last two
/// states' velocities (u_n + (u_n - u_{n-1}) dt_n / (2 dt_{n-1}) added to every velocity the backtrace reads, second
/// order in dt: Adams–Bashforth's extrapolation; the first step, without a previous state, keeps u_n). Start: frozen
/// at the step's start (the thesis' scheme, first order: a translating vortex pair drifts apart and gains energy, a
/// ring's impulse grows and its speed falls, in proportion to dt). Auto: midstep for the Biot–Savart velocity, start
/// with walls (Walk-on-Spheres' noise at the usual walk counts exceeds a step's change of velocity, and the
/// extrapolation adds half of two passes' noise: docs/fluid.md).
enum class VelocityTime { Auto, Midstep, Start };
const char* to_string(VelocityTime t);
/// The mid-step extrapolation's factor f in u_n + f (u_n - u_{n-1}) for a step of dt after one of last_dt: dt / (2
/// last_dt); 0 (the velocity at the step's start) without a last state, or after a step less than half as long as
/// this one (a shortened step, say one that landed on a queried time): the difference of the two velocities is then
/// mostly their Monte Carlo noise, which f would multiply (dt / last_dt = 10^5 after a step of 10^-6: departure points
/// thrown across the domain).
inline double midstep_factor(bool have_last, double dt, double last_dt) {
    if (!have_last || !(last_dt > 0) || dt > 2 * last_dt) return 0.0;
    return 0.5 * dt / last_dt;
}

/// What the 2D and 3D MCFluid solvers are configured with alike (MCFluidSettings, MCFluid3Settings add the cache's
/// resolution and, in 3D, what only 3D has: stretching and control variates).
template <int D>
struct SolverSettings {
    Domain<D> domain;
    Interpolation interpolation = Interpolation::Bilinear;  ///< Bilinear means trilinear in 3D
    Advection advection = Advection::RK4;
    VorticityTransport transport = VorticityTransport::Cubic;
    double dt = 0.05;
    double viscosity = 0;       ///< nu; 0 = inviscid: the diffusion step never runs
    int diffusion_samples = 1;  ///< n_d (used only when viscosity > 0)
    uint64_t seed = 0;
    /// Solid boundaries (walk_on_spheres, boundary.h): the velocity is the free-slip Walk-on-Spheres estimate (2D: on
    /// the stream function; 3D: on the vector potential) with `samples` gradient samples. Null: Biot–Savart, and no
    /// distance query or walk ever runs. With an `estimator`, its boundaries() (when these are null).
    std::shared_ptr<const WosVelocityOptions> boundaries;
    /// The velocity estimator (velocity.h; a <velocity> plugin that supports dimension D): the one owner of the
    /// mollifier delta (its delta(); negative: half a cell, in 3D half the smallest cell side), of its sampling
    /// options and of the scene's sample count. Null: WosVelocity over `boundaries`, else BiotSavartVelocity with its
    /// defaults. The solver asks it for the field of each state and queries that field with `samples` samples.
    std::shared_ptr<const VelocityEstimator> estimator;
    /// n_mc, the samples per velocity query of this run (a run's --spp: run_samples); 0: the estimator's samples().
    /// The solver's settings() hold the value in use.
    int samples = 0;
    VelocityTime velocity_time = VelocityTime::Auto;
};

/// What a 2D backtrace's Runge–Kutta stages read (the scene's `backtrace_velocity`). Estimates: the first stage the
/// cached cell-centre estimate, every later stage a fresh Monte Carlo estimate at its own point (the thesis' scheme:
/// each stage's noise is independent, and RK4 costs four estimates per cell and step). Cache: every stage reads the
/// state's cached cell-centre velocity, smoothed by a Gaussian of `velocity_filter` cells (renormalised over fluid
/// cells) and read between the centres by the monotone cubic interpolant (open boxes: the nearest centre's value
/// beyond the outer centres; solid cells next to fluid take their fluid neighbours' mean): one estimate per cell and
/// step, and the cells' independent noise averaged over the filter's width. The velocity is smooth (one derivative
/// smoother than the vorticity), its noise is not: the filter's bias is (sigma h)^2 / 2 times the velocity's
/// Laplacian, falling with h at a fixed width in cells; where the vorticity is zero the velocity is harmonic and a
/// radially symmetric filter leaves it unchanged. Auto (the default): Cache without boundaries, Estimates with them
/// (Walk-on-Spheres estimates at the stage points see solids thinner than a cell, which the cell grid does not);
/// the solver's settings() hold the resolved choice.
enum class BacktraceVelocity { Auto, Estimates, Cache };
const char* to_string(BacktraceVelocity b);

struct MCFluidSettings : SolverSettings<2> {
    int nx = 64, ny = 64;  ///< cache cells
    BacktraceVelocity backtrace_velocity = BacktraceVelocity::Auto;
    double velocity_filter = 1.0;  ///< Cache: the Gaussian's standard deviation in cells (0: no filter)
    FilterKernel filter_kernel = FilterKernel::Gaussian;  ///< Cache: the smoothing's kernel (grid.h)
};
/// The widest velocity filter accepted, in cells.
constexpr double MaxVelocityFilter = 8.0;
/// 3D's `stretching_filter` left to the solver (the parameter's default; MCFluid3Settings).
constexpr double AutoFilter = -1.0;

/// Cumulative work of a solver (each component counts its own). In a distributed run the counters are the whole
/// run's (summed over the ranks: the same as one process's); the seconds are this rank's own (its passes, with the
/// time spent exchanging slabs).
struct FluidWork {
    uint64_t biot_savart_evals = 0;      ///< kernel evaluations (samples)
    uint64_t velocity_queries = 0;       ///< Biot–Savart estimates
    uint64_t advection_backtraces = 0;   ///< departure points traced
    uint64_t diffusion_samples = 0;      ///< Gaussian displacements (Feynman–Kac diffusion)
    uint64_t invalid_velocity = 0;       ///< non-finite velocity estimates (replaced by zero velocity)
    uint64_t invalid_vorticity = 0;      ///< non-finite vorticity values (replaced by zero)
    uint64_t wos_walks = 0;              ///< Walk-on-Spheres walks (boundaries only)
    uint64_t wos_steps = 0;              ///< spheres crossed by those walks
    uint64_t wos_truncated = 0;          ///< walks that hit max_steps (ended at the nearest boundary, counted)
    uint64_t wos_invalid = 0;            ///< walks with a non-finite distance or value (counted as zero)
    uint64_t wos_boundary_queries = 0;   ///< velocity queries within epsilon of a boundary (moved to the shell)
    uint64_t solid_departures = 0;       ///< departure points inside a solid, moved to its surface
    uint64_t solid_cells = 0;            ///< cache cells inside solids at the current state
    uint64_t velocity_fields_built = 0;  ///< Biot–Savart tables or free-slip fields built (one per state)
    double seconds_velocity = 0;         ///< cell-centre velocity passes
    double seconds_advection = 0;        ///< backtrace (incl. RK stages) + diffusion + interpolation passes
    double seconds_energy = 0;           ///< the paired energy's passes (energy_passes)
};

/// The practical cached solver (Section 5.3.3). A FluidSolver (solver.h): the run loop and hosts step it through
/// that interface; the rest of its API (variances, the velocity field, work counters) is its own.
class MCFluidSolver final : public FluidSolver {
public:
    /// Initialises the cache with `initial` at the cell centres (non-finite values count as invalid and
    /// are stored as zero). Throws RuntimeError on settings the caller should have validated.
    MCFluidSolver(const MCFluidSettings& settings, const InitialField& initial);
    ~MCFluidSolver() override;

    const MCFluidSettings& settings() const { return m_settings; }
    /// The mollifier actually used (the estimator's delta(), or half a cell when that is negative).
    double delta() const { return m_delta; }
    /// Whether steps read the velocity at mid-step (velocity_time resolved).
    bool midstep() const { return m_midstep; }
    double time() const override { return m_time; }
    long long step_index() const override { return m_step; }

    /// One step of length dt (> 0; the last step of a run may be shorter than settings().dt). Returns false
    /// (and keeps the previous state) when the cancel token or a process-wide interrupt stopped it.
    bool step(double dt) override;
    bool step() { return step(m_settings.dt); }
    /// Steps until time() == t (the last step shortened to land on t). False if stopped.
    bool advance_to(double t);

    /// The cache: omega at cell centres of the current state.
    const Grid2& vorticity_grid() const { return m_omega; }
    const Grid2& vorticity_grid() override { return m_omega; }
    /// Velocity at the cell centres of the current state (estimated on first use with the step's own
    /// random streams, so asking for it never changes the simulation) and the variance of each estimate.
    const Grid2& velocity_u() override;
    const Grid2& velocity_v() override;
    const Grid2& velocity_variance_u();
    const Grid2& velocity_variance_v();
    /// Estimates the current state's velocity if not done yet; false when a stop (cancel token or interrupt)
    /// cut the pass short (velocity_u() and the others then hold zeros, and the next call estimates again).
    /// Every pass polls once per cell.
    bool velocity_available();
    /// Energy and the other diagnostics of the current state (zero velocity when velocity_available() is
    /// false). Without `with_velocity` no velocity pass is run and the energies are NaN (not estimated).
    FluidDiagnostics diagnostics(bool with_velocity);
    FluidDiagnostics diagnostics() override { return diagnostics(true); }

    // ----- pointwise API (the cached solver keeps the current state only: t >= time()).
    /// omega(t, x): advances to t, then interpolates the cache.
    double vorticity(double t, Vec2d x);
    /// v(t, x): advances to t, then a Biot–Savart estimate from the cache with n_mc samples on a stream
    /// derived from (seed, step, x), so the same query gives the same answer.
    Vec2d velocity(double t, Vec2d x);
    /// vorticity(time(), x) and velocity(time(), x): the FluidSolver queries.
    double vorticity_at(Vec2d x) override { return m_omega.sample(x, m_settings.interpolation); }
    Vec2d velocity_at(Vec2d x) override { return velocity(m_time, x); }
    /// A Biot–Savart estimate (Walk-on-Spheres with boundaries) of the current state's velocity at x with n
    /// samples from `rng`.
    VelocityEstimate velocity_estimate(Vec2d x, int n, Random& rng) const;
    /// The boundaries placed at the current state (null without boundaries).
    const WosVelocityField* boundary_field() const { return m_wos; }
    /// The velocity field of the current state (built by settings().estimator).
    const VelocityField2& velocity_field() const { return *m_field; }

    const FluidWork& work() const { return m_work; }
    /// The periodic kernel table (null unless the domain is periodic without solid boundaries).
    const PeriodicKernel* periodic_kernel() const { return m_periodic.get(); }

    /// The ranks the passes are spread over (core/distributed.h); null (the default): this process alone. Every
    /// rank then makes the same calls (steps, velocity passes, diagnostics) in the same order: each pass is a
    /// collective, after which every rank holds the whole state, bit-identical to a single process's. A stop on
    /// any rank stops the pass on every rank. `comm` must outlive the solver.
    void set_communicator(Communicator* comm);

    /// Passive scalars (dye) carried along the same backtraces as the vorticity (the dye moves with exactly
    /// the flow the solver computes). Null (the default): no dye, and no dye work.
    void set_dye(std::unique_ptr<PassiveScalars> dye);
    PassiveScalars* dye() const { return m_dye.get(); }
    PassiveScalars* dye() override { return m_dye.get(); }

    /// FluidSolver's counters: kernel evaluations, non-finite values, and the work counters into `stats`.
    double evaluations() const override { return double(m_work.biot_savart_evals); }
    uint64_t invalid() const override { return m_work.invalid_velocity + m_work.invalid_vorticity; }
    void report(Stats& stats) const override;

    /// The energy budget (energy_budget.h): when on, every step also measures where its energy went (five
    /// deterministic re-runs of the step, six with walls, and the states' energies and velocities by FFT or, with
    /// walls, Poisson solves; no random draws, so the simulation is unchanged). Inviscid runs only; with walls, static
    /// boundaries the grid represents (check_wall_budget; RuntimeError otherwise).
    void set_energy_budget(bool on);
    /// The last step's budget and the sum over the steps so far (null when the budget is off).
    const EnergyBudget* energy_budget_step() const { return budget_on() ? &m_budget_step : nullptr; }
    const EnergyBudget* energy_budget_total() const { return budget_on() ? &m_budget_total : nullptr; }
    /// Whether the budget measures a boundary term (the budget on, with walls).
    bool energy_budget_has_boundary() const { return bool(m_wall_flow); }

    /// The state's energy from independent velocity passes (energy_budget.h, PairedEnergy): `passes` (0: off, or 2
    /// and more; 3 and more for an error bar) fresh fields and cell passes per measured state, on streams of their
    /// own (the run's draws are unchanged).
    void set_energy_passes(int passes);
    int energy_passes() const { return m_energy_passes; }
    /// The current state's paired energy (measured on first use per state; an empty PairedEnergy when the passes
    /// are off or a stop cut them short).
    PairedEnergy paired_energy();

    /// Stream tags of the passes (part of the determinism contract; tests use them).
    enum StreamTag : uint64_t {
        TagVelocity = 1,
        TagAdvection = 2,
        TagQuery = 3,
        TagDye = 4,
        TagField = 5,
        TagEnergy = 6
    };

private:
    void rebuild_estimator();
    bool ensure_velocity();
    /// The estimator's input for the current state, its draws on `stream`.
    VelocityState2 velocity_state(uint64_t stream) const;
    /// One estimate of `field`'s velocity per cell centre (settings().samples each), row j's draws on stream(j);
    /// false (and zeros) when stopped.
    bool cell_pass(const VelocityField2& field, const std::function<uint64_t(std::size_t)>& stream, Grid2& u, Grid2& v,
                   Grid2* var_u, Grid2* var_v);
    Vec2d checked_velocity(Vec2d x, Random& rng, uint64_t& evals, uint64_t& queries, uint64_t& invalid,
                           wos::WalkCounters& walks) const;
    VelocityEstimate estimate_at(Vec2d x, int n, Random& rng, wos::WalkCounters& walks) const;
    void add_walks(const wos::WalkCounters& c);
    /// omega at the cells after a step of dt through the deterministic velocity (u, v) at the cell centres (read
    /// between them by the cubic interpolant), the backtrace in `substeps` steps of the scene's integrator.
    /// With walls the departure points are pushed out of the solids as the run's are; `source` is the state read
    /// (null: the current one).
    void transport_through(const Grid2& u, const Grid2& v, double dt, int substeps, Grid2& out,
                           const Grid2* source = nullptr) const;
    /// The current state with the solid cells within two cells of the fluid filled by their fluid neighbours' mean.
    Grid2 extended_into_solids() const;
    void measure_budget(double dt);
    /// MacCormack's correction of m_next (see VorticityTransport); false when stopped.
    bool maccormack_correction(double dt);
    /// (u, v) as the backtrace reads them with BacktraceVelocity::Cache: filtered, solid cells next to fluid
    /// extrapolated (uses m_fluid).
    void backtrace_grids(const Grid2& u, const Grid2& v, Grid2& bu, Grid2& bv) const;
    /// The backtrace's velocity at p from those grids (open boxes: p clamped to the outer cell centres).
    Vec2d cached_velocity(const Grid2& bu, const Grid2& bv, Vec2d p) const;
    /// u + f (u - last), cell by cell (the mid-step extrapolation with f = m_mid_factor).
    static Grid2 extrapolated(const Grid2& u, const Grid2& last, double f);
    /// The mid-step correction m_mid_factor (u_n - u_{n-1}) at p, the cached velocities read by the bilinear
    /// interpolant (zero on the first step or with velocity_time start).
    Vec2d midstep_correction(Vec2d p) const;

    MCFluidSettings m_settings;
    Communicator* m_comm;  ///< never null (the local communicator by default)
    double m_delta = 0;
    double m_time = 0;
    long long m_step = 0;
    Grid2 m_omega, m_next;
    Grid2 m_u, m_v, m_var_u, m_var_v;
    Grid2 m_bu, m_bv;          ///< BacktraceVelocity::Cache: the velocity the backtraces read
    bool m_midstep = false;    ///< velocity_time resolved
    Grid2 m_last_u, m_last_v;  ///< midstep: the last state's cached velocity
    Grid2 m_last_omega;        ///< midstep: the last state (the energy budget's extrapolation)
    bool m_have_last = false;
    double m_last_dt = 0;       ///< the step that led from the last state to the current one
    double m_mid_factor = 0;    ///< the current step's dt / (2 m_last_dt), 0 without a last state
    std::vector<char> m_fluid;  ///< with boundaries: the cells outside every solid at the current state
    bool m_velocity_valid = false;
    std::shared_ptr<const PeriodicKernel> m_periodic;
    std::unique_ptr<VelocityField2> m_field;  ///< the current state's velocity (settings().estimator)
    const WosVelocityField* m_wos = nullptr;  ///< m_field->boundaries(): solids, walls (null without boundaries)
    FluidWork m_work;
    std::unique_ptr<PassiveScalars> m_dye;
    Grid2 m_disp_x, m_disp_y;                ///< displacement x - x_departure of the last step (only with a dye)
    Grid2 m_advected;                        ///< MacCormack with viscosity: the advected values before diffusion
    std::vector<Vec2d> m_departure;          ///< MacCormack: each cell's departure point (wrapped)
    std::unique_ptr<FlowFFT> m_flow;         ///< the energy budget's FFTs (no walls; null: no budget)
    std::unique_ptr<WallFlow2> m_wall_flow;  ///< the energy budget's Poisson solves (walls; null: no budget)
    bool budget_on() const { return m_flow || m_wall_flow; }
    EnergyBudget m_budget_step, m_budget_total;
    int m_energy_passes = 0;
    PairedEnergy m_paired;  ///< of step m_paired_step
    long long m_paired_step = -1;
};

/// Settings of the recursive estimator (Algorithm C.1).
struct RecursiveSettings {
    Domain2 domain;
    double dt = 0.05;
    double viscosity = 0;
    int diffusion_samples = 1;  ///< n_d, used only when viscosity > 0
    Advection advection = Advection::Euler;
    BiotSavartOptions velocity;  ///< samples = n_mc per velocity estimate at every level; delta must be >= 0
    /// importance = vorticity: samples from |omega(0, .)| tabulated on this many cells per axis (tent basis),
    /// mixed with `defensive` of uniform sampling so that the density covers vorticity that has moved.
    int importance_resolution = 64;
    double defensive = 0.25;
};

/// The recursive, cache-free estimator (Algorithm C.1): omega(t, x) and v(t, x) at any point, for t a
/// multiple of dt. Cost grows like (stages * n_mc + n_d)^(t/dt). Thread-safe (const, atomic counters).
class RecursiveEstimator {
public:
    RecursiveEstimator(const RecursiveSettings& settings, InitialField initial);
    ~RecursiveEstimator();

    double vorticity(double t, Vec2d x, Random& rng) const;
    Vec2d velocity(double t, Vec2d x, Random& rng) const;
    /// Evaluations of the initial condition and Biot–Savart samples so far.
    uint64_t initial_evaluations() const { return m_initial_evals.load(); }
    uint64_t biot_savart_evals() const { return m_bs_evals.load(); }
    const RecursiveSettings& settings() const { return m_settings; }

private:
    long long steps_of(double t) const;
    double vor(long long n, Vec2d x, Random& rng) const;
    Vec2d vel(long long n, Vec2d x, Random& rng) const;
    Vec2d backtrace(long long n, Vec2d x, Random& rng) const;
    double init(Vec2d x) const;

    RecursiveSettings m_settings;
    InitialField m_initial;
    std::shared_ptr<const PeriodicKernel> m_periodic;
    struct Importance;
    std::unique_ptr<Importance> m_importance;
    mutable std::atomic<uint64_t> m_initial_evals{0}, m_bs_evals{0};
};

}  // namespace kelvin::fluid
