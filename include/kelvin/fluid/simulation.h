#pragma once
// What the baseline <simulation> plugins (vortex_particles, stable_fluids) share with mcfluid, so that a scene
// switches solver with one word: the same parameters (domain, time stepping, viscosity, advection, outputs,
// <vorticity>, <scalar>, <cache type="grid"> as the resolution), and one driver that writes the same files
// (<prefix>.csv with the same columns, <prefix>_NNNN.png/.exr, <prefix>_dye_NNNN.png/.exr), reports the same
// counters and prints which effects were active.
#include <kelvin/core/checkpoint.h>
#include <kelvin/core/job.h>
#include <kelvin/core/properties.h>
#include <kelvin/fluid/checks.h>
#include <kelvin/fluid/dye.h>
#include <kelvin/fluid/fields.h>
#include <kelvin/fluid/mcfluid.h>
#include <kelvin/fluid/mcfluid3.h>
#include <kelvin/fluid/output.h>
#include <kelvin/fluid/solver.h>

#include <functional>
#include <memory>
#include <string>

namespace kelvin::fluid {

/// dt, steps and end_time as every simulation (2D and 3D) reads them: give steps or end_time; end_time resolves to
/// the number of steps that reach it (the last one shortened by the run loop).
struct TimeStepping {
    double dt = 0.05;
    long long steps = 0;
    double end_time = 0;
    static TimeStepping parse(const Properties& props);
    /// The length of step `step` (1-based) taken at simulated time `time`, as every run loop takes it: dt, the
    /// last one shortened to land on end_time. A host stepping a solver itself uses it to compute run()'s states.
    double step_length(long long step, double time) const {
        double h = dt;
        if (end_time > 0 && step == steps) h = end_time - time;
        return h > 0 ? h : dt;
    }
};

/// The time limit of a run loop (RunContext::time_limit; 0: none) after `elapsed` seconds, decided by rank 0's clock
/// for every rank of a distributed run (one broadcast; none without a limit or with one rank), so that all ranks stop
/// after the same step.
bool time_limit_reached(Communicator& comm, double time_limit, double elapsed);

/// The parameters every 2D simulation reads (see docs/fluid.md, "Baselines").
struct SimulationParams {
    Domain2 domain;
    double dt = 0.05;
    long long steps = 0;  ///< resolved from end_time when that was given
    double end_time = 0;
    double viscosity = 0;
    Advection advection = Advection::RK4;
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
    /// parse() for a baseline solver: MCFluid-only inputs (<velocity>, diffusion_samples) are also accepted and
    /// ignored with a note, so that an mcfluid scene runs unchanged with `-D solver=...`.
    static SimulationParams parse_baseline(const Properties& props, const std::string& who);
};

/// A <simulation> plugin (mcfluid, stable_fluids, vortex_particles) as a host drives it: run() it as any Job, or
/// take its solver and step and query it yourself (docs/host-api.md). find_simulation() gets it from a loaded
/// scene.
class Simulation : public Job {
public:
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

/// The run loop of a baseline: CSV row per state, frames every output_every steps (and the last), dye frames,
/// progress, --time-limit, --write-partial, interruption, counters and the end-of-run summary. `effects` is
/// the solver's part of the effects line (its advection and boundaries; the driver adds diffusion, stretching
/// and dye).
RunResult run_fluid_solver(const std::string& who, FluidSolver& solver, const SimulationParams& p, RunContext& ctx,
                           const std::string& effects);

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
    kelvin::param::integer("dimension", 2, "2 (3D is not implemented)"),                                             \
        kelvin::param::point("min", kelvin::Vec3d(-1.0, -1.0, 0.0), "domain box corner (z = 0)"),                    \
        kelvin::param::point("max", kelvin::Vec3d(1.0, 1.0, 0.0), "domain box corner (z = 0)"),                      \
        kelvin::param::boolean("periodic", false, "periodic box (true) or open (false)"),                            \
        kelvin::param::real("dt", 0.05, "time step"),                                                                \
        kelvin::param::integer("steps", 0, "number of steps (or give end_time)"),                                    \
        kelvin::param::real("end_time", 0.0, "simulated time (or give steps)"),                                      \
        kelvin::param::real("viscosity", 0.0, "kinematic viscosity nu (0: inviscid)"),                               \
        kelvin::param::integer("diffusion_samples", 1, "mcfluid's n_d; accepted and ignored"),                       \
        kelvin::param::string("advection", "rk4", "'euler' or 'rk4'"),                                               \
        kelvin::param::integer("output_every", 0, "write PNG/EXR frames every N steps (0: none)"),                   \
        kelvin::param::boolean("write_png", true, "write frames as PNG"),                                            \
        kelvin::param::boolean("write_exr", true, "write frames as EXR"),                                            \
        kelvin::param::boolean("write_csv", true, "write diagnostics.csv, one row per step"),                        \
        kelvin::param::real("color_range", 0.0, "|omega| mapped to full colour (0: max at t = 0)"),                  \
        KELVIN_FRAME_STYLE_PARAMS, kelvin::param::object("vorticity", "vorticity", "initial vorticity field", true), \
        kelvin::param::object("velocity", "velocity", "mcfluid's velocity estimator; accepted and ignored"),         \
        kelvin::param::object("cache", "cache", "grid: its resolution is the solver's (default 64)"),                \
        kelvin::param::object("scalar", "scalar", "passive scalar (dye) advected with the flow (optional)")
