// mcfluid in 2D as a simulation: its parameters (MCFluidParams) and the driver's adapter of its solver (see
// include/kelvin/fluid/simulation.h).
#include <kelvin/core/distributed.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/boundary.h>
#include <kelvin/fluid/estimators.h>
#include <kelvin/fluid/output.h>
#include <kelvin/fluid/simulation.h>
#include <kelvin/fluid/velocity.h>

#include <fmt/format.h>

#include <algorithm>

namespace kelvin::fluid {

MCFluidParams MCFluidParams::parse(const Properties& props) {
    for (const char* name : {"stretching", "control_variates", "initial_samples", "control_variate_blend",
                             "sample_allocation", "write_vdb", "slice_axis"})
        if (props.has(name))
            props.error(name,
                        "is a 3D parameter (dimension = 3); 2D flows have no stretching term, and 2D outputs are "
                        "PNG/EXR frames");
    if (auto obj = props.get_object("vorticity");
        obj && !dynamic_cast<const VorticityField*>(obj.get()) && dynamic_cast<const VorticityField3*>(obj.get()))
        props.error("vorticity", fmt::format("'{}' is a 3D vorticity field; set dimension = 3", obj->plugin_name()));
    MCFluidParams p;
    // The parameters the baselines share (domain, dt, steps or end_time, viscosity, advection, outputs, the initial
    // vorticity, the grid resolution, the dye): one parser for all 2D solvers.
    p.common = SimulationParams::parse(props, "mcfluid");
    MCFluidSettings& s = p.settings;
    s.domain = p.common.domain;
    s.dt = p.common.dt;
    s.viscosity = p.common.viscosity;
    s.advection = p.common.advection;
    s.transport = p.common.transport;
    s.nx = p.common.nx;
    s.ny = p.common.ny;
    s.diffusion_samples = int(props.get_int("diffusion_samples", 1, 1 << 20));
    s.backtrace_velocity = p.common.backtrace_velocity;
    s.velocity_filter = p.common.velocity_filter;
    s.velocity_time = p.common.velocity_time;
    if (p.common.filter_kernel) s.filter_kernel = *p.common.filter_kernel;
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
        props.error("velocity", fmt::format("'{}' is a 3D velocity estimator; set dimension = 3 or use a 2D one such "
                                            "as biot_savart or walk_on_spheres",
                                            velocity->plugin_name()));
    auto cache = props.get_object_as<CacheSpec>("cache");
    if (!cache) cache = std::dynamic_pointer_cast<CacheSpec>(Registry::instance().create(Properties("cache", "grid")));
    s.estimator = velocity;
    if (const std::string why = velocity->check2(s.domain); !why.empty())
        props.error("velocity", velocity->plugin_name() + ": " + why);
    s.boundaries = velocity->boundaries();
    for (const char* name : {"velocity_filter", "filter_kernel"})
        if (props.has(name) && (s.backtrace_velocity == BacktraceVelocity::Estimates ||
                                (s.backtrace_velocity == BacktraceVelocity::Auto && s.boundaries)))
            props.error(name,
                        "filters the cached velocity the backtraces read: set backtrace_velocity = 'cache' (with "
                        "boundaries 'auto' reads fresh estimates)");
    if (s.boundaries)  // solid boundaries: what they leave of the cache
        if (const std::string why = check_wos_cells(*s.boundaries, s.domain, s.nx, s.ny); !why.empty())
            props.error("velocity", velocity->plugin_name() + ": " + why);
    s.interpolation = cache->interpolation();
    if (const auto* bs = dynamic_cast<const BiotSavartVelocity*>(velocity.get()); bs && !s.boundaries) {
        const Vec2d h = s.domain.size() / Vec2d(s.nx, s.ny);
        const double delta = bs->delta() >= 0 ? bs->delta() : 0.5 * std::min(h.x, h.y);
        if (const std::string why = bs->check_cells2(h, delta, s.nx, s.ny, s.domain.periodic); !why.empty())
            props.error("velocity", velocity->plugin_name() + ": " + why);
    }
    p.energy_passes = energy_passes_param(props);
    p.energy_budget = props.get_bool("energy_budget");
    if (p.energy_budget && s.boundaries)
        if (const std::string why = check_wall_budget(*s.boundaries, s.domain, s.nx, s.ny); !why.empty())
            props.error("energy_budget", why);
    if (p.energy_budget && s.viscosity > 0) props.error("energy_budget", "covers inviscid flows only (viscosity 0)");
    if (cache->resolution_z() != 0) props.error("cache", "resolution_z is for 3D caches (dimension = 3)");
    return p;
}

std::unique_ptr<MCFluidSolver> create_mcfluid_solver(const MCFluidParams& p, const RunContext& ctx) {
    MCFluidSettings settings = p.settings;
    settings.seed = ctx.seed;
    settings.samples = run_samples(ctx, settings.estimator->samples());
    const VorticityField* field = p.common.field.get();
    auto solver = std::make_unique<MCFluidSolver>(settings, [field](const Vec2d& x) { return field->vorticity(x); });
    if (p.common.dye)
        solver->set_dye(std::make_unique<PassiveScalars>(settings.domain, *p.common.dye, settings.nx, settings.ny));
    solver->set_cancel_token(ctx.cancel);
    solver->set_communicator(ctx.comm);
    if (p.energy_budget) solver->set_energy_budget(true);
    solver->set_energy_passes(p.energy_passes);
    return solver;
}

namespace {

// mcfluid's solver as the driver runs it: a Solver2Run whose velocity is a separate pass (skipped for the last
// state when no output needs it, and cut short by a stop), whose frames draw its boundaries, and whose counters
// include the walks.
class MCFluidRun final : public Solver2Run {
public:
    MCFluidRun(std::unique_ptr<MCFluidSolver> solver, const MCFluidParams& p, bool spp)
        : Solver2Run("mcfluid", std::move(solver), p.common, {}),
          m_mc(static_cast<MCFluidSolver&>(*m_solver)),
          m_params(p),
          m_spp(spp) {
        const MCFluidSettings& s = m_mc.settings();
        if (s.boundaries)  // PNG frames draw the solids and the walls (moving solids where they are)
            for (const auto& shape : s.boundaries->shapes)
                if (shape->role().moving()) m_overlay.fixed = false;
    }

