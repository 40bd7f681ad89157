#pragma once
// The simulation driver: the one run loop of every <simulation> — mcfluid in 2D and 3D, the baselines, and any
// solver written out of tree — as run_passes is the render side's. A solver supplies its steps, the diagnostics,
// fields, frames, image and checkpoint of its current state, and its counters (DrivenSolver); the driver owns,
// once for all of them: the CSV, frames, montage and video, checkpoints, progress, the time limit, signals,
// --write-partial, the non-finite and CFL checks, MPI agreement (rank 0's clock, any rank's stop) and the summary.
//
// The run, step by step (every solver alike):
//   state 0   diagnosed (with its velocity), checked, CSV row, frame, checkpoint 0
//   step s    stop requested on any rank? -> end;  step(dt) stopped? -> end (the state before it stays)
//             the last state's velocity is skipped when no output needs it (lazy_velocity() solvers)
//             diagnosed, checked (non-finite: exit 1 with the earlier rows), CFL, CSV row, frame when due,
//             progress, partial image, checkpoint; time limit (rank 0's clock, checkpoint overhead excluded)
//   end       counters, warnings, CSV committed, montage and video, summary line, the image
#include <kelvin/core/checkpoint.h>
#include <kelvin/core/image.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/job.h>
#include <kelvin/core/stats.h>
#include <kelvin/fluid/checks.h>
#include <kelvin/fluid/output.h>

#include <string>
#include <vector>

namespace kelvin {
class Communicator;
class Properties;
}  // namespace kelvin

namespace kelvin::fluid {

/// dt, steps and end_time as every simulation (2D and 3D) reads them: give steps or end_time; end_time resolves to
/// the number of steps that reach it (the last one shortened by the driver).
struct TimeStepping {
    double dt = 0.05;
    long long steps = 0;
    double end_time = 0;
    static TimeStepping parse(const Properties& props);
    /// The length of step `step` (1-based) taken at simulated time `time`, as the driver takes it: dt, the last one
    /// shortened to land on end_time. A host stepping a solver itself uses it to compute run()'s states.
    double step_length(long long step, double time) const {
        double h = dt;
        if (end_time > 0 && step == steps) h = end_time - time;
        return h > 0 ? h : dt;
    }
};

/// The time limit of a run (RunContext::time_limit; 0: none) after `elapsed` seconds, decided by rank 0's clock for
/// every rank of a distributed run (one broadcast; none without a limit or with one rank), so that all ranks stop
/// after the same step.
bool time_limit_reached(Communicator& comm, double time_limit, double elapsed);

/// The outputs every simulation declares (output_every, write_png, write_exr or write_vdb, write_csv, and the frame
/// style: KELVIN_FRAME_STYLE_PARAMS).
struct OutputSettings {
    long long every = 0;  ///< frames every N steps and at the last (0: none)
    bool png = true;      ///< PNG frames
    bool data = true;     ///< data frames: EXR (2D) or OpenVDB (3D)
    bool csv = true;      ///< diagnostics.csv
    double color_range = 0;
    FrameStyle style;
};

/// What the driver needs of a run besides its solver.
struct DriverSettings {
    std::string who;  ///< the solver's name in messages, and the folder's name in an output directory ("D/<who>/")
    TimeStepping time;
    OutputSettings outputs;
    RunSources sources;  ///< where the scene gave dt and the initial vorticity, for the checks' messages
    double h = 0;        ///< the smallest cell size (CFL)
    double extent = 0;   ///< the domain's smallest side
};

/// A solver as the driver runs it. The driver diagnoses each state once (diagnose()) and then asks for that state's
/// check values, fields, CSV row and frame; image() and checkpoint() describe the current state.
class DrivenSolver {
public:
    virtual ~DrivenSolver() = default;

    // ----- stepping
    /// The solver's cancellation points: the driver gives it the run's cancel token and the time-limit watch's.
    virtual Cancellable& cancellable() = 0;
    virtual double time() const = 0;
    virtual long long step_index() const = 0;
    /// One step of length dt; false (state unchanged) when a stop cut it short.
    virtual bool step(double dt) = 0;

    // ----- the state's velocity
    /// True when a state's velocity is a separate pass after its step (mcfluid): the driver then skips it for the
    /// last state when no output needs it (no CSV, checkpoint, partial image, data frame or image that carries it).
    virtual bool lazy_velocity() const { return false; }
    /// Whether the run's image, written as a file with extension `ext` (lower case, with the dot), carries the
    /// velocity (2D EXR: the u and v channels).
    virtual bool image_carries_velocity(const std::string& ext) const {
        (void)ext;
        return false;
    }

    // ----- the current state
    /// Diagnoses the current state, with its velocity (estimated now if need be) or without. Returns whether the
    /// state has its velocity: false when `velocity` was false, or when a stop cut the velocity's pass short.
    virtual bool diagnose(bool velocity) = 0;
    /// The diagnosed state's values as the CSV writes them, by name (checked for finiteness before any output).
    virtual std::vector<NamedValue> values() const = 0;
    /// The diagnosed state's fields that its outputs carry (checked as float32 before any output).
    virtual std::vector<FieldValues> fields() = 0;
    /// The number of cells of a state (the share of replaced values that means overflow, checks.h).
    virtual std::size_t cells() const = 0;
    /// The largest speed of the diagnosed state (its velocity's; called only when it has one).
    virtual double max_speed() = 0;
    /// Kernel evaluations and non-finite values replaced by zero, so far (the CSV's per-step columns).
    virtual double evaluations() const = 0;
    virtual uint64_t replaced() const = 0;
    /// The CSV's header (no newline) and the diagnosed state's row (with the newline): `seconds` of the step that
    /// produced it, its kernel `evals`, `invalid` values replaced and its `cfl` number.
    virtual std::string csv_header() const = 0;
    virtual std::string csv_row(double seconds, double evals, uint64_t invalid, double cfl) const = 0;
    /// The diagnosed state's frames (PNG and data, as `frames` is configured).
    virtual void write_frame(FrameWriter& frames) = 0;
    /// The current state as the run's image (and partial image); with the velocity when the state has it.
    virtual Bitmap image() = 0;
    /// The current state as a checkpoint (sim_time, grid, fields, exact solution); the driver sets the work, the
    /// seconds and the image.
    virtual Checkpoint checkpoint() = 0;

    // ----- the run
    /// The lines logged before the first step (the setup; the effects: what runs and what does not).
    virtual std::vector<std::string> describe() = 0;
    /// The solver's counters into `stats` (fluid.*); the driver adds fluid.steps, fluid.time_simulated, fluid.cells.
    virtual void report(Stats& stats) const = 0;
    /// Warnings of the run's end (e.g. the values replaced by zero).
    virtual void warn() const {}
    /// The last line: the final state's diagnostics against the initial state's; `ended` says why the run ended
    /// early ("interrupted", "stopped by the time limit") or is empty.
    virtual std::string summary(const std::string& ended) = 0;
};

/// Runs `solver` (at t = 0, set up from the scene with ctx.seed, ctx.spp and ctx.comm) to its end, writing its outputs
/// under ctx.output. Every solver behaves alike under the time limit, a stop, a full disk and MPI.
RunResult run_simulation(DrivenSolver& solver, const DriverSettings& settings, RunContext& ctx);

/// The Monte Carlo sample count of a run: --spp (ctx.spp, capped at 2^24) when given, otherwise the scene's.
int run_samples(const RunContext& ctx, int scene_samples);

/// mcfluid's `energy_passes` from the scene: 0 (off) or 2 to 64 (an error names the parameter).
int energy_passes_param(const Properties& props);

}  // namespace kelvin::fluid
