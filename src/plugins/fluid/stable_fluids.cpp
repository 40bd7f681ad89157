// stable_fluids: the grid baseline, Stam's "Stable Fluids" (1999) on a staggered MAC grid: semi-Lagrangian
// advection of the velocity (Euler or RK4 backtraces, bilinear lookups), implicit viscosity (Eigen's
// incomplete-Cholesky CG) and a pressure projection by FFT (boxes without obstacles) or multigrid-preconditioned CG
// (src/fluid/pressure.cpp). Run as a Job by `kelvin scene.xml`; takes the same scene as mcfluid (switch with one
// word: type="stable_fluids") and writes the same files. The grid is the <cache type="grid"> resolution. A
// periodic scene is periodic; an open one becomes a closed box with free-slip walls (a grid solver needs a finite
// box). The static obstacles of mcfluid's <velocity type="walk_on_spheres"> (its <boundary> children with an
// inside) become solid cells: every cell whose centre lies in a solid.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <simulation type="stable_fluids"> ... same children as mcfluid ... </simulation>
//
// dimension = 3 (include/kelvin/fluid/stable_fluids3.h): the same solvers on a 3D MAC grid, from 3D mcfluid's scene
// (Simulation3Params: its parameters are read and validated as mcfluid reads them; stretching, control variates and
// the Biot–Savart estimator are accepted and ignored), with its outputs (CSV columns, VDB frames, PNG slices, smoke)
// and checkpoints. The solids are the 3D <boundary> shapes of a walk_on_spheres velocity that have an inside; a shape
// without one, a moving one or an inflow is refused naming `velocity`. The 3D projection is fft or multigrid (cg is
// 2D only: refused naming `projection`).
//
// flip: the particle baseline the thesis compares against (FLIP, Zhu and Bridson 2005), on the same MAC grid,
// projection, obstacles and outputs: particles_per_cell (6) particles per fluid cell carry the velocity; each step
// they move through the grid velocity (the `advection` integrator run forward), are splatted to the faces, the grid
// is projected, and each particle takes flip_ratio (0.95) of the grid's change plus the rest of its value (PIC).
// Cells the flow empties are reseeded to half the nominal count, crowded ones (twice it) thinned.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
#include <kelvin/core/error.h>
#include <kelvin/core/job.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/memory.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/boundary.h>
#include <kelvin/fluid/stable_fluids.h>
#include <kelvin/fluid/stable_fluids3.h>

#include <fmt/format.h>
#include <fmt/ranges.h>

namespace kelvin::fluid {
namespace {

class StableFluids final : public Simulation {
public:
    StableFluids(const Properties& props, Transport transport)
        : m_who(transport == Transport::FLIP ? "flip" : "stable_fluids"), m_transport(transport) {
        const long long dim = props.get_int("dimension");
        if (dim != 2 && dim != 3) props.error("dimension", fmt::format("must be 2 or 3 (got {})", dim));
        if (dim == 3) {
            parse3(props);
            return;
        }
        m_params = SimulationParams::parse_baseline(props, m_who);
        read_solver_params(props);
        if (m_params.nx < 4 || m_params.ny < 4) props.error("cache", m_who + " needs at least 4x4 cells");
        if (!m_params.domain.periodic)
            log_info("{}: the open domain {} becomes a closed box with free-slip walls", m_who,
                     m_params.domain.to_string());
        read_obstacles(props);
        if (m_projection == Projection::FFT && !m_obstacles.empty())
            props.error("projection", "fft needs a box without obstacles; use multigrid (or auto)");
    }

    /// The projection and FLIP parameters (both dimensions).
    void read_solver_params(const Properties& props) {
        if (m_transport == Transport::FLIP) {
            m_flip_ratio = props.get_float("flip_ratio", 0.0, 1.0);
            m_particles_per_cell = int(props.get_int("particles_per_cell", 1, m_3d ? 512 : 256));
        }
        m_tolerance = props.get_float("tolerance", 1e-15, 1e-2);
        const std::string proj = props.get_choice("projection", {"auto", "fft", "multigrid", "cg"});
        m_projection = proj == "fft"         ? Projection::FFT
                       : proj == "multigrid" ? Projection::Multigrid
                       : proj == "cg"        ? Projection::CG
                                             : Projection::Auto;
    }