    bool lazy_velocity() const override { return true; }

    // With the energy budget, six more columns: the state's deterministic energy and the last step's split.
    std::string csv_header() const override {
        std::string h = Solver2Run::csv_header();
        if (m_mc.energy_budget_step()) h += EnergyBudget::csv_columns(false, m_mc.energy_budget_has_boundary());
        if (m_mc.energy_passes() > 0) h += paired_energy_columns();
        return h;
    }
    std::string csv_row(double seconds, double evals, uint64_t invalid, double cfl) const override {
        std::string row = Solver2Run::csv_row(seconds, evals, invalid, cfl);
        if (const EnergyBudget* b = m_mc.energy_budget_step()) {
            if (!row.empty() && row.back() == '\n') row.pop_back();
            row += b->csv_values(false, m_mc.energy_budget_has_boundary()) + "\n";
        }
        if (m_mc.energy_passes() > 0) {
            if (!row.empty() && row.back() == '\n') row.pop_back();
            row += paired_energy_values(m_paired_now ? m_paired : PairedEnergy{}) + "\n";
        }
        return row;
    }
    bool image_carries_velocity(const std::string& ext) const override { return ext == ".exr"; }

    bool diagnose(bool velocity) override {
        if (velocity && !m_mc.velocity_available()) {  // a stop cut the velocity's pass short
            m_d = m_mc.diagnostics(false);
            m_velocity = false;
            return false;
        }
        m_d = m_mc.diagnostics(velocity);
        m_paired_now =
            velocity && paired_energy_due(m_mc.energy_passes(), m_mc.step_index(), m_p.steps, m_p.output_every);
        if (m_paired_now) {
            m_paired = m_mc.paired_energy();
            if (!m_have_d0) m_paired0 = m_paired;
        }
        if (velocity)
            m_d.vorticity_rmse_exact = exact_vorticity_rmse(m_mc.vorticity_grid(), *m_p.field, m_d.time, m_p.viscosity,
                                                            bool(m_mc.settings().boundaries));
        m_velocity = velocity;
        if (!m_have_d0) m_d0 = m_d, m_have_d0 = true;
        return velocity;
    }

