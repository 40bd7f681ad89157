// vortex_particles: the vortex particle (blob) baseline, run as a Job by `kelvin scene.xml`. One particle per
// cell of the <cache type="grid"> lattice carries the circulation omega h^2 of its cell; the velocity is the
// Biot–Savart sum over the particles with the Rosenhead–Moore kernel, by a Barnes–Hut tree code (O(N log N); on
// periodic boxes over the 3 x 3 images, the farther ones interpolated) or the direct O(N^2) sum; particles move by RK4
// or Euler; viscosity is Chorin's random walk. Takes the same scene as mcfluid (switch with one word:
// type="vortex_particles") and writes the same files.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
// Free-slip walls and obstacles: a <velocity type="walk_on_spheres"> child's boundaries (the domain's walls and its
// <boundary> solids, static, open domains, inflow/outflow walls too) become vortex panels (fluid/panels.h): the same
// Dirichlet problem for Psi as mcfluid's walks, with each solid's stream_value.
//
//     <simulation type="vortex_particles"> ... same children as mcfluid ... </simulation>
#include <kelvin/core/job.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/boundary.h>
#include <kelvin/fluid/panels.h>
#include <kelvin/fluid/vortex_particles.h>

#include <fmt/format.h>

#include <cmath>

namespace kelvin::fluid {
namespace {

class VortexParticles final : public Simulation {
public:
    explicit VortexParticles(const Properties& props)
        : m_params(SimulationParams::parse_baseline(props, "vortex_particles")) {
        m_delta = props.get_float("blob_radius");
        if (!std::isfinite(m_delta) || (m_delta <= 0 && m_delta != -1))
            props.error("blob_radius", "must be positive, or -1 for one lattice spacing");
        m_threshold = props.get_float("threshold", 0.0, 1.0);
        m_summation = props.get_choice("summation", {"tree", "direct"}) == "tree" ? ParticleSummation::Tree
                                                                                  : ParticleSummation::Direct;
        m_theta = props.get_float("theta");
        if (!(m_theta > 0 && m_theta <= 1)) props.error("theta", fmt::format("must be in (0, 1] (got {:g})", m_theta));
        m_panel_length = props.get_float("panel_length");
        if (!std::isfinite(m_panel_length) || (m_panel_length <= 0 && m_panel_length != -1))
            props.error("panel_length", "must be positive, or -1 for one lattice spacing");
        // Lengths against the domain (checks.h): half its smaller side at most.
        const Vec2d size = m_params.domain.size();
        const double side = std::min(size.x, size.y);
        if (const std::string why = check_scale("blob_radius", m_delta, side, 0.5,
                                                "every blob would cover the domain (the velocity smoothed away)");
            m_delta > 0 && !why.empty())
            props.error("blob_radius", why);
        if (const std::string why = check_scale("panel_length", m_panel_length, side, 0.5,
                                                "a panel would be longer than the boundaries it discretises");
            m_panel_length > 0 && !why.empty())
            props.error("panel_length", why);
        read_boundaries(props);
    }

    /// The <velocity> estimator's boundaries (walk_on_spheres), checked as mcfluid checks them, plus what the panel
    /// method needs: an open domain, no inflow, static solids that give their segments.
    void read_boundaries(const Properties& props) {
        auto velocity = std::dynamic_pointer_cast<const VelocityEstimator>(props.get_object("velocity"));
        m_boundaries = velocity ? velocity->boundaries() : nullptr;
        if (!m_boundaries) return;
        const WosVelocityOptions& o = *m_boundaries;
        const Domain2& d = m_params.domain;
        if (d.periodic)
            props.error("velocity", "vortex_particles: free-slip boundaries need an open domain (periodic is set)");
        if (const std::string why = check_wos_options(o, d); !why.empty()) props.error("velocity", why);
        for (const auto& shape : o.shapes) {
            if (shape->role().moving())
                props.error("velocity", fmt::format("vortex_particles has static obstacles only; boundary '{}' moves",
                                                    shape->description()));
            if (shape->segments2(1).empty())
                props.error("velocity", fmt::format("vortex_particles: boundary '{}' gives no segments for the panel "
                                                    "method (use polygon, polyline, disk, box, capsule, a 2D mesh or "
                                                    "a signed level set)",
                                                    shape->description()));
        }
        if (const std::string why = check_wos_cells(o, d, m_params.nx, m_params.ny); !why.empty())
            props.error("velocity", why);
        const double h = std::min(d.size().x / m_params.nx, d.size().y / m_params.ny);
        const double length = m_panel_length > 0 ? m_panel_length : h;
        const std::size_t panels = boundary_panels(o, d, o.walls, length, nullptr).size();
        if (panels > MaxPanels)
            props.error(
                m_panel_length > 0 ? "panel_length" : "velocity",
                fmt::format("the boundaries make {} panels of length {:g} (at most {}: the dense panel system); "
                            "raise panel_length",
                            panels, length, MaxPanels));
    }