    /// dimension = 3: 3D mcfluid's parameters (the same scene), the solver's, and the solids of the <velocity>
    /// estimator's boundaries (static 3D shapes with an inside; anything else is refused naming `velocity`).
    void parse3(const Properties& props) {
        m_3d = std::make_unique<Simulation3Params>(Simulation3Params::parse(props));
        if (m_3d->energy_budget)
            props.error("energy_budget", "is measured by mcfluid only (" + m_who + " has no Monte Carlo velocity)");
        if (m_3d->energy_passes != 0)
            props.error("energy_passes", "is mcfluid's (" + m_who +
                                             "'s velocity has no Monte Carlo noise: its energy "
                                             "column is exact)");
        read_solver_params(props);
        if (m_transport == Transport::FLIP && !props.has("particles_per_cell")) m_particles_per_cell = 8;
        if (m_projection == Projection::CG)
            props.error("projection", "cg (incomplete Cholesky) is 2D only; 3D takes auto, fft or multigrid");
        const MCFluid3Settings& s = m_3d->settings;
        if (s.nx < 4 || s.ny < 4 || s.nz < 4) props.error("cache", m_who + " needs at least 4x4x4 cells");
        check_memory(memory_estimate_3d_grid(m_transport == Transport::FLIP, m_particles_per_cell, s.nx, s.ny, s.nz),
                     fmt::format("{}: a {}x{}x{} grid (parameter 'resolution')", m_who, s.nx, s.ny, s.nz),
                     props.location_of("cache"));
        if (props.get_object("velocity"))
            log_info(
                "{}: <velocity> is mcfluid's Monte Carlo estimator; {} computes its velocity itself (only the "
                "estimator's boundaries are used)",
                m_who, m_who);
        if (!s.domain.periodic)
            log_info("{}: the open domain {} becomes a closed box with free-slip walls", m_who, s.domain.to_string());
        if (s.boundaries) {
            const WosVelocityOptions& o = *s.boundaries;
            if (o.inflow_speed != 0)
                props.error("velocity", m_who + " has no inflow/outflow walls (inflow_speed must be 0)");
            for (const auto& shape : o.shapes) {
                if (!shape || shape->dimension() != 3) props.error("velocity", m_who + " in 3D takes 3D boundaries");
                if (shape->role().moving())
                    props.error("velocity", fmt::format("{} has static obstacles only; boundary '{}' moves", m_who,
                                                        shape->description()));
                if (!shape->has_inside())
                    props.error("velocity", fmt::format("{} voxelises solids at the cell centres; boundary '{}' has no "
                                                        "inside (unsigned), so it cannot",
                                                        m_who, shape->description()));
                m_obstacles.push_back(shape);
            }
        }
        if (m_projection == Projection::FFT && !m_obstacles.empty())
            props.error("projection", "fft needs a box without obstacles; use multigrid (or auto)");
        // Boundaries that leave no fluid cell are an input error; a solid that covers no cell centre is a warning.
        if (!m_obstacles.empty()) {
            const Grid3 grid(s.domain, s.nx, s.ny, s.nz);
            bool any_fluid = false;
            std::vector<long long> covered(m_obstacles.size(), 0);
            for (int k = 0; k < s.nz; ++k)
                for (int j = 0; j < s.ny; ++j)
                    for (int i = 0; i < s.nx; ++i) {
                        const Vec3d c = grid.cell_center(i, j, k);
                        bool solid_here = false;
                        for (std::size_t q = 0; q < m_obstacles.size(); ++q)
                            if (solid3(*m_obstacles[q], c)) {
                                ++covered[q];
                                solid_here = true;
                            }
                        any_fluid |= !solid_here;
                    }
            if (!any_fluid)
                props.error("velocity",
                            fmt::format("the boundaries leave no fluid cell on the {}x{}x{} grid", s.nx, s.ny, s.nz));
            for (std::size_t q = 0; q < m_obstacles.size(); ++q)
                if (covered[q] == 0)
                    log_warn(
                        "{}: boundary '{}' covers no cell centre of the {}x{}x{} grid (outside the domain or "
                        "thinner than a cell): the grid solver does not see it",
                        m_who, m_obstacles[q]->description(), s.nx, s.ny, s.nz);
        }
    }

    /// The solid region of a 3D shape: inside an obstacle, outside a container.
    static bool solid3(const BoundaryShape& shape, const Vec3d& p) {
        return shape.has_inside() && (shape.inside3(p) != shape.role().fluid_inside);
    }