    std::vector<std::string> describe() override {
        const MCFluidSettings& s = m_mc.settings();
        std::vector<std::string> lines;
        if (m_spp)  // --spp: the Monte Carlo sample count of a simulation is n_mc
            lines.push_back(fmt::format("--spp {} overrides the Biot–Savart samples (n_mc)", s.samples));
        lines.push_back(fmt::format("2D, domain {}, {}x{} cache ({}), initial {}", s.domain.to_string(), s.nx, s.ny,
                                    fluid::to_string(s.interpolation), m_p.field->description()));
        // The near field the estimator resolved on these cells (biot_savart: its default adapts to delta).
        const auto near_field_effect = [&]() -> std::string {
            const auto* bs = dynamic_cast<const BiotSavartVelocity*>(s.estimator.get());
            if (!bs) return {};
            const Vec2d h = s.domain.size() / Vec2d(s.nx, s.ny);
            const int R = bs->near_field2(h, m_mc.delta(), s.nx, s.ny, s.domain.periodic);
            return R > 0 ? fmt::format(", the {} nearest cells summed exactly", (2 * R + 1) * (2 * R + 1))
                         : std::string();
        };
        const std::string velocity =
            s.boundaries ? fmt::format(
                               "Walk-on-Spheres free-slip velocity ({} gradient samples, antithetic {}, {}{}{}, "
                               "epsilon {:g}, max_steps {})",
                               s.samples, s.boundaries->wos.antithetic ? "on" : "off",
                               m_mc.boundary_field()->control_variate()
                                   ? fmt::format("control variate with {} free samples", s.boundaries->free_samples)
                                   : std::string("plain walks"),
                               s.boundaries->stratified ? ", stratified" : "",
                               m_mc.boundary_field()->harmonic_disks() > 0
                                   ? fmt::format(", harmonic cache ({} disks hold {} of the {} cells at t = {:g})",
                                                 m_mc.boundary_field()->harmonic_disks(),
                                                 m_mc.boundary_field()->harmonic_cells(), s.nx * s.ny, m_mc.time())
                                   : std::string(),
                               m_mc.boundary_field()->settings().epsilon, s.boundaries->wos.max_steps)
                         : s.estimator->effect(s.samples, m_mc.delta(), s.domain.periodic) + near_field_effect();
        lines.push_back(fmt::format(
            "effects: advection ({}, dt {:g}, {} steps, transport {}, {}, velocity {}) with {}; boundaries {}; "
            "diffusion {}; "
            "stretching off (2D); {}",
            fluid::to_string(s.advection), s.dt, m_p.steps, fluid::to_string(s.transport),
            s.backtrace_velocity == BacktraceVelocity::Cache
                ? fmt::format("stages read the cached velocity, {} filter {:g} cells",
                              s.filter_kernel == FilterKernel::Twicing ? "twicing" : "Gaussian", s.velocity_filter)
                : std::string("a fresh estimate at every stage"),
            m_mc.midstep() ? "at mid-step, extrapolated" : "frozen at the step's start", velocity,
            s.boundaries ? fluid::describe(*s.boundaries, s.domain) : std::string("none"),
            s.viscosity > 0 ? fmt::format("on (nu {:g}, Feynman–Kac, n_d {})", s.viscosity, s.diffusion_samples)
                            : std::string("off (inviscid)"),
            dye_effect(m_p.dye.get())));
        return lines;
    }

