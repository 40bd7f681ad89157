#pragma once
// What every <simulation> plugin (mcfluid, vortex_particles, stable_fluids) shares, so that a scene switches solver
// with one word: the same parameters (domain, time stepping, viscosity, advection, outputs, <vorticity>, <scalar>,
// <cache type="grid"> as the resolution), and one driver (driver.h) that writes the same files (diagnostics.csv with
// the same columns, vorticity_NNNN.png, fields_NNNN.exr, dye_NNNN.png/.exr), reports the same counters and prints
// which effects were active.
#include <kelvin/core/checkpoint.h>
#include <kelvin/core/job.h>
#include <kelvin/core/properties.h>
#include <kelvin/fluid/checks.h>
#include <kelvin/fluid/driver.h>
#include <kelvin/fluid/dye.h>
#include <kelvin/fluid/fields.h>
#include <kelvin/fluid/mcfluid.h>
#include <kelvin/fluid/mcfluid3.h>
#include <kelvin/fluid/output.h>
#include <kelvin/fluid/solver.h>

#include <functional>
#include <memory>
#include <optional>
#include <string>

namespace kelvin::fluid {

/// The scene's `transport` ("cubic" or "linear"; mcfluid in 2D and 3D).
VorticityTransport parse_transport(const Properties& props);
/// 3D's `stretching_filter` in cells: AutoFilter (-1, the default: the solver's choice) or 0 to
/// MCFluid3Settings::MaxStretchingFilter; anything else is the parameter's error.
double parse_stretching_filter(const Properties& props);
/// The scene's `filter_kernel`: a kernel, or none for "auto" (the solver's: Gaussian in 2D, twicing in 3D).
std::optional<FilterKernel> parse_filter_kernel(const Properties& props);
/// The scene's `velocity_time`: 'auto', 'midstep' or 'start'.
VelocityTime parse_velocity_time(const Properties& props);

/// The parameters every 2D simulation reads (see docs/fluid.md, "Baselines").
struct SimulationParams {
    Domain2 domain;
    double dt = 0.05;
    long long steps = 0;  ///< resolved from end_time when that was given
    double end_time = 0;
    double viscosity = 0;
    Advection advection = Advection::RK4;
    VorticityTransport transport = VorticityTransport::Cubic;        ///< mcfluid's; the baselines ignore it
    BacktraceVelocity backtrace_velocity = BacktraceVelocity::Auto;  ///< mcfluid's; the baselines ignore it
    double velocity_filter = 1.0;                                    ///< mcfluid's; the baselines ignore it
    VelocityTime velocity_time = VelocityTime::Auto;                 ///< mcfluid's; the baselines ignore it
    std::optional<FilterKernel> filter_kernel;                       ///< mcfluid's (none: auto); ignored likewise
    long long output_every = 0;
    bool write_png = true, write_exr = true, write_csv = true;
    double color_range = 0;
    FrameStyle frames;     ///< frame_size, montage, write_video, video_fps
    int nx = 64, ny = 64;  ///< <cache type="grid"> resolution (square cells when resolution_y = 0)
    std::shared_ptr<VorticityField> field;
    std::shared_ptr<DyeSpec> dye;
    RunSources sources;  ///< where the scene gave dt and the initial vorticity (checks.h)

    /// Reads and validates them (and the memory the solver `who` will need at this resolution, checks.h) (errors name
    /// the parameter; `who` names the solver in messages). mcfluid and the baselines share this parser.
    static SimulationParams parse(const Properties& props, const std::string& who);
    /// The driver's settings of a run of the solver `who` on the nx x ny grid.
    DriverSettings driver_settings(const std::string& who) const;
    /// parse() for a baseline solver: MCFluid-only inputs (<velocity>, diffusion_samples) are also accepted and
    /// ignored with a note, so that an mcfluid scene runs unchanged with `-D solver=...`.
    static SimulationParams parse_baseline(const Properties& props, const std::string& who);
};

/// A <simulation> plugin (mcfluid, stable_fluids, vortex_particles) as a host drives it: run() it as any Job, or
/// take its solver and step and query it yourself (docs/host-api.md). find_simulation() gets it from a loaded
/// scene.
class Simulation : public Job {
public:
    /// Runs the simulation through the driver (driver.h): driven_solver(ctx) stepped with driver_settings().
    RunResult run(RunContext& ctx) override;
    /// The solver run(ctx) steps, at t = 0, as the driver sees it (set up from ctx.seed, ctx.spp, ctx.comm).
    virtual std::unique_ptr<DrivenSolver> driven_solver(const RunContext& ctx) const = 0;
    /// The driver's settings: the solver's name, time stepping, outputs, sources and cell size.
    virtual DriverSettings driver_settings() const = 0;