    /// The 3D solver run(ctx) steps, at t = 0 (ctx.cancel as its token); it refers to this object.
    std::unique_ptr<StableFluids3Solver> make_solver3(const RunContext& ctx) const {
        const MCFluid3Settings& m = m_3d->settings;
        StableFluids3Settings s;
        s.domain = m.domain;
        s.nx = m.nx;
        s.ny = m.ny;
        s.nz = m.nz;
        s.advection = m.advection;
        s.viscosity = m.viscosity;
        s.tolerance = m_tolerance;
        s.seed = ctx.seed;
        s.projection = m_projection;
        s.transport = m_transport;
        s.flip_ratio = m_flip_ratio;
        s.particles_per_cell = m_particles_per_cell;
        if (!m_obstacles.empty())
            s.solid = [this](const Vec3d& p) {
                for (const auto& shape : m_obstacles)
                    if (solid3(*shape, p)) return true;
                return false;
            };
        const VorticityField3* field = m_3d->field;
        auto solver =
            std::make_unique<StableFluids3Solver>(s, [field](const Vec3d& x) { return field->vorticity3(x); });
        if (const auto& sm = m_3d->smoke)
            solver->set_smoke({sm->center(), sm->radius(), sm->initial_density(), sm->rate()});
        solver->set_cancel_token(ctx.cancel);
        return solver;
    }

    std::unique_ptr<DrivenSolver> driven_solver3(const RunContext& ctx) const {
        std::unique_ptr<StableFluids3Solver> owned = make_solver3(ctx);
        const StableFluids3Solver& solver = *owned;
        const StableFluids3Settings& s = solver.settings();
        const std::string transport =
            m_transport == Transport::FLIP
                ? fmt::format("FLIP particles ({} per cell, flip_ratio {:g}, {} moves)", s.particles_per_cell,
                              s.flip_ratio, fluid::to_string(s.advection))
                : fmt::format("semi-Lagrangian advection ({}, trilinear)", fluid::to_string(s.advection));
        const std::size_t cells = std::size_t(s.nx) * std::size_t(s.ny) * std::size_t(s.nz);
        const std::string effects = fmt::format(
            "{}, dt {:g}, {} steps, on a {}x{}x{} MAC grid; pressure projection ({}){}; boundaries {}{}; smoke {}",
            transport, m_3d->settings.dt, m_3d->steps, s.nx, s.ny, s.nz,
            solver.projection() == Projection::FFT ? "FFT, exact inverse of the discrete Laplacian"
                                                   : fmt::format("multigrid-preconditioned CG to {:g}", s.tolerance),
            s.viscosity > 0 ? "; implicit viscosity (FFT)" : "", s.domain.periodic ? "periodic" : "free-slip box walls",
            m_obstacles.empty() ? ""
                                : fmt::format(" + {} static solid(s), {} fluid cells of {}", m_obstacles.size(),
                                              solver.fluid_cells(), cells),
            m_3d->smoke ? m_3d->smoke->description() : std::string("none"));
        return drive_grid_solver3(m_who, std::move(owned), *m_3d, effects);
    }

    /// The solid shapes of the <velocity> estimator's boundaries (walk_on_spheres; static, with an inside),
    /// checked on the grid.
    void read_obstacles(const Properties& props) {
        auto velocity = std::dynamic_pointer_cast<const VelocityEstimator>(props.get_object("velocity"));
        const std::shared_ptr<const WosVelocityOptions> boundaries = velocity ? velocity->boundaries() : nullptr;
        if (!boundaries) return;  // the estimator itself is mcfluid's; the grid solver only takes its solids
        const WosVelocityOptions& o = *boundaries;
        if (o.inflow_speed != 0)
            props.error("velocity", m_who + " has no inflow/outflow walls (inflow_speed must be 0)");
        std::vector<std::string> names;
        for (const auto& shape : o.shapes) {
            if (!shape || shape->dimension() != 2) props.error("velocity", m_who + " takes 2D boundaries only");
            if (shape->role().moving())
                props.error("velocity", fmt::format("{} has static obstacles only; boundary '{}' moves", m_who,
                                                    shape->description()));
            if (!shape->has_inside()) {
                log_warn("{}: boundary '{}' has no inside (unsigned); a grid solver cannot voxelise it, ignored", m_who,
                         shape->description());
                continue;
            }
            if (shape->role().stream_value != 0 || shape->role().stream_value_given)
                log_warn(
                    "{}: boundary '{}': stream_value (the flux between solids) has no effect on the "
                    "grid solver, whose static solids carry no net flux between them",
                    m_who, shape->description());
            m_obstacles.push_back(shape);
            names.push_back(shape->description());
        }
        if (m_obstacles.empty()) return;
        // Item 6 of issue 16: boundaries that leave no fluid cell are an input error, not an empty run; a solid
        // that covers no cell centre (outside the domain, or thinner than a cell) is a warning.
        const Grid2 grid(m_params.domain, m_params.nx, m_params.ny);
        bool any_fluid = false;
        std::vector<long long> covered(m_obstacles.size(), 0);
        for (int j = 0; j < m_params.ny; ++j)
            for (int i = 0; i < m_params.nx; ++i) {
                const Vec2d c = grid.cell_center(i, j);
                bool solid_here = false;
                for (std::size_t k = 0; k < m_obstacles.size(); ++k)
                    if (m_obstacles[k]->solid2(c)) {
                        ++covered[k];
                        solid_here = true;
                    }
                any_fluid |= !solid_here;
            }
        if (!any_fluid)
            props.error("velocity", fmt::format("the boundaries {} leave no fluid cell on the {}x{} grid",
                                                fmt::join(names, ", "), m_params.nx, m_params.ny));
        for (std::size_t k = 0; k < m_obstacles.size(); ++k)
            if (covered[k] == 0)
                log_warn(
                    "{}: boundary '{}' covers no cell centre of the {}x{} grid (outside the domain "
                    "or thinner than a cell): the grid solver does not see it",
                    m_who, names[k], m_params.nx, m_params.ny);
    }

