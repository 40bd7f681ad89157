// mcfluid: the 2D Monte Carlo fluid solver of thesis Chapter 5 (cached, Section 5.3.3), run as a Job by
// `kelvin scene.xml`. Every step backtraces each cache cell through a Biot–Savart Monte Carlo velocity
// (Eqs. 5.3, 5.5; Euler Eq. 3.139 or RK4 Eqs. 3.140–3.144) and, when viscous, averages n_d Feynman–Kac
// Gaussian displacements of variance 2 nu dt (Eq. 5.22). The solver is assembled from what the scene
// declares: an inviscid scene never runs the diffusion step; 2D never evaluates stretching.
//
// Outputs, in the run's folder (output.h, OutputPaths: "out/run.exr" -> "out/run/"; a directory D -> "D/mcfluid/"):
//   diagnostics.csv        diagnostics per step (energy, enstrophy, circulation, max |omega|, timings)
//   vorticity_NNNN.png     colour-mapped vorticity every `output_every` steps (and the last step), frame_size
//                          pixels wide, solids and walls drawn
//   fields_NNNN.exr        channels R, G, B (colour map), vorticity, u, v at the cell centres
//   dye_NNNN.png/.exr      the dye, with a <scalar>
//   montage.png, vorticity.mp4 and dye.mp4 (write_video)
// and the final state is returned as the run's image (the CLI writes it to -o). The run's seed is --seed;
// --spp overrides n_mc; --time-limit stops after the step that exceeds it; --write-partial writes the
// current state to -o every N seconds.
//
// Distributed (`mpirun -np N kelvin scene.xml`, 2D and 3D): every pass of a step runs a slab of cache rows (3D: z
// slabs) per rank, and the ranks exchange their slabs before the next pass (the solvers' set_communicator), so every
// rank holds the whole state, bit-identical to one process's, and computes the same diagnostics. The ranks take
// every decision together: a stop on any rank ends the run on all of them at the same step, and the time limit is
// rank 0's clock. Only rank 0 writes files (frames, CSV, montage, video, partial images) and reports progress.
// Checkpoints (kelvin converge) are refused in a distributed run: a study distributes its runs instead.
//
// | parameter         | type    | default   | meaning                                                      |
// |-------------------|---------|-----------|--------------------------------------------------------------|
// | dimension         | integer | 2         | 2, or 3: the Feynman–Kac Navier–Stokes solver (simulation3.h) |
// | min, max          | point   | -1 / 1    | the domain box (2D: z = 0)                                    |
// | periodic          | boolean | false     | periodic box, or open (free space, omega = 0 outside the box) |
// | dt                | float   | 0.05      | time step                                                     |
// | steps             | integer | 0         | number of steps (give steps or end_time)                      |
// | end_time          | float   | 0         | simulated time (the last step is shortened to land on it)     |
// | viscosity         | float   | 0         | nu; 0: inviscid (no diffusion step)                           |
// | diffusion_samples | integer | 1         | n_d, Gaussian displacements per cell and step (Eq. 5.22)      |
// | advection         | string  | rk4       | backtrace: "euler" or "rk4"                                   |
// | output_every      | integer | 0         | write PNG/EXR frames every N steps (0: none)                  |
// | write_png         | boolean | true      | frames as PNG                                                 |
// | write_exr         | boolean | true      | frames as EXR                                                 |
// | write_csv         | boolean | true      | diagnostics CSV                                               |
// | color_range       | float   | 0         | |omega| mapped to full colour; 0: max |omega| at t = 0         |
// | frame_size        | integer | 512       | PNG frames: pixels along the longer side (0: one per cell)    |
// | montage           | boolean | true      | montage.png: up to 8 frames of the run                        |
// | write_video       | boolean | false     | <kind>.mp4 of the PNG frames (ffmpeg on PATH)                 |
// | video_fps         | float   | 24        | the video's frame rate                                        |
// | vdb_slab          | float   | 0         | 2D dye: also dye_NNNN.vdb, the dye as a slab this thick        |
// | stretching        | boolean | true      | 3D: vortex stretching (Eq. 5.21); false only to study it      |
// | control_variates  | boolean | false     | 3D: previous step as control variate (Eq. 5.23)               |
// | initial_samples   | integer | 0         | 3D, control variates: n_mc of the first velocity (0: n_mc)    |
// | control_variate_blend | float | 1       | 3D, control variates: beta in (0, 1]; < 1 mixes in a direct   |
// |                   |         |           | estimate, (1 - beta), so carried errors decay as beta^k       |
// | write_vdb         | boolean | true      | 3D: frames as OpenVDB (vorticity, |vorticity|, velocity)      |
// | slice_axis        | string  | y         | 3D: PNG slice through the centre normal to x, y or z          |
// | (vorticity)       | nested  | required  | initial condition                                             |
// | (velocity)        | nested  | biot_savart | velocity estimator                                          |
// | (cache)           | nested  | grid      | vorticity cache                                               |
// | (scalar)          | nested  | none      | dye advected along the same backtraces (<prefix>_dye_NNNN.*)  |
//
//     <simulation type="mcfluid">
//         <point name="min" x="-3.14159265358979" y="-3.14159265358979"/>
//         <point name="max" x="3.14159265358979" y="3.14159265358979"/>
//         <boolean name="periodic" value="true"/>
//         <float name="dt" value="0.05"/> <float name="end_time" value="1"/>
//         <vorticity type="taylor_green"/>
//         <velocity type="biot_savart"><integer name="samples" value="256"/></velocity>
//         <cache type="grid"><integer name="resolution" value="64"/></cache>
//     </simulation>
#include <kelvin/core/distributed.h>
#include <kelvin/core/error.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/job.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/progress.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/boundary.h>
#include <kelvin/fluid/fields.h>
#include <kelvin/fluid/mcfluid.h>
#include <kelvin/fluid/output.h>
#include <kelvin/fluid/simulation.h>
#include <kelvin/fluid/simulation3.h>
#include <kelvin/fluid/velocity.h>

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <optional>