    void report(Stats& stats) const override {
        const FluidWork& w = m_mc.work();
        const MCFluidSettings& s = m_mc.settings();
        report_fluid_counters(stats, w);
        report_walks(stats, "fluid.wos_",
                     {w.wos_walks, w.wos_steps, w.wos_truncated, w.wos_invalid, w.wos_boundary_queries}, "mcfluid",
                     s.boundaries ? s.boundaries->wos.max_steps : 0);
        stats.add("fluid.solid_departures", double(w.solid_departures), "points");
        if (const EnergyBudget* b = m_mc.energy_budget_total())
            b->add_stats(stats, false, m_mc.energy_budget_has_boundary());
        if (m_mc.energy_passes() > 0) add_paired_energy_stats(stats, m_paired0, m_paired);
        report_dye_stats(stats, m_mc.dye());
    }

    void warn() const override {
        const FluidWork& w = m_mc.work();
        if (w.invalid_velocity + w.invalid_vorticity > 0)
            log_warn(
                "mcfluid: {} non-finite velocity estimate(s) and {} non-finite vorticity value(s) were replaced by "
                "zero",
                w.invalid_velocity, w.invalid_vorticity);
    }

    std::string summary(const std::string& ended) override {
        std::string s = summary_line(ended);
        if (const EnergyBudget* b = m_mc.energy_budget_total())
            s += b->summary(false, m_mc.energy_budget_has_boundary());
        if (m_mc.energy_passes() > 0) s += paired_energy_summary(m_paired0, m_paired);
        return s;
    }

    std::string summary_line(const std::string& ended) {
        const bool viscous = m_p.viscosity > 0;
        const char* dye = m_mc.dye() ? ", dye" : "";
        if (!m_velocity && ended.empty()) {  // the last state without its velocity: no output needed it
            const FluidDiagnostics dn = m_mc.diagnostics(false);
            return fmt::format(
                "t = {:g}: enstrophy {:.6g} (initial {:.6g}), circulation {:.6g}, max |omega| {:.6g} (the final "
                "state's velocity and energy were not estimated: no output needs them; the CSV or an .exr output "
                "does); active effects: advection{}{}",
                dn.time, dn.enstrophy, m_d0.enstrophy, dn.circulation, dn.max_abs_vorticity,
                viscous ? ", diffusion" : "", dye);
        }
        if (!m_velocity)
            return fmt::format(
                "{} at t = {:g} before the velocity of that state was estimated; the image has no u "
                "and v channels",
                ended, m_mc.time());
        const FluidDiagnostics dn = m_mc.diagnostics(true);
        return fmt::format(
            "t = {:g}: energy noise-corrected {:.6g}, raw {:.6g} (initial {:.6g}, {:.6g}), enstrophy {:.6g} (initial "
            "{:.6g}), circulation {:.6g}, max |omega| {:.6g}; active effects: advection{}{}",
            dn.time, dn.kinetic_energy, dn.kinetic_energy_raw, m_d0.kinetic_energy, m_d0.kinetic_energy_raw,
            dn.enstrophy, m_d0.enstrophy, dn.circulation, dn.max_abs_vorticity, viscous ? ", diffusion" : "", dye);
    }

protected:
    const FrameOverlay* overlay() override {
        const WosVelocityField* b = m_mc.boundary_field();
        if (!b) return nullptr;
        m_overlay.solid = [b](Vec2d x) { return b->solid_at(x) >= 0; };
        m_overlay.distance = [b](Vec2d x) { return b->distance(x); };
        return &m_overlay;
    }

private:
    MCFluidSolver& m_mc;
    const MCFluidParams& m_params;
    bool m_spp;
    FrameOverlay m_overlay;
    PairedEnergy m_paired0, m_paired;  ///< energy_passes: the first and the last measured state's
    bool m_paired_now = false;         ///< the current state's was measured
};

}  // namespace

std::unique_ptr<DrivenSolver> drive_mcfluid(const MCFluidParams& p, const RunContext& ctx) {
    return std::make_unique<MCFluidRun>(create_mcfluid_solver(p, ctx), p, ctx.spp > 0);
}

}  // namespace kelvin::fluid