    bool solid(const Vec2d& p) const {
        for (const auto& s : m_obstacles)
            if (s->solid2(p)) return true;
        return false;
    }

    int dimension() const override { return m_3d ? 3 : 2; }
    TimeStepping time_stepping() const override { return driver_settings().time; }
    double viscosity() const override { return m_3d ? m_3d->settings.viscosity : m_params.viscosity; }
    std::shared_ptr<const VorticityField> vorticity_field() const override { return m_3d ? nullptr : m_params.field; }
    const VorticityField3* vorticity_field3() const override { return m_3d ? m_3d->field : nullptr; }
    std::unique_ptr<FluidSolver> create_solver(const RunContext& ctx) const override {
        if (m_3d)
            throw InputError({}, fmt::format("simulation '{}' is 3D: its solver is a StableFluids3Solver (run it as a "
                                             "job, or build one from stable_fluids3.h)",
                                             m_who));
        return make_solver(ctx);
    }
    std::unique_ptr<MCFluid3Solver> create_solver3(const RunContext& ctx) const override {
        if (!m_3d) return Simulation::create_solver3(ctx);  // the 2D error
        throw InputError({}, fmt::format("simulation '{}' is a 3D grid baseline, not an MCFluid3Solver (run it as a "
                                         "job, or build a StableFluids3Solver from stable_fluids3.h)",
                                         m_who));
    }

    /// The solver run(ctx) steps, at t = 0 (with the dye and ctx.cancel as its token); it refers to this object.
    std::unique_ptr<StableFluidsSolver> make_solver(const RunContext& ctx) const {
        StableFluidsSettings s;
        s.domain = m_params.domain;
        s.nx = m_params.nx;
        s.ny = m_params.ny;
        s.advection = m_params.advection;
        s.viscosity = m_params.viscosity;
        s.tolerance = m_tolerance;
        s.seed = ctx.seed;
        s.projection = m_projection;
        s.transport = m_transport;
        s.flip_ratio = m_flip_ratio;
        s.particles_per_cell = m_particles_per_cell;
        if (!m_obstacles.empty()) s.solid = [this](const Vec2d& p) { return solid(p); };
        const VorticityField* field = m_params.field.get();
        auto solver = std::make_unique<StableFluidsSolver>(s, [field](const Vec2d& x) { return field->vorticity(x); });
        if (m_params.dye) solver->set_dye(std::make_unique<PassiveScalars>(s.domain, *m_params.dye, s.nx, s.ny));
        solver->set_cancel_token(ctx.cancel);
        return solver;
    }