namespace kelvin::fluid {
namespace {

class MCFluid final : public Simulation {
public:
    explicit MCFluid(const Properties& props) {
        const long long dim = props.get_int("dimension");
        if (dim == 3) {  // the Feynman–Kac Navier–Stokes solver (include/kelvin/fluid/simulation3.h)
            m_3d = std::make_unique<Simulation3Params>(Simulation3Params::parse(props));
            return;
        }
        if (dim != 2) props.error("dimension", fmt::format("must be 2 or 3 (got {})", dim));
        for (const char* name :
             {"stretching", "control_variates", "initial_samples", "control_variate_blend", "write_vdb", "slice_axis"})
            if (props.has(name))
                props.error(name,
                            "is a 3D parameter (dimension = 3); 2D flows have no stretching term, and 2D "
                            "outputs are PNG/EXR frames");
        if (auto obj = props.get_object("vorticity");
            obj && !dynamic_cast<const VorticityField*>(obj.get()) && dynamic_cast<const VorticityField3*>(obj.get()))
            props.error("vorticity",
                        fmt::format("'{}' is a 3D vorticity field; set dimension = 3", obj->plugin_name()));
        // The parameters the baselines share (domain, dt, steps or end_time, viscosity, advection, outputs, the
        // initial vorticity, the grid resolution, the dye): one parser for all 2D solvers.
        const SimulationParams p = SimulationParams::parse(props, "mcfluid");
        m_settings.domain = p.domain;
        m_settings.dt = p.dt;
        m_steps = p.steps;
        m_end_time = p.end_time;
        m_settings.viscosity = p.viscosity;
        m_settings.advection = p.advection;
        m_settings.nx = p.nx;
        m_settings.ny = p.ny;
        m_output_every = p.output_every;
        m_write_png = p.write_png;
        m_write_exr = p.write_exr;
        m_write_csv = p.write_csv;
        m_color_range = p.color_range;
        m_frames = p.frames;
        m_field = p.field;
        m_dye = p.dye;
        m_sources = p.sources;
        m_settings.diffusion_samples = int(props.get_int("diffusion_samples", 1, 1 << 20));
        // The velocity estimator, through its interface only (velocity.h): built-in or a plugin's.
        std::shared_ptr<const VelocityEstimator> velocity;
        if (auto obj = props.get_object("velocity")) {
            velocity = std::dynamic_pointer_cast<const VelocityEstimator>(obj);
            if (!velocity) props.error("velocity", fmt::format("'{}' is not a velocity estimator", obj->plugin_name()));
        } else {
            velocity = std::dynamic_pointer_cast<const VelocityEstimator>(
                Registry::instance().create(Properties("velocity", "biot_savart")));
        }
        if (!velocity->supports(2))
            props.error("velocity", fmt::format("'{}' is a 3D velocity estimator; set dimension = 3 or use a 2D one "
                                                "such as biot_savart or walk_on_spheres",
                                                velocity->plugin_name()));
        auto cache = props.get_object_as<CacheSpec>("cache");
        if (!cache)
            cache = std::dynamic_pointer_cast<CacheSpec>(Registry::instance().create(Properties("cache", "grid")));
        m_velocity_name = velocity->plugin_name();
        m_settings.estimator = velocity;
        m_settings.velocity.samples = velocity->samples();
        m_settings.velocity.delta = velocity->delta();
        if (const std::string why = velocity->check2(m_settings.domain); !why.empty())
            props.error("velocity", velocity->plugin_name() + ": " + why);
        m_settings.boundaries = velocity->boundaries();
        if (m_settings.boundaries)  // solid boundaries: what they leave of the cache
            if (const std::string why =
                    check_wos_cells(*m_settings.boundaries, m_settings.domain, m_settings.nx, m_settings.ny);
                !why.empty())
                props.error("velocity", velocity->plugin_name() + ": " + why);
        m_settings.interpolation = cache->interpolation();
        if (cache->resolution_z() != 0) props.error("cache", "resolution_z is for 3D caches (dimension = 3)");
    }

