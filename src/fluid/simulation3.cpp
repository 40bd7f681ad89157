// mcfluid in 3D: parameters, outputs and the solver as the driver runs it (see include/kelvin/fluid/simulation3.h).
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
#include <kelvin/fluid/checks.h>
#include <kelvin/fluid/estimators.h>
#include <kelvin/fluid/output.h>
#include <kelvin/fluid/ring_cores.h>
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
    s.transport = parse_transport(props);
    const std::string bt = props.get_choice("backtrace_velocity", {"auto", "cache", "estimates"});
    s.backtrace_velocity = bt == "cache"       ? BacktraceVelocity::Cache
                           : bt == "estimates" ? BacktraceVelocity::Estimates
                                               : BacktraceVelocity::Auto;
    s.velocity_filter = props.get_float("velocity_filter", 0.0, MaxVelocityFilter);
    if (const auto k = parse_filter_kernel(props)) s.filter_kernel = *k;
    p.energy_passes = energy_passes_param(props);
    p.energy_budget = props.get_bool("energy_budget");
    if (p.energy_budget && s.viscosity > 0) props.error("energy_budget", "covers inviscid flows only (viscosity 0)");
    s.stretching = props.get_bool("stretching");
    s.velocity_time = parse_velocity_time(props);
    s.control_variates = props.get_bool("control_variates");
    s.initial_samples = int(props.get_int("initial_samples", 0, 1 << 24));
    s.control_variate_blend = props.get_float("control_variate_blend", 1e-6, 1.0);
    s.vorticity_allocation = props.get_choice("sample_allocation", {"uniform", "vorticity"}) == "vorticity";
    s.stretching_filter = parse_stretching_filter(props);
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
    // The cache, the mollifier and the near field assume cells of comparable sides; a box far longer on one axis
    // (or a per-axis resolution) that makes them needles or plates is refused before any table is built (the near
    // field's quadrature grows with the sides' ratio: a box 1e300 across at 8 cells ran for hours).
    if (const Vec3d h = size / Vec3d(s.nx, s.ny, s.nz);
        !(std::max({h.x, h.y, h.z}) <= MaxCellAspect * std::min({h.x, h.y, h.z})))
        props.error("cache", fmt::format("cells of {:g} x {:g} x {:g} ({}x{}x{} over the box {:g} x {:g} x {:g}): a "
                                         "side more than {:g} times another; give a resolution per axis or a less "
                                         "elongated box",
                                         h.x, h.y, h.z, s.nx, s.ny, s.nz, size.x, size.y, size.z, MaxCellAspect));
    s.interpolation = cache->interpolation();
    if (const auto* bs = dynamic_cast<const BiotSavartVelocity*>(s.estimator.get())) {
        const Vec3d h = size / Vec3d(s.nx, s.ny, s.nz);
        const double delta = resolved_delta3(*bs, h, s.nx, s.ny, s.nz, s.domain.periodic);
        if (const std::string why = bs->check_cells3(h, delta, s.nx, s.ny, s.nz, s.domain.periodic); !why.empty())
            props.error("velocity", why);
    }
    if (auto scalar = props.get_object("scalar")) {
        p.smoke = std::dynamic_pointer_cast<SmokeSpec3>(scalar);
        if (!p.smoke)
            props.error("scalar",
                        fmt::format("'{}' is a 2D dye; 3D scenes take <scalar type=\"smoke\">", scalar->plugin_name()));
    }
    if (p.energy_budget && s.boundaries)
        props.error("energy_budget",
                    "covers flows without boundaries only (walk_on_spheres has none in closed form; energy_passes "
                    "measures the energy there)");
    if (s.boundaries)
        if (const std::string why = check_wos_cells3(*s.boundaries, s.domain, s.nx, s.ny, s.nz); !why.empty())
            props.error("velocity", "walk_on_spheres: " + why);
    p.field->check_domain3(s.domain);
    p.sources = RunSources::from(props, obj->plugin_name(), p.field->strength_parameter3());
    // The memory the run will need, before anything is allocated (checks.h: measured per cell).
    // With the energy budget, its transforms (energy_budget3.cpp): about 120 B per cell of the transform's grid (8x
    // the cells of an open box, zero-padded; measured: 73 MB at 40^3 open) and three vector grids.
    const double budget_bytes =
        p.energy_budget ? double(s.nx) * double(s.ny) * double(s.nz) * ((s.domain.periodic ? 1 : 8) * 120.0 + 72.0)
                        : 0.0;
    check_memory(memory_estimate_3d(s.nx, s.ny, s.nz, s.control_variates, bool(p.smoke), bool(s.boundaries),
                                    p.write_vdb && p.output_every > 0) +
                     budget_bytes,
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
// The solver as the driver runs it.

DriverSettings Simulation3Params::driver_settings() const {
    DriverSettings d;
    d.who = "mcfluid";
    d.time = {settings.dt, steps, end_time};
    d.outputs = {output_every, write_png, write_vdb, write_csv, color_range, frames};
    d.sources = sources;
    const Vec3d size = settings.domain.size();
    d.h = std::min({size.x / settings.nx, size.y / settings.ny, size.z / settings.nz});  // as Grid3::h()
    d.extent = std::min({size.x, size.y, size.z});
    return d;
}

std::unique_ptr<MCFluid3Solver> create_mcfluid3_solver(const Simulation3Params& p, const RunContext& ctx) {
    MCFluid3Settings settings = p.settings;
    settings.seed = ctx.seed;
    settings.samples = run_samples(ctx, settings.estimator->samples());
    const VorticityField3* field = p.field;
    auto solver = std::make_unique<MCFluid3Solver>(settings, [field](const Vec3d& x) { return field->vorticity3(x); });
    if (p.smoke) solver->set_smoke({p.smoke->center(), p.smoke->radius(), p.smoke->initial_density(), p.smoke->rate()});
    solver->set_cancel_token(ctx.cancel);
    solver->set_communicator(ctx.comm);
    if (p.energy_budget) solver->set_energy_budget(true);
    solver->set_energy_passes(p.energy_passes);
    return solver;
}

namespace {

class MCFluid3Run final : public DrivenSolver {
public:
    MCFluid3Run(std::unique_ptr<MCFluid3Solver> solver, const Simulation3Params& p, bool spp)
        : m_solver(std::move(solver)), m_p(p), m_spp(spp) {
        const VectorGrid3& w = m_solver->vorticity_grid();
        const int axis = p.slice_axis;
        m_range = p.color_range > 0 ? p.color_range : (axis == 0 ? w.x : (axis == 1 ? w.y : w.z)).max_abs();
    }

    Cancellable& cancellable() override { return *m_solver; }
    double time() const override { return m_solver->time(); }
    long long step_index() const override { return m_solver->step_index(); }
    bool step(double dt) override {
        if (!m_solver->step(dt)) return false;
        m_velocity = false;
        return true;
    }
    bool lazy_velocity() const override { return true; }

    bool diagnose(bool velocity) override {
        if (velocity && !m_solver->velocity_available()) velocity = false;  // a stop cut the velocity's pass short
        m_d = m_solver->diagnostics(velocity);
        m_cores.update(m_solver->vorticity_grid());
        m_velocity = velocity;
        m_paired_now = velocity && paired_energy_due(m_solver->energy_passes(), m_solver->step_index(), m_p.steps,
                                                     m_p.output_every);
        if (m_paired_now) {
            m_paired = m_solver->paired_energy();
            if (!m_have_d0) m_paired0 = m_paired;
        }
        if (!m_have_d0) m_d0 = m_d, m_have_d0 = true;
        return velocity;
    }
    std::vector<NamedValue> values() const override {
        const FluidDiagnostics3& d = m_d;
        std::vector<NamedValue> v = {{d.enstrophy, "enstrophy"},
                                     {d.impulse.x, "impulse x"},
                                     {d.impulse.y, "impulse y"},
                                     {d.impulse.z, "impulse z"},
                                     {d.max_abs_vorticity, "max |vorticity|"},
                                     {d.smoke_mass, "smoke mass"}};
        if (m_velocity)
            v.insert(v.begin(), {{d.kinetic_energy, "kinetic energy"},
                                 {d.kinetic_energy_raw, "raw kinetic energy"},
                                 {d.helicity, "helicity"},
                                 {d.divergence_rms, "divergence RMS"}});
        return v;
    }
    std::vector<FieldValues> fields() override {
        const VectorGrid3& w = m_solver->vorticity_grid();
        const int nx = w.x.nx(), ny = w.x.ny();
        std::vector<FieldValues> f = {{&w.x.values(), "vorticity x", nx, ny},
                                      {&w.y.values(), "vorticity y", nx, ny},
                                      {&w.z.values(), "vorticity z", nx, ny}};
        if (m_velocity) {
            const VectorGrid3& u = m_solver->velocity_grid();
            f.push_back({&u.x.values(), "velocity x", nx, ny});
            f.push_back({&u.y.values(), "velocity y", nx, ny});
            f.push_back({&u.z.values(), "velocity z", nx, ny});
        }
        if (m_solver->smoke()) f.push_back({&m_solver->smoke()->values(), "smoke density", nx, ny});
        return f;
    }
    std::size_t cells() const override { return m_solver->vorticity_grid().cell_count(); }
    double max_speed() override {
        const VectorGrid3& u = m_solver->velocity_grid();
        return fluid::max_speed({&u.x.values(), &u.y.values(), &u.z.values()});
    }
    double evaluations() const override { return double(m_solver->work().biot_savart_evals); }
    uint64_t replaced() const override {
        const FluidWork3& w = m_solver->work();
        return w.invalid_velocity + w.invalid_vorticity;
    }
    std::string csv_header() const override {
        return "step,time,kinetic_energy,kinetic_energy_raw,enstrophy,helicity,impulse_x,impulse_y,impulse_z,"
               "centroid_x,centroid_y,centroid_z,impulse_centroid_x,impulse_centroid_y,impulse_centroid_z,max_abs_"
               "vorticity,divergence_rms,smoke_mass,step_seconds,"
               "biot_savart_evals,invalid,cfl" +
               (m_solver->energy_budget_step() ? EnergyBudget::csv_columns(true) : std::string()) +
               (m_solver->energy_passes() > 0 ? paired_energy_columns() : std::string()) + m_cores.header();
    }
    std::string csv_row(double seconds, double evals, uint64_t invalid, double cfl) const override {
        const FluidDiagnostics3& d = m_d;
        return fmt::format(
            "{},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:."
            "9g},"
            "{:.9g},{:.9g},{:.6g},{:.0f},{},{:.6g}{}\n",
            d.step, d.time, d.kinetic_energy, d.kinetic_energy_raw, d.enstrophy, d.helicity, d.impulse.x, d.impulse.y,
            d.impulse.z, d.centroid.x, d.centroid.y, d.centroid.z, d.impulse_centroid.x, d.impulse_centroid.y,
            d.impulse_centroid.z, d.max_abs_vorticity, d.divergence_rms, d.smoke_mass, seconds, evals, invalid, cfl,
            budget_values() +
                (m_solver->energy_passes() > 0 ? paired_energy_values(m_paired_now ? m_paired : PairedEnergy{})
                                               : std::string()) +
                m_cores.values());
    }
    // With the energy budget, seven more columns: the state's deterministic energy and the last step's split.
    std::string budget_values() const {
        const EnergyBudget* b = m_solver->energy_budget_step();
        return b ? b->csv_values(true) : std::string();
    }
    void write_frame(FrameWriter& frames) override {
        MCFluid3Solver& solver = *m_solver;
        if (m_p.write_vdb)  // the data frames (the EXR role of 2D)
            frames.write_data("fields", solver.step_index(), ".vdb", [&](const std::filesystem::path& path) {
                write_vdb_frame(path, solver.vorticity_grid(), m_velocity ? &solver.velocity_grid() : nullptr,
                                solver.smoke());
            });
        frames.write_png("vorticity", solver.step_index(), image(), "value", m_range, {0, 0}, {1, 1});
    }
    Bitmap image() override { return slice_image(m_solver->vorticity_grid(), m_p.slice_axis, m_range); }
    // The vorticity and velocity components on the cache grid, the field's exact solution where it has one (abc).
    Checkpoint checkpoint() override {
        MCFluid3Solver& solver = *m_solver;
        const MCFluid3Settings& s = solver.settings();
        Checkpoint cp;
        cp.sim_time = solver.time();
        cp.dimension = 3;
        cp.grid3 = {s.domain.min, s.domain.max, s.nx, s.ny, s.nz};
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
        const double nu = s.viscosity;
        const VorticityField3& field = *m_p.field;
        cp.exact3 = [&field, nu](const std::string& name, double t, Vec3d x) {
            return field.exact_component3(name, t, x, nu);
        };
        return cp;
    }

    std::vector<std::string> describe() override {
        const MCFluid3Solver& solver = *m_solver;
        const MCFluid3Settings& s = solver.settings();
        std::vector<std::string> lines;
        if (m_spp) lines.push_back(fmt::format("--spp {} overrides the Biot–Savart samples (n_mc)", s.samples));
        lines.push_back(fmt::format("3D, domain {}, {}x{}x{} cache ({}), initial {}", s.domain.to_string(), s.nx, s.ny,
                                    s.nz, s.interpolation == Interpolation::Nearest ? "nearest" : "trilinear",
                                    m_p.field->description3()));
        // The near field the estimator resolved on these cells (biot_savart: its default adapts to delta).
        const auto near_field_effect = [&]() -> std::string {
            const auto* bs = dynamic_cast<const BiotSavartVelocity*>(s.estimator.get());
            if (!bs) return {};
            const Vec3d h = s.domain.size() / Vec3d(s.nx, s.ny, s.nz);
            const int R = bs->near_field3(h, solver.delta(), s.nx, s.ny, s.nz, s.domain.periodic);
            return R > 0 ? fmt::format(", the {} nearest cells summed exactly", (2 * R + 1) * (2 * R + 1) * (2 * R + 1))
                         : std::string();
        };
        std::string velocity =
            s.boundaries
                ? fmt::format(
                      "free-slip Walk-on-Spheres velocity on the vector potential ({} gradient samples, max {} "
                      "steps, {}{})",
                      s.samples, s.boundaries->wos.max_steps,
                      solver.boundary_field() && solver.boundary_field()->control_variate()
                          ? fmt::format("wall control variate with {} free samples{}", s.boundaries->free_samples,
                                        s.boundaries->stratified ? ", stratified" : "")
                          : fmt::format("plain walks, {} volume sampling",
                                        s.boundaries->vorticity_importance ? "|omega|-mixed" : "Green's-function"),
                      solver.boundary_field() && solver.boundary_field()->harmonic_balls() > 0
                          ? fmt::format(", harmonic cache ({} balls of degree {} hold {} of the {} cells at t = {:g})",
                                        solver.boundary_field()->harmonic_balls(), s.boundaries->cache_degree,
                                        solver.boundary_field()->harmonic_cells(), s.nx * s.ny * s.nz, solver.time())
                          : std::string())
                : s.estimator->effect(s.samples, solver.delta(), s.domain.periodic) + near_field_effect();
        if (s.vorticity_allocation)
            velocity +=
                fmt::format(", samples allocated by |omega| (n_mc / {} to {} n_mc per cell, at most n_mc on average)",
                            s.AllocationFloor, s.AllocationCap);
        lines.push_back(fmt::format(
            "effects: advection ({}, dt {:g}, {} steps, transport {}, velocity {}) with {}; stretching {}; diffusion "
            "{}; control variates {}; boundaries {}; smoke {}",
            fluid::to_string(s.advection), s.dt, m_p.steps, fluid::to_string(s.transport),
            std::string(solver.midstep() ? "at mid-step, extrapolated" : "frozen at the step's start") +
                (solver.settings().backtrace_velocity == BacktraceVelocity::Cache
                     ? fmt::format("; the stages read the cache smoothed over {:g} cells ({})",
                                   solver.settings().velocity_filter, to_string(solver.settings().filter_kernel))
                     : std::string("; a fresh estimate at each stage")),
            velocity,
            s.stretching ? fmt::format("on (vortex segments, h = {:g}{})", solver.segment_length(),
                                       solver.settings().stretching_filter > 0
                                           ? fmt::format(", velocity smoothed over {:g} cells ({})",
                                                         solver.settings().stretching_filter,
                                                         to_string(solver.settings().filter_kernel))
                                           : std::string())
                         : std::string("OFF (requested; the 3D equations need it)"),
            s.viscosity > 0 ? fmt::format("on (nu {:g}, Feynman–Kac, n_d {})", s.viscosity, s.diffusion_samples)
                            : std::string("off (inviscid)"),
            s.control_variates
                ? fmt::format("on (initial samples {}{})", s.initial_samples > 0 ? s.initial_samples : s.samples,
                              s.control_variate_blend < 1 ? fmt::format(", blend {:g}", s.control_variate_blend)
                                                          : std::string())
                : std::string("off"),
            s.boundaries ? describe3(*s.boundaries, s.domain) : std::string("none"),
            m_p.smoke ? m_p.smoke->description() : std::string("none")));
        return lines;
    }

    void report(Stats& stats) const override {
        const FluidWork3& w = m_solver->work();
        const MCFluid3Settings& s = m_solver->settings();
        report_fluid_counters(stats, w);
        stats.add("fluid.stretching_evals", double(w.stretching_evals), "segments");
        stats.add("fluid.control_variate_queries", double(w.control_variate_queries), "queries");
        if (s.boundaries) {
            report_walks(stats, "fluid.wos_",
                         {w.wos_walks, w.wos_steps, w.wos_truncated, w.wos_invalid, w.wos_boundary_queries}, "mcfluid",
                         s.boundaries->wos.max_steps);
            stats.add("fluid.solid_cells", double(w.solid_cells), "cells");
            stats.add("fluid.solid_departures", double(w.solid_departures), "backtraces");
            stats.add("fluid.distance_queries", double(w.distance_queries), "queries");
        } else {
            stats.add("fluid.wos_walks", 0.0, "walks");
        }
        stats.add("fluid.smoke_lookups", double(w.smoke_lookups), "lookups");
        if (const EnergyBudget* b = m_solver->energy_budget_total()) b->add_stats(stats, true);
        if (m_solver->energy_passes() > 0) add_paired_energy_stats(stats, m_paired0, m_paired);
    }

    void warn() const override {
        const FluidWork3& w = m_solver->work();
        if (w.invalid_velocity + w.invalid_vorticity > 0)
            log_warn(
                "mcfluid: {} non-finite velocity estimate(s) and {} non-finite vorticity value(s) were replaced by "
                "zero",
                w.invalid_velocity, w.invalid_vorticity);
    }

    std::string summary(const std::string& ended) override {
        std::string line = summary_line(ended);
        if (const EnergyBudget* b = m_solver->energy_budget_total()) line += b->summary(true);
        if (m_solver->energy_passes() > 0) line += paired_energy_summary(m_paired0, m_paired);
        return line;
    }

    std::string summary_line(const std::string& ended) {
        const MCFluid3Settings& s = m_solver->settings();
        const std::string effects =
            fmt::format("active effects: advection{}{}{}{}", s.stretching ? ", stretching" : "",
                        s.viscosity > 0 ? ", diffusion" : "", s.control_variates ? ", control variates" : "",
                        s.boundaries ? ", boundaries" : "");
        if (!m_velocity) {
            const FluidDiagnostics3 dn = m_solver->diagnostics(false);
            return fmt::format("t = {:g}: enstrophy {:.6g}, max |omega| {:.6g} ({}); {}", dn.time, dn.enstrophy,
                               dn.max_abs_vorticity,
                               ended.empty() ? "the final state's velocity and energy were not estimated: no output "
                                               "needs them; the CSV or a VDB frame does"
                                             : ended + " before the velocity of that state was estimated",
                               effects);
        }
        const FluidDiagnostics3 dn = m_solver->diagnostics(true);
        return fmt::format(
            "t = {:g}: energy noise-corrected {:.6g}, raw {:.6g} (initial {:.6g}, {:.6g}), enstrophy {:.6g}, helicity "
            "{:.6g}, max |omega| {:.6g}; {}",
            dn.time, dn.kinetic_energy, dn.kinetic_energy_raw, m_d0.kinetic_energy, m_d0.kinetic_energy_raw,
            dn.enstrophy, dn.helicity, dn.max_abs_vorticity, effects);
    }

private:
    std::unique_ptr<MCFluid3Solver> m_solver;
    const Simulation3Params& m_p;
    bool m_spp;
    double m_range = 0;
    FluidDiagnostics3 m_d, m_d0;
    bool m_velocity = false, m_have_d0 = false;
    PairedEnergy m_paired0, m_paired;    ///< energy_passes: the first and the last measured state's
    bool m_paired_now = false;           ///< the current state's was measured
    RingCoreColumns m_cores{m_p.field};  // rings: each core's (r, z, circulation) in the CSV
};

}  // namespace

std::unique_ptr<DrivenSolver> drive_mcfluid3(const Simulation3Params& p, const RunContext& ctx) {
    return std::make_unique<MCFluid3Run>(create_mcfluid3_solver(p, ctx), p, ctx.spp > 0);
}

}  // namespace kelvin::fluid
