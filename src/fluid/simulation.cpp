// The shared parameters and run loop of the baseline fluid solvers (see include/kelvin/fluid/simulation.h).
#include <kelvin/core/checkpoint.h>
#include <kelvin/core/distributed.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/memory.h>
#include <kelvin/core/progress.h>
#include <kelvin/core/registry.h>
#include <kelvin/core/stats.h>
#include <kelvin/fluid/output.h>
#include <kelvin/fluid/simulation.h>
#include <kelvin/render/scene.h>

#include <fmt/format.h>

#include <algorithm>
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

SimulationParams SimulationParams::parse(const Properties& props, const std::string& who) {
    SimulationParams p;
    const long long dim = props.get_int("dimension");
    if (dim != 2) props.error("dimension", fmt::format("must be 2 (got {}); {} is a 2D solver", dim, who));
    const Vec3d lo = props.get_point("min"), hi = props.get_point("max");
    if (lo.z != 0) props.error("min", "a 2D domain takes z = 0");
    if (hi.z != 0) props.error("max", "a 2D domain takes z = 0");
    for (double v : {lo.x, lo.y, hi.x, hi.y})
        if (!std::isfinite(v))
            props.error(std::isfinite(lo.x) && std::isfinite(lo.y) ? "max" : "min", "must be finite");
    if (!(hi.x > lo.x) || !(hi.y > lo.y))
        props.error("max", fmt::format("must exceed min in x and y (min = ({:g}, {:g}), max = ({:g}, {:g}))", lo.x,
                                       lo.y, hi.x, hi.y));
    p.domain = {{lo.x, lo.y}, {hi.x, hi.y}, props.get_bool("periodic")};

    const TimeStepping ts = TimeStepping::parse(props);
    p.dt = ts.dt;
    p.steps = ts.steps;
    p.end_time = ts.end_time;
    p.viscosity = props.get_float("viscosity", 0.0, 1e300);
    p.advection = props.get_choice("advection", {"euler", "rk4"}) == "euler" ? Advection::Euler : Advection::RK4;
    p.output_every = props.get_int("output_every", 0, 1LL << 40);
    p.write_png = props.get_bool("write_png");
    p.write_exr = props.get_bool("write_exr");
    p.write_csv = props.get_bool("write_csv");
    p.color_range = props.get_float("color_range", 0.0, 1e300);
    p.frames = FrameStyle::parse(props);

    if (auto obj = props.get_object("vorticity");
        obj && !dynamic_cast<const VorticityField*>(obj.get()) && dynamic_cast<const VorticityField3*>(obj.get()))
        props.error("vorticity", fmt::format("'{}' is a 3D vorticity field; {} is 2D", obj->plugin_name(), who));
    p.field = props.get_object_as<VorticityField>("vorticity");
    auto cache = props.get_object_as<CacheSpec>("cache");
    if (!cache) cache = std::dynamic_pointer_cast<CacheSpec>(Registry::instance().create(Properties("cache", "grid")));
    p.nx = cache->resolution_x();
    const Vec2d size = p.domain.size();
    p.ny = cache->resolution_y() > 0 ? cache->resolution_y()
                                     : int(std::clamp(std::lround(p.nx * size.y / size.x), 2L, 16384L));
    p.field->bind_domain(p.domain);
    p.field->check_domain(p.domain);
    if (auto obj = props.get_object("scalar"); obj && dynamic_cast<const SmokeSpec3*>(obj.get()))
        props.error("scalar",
                    fmt::format("'{}' is 3D smoke (dimension = 3); 2D scenes take a dye", obj->plugin_name()));
    p.dye = props.get_object_as<DyeSpec>("scalar");
    p.sources = RunSources::from(props, p.field->plugin_name(), p.field->strength_parameter());
    // The memory the run will need, before anything is allocated (checks.h: measured per cell).
    check_memory(memory_estimate_2d(who, p.nx, p.ny, bool(p.dye)),
                 fmt::format("{}: a {}x{} grid (parameter 'resolution')", who, p.nx, p.ny), props.location_of("cache"));
    return p;
}