    std::string description() const override {
        return m_3d ? plugin_name() + " (3D)" : fmt::format("{} (2D, {})", plugin_name(), m_velocity_name);
    }
    /// The passes of both solvers split over ranks (see the header comment).
    bool distributable() const override { return true; }

    // ----- Simulation (simulation.h): what a host drives itself.
    int dimension() const override { return m_3d ? 3 : 2; }
    const VorticityField3* vorticity_field3() const override { return m_3d ? m_3d->field : nullptr; }
    TimeStepping time_stepping() const override {
        if (m_3d) return {m_3d->settings.dt, m_3d->steps, m_3d->end_time};
        return {m_settings.dt, m_steps, m_end_time};
    }
    double viscosity() const override { return m_3d ? m_3d->settings.viscosity : m_settings.viscosity; }
    std::shared_ptr<const VorticityField> vorticity_field() const override { return m_field; }
    std::unique_ptr<FluidSolver> create_solver(const RunContext& ctx) const override {
        if (m_3d) return Simulation::create_solver(ctx);  // the error
        return make_solver(ctx);
    }
    std::unique_ptr<MCFluid3Solver> create_solver3(const RunContext& ctx) const override {
        if (!m_3d) return Simulation::create_solver3(ctx);
        return create_mcfluid3_solver(*m_3d, ctx);
    }

    /// The solver's settings for a run with `ctx`: the scene's, with the run's seed and --spp as n_mc.
    MCFluidSettings settings_for(const RunContext& ctx) const {
        MCFluidSettings settings = m_settings;
        settings.seed = ctx.seed;
        if (ctx.spp > 0) settings.velocity.samples = int(std::min<long long>(ctx.spp, 1 << 24));
        return settings;
    }
    /// The solver run(ctx) steps, at t = 0 (with the dye, ctx.cancel as its token and ctx.comm as its ranks).
    std::unique_ptr<MCFluidSolver> make_solver(const RunContext& ctx) const {
        const MCFluidSettings settings = settings_for(ctx);
        const VorticityField* field = m_field.get();
        auto solver =
            std::make_unique<MCFluidSolver>(settings, [field](const Vec2d& x) { return field->vorticity(x); });
        if (m_dye) solver->set_dye(std::make_unique<PassiveScalars>(settings.domain, *m_dye, settings.nx, settings.ny));
        solver->set_cancel_token(ctx.cancel);
        solver->set_communicator(ctx.comm);
        return solver;
    }

