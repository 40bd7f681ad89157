// What the <simulation>s share: their parameters, the driver's adapter of a 2D FluidSolver (see
// include/kelvin/fluid/simulation.h), and Simulation::run.
#include <kelvin/core/checkpoint.h>
#include <kelvin/core/distributed.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/memory.h>
#include <kelvin/core/progress.h>
#include <kelvin/core/registry.h>
#include <kelvin/core/stats.h>
#include <kelvin/fluid/checks.h>
#include <kelvin/fluid/output.h>
#include <kelvin/fluid/simulation.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <optional>

namespace kelvin::fluid {

VorticityTransport parse_transport(const Properties& props) {
    const std::string t = props.get_choice("transport", {"cubic", "linear", "maccormack"});
    return t == "linear"       ? VorticityTransport::Linear
           : t == "maccormack" ? VorticityTransport::MacCormack
                               : VorticityTransport::Cubic;
}

double parse_stretching_filter(const Properties& props) {
    const double f = props.get_float("stretching_filter");
    if (f == AutoFilter) return f;
    if (!(f >= 0 && f <= MCFluid3Settings::MaxStretchingFilter))
        props.error("stretching_filter",
                    fmt::format("must lie in [0, {:g}] cells, or be {:g} (the solver's choice; got {:g})",
                                MCFluid3Settings::MaxStretchingFilter, AutoFilter, f));
    return f;
}

std::optional<FilterKernel> parse_filter_kernel(const Properties& props) {
    const std::string k = props.get_choice("filter_kernel", {"auto", "gaussian", "twicing"});
    if (k == "auto") return std::nullopt;
    return k == "twicing" ? FilterKernel::Twicing : FilterKernel::Gaussian;
}

VelocityTime parse_velocity_time(const Properties& props) {
    const std::string t = props.get_choice("velocity_time", {"auto", "midstep", "start"});
    return t == "midstep" ? VelocityTime::Midstep : t == "start" ? VelocityTime::Start : VelocityTime::Auto;
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
    p.transport = parse_transport(props);
    const std::string bt = props.get_choice("backtrace_velocity", {"auto", "cache", "estimates"});
    p.backtrace_velocity = bt == "estimates" ? BacktraceVelocity::Estimates
                           : bt == "cache"   ? BacktraceVelocity::Cache
                                             : BacktraceVelocity::Auto;
    p.velocity_filter = props.get_float("velocity_filter", 0.0, MaxVelocityFilter);
    p.velocity_time = parse_velocity_time(props);
    p.filter_kernel = parse_filter_kernel(props);
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
    // Cells of comparable sides (the cache, the mollifier and the near field assume them; see simulation3.cpp).
    if (const Vec2d h = size / Vec2d(p.nx, p.ny); !(std::max(h.x, h.y) <= MaxCellAspect * std::min(h.x, h.y)))
        props.error("cache", fmt::format("cells of {:g} x {:g} ({}x{} over the box {:g} x {:g}): a side more than {:g} "
                                         "times the other; give resolution_y or a less elongated box",
                                         h.x, h.y, p.nx, p.ny, size.x, size.y, MaxCellAspect));
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
    if (props.get_bool("energy_budget"))
        props.error("energy_budget", "is measured by mcfluid only (" + who + " has no Monte Carlo velocity)");
    if (props.get_int("energy_passes", 0, 64) != 0)
        props.error("energy_passes", "is mcfluid's (" + who +
                                         "'s velocity has no Monte Carlo noise: its energy "
                                         "column is exact)");
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
    if (root && root->plugin_kind() == "scene") {
        const std::shared_ptr<Job> job = std::dynamic_pointer_cast<Job>(root)->delegate();
        if (auto sim = std::dynamic_pointer_cast<Simulation>(job)) return sim;
        throw InputError({},
                         job ? fmt::format("the scene's <simulation type=\"{}\"> offers no solver", job->plugin_name())
                             : std::string("the scene has no <simulation> (it is a render)"));
    }
    throw InputError({}, fmt::format("{} is not a scene or a simulation",
                                     root ? "<" + root->plugin_kind() + " type=\"" + root->plugin_name() + "\">"
                                          : std::string("a null object")));
}

RunResult Simulation::run(RunContext& ctx) {
    const std::unique_ptr<DrivenSolver> solver = driven_solver(ctx);
    return run_simulation(*solver, driver_settings(), ctx);
}

DriverSettings SimulationParams::driver_settings(const std::string& who) const {
    DriverSettings d;
    d.who = who;
    d.time = {dt, steps, end_time};
    d.outputs = {output_every, write_png, write_exr, write_csv, color_range, frames};
    d.sources = sources;
    const Vec2d size = domain.size();
    d.h = std::min(size.x / nx, size.y / ny);  // as Grid2::h()
    d.extent = std::min(size.x, size.y);
    return d;
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

// ------------------------------------------------------------------------------------------------
// A 2D FluidSolver as the driver runs it.

Solver2Run::Solver2Run(std::string who, std::unique_ptr<FluidSolver> solver, const SimulationParams& params,
                       std::string effects)
    : m_who(std::move(who)), m_solver(std::move(solver)), m_p(params), m_effects(std::move(effects)) {
    m_range = m_p.color_range > 0 ? m_p.color_range : m_solver->vorticity_grid().max_abs();
}

bool Solver2Run::step(double dt) {
    if (!m_solver->step(dt)) return false;
    m_velocity = false;
    return true;
}

bool Solver2Run::diagnose(bool) {
    if (!m_solver->fields_available()) {  // a stop cut the pass that computes the state's fields
        m_velocity = false;
        return false;
    }
    m_d = m_solver->diagnostics();
    m_d.vorticity_rmse_exact = exact_vorticity_rmse(m_solver->vorticity_grid(), *m_p.field, m_d.time, m_p.viscosity);
    m_velocity = true;
    if (!m_have_d0) m_d0 = m_d, m_have_d0 = true;
    return true;
}

std::vector<FieldValues> Solver2Run::fields() {
    std::vector<FieldValues> f = {{&m_solver->vorticity_grid().values(), "vorticity", m_p.nx, 0}};
    if (m_velocity) {
        f.push_back({&m_solver->velocity_u().values(), "velocity u", m_p.nx, 0});
        f.push_back({&m_solver->velocity_v().values(), "velocity v", m_p.nx, 0});
    }
    return f;
}

double Solver2Run::max_speed() {
    return fluid::max_speed({&m_solver->velocity_u().values(), &m_solver->velocity_v().values()});
}

Bitmap Solver2Run::image() {
    return field_image(m_solver->vorticity_grid(), m_velocity ? &m_solver->velocity_u() : nullptr,
                       m_velocity ? &m_solver->velocity_v() : nullptr, m_range);
}

void Solver2Run::write_frame(FrameWriter& frames) {
    // A PNG (or the run's picture) colour-maps the vorticity itself: the fields in full only for an EXR frame.
    const Bitmap fields =
        frames.writes_fields() ? image() : field_image(m_solver->vorticity_grid(), nullptr, nullptr, m_range, false);
    frames.write_2d(m_solver->step_index(), fields, m_range, overlay(), m_p.domain.min, m_p.domain.max,
                    m_solver->dye());
}

Checkpoint Solver2Run::checkpoint() {
    FluidSolver& solver = *m_solver;
    auto fields = [&solver](const std::string& name) -> const Grid2* {
        return name == "vorticity" ? &solver.vorticity_grid()
               : name == "u"       ? &solver.velocity_u()
               : name == "v"       ? &solver.velocity_v()
                                   : nullptr;
    };
    return state_checkpoint(solver.step_index(), solver.time(), {m_p.domain.min, m_p.domain.max, m_p.nx, m_p.ny},
                            fields, *m_p.field, m_p.viscosity);
}

std::vector<std::string> Solver2Run::describe() {
    return {fmt::format("2D, domain {}, {}x{} grid, initial {}", m_p.domain.to_string(), m_p.nx, m_p.ny,
                        m_p.field->description()),
            fmt::format("effects: {}; diffusion {}; stretching off (2D); {}", m_effects,
                        m_p.viscosity > 0 ? fmt::format("on (nu {:g})", m_p.viscosity) : std::string("off (inviscid)"),
                        dye_effect(m_p.dye.get()))};
}

void Solver2Run::report(Stats& stats) const {
    m_solver->report(stats);
    report_dye_stats(stats, m_solver->dye());
}

void Solver2Run::warn() const {
    if (m_solver->invalid() > 0)
        log_warn("{}: {} non-finite value(s) were replaced by zero", m_who, m_solver->invalid());
}

std::string Solver2Run::summary(const std::string&) {
    if (!m_have_d0)
        return fmt::format("t = {:g}: stopped before the initial state's fields were computed (no diagnostics)",
                           m_solver->time());
    const FluidDiagnostics dn = m_solver->diagnostics();
    return fmt::format(
        "t = {:g}: energy {:.6g} (initial {:.6g}), enstrophy {:.6g} (initial {:.6g}), circulation {:.6g}, max |omega| "
        "{:.6g}; active effects: advection{}{}",
        dn.time, dn.kinetic_energy, m_d0.kinetic_energy, dn.enstrophy, m_d0.enstrophy, dn.circulation,
        dn.max_abs_vorticity, m_p.viscosity > 0 ? ", diffusion" : "", m_solver->dye() ? ", dye" : "");
}

}  // namespace kelvin::fluid