    std::unique_ptr<DrivenSolver> driven_solver(const RunContext& ctx) const override {
        if (m_3d) return driven_solver3(ctx);
        std::unique_ptr<StableFluidsSolver> owned = make_solver(ctx);
        const StableFluidsSolver& solver = *owned;
        const StableFluidsSettings& s = solver.settings();
        const std::string transport =
            m_transport == Transport::FLIP
                ? fmt::format("FLIP particles ({} per cell, flip_ratio {:g}, {} moves)", s.particles_per_cell,
                              s.flip_ratio, fluid::to_string(s.advection))
                : fmt::format("semi-Lagrangian advection ({})", fluid::to_string(s.advection));
        const std::string effects = fmt::format(
            "{}, dt {:g}, {} steps, on a {}x{} MAC grid; pressure projection ({}){}; boundaries {}{}", transport,
            m_params.dt, m_params.steps, s.nx, s.ny,
            solver.projection() == Projection::FFT ? "FFT, exact inverse of the discrete Laplacian"
            : solver.projection() == Projection::Multigrid
                ? fmt::format("multigrid-preconditioned CG to {:g}", s.tolerance)
                : fmt::format("incomplete-Cholesky CG to {:g}", s.tolerance),
            s.viscosity > 0 ? "; implicit viscosity" : "", s.domain.periodic ? "periodic" : "free-slip box walls",
            m_obstacles.empty() ? ""
                                : fmt::format(" + {} static solid(s), {} fluid cells of {}", m_obstacles.size(),
                                              solver.fluid_cells(), std::size_t(s.nx) * std::size_t(s.ny)));
        return std::make_unique<Solver2Run>(m_who, std::move(owned), m_params, effects);
    }
    DriverSettings driver_settings() const override {
        if (!m_3d) return m_params.driver_settings(m_who);
        DriverSettings d = m_3d->driver_settings();
        d.who = m_who;
        return d;
    }

private:
    std::string m_who;
    SimulationParams m_params;                ///< dimension = 2
    std::unique_ptr<Simulation3Params> m_3d;  ///< dimension = 3
    Transport m_transport;
    double m_flip_ratio = 0.95;
    int m_particles_per_cell = 6;
    double m_tolerance = 1e-10;
    Projection m_projection = Projection::Auto;
    std::vector<std::shared_ptr<const BoundaryShape>> m_obstacles;
};

}  // namespace
}  // namespace kelvin::fluid

namespace {
/// The parameters of the MAC-grid solvers (stable_fluids, flip): the simulations' own, then the projection's, then
/// `extra`.
std::vector<kelvin::ParamSpec> grid_solver_params(std::vector<kelvin::ParamSpec> extra = {}) {
    std::vector<kelvin::ParamSpec> p{
        KELVIN_FLUID_SIMULATION_PARAMS,
        kelvin::param::real("tolerance", 1e-10, "relative residual of the iterative solves"),
        kelvin::param::string("projection", "auto",
                              "pressure solver: auto (fft without obstacles, else multigrid), fft, multigrid, cg (2D)"),
        kelvin::param::boolean("write_vdb", true, "3D: write frames as OpenVDB files"),
        kelvin::param::string("slice_axis", "y", "3D: PNG slices normal to 'x', 'y' or 'z'"),
        kelvin::param::boolean("stretching", true, "3D mcfluid's; accepted and ignored (a grid solver stretches)"),
        kelvin::param::boolean("control_variates", false, "3D mcfluid's; accepted and ignored"),
        kelvin::param::integer("initial_samples", 0, "3D mcfluid's; accepted and ignored"),
        kelvin::param::real("control_variate_blend", 1.0, "3D mcfluid's; accepted and ignored"),
        kelvin::param::string("sample_allocation", "uniform", "3D mcfluid's; accepted and ignored"),
        kelvin::param::real("stretching_filter", kelvin::fluid::AutoFilter, "3D mcfluid's; accepted and ignored")};
    p.insert(p.end(), extra.begin(), extra.end());
    return p;
}
}  // namespace

static const kelvin::PluginRegistrar kelvin_stable_fluids_registrar(
    "simulation", "stable_fluids",
    "Baseline: Stam's stable fluids on a MAC grid, 2D or 3D (semi-Lagrangian advection, implicit viscosity, "
    "pressure projection by FFT or multigrid-preconditioned CG, static obstacles); same scene and outputs as mcfluid.",
    grid_solver_params(), [](const kelvin::Properties& p) -> kelvin::ObjectPtr {
        return std::make_shared<kelvin::fluid::StableFluids>(p, kelvin::fluid::Transport::SemiLagrangian);
    });

static const kelvin::PluginRegistrar kelvin_flip_registrar(
    "simulation", "flip",
    "Baseline: FLIP particles (6 per cell in 2D, 8 in 3D; flip_ratio 0.95) on the stable_fluids MAC grid and "
    "projection, 2D or 3D, static obstacles; same scene and outputs as mcfluid.",
    grid_solver_params(
        {kelvin::param::real("flip_ratio", 0.95, "weight of the grid's change in the particles' update (0: PIC)"),
         kelvin::param::integer("particles_per_cell", 6, "particles seeded per fluid cell (3D default: 8)")}),
    [](const kelvin::Properties& p) -> kelvin::ObjectPtr {
        return std::make_shared<kelvin::fluid::StableFluids>(p, kelvin::fluid::Transport::FLIP);
    });