    RunResult run(RunContext& ctx) override {
        if (m_3d) return run_mcfluid3(*m_3d, ctx);
        check_frames_folder(OutputPaths(ctx.output), "mcfluid");  // before any work
        Timer total;
        // The time limit inside a step: the solver's passes poll the watch's token (checks.h).
        TimeLimitWatch watch(ctx.time_limit);
        const MCFluidSettings settings = settings_for(ctx);
        if (ctx.spp > 0)  // --spp: the Monte Carlo sample count of a simulation is n_mc
            log_info("mcfluid: --spp {} overrides the Biot–Savart samples (n_mc)", settings.velocity.samples);
        const VorticityField& field = *m_field;
        const std::unique_ptr<MCFluidSolver> owned = make_solver(ctx);
        MCFluidSolver& solver = *owned;
        solver.set_time_limit_token(watch.token());
        const bool viscous = settings.viscosity > 0;
        const Vec2d cell = solver.vorticity_grid().h(), size = settings.domain.size();
        StepChecks checks("mcfluid", m_sources, std::min(cell.x, cell.y), std::min(size.x, size.y));

        log_info("mcfluid: 2D, domain {}, {}x{} cache ({}), initial {}", settings.domain.to_string(), settings.nx,
                 settings.ny, fluid::to_string(settings.interpolation), field.description());
        const std::string velocity_effect =
            settings.boundaries
                ? fmt::format(
                      "Walk-on-Spheres free-slip velocity ({} gradient samples, antithetic {}, epsilon {:g}, "
                      "max_steps {})",
                      settings.velocity.samples, settings.boundaries->wos.antithetic ? "on" : "off",
                      solver.boundary_field()->settings().epsilon, settings.boundaries->wos.max_steps)
                : settings.estimator->effect(settings.velocity.samples, solver.delta(), settings.domain.periodic);
        log_info(
            "mcfluid: effects: advection ({}, dt {:g}, {} steps) with {}; boundaries {}; diffusion {}; "
            "stretching off (2D); {}",
            fluid::to_string(settings.advection), settings.dt, m_steps, velocity_effect,
            settings.boundaries ? describe(*settings.boundaries, settings.domain) : std::string("none"),
            viscous ? fmt::format("on (nu {:g}, Feynman–Kac, n_d {})", settings.viscosity, settings.diffusion_samples)
                    : std::string("off (inviscid)"),
            dye_effect(m_dye.get()));

        // Only rank 0 writes; the other ranks have no output folder, but take every decision that depends on the
        // outputs (which velocity passes to run) as rank 0 does: `paths` and `csv_wanted` are the same everywhere.
        Communicator& comm = communicator_of(ctx);
        const OutputPaths paths(ctx.output);
        const bool csv_wanted = paths.enabled() && m_write_csv;
        std::optional<DiagnosticsCsv> csv;
        RunResult result;
        result.work_unit = "steps";
        FrameWriter frames(comm.root() ? paths : OutputPaths({}), m_output_every, m_write_png, m_write_exr, m_frames,
                           m_steps, result.files_written);
        if (csv_wanted && comm.root()) {
            csv.emplace(paths.csv());
            result.files_written.push_back(paths.csv());
        }
        const double range = m_color_range > 0 ? m_color_range : solver.vorticity_grid().max_abs();
        // PNG frames draw the solids and the walls of the state's boundaries (moving solids where they are).
        FrameOverlay overlay;
        if (settings.boundaries)
            for (const auto& shape : settings.boundaries->shapes)
                if (shape->role().moving()) overlay.fixed = false;
        auto write_frame = [&](bool uv) {  // uv: the state's velocity channels (estimated if not yet)
            if (!frames.enabled()) return;
            if (const WosVelocityField* b = solver.boundary_field()) {
                overlay.solid = [b](Vec2d x) { return b->solid_at(x) >= 0; };
                overlay.distance = [b](Vec2d x) { return b->distance(x); };
            }
            const Bitmap img = field_image(solver.vorticity_grid(), uv ? &solver.velocity_u() : nullptr,
                                           uv ? &solver.velocity_v() : nullptr, range);
            frames.write_2d(solver.step_index(), img, range, overlay ? &overlay : nullptr, settings.domain.min,
                            settings.domain.max, solver.dye());
        };

        // Checkpoints (core/checkpoint.h): the state after the steps that reach them, fields on the cache grid.
        CheckpointSchedule checkpoints(ctx);
        if (checkpoints.active() && comm.distributed())
            throw RuntimeError(
                "mcfluid: checkpoints are not supported in a distributed job (a convergence study distributes its "
                "runs instead: kelvin converge under mpirun)");
        auto checkpoint = [&](long long steps) {
            auto fields = [&solver](const std::string& name) -> const Grid2* {
                return name == "vorticity" ? &solver.vorticity_grid()
                       : name == "u"       ? &solver.velocity_u()
                       : name == "v"       ? &solver.velocity_v()
                                           : nullptr;
            };
            Checkpoint cp = state_checkpoint(steps, solver.time(),
                                             {settings.domain.min, settings.domain.max, settings.nx, settings.ny},
                                             fields, field, settings.viscosity);
            cp.seconds = total.seconds() - checkpoints.overhead();
            cp.image = [&] {
                return field_image(solver.vorticity_grid(), &solver.velocity_u(), &solver.velocity_v(), range);
            };
            checkpoints.reached(ctx, cp);
        };

        // Nothing non-finite reaches the CSV or a frame: the diagnostics and every field an output carries are checked
        // first (as the float32 EXR stores). The initial state is refused as input (exit 2, naming the initial
        // vorticity's strength); a later one stops the run with the CSV and frames of the earlier steps (exit 1).
        const int nx = settings.nx;
        auto check_state = [&](const FluidDiagnostics& d, bool uv, uint64_t replaced) {
            std::vector<FieldValues> fields = {{&solver.vorticity_grid().values(), "vorticity", nx, 0}};
            if (uv) {
                fields.push_back({&solver.velocity_u().values(), "velocity u", nx, 0});
                fields.push_back({&solver.velocity_v().values(), "velocity v", nx, 0});
            }
            const std::string why =
                checks.state(d.step, diagnostic_values(d, uv), fields, replaced, solver.vorticity_grid().cell_count());
            if (why.empty()) return;
            if (csv) csv->close();
            throw RuntimeError(why);
        };
        // The state's CFL number for the step that starts from it (checks.h); a refused dt keeps the earlier rows.
        auto cfl = [&](long long s) {
            const double dt = time_stepping().step_length(s + 1, solver.time());
            try {
                return checks.cfl(s, max_speed({&solver.velocity_u().values(), &solver.velocity_v().values()}), dt,
                                  s == m_steps);
            } catch (...) {
                if (csv && s > 0) csv->close();
                throw;
            }
        };

        // State 0: its velocity is the first step's k1, so diagnostics cost nothing extra. An interrupt during
        // that first velocity pass leaves nothing to record.
        FluidDiagnostics d0 = solver.diagnostics();
        d0.vorticity_rmse_exact =
            exact_vorticity_rmse(solver.vorticity_grid(), field, 0.0, settings.viscosity, bool(settings.boundaries));
        if (solver.velocity_available()) {
            check_state(d0, true, solver.work().invalid_velocity + solver.work().invalid_vorticity);
            const double cfl0 = cfl(0);
            if (csv)
                csv->write(d0, 0.0, double(solver.work().biot_savart_evals),
                           solver.work().invalid_velocity + solver.work().invalid_vorticity, cfl0);
            write_frame(true);
            if (checkpoints.active()) checkpoint(0);
        } else {  // stopped during that pass: the vorticity is still the image
            check_state(d0, false, 0);
        }

        // The last state's velocity is estimated only when an output needs it (issue 16, item 7): the CSV (its
        // energies), a checkpoint, an EXR result or frame (u and v channels), partial images, or a host that
        // takes the image itself (no output path). Otherwise a run of n steps does n velocity passes, not n + 1.
        std::string ext = ctx.output.extension().string();
        std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char ch) { return char(std::tolower(ch)); });
        auto velocity_needed_at = [&](long long s) {
            if (s < m_steps || csv_wanted || checkpoints.active() || ctx.write_partial > 0 || ctx.output.empty() ||
                ext == ".exr")
                return true;
            const bool frame = paths.enabled() && m_output_every > 0;
            return frame && m_write_exr;
        };
        bool final_without_velocity = false;
        ProgressReporter progress(ctx, "Simulating", double(m_steps), "steps", ctx.time_limit);
        Timer since_partial;
        long long done = 0;
        bool stopped_by_time = false;
        for (long long s = 1; s <= m_steps; ++s) {
            if (any_rank(comm, ctx.cancel.stop_requested())) break;
            const FluidWork before = solver.work();
            Timer step_timer;
            const double dt = time_stepping().step_length(s, solver.time());
            if (!solver.step(dt)) break;
            ++done;
            if (!velocity_needed_at(s)) {  // the final state, vorticity only
                const FluidDiagnostics d = solver.diagnostics(false);
                const FluidWork& after = solver.work();
                check_state(d, false,
                            (after.invalid_velocity + after.invalid_vorticity) -
                                (before.invalid_velocity + before.invalid_vorticity));
                if (m_output_every > 0) write_frame(false);
                final_without_velocity = true;
                progress.update(1);
                break;
            }
            // The new state's velocity: diagnostics now, k1 of the next step later (computed once). An
            // interrupt during its pass ends the run with the new state and no velocity.
            FluidDiagnostics d = solver.diagnostics();
            if (!solver.velocity_available()) break;
            d.vorticity_rmse_exact = exact_vorticity_rmse(solver.vorticity_grid(), field, d.time, settings.viscosity,
                                                          bool(settings.boundaries));
            const FluidWork& after = solver.work();
            const uint64_t replaced = (after.invalid_velocity + after.invalid_vorticity) -
                                      (before.invalid_velocity + before.invalid_vorticity);
            check_state(d, true, replaced);
            const double c = cfl(s);
            const double seconds = step_timer.seconds();
            if (csv) csv->write(d, seconds, double(after.biot_savart_evals - before.biot_savart_evals), replaced, c);
            if (frames.due(s)) write_frame(true);
            progress.update(1);
            if (comm.root() && ctx.write_partial > 0 && ctx.write_partial_image &&
                since_partial.seconds() >= ctx.write_partial) {
                ctx.write_partial_image(
                    field_image(solver.vorticity_grid(), &solver.velocity_u(), &solver.velocity_v(), range));
                since_partial.reset();
            }
            if (checkpoints.active()) {
                checkpoint(done);
                if (ctx.time_limit > 0) watch.set_limit(ctx.time_limit + checkpoints.overhead());
            }
            if (s < m_steps && time_limit_reached(comm, ctx.time_limit, total.seconds() - checkpoints.overhead())) {
                stopped_by_time = true;
                break;
            }
        }
        progress.finish();
        result.interrupted = any_rank(comm, ctx.cancel.stop_requested());
        // The limit passed inside a step (the watch stopped it; the partial step was discarded): as at a step
        // boundary.
        if (!result.interrupted && done < m_steps && any_rank(comm, watch.passed())) stopped_by_time = true;
        checks.report(ctx.stats);
        if (stopped_by_time)
            log_warn("mcfluid: time limit of {:g} s reached after {} of {} steps (t = {:g})", ctx.time_limit, done,
                     m_steps, solver.time());