SimulationParams SimulationParams::parse_baseline(const Properties& props, const std::string& who) {
    SimulationParams p = parse(props, who);
    props.get_int("diffusion_samples", 1, 1 << 20);  // mcfluid's n_d: read (validated), not used
    if (props.get_object("velocity"))
        log_info(
            "{}: <velocity> is mcfluid's Monte Carlo estimator; {} computes its velocity itself (only the "
            "estimator's boundaries are used)",
            who, who);
    return p;
}

Checkpoint state_checkpoint(long long steps, double sim_time, const CellGrid2& grid, FieldLookup fields,
                            const VorticityField& field, double viscosity) {
    Checkpoint cp;
    cp.work = double(steps);
    cp.work_unit = "steps";
    cp.sim_time = sim_time;
    cp.grid = grid;
    cp.field = [fields = std::move(fields)](const std::string& name, std::vector<double>& values) {
        const Grid2* g = fields(name);
        if (g) values = g->values();
        return g != nullptr;
    };
    cp.exact = [&field, viscosity](const std::string& name, double t, Vec2d x) -> std::optional<double> {
        if (name == "vorticity") return field.exact_vorticity(t, x, viscosity);
        if (name != "u" && name != "v") return std::nullopt;
        auto v = field.exact_velocity(t, x, viscosity);
        return v ? std::optional<double>(name == "u" ? v->x : v->y) : std::nullopt;
    };
    return cp;
}

FluidDiagnostics grid_diagnostics(const Grid2& omega, const Grid2& u, const Grid2& v) {
    FluidDiagnostics d;
    const double a = omega.cell_area();
    double e = 0, z = 0, c = 0, mx = 0;
    for (std::size_t k = 0; k < omega.cell_count(); ++k) {
        const double uu = u.values()[k], vv = v.values()[k], w = omega.values()[k];
        e += uu * uu + vv * vv;
        z += w * w;
        c += w;
        mx = std::max(mx, std::abs(w));
    }
    d.kinetic_energy = d.kinetic_energy_raw = 0.5 * e * a;
    d.enstrophy = 0.5 * z * a;
    d.circulation = c * a;
    d.max_abs_vorticity = mx;
    return d;
}

std::unique_ptr<FluidSolver> Simulation::create_solver(const RunContext&) const {
    throw InputError({}, fmt::format("simulation '{}' is {}D: use create_solver3", plugin_name(), dimension()));
}

std::unique_ptr<MCFluid3Solver> Simulation::create_solver3(const RunContext&) const {
    throw InputError({}, fmt::format("simulation '{}' is {}D: use create_solver", plugin_name(), dimension()));
}

std::shared_ptr<Simulation> find_simulation(const ObjectPtr& root) {
    if (auto sim = std::dynamic_pointer_cast<Simulation>(root)) return sim;
    if (auto scene = std::dynamic_pointer_cast<Scene>(root)) {
        if (auto sim = std::dynamic_pointer_cast<Simulation>(scene->simulation())) return sim;
        throw InputError({}, scene->simulation() ? fmt::format("the scene's <simulation type=\"{}\"> offers no solver",
                                                               scene->simulation()->plugin_name())
                                                 : std::string("the scene has no <simulation> (it is a render)"));
    }
    throw InputError({}, fmt::format("{} is not a scene or a simulation",
                                     root ? "<" + root->plugin_kind() + " type=\"" + root->plugin_name() + "\">"
                                          : std::string("a null object")));
}

double FluidSolver::vorticity_at(Vec2d x) { return vorticity_grid().sample(x, Interpolation::Bilinear); }

Vec2d FluidSolver::velocity_at(Vec2d x) {
    return {velocity_u().sample(x, Interpolation::Bilinear), velocity_v().sample(x, Interpolation::Bilinear)};
}

FluidDiagnostics FluidSolver::diagnostics() {
    FluidDiagnostics d = grid_diagnostics(vorticity_grid(), velocity_u(), velocity_v());
    d.step = step_index();
    d.time = time();
    return d;
}

