// mcfluid in 3D: parameters, run loop and outputs (see include/kelvin/fluid/simulation3.h).
#include <kelvin/core/distributed.h>
#include <kelvin/core/error.h>
#include <kelvin/core/files.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/memory.h>
#include <kelvin/core/progress.h>
#include <kelvin/core/registry.h>
#include <kelvin/core/stats.h>
#include <kelvin/core/vdb.h>
#include <kelvin/fluid/boundary.h>
#include <kelvin/fluid/output.h>
#include <kelvin/fluid/simulation.h>
#include <kelvin/fluid/simulation3.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <mutex>
#include <string>

namespace kelvin::fluid {

Simulation3Params Simulation3Params::parse(const Properties& props) {
    Simulation3Params p;
    MCFluid3Settings& s = p.settings;
    const Vec3d lo = props.get_point("min"), hi = props.get_point("max");
    for (int a = 0; a < 3; ++a) {
        if (!std::isfinite(lo[a])) props.error("min", "must be finite");
        if (!std::isfinite(hi[a])) props.error("max", "must be finite");
    }
    if (!(hi.x > lo.x) || !(hi.y > lo.y) || !(hi.z > lo.z))
        props.error("max", fmt::format("must exceed min in x, y and z (a 3D domain; min = ({:g}, {:g}, {:g}), max = "
                                       "({:g}, {:g}, {:g}))",
                                       lo.x, lo.y, lo.z, hi.x, hi.y, hi.z));
    s.domain = {lo, hi, props.get_bool("periodic")};
    if (s.domain.periodic) {
        // The periodic Biot–Savart kernel (an Ewald sum, biot_savart3.h) is tabulated for boxes whose sides differ by
        // at most 8x.
        const Vec3d size = hi - lo;
        const double ratio = std::max({size.x, size.y, size.z}) / std::min({size.x, size.y, size.z});
        if (!(ratio <= 8))
            props.error("max", fmt::format("a periodic box's sides may differ by at most 8x; these differ by {:.3g}x "
                                           "({:g} x {:g} x {:g})",
                                           ratio, size.x, size.y, size.z));
    }
    const TimeStepping ts = TimeStepping::parse(props);
    s.dt = ts.dt;
    p.steps = ts.steps;
    p.end_time = ts.end_time;
    s.viscosity = props.get_float("viscosity", 0.0, 1e300);
    s.diffusion_samples = int(props.get_int("diffusion_samples", 1, 1 << 20));
    s.advection = props.get_choice("advection", {"euler", "rk4"}) == "euler" ? Advection::Euler : Advection::RK4;
    s.stretching = props.get_bool("stretching");
    s.control_variates = props.get_bool("control_variates");
    s.initial_samples = int(props.get_int("initial_samples", 0, 1 << 24));
    s.control_variate_blend = props.get_float("control_variate_blend", 1e-6, 1.0);
    if (s.initial_samples > 0 && !s.control_variates)
        log_info(
            "mcfluid: initial_samples = {} is the control variates' initial sample count; control_variates is "
            "off, so every velocity pass uses n_mc",
            s.initial_samples);
    if (s.control_variate_blend < 1 && !s.control_variates)
        log_info(
            "mcfluid: control_variate_blend = {:g} blends the control variate; control_variates is off, so it "
            "has no effect",
            s.control_variate_blend);
    p.output_every = props.get_int("output_every", 0, 1LL << 40);
    p.write_png = props.get_bool("write_png");
    p.write_vdb = props.get_bool("write_vdb");
    p.write_csv = props.get_bool("write_csv");
    if (props.has("write_exr") && props.get_bool("write_exr"))
        props.error("write_exr", "3D frames are OpenVDB files (write_vdb) and PNG slices (write_png); set it false");
    p.color_range = props.get_float("color_range", 0.0, 1e300);
    p.frames = FrameStyle::parse(props);
    if (p.frames.dye_slab > 0)
        props.error("vdb_slab", "is for a 2D dye; 3D runs write the smoke's `density` grid in their fields_NNNN.vdb");
    const std::string axis = props.get_choice("slice_axis", {"x", "y", "z"});
    p.slice_axis = axis == "x" ? 0 : (axis == "y" ? 1 : 2);

    ObjectPtr obj = props.get_object("vorticity");
    p.field = dynamic_cast<const VorticityField3*>(obj.get());
    if (!p.field)
        props.error("vorticity",
                    fmt::format("'{}' is a 2D vorticity field; a dimension = 3 scene needs a 3D one (vortex_ring, abc, "
                                "taylor_green)",
                                obj ? obj->plugin_name() : std::string("?")));
    p.field_object = obj;

    // The estimator, through its interface only (velocity.h); default biot_savart.
    if (auto obj = props.get_object("velocity")) {
        auto velocity = std::dynamic_pointer_cast<const VelocityEstimator>(obj);
        if (!velocity) props.error("velocity", fmt::format("'{}' is not a velocity estimator", obj->plugin_name()));
        if (!velocity->supports(3))
            props.error("velocity",
                        fmt::format("'{}' is not available in 3D (a 2D velocity estimator); use a 3D one such as "
                                    "biot_savart or walk_on_spheres",
                                    velocity->plugin_name()));
        s.estimator = velocity;
    } else {
        s.estimator = std::dynamic_pointer_cast<const VelocityEstimator>(
            Registry::instance().create(Properties("velocity", "biot_savart")));
    }
    s.velocity.samples = s.estimator->samples();
    s.velocity.delta = s.estimator->delta();
    s.boundaries = s.estimator->boundaries();
    if (const std::string why = s.estimator->check3(s.domain); !why.empty()) props.error("velocity", why);
    auto cache = props.get_object_as<CacheSpec>("cache");
    if (!cache) cache = std::dynamic_pointer_cast<CacheSpec>(Registry::instance().create(Properties("cache", "grid")));
    const Vec3d size = s.domain.size();
    s.nx = cache->resolution_x();
    auto cubic = [&](double len) { return int(std::clamp(std::lround(s.nx * len / size.x), 2L, 1024L)); };
    s.ny = cache->resolution_y() > 0 ? cache->resolution_y() : cubic(size.y);
    s.nz = cache->resolution_z() > 0 ? cache->resolution_z() : cubic(size.z);
    if (s.nx > BiotSavartEstimator3::MaxResolution || s.ny > BiotSavartEstimator3::MaxResolution ||
        s.nz > BiotSavartEstimator3::MaxResolution)
        props.error("cache", fmt::format("3D caches are limited to {} cells per axis (got {}x{}x{})",
                                         BiotSavartEstimator3::MaxResolution, s.nx, s.ny, s.nz));
    s.interpolation = cache->interpolation();
    if (auto scalar = props.get_object("scalar")) {
        p.smoke = std::dynamic_pointer_cast<SmokeSpec3>(scalar);
        if (!p.smoke)
            props.error("scalar",
                        fmt::format("'{}' is a 2D dye; 3D scenes take <scalar type=\"smoke\">", scalar->plugin_name()));
    }
    if (s.boundaries)
        if (const std::string why = check_wos_cells3(*s.boundaries, s.domain, s.nx, s.ny, s.nz); !why.empty())
            props.error("velocity", "walk_on_spheres: " + why);
    p.field->check_domain3(s.domain);
    p.sources = RunSources::from(props, obj->plugin_name(), p.field->strength_parameter3());
    // The memory the run will need, before anything is allocated (checks.h: measured per cell).
    check_memory(memory_estimate_3d(s.nx, s.ny, s.nz, s.control_variates, bool(p.smoke), bool(s.boundaries),
                                    p.write_vdb && p.output_every > 0),
                 fmt::format("mcfluid: a {}x{}x{} cache (parameter 'resolution')", s.nx, s.ny, s.nz),
                 props.location_of("cache"));
    return p;
}

// ------------------------------------------------------------------------------------------------
// Outputs.

namespace {
// The backstop of every VDB write (as write_image's for images): OpenVDB stores float32, so a double beyond
// 3.4e38 would be written as inf. The solvers' own checks (checks.h) stop a run before it gets here.
void refuse_unstorable(const std::filesystem::path& path, const Grid3& g, const std::string& name) {
    const std::vector<double>& v = g.values();
    std::size_t bad = 0, first = 0;
    for (std::size_t k = 0; k < v.size(); ++k)
        if (!(std::abs(v[k]) <= FloatMax) && bad++ == 0) first = k;
    if (bad == 0) return;
    const std::size_t nx = std::size_t(g.nx()), ny = std::size_t(g.ny());
    throw_runtime(
        "not writing '{}': grid '{}' is {:g} at voxel ({}, {}, {}); {} value(s) are not finite as 32-bit floats "
        "(numerical trouble is never written into an output)",
        path.string(), name, v[first], first % nx, (first / nx) % ny, first / (nx * ny), bad);
}
}  // namespace

void write_vdb_frame(const std::filesystem::path& path, const VectorGrid3& vorticity, const VectorGrid3* velocity,
                     const Grid3* density) {
    refuse_unstorable(path, vorticity.x, "vorticity x");
    refuse_unstorable(path, vorticity.y, "vorticity y");
    refuse_unstorable(path, vorticity.z, "vorticity z");
    // |vorticity| is stored too: finite components can still have a magnitude beyond float32.
    for (std::size_t c = 0; c < vorticity.cell_count(); ++c)
        if (const double m = glm::length(vorticity.at(c)); !(m <= FloatMax)) {
            const std::size_t nx = std::size_t(vorticity.x.nx()), ny = std::size_t(vorticity.x.ny());
            throw_runtime(
                "not writing '{}': grid 'vorticity_magnitude' is {:g} at voxel ({}, {}, {}), not finite as a 32-bit "
                "float (numerical trouble is never written into an output)",
                path.string(), m, c % nx, (c / nx) % ny, c / (nx * ny));
        }
    if (velocity) {
        refuse_unstorable(path, velocity->x, "velocity x");
        refuse_unstorable(path, velocity->y, "velocity y");
        refuse_unstorable(path, velocity->z, "velocity z");
    }
    if (density) refuse_unstorable(path, *density, "density");
    // OpenVDB (core/vdb.h, loaded on first use): |vorticity|, density, vorticity, velocity, in this order.
    std::vector<double> magnitude(vorticity.cell_count());
    for (std::size_t c = 0; c < magnitude.size(); ++c) magnitude[c] = glm::length(vorticity.at(c));
    std::vector<VdbGridData> data{{"vorticity_magnitude", vdb_lattice(vorticity.x), magnitude.data()}};
    if (density) data.push_back(vdb_grid("density", *density));
    data.push_back(vdb_grid("vorticity", vorticity));
    if (velocity) data.push_back(vdb_grid("velocity", *velocity));
    write_vdb(path, data);
}

void write_vdb_grids(const std::filesystem::path& path,
                     const std::vector<std::pair<std::string, const Grid3*>>& grids) {
    for (const auto& [name, grid] : grids)
        if (grid) refuse_unstorable(path, *grid, name);
    std::vector<VdbGridData> data;
    for (const auto& [name, grid] : grids) data.push_back(vdb_grid(name, *grid));
    write_vdb(path, data);
}

Bitmap slice_image(const VectorGrid3& field, int axis, double range) {
    const Grid3& g = field.x;
    const Grid3& comp = axis == 0 ? field.x : (axis == 1 ? field.y : field.z);
    // Image axes: (u, v) = (y, z) for axis x, (x, z) for axis y, (x, y) for axis z.
    const int ua = axis == 0 ? 1 : 0, va = axis == 2 ? 1 : 2;
    const int n[3] = {g.nx(), g.ny(), g.nz()};
    const int width = n[ua], height = n[va];
    const int mid = n[axis] / 2;
    if (!(range > 0)) range = comp.max_abs();
    if (!(range > 0)) range = 1;
    Bitmap img(width, height, {"R", "G", "B", "value"});
    for (int row = 0; row < height; ++row)
        for (int col = 0; col < width; ++col) {
            int c[3];
            c[axis] = mid;
            c[ua] = col;
            c[va] = height - 1 - row;
            const double w = comp.at(c[0], c[1], c[2]);
            const Color3 rgb = diverging_colormap(w / range);
            img.at(col, row, 0) = float(srgb_to_linear(rgb.r));
            img.at(col, row, 1) = float(srgb_to_linear(rgb.g));
            img.at(col, row, 2) = float(srgb_to_linear(rgb.b));
            img.at(col, row, 3) = float(w);
        }
    return img;
}

// ------------------------------------------------------------------------------------------------
// Run loop.

namespace {
// The solver's settings for a run with `ctx`: the scene's, with the run's seed and --spp as n_mc.
MCFluid3Settings settings_for(const Simulation3Params& p, const RunContext& ctx) {
    MCFluid3Settings settings = p.settings;
    settings.seed = ctx.seed;
    if (ctx.spp > 0) settings.velocity.samples = int(std::min<long long>(ctx.spp, 1 << 24));
    return settings;
}
}  // namespace

std::unique_ptr<MCFluid3Solver> create_mcfluid3_solver(const Simulation3Params& p, const RunContext& ctx) {
    const VorticityField3* field = p.field;
    auto solver = std::make_unique<MCFluid3Solver>(settings_for(p, ctx),
                                                   [field](const Vec3d& x) { return field->vorticity3(x); });
    if (p.smoke) solver->set_smoke({p.smoke->center(), p.smoke->radius(), p.smoke->initial_density(), p.smoke->rate()});
    solver->set_cancel_token(ctx.cancel);
    solver->set_communicator(ctx.comm);
    return solver;
}

RunResult run_mcfluid3(const Simulation3Params& p, RunContext& ctx) {
    check_frames_folder(OutputPaths(ctx.output), "mcfluid");  // before any work
    Timer total;
    // The time limit inside a step: the solver's passes poll the watch's token (checks.h).
    TimeLimitWatch watch(ctx.time_limit);
    const MCFluid3Settings settings = settings_for(p, ctx);
    if (ctx.spp > 0) log_info("mcfluid: --spp {} overrides the Biot–Savart samples (n_mc)", settings.velocity.samples);
    const VorticityField3& field = *p.field;
    const std::unique_ptr<MCFluid3Solver> owned = create_mcfluid3_solver(p, ctx);
    MCFluid3Solver& solver = *owned;
    solver.set_time_limit_token(watch.token());
    const bool viscous = settings.viscosity > 0;
    const Vec3d cell = solver.vorticity_grid().x.h(), size = settings.domain.size();
    StepChecks checks("mcfluid", p.sources, std::min({cell.x, cell.y, cell.z}), std::min({size.x, size.y, size.z}));
    log_info("mcfluid: 3D, domain {}, {}x{}x{} cache ({}), initial {}", settings.domain.to_string(), settings.nx,
             settings.ny, settings.nz, settings.interpolation == Interpolation::Nearest ? "nearest" : "trilinear",
             field.description3());
    const std::string velocity =
        settings.boundaries
            ? fmt::format(
                  "free-slip Walk-on-Spheres velocity on the vector potential ({} gradient samples, max {} "
                  "steps, {} volume sampling)",
                  settings.velocity.samples, settings.boundaries->wos.max_steps,
                  settings.boundaries->vorticity_importance ? "|omega|-mixed" : "Green's-function")
            : settings.estimator->effect(settings.velocity.samples, solver.delta(), settings.domain.periodic);
    log_info(
        "mcfluid: effects: advection ({}, dt {:g}, {} steps) with {}; stretching {}; diffusion {}; control variates "
        "{}; boundaries {}; smoke {}",
        fluid::to_string(settings.advection), settings.dt, p.steps, velocity,
        settings.stretching ? fmt::format("on (vortex segments, h = {:g})", solver.segment_length())
                            : std::string("OFF (requested; the 3D equations need it)"),
        viscous ? fmt::format("on (nu {:g}, Feynman–Kac, n_d {})", settings.viscosity, settings.diffusion_samples)
                : std::string("off (inviscid)"),
        settings.control_variates
            ? fmt::format("on (initial samples {}{})",
                          settings.initial_samples > 0 ? settings.initial_samples : settings.velocity.samples,
                          settings.control_variate_blend < 1
                              ? fmt::format(", blend {:g}", settings.control_variate_blend)
                              : std::string())
            : std::string("off"),
        settings.boundaries ? describe3(*settings.boundaries, settings.domain) : std::string("none"),
        p.smoke ? p.smoke->description() : std::string("none"));

    // Distributed: every rank steps the whole state (the solver's passes are collectives) and takes the same
    // decisions; only rank 0 writes files and reports progress.
    Communicator& comm = communicator_of(ctx);
    const OutputPaths paths(ctx.output);
    RunResult result;
    result.work_unit = "steps";
    // The data frames are the .vdb files (the EXR role of 2D).
    FrameWriter frames(comm.root() ? paths : OutputPaths({}), p.output_every, p.write_png, p.write_vdb, p.frames,
                       p.steps, result.files_written);
    std::string csv =
        "step,time,kinetic_energy,kinetic_energy_raw,enstrophy,helicity,impulse_x,impulse_y,impulse_z,centroid_x,"
        "centroid_y,centroid_z,max_abs_vorticity,divergence_rms,smoke_mass,step_seconds,biot_savart_evals,invalid,"
        "cfl\n";
    auto add_row = [&](const FluidDiagnostics3& d, double seconds, double evals, uint64_t invalid, double cfl) {
        csv += fmt::format(
            "{},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},"
            "{:.9g},{:.6g},{:.0f},{},{:.6g}\n",
            d.step, d.time, d.kinetic_energy, d.kinetic_energy_raw, d.enstrophy, d.helicity, d.impulse.x, d.impulse.y,
            d.impulse.z, d.centroid.x, d.centroid.y, d.centroid.z, d.max_abs_vorticity, d.divergence_rms, d.smoke_mass,
            seconds, evals, invalid, cfl);
    };
    auto save_csv = [&] {  // at the end of the run, or before a stop (the rows of the steps before it)
        if (paths.enabled() && p.write_csv && comm.root()) {
            write_text_atomically(paths.csv(), csv);
            result.files_written.push_back(paths.csv());
        }
    };
    const int axis = p.slice_axis;
    const VectorGrid3& omega0 = solver.vorticity_grid();
    const double range =
        p.color_range > 0 ? p.color_range : (axis == 0 ? omega0.x : (axis == 1 ? omega0.y : omega0.z)).max_abs();
    auto write_frame = [&]() {
        if (!frames.enabled()) return;
        if (p.write_vdb)
            frames.write_data("fields", solver.step_index(), ".vdb", [&](const std::filesystem::path& path) {
                write_vdb_frame(path, solver.vorticity_grid(), &solver.velocity_grid(), solver.smoke());
            });
        frames.write_png("vorticity", solver.step_index(), slice_image(solver.vorticity_grid(), axis, range), "value",
                         range, {0, 0}, {1, 1});
    };

    // Nothing non-finite reaches the CSV or a frame: diagnostics and every grid an output carries are checked first
    // (as the float32 the VDB frames store). The initial state is refused as input (exit 2, naming the initial
    // vorticity's strength); a later one stops the run with the CSV of the earlier steps (exit 1).
    auto refuse = [&](const FluidDiagnostics3& d, uint64_t replaced) {
        const VectorGrid3& w = solver.vorticity_grid();
        const int nx = w.x.nx(), ny = w.x.ny();
        std::vector<FieldValues> fields = {{&w.x.values(), "vorticity x", nx, ny},
                                           {&w.y.values(), "vorticity y", nx, ny},
                                           {&w.z.values(), "vorticity z", nx, ny}};
        if (solver.velocity_available()) {
            const VectorGrid3& u = solver.velocity_grid();
            fields.push_back({&u.x.values(), "velocity x", nx, ny});
            fields.push_back({&u.y.values(), "velocity y", nx, ny});
            fields.push_back({&u.z.values(), "velocity z", nx, ny});
        }
        if (solver.smoke()) fields.push_back({&solver.smoke()->values(), "smoke density", nx, ny});
        const std::string why = checks.state(d.step,
                                             {{d.kinetic_energy, "kinetic energy"},
                                              {d.kinetic_energy_raw, "raw kinetic energy"},
                                              {d.enstrophy, "enstrophy"},
                                              {d.helicity, "helicity"},
                                              {d.impulse.x, "impulse x"},
                                              {d.impulse.y, "impulse y"},
                                              {d.impulse.z, "impulse z"},
                                              {d.max_abs_vorticity, "max |vorticity|"},
                                              {d.divergence_rms, "divergence RMS"},
                                              {d.smoke_mass, "smoke mass"}},
                                             fields, replaced, w.cell_count());
        if (why.empty()) return;
        save_csv();
        throw RuntimeError(why);
    };
    // The state's CFL number for the step that starts from it (0 without a velocity).
    auto cfl = [&](long long step) {
        if (!solver.velocity_available()) return 0.0;
        const VectorGrid3& u = solver.velocity_grid();
        const double dt = TimeStepping{settings.dt, p.steps, p.end_time}.step_length(step + 1, solver.time());
        try {
            return checks.cfl(step, max_speed({&u.x.values(), &u.y.values(), &u.z.values()}), dt, step == p.steps);
        } catch (...) {  // a refused dt mid-run: the CSV of the steps before it is kept
            if (step > 0) save_csv();
            throw;
        }
    };
    // Checkpoints (core/checkpoint.h, `kelvin converge`): the state after the steps that reach them, the vorticity
    // and velocity components on the cache grid, the field's exact solution where it has one (abc).
    CheckpointSchedule checkpoints(ctx);
    if (checkpoints.active() && comm.distributed())
        throw RuntimeError(
            "mcfluid: checkpoints are not supported in a distributed job (a convergence study distributes its runs "
            "instead: kelvin converge under mpirun)");
    auto checkpoint = [&](long long steps) {
        Checkpoint cp;
        cp.work = double(steps);
        cp.work_unit = "steps";
        cp.sim_time = solver.time();
        cp.dimension = 3;
        cp.grid3 = {settings.domain.min, settings.domain.max, settings.nx, settings.ny, settings.nz};
        cp.field = [&solver](const std::string& name, std::vector<double>& values) {
            const VectorGrid3& w = solver.vorticity_grid();
            const Grid3* g = name == "vorticity_x"   ? &w.x
                             : name == "vorticity_y" ? &w.y
                             : name == "vorticity_z" ? &w.z
                                                     : nullptr;
            if (!g && solver.velocity_available()) {
                const VectorGrid3& u = solver.velocity_grid();
                g = name == "u" ? &u.x : name == "v" ? &u.y : name == "w" ? &u.z : nullptr;
            }
            if (g) values = g->values();
            return g != nullptr;
        };
        const double nu = settings.viscosity;
        cp.exact3 = [&field, nu](const std::string& name, double t, Vec3d x) -> std::optional<double> {
            const bool vort = name.rfind("vorticity_", 0) == 0;
            const std::optional<Vec3d> e = vort ? field.exact_vorticity3(t, x, nu) : field.exact_velocity3(t, x, nu);
            if (!e) return std::nullopt;
            const char c = vort ? name.back() : name == "u" ? 'x' : name == "v" ? 'y' : name == "w" ? 'z' : '?';
            if (c == '?') return std::nullopt;
            return c == 'x' ? e->x : c == 'y' ? e->y : e->z;
        };
        cp.seconds = total.seconds() - checkpoints.overhead();
        cp.image = [&] { return slice_image(solver.vorticity_grid(), axis, range); };
        checkpoints.reached(ctx, cp);
    };

    const FluidDiagnostics3 d0 = solver.diagnostics();
    refuse(d0, solver.work().invalid_velocity + solver.work().invalid_vorticity);
    if (solver.velocity_available()) {
        const double cfl0 = cfl(0);
        add_row(d0, 0.0, double(solver.work().biot_savart_evals), solver.work().invalid_velocity, cfl0);
        write_frame();
        if (checkpoints.active()) checkpoint(0);
    }
    ProgressReporter progress(ctx, "Simulating", double(p.steps), "steps", ctx.time_limit);
    long long done = 0;
    bool stopped_by_time = false;
    Timer since_partial;
    for (long long step = 1; step <= p.steps; ++step) {
        if (any_rank(comm, ctx.cancel.stop_requested())) break;
        const FluidWork3 before = solver.work();
        Timer step_timer;
        const double dt = TimeStepping{settings.dt, p.steps, p.end_time}.step_length(step, solver.time());
        if (!solver.step(dt)) break;
        ++done;
        const FluidDiagnostics3 d = solver.diagnostics();
        if (!solver.velocity_available()) break;
        const FluidWork3& after = solver.work();
        const uint64_t replaced =
            (after.invalid_velocity + after.invalid_vorticity) - (before.invalid_velocity + before.invalid_vorticity);
        refuse(d, replaced);
        const double c = cfl(step);
        add_row(d, step_timer.seconds(), double(after.biot_savart_evals - before.biot_savart_evals), replaced, c);
        if (frames.due(step)) write_frame();
        if (checkpoints.active()) checkpoint(done);
        progress.update(1);
        if (comm.root() && ctx.write_partial > 0 && ctx.write_partial_image &&
            since_partial.seconds() >= ctx.write_partial) {
            ctx.write_partial_image(slice_image(solver.vorticity_grid(), axis, range));
            since_partial.reset();
        }
        if (step < p.steps && time_limit_reached(comm, ctx.time_limit, total.seconds())) {
            stopped_by_time = true;
            break;
        }
    }
    progress.finish();
    result.interrupted = any_rank(comm, ctx.cancel.stop_requested());
    // The limit passed inside a step (the watch stopped it; the partial step was discarded): as at a step boundary.
    if (!result.interrupted && done < p.steps && any_rank(comm, watch.passed())) stopped_by_time = true;
    if (stopped_by_time)
        log_warn("mcfluid: time limit of {:g} s reached after {} of {} steps (t = {:g})", ctx.time_limit, done, p.steps,
                 solver.time());
    checks.report(ctx.stats);

    const FluidWork3& w = solver.work();
    report_fluid_work(ctx.stats, done, solver.time(), solver.vorticity_grid().cell_count(), w);
    ctx.stats.add("fluid.stretching_evals", double(w.stretching_evals), "segments");
    ctx.stats.add("fluid.control_variate_queries", double(w.control_variate_queries), "queries");
    if (settings.boundaries) {
        report_walks(ctx.stats, "fluid.wos_",
                     {w.wos_walks, w.wos_steps, w.wos_truncated, w.wos_invalid, w.wos_boundary_queries}, "mcfluid",
                     settings.boundaries->wos.max_steps);
        ctx.stats.add("fluid.solid_cells", double(w.solid_cells), "cells");
        ctx.stats.add("fluid.solid_departures", double(w.solid_departures), "backtraces");
        ctx.stats.add("fluid.distance_queries", double(w.distance_queries), "queries");
    } else {
        ctx.stats.add("fluid.wos_walks", 0.0, "walks");
    }
    ctx.stats.add("fluid.smoke_lookups", double(w.smoke_lookups), "lookups");
    frames.finish();
    ctx.stats.add_time("fluid.time.output", frames.seconds());
    if (w.invalid_velocity + w.invalid_vorticity > 0)
        log_warn(
            "mcfluid: {} non-finite velocity estimate(s) and {} non-finite vorticity value(s) were replaced by zero",
            w.invalid_velocity, w.invalid_vorticity);
    save_csv();
    if (solver.velocity_available()) {
        const FluidDiagnostics3 dn = solver.diagnostics();
        log_info(
            "mcfluid: t = {:g}: energy noise-corrected {:.6g}, raw {:.6g} (initial {:.6g}, {:.6g}), enstrophy {:.6g}, "
            "helicity {:.6g}, max |omega| {:.6g}; active effects: advection{}{}{}{}",
            dn.time, dn.kinetic_energy, dn.kinetic_energy_raw, d0.kinetic_energy, d0.kinetic_energy_raw, dn.enstrophy,
            dn.helicity, dn.max_abs_vorticity, settings.stretching ? ", stretching" : "", viscous ? ", diffusion" : "",
            settings.control_variates ? ", control variates" : "", settings.boundaries ? ", boundaries" : "");
    }
    result.image = slice_image(solver.vorticity_grid(), axis, range);
    result.work = double(done);
    result.seconds = total.seconds();
    return result;
}

}  // namespace kelvin::fluid