        const FluidWork& w = solver.work();
        report_fluid_work(ctx.stats, done, solver.time(), solver.vorticity_grid().cell_count(), w);
        report_walks(ctx.stats, "fluid.wos_",
                     {w.wos_walks, w.wos_steps, w.wos_truncated, w.wos_invalid, w.wos_boundary_queries}, "mcfluid",
                     settings.boundaries ? settings.boundaries->wos.max_steps : 0);
        ctx.stats.add("fluid.solid_departures", double(w.solid_departures), "points");
        frames.finish();
        ctx.stats.add_time("fluid.time.output", frames.seconds());
        report_dye_stats(ctx.stats, solver.dye());
        if (w.invalid_velocity + w.invalid_vorticity > 0)
            log_warn(
                "mcfluid: {} non-finite velocity estimate(s) and {} non-finite vorticity value(s) were replaced "
                "by zero",
                w.invalid_velocity, w.invalid_vorticity);

        if (csv) csv->close();  // the CSV so far replaces the previous one (interrupted runs included)
        if (final_without_velocity) {
            const FluidDiagnostics dn = solver.diagnostics(false);
            log_info(
                "mcfluid: t = {:g}: enstrophy {:.6g} (initial {:.6g}), circulation {:.6g}, max |omega| {:.6g} (the "
                "final state's velocity and energy were not estimated: no output needs them; the CSV or an .exr "
                "output does); active effects: advection{}{}",
                dn.time, dn.enstrophy, d0.enstrophy, dn.circulation, dn.max_abs_vorticity, viscous ? ", diffusion" : "",
                m_dye ? ", dye" : "");
            result.image = field_image(solver.vorticity_grid(), nullptr, nullptr, range);
        } else if (solver.velocity_available()) {
            const FluidDiagnostics dn = solver.diagnostics();
            log_info(
                "mcfluid: t = {:g}: energy noise-corrected {:.6g}, raw {:.6g} (initial {:.6g}, {:.6g}), enstrophy "
                "{:.6g} (initial {:.6g}), circulation {:.6g}, max |omega| {:.6g}; active effects: advection{}{}",
                dn.time, dn.kinetic_energy, dn.kinetic_energy_raw, d0.kinetic_energy, d0.kinetic_energy_raw,
                dn.enstrophy, d0.enstrophy, dn.circulation, dn.max_abs_vorticity, viscous ? ", diffusion" : "",
                m_dye ? ", dye" : "");
            result.image = field_image(solver.vorticity_grid(), &solver.velocity_u(), &solver.velocity_v(), range);
        } else {  // interrupted (or out of time) while estimating the velocity: the vorticity channels only
            log_info(
                "mcfluid: {} at t = {:g} before the velocity of that state was estimated; the image has no u and v "
                "channels",
                result.interrupted ? "interrupted" : "stopped by the time limit", solver.time());
            result.image = field_image(solver.vorticity_grid(), nullptr, nullptr, range);
        }
        result.work = double(done);
        result.seconds = total.seconds();
        return result;
    }

private:
    MCFluidSettings m_settings;
    long long m_steps = 0;
    double m_end_time = 0;
    long long m_output_every = 0;
    bool m_write_png = true, m_write_exr = true, m_write_csv = true;
    double m_color_range = 0;
    FrameStyle m_frames;
    std::shared_ptr<VorticityField> m_field;
    std::shared_ptr<DyeSpec> m_dye;
    RunSources m_sources;
    std::unique_ptr<Simulation3Params> m_3d;  ///< dimension = 3
    std::string m_velocity_name;              ///< the velocity estimator plugin (2D)
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(kelvin::fluid::MCFluid, "simulation", "mcfluid",
              "2D Monte Carlo fluid solver (thesis Ch. 5): cached Biot–Savart MC velocity, semi-Lagrangian vorticity "
              "advection, Feynman–Kac viscosity.",
              kelvin::param::integer("dimension", 2, "2, or 3 (Feynman–Kac Navier–Stokes with stretching)"),
              kelvin::param::point("min", kelvin::Vec3d(-1.0, -1.0, 0.0), "domain box corner (2D: z = 0)"),
              kelvin::param::point("max", kelvin::Vec3d(1.0, 1.0, 0.0), "domain box corner (2D: z = 0)"),
              kelvin::param::boolean("periodic", false, "periodic box (true) or open free space (false)"),
              kelvin::param::real("dt", 0.05, "time step"),
              kelvin::param::integer("steps", 0, "number of steps (or give end_time)"),
              kelvin::param::real("end_time", 0.0, "simulated time (or give steps)"),
              kelvin::param::real("viscosity", 0.0, "kinematic viscosity nu (0: inviscid, no diffusion step)"),
              kelvin::param::integer("diffusion_samples", 1, "n_d, Feynman–Kac samples per cell and step"),
              kelvin::param::string("advection", "rk4", "'euler' or 'rk4' semi-Lagrangian backtrace"),
              kelvin::param::integer("output_every", 0, "write PNG/EXR frames every N steps (0: none)"),
              kelvin::param::boolean("write_png", true, "write frames as PNG (colour-mapped vorticity)"),
              kelvin::param::boolean("write_exr", true, "write frames as EXR (vorticity, u, v channels)"),
              kelvin::param::boolean("write_csv", true, "write diagnostics.csv, one row per step"),
              kelvin::param::real("color_range", 0.0, "|omega| mapped to full colour (0: max at t = 0)"),
              KELVIN_FRAME_STYLE_PARAMS,
              kelvin::param::boolean("stretching", true, "3D: vortex stretching (Eq. 5.21); off only to study it"),
              kelvin::param::boolean("control_variates", false, "3D: previous step as control variate (Eq. 5.23)"),
              kelvin::param::integer("initial_samples", 0, "3D with control variates: n_mc of the first velocity"),
              kelvin::param::real("control_variate_blend", 1.0,
                                  "3D with control variates: beta in (0, 1]; below 1 a direct estimate of weight "
                                  "1 - beta is mixed in (n_mc more samples)"),
              kelvin::param::boolean("write_vdb", true, "3D: write frames as OpenVDB files"),
              kelvin::param::string("slice_axis", "y", "3D: PNG slices normal to 'x', 'y' or 'z'"),
              kelvin::param::object("vorticity", "vorticity", "initial vorticity field", true),
              kelvin::param::object("velocity", "velocity", "velocity estimator (default biot_savart)"),
              kelvin::param::object("cache", "cache", "vorticity cache (default grid)"),
              kelvin::param::object("scalar", "scalar", "passive scalar (dye) advected with the flow (optional)"));