    /// 2, or 3 (mcfluid with dimension = 3).
    virtual int dimension() const { return 2; }
    /// dt, steps and end_time as the scene gives them (steps resolved from end_time).
    virtual TimeStepping time_stepping() const = 0;
    /// The kinematic viscosity nu.
    virtual double viscosity() const = 0;
    /// The initial vorticity field of a 2D simulation (its exact_vorticity/exact_velocity give the exact
    /// solution where one is known: Lamb–Oseen, Taylor–Green); null in 3D.
    virtual std::shared_ptr<const VorticityField> vorticity_field() const { return nullptr; }
    /// The initial vorticity field of a 3D simulation (exact_vorticity3/exact_velocity3 where known: Taylor–Green);
    /// null in 2D. It lives as long as the simulation.
    virtual const VorticityField3* vorticity_field3() const { return nullptr; }

    /// The solver of a 2D simulation at t = 0, set up as run(ctx) sets it up: from the scene's parameters,
    /// ctx.seed, ctx.spp (mcfluid: n_mc), ctx.cancel (the solver's cancel token) and ctx.comm (mcfluid: the ranks its
    /// passes are spread over; every rank must then make the same calls). Stepping it by
    /// time_stepping().step_length(s, time) computes the states run(ctx) computes, bit for bit. No file is written and
    /// nothing is logged. The solver may refer to this object: keep the simulation (or its scene) alive while using it.
    /// Throws InputError for a 3D simulation.
    virtual std::unique_ptr<FluidSolver> create_solver(const RunContext& ctx) const;
    /// The same for a 3D simulation (mcfluid with dimension = 3); throws InputError for a 2D one.
    virtual std::unique_ptr<MCFluid3Solver> create_solver3(const RunContext& ctx) const;
};

/// The simulation of a loaded scene: `root` itself when it is one, or the <simulation> of a <scene>. Throws
/// InputError when there is none (a render scene).
std::shared_ptr<Simulation> find_simulation(const ObjectPtr& root);

/// A 2D FluidSolver (the baselines; mcfluid's adapter derives from it) as the driver runs it: its diagnostics, the
/// exact solution's RMSE, the CSV's 2D columns, field_image frames and images, checkpoints on its grid, its counters.
/// `effects` is the solver's part of the effects line (its advection and boundaries; the adapter adds diffusion,
/// stretching and dye).
class Solver2Run : public DrivenSolver {
public:
    Solver2Run(std::string who, std::unique_ptr<FluidSolver> solver, const SimulationParams& params,
               std::string effects);
    Cancellable& cancellable() override { return *m_solver; }
    double time() const override { return m_solver->time(); }
    long long step_index() const override { return m_solver->step_index(); }
    bool step(double dt) override;
    bool diagnose(bool velocity) override;
    std::vector<NamedValue> values() const override { return diagnostic_values(m_d, m_velocity); }
    std::vector<FieldValues> fields() override;
    std::size_t cells() const override { return m_solver->vorticity_grid().cell_count(); }
    double max_speed() override;
    double evaluations() const override { return m_solver->evaluations(); }
    uint64_t replaced() const override { return m_solver->invalid(); }
    std::string csv_header() const override { return DiagnosticsCsv::header(); }
    std::string csv_row(double seconds, double evals, uint64_t invalid, double cfl) const override {
        return DiagnosticsCsv::row(m_d, seconds, evals, invalid, cfl);
    }
    void write_frame(FrameWriter& frames) override;
    Bitmap image() override;
    Checkpoint checkpoint() override;
    std::vector<std::string> describe() override;
    void report(Stats& stats) const override;
    void warn() const override;
    std::string summary(const std::string& ended) override;

protected:
    /// The PNG frames' overlay (none by default).
    virtual const FrameOverlay* overlay() { return nullptr; }
    /// Whether the exact solution describes this flow (solid boundaries change it).
    virtual bool bounded() const { return false; }
    std::string m_who;
    std::unique_ptr<FluidSolver> m_solver;
    const SimulationParams& m_p;
    std::string m_effects;
    double m_range = 0;
    FluidDiagnostics m_d, m_d0;  ///< the diagnosed state, and the first one
    bool m_velocity = false;     ///< the current state's velocity is known (diagnosed with it)
    bool m_have_d0 = false;
};

/// mcfluid's parameters in 2D (dimension = 2): the shared ones, n_d, the velocity estimator (the owner of n_mc and
/// the mollifier delta, which --spp overrides for a run) and the cache.
struct MCFluidParams {
    SimulationParams common;
    MCFluidSettings settings;    ///< the solver's, from the scene (seed 0, n_mc the estimator's)
    bool energy_budget = false;  ///< measure where each step's energy goes (energy_budget.h)
    int energy_passes = 0;       ///< the states' paired energy from this many independent passes (0: off)
    /// Reads and validates them (errors name the parameter).
    static MCFluidParams parse(const Properties& props);
};
/// The 2D mcfluid solver of a run with `ctx`, at t = 0: ctx.seed, ctx.spp as n_mc (run_samples), the dye, ctx.cancel
/// as its token, ctx.comm as its ranks. It refers to p's field: keep `p` alive while using it.
std::unique_ptr<MCFluidSolver> create_mcfluid_solver(const MCFluidParams& p, const RunContext& ctx);
/// That solver as the driver runs it.
std::unique_ptr<DrivenSolver> drive_mcfluid(const MCFluidParams& p, const RunContext& ctx);

/// The named fields of a state on its output grid ("vorticity", "u", "v"; null for other names), looked up
/// only when a checkpoint consumer asks for them.
using FieldLookup = std::function<const Grid2*(const std::string& name)>;

/// A checkpoint of a 2D simulation state (mcfluid and the baselines): work, simulated time and grid, its fields
/// through `fields`, and the exact solution of the initial condition (when `field` has one) at `viscosity`.
/// The caller sets `seconds` and `image`. `fields` and `field` must outlive the checkpoint callback.
Checkpoint state_checkpoint(long long steps, double sim_time, const CellGrid2& grid, FieldLookup fields,
                            const VorticityField& field, double viscosity);

/// Diagnostics of a state given as fields on one grid (midpoint rule over the domain box).
FluidDiagnostics grid_diagnostics(const Grid2& omega, const Grid2& u, const Grid2& v);

}  // namespace kelvin::fluid