    int dimension() const override { return 2; }
    TimeStepping time_stepping() const override { return {m_params.dt, m_params.steps, m_params.end_time}; }
    double viscosity() const override { return m_params.viscosity; }
    std::shared_ptr<const VorticityField> vorticity_field() const override { return m_params.field; }
    std::unique_ptr<FluidSolver> create_solver(const RunContext& ctx) const override { return make_solver(ctx); }

    /// The solver run(ctx) steps, at t = 0 (with the dye and ctx.cancel as its token).
    std::unique_ptr<VortexParticleSolver> make_solver(const RunContext& ctx) const {
        VortexParticleSettings s;
        s.domain = m_params.domain;
        s.nx = m_params.nx;
        s.ny = m_params.ny;
        s.delta = m_delta;
        s.advection = m_params.advection;
        s.viscosity = m_params.viscosity;
        s.threshold = m_threshold;
        s.seed = ctx.seed;
        s.summation = m_summation;
        s.theta = m_theta;
        s.boundaries = m_boundaries;
        s.panel_length = m_panel_length;
        const VorticityField* field = m_params.field.get();
        auto solver =
            std::make_unique<VortexParticleSolver>(s, [field](const Vec2d& x) { return field->vorticity(x); });
        if (m_params.dye) solver->set_dye(std::make_unique<PassiveScalars>(s.domain, *m_params.dye, s.nx, s.ny));
        solver->set_cancel_token(ctx.cancel);
        return solver;
    }

    std::unique_ptr<DrivenSolver> driven_solver(const RunContext& ctx) const override {
        std::unique_ptr<VortexParticleSolver> owned = make_solver(ctx);
        const VortexParticleSolver& solver = *owned;
        const VortexParticleSettings& s = solver.settings();
        const std::string effects = fmt::format(
            "particle transport ({}, dt {:g}, {} steps, {} particles) with {} Biot–Savart summation (blob "
            "radius {:g}{}){}; boundaries {}",
            fluid::to_string(s.advection), m_params.dt, m_params.steps, solver.particle_count(),
            solver.uses_tree()
                ? fmt::format("Barnes–Hut tree (theta {:g}{})", s.theta,
                              s.domain.periodic
                                  ? ", periodic: 3 x 3 images, the far images interpolated from a 16 x 16 "
                                    "lattice"
                                  : "")
            : s.summation == ParticleSummation::Tree
                ? fmt::format("direct (periodic box with fewer than {} particles: cheaper than the tree)",
                              VortexParticleSolver::PeriodicTreeMinParticles)
                : std::string("direct"),
            solver.delta(), s.domain.periodic ? ", periodic kernel" : "",
            s.viscosity > 0 ? ", viscosity by random walk" : "",
            solver.panels()     ? fmt::format("free slip by {} vortex panels ({})", solver.panels()->size(),
                                              describe(*m_boundaries, s.domain))
            : s.domain.periodic ? std::string("none (periodic)")
                                : std::string("none (free space)"));
        return std::make_unique<Solver2Run>("vortex_particles", std::move(owned), m_params, effects);
    }
    DriverSettings driver_settings() const override { return m_params.driver_settings("vortex_particles"); }

private:
    SimulationParams m_params;
    double m_delta = -1, m_threshold = 0, m_theta = 0.5, m_panel_length = -1;
    std::shared_ptr<const WosVelocityOptions> m_boundaries;
    ParticleSummation m_summation = ParticleSummation::Tree;
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(
    kelvin::fluid::VortexParticles, "simulation", "vortex_particles",
    "Baseline: vortex particles (blobs) with Barnes–Hut tree (O(N log N)) or direct O(N^2) Biot–Savart "
    "summation, RK4/Euler, random-walk viscosity; same scene and outputs as mcfluid.",
    KELVIN_FLUID_SIMULATION_PARAMS,
    kelvin::param::real("blob_radius", -1.0, "blob radius delta; -1: one lattice spacing"),
    kelvin::param::real("threshold", 0.0, "skip cells with |omega| <= threshold * max |omega|"),
    kelvin::param::string("summation", "tree",
                          "'tree' (Barnes–Hut; periodic boxes: 3 x 3 images + interpolated far images) or 'direct'"),
    kelvin::param::real("theta", 0.5, "tree opening angle in (0, 1]: node used whole if size < theta * distance"),
    kelvin::param::real("panel_length", -1.0, "longest free-slip boundary panel; -1: one lattice spacing"));