RunResult run_fluid_solver(const std::string& who, FluidSolver& solver, const SimulationParams& p, RunContext& ctx,
                           const std::string& effects) {
    check_frames_folder(OutputPaths(ctx.output, who), who);  // before any work
    solver.set_cancel_token(ctx.cancel);                     // the solver's own loops stop with this job
    Timer total;
    // The time limit inside a step: the solver's loops poll the watch's token (checks.h).
    TimeLimitWatch watch(ctx.time_limit);
    solver.set_time_limit_token(watch.token());
    const Vec2d cell = solver.vorticity_grid().h(), size = p.domain.size();
    StepChecks checks(who, p.sources, std::min(cell.x, cell.y), std::min(size.x, size.y));
    const VorticityField& field = *p.field;
    log_info("{}: 2D, domain {}, {}x{} grid, initial {}", who, p.domain.to_string(), p.nx, p.ny, field.description());
    log_info("{}: effects: {}; diffusion {}; stretching off (2D); {}", who, effects,
             p.viscosity > 0 ? fmt::format("on (nu {:g})", p.viscosity) : std::string("off (inviscid)"),
             dye_effect(p.dye.get()));

    OutputPaths paths(ctx.output, who);
    std::optional<DiagnosticsCsv> csv;
    RunResult result;
    result.work_unit = "steps";
    FrameWriter frames(paths, p.output_every, p.write_png, p.write_exr, p.frames, p.steps, result.files_written);
    if (paths.enabled() && p.write_csv) {
        csv.emplace(paths.csv());
        result.files_written.push_back(paths.csv());
    }
    const double range = p.color_range > 0 ? p.color_range : solver.vorticity_grid().max_abs();
    auto image = [&] {
        return field_image(solver.vorticity_grid(), &solver.velocity_u(), &solver.velocity_v(), range);
    };
    auto write_frame = [&] {
        if (frames.enabled())
            frames.write_2d(solver.step_index(), image(), range, nullptr, p.domain.min, p.domain.max, solver.dye());
    };
    auto diagnostics = [&] {
        FluidDiagnostics d = solver.diagnostics();
        d.vorticity_rmse_exact = exact_vorticity_rmse(solver.vorticity_grid(), field, d.time, p.viscosity);
        return d;
    };

    // Checkpoints (core/checkpoint.h), as mcfluid: the state after the steps that reach them, on the output grid.
    CheckpointSchedule checkpoints(ctx);
    auto checkpoint = [&](long long steps) {
        auto fields = [&solver](const std::string& name) -> const Grid2* {
            return name == "vorticity" ? &solver.vorticity_grid()
                   : name == "u"       ? &solver.velocity_u()
                   : name == "v"       ? &solver.velocity_v()
                                       : nullptr;
        };
        Checkpoint cp = state_checkpoint(steps, solver.time(), {p.domain.min, p.domain.max, p.nx, p.ny}, fields, field,
                                         p.viscosity);
        cp.seconds = total.seconds() - checkpoints.overhead();
        cp.image = image;
        checkpoints.reached(ctx, cp);
    };

    // Nothing non-finite reaches the CSV or a frame (checks.h): the initial state is refused as input (exit 2,
    // naming the initial vorticity's strength), a later one stops the run with the earlier steps' outputs (exit 1).
    auto check_state = [&](const FluidDiagnostics& d, uint64_t replaced) {
        const int nx = p.nx;
        const std::string why = checks.state(d.step, diagnostic_values(d),
                                             {{&solver.vorticity_grid().values(), "vorticity", nx, 0},
                                              {&solver.velocity_u().values(), "velocity u", nx, 0},
                                              {&solver.velocity_v().values(), "velocity v", nx, 0}},
                                             replaced, solver.vorticity_grid().cell_count());
        if (why.empty()) return;
        if (csv) csv->close();
        throw RuntimeError(why);
    };
    // The state's CFL number for the step that starts from it; a refused dt keeps the earlier rows.
    auto cfl = [&](long long s) {
        const double dt = TimeStepping{p.dt, p.steps, p.end_time}.step_length(s + 1, solver.time());
        try {
            return checks.cfl(s, max_speed({&solver.velocity_u().values(), &solver.velocity_v().values()}), dt,
                              s == p.steps);
        } catch (...) {
            if (csv && s > 0) csv->close();
            throw;
        }
    };

    const FluidDiagnostics d0 = diagnostics();
    check_state(d0, 0);
    if (csv) csv->write(d0, 0.0, solver.evaluations(), solver.invalid(), cfl(0));
    write_frame();
    if (checkpoints.active()) checkpoint(0);

    ProgressReporter progress(ctx, "Simulating", double(p.steps), "steps", ctx.time_limit);
    Timer since_partial;
    long long done = 0;
    bool stopped_by_time = false;
    for (long long s = 1; s <= p.steps; ++s) {
        if (ctx.cancel.stop_requested()) break;
        const double evals_before = solver.evaluations();
        const uint64_t invalid_before = solver.invalid();
        Timer step_timer;
        const double dt = TimeStepping{p.dt, p.steps, p.end_time}.step_length(s, solver.time());
        if (!solver.step(dt)) break;
        const FluidDiagnostics d = diagnostics();
        check_state(d, solver.invalid() - invalid_before);
        const double c = cfl(s);
        const double seconds = step_timer.seconds();
        if (csv) csv->write(d, seconds, solver.evaluations() - evals_before, solver.invalid() - invalid_before, c);
        ++done;
        if (frames.due(s)) write_frame();
        progress.update(1);
        if (ctx.write_partial > 0 && ctx.write_partial_image && since_partial.seconds() >= ctx.write_partial) {
            ctx.write_partial_image(image());
            since_partial.reset();
        }
        if (checkpoints.active()) {
            checkpoint(done);
            if (ctx.time_limit > 0) watch.set_limit(ctx.time_limit + checkpoints.overhead());
        }
        if (ctx.time_limit > 0 && total.seconds() - checkpoints.overhead() >= ctx.time_limit && s < p.steps) {
            stopped_by_time = true;
            break;
        }
    }
    progress.finish();
    result.interrupted = ctx.cancel.stop_requested();
    // The limit passed inside a step (the watch stopped it; the partial step was discarded): as at a step boundary.
    if (!result.interrupted && done < p.steps && watch.passed()) stopped_by_time = true;
    checks.report(ctx.stats);
    if (csv) csv->close();  // the CSV so far replaces the previous one (interrupted runs included)
    if (stopped_by_time)
        log_warn("{}: time limit of {:g} s reached after {} of {} steps (t = {:g})", who, ctx.time_limit, done, p.steps,
                 solver.time());

    ctx.stats.add("fluid.steps", double(done), "steps");
    ctx.stats.set("fluid.time_simulated", solver.time(), "");
    ctx.stats.add("fluid.cells", double(solver.vorticity_grid().cell_count()), "cells");
    solver.report(ctx.stats);
    frames.finish();
    ctx.stats.add_time("fluid.time.output", frames.seconds());
    report_dye_stats(ctx.stats, solver.dye());
    if (solver.invalid() > 0) log_warn("{}: {} non-finite value(s) were replaced by zero", who, solver.invalid());

    const FluidDiagnostics dn = diagnostics();
    log_info(
        "{}: t = {:g}: energy {:.6g} (initial {:.6g}), enstrophy {:.6g} (initial {:.6g}), circulation {:.6g}, max "
        "|omega| {:.6g}; active effects: advection{}{}",
        who, dn.time, dn.kinetic_energy, d0.kinetic_energy, dn.enstrophy, d0.enstrophy, dn.circulation,
        dn.max_abs_vorticity, p.viscosity > 0 ? ", diffusion" : "", solver.dye() ? ", dye" : "");
    result.image = image();
    result.work = double(done);
    result.seconds = total.seconds();
    return result;
}

}  // namespace kelvin::fluid
