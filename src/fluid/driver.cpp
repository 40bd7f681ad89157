// The simulation driver (include/kelvin/fluid/driver.h): the one run loop of every <simulation>.
#include <kelvin/core/checkpoint.h>
#include <kelvin/core/distributed.h>
#include <kelvin/core/error.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/progress.h>
#include <kelvin/core/properties.h>
#include <kelvin/fluid/driver.h>

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <optional>

namespace kelvin::fluid {

TimeStepping TimeStepping::parse(const Properties& props) {
    TimeStepping t;
    t.dt = props.get_float("dt", 0.0, 1e300);
    if (!(t.dt > 0)) props.error("dt", "must be positive");
    t.steps = props.get_int("steps", 0, 1LL << 40);
    t.end_time = props.get_float("end_time", 0.0, 1e300);
    if (t.steps > 0 && t.end_time > 0) props.error("end_time", "give either steps or end_time, not both");
    if (t.steps == 0 && t.end_time == 0) props.error("steps", "give the number of steps or an end_time (> 0)");
    if (t.end_time > 0) {
        const double n = t.end_time / t.dt;
        if (n > double(1LL << 40)) props.error("end_time", "needs more than 2^40 steps of dt");
        t.steps = std::max(1LL, (long long)std::ceil(n - 1e-9));
    }
    return t;
}

bool time_limit_reached(Communicator& comm, double time_limit, double elapsed) {
    if (!(time_limit > 0)) return false;
    comm.broadcast(&elapsed, sizeof elapsed);  // rank 0's clock
    return elapsed >= time_limit;
}

int run_samples(const RunContext& ctx, int scene_samples) {
    return ctx.spp > 0 ? int(std::min<long long>(ctx.spp, 1 << 24)) : scene_samples;
}

int energy_passes_param(const Properties& props) {
    const int passes = int(props.get_int("energy_passes", 0, 64));
    if (passes == 1)
        props.error("energy_passes",
                    "1: one pass's square carries its noise; use 0 (off) or 2 and more (3 and more for an error bar)");
    return passes;
}

RunResult run_simulation(DrivenSolver& solver, const DriverSettings& s, RunContext& ctx) {
    const std::string& who = s.who;
    const OutputSettings& out = s.outputs;
    const long long steps = s.time.steps;
    // Distributed: every rank steps the whole state (the solver's passes are collectives) and takes the same
    // decisions; only rank 0 writes files and reports progress. `paths` is the same on every rank, so that the
    // decisions that depend on the outputs (which velocity passes run) are too.
    Communicator& comm = communicator_of(ctx);
    const OutputPaths paths(ctx.output, who);
    check_frames_folder(paths, who);  // before any work
    Timer total;
    solver.cancellable().set_cancel_token(ctx.cancel);  // the solver's own loops stop with this job
    // The time limit inside a step: the solver's loops poll the watch's token (checks.h).
    TimeLimitWatch watch(ctx.time_limit);
    solver.cancellable().set_time_limit_token(watch.token());
    StepChecks checks(who, s.sources, s.h, s.extent);
    for (const std::string& line : solver.describe()) log_info("{}: {}", who, line);

    RunResult result;
    result.work_unit = "steps";
    const bool csv_wanted = paths.enabled() && out.csv;
    FrameWriter frames(comm.root() ? paths : OutputPaths({}), out.every, out.png, out.data, out.style, steps,
                       result.files_written);  // creates the folder
    std::optional<DiagnosticsCsv> csv;
    if (csv_wanted && comm.root()) {
        csv.emplace(paths.csv(), solver.csv_header());
        result.files_written.push_back(paths.csv());
    }

    // Checkpoints (core/checkpoint.h, `kelvin converge`): the state after the steps that reach them.
    CheckpointSchedule checkpoints(ctx);
    if (checkpoints.active() && comm.distributed())
        throw RuntimeError(fmt::format(
            "{}: checkpoints are not supported in a distributed job (a convergence study distributes its runs "
            "instead: kelvin converge under mpirun)",
            who));
    auto checkpoint = [&](long long done) {
        Checkpoint cp = solver.checkpoint();
        cp.work = double(done);
        cp.work_unit = "steps";
        cp.seconds = total.seconds() - checkpoints.overhead();
        cp.image = [&solver] { return solver.image(); };
        checkpoints.reached(ctx, cp);
    };

    // Nothing non-finite reaches the CSV or a frame (checks.h): the initial state is refused as input (exit 2, naming
    // the initial vorticity's strength), a later one stops the run with the earlier steps' outputs (exit 1).
    auto check_state = [&](long long step, uint64_t replaced) {
        const std::string why = checks.state(step, solver.values(), solver.fields(), replaced, solver.cells());
        if (why.empty()) return;
        if (csv) csv->close();
        throw RuntimeError(why);
    };
    // The state's CFL number for the step that starts from it; a refused dt keeps the earlier rows.
    auto cfl = [&](long long step) {
        const double dt = s.time.step_length(step + 1, solver.time());
        try {
            return checks.cfl(step, solver.max_speed(), dt, step == steps);
        } catch (...) {
            if (csv && step > 0) csv->close();
            throw;
        }
    };

    // The last state's velocity is estimated only when an output needs it: the CSV (its energies), a checkpoint, a
    // data frame, partial images, an image that carries it, or a host that takes the image itself (no output path).
    std::string ext = ctx.output.extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char ch) { return char(std::tolower(ch)); });
    const bool final_velocity = !solver.lazy_velocity() || csv_wanted || checkpoints.active() ||
                                ctx.write_partial > 0 || ctx.output.empty() || solver.image_carries_velocity(ext) ||
                                (paths.enabled() && out.every > 0 && out.data);

    auto write_frame = [&] {
        frames.set_time(solver.time());  // the montage's labels
        solver.write_frame(frames);
    };
    // The run's image (and partial images): an EXR output is data, the fields one pixel per cell (solver.image());
    // any other format (PNG, JPEG, ...) holds only colours, and gets the picture a PNG frame shows (frame_size
    // pixels, solids and walls drawn). Without an output path (a host), the data.
    const bool picture = !ctx.output.empty() && ext != ".exr";
    auto output_image = [&]() -> Bitmap {
        if (picture) {
            std::vector<std::filesystem::path> none;
            FrameWriter capture = FrameWriter::capture(out.style, none);
            solver.write_frame(capture);
            if (!capture.captured().empty()) return capture.captured();
        }
        return solver.image();
    };

    // State 0 (for mcfluid its velocity is the first step's k1, so its diagnostics cost nothing extra). A stop during
    // that velocity pass leaves nothing to record.
    const bool velocity0 = solver.diagnose(true);
    check_state(0, velocity0 ? solver.replaced() : 0);
    if (velocity0) {
        const double c = cfl(0);
        if (csv) csv->write_row(solver.csv_row(0.0, solver.evaluations(), solver.replaced(), c));
        if (frames.enabled()) write_frame();
        if (checkpoints.active()) checkpoint(0);
    }

    ProgressReporter progress(ctx, "Simulating", double(steps), "steps", ctx.time_limit);
    Timer since_partial;
    long long done = 0;
    bool stopped_by_time = false;
    bool last_unrecorded = false;  // the last state's velocity pass was cut: no CSV row, no frame
    for (long long step = 1; step <= steps; ++step) {
        if (any_rank(comm, ctx.cancel.stop_requested())) break;
        const double evals_before = solver.evaluations();
        const uint64_t replaced_before = solver.replaced();
        Timer step_timer;
        if (!solver.step(s.time.step_length(step, solver.time()))) break;
        ++done;
        if (step == steps && !final_velocity) {  // the last state, without its velocity
            solver.diagnose(false);
            check_state(step, solver.replaced() - replaced_before);
            if (frames.enabled() && frames.due(step)) write_frame();
            progress.update(1);
            break;
        }
        // The new state's velocity: diagnostics now (for mcfluid, k1 of the next step later, computed once). A stop
        // during its pass ends the run with the new state and no velocity.
        if (!solver.diagnose(true)) {
            last_unrecorded = true;
            break;
        }
        const uint64_t replaced = solver.replaced() - replaced_before;
        check_state(step, replaced);
        const double c = cfl(step);
        const double seconds = step_timer.seconds();
        if (csv) csv->write_row(solver.csv_row(seconds, solver.evaluations() - evals_before, replaced, c));
        if (frames.enabled() && frames.due(step)) write_frame();
        progress.update(1);
        if (comm.root() && ctx.write_partial > 0 && ctx.write_partial_image &&
            since_partial.seconds() >= ctx.write_partial) {
            ctx.write_partial_image(output_image());
            since_partial.reset();
        }
        if (checkpoints.active()) {
            checkpoint(done);
            if (ctx.time_limit > 0) watch.set_limit(ctx.time_limit + checkpoints.overhead());
        }
        if (step < steps && time_limit_reached(comm, ctx.time_limit, total.seconds() - checkpoints.overhead())) {
            stopped_by_time = true;
            break;
        }
    }
    progress.finish();
    result.interrupted = any_rank(comm, ctx.cancel.stop_requested());
    // The limit passed inside a step (the watch stopped it; the partial step was discarded): as at a step boundary.
    if (!result.interrupted && done < steps && any_rank(comm, watch.passed())) stopped_by_time = true;
    checks.report(ctx.stats);
    if (stopped_by_time)
        log_warn("{}: time limit of {:g} s reached after {} of {} steps (t = {:g}{})", who, ctx.time_limit, done, steps,
                 solver.time(),
                 last_unrecorded ? "; the limit cut this state's velocity pass: it has no CSV row and no frame" : "");

    ctx.stats.add("fluid.steps", double(done), "steps");
    ctx.stats.set("fluid.time_simulated", solver.time(), "");
    ctx.stats.add("fluid.cells", double(solver.cells()), "cells");
    solver.report(ctx.stats);
    if (csv) csv->close();  // the CSV so far replaces the previous one (interrupted runs included)
    frames.finish();
    ctx.stats.add_time("fluid.time.output", frames.seconds());
    solver.warn();
    const char* ended = result.interrupted ? "interrupted" : stopped_by_time ? "stopped by the time limit" : "";
    log_info("{}: {}", who, solver.summary(ended));
    result.image = comm.root() ? output_image() : solver.image();
    result.work = double(done);
    result.seconds = total.seconds();
    return result;
}

}  // namespace kelvin::fluid