/// The parameter declarations shared by the baseline simulations (same names and defaults as mcfluid).
#define KELVIN_FLUID_SIMULATION_PARAMS                                                                               \
    kelvin::param::integer("dimension", 2, "2, or 3 (stable_fluids and flip; vortex_particles is 2D)"),              \
        kelvin::param::point("min", kelvin::Vec3d(-1.0, -1.0, 0.0), "domain box corner (z = 0)"),                    \
        kelvin::param::point("max", kelvin::Vec3d(1.0, 1.0, 0.0), "domain box corner (z = 0)"),                      \
        kelvin::param::boolean("periodic", false, "periodic box (true) or open (false)"),                            \
        kelvin::param::real("dt", 0.05, "time step"),                                                                \
        kelvin::param::integer("steps", 0, "number of steps (or give end_time)"),                                    \
        kelvin::param::real("end_time", 0.0, "simulated time (or give steps)"),                                      \
        kelvin::param::real("viscosity", 0.0, "kinematic viscosity nu (0: inviscid)"),                               \
        kelvin::param::integer("diffusion_samples", 1, "mcfluid's n_d; accepted and ignored"),                       \
        kelvin::param::string("advection", "rk4", "'euler' or 'rk4'"),                                               \
        kelvin::param::string("transport", "cubic", "mcfluid's vorticity lookup; accepted and ignored"),             \
        kelvin::param::string("backtrace_velocity", "auto", "mcfluid's; accepted and ignored"),                      \
        kelvin::param::real("velocity_filter", 1.0, "mcfluid's; accepted and ignored"),                              \
        kelvin::param::string("velocity_time", "auto", "mcfluid's; accepted and ignored"),                           \
        kelvin::param::string("filter_kernel", "auto", "mcfluid's; accepted and ignored"),                           \
        kelvin::param::boolean("energy_budget", false, "mcfluid's; must be false"),                                  \
        kelvin::param::integer("energy_passes", 0, "mcfluid's; must be 0"),                                          \
        kelvin::param::integer("output_every", 0, "write PNG/EXR frames every N steps (0: none)"),                   \
        kelvin::param::boolean("write_png", true, "write frames as PNG"),                                            \
        kelvin::param::boolean("write_exr", true, "write frames as EXR"),                                            \
        kelvin::param::boolean("write_csv", true, "write diagnostics.csv, one row per step"),                        \
        kelvin::param::real("color_range", 0.0, "|omega| mapped to full colour (0: max at t = 0)"),                  \
        KELVIN_FRAME_STYLE_PARAMS, kelvin::param::object("vorticity", "vorticity", "initial vorticity field", true), \
        kelvin::param::object("velocity", "velocity", "mcfluid's velocity estimator; accepted and ignored"),         \
        kelvin::param::object("cache", "cache", "grid: its resolution is the solver's (default 64)"),                \
        kelvin::param::object("scalar", "scalar", "passive scalar (dye) advected with the flow (optional)")
